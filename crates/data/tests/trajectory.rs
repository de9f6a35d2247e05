//! Trajectory files, association and evaluation on synthetic data with known answers.

use data::eval::{Alignment, EvalError, apply_similarity, ate, rpe, rpe_pairs};
use data::trajectory::{
    Trajectory, associate, parse_euroc_groundtruth, parse_kitti, parse_tum, write_kitti, write_tum,
};
use lie::{LieGroup, Se3, Sim3, So3};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;

fn random_trajectory(rng: &mut ChaCha8Rng, n: usize) -> Trajectory {
    let mut pose = Se3::identity();
    let mut t = Trajectory::default();
    for i in 0..n {
        let step = nalgebra::Vector6::from_fn(|k, _| {
            if k < 3 {
                rng.random_range(-0.5..0.5)
            } else {
                rng.random_range(-0.2..0.2)
            }
        });
        pose = pose.compose(&Se3::exp(&step));
        t.timestamps.push(1000.0 + 0.1 * i as f64);
        t.world_from_body.push(pose);
    }
    t
}

fn close(a: &Se3, b: &Se3) -> bool {
    a.inverse().compose(b).log().norm() < 1e-12
}

#[test]
fn tum_and_kitti_round_trip() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let t = random_trajectory(&mut rng, 50);
    let mut text = Vec::new();
    write_tum(&t, &mut text).unwrap();
    let back = parse_tum(std::str::from_utf8(&text).unwrap(), Path::new("t.txt")).unwrap();
    assert_eq!(back.timestamps, t.timestamps);
    assert!(
        back.world_from_body
            .iter()
            .zip(&t.world_from_body)
            .all(|(a, b)| close(a, b))
    );
    let mut text = Vec::new();
    write_kitti(&t.world_from_body, &mut text).unwrap();
    let back = parse_kitti(std::str::from_utf8(&text).unwrap(), Path::new("k.txt")).unwrap();
    assert!(
        back.iter()
            .zip(&t.world_from_body)
            .all(|(a, b)| close(a, b))
    );
}

#[test]
fn euroc_columns_and_nanoseconds() {
    let text = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v\n\
                1403715273262142976,1,2,3,0,1,0,0,0.5\n";
    let t = parse_euroc_groundtruth(text, Path::new("gt.csv")).unwrap();
    assert_eq!(t.timestamps, vec![1403715273.262143]);
    assert_eq!(
        t.world_from_body[0].translation(),
        &Vector3::new(1.0, 2.0, 3.0)
    );
    // q = (w 0, x 1): 180° about x.
    assert!((t.world_from_body[0].rotation().angle() - std::f64::consts::PI).abs() < 1e-12);
}

#[test]
fn malformed_trajectory_files_name_the_line() {
    let tum_cases = [
        ("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", 2),
        ("# c\n1 0 0 0 0 0 0 1\n2 0 x 0 0 0 0 1\n", 3),
        ("1 0 0 0 0 0 0 1\n2 0 0 NaN 0 0 0 1\n", 2),
        ("1 0 0 0 0 0 0 0\n", 1),
        ("1 inf 0 0 0 0 0 1\n", 1),
    ];
    for (text, line) in tum_cases {
        let err = parse_tum(text, Path::new("est.txt")).unwrap_err();
        assert_eq!(err.line(), Some(line), "{text:?}: {err}");
        assert!(err.to_string().starts_with("est.txt:"), "{err}");
    }
    assert!(parse_tum("# only comments\n\n", Path::new("e")).is_err());
    let kitti_cases = [
        ("1 0 0 0 0 1 0 0 0 0 1\n", 1),
        ("1 0 0 0 0 1 0 0 0 0 1 0\n2 0 0 0 0 1 0 0 0 0 1 0\n", 2),
        ("1 0 0 0 0 1 0 0 0 0 -1 0\n", 1),
        ("1 0 0 0 0 1 0 0 0 0 1 nan\n", 1),
    ];
    for (text, line) in kitti_cases {
        let err = parse_kitti(text, Path::new("k.txt")).unwrap_err();
        assert_eq!(err.line(), Some(line), "{text:?}: {err}");
    }
    let err = parse_euroc_groundtruth("1,2,3\n", Path::new("gt.csv")).unwrap_err();
    assert_eq!(err.line(), Some(1));
}

#[test]
fn association_follows_evo() {
    let reference = [0.0, 1.0, 2.0, 3.0, 4.0];
    // Estimate is shorter: each of its stamps finds the nearest reference stamp within 0.1 s;
    // 2.5 is a tie between 2 and 3 but beyond max_difference; 3.96 matches 4.
    let estimate = [0.05, 2.5, 3.96];
    assert_eq!(
        associate(&reference, &estimate, 0.1, 0.0),
        vec![(0, 0), (4, 2)]
    );
    // Ties go to the earlier stamp.
    assert_eq!(associate(&reference, &[2.5], 0.5, 0.0), vec![(2, 0)]);
    // The offset applies to the estimate: estimate stamps + 1.0 ≈ reference.
    assert_eq!(
        associate(&reference, &[-0.98, 0.01], 0.05, 1.0),
        vec![(0, 0), (1, 1)]
    );
    // The estimate longer than the reference: pairs still come as (reference, estimate).
    let long = [0.0, 0.5, 1.02, 1.5, 2.0, 2.5];
    assert_eq!(
        associate(&[1.0, 2.0], &long, 0.05, 0.0),
        vec![(0, 2), (1, 4)]
    );
    assert!(associate(&[], &long, 0.05, 0.0).is_empty());
}

#[test]
fn ate_is_zero_after_the_right_alignment_and_not_before() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let reference = random_trajectory(&mut rng, 100).world_from_body;
    let s = Sim3::new(
        So3::exp(&Vector3::new(0.3, -1.0, 2.0)),
        Vector3::new(4.0, -2.0, 1.0),
        2.5,
    )
    .unwrap();
    // estimate = S⁻¹·reference, so S aligns it back.
    let estimate: Vec<Se3> = reference
        .iter()
        .map(|p| apply_similarity(&s.inverse(), p))
        .collect();
    let sim = ate(&reference, &estimate, Alignment::Sim3).unwrap();
    assert!(sim.translation.rmse < 1e-10, "{}", sim.translation.rmse);
    assert!(
        sim.reference_from_estimate
            .inverse()
            .compose(&s)
            .log()
            .norm()
            < 1e-9
    );
    assert!(
        ate(&reference, &estimate, Alignment::Se3)
            .unwrap()
            .translation
            .rmse
            > 0.1
    );
    assert!(
        ate(&reference, &estimate, Alignment::None)
            .unwrap()
            .translation
            .rmse
            > 1.0
    );
    // RPE is invariant to rigid alignment and needs the scale for similarities.
    let rigid = Sim3::from_se3(&s.rigid_part());
    let moved: Vec<Se3> = reference
        .iter()
        .map(|p| apply_similarity(&rigid, p))
        .collect();
    assert!(
        rpe(&reference, &moved, 1, false, Alignment::None)
            .unwrap()
            .translation
            .rmse
            < 1e-12
    );
    let r = rpe(&reference, &estimate, 3, true, Alignment::Sim3).unwrap();
    assert!(r.translation.rmse < 1e-10 && r.rotation_rad.rmse < 1e-10);
}

#[test]
fn ate_statistics_by_hand() {
    // Three poses displaced along x by 0, 3, 4 with no alignment: errors 0, 3, 4.
    let reference: Vec<Se3> = (0..3)
        .map(|i| Se3::from_translation(Vector3::new(0.0, i as f64, 0.0)))
        .collect();
    let estimate: Vec<Se3> = reference
        .iter()
        .zip([0.0, 3.0, 4.0])
        .map(|(p, dx)| Se3::from_translation(p.translation() + Vector3::new(dx, 0.0, 0.0)))
        .collect();
    let s = ate(&reference, &estimate, Alignment::None)
        .unwrap()
        .translation;
    assert!((s.rmse - (25.0f64 / 3.0).sqrt()).abs() < 1e-15);
    assert!((s.mean - 7.0 / 3.0).abs() < 1e-15);
    assert_eq!(
        (s.median, s.min, s.max, s.sse, s.count),
        (3.0, 0.0, 4.0, 25.0, 3)
    );
}

#[test]
fn rpe_pairs_match_evo() {
    assert_eq!(rpe_pairs(7, 3, false), vec![(0, 3), (3, 6)]);
    assert_eq!(rpe_pairs(5, 2, true), vec![(0, 2), (1, 3), (2, 4)]);
    assert_eq!(rpe_pairs(4, 1, false), vec![(0, 1), (1, 2), (2, 3)]);
}

#[test]
fn evaluation_errors() {
    let a = vec![Se3::identity(); 3];
    assert!(matches!(
        ate(&a, &a[..2], Alignment::None),
        Err(EvalError::LengthMismatch { .. })
    ));
    assert!(matches!(
        ate(&[], &[], Alignment::None),
        Err(EvalError::Empty { .. })
    ));
    // Coincident positions cannot be aligned.
    assert!(matches!(
        ate(&a, &a, Alignment::Se3),
        Err(EvalError::Align(_))
    ));
    assert!(matches!(
        rpe(&a[..1], &a[..1], 1, false, Alignment::None),
        Err(EvalError::Empty { .. })
    ));
}
