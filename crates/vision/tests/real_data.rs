//! Real-data checks of the front-end on `shared/data` (skipped with a message if absent).
//! Heavy measurements are `#[ignore]`d: run them with
//! `cargo test --release -p vision --test real_data -- --ignored --nocapture`.

mod common;

use common::*;
use lie::{LieGroup, Se3};
use std::time::Instant;
use vision::bow::{Database, Vocabulary};
use vision::dense::{DenseParams, align};
use vision::image::{Image, load_gray_u8};
use vision::orb::{Descriptor, OrbParams, detect_and_describe};
use vision::pyramid::Pyramid;
use vision::stereo::{StereoParams, block_match, disparity_to_depth};

#[test]
fn dbow_vocabularies_load() {
    let Some(dir) = data_dir("bow_vocabulary") else {
        return;
    };
    // Node and word counts as stated in the data's PROVENANCE.md (root not counted there).
    for (file, nodes, words) in [
        ("slambook2_ch11_vocabulary_k10_L5.yml.gz", 6162, 4983),
        ("kimera_small_voc_k9_L3.yml.gz", 781, 692),
    ] {
        let v = Vocabulary::load_dbow_yaml(dir.join(file)).unwrap();
        assert_eq!(v.nodes.len() - 1, nodes, "{file}");
        assert_eq!(v.num_words(), words, "{file}");
        // Every word is a leaf and every leaf a word.
        for (i, n) in v.nodes.iter().enumerate().skip(1) {
            assert_eq!(n.children.is_empty(), n.word.is_some(), "{file} node {i}");
        }
        // Transforming descriptors works with a read vocabulary.
        let d: Vec<Descriptor> = (0..50u64)
            .map(|i| [i * 7919, i * 104729, !i, i << 13])
            .collect();
        let bv = v.transform(&d);
        let s: f64 = bv.iter().map(|x| x.1).sum();
        assert!(bv.is_empty() || (s - 1.0).abs() < 1e-9);
    }
}

#[test]
fn euroc_images_decode_and_fast_runs() {
    let Some(root) = data_dir("euroc_v1_01_easy_micro") else {
        return;
    };
    let rig = EurocStereo::load(&root);
    let img = rig.left_raw(0);
    assert_eq!((img.width(), img.height()), (752, 480));
    let pyr = Pyramid::new(&img, 4, 8).unwrap();
    let corners = vision::fast::fast9_pyramid(&pyr, 20, true);
    assert!(corners[0].len() > 100, "{} corners", corners[0].len());
    // 16-bit PNG depth (7-Scenes) decodes to millimetres.
    if let Some(ss) = data_dir("seven_scenes_redkitchen_1000") {
        let d = vision::image::load_u16(ss.join("depth/frame-000000.depth.png")).unwrap();
        let valid: Vec<u16> = d
            .data()
            .iter()
            .copied()
            .filter(|&x| x > 0 && x < 65535)
            .collect();
        let mean = valid.iter().map(|&x| x as f64).sum::<f64>() / valid.len() as f64;
        assert!((500.0..5000.0).contains(&mean), "mean depth {mean} mm");
        let rgb = load_gray_u8(ss.join("rgb/frame-000000.color.jpg")).unwrap();
        assert_eq!((rgb.width(), rgb.height()), (640, 480));
    }
}

/// The SIMD kernels and their scalar reference paths (`vision::simd::scalar_only`) give the
/// same results on real frames of EuRoC, KITTI and 7-Scenes: pyramids, FAST, ORB, LK
/// (bit for bit: the arithmetic is the same, only the vector width differs), stereo on the three
/// Middlebury pairs and a KITTI pair, and TV-L1 on a Middlebury pair.
#[test]
fn simd_and_scalar_paths_agree_on_real_frames() {
    use vision::simd::scalar_only;
    let mut frames = Vec::new();
    if let Some(root) = data_dir("euroc_v1_01_easy_micro") {
        let rig = EurocStereo::load(&root);
        frames.push((rig.left_raw(20), rig.left_raw(21)));
    }
    if let Some(k) = data_dir("kitti_odometry_snippets/KITTI_sequence_1/image_l") {
        let f = |i: usize| load_gray_u8(k.join(format!("{i:06}.png"))).unwrap();
        frames.push((f(0), f(1)));
    }
    if let Some(ss) = data_dir("seven_scenes_redkitchen_1000") {
        let f = |i: usize| load_gray_u8(ss.join(format!("rgb/frame-{i:06}.color.jpg"))).unwrap();
        frames.push((f(100), f(101)));
    }
    for (a, b) in &frames {
        let both = |f: &dyn Fn() -> String| (f(), scalar_only(f));
        let (pa, pb) = (
            Pyramid::new(a, 4, 8).unwrap(),
            Pyramid::new(b, 4, 8).unwrap(),
        );
        let (fast, reference) = both(&|| {
            let p = Pyramid::new(a, 4, 8).unwrap();
            let c = vision::fast::fast9_pyramid(&p, 20, true);
            format!(
                "{:?} {:?}",
                p.levels
                    .iter()
                    .map(|l| l.data().to_vec())
                    .collect::<Vec<_>>(),
                c
            )
        });
        assert_eq!(fast, reference, "pyramid + FAST");
        let (fast, reference) = both(&|| {
            format!(
                "{:?}",
                detect_and_describe(a, &OrbParams::default()).unwrap()
            )
        });
        assert_eq!(fast, reference, "ORB");
        let corners = vision::fast::fast9(a, 30, true);
        let pts: Vec<[f32; 2]> = corners.iter().step_by(7).map(|c| [c.u, c.v]).collect();
        let (fast, reference) = both(&|| {
            let t = vision::lk::track(&pa, &pb, &pts, None, &vision::lk::LkParams::default());
            format!("{t:?}")
        });
        assert_eq!(fast, reference, "LK over {} points", pts.len());
        // The guided search's patch kernels (a mildly warped template from `a`, candidates
        // and sub-pixel refinement in `b`), as the live tracker runs them.
        let warp = nalgebra::Matrix2::new(1.03, -0.08, 0.08, 1.03);
        let (fast, reference) = both(&|| {
            use vision::patch::{Patch, nssd, refine_subpixel, template_with_gradient, zmssd};
            let mut s = String::new();
            for c in corners.iter().step_by(5) {
                let t = Patch::extract_warped(a, c.u, c.v, &warp);
                let p = Patch::extract(b, c.u + 0.4, c.v - 0.3);
                if let (Some(t), Some(p)) = (&t, &p) {
                    s += &format!("{:?} {:?} ", nssd(t, p).to_bits(), zmssd(t, p).to_bits());
                }
                let r = template_with_gradient(a, c.u, c.v, &warp)
                    .and_then(|tg| refine_subpixel(&tg, b, [c.u + 0.5, c.v], 10));
                s += &format!("{t:?} {r:?}\n");
            }
            s
        });
        assert_eq!(fast, reference, "patch kernels");
    }
    // Stereo on the three Middlebury pairs (16, 32 and 64 disparities: the two-pixel cost
    // vectors, the interior kernels with and without the costs computed in the column step)
    // and a KITTI pair with the live system's 128 (129 disparities, padded to 144).
    let mut pairs = Vec::new();
    if let Some(dir) = data_dir("middlebury_stereo") {
        for (name, l, r, _, _, ndisp) in MIDDLEBURY {
            let d = dir.join(name);
            let (l, r) = (
                load_gray_u8(d.join(l)).unwrap(),
                load_gray_u8(d.join(r)).unwrap(),
            );
            pairs.push((name.to_string(), l, r, ndisp - 1));
        }
    }
    if let Some(k) = data_dir("kitti_odometry_snippets/KITTI_sequence_1") {
        let f = |side: &str| load_gray_u8(k.join(format!("{side}/000000.png"))).unwrap();
        pairs.push(("KITTI".into(), f("image_l"), f("image_r"), 128));
    }
    for (name, l, r, max_disparity) in &pairs {
        let params = StereoParams {
            max_disparity: *max_disparity,
            ..Default::default()
        };
        let bits = |i: Image<f32>| i.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let f = || bits(block_match(l, r, &params).unwrap());
        assert!(f() == vision::simd::scalar_only(f), "stereo, {name}");
        // The AVX-512 interior kernels (where the CPU has them) against the AVX2 ones.
        assert!(
            f() == vision::simd::without_avx512(f),
            "stereo AVX-512, {name}"
        );
    }
    if let Some(dir) = data_dir("middlebury_stereo") {
        let d = dir.join("tsukuba");
        let (l, r) = (
            load_gray_u8(d.join("im3.png")).unwrap(),
            load_gray_u8(d.join("im4.png")).unwrap(),
        );
        let tv = vision::tvl1::Tvl1Params {
            levels: 3,
            warps: 2,
            iterations: 10,
            ..Default::default()
        };
        let f = || {
            let flow = vision::tvl1::tvl1_flow(&l, &r, &tv).unwrap();
            let bits = |i: &Image<f32>| i.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            (bits(&flow.du), bits(&flow.dv))
        };
        assert!(f() == vision::simd::scalar_only(f), "TV-L1");
    }
    if let Some(ss) = data_dir("seven_scenes_redkitchen_1000") {
        // Dense alignment as the live tracker runs it (4 levels down to level 2, 10 iterations)
        // and down to level 0, frame 100 (with depth) to 101.
        let f = |i: usize| load_gray_u8(ss.join(format!("rgb/frame-{i:06}.color.jpg"))).unwrap();
        let raw = vision::image::load_u16(ss.join("depth/frame-000100.depth.png")).unwrap();
        let depth = raw.map(|d| {
            if d == 0 || d == u16::MAX {
                f32::NAN
            } else {
                d as f32 * 1e-3
            }
        });
        let cam = geom::PinholeCamera::new(585.0, 585.0, 320.0, 240.0);
        let (pa, pb) = (
            Pyramid::new(&f(100), 4, 16).unwrap(),
            Pyramid::new(&f(101), 4, 16).unwrap(),
        );
        for finest in [2, 0] {
            let params = DenseParams {
                levels: 4,
                finest_level: finest,
                max_iterations: 10,
                ..Default::default()
            };
            let run = || {
                let r = vision::dense::DenseReference::new(&pa, &depth, &cam, &params).unwrap();
                let a = r
                    .align(&pb, &Se3::identity(), &mut Default::default())
                    .unwrap();
                let m = a.cur_from_ref.matrix();
                (
                    m.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    a.final_cost.to_bits(),
                    a.iterations,
                    a.num_residuals,
                )
            };
            assert_eq!(
                run(),
                vision::simd::scalar_only(run),
                "dense, finest level {finest}"
            );
        }
    }
}

/// Evaluates our stereo matcher on the three Middlebury pairs (non-occluded mask derived from
/// the left ground truth, see `nonocc_mask`).
#[test]
fn middlebury_stereo_bad_pixel_rates() {
    let Some(dir) = data_dir("middlebury_stereo") else {
        return;
    };
    for MiddleburyPair {
        name,
        left,
        right,
        gt,
        mask,
        params,
    } in middlebury_pairs(&dir)
    {
        let t = Instant::now();
        let disp = block_match(&left, &right, &params).unwrap();
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let (bad, density) = bad_pixel_rate(&disp, &gt, &mask);
        println!(
            "{name}: bad pixels (>1 px, invalid = bad) {:.1} %, density {:.1} %, {ms:.1} ms",
            bad * 100.0,
            density * 100.0
        );
        // Sanity bound only; the comparison with OpenCV's StereoBM is bench/vision.
        assert!(bad < 0.5, "{name}: {bad}");
    }
}

/// The disparity of a point measured with its own patch (`stereo::point_disparity`, what the
/// live system's stereo measurements use) against the block matcher's value at the same pixel,
/// both scored against the Middlebury ground truth at FAST corners (non-occluded, where the
/// matcher has a disparity). Measured (2026-12-03), map / point, over the corners both put
/// within 1 px: venus median |error| 0.084 / 0.065 px, mean error +0.011 / −0.001 px; teddy
/// 0.128 / 0.102 px, +0.011 / +0.002 px; the RMS over those is 0.130 / 0.135 and 0.202 / 0.224
/// px (the 8×8 patch has heavier tails than the 15×15 block support). Asserted: the point
/// disparity's median error and bias are below the map's, on the pairs whose ground truth is
/// sub-pixel (tsukuba's is integer: it is printed only), and most corners (86–94 %) are scored.
/// Beside them, sparse stereo's measurements (`stereo::point_block_disparity` as the start, the
/// live system's default) against the map's start, over every measured corner.
#[test]
fn point_disparities_on_middlebury() {
    let Some(dir) = data_dir("middlebury_stereo") else {
        return;
    };
    for MiddleburyPair {
        name,
        left,
        right,
        gt,
        mask,
        params,
    } in middlebury_pairs(&dir)
    {
        let disp = block_match(&left, &right, &params).unwrap();
        let sparse = vision::stereo::SparseParams {
            max_disparity: params.max_disparity,
            block_radius: params.block_radius,
            ..Default::default()
        };
        let (mut e_map, mut e_point, mut corners) = (Vec::new(), Vec::new(), 0usize);
        // Sparse stereo (the live system's default): the point's block disparity searched along
        // the row, then the same patch refinement; every measured corner's error.
        let (mut e_sparse, mut e_dense_all) = (Vec::new(), Vec::new());
        for c in vision::fast::fast9(&left, 20, true) {
            let (x, y) = (c.u as usize, c.v as usize);
            let (g, d0) = (gt.get(x, y), disp.get(x, y));
            if mask.get(x, y) == 0 || g <= 0.0 {
                continue;
            }
            let (xr, yr) = ((c.u + 0.5) as usize, (c.v + 0.5) as usize);
            if let Some(ds) = vision::stereo::point_block_disparity(&left, &right, xr, yr, &sparse)
                .and_then(|ds| vision::stereo::point_disparity(&left, &right, c.u, c.v, ds, 1.0))
            {
                e_sparse.push((ds - g) as f64);
            }
            if !d0.is_finite() {
                continue;
            }
            corners += 1;
            if let Some(dp) = vision::stereo::point_disparity(&left, &right, c.u, c.v, d0, 1.0) {
                e_dense_all.push((dp - g) as f64);
                // Scored where both are within a pixel: the sub-pixel accuracy, not the
                // matcher's gross errors (which the point's start inherits).
                if (d0 - g).abs() < 1.0 && (dp - g).abs() < 1.0 {
                    e_map.push((d0 - g) as f64);
                    e_point.push((dp - g) as f64);
                }
            }
        }
        let median_abs = |e: &[f64]| {
            let mut a: Vec<f64> = e.iter().map(|x| x.abs()).collect();
            a.sort_by(f64::total_cmp);
            a[a.len() / 2]
        };
        let mean = |e: &[f64]| e.iter().sum::<f64>() / e.len() as f64;
        let rms = |e: &[f64]| (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
        println!(
            "{name}: {} of {corners} corners within 1 px, map / point: median |error| {:.3} / {:.3} px, mean {:+.4} / {:+.4} px, RMS {:.3} / {:.3} px",
            e_map.len(),
            median_abs(&e_map),
            median_abs(&e_point),
            mean(&e_map),
            mean(&e_point),
            rms(&e_map),
            rms(&e_point)
        );
        let within = |e: &[f64]| {
            e.iter()
                .copied()
                .filter(|e| e.abs() < 1.0)
                .collect::<Vec<_>>()
        };
        let gross = |e: &[f64]| 1.0 - within(e).len() as f64 / e.len() as f64;
        let (sparse_in, dense_in) = (within(&e_sparse), within(&e_dense_all));
        println!(
            "{name}: measured points, sparse / dense start: {} / {}, over 1 px {:.1} / {:.1} %, within 1 px: median |error| {:.3} / {:.3} px, mean {:+.4} / {:+.4} px",
            e_sparse.len(),
            e_dense_all.len(),
            100.0 * gross(&e_sparse),
            100.0 * gross(&e_dense_all),
            median_abs(&sparse_in),
            median_abs(&dense_in),
            mean(&sparse_in),
            mean(&dense_in)
        );
        assert!(
            e_map.len() as f64 > 0.8 * corners as f64,
            "{name}: {}",
            e_map.len()
        );
        if name != "tsukuba" {
            assert!(median_abs(&e_point) < median_abs(&e_map), "{name}");
            assert!(mean(&e_point).abs() < mean(&e_map).abs(), "{name}");
            assert!(mean(&sparse_in).abs() < 0.01, "{name}: sparse bias");
        }
        // Sparse stereo as good as the disparity map's start: as few gross errors (measured:
        // 2.2 / 1.2 / 5.4 % against 5.8 / 1.0 / 8.5 %), the same sub-pixel error (within
        // 0.01 px), most of the corners (73–98 % of the map's: it refuses more on depth edges).
        assert!(
            gross(&e_sparse) <= gross(&e_dense_all) + 0.005,
            "{name}: gross errors"
        );
        assert!(
            median_abs(&sparse_in) <= median_abs(&dense_in) + 0.01,
            "{name}: sub-pixel error"
        );
        assert!(
            e_sparse.len() as f64 >= 0.7 * e_dense_all.len() as f64,
            "{name}: {} of {} measured",
            e_sparse.len(),
            e_dense_all.len()
        );
    }
}

/// Dense photometric alignment on EuRoC with depth from our stereo (issue 8: within 1 cm and
/// 0.5° of the ground truth).
///
/// The micro sequence is static (the MAV sits on the ground for all 95 frames: ground-truth
/// motion between consecutive frames is ~0.1 mm), so two non-trivial relative poses are used:
/// 1. reference = rectified left frame `i` (depth from the stereo pair `i`), current = rectified
///    *right* frame `i + 1`: the true `cur_from_ref` is the ground-truth motion `i → i + 1`
///    followed by the rectified stereo extrinsics (a pure 11 cm translation along `x`);
/// 2. reference = left `i`, current = left `i + 1`, started from a perturbed guess
///    (3 cm, 2.3°) away from the ground truth.
fn euroc_dense_pairs(pairs: &[usize]) {
    let Some(root) = data_dir("euroc_v1_01_easy_micro") else {
        return;
    };
    let rig = EurocStereo::load(&root);
    let cam = rig.rect.pinhole;
    let params = StereoParams {
        max_disparity: 64,
        ..Default::default()
    };
    let right_from_left =
        Se3::from_translation(nalgebra::Vector3::new(-rig.rect.baseline, 0.0, 0.0));
    let perturbation = Se3::exp(&nalgebra::Vector6::new(
        0.02, -0.015, 0.015, 0.02, -0.025, 0.015,
    ));
    for &i in pairs {
        let (l0, r0) = rig.rectified(i);
        let (l1, r1) = rig.rectified(i + 1);
        let disp = block_match(&l0, &r0, &params).unwrap();
        let depth = disparity_to_depth(&disp, cam.fx, rig.rect.baseline);
        let motion = rig
            .world_from_rect(i + 1)
            .inverse()
            .compose(&rig.world_from_rect(i));
        for (what, current, truth, init) in [
            (
                "left i -> right i+1",
                &r1,
                right_from_left.compose(&motion),
                Se3::identity(),
            ),
            (
                "left i -> left i+1, perturbed start",
                &l1,
                motion,
                perturbation.compose(&motion),
            ),
        ] {
            let t = Instant::now();
            // Coarse enough that the largest image motion (a full stereo baseline: up to
            // 64 px of disparity) is a few pixels on the coarsest level: 64 / 2⁴ = 4 px.
            let dense = DenseParams {
                levels: 5,
                ..Default::default()
            };
            let res = align(&l0, &depth, current, &cam, &init, &dense).unwrap();
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let err = res.cur_from_ref.compose(&truth.inverse());
            let start = init.compose(&truth.inverse());
            let dt = err.translation().norm();
            let dr = err.rotation().angle().to_degrees();
            println!(
                "pair {i} ({what}): true {:.1} mm {:.2}°, start error {:.1} mm {:.2}°, final error {:.2} mm {:.3}°, {} residuals, {} iterations, {ms:.0} ms",
                truth.translation().norm() * 1e3,
                truth.rotation().angle().to_degrees(),
                start.translation().norm() * 1e3,
                start.rotation().angle().to_degrees(),
                dt * 1e3,
                dr,
                res.num_residuals,
                res.iterations
            );
            assert!(dt < 0.01 && dr < 0.5, "pair {i} ({what}): {dt} m, {dr}°");
        }
    }
}

#[test]
fn euroc_dense_alignment_one_pair() {
    euroc_dense_pairs(&[40]);
}

#[test]
#[ignore = "heavy: pairs spread over the sequence"]
fn euroc_dense_alignment_many_pairs() {
    euroc_dense_pairs(&(0..94).step_by(6).collect::<Vec<_>>());
}

/// ORB descriptors of the independent training images (slambook2's BoW images, the KITTI
/// snippet, the TUM fragment): the vocabulary never sees the query datasets.
fn training_descriptors(params: &OrbParams) -> Vec<Vec<Descriptor>> {
    let mut files = Vec::new();
    for (sub, ext) in [
        ("slambook2_sample_images/bow_training_images", "png"),
        ("kitti_odometry_snippets/KITTI_sequence_1/image_l", "png"),
        ("tum_rgbd_fr1_xyz_fragment/rgb", "png"),
    ] {
        if let Some(d) = data_dir(sub) {
            let mut f: Vec<_> = std::fs::read_dir(d)
                .unwrap()
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|x| x == ext))
                .collect();
            f.sort();
            files.extend(f);
        }
    }
    files
        .iter()
        .map(|f| {
            detect_and_describe(&load_gray_u8(f).unwrap(), params)
                .unwrap()
                .1
        })
        .collect()
}

fn euroc_place_recognition(num_queries: usize) {
    let Some(root) = data_dir("euroc_v1_01_easy_micro") else {
        return;
    };
    let rig = EurocStereo::load(&root);
    let params = OrbParams::default();
    let t = Instant::now();
    let voc = Vocabulary::train(&training_descriptors(&params), 10, 4, 10, 42).unwrap();
    println!(
        "vocabulary: {} words, trained in {:.1} s",
        voc.num_words(),
        t.elapsed().as_secs_f64()
    );
    let n = rig.stamps.len();
    let mut db = Database::new();
    for i in 0..n {
        let (_, d) = detect_and_describe(&rig.right_raw(i), &params).unwrap();
        db.add(voc.transform(&d));
    }
    let step = (n / num_queries.max(1)).max(1);
    let (mut hits, mut total, mut qtime) = (0, 0, 0.0);
    for i in (0..n).step_by(step) {
        let (_, d) = detect_and_describe(&rig.left_raw(i), &params).unwrap();
        let t = Instant::now();
        let r = db.query(&voc.transform(&d), 1);
        qtime += t.elapsed().as_secs_f64();
        total += 1;
        if r.first()
            .is_some_and(|&(j, _)| (j as i64 - i as i64).abs() <= 2)
        {
            hits += 1;
        }
    }
    let rate = hits as f64 / total as f64;
    println!(
        "EuRoC left→right place recognition: {hits}/{total} = {:.1} % top-1 within ±2 frames; {:.2} ms per query (transform + search)",
        rate * 100.0,
        qtime / total as f64 * 1e3
    );
    assert!(rate >= 0.8, "{rate}");
}

/// Issue 8's EuRoC criterion. NB: the micro sequence is static (see `euroc_dense_pairs`), so
/// all 95 frames show the same view and "its own frame ±2" is decided by image noise; this
/// measures that and is expected to fail (chance level is 5/95).
#[test]
#[ignore = "heavy, and the static micro sequence makes frames indistinguishable (see doc)"]
fn euroc_place_recognition_all() {
    euroc_place_recognition(95);
}

fn read_pose(path: &std::path::Path) -> Se3 {
    let v: Vec<f64> = std::fs::read_to_string(path)
        .unwrap()
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    se3_from_matrix(&nalgebra::Matrix4::from_row_slice(&v[..16]))
}

/// 7-Scenes: database frames 0–400, queries 600–700 and 940–999; a query succeeds if its top-1
/// database frame is within 0.3 m and 20° of it (ground truth). Queries with no such frame in
/// the database at all are reported separately (they cannot succeed).
#[test]
#[ignore = "heavy: decodes and describes 562 JPEG frames"]
fn seven_scenes_place_recognition() {
    seven_scenes(1, 1);
}

/// The same with every 4th database frame and every 10th query (a fast version for CI).
#[test]
fn seven_scenes_place_recognition_sample() {
    seven_scenes(4, 10);
}

fn seven_scenes(db_step: usize, query_step: usize) {
    let Some(root) = data_dir("seven_scenes_redkitchen_1000") else {
        return;
    };
    let params = OrbParams::default();
    let t = Instant::now();
    let voc = Vocabulary::train(&training_descriptors(&params), 10, 4, 10, 42).unwrap();
    println!(
        "vocabulary: {} words, trained in {:.1} s",
        voc.num_words(),
        t.elapsed().as_secs_f64()
    );
    let frame = |i: usize| load_gray_u8(root.join(format!("rgb/frame-{i:06}.color.jpg"))).unwrap();
    let pose = |i: usize| read_pose(&root.join(format!("pose/frame-{i:06}.pose.txt")));
    let db_frames: Vec<usize> = (0..=400).step_by(db_step).collect();
    let db_poses: Vec<Se3> = db_frames.iter().map(|&i| pose(i)).collect();
    let mut db = Database::new();
    for &i in &db_frames {
        db.add(voc.transform(&detect_and_describe(&frame(i), &params).unwrap().1));
    }
    let close = |a: &Se3, b: &Se3| {
        let d = a.inverse().compose(b);
        d.translation().norm() <= 0.3 && d.rotation().angle().to_degrees() <= 20.0
    };
    let (mut hits, mut total, mut answerable, mut qtime) = (0, 0, 0, 0.0);
    for i in (600..=700)
        .step_by(query_step)
        .chain((940..=999).step_by(query_step))
    {
        let q = pose(i);
        let (_, d) = detect_and_describe(&frame(i), &params).unwrap();
        let t = Instant::now();
        let r = db.query(&voc.transform(&d), 1);
        qtime += t.elapsed().as_secs_f64();
        total += 1;
        if db_poses.iter().any(|p| close(p, &q)) {
            answerable += 1;
        }
        if r.first().is_some_and(|&(j, _)| close(&db_poses[j], &q)) {
            hits += 1;
        }
    }
    let rate = hits as f64 / total as f64;
    println!(
        "7-Scenes place recognition: {hits}/{total} = {:.1} % top-1 true revisits (≤0.3 m, ≤20°); {answerable} queries have a revisit in the database; {:.2} ms per query",
        rate * 100.0,
        qtime / total as f64 * 1e3
    );
    assert!(rate >= 0.5, "{rate}");
}

#[test]
fn corrupt_and_odd_images_from_disk() {
    let dir = std::env::temp_dir().join(format!("vision-real-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let empty = dir.join("empty.png");
    std::fs::write(&empty, b"").unwrap();
    assert!(load_gray_u8(&empty).is_err());
    let garbage = dir.join("garbage.jpg");
    std::fs::write(&garbage, [0xFFu8, 0xD8, 0xFF, 0x00, 0x12]).unwrap();
    let e = load_gray_u8(&garbage).unwrap_err().to_string();
    assert!(e.contains("garbage.jpg"), "{e}");
    // Odd-sized and 1×1 images run through every operation without panicking.
    for (w, h) in [(1usize, 1usize), (3, 2), (17, 9), (33, 31)] {
        let img = Image::from_fn(w, h, |u, v| ((u * 37 + v * 91) % 251) as u8);
        let _ = vision::fast::fast9(&img, 10, true);
        let p = Pyramid::new(&img, 4, 1).unwrap();
        let _ = vision::lk::track(&p, &p, &[[0.0, 0.0]], None, &Default::default());
        let _ = detect_and_describe(&img, &OrbParams::default()).unwrap();
        let _ = block_match(&img, &img, &StereoParams::default());
        let _ = vision::tvl1::tvl1_flow(&img, &img, &Default::default());
        let d = Image::<f32>::filled(w, h, 1.0);
        let cam = geom::PinholeCamera::new(100.0, 100.0, w as f64 / 2.0, h as f64 / 2.0);
        let _ = align(
            &img,
            &d,
            &img,
            &cam,
            &Se3::identity(),
            &DenseParams::default(),
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}
