//! ATE and RPE checked against evo (PyPI `evo` 1.38.1) on the trajectories evo's own tests use
//! (`../shared/data/trajectories_evo`).
//!
//! The numbers below were recorded from evo with `bench/eval/evo_reference.sh`, which runs the
//! command written above each case in that directory (`MPLBACKEND=Agg`, `--save_results`, the
//! statistics read from the saved `stats.json`). The ignored test at the end re-runs evo live:
//! `cargo test -p data --test eval_evo -- --ignored` (it creates the venv on first use).
//!
//! Agreement is to ~1e-13 relative everywhere except KITTI RPE (~2e-7): KITTI files store
//! rotation matrices with 7 digits, which we read as exact rotations (quaternions) while evo
//! keeps the slightly non-orthonormal matrices; the tolerance below is 1e-6.

use data::eval::{Alignment, Statistics, ate, rpe};
use data::paths::require;
use data::trajectory::{
    Trajectory, associate_trajectories, read_euroc_groundtruth, read_kitti, read_tum,
};
use lie::Se3;
use std::path::Path;

#[derive(Clone, Copy, Debug)]
enum File {
    Tum(&'static str),
    Kitti(&'static str),
    Euroc(&'static str),
}

#[derive(Clone, Copy, Debug)]
enum Metric {
    Ape(Alignment),
    RpeTranslation {
        delta: usize,
        all_pairs: bool,
        alignment: Alignment,
    },
    RpeRotation {
        delta: usize,
        all_pairs: bool,
        alignment: Alignment,
    },
}

#[derive(Clone, Copy, Debug)]
struct EvoStats {
    rmse: f64,
    mean: f64,
    median: f64,
    std: f64,
    min: f64,
    max: f64,
}

struct Case {
    name: &'static str,
    reference: File,
    estimate: File,
    metric: Metric,
    evo: EvoStats,
}

const CASES: [Case; 10] = [
    // evo_ape tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt --align
    Case {
        name: "ape_fr2_desk_se3",
        reference: File::Tum("fr2_desk_groundtruth.txt"),
        estimate: File::Tum("fr2_desk_ORB.txt"),
        metric: Metric::Ape(Alignment::Se3),
        evo: EvoStats {
            rmse: 0.008118977562044926,
            mean: 0.0074917768702161495,
            median: 0.007414629829316952,
            std: 0.00312906950703932,
            min: 0.0003496361984068482,
            max: 0.024299593694385276,
        },
    },
    // evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt --align --correct_scale
    Case {
        name: "ape_fr1_xyz_mono_sim3",
        reference: File::Tum("freiburg1_xyz-groundtruth.txt"),
        estimate: File::Tum("freiburg1_xyz-ORB_kf_mono.txt"),
        metric: Metric::Ape(Alignment::Sim3),
        evo: EvoStats {
            rmse: 0.009754581898685118,
            mean: 0.008218698588816626,
            median: 0.007909070259951256,
            std: 0.0052540328819240326,
            min: 0.0018768480970276604,
            max: 0.02792400173407602,
        },
    },
    // evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam_drift.txt
    Case {
        name: "ape_fr1_xyz_drift_none",
        reference: File::Tum("freiburg1_xyz-groundtruth.txt"),
        estimate: File::Tum("freiburg1_xyz-rgbdslam_drift.txt"),
        metric: Metric::Ape(Alignment::None),
        evo: EvoStats {
            rmse: 0.1341854204892675,
            mean: 0.12298561737556277,
            median: 0.12653056052590608,
            std: 0.053668100307661386,
            min: 0.0012561023047507462,
            max: 0.249332053412713,
        },
    },
    // evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt --align
    Case {
        name: "ape_kitti00_se3",
        reference: File::Kitti("KITTI_00_gt.txt"),
        estimate: File::Kitti("KITTI_00_ORB.txt"),
        metric: Metric::Ape(Alignment::Se3),
        evo: EvoStats {
            rmse: 1.3034497145650337,
            mean: 1.1569971285389835,
            median: 1.0656247695557912,
            std: 0.600282269396835,
            min: 0.06931322021482282,
            max: 3.587949120678975,
        },
    },
    // evo_ape euroc V102_groundtruth.csv V102.txt --align
    Case {
        name: "ape_v102_se3",
        reference: File::Euroc("V102_groundtruth.csv"),
        estimate: File::Tum("V102.txt"),
        metric: Metric::Ape(Alignment::Se3),
        evo: EvoStats {
            rmse: 0.09172711520685745,
            mean: 0.08152162194619841,
            median: 0.07791194901949514,
            std: 0.04204864824739554,
            min: 0.0026199870973829826,
            max: 0.2558167338139711,
        },
    },
    // evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt --delta 1
    Case {
        name: "rpe_fr1_xyz_trans",
        reference: File::Tum("freiburg1_xyz-groundtruth.txt"),
        estimate: File::Tum("freiburg1_xyz-rgbdslam.txt"),
        metric: Metric::RpeTranslation {
            delta: 1,
            all_pairs: false,
            alignment: Alignment::None,
        },
        evo: EvoStats {
            rmse: 0.005764370848928318,
            mean: 0.00481560947020396,
            median: 0.004138857799364448,
            std: 0.003168260834346898,
            min: 0.00017106115346223795,
            max: 0.020865814532329843,
        },
    },
    // evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt --delta 1 --pose_relation angle_rad
    Case {
        name: "rpe_fr1_xyz_rot",
        reference: File::Tum("freiburg1_xyz-groundtruth.txt"),
        estimate: File::Tum("freiburg1_xyz-rgbdslam.txt"),
        metric: Metric::RpeRotation {
            delta: 1,
            all_pairs: false,
            alignment: Alignment::None,
        },
        evo: EvoStats {
            rmse: 0.006171713938616683,
            mean: 0.005241338606301213,
            median: 0.004575188642116212,
            std: 0.0032585921122797678,
            min: 0.00029560892037159756,
            max: 0.028506393947577036,
        },
    },
    // evo_rpe kitti KITTI_00_gt.txt KITTI_00_ORB.txt --delta 10
    Case {
        name: "rpe_kitti00_trans_d10",
        reference: File::Kitti("KITTI_00_gt.txt"),
        estimate: File::Kitti("KITTI_00_ORB.txt"),
        metric: Metric::RpeTranslation {
            delta: 10,
            all_pairs: false,
            alignment: Alignment::None,
        },
        evo: EvoStats {
            rmse: 0.19400775757968894,
            mean: 0.1415104948739975,
            median: 0.11125927424444243,
            std: 0.13271695385901408,
            min: 0.01665741182263252,
            max: 1.1885349127453586,
        },
    },
    // evo_rpe tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt --delta 5 --all_pairs
    Case {
        name: "rpe_fr2_desk_all_pairs_d5",
        reference: File::Tum("fr2_desk_groundtruth.txt"),
        estimate: File::Tum("fr2_desk_ORB.txt"),
        metric: Metric::RpeTranslation {
            delta: 5,
            all_pairs: true,
            alignment: Alignment::None,
        },
        evo: EvoStats {
            rmse: 0.005284571430848784,
            mean: 0.004590884485710595,
            median: 0.004061629081560977,
            std: 0.0026173411788692987,
            min: 0.00019128091425326288,
            max: 0.023985060718307354,
        },
    },
    // evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt --delta 1 --align --correct_scale
    Case {
        name: "rpe_fr1_xyz_mono_sim3",
        reference: File::Tum("freiburg1_xyz-groundtruth.txt"),
        estimate: File::Tum("freiburg1_xyz-ORB_kf_mono.txt"),
        metric: Metric::RpeTranslation {
            delta: 1,
            all_pairs: false,
            alignment: Alignment::Sim3,
        },
        evo: EvoStats {
            rmse: 0.013834917845974098,
            mean: 0.01205827516547716,
            median: 0.01114185876756864,
            std: 0.006782547592054872,
            min: 0.001783531609812972,
            max: 0.030228647349587398,
        },
    },
];

/// Reads a file; KITTI files have no timestamps (index = time, as evo's `kitti` mode pairs
/// poses by index).
fn load(dir: &Path, file: File) -> Trajectory {
    match file {
        File::Tum(name) => read_tum(dir.join(name)).unwrap(),
        File::Kitti(name) => Trajectory::from_poses(read_kitti(dir.join(name)).unwrap()),
        File::Euroc(name) => read_euroc_groundtruth(dir.join(name)).unwrap(),
    }
}

/// Our statistics for a case: associate as evo does (max 0.01 s, no offset), then the metric.
fn ours(dir: &Path, case: &Case) -> Statistics {
    let reference = load(dir, case.reference);
    let estimate = load(dir, case.estimate);
    let (r, e): (Vec<Se3>, Vec<Se3>) = associate_trajectories(&reference, &estimate, 0.01, 0.0);
    match case.metric {
        Metric::Ape(alignment) => ate(&r, &e, alignment).unwrap().translation,
        Metric::RpeTranslation {
            delta,
            all_pairs,
            alignment,
        } => {
            rpe(&r, &e, delta, all_pairs, alignment)
                .unwrap()
                .translation
        }
        Metric::RpeRotation {
            delta,
            all_pairs,
            alignment,
        } => {
            rpe(&r, &e, delta, all_pairs, alignment)
                .unwrap()
                .rotation_rad
        }
    }
}

fn assert_agrees(name: &str, ours: &Statistics, evo: &EvoStats) {
    for (what, a, b) in [
        ("rmse", ours.rmse, evo.rmse),
        ("mean", ours.mean, evo.mean),
        ("median", ours.median, evo.median),
        ("std", ours.std, evo.std),
        ("min", ours.min, evo.min),
        ("max", ours.max, evo.max),
    ] {
        let rel = (a - b).abs() / b.abs().max(1e-12);
        eprintln!("{name} {what}: ours {a:.12e} evo {b:.12e} relative difference {rel:.1e}");
        assert!(
            rel < 1e-6,
            "{name} {what}: ours {a} vs evo {b} (relative {rel:e})"
        );
    }
}

#[test]
fn ate_and_rpe_agree_with_recorded_evo_numbers() {
    let Some(dir) = require("trajectories_evo") else {
        return;
    };
    for case in &CASES {
        assert_agrees(case.name, &ours(&dir, case), &case.evo);
    }
}

#[test]
#[ignore = "installs evo from PyPI into bench/eval/.venv-evo and runs it (about a minute)"]
fn ate_and_rpe_agree_with_live_evo() {
    let Some(dir) = require("trajectories_evo") else {
        return;
    };
    let script = data::paths::workspace_root().join("bench/eval/evo_reference.sh");
    let output = std::process::Command::new("bash")
        .arg(&script)
        .env("DWSLAM_DATA", dir.parent().unwrap())
        .output()
        .expect("runs bash");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let text = String::from_utf8(output.stdout).unwrap();
    let mut checked = 0;
    for line in text.lines() {
        let field = |key: &str| -> f64 {
            let start = line.find(&format!("\"{key}\": ")).unwrap() + key.len() + 4;
            let rest = &line[start..];
            let end = rest.find([',', '}']).unwrap();
            rest[..end].trim().parse().unwrap()
        };
        let name_start = line.find("\"case\": \"").unwrap() + 9;
        let name = &line[name_start..name_start + line[name_start..].find('"').unwrap()];
        let case = CASES.iter().find(|c| c.name == name).unwrap();
        let evo = EvoStats {
            rmse: field("rmse"),
            mean: field("mean"),
            median: field("median"),
            std: field("std"),
            min: field("min"),
            max: field("max"),
        };
        assert_agrees(name, &ours(&dir, case), &evo);
        checked += 1;
    }
    assert_eq!(checked, CASES.len());
}
