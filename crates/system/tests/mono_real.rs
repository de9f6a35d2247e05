//! The monocular live system on real images (issue 20): the KITTI snippet's left camera and
//! 7-Scenes Red Kitchen's colour camera. Corner tracks feed `slam::exploration` (bootstrap
//! with homography/essential model selection, motion-only BA, inverse-depth feature filters,
//! the keyframe BA of the covisible window with older observers fixed and outliers removed);
//! the trajectory of every frame is scored after Sim(3) alignment (a monocular map has its own
//! scale). The bounds: KITTI at most ORB-SLAM3 mono's best run measured here (10.1 cm, issue
//! 20); 7-Scenes initialised within 15 frames, 95 % tracked, a regression bound a little above
//! today's 4.28 cm (ORB-SLAM3's best run measured here: 3.72 cm). Two deterministic runs are
//! identical.

use data::eval::{Alignment, ate};
use data::paths;
use data::sequence::{OpenOptions, Sequence};
use lie::{LieGroup, Se3};
use system::config::SystemConfig;
use system::{LiveRun, Mode, Options, RunResult, System};

/// The grey image of a 7-Scenes (RGB-D or colour-only) frame, to alter.
fn grey_mut(frame: &mut data::sequence::Frame) -> &mut vision::image::GrayImage {
    match &mut frame.images {
        data::sequence::FrameImages::Rgbd { image, .. }
        | data::sequence::FrameImages::Mono { image, .. } => image,
        data::sequence::FrameImages::Stereo { left, .. } => left,
    }
}

/// A deterministic monocular system for `camera` with `config` (and loop closure with
/// `vocabulary`).
fn mono(
    camera: geom::PinholeCamera,
    config: SystemConfig,
    name: &str,
    vocabulary: Option<std::sync::Arc<vision::bow::Vocabulary>>,
) -> System {
    System::new(
        &data::camera::SensorModel::Mono(camera),
        config,
        Options {
            mode: Mode::Deterministic,
            sequence: name.into(),
            vocabulary,
            ..Options::default()
        },
    )
    .unwrap()
}

struct Scored {
    result: RunResult,
    /// Frames with a live pose.
    tracked: usize,
    frames: usize,
    /// ATE RMSE (m) of the live poses after Sim(3) alignment.
    ate: f64,
    /// The first frame with a live pose.
    first_pose: usize,
    truth: Vec<Se3>,
}

fn run(name: &str, frames: usize) -> Option<Scored> {
    let path = paths::require(name)?;
    let sequence = Sequence::open(&path, &OpenOptions::default()).unwrap();
    let camera = *sequence.info().camera.pinhole();
    let mut system = mono(camera, SystemConfig::default(), name, None);
    let mut truth = Vec::new();
    let n = frames.min(sequence.len());
    for k in 0..n {
        let frame = sequence.read(k).unwrap().unwrap();
        truth.push(frame.world_from_camera.expect("ground truth"));
        system.process(frame).unwrap();
    }
    let result = system.finish(false).unwrap();
    let (mut r, mut e) = (Vec::new(), Vec::new());
    for f in &result.record.frames {
        if let Some(p) = f.world_from_camera {
            r.push(truth[f.index]);
            e.push(p);
        }
    }
    let first_pose = result
        .record
        .frames
        .iter()
        .find(|f| f.world_from_camera.is_some())
        .map_or(usize::MAX, |f| f.index);
    let ate = ate(&r, &e, Alignment::Sim3).unwrap().translation.rmse;
    Some(Scored {
        tracked: e.len(),
        frames: n,
        ate,
        first_pose,
        truth,
        result,
    })
}

#[test]
fn kitti_left_camera_is_tracked_at_orb_slam3_accuracy() {
    let Some(s) = run("kitti_odometry_snippets/KITTI_sequence_1", 51) else {
        return;
    };
    println!(
        "KITTI mono: first pose at frame {}, {}/{} frames tracked, ATE (Sim(3)) {:.2} cm, {} keyframes, {} points",
        s.first_pose,
        s.tracked,
        s.frames,
        s.ate * 100.0,
        s.result.record.keyframes.len(),
        s.result.record.points.len()
    );
    assert!(s.first_pose < 15, "initialised at frame {}", s.first_pose);
    assert!(s.tracked * 100 >= 95 * s.frames, "{} tracked", s.tracked);
    assert!(s.ate <= 0.101, "ATE {:.2} cm", s.ate * 100.0);
    // The bootstrap's relative pose (the first two keyframes) against the ground truth.
    let k = &s.result.record.keyframes;
    let estimate = k[1]
        .world_from_camera
        .inverse()
        .compose(&k[0].world_from_camera);
    let truth = s.truth[k[1].frame_index]
        .inverse()
        .compose(&s.truth[k[0].frame_index]);
    let rotation = estimate
        .rotation()
        .compose(&truth.rotation().inverse())
        .log()
        .norm()
        .to_degrees();
    let (a, b) = (estimate.translation(), truth.translation());
    let direction = (a.dot(b) / (a.norm() * b.norm()))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    println!(
        "bootstrap between frames {} and {}: rotation error {rotation:.2}°, translation direction {direction:.2}°",
        k[0].frame_index, k[1].frame_index
    );
    assert!(rotation < 0.5 && direction < 2.0);
    // Every keyframe after the bootstrap's says which criterion made it; a car driving
    // straight makes them by its baseline (the distance over the scene depth, beyond 5 %).
    let reasons: Vec<_> = s
        .result
        .frames
        .iter()
        .filter_map(|f| f.keyframe.as_ref().map(|(_, r)| r.clone()))
        .collect();
    assert_eq!(reasons[0], system::KeyframeReason::First, "{reasons:?}");
    assert!(
        reasons[1..]
            .iter()
            .all(|r| !matches!(r, system::KeyframeReason::First)),
        "{reasons:?}"
    );
    let by_baseline = reasons[1..]
        .iter()
        .filter(|r| matches!(r, system::KeyframeReason::Parallax(p) if *p > 0.05))
        .count();
    assert!(by_baseline * 10 >= 9 * (reasons.len() - 1), "{reasons:?}");
}

#[test]
fn seven_scenes_colour_camera_is_tracked_and_runs_are_deterministic() {
    let Some(a) = run("seven_scenes_redkitchen_1000", 1000) else {
        return;
    };
    println!(
        "7-Scenes mono: first pose at frame {}, {}/{} frames tracked, ATE (Sim(3)) {:.2} cm, {} keyframes; {:?}",
        a.first_pose,
        a.tracked,
        a.frames,
        a.ate * 100.0,
        a.result.record.keyframes.len(),
        a.result.warnings
    );
    // Issue 20: initialised within the first 15 frames (the bootstrap measures the tracks'
    // noise on its two frames), at least 95 % of the frames tracked.
    assert!(a.first_pose < 15, "initialised at frame {}", a.first_pose);
    assert!(a.tracked * 100 >= 95 * a.frames, "{} tracked", a.tracked);
    assert!(a.ate <= 0.055, "ATE {:.2} cm", a.ate * 100.0);
    // Frames before the first pose say why.
    for f in &a.result.record.frames[..a.first_pose.min(a.frames)] {
        assert!(
            matches!(&f.state, data::output::TrackingState::Lost(why) if !why.is_empty()),
            "{:?}",
            f.state
        );
    }
    let b = run("seven_scenes_redkitchen_1000", 300).unwrap();
    for (x, y) in a.result.record.frames.iter().zip(&b.result.record.frames) {
        assert_eq!(x.state, y.state, "frame {}", x.index);
        assert_eq!(
            x.world_from_camera.map(|p| p.log()),
            y.world_from_camera.map(|p| p.log()),
            "frame {} differs between runs",
            x.index
        );
    }
}

/// Hard input (issue 20): gaps of 5 and 30 frames, a black frame, a textureless stretch and an
/// unreadable frame never stop the run; every frame is in the record with a state saying what
/// happened, and the map survives a single black frame.
#[test]
fn gaps_black_textureless_and_unreadable_frames_are_reported_and_the_run_goes_on() {
    let Some(path) = paths::require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let sequence = Sequence::open(&path, &OpenOptions::default()).unwrap();
    let camera = *sequence.info().camera.pinhole();
    // Frames 0–119 (initialised by ~50), a gap of 5, to 160, a gap of 30, to 260.
    let indices: Vec<usize> = (0..120).chain(125..160).chain(190..260).collect();
    let mut system = mono(camera, SystemConfig::default(), "hard", None);
    let (black, unreadable) = (100, 110);
    let textureless = 200..215;
    for &k in &indices {
        if k == unreadable {
            system.skip_frame(k, k as f64 / 30.0, "skipped: corrupt image".into());
            continue;
        }
        let mut frame = sequence.read(k).unwrap().unwrap();
        let image = grey_mut(&mut frame);
        if k == black {
            image.data_mut().fill(0);
        } else if textureless.contains(&k) {
            image.data_mut().fill(128);
        }
        system.process(frame).unwrap();
    }
    let r = system.finish(false).unwrap();
    assert_eq!(
        r.record.frames.len(),
        indices.len(),
        "every frame is in the record"
    );
    let state = |k: usize| {
        &r.record
            .frames
            .iter()
            .find(|f| f.index == k)
            .expect("in the record")
            .state
    };
    let pose = |k: usize| {
        r.record
            .frames
            .iter()
            .find(|f| f.index == k)
            .and_then(|f| f.world_from_camera)
    };
    use data::output::TrackingState::Lost;
    assert!(
        matches!(state(black), Lost(why) if why.contains("corner tracks")),
        "black frame: {:?}",
        state(black)
    );
    // The next frame is tracked against the last good one, in the same map.
    assert!(pose(black + 1).is_some(), "{:?}", state(black + 1));
    assert!(matches!(state(unreadable), Lost(why) if why.contains("corrupt")));
    // After the short gap the camera is still tracked.
    assert!(
        pose(125).is_some() || pose(126).is_some(),
        "{:?}",
        state(125)
    );
    // The textureless stretch is refused frame by frame, then a new map starts, and the
    // camera is initialised again before the end.
    for k in textureless.clone() {
        assert!(matches!(state(k), Lost(_)), "frame {k}: {:?}", state(k));
    }
    // The new map has a frame and a scale of its own: the outputs hold one map, the one with
    // the more keyframes (here the first, from frame ~50 to 200, against the new one's 45
    // frames), and the new map's frames say where they were tracked.
    assert_eq!(r.new_maps.len(), 1, "{:?}", r.new_maps);
    let m = &r.new_maps[0];
    assert!(m.frame >= textureless.end && m.map == 1, "{m:?}");
    assert_eq!(r.world_map, slam::map::FIRST_MAP);
    for (f, report) in r.record.frames.iter().zip(&r.frames) {
        assert_eq!(f.state, report.state, "frame {}", f.index);
    }
    assert!(!m.joined && m.frames > 0, "{m:?}");
    use data::output::TrackingState::Weak;
    let in_new_map: Vec<usize> = (m.frame..260)
        .filter(|&k| matches!(state(k), Weak(w) if w.contains("tracked in map 1")))
        .collect();
    assert_eq!(
        in_new_map.len(),
        m.frames,
        "initialised again after the textureless stretch"
    );
    assert!(in_new_map.iter().all(|&k| pose(k).is_none()));
    let last_first_map = 200.0 / 30.0;
    assert!(
        r.final_trajectory
            .timestamps
            .iter()
            .all(|&t| t < last_first_map),
        "the final trajectory holds the first map's frames only"
    );
    assert!(
        r.warnings.iter().any(|w| w.contains("new map (map 1)")),
        "{:?}",
        r.warnings
    );
}

/// A camera that only rotates sees no parallax: depth is unobservable, so the bootstrap never
/// makes a map from it, and every frame says why (7-Scenes frame 0 rolled about the principal
/// point, 0.5° per frame — an exact pure rotation of a pinhole camera about its optical axis).
#[test]
fn a_purely_rotating_camera_is_never_initialised_and_says_why() {
    let Some(path) = paths::require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let sequence = Sequence::open(&path, &OpenOptions::default()).unwrap();
    let camera = *sequence.info().camera.pinhole();
    let first = sequence.read(0).unwrap().unwrap();
    let source = first.gray().clone();
    let mut system = mono(camera, SystemConfig::default(), "rotation", None);
    let (w, h) = (source.width(), source.height());
    for k in 0..40usize {
        let angle = (0.5 * k as f64).to_radians() as f32;
        let (c, s) = (angle.cos(), angle.sin());
        let (cx, cy) = (camera.cx as f32, camera.cy as f32);
        let mut image = vision::image::GrayImage::new(w, h);
        for v in 0..h {
            for u in 0..w {
                let (x, y) = (u as f32 - cx, v as f32 - cy);
                let (su, sv) = (c * x + s * y + cx, -s * x + c * y + cy);
                let value = vision::interp::bilinear(&source, su, sv).unwrap_or(0.0);
                image.set(u, v, value.round().clamp(0.0, 255.0) as u8);
            }
        }
        let mut frame = first.clone();
        frame.index = k;
        frame.timestamp = k as f64 / 30.0;
        *grey_mut(&mut frame) = image;
        let report = system.process(frame).unwrap();
        assert!(
            matches!(&report.state, data::output::TrackingState::Lost(why) if why.contains("initialising") || why.contains("parallax")),
            "frame {k}: {:?}",
            report.state
        );
    }
    let r = system.finish(false).unwrap();
    assert!(r.record.keyframes.is_empty(), "no map from a pure rotation");
    assert!(
        r.record
            .frames
            .iter()
            .all(|f| f.world_from_camera.is_none())
    );
}

/// 7-Scenes (`None` without the data) and a monocular system for it with `config` and the
/// shipped vocabulary, made by the returned function.
fn seven_scenes_with_loops() -> Option<(Sequence, impl Fn(SystemConfig) -> System)> {
    let path = paths::require("seven_scenes_redkitchen_1000")?;
    let sequence = Sequence::open(&path, &OpenOptions::default()).unwrap();
    let camera = *sequence.info().camera.pinhole();
    let vocabulary = std::sync::Arc::new(system::vocabulary::default_vocabulary().unwrap());
    let system = move |config| mono(camera, config, "cut", Some(vocabulary.clone()));
    Some((sequence, system))
}

/// A camera lost in a mapped place is relocalised in the same map (P3P against a keyframe's
/// points, then the guided search around that pose): 7-Scenes with frames 301–399 cut, as a
/// camera that looks away for three seconds. The tracks cannot follow across the cut, so
/// tracking is lost; the frames after it are tried against the keyframe database until one
/// shows a mapped place, and from there the camera tracks on in the first map — no new map,
/// and its poses after the loss agree with the ground truth under the similarity of its poses
/// before it (a new map would have a frame and a scale of its own) about as well as those of
/// a camera never lost (the same frames without the cut) do.
///
/// Two feature seeds (`mono.seed` 0 and 3): one run of a monocular sequence is one draw of a
/// chaotic estimate, and a bound met by one draw can be met by chance.
#[test]
fn a_lost_camera_is_relocalised_in_its_map_by_p3p() {
    let Some((sequence, new_system)) = seven_scenes_with_loops() else {
        return;
    };
    for seed in [0, 3] {
        relocalised_after_a_loss(&sequence, &new_system, seed);
    }
}

/// [`a_lost_camera_is_relocalised_in_its_map_by_p3p`] with feature seed `seed`.
fn relocalised_after_a_loss(
    sequence: &Sequence,
    new_system: &impl Fn(SystemConfig) -> System,
    seed: u64,
) {
    let mut truth = std::collections::HashMap::new();
    let mut config = SystemConfig::default();
    config.mono.seed = seed;
    let mut run = |indices: &[usize]| {
        let mut system = new_system(config.clone());
        for &k in indices {
            let frame = sequence.read(k).unwrap().unwrap();
            truth.insert(k, frame.world_from_camera.expect("ground truth"));
            system.process(frame).unwrap();
        }
        system.finish(false).unwrap()
    };
    let cut: Vec<usize> = (0..=300).chain(400..540).collect();
    let r = run(&cut);
    let never_lost = run(&(0..540).collect::<Vec<_>>());
    assert!(r.new_maps.is_empty(), "{:?}", r.new_maps);
    let first = r.relocalisations.first().expect("a relocalisation");
    println!("relocalisations: {:?}", r.relocalisations);
    assert!(
        first.frame >= 400 && first.keyframe_frame <= 300,
        "{first:?}"
    );
    assert!(
        first.ransac_inliers >= 20 && first.tracked >= 40,
        "{first:?}"
    );
    // The error after `from` under one similarity, fitted to the frames before the loss.
    let after_loss = |r: &RunResult, from: usize| {
        let posed: Vec<(usize, Se3)> = r
            .record
            .frames
            .iter()
            .filter_map(|f| Some((f.index, f.world_from_camera?)))
            .collect();
        let (before_truth, before_est): (Vec<Se3>, Vec<Se3>) = posed
            .iter()
            .filter(|(k, _)| *k <= 300)
            .map(|(k, p)| (truth[k], *p))
            .unzip();
        let fit = ate(&before_truth, &before_est, Alignment::Sim3).unwrap();
        let errors: Vec<f64> = posed
            .iter()
            .filter(|(k, _)| *k >= from)
            .map(|(k, e)| {
                (fit.reference_from_estimate.act(e.translation()) - truth[k].translation()).norm()
            })
            .collect();
        let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        (fit.translation.rmse, errors.len(), rmse)
    };
    let (before, n, relocalised) = after_loss(&r, first.frame);
    let (_, n_never, never) = after_loss(&never_lost, first.frame);
    println!(
        "seed {seed}: before the loss: ATE {:.2} cm; from frame {} on, under the same \
         similarity: {:.2} cm over {n} frames (never lost: {:.2} cm over {n_never})",
        before * 100.0,
        first.frame,
        relocalised * 100.0,
        never * 100.0
    );
    assert!(
        n * 10 >= (540 - first.frame) * 9,
        "{n} of the {} frames from the relocalisation on have a pose",
        540 - first.frame
    );
    assert!(
        relocalised <= 1.5 * never + 0.01,
        "seed {seed}: {relocalised} m, never lost {never} m"
    );
}

/// A camera that jumps to a mapped place is relocalised at the first frame after the jump, not
/// after `mono.max_refused` frames in which the tracks could not follow: 7-Scenes with frames
/// 301–619 cut, so that the camera lands where it was around frame 200 (PROVENANCE.md: frames
/// 136–205 are revisited at 616–680). Every frame from the jump on has a pose in the first map.
#[test]
fn a_camera_that_jumps_to_a_mapped_place_is_relocalised_at_once() {
    let Some((sequence, new_system)) = seven_scenes_with_loops() else {
        return;
    };
    let mut system = new_system(SystemConfig::default());
    let cut: Vec<usize> = (0..=300).chain(620..680).collect();
    let mut states = Vec::new();
    for &k in &cut {
        let report = system.process(sequence.read(k).unwrap().unwrap()).unwrap();
        states.push((k, report.state));
    }
    let r = system.finish(false).unwrap();
    println!("relocalisations: {:?}", r.relocalisations);
    assert!(r.new_maps.is_empty(), "{:?}", r.new_maps);
    let first = r.relocalisations.first().expect("a relocalisation");
    assert!(
        first.frame == 620 && first.keyframe_frame <= 300,
        "relocalised at frame {} (the jump lands at 620), in keyframe of frame {}",
        first.frame,
        first.keyframe_frame
    );
    let unposed: Vec<usize> = r
        .record
        .frames
        .iter()
        .filter(|f| f.index >= 620 && f.world_from_camera.is_none())
        .map(|f| f.index)
        .collect();
    assert!(
        unposed.is_empty(),
        "frames after the jump without a pose: {unposed:?}; states: {:?}",
        states
            .iter()
            .filter(|(k, _)| *k >= 620)
            .take(12)
            .collect::<Vec<_>>()
    );
}

/// Monocular maps joined by place recognition: the same 7-Scenes cut (frames 301–399), but with
/// `tracker.new_map_after` 0, so that the lost camera starts a new map at once instead of
/// relocalising. When the new map's keyframes come back to places of the first (the camera
/// sees the first map's side of the table again around frame 480), three agreeing Sim(3)
/// detections join the two maps: the final trajectory then holds the frames of both in one
/// world, about as accurately as the written map's own frames are alone (a wrong similarity
/// between the two worlds, in scale above all, would put the first map's frames metres off).
#[test]
fn a_new_monocular_map_is_joined_to_the_first_by_place_recognition() {
    let Some((sequence, new_system)) = seven_scenes_with_loops() else {
        return;
    };
    let mut config = SystemConfig::default();
    config.tracker.new_map_after = 0.0;
    let mut system = new_system(config);
    let mut truth = std::collections::HashMap::new();
    let cut: Vec<usize> = (0..=300).chain(400..sequence.len()).collect();
    for &k in &cut {
        let frame = sequence.read(k).unwrap().unwrap();
        truth.insert(
            frame.timestamp.to_bits(),
            frame.world_from_camera.expect("ground truth"),
        );
        system.process(frame).unwrap();
    }
    let r = system.finish(false).unwrap();
    println!("new maps: {:?}", r.new_maps);
    for w in &r.warnings {
        println!("{w}");
    }
    assert_eq!(r.new_maps.len(), 1, "{:?}", r.new_maps);
    assert!(r.new_maps[0].joined, "{:?}", r.new_maps);
    let merge = r
        .loops
        .iter()
        .find(|l| l.kind == "merge")
        .expect("a merge event");
    assert!(merge.frames.0 >= 400 && merge.frames.1 <= 300, "{merge:?}");
    // Sim(3) ATE of a trajectory's frames (those with ground truth).
    let score = |timestamps: &[f64], poses: &[Se3]| {
        let (r, e): (Vec<Se3>, Vec<Se3>) = timestamps
            .iter()
            .zip(poses)
            .filter_map(|(t, p)| Some((*truth.get(&t.to_bits())?, *p)))
            .unzip();
        (
            r.len(),
            ate(&r, &e, Alignment::Sim3).unwrap().translation.rmse,
        )
    };
    let t = &r.final_trajectory;
    let (joined, joined_ate) = score(&t.timestamps, &t.world_from_body);
    // The written map's frames alone: those after the loss.
    let lost_at = r.new_maps[0].frame;
    let first_new = cut.iter().position(|&k| k >= 400).unwrap();
    let alone: Vec<usize> = (0..t.timestamps.len())
        .filter(|&i| {
            r.record
                .frames
                .iter()
                .position(|f| f.timestamp == t.timestamps[i])
                .is_some_and(|p| p >= first_new)
        })
        .collect();
    let (n_alone, alone_ate) = score(
        &alone.iter().map(|&i| t.timestamps[i]).collect::<Vec<_>>(),
        &alone
            .iter()
            .map(|&i| t.world_from_body[i])
            .collect::<Vec<_>>(),
    );
    println!(
        "new map at frame {lost_at}; joined at frame {} to frame {}: final trajectory {joined} of \
         {} frames, ATE {:.2} cm; the written map's frames alone: {n_alone}, {:.2} cm",
        merge.frames.0,
        merge.frames.1,
        cut.len(),
        joined_ate * 100.0,
        alone_ate * 100.0
    );
    assert!(joined * 100 >= cut.len() * 95, "{joined} of {}", cut.len());
    assert!(joined >= n_alone + 250, "{joined} against {n_alone} alone");
    assert!(
        joined_ate <= 1.25 * alone_ate + 0.01,
        "{joined_ate} m joined, {alone_ate} m alone"
    );
}
