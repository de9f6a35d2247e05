//! The Gauss-Newton filter against batch least squares: its joint update converges to the BA
//! optimum (stereo priors are exactly quadratic), its information after marginalisation
//! equals the batch marginal (noise-free, so both linearise at the truth), pose estimation
//! from the map prior (Alg. 6) recovers the pose, and the monocular bootstrap yields a full-rank
//! map with unit baseline.

#![allow(clippy::needless_range_loop)]

use geom::{PinholeCamera, StereoCamera};
use lie::{LieGroup, Se3};
use lsq::{Information, Problem, SolverOptions, Var};
use nalgebra::{DMatrix, SVector, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim::why_filter::bootstrap::{BootstrapOptions, bootstrap};
use sim::why_filter::features::ImageArea;
use sim::why_filter::filter::{Anchor, GaussNewtonFilter, LmSettings};
use slam::factors::{AnchoredObservation, InverseDepthObservation, Projector};

const SIGMA: f64 = 0.5;

fn camera() -> PinholeCamera {
    PinholeCamera::new(500.0, 500.0, 320.0, 240.0)
}

fn stereo() -> StereoCamera {
    StereoCamera::new(camera(), 0.1)
}

/// Sideways poses `T_0 = I`, `T_k` at `x = 0.1·k`, slightly rotated.
fn poses(n: usize) -> Vec<Se3> {
    (0..n)
        .map(|k| {
            let k = k as f64;
            Se3::exp(&Vector6::new(
                -0.1 * k,
                0.01 * k,
                0.0,
                0.0,
                0.02 * k,
                0.005 * k,
            ))
        })
        .collect()
}

fn points(rng: &mut ChaCha8Rng, n: usize) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|_| {
            Vector3::new(
                rng.random_range(-0.8..1.0),
                rng.random_range(-0.6..0.6),
                rng.random_range(2.0..3.0),
            )
        })
        .collect()
}

fn measure<P: Projector<N>, const N: usize>(
    p: &P,
    t: &Se3,
    y: &Vector3<f64>,
    noise: Option<&mut ChaCha8Rng>,
) -> SVector<f64, N> {
    let (z, _) = p.project(&t.act(y)).expect("in front");
    match noise {
        Some(rng) => {
            let n = rand_distr::Normal::new(0.0, SIGMA).unwrap();
            z + SVector::<f64, N>::from_fn(|_, _| rand_distr::Distribution::sample(&n, rng))
        }
        None => z,
    }
}

fn perturb(t: &Se3, rng: &mut ChaCha8Rng, s: f64) -> Se3 {
    Se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-s..s))).compose(t)
}

#[test]
fn converged_joint_update_equals_batch_ba() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let cam = stereo();
    let truth = poses(2);
    let ys = points(&mut rng, 25);
    let z0: Vec<_> = ys
        .iter()
        .map(|y| measure(&cam, &truth[0], y, Some(&mut rng)))
        .collect();
    let z1: Vec<_> = ys
        .iter()
        .map(|y| measure(&cam, &truth[1], y, Some(&mut rng)))
        .collect();
    let initial = perturb(&truth[1], &mut rng, 0.02);

    let mut filter = GaussNewtonFilter::new(cam, SIGMA, Se3::identity());
    for (j, z) in z0.iter().enumerate() {
        filter.add_point(j, z, Anchor::Origin, 1.0).unwrap();
    }
    filter.begin_frame(1, initial).unwrap();
    let obs: Vec<_> = z1.iter().copied().enumerate().collect();
    let settings = LmSettings {
        function_tolerance: 0.0,
        ..LmSettings::with_iterations(30)
    };
    filter.optimise(&obs, &settings).unwrap();

    let mut problem = Problem::new();
    let origin = problem.add_variable(Se3::identity());
    problem.set_fixed(origin.key(), true);
    let t1 = problem.add_variable(initial);
    let psis: Vec<Var<Vector3<f64>>> = (0..ys.len())
        .map(|j| {
            let (psi, _) = filter.inverse_depth_point(j).unwrap();
            // Start the batch where the filter started: the stereo initialisation.
            let x = cam.unproject(&z0[j]).unwrap();
            let _ = psi;
            problem.add_variable(Vector3::new(x.x / x.z, x.y / x.z, 1.0 / x.z))
        })
        .collect();
    for j in 0..ys.len() {
        problem
            .add_factor(
                InverseDepthObservation {
                    observer_from_anchor: None,
                    inverse_depth_point: psis[j],
                    measurement: z0[j],
                    projector: cam,
                },
                Information::Isotropic(SIGMA),
                None,
            )
            .unwrap();
        problem
            .add_factor(
                AnchoredObservation {
                    observer_from_world: t1,
                    anchor_from_world: origin,
                    inverse_depth_point: psis[j],
                    measurement: z1[j],
                    projector: cam,
                },
                Information::Isotropic(SIGMA),
                None,
            )
            .unwrap();
    }
    problem
        .optimise(&SolverOptions {
            max_iterations: 50,
            function_tolerance: 1e-15,
            ..Default::default()
        })
        .unwrap();
    let (_, t_filter) = filter.current().unwrap();
    let d = t_filter.compose(&problem.value(t1).inverse()).log().norm();
    assert!(d < 1e-7, "pose differs by {d}");
    for j in 0..ys.len() {
        let (psi, _) = filter.inverse_depth_point(j).unwrap();
        assert!((psi - problem.value(psis[j])).norm() < 1e-7);
    }
}

/// The batch information of noise-free stereo observations over anchored points, marginalised
/// to `keep` (variables in order), compared with the filter's information.
#[test]
fn information_after_marginalisation_equals_the_batch_marginal() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let cam = stereo();
    let truth = poses(3);
    let ys = points(&mut rng, 12);
    // Points 0..8 anchored at the origin (seen in frames 0, 1, 2); points 8..12 anchored at
    // frame 1 (seen in frames 1, 2). Frame 1 becomes an anchor.
    let mut filter = GaussNewtonFilter::new(cam, SIGMA, Se3::identity());
    for (j, y) in ys.iter().enumerate().take(8) {
        filter
            .add_point(j, &measure(&cam, &truth[0], y, None), Anchor::Origin, 1.0)
            .unwrap();
    }
    let obs = |frame: usize, ids: std::ops::Range<usize>| -> Vec<(usize, SVector<f64, 3>)> {
        ids.map(|j| (j, measure(&cam, &truth[frame], &ys[j], None)))
            .collect()
    };
    let settings = LmSettings::with_iterations(5);
    filter.begin_frame(1, truth[1]).unwrap();
    filter.update(&obs(1, 0..8), &settings).unwrap();
    filter.current_to_anchor().unwrap();
    for (j, y) in ys.iter().enumerate().skip(8) {
        filter
            .add_point(j, &measure(&cam, &truth[1], y, None), Anchor::Frame(1), 1.0)
            .unwrap();
    }
    filter.begin_frame(2, truth[2]).unwrap();
    filter.update(&obs(2, 0..12), &settings).unwrap();
    // A second pose marginalised: frame 2 out, frame 3 in (same pose as 2, no new info).
    assert_eq!(filter.anchor_frames(), vec![1]);

    // Batch: T1 (anchor), ψ_0..ψ_12, T2 free; origin fixed.
    let mut problem = Problem::new();
    let origin = problem.add_variable(Se3::identity());
    problem.set_fixed(origin.key(), true);
    let t1 = problem.add_variable(truth[1]);
    let psi_vars: Vec<Var<Vector3<f64>>> = (0..ys.len())
        .map(|j| problem.add_variable(filter.inverse_depth_point(j).unwrap().0))
        .collect();
    let t2 = problem.add_variable(truth[2]);
    let info = Information::Isotropic(SIGMA);
    for j in 0..ys.len() {
        let (anchor_var, anchor_frame) = if j < 8 { (origin, 0) } else { (t1, 1) };
        problem
            .add_factor(
                InverseDepthObservation {
                    observer_from_anchor: None,
                    inverse_depth_point: psi_vars[j],
                    measurement: measure(&cam, &truth[anchor_frame], &ys[j], None),
                    projector: cam,
                },
                info.clone(),
                None,
            )
            .unwrap();
        let observers: &[(usize, Var<Se3>)] = if j < 8 {
            &[(1, t1), (2, t2)]
        } else {
            &[(2, t2)]
        };
        for &(frame, var) in observers {
            problem
                .add_factor(
                    AnchoredObservation {
                        observer_from_world: var,
                        anchor_from_world: anchor_var,
                        inverse_depth_point: psi_vars[j],
                        measurement: measure(&cam, &truth[frame], &ys[j], None),
                        projector: cam,
                    },
                    info.clone(),
                    None,
                )
                .unwrap();
        }
    }
    let mut keys = vec![t1.key()];
    keys.extend(psi_vars.iter().map(|v| v.key()));
    keys.push(t2.key());
    let cov = problem.covariance(&keys).unwrap();
    let filter_cov = lsq::dense::spd_inverse(filter.information()).unwrap();
    let scale = cov.amax();
    let diff = (&filter_cov - &cov).amax();
    assert!(
        diff < 1e-6 * scale,
        "covariances differ by {diff} (scale {scale})"
    );
}

#[test]
fn pose_from_the_map_prior_recovers_the_pose() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let cam = stereo();
    let truth = poses(3);
    let ys = points(&mut rng, 30);
    let mut filter = GaussNewtonFilter::new(cam, SIGMA, Se3::identity());
    for (j, y) in ys.iter().enumerate() {
        filter
            .add_point(j, &measure(&cam, &truth[0], y, None), Anchor::Origin, 1.0)
            .unwrap();
    }
    let obs = |frame: usize| -> Vec<(usize, SVector<f64, 3>)> {
        (0..ys.len())
            .map(|j| (j, measure(&cam, &truth[frame], &ys[j], None)))
            .collect()
    };
    filter.begin_frame(1, truth[1]).unwrap();
    filter
        .update(&obs(1), &LmSettings::with_iterations(3))
        .unwrap();
    filter.marginalise_current().unwrap();
    let start = perturb(&truth[2], &mut rng, 0.03);
    for exact in [false, true] {
        let t = filter
            .motion_from_map_prior(&obs(2), &start, 10, exact)
            .unwrap();
        let d = t.compose(&truth[2].inverse()).log().norm();
        assert!(d < 1e-6, "exact = {exact}: off by {d}");
    }
    let t = filter.motion_only_ba(&obs(2), &start, 10).unwrap();
    assert!(t.compose(&truth[2].inverse()).log().norm() < 1e-6);
    // A map without a pose to marginalise first is refused.
    filter.begin_frame(2, start).unwrap();
    assert!(
        filter
            .motion_from_map_prior(&obs(2), &start, 10, false)
            .is_err()
    );
}

#[test]
fn monocular_bootstrap_gives_a_full_rank_map_with_unit_baseline() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let cam = camera();
    let ys = points(&mut rng, 400);
    // T_b0 = I, T_b1 and T_0 further right; noise-free, so the geometry is exact.
    let truth = [
        Se3::identity(),
        Se3::from_translation(Vector3::new(-0.05, 0.0, 0.0)),
        Se3::from_translation(Vector3::new(-0.1, 0.0, 0.0)),
    ];
    let frames: Vec<Vec<(usize, Vector2<f64>)>> = truth
        .iter()
        .map(|t| {
            ys.iter()
                .enumerate()
                .filter_map(|(j, y)| {
                    let z = measure(&cam, t, y, None::<&mut ChaCha8Rng>);
                    (z.x >= 0.0 && z.x < 640.0 && z.y >= 0.0 && z.y < 480.0).then_some((j, z))
                })
                .collect()
        })
        .collect();
    let options = BootstrapOptions {
        num_points: 60,
        iterations: 20,
        pose_iterations: 10,
        min_parallax: 0.5f64.to_radians(),
        area: ImageArea {
            width: 640.0,
            height: 480.0,
        },
        seed: 9,
    };
    let boot = bootstrap(cam, SIGMA, [&frames[0], &frames[1], &frames[2]], &options).unwrap();
    assert_eq!(boot.features.len(), 60);
    assert!((boot.b1_from_world.translation().norm() - 1.0).abs() < 1e-12);
    // T_0 is twice as far as T_b1, in the same direction (unit-baseline scale: 2).
    let (_, t0) = boot.filter.current().unwrap();
    let c0 = t0.inverse().translation().to_owned();
    assert!(
        (c0 - Vector3::new(2.0, 0.0, 0.0)).norm() < 1e-4,
        "T_0 centre {c0}"
    );
    // The information is full rank (the 5-DoF marginalisation left a scale prior).
    let info = boot.filter.information();
    let eig = nalgebra::SymmetricEigen::new(info.clone()).eigenvalues;
    assert!(
        eig.min() > 1e-9 * eig.max(),
        "eigenvalues {} … {}",
        eig.min(),
        eig.max()
    );
    // Same inputs, same bits.
    let again = bootstrap(cam, SIGMA, [&frames[0], &frames[1], &frames[2]], &options).unwrap();
    assert_eq!(again.filter.information(), info);
    let _: &DMatrix<f64> = info;
    // Too little parallax is refused.
    let same: [&[(usize, Vector2<f64>)]; 3] = [&frames[0], &frames[0], &frames[2]];
    assert!(bootstrap(cam, SIGMA, same, &options).is_err());
}
