//! Bundle adjustment on synthetic scenes with known ground truth (issue 4).

use geom::BalCamera;
use lie::LieGroup;
use lsq::{LinearSolver, SolverOptions};
use nalgebra::Vector2;
use sim::ba_scene::{CircleSceneParams, circle_scene, perturb, to_bal};
use slam::ba::{BaMode, BalAdjustment, BundleAdjustment, Gauge};
use slam::factors::BalCameraState;

/// RMS of the whitened residual per coordinate, `√(χ²/m)`, in units of σ.
fn rms_in_sigma(chi2: f64, coordinates: usize) -> f64 {
    (chi2 / coordinates as f64).sqrt()
}

#[test]
fn full_ba_converges_to_the_noise_floor_with_either_gauge() {
    let scene = circle_scene(&CircleSceneParams {
        points: 500,
        noise_sigma: 1.0,
        ..Default::default()
    });
    let (poses, points) = perturb(&scene, 0.05, 0.01, 0.05, 2);
    for gauge in [Gauge::FixPoses(vec![0, 1]), Gauge::Damping] {
        let mut ba = BundleAdjustment::new(
            &scene.camera,
            &poses,
            &points,
            &scene.observations,
            1.0,
            None,
            BaMode::Full,
            &gauge,
        )
        .unwrap();
        let s = ba
            .problem
            .optimise(&SolverOptions {
                max_iterations: 50,
                ..Default::default()
            })
            .unwrap();
        let m = 2 * scene.observations.len();
        let rms = rms_in_sigma(s.final_chi2, m);
        // Expected √((m − n)/m)·σ with n the free parameters: slightly below σ.
        let n = 6 * scene.camera_from_world.len() + 3 * scene.points_world.len();
        let expected = ((m - n) as f64 / m as f64).sqrt();
        assert!(
            (rms - expected).abs() < 0.05,
            "{gauge:?}: RMS {rms:.4}σ, expected ≈ {expected:.4}σ ({:?})",
            s.termination
        );
        assert!(s.termination.converged(), "{:?}", s.termination);
        assert_eq!(s.linear_solver, LinearSolver::SchurCholesky);
    }
}

#[test]
fn motion_only_and_structure_only_recover_what_is_free() {
    // Noise-free measurements: the answer is the ground truth, exactly.
    let scene = circle_scene(&CircleSceneParams {
        points: 300,
        noise_sigma: 0.0,
        ..Default::default()
    });
    let (poses, points) = perturb(&scene, 0.1, 0.02, 0.1, 3);
    // Motion only: points at the truth, poses perturbed.
    let mut ba = BundleAdjustment::new(
        &scene.camera,
        &poses,
        &scene.points_world,
        &scene.observations,
        0.5,
        None,
        BaMode::MotionOnly,
        &Gauge::Damping,
    )
    .unwrap();
    let exact = SolverOptions {
        function_tolerance: 1e-14,
        ..Default::default()
    };
    ba.problem.optimise(&exact).unwrap();
    for (est, truth) in ba.camera_from_world().iter().zip(&scene.camera_from_world) {
        let err = est.compose(&truth.inverse()).log();
        assert!(err.amax() < 1e-8, "pose error {err:?}");
    }
    assert_eq!(
        ba.points_world(),
        scene.points_world,
        "points must stay fixed"
    );
    // Structure only: poses at the truth, points perturbed.
    let mut ba = BundleAdjustment::new(
        &scene.camera,
        &scene.camera_from_world,
        &points,
        &scene.observations,
        0.5,
        None,
        BaMode::StructureOnly,
        &Gauge::Damping,
    )
    .unwrap();
    ba.problem.optimise(&exact).unwrap();
    let max_point_error = ba
        .points_world()
        .iter()
        .zip(&scene.points_world)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(max_point_error < 1e-8, "point error {max_point_error}");
    assert_eq!(
        ba.camera_from_world(),
        scene.camera_from_world,
        "poses must stay fixed"
    );
}

#[test]
fn schur_and_full_solvers_reach_the_same_optimum() {
    let scene = circle_scene(&CircleSceneParams {
        points: 200,
        cameras: 20,
        ..Default::default()
    });
    let (poses, points) = perturb(&scene, 0.03, 0.005, 0.03, 4);
    let mut costs = Vec::new();
    for solver in [
        LinearSolver::SparseCholesky,
        LinearSolver::SchurCholesky,
        LinearSolver::SchurPcg,
    ] {
        let mut ba = BundleAdjustment::new(
            &scene.camera,
            &poses,
            &points,
            &scene.observations,
            1.0,
            None,
            BaMode::Full,
            &Gauge::FixPoses(vec![0, 1]),
        )
        .unwrap();
        if solver == LinearSolver::SparseCholesky {
            ba.problem.set_eliminated::<nalgebra::Vector3<f64>>(false);
        }
        let s = ba
            .problem
            .optimise(&SolverOptions {
                linear_solver: solver,
                function_tolerance: 1e-12,
                pcg_tolerance: 1e-10,
                ..Default::default()
            })
            .unwrap();
        costs.push((solver, s.final_cost, ba.points_world()[17]));
    }
    for (solver, cost, p) in &costs[1..] {
        assert!(
            (cost - costs[0].1).abs() < 1e-6 * costs[0].1,
            "{solver:?}: {cost} vs {}",
            costs[0].1
        );
        assert!((p - costs[0].2).norm() < 1e-5, "{solver:?}: point differs");
    }
}

#[test]
fn bal_form_of_a_scene_converges_like_the_pinhole_form() {
    let scene = circle_scene(&CircleSceneParams {
        points: 300,
        noise_sigma: 1.0,
        ..Default::default()
    });
    let (poses, points) = perturb(&scene, 0.02, 0.005, 0.02, 5);
    let bal = to_bal(&scene, &poses, &points);
    let cameras: Vec<BalCameraState> = bal
        .cameras
        .iter()
        .map(|c| BalCameraState {
            camera_from_world: c.camera_from_world,
            intrinsics: BalCamera::new(c.intrinsics.f, 0.0, 0.0),
        })
        .collect();
    let observations: Vec<(usize, usize, Vector2<f64>)> = bal
        .observations
        .iter()
        .map(|o| (o.camera, o.point, o.measurement))
        .collect();
    let mut ba = BalAdjustment::new(&cameras, &bal.points_world, &observations, None).unwrap();
    assert!(ba.rejected.is_empty());
    let s = ba
        .problem
        .optimise(&SolverOptions {
            max_iterations: 50,
            ..Default::default()
        })
        .unwrap();
    // BAL cameras also estimate (f, k₁, k₂): 9 parameters per camera absorb some noise.
    let m = 2 * observations.len();
    let n = 9 * cameras.len() + 3 * bal.points_world.len();
    let expected = ((m - n) as f64 / m as f64).sqrt();
    let rms = rms_in_sigma(s.final_chi2, m);
    assert!(
        (rms - expected).abs() < 0.05,
        "RMS {rms}σ, expected ≈ {expected}σ ({:?})",
        s.termination
    );
}

#[test]
fn bad_observations_are_rejected_and_never_produce_nans() {
    let scene = circle_scene(&CircleSceneParams {
        points: 100,
        ..Default::default()
    });
    let bal = to_bal(&scene, &scene.camera_from_world, &scene.points_world);
    let cameras: Vec<BalCameraState> = bal
        .cameras
        .iter()
        .map(|c| BalCameraState {
            camera_from_world: c.camera_from_world,
            intrinsics: c.intrinsics,
        })
        .collect();
    let mut points = bal.points_world.clone();
    let mut observations: Vec<(usize, usize, Vector2<f64>)> = bal
        .observations
        .iter()
        .map(|o| (o.camera, o.point, o.measurement))
        .collect();
    // A NaN measurement, a point at (numerical) infinity, a point behind its camera.
    observations[0].2 = Vector2::new(f64::NAN, 1.0);
    points[observations[5].1] = nalgebra::Vector3::new(1e300, 1e300, 1e300);
    let behind = observations[9];
    let cam = &cameras[behind.0].camera_from_world;
    // Put the point 2 m behind the camera (BAL cameras look down −z: behind is +z).
    points[behind.1] = cam.inverse().act(&nalgebra::Vector3::new(0.0, 0.0, 2.0));
    let mut ba = BalAdjustment::new(&cameras, &points, &observations, None).unwrap();
    assert!(
        ba.rejected.contains(&0) && ba.rejected.contains(&9),
        "rejected: {:?}",
        ba.rejected
    );
    let s = ba
        .problem
        .optimise(&SolverOptions {
            max_iterations: 20,
            ..Default::default()
        })
        .unwrap();
    assert!(s.final_cost.is_finite());
    for v in &ba.cameras {
        let c = ba.problem.value(*v);
        assert!(LieGroup::is_finite(&c.camera_from_world) && c.intrinsics.f.is_finite());
    }
    // Out-of-range indices are an error, not a panic.
    let bad = vec![(99, 0, Vector2::zeros())];
    assert!(BalAdjustment::new(&cameras, &points, &bad, None).is_err());
}
