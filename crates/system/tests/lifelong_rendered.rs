//! Bounded maps on revisits (issue 43, lifelong mapping), the short version of
//! `bench/live/lifelong.py`: the rendered room browsed hand-held (RGB-D, default revisit
//! jitter, `keyframes.reuse_map_points` on) for two laps. Once the first lap has mapped the room, the second adds at most a
//! tenth to its points (a revisited surface is measured by the points it has, not given new
//! ones) and, with the keyframes that revisits make redundant culled, fewer than half the
//! keyframes it adds without culling; every frame still has its pose after the run (the frames
//! kept relative to a culled keyframe follow its heir), the graph keeps its invariants, and
//! the trajectory is as accurate as without culling.

use data::camera::SensorModel as DataSensor;
use lie::Se3;
use sim::render::{SceneKind, SensorKind, SensorModel, Sequence, SequenceConfig};
use system::vocabulary::default_vocabulary;
use system::{LiveRun, Mode, Options, RunGraph, RunResult, System, SystemConfig};

/// The first lap around the room's twelve views ends at about frame 1560 (30 Hz).
const FIRST_LAP: usize = 1560;

struct Run {
    result: RunResult,
    /// `(frame, keyframes, points)` at the end of each lap.
    laps: Vec<(usize, usize, usize)>,
    truth: Vec<Se3>,
}

fn run(frames: usize, cull: bool) -> Run {
    let sensor = SensorModel::new(SensorKind::Rgbd, 640, 480);
    let camera: DataSensor = sensor.sequence_camera().unwrap();
    let mut sequence = Sequence::new(SequenceConfig {
        scene: SceneKind::Room,
        sensor,
        seed: 1,
        path_seed: None,
        frames: Some(frames),
        revisit_jitter: sim::render::DEFAULT_REVISIT_JITTER,
    })
    .unwrap();
    let mut config = SystemConfig::default();
    config.keyframes.cull = cull;
    config.keyframes.reuse_map_points = true;
    let mut system = System::new(
        &camera,
        config,
        Options {
            mode: Mode::Deterministic,
            sequence: "room".into(),
            vocabulary: Some(std::sync::Arc::new(default_vocabulary().unwrap())),
            keyframe_depth: false,
            ..Options::default()
        },
    )
    .unwrap();
    let mut laps = Vec::new();
    let mut truth = Vec::new();
    for k in 0..frames {
        let frame = sequence.render_frame(k).unwrap();
        truth.push(frame.world_from_camera);
        system.process(frame.to_sequence_frame()).unwrap();
        if k + 1 == FIRST_LAP || k + 1 == frames {
            let p = system.progress();
            laps.push((k + 1, p.keyframes, p.points));
        }
    }
    Run {
        result: system.finish(false).unwrap(),
        laps,
        truth,
    }
}

/// ATE RMSE (m) of the trajectory after the run against the ground truth (SE(3)-aligned).
fn ate(run: &Run) -> f64 {
    let t = &run.result.final_trajectory;
    assert_eq!(
        t.world_from_body.len(),
        run.truth.len(),
        "every frame has a pose"
    );
    data::eval::ate(&run.truth, &t.world_from_body, data::eval::Alignment::Se3)
        .unwrap()
        .translation
        .rmse
}

#[test]
fn a_room_browsed_twice_keeps_its_map_size() {
    let frames = 2 * FIRST_LAP;
    let culled = run(frames, true);
    let kept = run(frames, false);
    let [(_, k1, p1), (_, k2, p2)] = culled.laps[..] else {
        unreachable!()
    };
    println!(
        "culling: {k1} → {k2} keyframes, {p1} → {p2} points, {} culled; without: {:?}",
        culled.result.culled, kept.laps
    );
    assert!(culled.result.culled > 0);
    assert_eq!(kept.result.culled, 0);
    assert!(
        p2 as f64 <= 1.1 * p1 as f64,
        "the second lap grew the points: {:?}",
        culled.laps
    );
    let grown = |r: &Run| r.laps[1].1 as f64 - r.laps[0].1 as f64;
    assert!(
        grown(&culled) < 0.5 * grown(&kept),
        "keyframes: {:?} culling, {:?} without",
        culled.laps,
        kept.laps
    );
    let RunGraph::Depth(graph) = &culled.result.graph else {
        unreachable!("RGB-D")
    };
    graph.check_invariants().unwrap();
    let (with, without) = (ate(&culled), ate(&kept));
    println!(
        "ATE after the run: {:.3} cm culling, {:.3} cm without",
        with * 100.0,
        without * 100.0
    );
    assert!(
        with <= 1.5 * without.max(0.001),
        "{with} m with culling, {without} m without"
    );
}
