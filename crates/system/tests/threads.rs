//! Threads that keep the run (issue 41): a back-end worker — the double window optimisation,
//! the loop closer — that panics or whose thread ends in the middle of a run becomes a warning,
//! its work runs in the tracking thread from then on, and the run's outputs are complete, for
//! every sensor: stereo (the KITTI snippet), RGB-D (7-Scenes) and monocular (7-Scenes' colour
//! camera). The faults are a test switch of the workers (`Options::faults`). A clean run
//! reports each thread's lock waits.

use data::camera::SensorModel;
use data::paths;
use data::sequence::{Frame, OpenOptions, Sequence};
use system::vocabulary::default_vocabulary;
use system::{Fault, Faults, LiveRun, Mode, Options, RunResult, System, SystemConfig};

/// The first `n` frames of `name` (`None` without the data), and its sensor (monocular: the
/// camera's left or colour image).
fn sequence(name: &str, n: usize, mono: bool) -> Option<(SensorModel, Vec<Frame>)> {
    let path = paths::require(name)?;
    let options = OpenOptions {
        no_depth: mono,
        require_depth: !mono && name.starts_with("seven"),
        ..OpenOptions::default()
    };
    let sequence = Sequence::open(&path, &options).unwrap();
    let sensor = match sequence.info().camera {
        s if mono => SensorModel::Mono(*s.pinhole()),
        s => s,
    };
    let frames = (0..n)
        .map_while(|i| sequence.read(i))
        .map(|f| f.unwrap())
        .collect();
    Some((sensor, frames))
}

/// A threaded run of `frames` with `faults`.
fn run(sensor: &SensorModel, frames: &[Frame], faults: Faults) -> RunResult {
    let mut system = System::new(
        sensor,
        SystemConfig::default(),
        Options {
            mode: Mode::Threaded,
            sequence: "faults".into(),
            vocabulary: Some(std::sync::Arc::new(default_vocabulary().unwrap())),
            faults,
            ..Options::default()
        },
    )
    .unwrap();
    for f in frames {
        system.process(f.clone()).unwrap();
    }
    system.finish(false).unwrap()
}

/// The outputs of a run with a fault are as complete as those of a run without: every frame in
/// the record with its state, as many frames with a pose (within a tenth: the threads' timing
/// differs from run to run), a trajectory after the run for every posed frame of the map
/// written, keyframes and points; and the warning names the worker.
fn assert_complete(clean: &RunResult, faulty: &RunResult, worker: &str, what: &str) {
    assert_eq!(faulty.record.frames.len(), clean.record.frames.len());
    let posed = |r: &RunResult| {
        r.record
            .frames
            .iter()
            .filter(|f| f.world_from_camera.is_some())
            .count()
    };
    let (a, b) = (posed(clean), posed(faulty));
    assert!(
        b * 10 >= a * 9,
        "{worker} {what}: {b} frames with a pose against {a} without the fault"
    );
    assert!(faulty.final_trajectory.timestamps.len() >= b);
    assert!(!faulty.record.keyframes.is_empty() && !faulty.record.points.is_empty());
    assert!(
        faulty
            .warnings
            .iter()
            .any(|w| w.contains(worker) && w.contains(what)),
        "{worker} {what}: {:?}",
        faulty.warnings
    );
    assert!(
        !clean.warnings.iter().any(|w| w.contains("thread")),
        "{:?}",
        clean.warnings
    );
}

/// Each fault of the workers a sensor has (its optimiser's thread named `optimiser`), after
/// two jobs.
fn faults(optimiser: &'static str) -> Vec<(Faults, &'static str, &'static str)> {
    let panic = Some(Fault::Panic { after: 2 });
    let disconnect = Some(Fault::Disconnect { after: 2 });
    let mut cases = vec![
        (
            Faults {
                loops: panic,
                ..Faults::default()
            },
            "loop closure thread",
            "panicked",
        ),
        (
            Faults {
                loops: disconnect,
                ..Faults::default()
            },
            "loop closure thread",
            "ended before the run did",
        ),
    ];
    cases.extend([
        (
            Faults {
                optimiser: panic,
                ..Faults::default()
            },
            optimiser,
            "panicked",
        ),
        (
            Faults {
                optimiser: disconnect,
                ..Faults::default()
            },
            optimiser,
            "ended before the run did",
        ),
    ]);
    cases
}

fn check(name: &str, n: usize, mono: bool) {
    let Some((sensor, frames)) = sequence(name, n, mono) else {
        return;
    };
    let clean = run(&sensor, &frames, Faults::default());
    // Each back-end thread's waits for the locks it shares with the tracking thread are in the
    // result (its jobs take the graph's locks).
    let threads: Vec<&str> = clean.backend_lock_waits.iter().map(|(t, _)| *t).collect();
    let expected: &[&str] = if mono {
        &["loop closure", "keyframe window"]
    } else {
        &["loop closure", "double window optimisation"]
    };
    assert_eq!(threads, expected);
    for (thread, w) in &clean.backend_lock_waits {
        assert!(
            w.count > 0 && w.median <= w.p99 && w.p99 <= w.max,
            "{thread}: {w:?}"
        );
    }
    let optimiser = if mono {
        "keyframe window thread"
    } else {
        "double window optimisation thread"
    };
    for (faults, worker, what) in faults(optimiser) {
        let faulty = run(&sensor, &frames, faults);
        println!(
            "{name}{}: {worker} {what}: {} of {} frames posed",
            if mono { " mono" } else { "" },
            faulty
                .record
                .frames
                .iter()
                .filter(|f| f.world_from_camera.is_some())
                .count(),
            faulty.record.frames.len()
        );
        assert_complete(&clean, &faulty, worker, what);
    }
}

#[test]
fn a_worker_that_dies_in_a_stereo_run_leaves_complete_outputs() {
    check("kitti_odometry_snippets/KITTI_sequence_1", 51, false);
}

#[test]
fn a_worker_that_dies_in_an_rgbd_run_leaves_complete_outputs() {
    check("seven_scenes_redkitchen_1000", 150, false);
}

#[test]
fn a_worker_that_dies_in_a_monocular_run_leaves_complete_outputs() {
    check("seven_scenes_redkitchen_1000", 300, true);
}
