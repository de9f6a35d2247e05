//! Diagnostics of the study (`--ignored --nocapture`): the filter's error against the pixel noise.

use super::*;

/// The filter's mean error in setting (i) stereo, `⟨8, 60⟩`, 12 trials, against the pixel
/// noise: zero without noise (no modelling error), and growing faster than linearly with
/// `σ` (a linearisation effect). Prints the means; `--ignored --nocapture` to see them.
#[test]
#[ignore]
fn filter_bias_against_noise() {
    for sigma in [1e-6, 0.25, 0.5, 1.0] {
        let (m, n) = (8usize, 60usize);
        let mut sum = Vector3::zeros();
        let k = 12;
        for trial in 0..k {
            let spec = TrialSpec {
                setting: Setting::I,
                sensor: SensorKind::Stereo,
                m,
                n,
                trial,
                seed: 2012,
            };
            let setting = spec.setting;
            let mut rng = ChaCha8Rng::seed_from_u64(spec.trial_seed());
            let scene = setting.scene(&mut rng);
            let truth = setting.trajectory(spec.m);
            let sensor = StereoSensor::vga(FOCAL, BASELINE, sigma);
            let frames = measure(&sensor, &truth, &scene, &mut rng);
            let all: Vec<usize> = frames[0].iter().map(|(id, _)| *id).collect();
            let selected = select_spread(&frames[0], &all, &[], n, AREA, 1);
            let t0 = truth[0];
            let t_true = relative_end(&truth[0], &truth[m]);
            let mut filter = GaussNewtonFilter::new(sensor.camera, sigma, t0);
            for id in &selected {
                let z = find(&frames[0], *id).unwrap();
                filter.add_point(*id, &z, Anchor::Origin, 1.0).unwrap();
            }
            let mut slam = FilterSlam::new(
                filter,
                FilterSlamOptions {
                    iterations: 3,
                    motion: MotionEstimate::MotionOnlyBa,
                    area: AREA,
                    seed: 1,
                },
                0,
            );
            for i in 1..frames.len() {
                slam.step(&frames[i - 1], &frames[i]).unwrap();
            }
            sum += t_true - relative_end(&t0, &slam.current());
        }
        let mean = sum / k as f64;
        println!(
            "sigma {sigma}: filter mean error {:?} mm",
            (mean * 1e3).as_slice()
        );
        if sigma < 1e-3 {
            assert!(mean.norm() < 1e-6, "noise-free runs are exact: {mean:?}");
        }
    }
}

/// How setting (i) stereo is estimated in [`run_i`].
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Estimator {
    /// The filter as in filter-SLAM: the previous pose is marginalised (eq. 4.25).
    Filter,
    /// The filter keeping every previous pose in the state (as an anchor) instead of
    /// marginalising it: the same linearised information, no Schur complement.
    FilterKeepingPoses,
    /// BA-SLAM (full BA over all keyframes).
    Ba,
}

/// Setting (i) stereo with `m` keyframes and the first `n` candidates visible in all frames
/// (so that BA-SLAM replaces none; a selection
/// independent of the noise, so that runs at different `σ` see the same points and, the
/// generator being reseeded, the noise `σ·ε` with the same `ε`), the slab `thickness` m
/// deep, every optimisation run to convergence. Returns `Δt = t_true − t_est` (m).
fn run_i(
    estimator: Estimator,
    (m, n): (usize, usize),
    sigma: f64,
    trial: usize,
    thickness: f64,
) -> Vector3<f64> {
    let iterations = 30;
    let spec = TrialSpec {
        setting: Setting::I,
        sensor: SensorKind::Stereo,
        m,
        n,
        trial,
        seed: 2012,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(spec.trial_seed());
    let scene =
        crate::world::planar_slab(&mut rng, (0.03, 0.47), (-0.42, 0.42), 1.0, thickness, 1500);
    let truth = Setting::I.trajectory(m);
    let sensor = StereoSensor::vga(FOCAL, BASELINE, sigma);
    let frames = measure(&sensor, &truth, &scene, &mut rng);
    let selected: Vec<usize> = frames[0]
        .iter()
        .map(|(id, _)| *id)
        .filter(|id| frames.iter().all(|f| find(f, *id).is_some()))
        .take(n)
        .collect();
    assert_eq!(selected.len(), n, "enough points seen in all frames");
    let t0 = truth[0];
    let t_true = relative_end(&truth[0], &truth[m]);
    let camera = sensor.camera;
    if estimator == Estimator::Ba {
        let points: Vec<(usize, Vector3<f64>)> = selected
            .iter()
            .map(|id| {
                let z = find(&frames[0], *id).expect("visible");
                let psi = camera.inverse_depth_from(&z, 1.0).expect("valid");
                (*id, slam::factors::inverse_depth_to_point(&psi))
            })
            .collect();
        let options = BaSlamOptions {
            iterations,
            area: AREA,
            seed: 1,
        };
        let mut ba = BaSlam::with_map(camera, sigma, options, t0, &points, &frames[0]);
        for i in 1..frames.len() {
            ba.step(&frames[i - 1], &frames[i], None)
                .expect("BA-SLAM step");
        }
        return t_true - relative_end(&t0, &ba.current());
    }
    let mut filter = GaussNewtonFilter::new(camera, sigma, t0);
    for id in &selected {
        let z = find(&frames[0], *id).expect("visible");
        filter
            .add_point(*id, &z, Anchor::Origin, 1.0)
            .expect("valid");
    }
    let mut pose = t0;
    for (i, frame) in frames.iter().enumerate().skip(1) {
        if filter.current().is_some() {
            if estimator == Estimator::FilterKeepingPoses {
                filter.current_to_anchor().expect("a current pose");
            } else {
                filter.marginalise_current().expect("positive definite");
            }
        }
        let obs: Vec<_> = selected
            .iter()
            .filter_map(|id| find(frame, *id).map(|z| (*id, z)))
            .collect();
        let predicted = filter
            .motion_only_ba(&obs, &pose, iterations)
            .expect("motion-only BA");
        filter.begin_frame(i, predicted).expect("no current pose");
        filter
            .update(&obs, &filter::LmSettings::with_iterations(iterations))
            .expect("a current pose");
        pose = filter.current().expect("just added").1;
    }
    t_true - relative_end(&t0, &pose)
}

/// Suspect (1) of the bias: the Schur complement of eq. 4.25 changes nothing — keeping the
/// previous poses in the state with the same information gives the same estimate.
#[test]
fn marginalising_a_pose_equals_keeping_it() {
    for trial in 0..3 {
        let a = run_i(Estimator::Filter, (3, 30), 0.5, trial, 0.2);
        let b = run_i(Estimator::FilterKeepingPoses, (3, 30), 0.5, trial, 0.2);
        assert!((a - b).norm() < 1e-5, "trial {trial}: {a:?} vs {b:?}");
    }
}

/// The filter equals BA to first order in the pixel noise: per trial (same points, noise
/// `σ·ε` with the same `ε`), `Δt_filter − Δt_BA` grows as `σ²` — what linearising the
/// measurements of marginalised poses at their estimate must give; an error in the stored
/// prior, its centre or its chart, or in the Jacobians would show as a term linear in `σ`.
#[test]
fn filter_equals_ba_to_first_order_in_the_noise() {
    for trial in 0..3 {
        let d = |sigma: f64| {
            run_i(Estimator::Filter, (4, 30), sigma, trial, 0.2)
                - run_i(Estimator::Ba, (4, 30), sigma, trial, 0.2)
        };
        let (d1, d2) = (d(0.1), d(0.2));
        let ratio = d2.norm() / d1.norm();
        assert!(
            d2.norm() > 1e-5 && (ratio - 4.0).abs() < 0.4,
            "trial {trial}: |d(0.1)| = {:.3e}, |d(0.2)| = {:.3e}, ratio {ratio}",
            d1.norm(),
            d2.norm()
        );
        assert!(
            (d2 - d1 * 4.0).norm() < 0.1 * d2.norm(),
            "trial {trial}: {d1:?} {d2:?}"
        );
    }
}

/// The filter's bias against BA in setting (i) stereo, `M = 4`, 24 trials: mean and spread
/// of the paired difference `Δt_filter − Δt_BA` against `σ`, for two `N` and the slab
/// 0.2 m (as the experiment) and 0.8 m deep. `--ignored --nocapture` to see them.
#[test]
#[ignore]
fn filter_minus_ba_against_noise() {
    for (thickness, n) in [(0.2, 30), (0.2, 120), (0.8, 30)] {
        for sigma in [0.125, 0.25, 0.5, 1.0, 2.0] {
            let k = 24;
            let d: Vec<Vector3<f64>> = (0..k)
                .map(|trial| {
                    run_i(Estimator::Filter, (4, n), sigma, trial, thickness)
                        - run_i(Estimator::Ba, (4, n), sigma, trial, thickness)
                })
                .collect();
            let mean = d.iter().sum::<Vector3<f64>>() / k as f64;
            let sd =
                (d.iter().map(|x| (x - mean).norm_squared()).sum::<f64>() / (k - 1) as f64).sqrt();
            println!(
                "slab {thickness} m, N {n}, sigma {sigma}: mean(filter - BA) {:?} mm, sd {:.3} mm",
                (mean * 1e3).as_slice(),
                sd * 1e3
            );
        }
    }
}
