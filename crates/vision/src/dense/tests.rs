//! Dense alignment's tests on rendered scenes.

use super::*;
use nalgebra::Vector3;

/// Renders a textured fronto-parallel-ish scene (a slanted plane) seen from `cam_from_world`.
fn render(
    cam: &PinholeCamera,
    cam_from_world: &Se3,
    w: usize,
    h: usize,
) -> (GrayImage, Image<f32>) {
    // Plane z = 3 + 0.2 x in world; texture by world (x, y).
    let world_from_cam = cam_from_world.inverse();
    let tex = |x: f64, y: f64| {
        128.0 + 50.0 * (x * 9.0).sin() * (y * 7.0).cos() + 40.0 * ((x + 2.0 * y) * 4.0).sin()
    };
    let mut img = GrayImage::new(w, h);
    let mut depth = Image::<f32>::filled(w, h, f32::NAN);
    for v in 0..h {
        for u in 0..w {
            let ray_c = cam
                .unproject_depth(&Vector2::new(u as f64, v as f64), 1.0)
                .unwrap();
            let o = world_from_cam.act(&Vector3::zeros());
            let dir = world_from_cam.act(&ray_c) - o;
            // Solve (o + s dir).z = 3 + 0.2 (o + s dir).x
            let s = (3.0 + 0.2 * o.x - o.z) / (dir.z - 0.2 * dir.x);
            let p = o + dir * s;
            img.set(u, v, tex(p.x, p.y).clamp(0.0, 255.0) as u8);
            depth.set(u, v, (cam_from_world.act(&p)).z as f32);
        }
    }
    (img, depth)
}

#[test]
fn recovers_a_small_motion() {
    let cam = PinholeCamera::new(200.0, 200.0, 79.5, 59.5);
    let ref_from_world = Se3::identity();
    let cur_from_world = Se3::exp(&Vector6::new(0.03, -0.02, 0.04, 0.01, -0.015, 0.02));
    let (iref, dref) = render(&cam, &ref_from_world, 160, 120);
    let (icur, _) = render(&cam, &cur_from_world, 160, 120);
    let r = align(
        &iref,
        &dref,
        &icur,
        &cam,
        &Se3::identity(),
        &DenseParams {
            levels: 3,
            ..Default::default()
        },
    )
    .unwrap();
    let truth = cur_from_world.compose(&ref_from_world.inverse());
    let err = r.cur_from_ref.compose(&truth.inverse()).log();
    assert!(
        err.fixed_rows::<3>(0).norm() < 2e-3,
        "translation error {}",
        err.fixed_rows::<3>(0).norm()
    );
    assert!(
        err.fixed_rows::<3>(3).norm() < 2e-3,
        "rotation error {}",
        err.fixed_rows::<3>(3).norm()
    );
    let res = residual_image(&iref, &dref, &icur, &cam, &r.cur_from_ref);
    assert_eq!(res.width(), 160);
}

#[test]
fn stopping_at_a_coarser_level_is_a_coarser_prior() {
    // The same motion, aligned down to level 1 only (the live tracker's prior) on prebuilt
    // pyramids: close to the truth, and the residual count is level 1's.
    let cam = PinholeCamera::new(200.0, 200.0, 79.5, 59.5);
    let cur_from_world = Se3::exp(&Vector6::new(0.03, -0.02, 0.04, 0.01, -0.015, 0.02));
    let (iref, dref) = render(&cam, &Se3::identity(), 160, 120);
    let (icur, _) = render(&cam, &cur_from_world, 160, 120);
    let params = DenseParams {
        levels: 3,
        finest_level: 1,
        ..Default::default()
    };
    let (pr, pc) = (
        Pyramid::new(&iref, 3, 16).unwrap(),
        Pyramid::new(&icur, 3, 16).unwrap(),
    );
    let coarse = align_pyramids(&pr, &dref, &pc, &cam, &Se3::identity(), &params).unwrap();
    let full = align(
        &iref,
        &dref,
        &icur,
        &cam,
        &Se3::identity(),
        &DenseParams {
            levels: 3,
            ..Default::default()
        },
    )
    .unwrap();
    let err = coarse.cur_from_ref.compose(&cur_from_world.inverse()).log();
    assert!(err.norm() < 1e-2, "level-1 prior error {}", err.norm());
    assert!(
        coarse.num_residuals < full.num_residuals / 2,
        "{} vs {}",
        coarse.num_residuals,
        full.num_residuals
    );
}

/// A rendered pair of an odd size (points not a multiple of 8, rows not a multiple of the
/// AVX2 steps) with holes in the depth (NaN, 0, negative, ∞) and a textured plane.
fn holey_pair() -> (PinholeCamera, GrayImage, Image<f32>, GrayImage, Se3) {
    let cam = PinholeCamera::new(180.0, 175.0, 78.3, 56.1);
    let cur_from_world = Se3::exp(&Vector6::new(0.02, -0.03, 0.05, -0.012, 0.02, 0.01));
    let (w, h) = (157, 113);
    let (iref, mut dref) = render(&cam, &Se3::identity(), w, h);
    let (icur, _) = render(&cam, &cur_from_world, w, h);
    for v in 0..h {
        for u in 0..w {
            let bad = [f32::NAN, 0.0, -1.0, f32::INFINITY];
            if (u * 7 + v * 13) % 11 == 0 {
                dref.set(u, v, bad[(u + v) % 4]);
            }
            if (40..52).contains(&u) && (30..70).contains(&v) {
                dref.set(u, v, f32::NAN); // a block of missing depth
            }
        }
    }
    (cam, iref, dref, icur, cur_from_world)
}

fn reference_bits(r: &DenseReference) -> Vec<Vec<u32>> {
    r.levels
        .iter()
        .flat_map(|l| [&l.x, &l.y, &l.z, &l.intensity])
        .map(|c| c.iter().map(|x| x.to_bits()).collect())
        .collect()
}

#[test]
fn simd_and_scalar_paths_agree_bit_for_bit() {
    let (cam, iref, dref, icur, _) = holey_pair();
    let (pr, pc) = (
        Pyramid::new(&iref, 4, 8).unwrap(),
        Pyramid::new(&icur, 4, 8).unwrap(),
    );
    for finest in [0, 1, 2] {
        let params = DenseParams {
            levels: 4,
            finest_level: finest,
            max_iterations: 8,
            ..Default::default()
        };
        let run = || {
            let r = DenseReference::new(&pr, &dref, &cam, &params).unwrap();
            let mut scratch = DenseScratch::default();
            // Start far enough out that some points leave the current image.
            let start = Se3::exp(&Vector6::new(0.08, 0.0, 0.0, 0.0, 0.03, 0.0));
            let a = r.align(&pc, &start, &mut scratch).unwrap();
            // The kernels themselves at one pose, every buffer.
            let pose = Pose32::new(&start);
            scratch.prepare(&pc.levels[finest], r.levels[finest].x.len());
            let n = scratch.residuals(&r.levels[finest], &pose, crate::simd::avx2());
            let sums = scratch.accumulate(3.7, crate::simd::avx2());
            let bufs: Vec<Vec<u32>> = [&scratch.r, &scratch.absr]
                .into_iter()
                .chain(&scratch.j)
                .map(|b| b.iter().map(|x| x.to_bits()).collect())
                .collect();
            (
                reference_bits(&r),
                format!("{:?} {:?}", a.cur_from_ref, a.final_cost),
                (a.iterations, a.num_residuals, n),
                bufs,
                sums.map(f64::to_bits),
            )
        };
        let simd = run();
        let scalar = crate::simd::scalar_only(run);
        assert!(
            simd.2.2 > 0 && simd.2.2 < simd.3[0].len(),
            "some points leave the image"
        );
        assert_eq!(simd.0, scalar.0, "reference points, finest {finest}");
        assert_eq!(simd.1, scalar.1, "pose and cost, finest {finest}");
        assert_eq!(simd.2, scalar.2, "counts, finest {finest}");
        assert_eq!(simd.3, scalar.3, "residual buffers, finest {finest}");
        assert_eq!(simd.4, scalar.4, "normal equations, finest {finest}");
    }
}

#[test]
fn reference_points_are_the_block_means_of_inverse_depth() {
    // The block-sum pyramid gives the points of the direct definition: every level-l pixel
    // with enough gradient and at least half of its 2ˡ×2ˡ depths valid, at the harmonic
    // mean of those depths.
    let (cam, iref, dref, _, _) = holey_pair();
    let pr = Pyramid::new(&iref, 4, 8).unwrap();
    let params = DenseParams {
        levels: 4,
        finest_level: 0,
        ..Default::default()
    };
    let r = DenseReference::new(&pr, &dref, &cam, &params).unwrap();
    for (l, level) in r.levels.iter().enumerate() {
        let img = &pr.levels[l];
        let c = cam.scaled(0.5f64.powi(l as i32));
        let s = 1usize << l;
        let mut expected = Vec::new();
        for v in 1..img.height() - 1 {
            for u in 1..img.width() - 1 {
                let gx = 0.5 * (img.get(u + 1, v) as f32 - img.get(u - 1, v) as f32);
                let gy = 0.5 * (img.get(u, v + 1) as f32 - img.get(u, v - 1) as f32);
                if gx * gx + gy * gy < params.min_gradient * params.min_gradient {
                    continue;
                }
                let (mut sum, mut n) = (0.0f64, 0usize);
                for dv in 0..s {
                    for du in 0..s {
                        let d = dref.get(u * s + du, v * s + dv);
                        if d.is_finite() && d > 0.0 {
                            sum += 1.0 / d as f64;
                            n += 1;
                        }
                    }
                }
                if 2 * n >= s * s && n > 0 {
                    let p = c
                        .unproject_depth(&Vector2::new(u as f64, v as f64), n as f64 / sum)
                        .unwrap();
                    expected.push((p, img.get(u, v) as f32));
                }
            }
        }
        assert_eq!(level.count, expected.len(), "level {l}");
        assert!(
            level.x.len().is_multiple_of(LANES)
                && level.z[level.count..].iter().all(|z| z.is_nan())
        );
        for (k, (p, i)) in expected.iter().enumerate() {
            let got = Vector3::new(level.x[k] as f64, level.y[k] as f64, level.z[k] as f64);
            assert!(
                (got - p).norm() < 1e-6 * p.norm(),
                "level {l} point {k}: {got} vs {p}"
            );
            assert_eq!(level.intensity[k], *i);
        }
    }
}

#[test]
fn a_kept_reference_aligns_like_align_pyramids() {
    let (cam, iref, dref, icur, truth) = holey_pair();
    let (pr, pc) = (
        Pyramid::new(&iref, 3, 8).unwrap(),
        Pyramid::new(&icur, 3, 8).unwrap(),
    );
    let params = DenseParams {
        levels: 3,
        ..Default::default()
    };
    let once = align_pyramids(&pr, &dref, &pc, &cam, &Se3::identity(), &params).unwrap();
    let reference = DenseReference::new(&pr, &dref, &cam, &params).unwrap();
    let mut scratch = DenseScratch::default();
    for _ in 0..2 {
        // Twice with the same scratch: reused buffers give the same result.
        let kept = reference
            .align(&pc, &Se3::identity(), &mut scratch)
            .unwrap();
        assert_eq!(kept.cur_from_ref.matrix(), once.cur_from_ref.matrix());
        assert_eq!(kept.iterations, once.iterations);
    }
    let err = once.cur_from_ref.compose(&truth.inverse()).log();
    assert!(err.norm() < 3e-3, "error {}", err.norm());
    assert_eq!(reference.params(), &params);
    assert!(reference.num_points(0) > reference.num_points(1));
    // A depth image of another size is refused.
    let small = Image::<f32>::filled(10, 10, 1.0);
    assert!(DenseReference::new(&pr, &small, &cam, &params).is_err());
}

#[test]
fn rejects_bad_input() {
    let cam = PinholeCamera::new(100.0, 100.0, 10.0, 10.0);
    let a = GrayImage::filled(20, 20, 5);
    let d = Image::<f32>::filled(20, 20, 1.0);
    // Flat image: no gradient, no usable pixel.
    assert!(align(&a, &d, &a, &cam, &Se3::identity(), &DenseParams::default()).is_err());
    let b = GrayImage::new(21, 20);
    assert!(align(&a, &d, &b, &cam, &Se3::identity(), &DenseParams::default()).is_err());
    let one = GrayImage::new(1, 1);
    let d1 = Image::<f32>::filled(1, 1, 1.0);
    assert!(
        align(
            &one,
            &d1,
            &one,
            &cam,
            &Se3::identity(),
            &DenseParams::default()
        )
        .is_err()
    );
}
