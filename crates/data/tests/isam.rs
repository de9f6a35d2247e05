//! iSAM ground truth: the chained odometry agrees with the noise-free loop closures, and with
//! the noisy g2o datasets' vertices up to their noise.

use data::isam::{IsamGroundTruth, parse_isam_groundtruth, read_isam_groundtruth};
use data::paths::require;
use lie::LieGroup;
use std::path::Path;

/// Largest translation and rotation disagreement of any edge with the chained poses.
fn worst_edge<G: LieGroup<DOF>, const DOF: usize>(g: &data::isam::IsamGraph<G>) -> f64 {
    g.edges
        .iter()
        .map(|e| {
            let a = &g.world_from_body[e.from as usize];
            let b = &g.world_from_body[e.to as usize];
            e.measurement
                .inverse()
                .compose(&a.inverse().compose(b))
                .log()
                .norm()
        })
        .fold(0.0, f64::max)
}

#[test]
fn ground_truth_loop_closures_agree_with_chained_odometry() {
    // PROVENANCE.md: loop closures agree up to print rounding (mm over thousands of steps).
    for (name, poses, edges, bound) in [
        ("manhattanOlson3500_groundtruth.txt", 3500, 5598, 0.01),
        ("city10000_groundtruth.txt", 10000, 20687, 0.02),
        ("sphere2500_groundtruth.txt", 2500, 4949, 0.01),
    ] {
        let Some(path) = require(Path::new("pose_graph_groundtruth_isam").join(name)) else {
            return;
        };
        let gt = read_isam_groundtruth(path).unwrap();
        let worst = match &gt {
            IsamGroundTruth::Se2(g) => {
                assert_eq!((g.world_from_body.len(), g.edges.len()), (poses, edges));
                worst_edge(g)
            }
            IsamGroundTruth::Se3(g) => {
                assert_eq!((g.world_from_body.len(), g.edges.len()), (poses, edges));
                worst_edge(g)
            }
        };
        assert!(worst < bound, "{name}: worst loop-closure residual {worst}");
    }
}

#[test]
fn roll_pitch_yaw_convention_is_the_consistent_one() {
    // With the rotation composed the other way round (R_x·R_y·R_z) the sphere's loop closures
    // disagree with the chained odometry by far more than rounding: the convention matters.
    let Some(path) = require("pose_graph_groundtruth_isam/sphere2500_groundtruth.txt") else {
        return;
    };
    let text = std::fs::read_to_string(&path).unwrap();
    let swapped: String = text
        .lines()
        .map(|l| {
            let mut w: Vec<&str> = l.split_whitespace().collect();
            w.swap(6, 8); // roll <-> yaw: R_z(roll)·R_y(pitch)·R_x(yaw)
            w.join(" ") + "\n"
        })
        .collect();
    let IsamGroundTruth::Se3(g) = parse_isam_groundtruth(&swapped, Path::new("swapped")).unwrap()
    else {
        panic!("3D")
    };
    assert!(worst_edge(&g) > 0.1);
}

#[test]
fn malformed_ground_truth_is_an_error_naming_the_line() {
    let cases = [
        ("EDGE2 0 1 1 0 0 1 0 0 1 0\n", 1),
        (
            "EDGE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE2 1 2 1 0 nan 1 0 0 1 0 1\n",
            2,
        ),
        ("EDGE2 0 1 1 0 0 1 0 0 1 0 1\nVERTEX2 1 0 0 0\n", 2),
        (
            "EDGE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE3 1 2 1 0 0 0 0 0 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n",
            2,
        ),
    ];
    for (text, line) in cases {
        let err = parse_isam_groundtruth(text, Path::new("gt.txt")).unwrap_err();
        assert_eq!(err.line(), Some(line), "{text}: {err}");
        assert!(err.to_string().starts_with("gt.txt:"));
    }
    // A missing odometry edge: 0→1 and 2→3 but no 1→2.
    let err = parse_isam_groundtruth(
        "EDGE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE2 2 3 1 0 0 1 0 0 1 0 1\n",
        Path::new("gt.txt"),
    )
    .unwrap_err();
    assert!(err.to_string().contains("odometry edge 1 → 2"), "{err}");
    assert!(parse_isam_groundtruth("", Path::new("gt.txt")).is_err());
}

#[test]
fn noisy_g2o_odometry_matches_ground_truth_up_to_its_noise() {
    // sphere2500.g2o is the ground truth with noise added: its odometry measurements differ from
    // the noise-free ones by noise of σ = 1/10 m per axis (the iSAM file's square-root
    // information is 10 on the translation). The per-axis RMS of the differences over 2499
    // odometry edges must be that σ, which checks that ids and conventions line up.
    let (Some(gt), Some(g2o)) = (
        require("pose_graph_groundtruth_isam/sphere2500_groundtruth.txt"),
        require("pose_graph_g2o/sphere2500.g2o"),
    ) else {
        return;
    };
    let IsamGroundTruth::Se3(gt) = read_isam_groundtruth(gt).unwrap() else {
        panic!("3D")
    };
    let (graph, _) = data::g2o::read_g2o_se3(g2o).unwrap();
    let mut sum = 0.0;
    let mut n = 0;
    for e in graph.edges().iter().filter(|e| e.to == e.from + 1) {
        let truth = gt.world_from_body[e.from as usize]
            .inverse()
            .compose(&gt.world_from_body[e.to as usize]);
        sum += (truth.translation() - e.measurement.translation()).norm_squared();
        n += 3;
    }
    let rms = (sum / n as f64).sqrt();
    assert_eq!(n, 3 * 2499);
    assert!((rms - 0.1).abs() < 0.01, "per-axis RMS {rms}");
}
