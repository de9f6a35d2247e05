//! The study's tests: the scenes' overlaps, the estimators and the figures' shapes.

use super::*;

#[test]
fn scenes_have_the_stated_overlaps() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let stereo = StereoSensor::vga(FOCAL, BASELINE, SIGMA);
    let mono = MonoSensor::vga(FOCAL, SIGMA);
    // (i): every point seen in every frame, bootstrap frames included.
    let scene = Setting::I.scene(&mut rng);
    let mut poses = Setting::I.trajectory(16);
    poses.extend(Setting::I.bootstrap_poses());
    for t in &poses {
        for y in &scene {
            assert!(stereo.predict(t, y).is_some() && mono.predict(t, y).is_some());
        }
    }
    // (ii), (iii): first and last frames share few points; (iv) none at all.
    for (setting, max_shared) in [(Setting::II, 0.3), (Setting::III, 0.3), (Setting::IV, 0.0)] {
        let scene = setting.scene(&mut rng);
        let traj = setting.trajectory(2);
        let first: Vec<bool> = scene
            .iter()
            .map(|y| mono.predict(&traj[0], y).is_some())
            .collect();
        let last: Vec<bool> = scene
            .iter()
            .map(|y| mono.predict(&traj[2], y).is_some())
            .collect();
        let n_first = first.iter().filter(|v| **v).count();
        let shared = first.iter().zip(&last).filter(|(a, b)| **a && **b).count();
        assert!(n_first > 500, "{setting:?}: {n_first} visible");
        let fraction = shared as f64 / n_first as f64;
        assert!(fraction <= max_shared, "{setting:?}: {fraction}");
        if setting != Setting::IV {
            assert!(fraction > 0.0, "{setting:?}: no overlap");
        }
    }
}

#[test]
fn mono_error_is_zero_for_a_scaled_estimate_and_tangent_otherwise() {
    let t = Vector3::new(0.5, 0.0, 0.0);
    let e = mono_error(&t, &(t * 3.0)).unwrap();
    assert!(e.iter().all(|x| x.abs() < 1e-15));
    let e = mono_error(&t, &Vector3::new(0.5, 0.01, 0.0)).unwrap();
    assert!((e[0].hypot(e[1]) - 0.01).abs() < 1e-4);
}

#[test]
fn pipeline_stats_rmse_median_and_failures() {
    let r = |e: Option<Vec<f64>>| PipelineResult {
        error: e,
        cost_total: 1.0,
        cost_joint: 0.5,
    };
    let results = [
        r(Some(vec![3.0, 4.0])),
        r(Some(vec![0.0, 1.0])),
        r(Some(vec![0.0, 100.0])),
        r(None),
    ];
    let s = pipeline_stats(&results.iter().collect::<Vec<_>>());
    assert_eq!((s.successes, s.failures), (3, 1));
    assert!((s.rmse - ((25.0 + 1.0 + 10000.0) / 3.0f64).sqrt()).abs() < 1e-12);
    assert_eq!(s.median_error, 5.0);
    assert_eq!(s.cost_total, 1.0);
}

#[test]
fn the_map_prior_predicts_the_monocular_pose_better_than_motion_only_ba() {
    // ⟨1, 240⟩ monocular, setting (i): the end pose is 0.5 m from the bootstrap, whose
    // depths are uncertain. Every prediction lands near the truth, the three differ, the
    // run repeats exactly, and Alg. 6 (approximate), which weighs each point by its
    // uncertainty, beats motion-only BA against the mean map (thesis Fig. 4.10 a).
    let specs: Vec<TrialSpec> = (0..6)
        .map(|trial| TrialSpec {
            setting: Setting::I,
            sensor: SensorKind::Mono,
            m: 1,
            n: 240,
            trial,
            seed: 7,
        })
        .collect();
    let mut sq = [0.0; 3];
    for spec in &specs {
        let a = run_motion_trial(spec);
        let b = run_motion_trial(spec);
        for (k, (p, q)) in a.iter().zip(&b).enumerate() {
            assert_eq!(p.error, q.error, "deterministic");
            assert!(p.cost_total > 0.0);
            let e = p.error.as_ref().expect("no failure");
            assert!(e.iter().all(|x| x.abs() < 0.03), "{e:?}");
            sq[k] += e.iter().map(|x| x * x).sum::<f64>();
        }
        assert_ne!(a[0].error, a[1].error);
        assert_ne!(a[1].error, a[2].error);
    }
    assert!(
        sq[1] < 0.8 * sq[0],
        "Alg. 6 {} vs motion-only BA {}",
        sq[1],
        sq[0]
    );
}

#[test]
fn log_log_slope_recovers_exponents() {
    let p: Vec<(f64, f64)> = [15.0, 30.0, 60.0, 120.0]
        .iter()
        .map(|&n: &f64| (n, 2e-6 * n.powi(3)))
        .collect();
    assert!((log_log_slope(&p) - 3.0).abs() < 1e-12);
}
