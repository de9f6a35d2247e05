//! The exploration's tests: simulated cameras and their tracks.

use super::*;
use crate::map::SharedGraph;
use crate::pose_graph::rigid_from_similarity;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Measurements per frame.
type Frames = Vec<Vec<(TrackId, Vector2<f64>)>>;

/// A simulated camera's true poses and its measurements per frame.
type Drive = (Vec<Se3>, Frames);

/// A camera sliding sideways (x) past a box of points 3–6 m ahead, `n` frames 4 cm apart,
/// measured with Gaussian pixel noise `sigma`: `(truth, measurements per frame)`.
fn sideways(seed: u64, n: usize, sigma: f64) -> Drive {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let points: Vec<Vector3<f64>> = (0..400)
        .map(|_| {
            Vector3::new(
                rng.random_range(-4.0..(4.0 + 0.04 * n as f64)),
                rng.random_range(-2.0..2.0),
                rng.random_range(3.0..6.0),
            )
        })
        .collect();
    moving(
        &mut rng,
        &points,
        Vector3::new(0.04, 0.0, 0.0),
        n,
        sigma,
        f64::INFINITY,
    )
}

/// A camera driving forward (z) down a street 12 m wide between walls of points from 5 m
/// ahead to 40 m beyond the end of the drive, `n` frames 50 cm apart.
fn forward(seed: u64, n: usize, sigma: f64) -> Drive {
    street(seed, n, sigma, 3000, f64::INFINITY)
}

/// [`forward`] with `count` points, each tracked only within `range` metres of the camera (a
/// corner tracker finds a façade's corners only once they are near enough): new tracks appear
/// ahead as the camera drives.
fn street(seed: u64, n: usize, sigma: f64, count: usize, range: f64) -> Drive {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let end = 0.5 * n as f64 + 40.0;
    let points: Vec<Vector3<f64>> = (0..count)
        .map(|_| {
            let side = if rng.random_bool(0.5) { -6.0 } else { 6.0 };
            Vector3::new(
                side + rng.random_range(-0.5..0.5),
                rng.random_range(-2.0..2.0),
                rng.random_range(5.0..end),
            )
        })
        .collect();
    moving(
        &mut rng,
        &points,
        Vector3::new(0.0, 0.0, 0.5),
        n,
        sigma,
        range,
    )
}

/// `points` measured with Gaussian pixel noise `sigma` by a camera whose centre moves by
/// `step` a frame for `n` frames (identity rotation), each where it is within `range` of the
/// camera's depth.
fn moving(
    rng: &mut ChaCha8Rng,
    points: &[Vector3<f64>],
    step: Vector3<f64>,
    n: usize,
    sigma: f64,
    range: f64,
) -> Drive {
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let noise = Normal::new(0.0, sigma).unwrap();
    let truth: Vec<Se3> = (0..n)
        .map(|k| Se3::from_translation(-step * k as f64))
        .collect();
    let frames = truth
        .iter()
        .map(|t| {
            points
                .iter()
                .enumerate()
                .filter_map(|(j, p)| {
                    let y = t.act(p);
                    if y.z > range {
                        return None;
                    }
                    let z = CameraModel::project(&camera, &y).ok()?;
                    (z.x >= 0.0 && z.x < 640.0 && z.y >= 0.0 && z.y < 480.0).then(|| {
                        (
                            j as TrackId,
                            z + Vector2::new(noise.sample(&mut *rng), noise.sample(&mut *rng)),
                        )
                    })
                })
                .collect()
        })
        .collect();
    (truth, frames)
}

fn explore(frames: &[Vec<(TrackId, Vector2<f64>)>], sigma: f64) -> (MonoExplorer, SlamGraph<2>) {
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let mut graph = SlamGraph::new();
    let mut explorer = MonoExplorer::new(
        camera,
        ExplorationConfig {
            sigma,
            ..ExplorationConfig::default()
        },
    );
    for (f, m) in frames.iter().enumerate() {
        explorer.process(&mut graph, f, m).unwrap();
    }
    (explorer, graph)
}

/// The live system's settings: covisible window, fixed older observers, outliers removed.
fn map_reuse(sigma: f64) -> ExplorationConfig {
    ExplorationConfig {
        sigma,
        local_window: LocalWindow::Covisible,
        fixed_observers: 10,
        remove_outliers: true,
        ..ExplorationConfig::default()
    }
}

/// [`sideways`] (seed 3, 100 frames, 0.5 px noise) with one track, a point seen from the
/// first frame to the last, jumping to another corner 15 px off its point (across the
/// direction of motion) from frame 60 on: the measurements and that track.
fn jumping_track() -> (Frames, TrackId) {
    let (_, mut frames) = sideways(3, 100, 0.5);
    let track = frames[0]
        .iter()
        .map(|(t, _)| *t)
        .find(|t| frames[99].iter().any(|(u, _)| u == t))
        .unwrap();
    for m in frames.iter_mut().skip(60) {
        for (t, z) in m.iter_mut() {
            if *t == track {
                z.y += 15.0;
            }
        }
    }
    (frames, track)
}

/// A track that jumps to another corner ([`jumping_track`]: no one point explains its
/// measurements before and after): with outliers removed, after the keyframe BA or the double
/// window, the map keeps only measurements of the point that agree with it (all within 3σ of
/// its projection); without, the keyframes keep both and contradict each other.
#[test]
fn a_track_that_jumps_off_its_point_leaves_no_contradiction_in_the_map() {
    let (frames, track) = jumping_track();
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let double_window = ExplorationConfig {
        double_window: Some(crate::dwo::DwoParams {
            kernel: Some(RobustKernel::Huber(2.0)),
            ..crate::dwo::DwoParams::new(20, 100, 500.0, 0.5)
        }),
        ..map_reuse(0.5)
    };
    for (config, removed) in [
        (map_reuse(0.5), true),
        (double_window, true),
        (ExplorationConfig::default(), false),
    ] {
        let config = ExplorationConfig {
            sigma: 0.5,
            ..config
        };
        let mut explorer = MonoExplorer::new(camera, config);
        let mut graph = SlamGraph::new();
        let mut point = None;
        for (f, m) in frames.iter().enumerate() {
            explorer.process(&mut graph, f, m).unwrap();
            if f == 59 {
                point = explorer.active().get(&track).copied();
            }
        }
        let point = point.expect("a map point by frame 59");
        let graph = &graph;
        let worst = graph.point(point).map_or(0.0, |pt| {
            let y = graph.point_world(point).unwrap();
            pt.observers()
                .iter()
                .map(|&k| {
                    let z = graph.keyframe(k).unwrap().observations()[&point];
                    let t = rigid_from_similarity(&graph.pose(k).unwrap());
                    (CameraModel::project(&camera, &t.act(&y)).unwrap() - z).norm()
                })
                .fold(0.0, f64::max)
        });
        println!("outliers removed {removed}: worst residual {worst:.2} px");
        if removed {
            assert!(worst <= 1.5, "{worst} px");
        } else {
            assert!(worst > 5.0, "{worst} px");
        }
    }
}

/// A measurement on probation ([`MonoExplorer::suspect`]) keeps its point where the frame's
/// pose explains it and loses it in that frame where it does not: the track that jumps 15 px
/// off its point at frame 60 ([`jumping_track`]), put on probation there with 20 honest
/// tracks, measures no point after frame 60, and the honest ones all keep theirs (noise
/// 0.5 px against σ = 1 px). Not on probation, the jumped track still measures its point
/// after frame 60 (a keyframe's BA finds it out later).
#[test]
fn a_measurement_on_probation_the_pose_does_not_explain_loses_its_point() {
    let (frames, track) = jumping_track();
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    for probation in [true, false] {
        let mut explorer = MonoExplorer::new(camera, map_reuse(1.0));
        let mut graph = SlamGraph::new();
        let mut honest: Vec<TrackId> = Vec::new();
        for (f, m) in frames.iter().enumerate().take(61) {
            if f == 60 {
                assert!(explorer.active().contains_key(&track));
                honest = explorer
                    .active()
                    .keys()
                    .copied()
                    .filter(|t| *t != track)
                    .collect();
                honest.sort_unstable();
                honest.truncate(20);
                assert_eq!(honest.len(), 20);
                if probation {
                    explorer.suspect(track);
                    honest.iter().for_each(|t| explorer.suspect(*t));
                }
            }
            explorer.process(&mut graph, f, m).unwrap();
        }
        let active = explorer.active();
        assert_eq!(
            active.contains_key(&track),
            !probation,
            "probation {probation}"
        );
        let kept = honest.iter().filter(|t| active.contains_key(t)).count();
        assert_eq!(kept, 20, "probation {probation}");
    }
}

/// The measurements on probation are judged by the pose of the trusted ones: at frame 60 of
/// [`sideways`] every tracked point but 20 is on probation and all of those but 20 more are
/// measured 6 px off (as if a majority had jumped together — a pose solved with them in it
/// would turn to explain them and refuse the honest ones). Every jumped measurement loses its
/// point in that frame; the 20 trusted and the 20 honest measurements on probation keep theirs.
#[test]
fn measurements_on_probation_are_judged_by_the_pose_of_the_trusted_ones() {
    let (_, mut frames) = sideways(3, 100, 0.5);
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let mut explorer = MonoExplorer::new(camera, map_reuse(1.0));
    let mut graph = SlamGraph::new();
    for (f, m) in frames.iter().enumerate().take(60) {
        explorer.process(&mut graph, f, m).unwrap();
    }
    let mut tracked: Vec<TrackId> = explorer.active().keys().copied().collect();
    tracked.sort_unstable();
    assert!(tracked.len() >= 100, "{} points tracked", tracked.len());
    let (trusted, suspects) = tracked.split_at(20);
    let (honest, jumped) = suspects.split_at(20);
    suspects.iter().for_each(|t| explorer.suspect(*t));
    for (t, z) in frames[60].iter_mut() {
        if jumped.contains(t) {
            z.y += 6.0;
        }
    }
    explorer.process(&mut graph, 60, &frames[60]).unwrap();
    let active = explorer.active();
    let kept = |ts: &[TrackId]| ts.iter().filter(|t| active.contains_key(t)).count();
    assert_eq!(kept(jumped), 0, "of {} jumped", jumped.len());
    assert_eq!(kept(honest), 20);
    assert_eq!(kept(trusted), 20);
}

/// A camera lost for ten frames, whose tracks all die, found again by P3P RANSAC against
/// the map's points (`geom::pnp`) and relocalised there: it tracks on in the same map with
/// new tracks (associated with the points they see), and after the gap it is where the
/// map's frame and scale (from the path before the gap) put the ground truth, as closely
/// as a camera never lost (the same frames without the gap) is.
#[test]
fn a_lost_camera_relocalised_by_p3p_tracks_on_in_the_same_map() {
    let (truth, frames) = sideways(5, 100, 0.5);
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let mut explorer = MonoExplorer::new(camera, map_reuse(0.5));
    let mut graph = SlamGraph::new();
    assert!(!explorer.relocalise(0, Se3::identity()), "no map yet");
    for (f, m) in frames.iter().enumerate().take(60) {
        explorer.process(&mut graph, f, m).unwrap();
    }
    // Frame 60 measures nothing (tracking is lost: the exploration stops tracking),
    // 61–69 are not given; from 70 on every track is new (ids + 10 000).
    assert!(matches!(
        explorer.process(&mut graph, 60, &[]),
        Err(ExplorationError::TrackingLost { frame: 60, .. })
    ));
    const NEW: TrackId = 10_000;
    let renamed: Vec<Vec<(TrackId, Vector2<f64>)>> = frames[70..]
        .iter()
        .map(|m| m.iter().map(|&(t, z)| (t + NEW, z)).collect())
        .collect();
    let point_of: HashMap<TrackId, PointId> = graph
        .points()
        .map(|(p, _)| (explorer.map().track(p), p))
        .collect();
    let seen: Vec<(TrackId, PointId, Vector2<f64>)> = renamed[0]
        .iter()
        .filter_map(|&(t, z)| point_of.get(&(t - NEW)).map(|&p| (t, p, z)))
        .collect();
    let normalised: Vec<Vector2<f64>> = seen
        .iter()
        .map(|(_, _, z)| camera.normalised_from_pixel(z))
        .collect();
    let points: Vec<Vector3<f64>> = seen
        .iter()
        .map(|(_, p, _)| graph.point_world(*p).unwrap())
        .collect();
    let sigma = vec![0.5 / 500.0; seen.len()];
    let pnp = geom::pnp::PnpEstimator {
        normalised: &normalised,
        points: &points,
        sigma: &sigma,
    };
    let found = geom::ransac::ransac(
        &pnp,
        &RansacConfig {
            threshold: 3.03,
            ..RansacConfig::default()
        },
    )
    .unwrap();
    assert!(found.inliers.len() >= 20, "{} inliers", found.inliers.len());
    assert!(explorer.relocalise(70, found.model));
    assert!(explorer.active().is_empty());
    for (t, p, _) in &seen {
        assert!(explorer.associate(&graph, *t, *p));
    }
    for (i, m) in renamed.iter().enumerate() {
        let o = explorer
            .process(&mut graph, 70 + i, m)
            .unwrap_or_else(|e| panic!("frame {}: {e}", 70 + i));
        assert!(o.tracked >= 20, "frame {}: {} tracked", 70 + i, o.tracked);
    }
    // The true centres in the map's frame and scale, by the first tracked frame's pose
    // and the scale of the path before the gap: after it, the camera is where the map
    // before it puts it, as far as it is for a camera never lost (the same frames without
    // the gap: the monocular drift of this sequence).
    let worst = |poses: &[(usize, Se3)]| {
        let (first, t_first) = poses[0];
        let (before, t_before) = *poses.iter().rfind(|(f, _)| *f < 60).unwrap();
        let scale = (centre(&t_before) - centre(&t_first)).norm()
            / (centre(&truth[before]) - centre(&truth[first])).norm();
        let in_map = |c: &Vector3<f64>| t_first.inverse().act(&(truth[first].act(c) * scale));
        poses
            .iter()
            .filter(|(f, _)| *f >= 70)
            .map(|(f, t)| (centre(t) - in_map(&centre(&truth[*f]))).norm() / scale)
            .fold(0.0, f64::max)
    };
    let poses = explorer.frame_poses(&graph);
    assert_eq!(poses.iter().filter(|(f, _)| *f >= 70).count(), 30);
    let relocalised = worst(&poses);
    let mut plain = MonoExplorer::new(camera, map_reuse(0.5));
    let mut plain_graph = SlamGraph::new();
    for (f, m) in frames.iter().enumerate() {
        plain.process(&mut plain_graph, f, m).unwrap();
    }
    let never_lost = worst(&plain.frame_poses(&plain_graph));
    println!(
        "worst centre error after the gap: relocalised {relocalised:.4} m, never lost \
         {never_lost:.4} m (4 m path)"
    );
    assert!(relocalised <= 1.5 * never_lost + 0.005, "{relocalised} m");
}

/// With the keyframe criterion of coverage (`keyframe_rotation`), a camera that walks back
/// along a mapped path adds no keyframes: its view is covered by the keyframes of the way
/// out, which measure the points it tracks. By distance from the last keyframe alone it
/// adds as many on the way back as on the way out.
#[test]
fn a_camera_walking_back_over_its_map_adds_no_keyframes_where_keyframes_cover_its_view() {
    let (_, out) = sideways(4, 80, 0.5);
    // Back along the same poses (the same measurements in reverse order).
    let frames: Vec<_> = out
        .iter()
        .chain(out.iter().rev().skip(1))
        .cloned()
        .collect();
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let added_back = |config: ExplorationConfig| {
        let mut explorer = MonoExplorer::new(camera, config);
        let mut graph = SlamGraph::new();
        let mut back = 0;
        for (f, m) in frames.iter().enumerate() {
            let o = explorer
                .process(&mut graph, f, m)
                .unwrap_or_else(|e| panic!("frame {f}: {e}"));
            back += usize::from(f >= 85 && o.keyframe.is_some());
        }
        back
    };
    let by_distance = added_back(map_reuse(0.5));
    let by_coverage = added_back(ExplorationConfig {
        keyframe_rotation: Some(10f64.to_radians()),
        ..map_reuse(0.5)
    });
    println!("keyframes on the way back: {by_distance} by distance, {by_coverage} by coverage");
    assert!(by_distance >= 5, "{by_distance}");
    assert!(
        by_coverage <= 1,
        "{by_coverage} (by distance: {by_distance})"
    );
}

/// Keyframes by parallax ([`KeyframeBaseline::Parallax`]): a camera sliding sideways gets
/// about as many as by distance over the scene depth (the two measures agree for it), one
/// driving forward far fewer (its points near the direction of travel gain no parallax),
/// and both trajectories are recovered.
#[test]
fn keyframes_by_parallax_are_sparser_only_for_forward_motion() {
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let run = |(truth, frames): &Drive, baseline| {
        let mut explorer = MonoExplorer::new(
            camera,
            ExplorationConfig {
                keyframe_baseline: baseline,
                keyframe_rotation: Some(10f64.to_radians()),
                ..map_reuse(0.5)
            },
        );
        let mut graph = SlamGraph::new();
        let mut reasons = Vec::new();
        for (f, m) in frames.iter().enumerate() {
            let o = explorer
                .process(&mut graph, f, m)
                .unwrap_or_else(|e| panic!("frame {f}: {e}"));
            assert!(
                o.keyframe.is_some() || o.keyframe_reason.is_none(),
                "frame {f}"
            );
            if o.keyframe.is_some() {
                reasons.push(o.keyframe_reason);
            }
        }
        // Every keyframe after the bootstrap's says why it was made, and the reason is the
        // criterion's: a baseline beyond its threshold, a map thinned below its fraction.
        let bootstrap = reasons.iter().take_while(|r| r.is_none()).count();
        assert_eq!(bootstrap, 1, "{reasons:?}");
        for r in &reasons[bootstrap..] {
            match r.expect("a keyframe after the bootstrap has a reason") {
                ExplorationKeyframe::Baseline(b) => assert!(b > 1.0, "{r:?}"),
                ExplorationKeyframe::Thinning(f) => assert!(
                    f < ExplorationConfig::default().keyframe_min_tracked_fraction,
                    "{r:?}"
                ),
                ExplorationKeyframe::Rotation(_) | ExplorationKeyframe::FewTracked(_) => {
                    panic!("no turn, points enough: {r:?}")
                }
            }
        }
        // Sim(3)-aligned centre error over the path.
        let poses = explorer.frame_poses(&graph);
        let est: Vec<Se3> = poses.iter().map(|(_, t)| *t).collect();
        let gt: Vec<Se3> = poses.iter().map(|(f, _)| truth[*f]).collect();
        let c = |t: &Se3| t.inverse().act(&Vector3::zeros());
        let (e0, g0) = (c(&est[0]), c(&gt[0]));
        let (e1, g1) = (c(est.last().unwrap()), c(gt.last().unwrap()));
        let scale = (g1 - g0).norm() / (e1 - e0).norm();
        let error = est
            .iter()
            .zip(&gt)
            .map(|(e, g)| ((c(e) - e0) * scale - (c(g) - g0)).norm())
            .fold(0.0, f64::max);
        (explorer.map().keyframes.len(), error / (g1 - g0).norm())
    };
    let side = sideways(5, 100, 0.5);
    let ahead = forward(5, 100, 0.5);
    let (side_d, side_d_err) = run(&side, KeyframeBaseline::Distance);
    let (side_p, side_p_err) = run(&side, KeyframeBaseline::Parallax);
    let (ahead_d, ahead_d_err) = run(&ahead, KeyframeBaseline::Distance);
    let (ahead_p, ahead_p_err) = run(&ahead, KeyframeBaseline::Parallax);
    println!(
        "keyframes sideways {side_d} by distance, {side_p} by parallax (worst error \
         {side_d_err:.4} / {side_p_err:.4} of the path); forward {ahead_d}, {ahead_p} \
         ({ahead_d_err:.4} / {ahead_p_err:.4})"
    );
    assert!(
        (side_p as f64) >= 0.7 * side_d as f64 && (side_p as f64) <= 1.3 * side_d as f64,
        "sideways: {side_p} by parallax, {side_d} by distance"
    );
    assert!(
        (ahead_p as f64) <= 0.5 * ahead_d as f64,
        "forward: {ahead_p} by parallax, {ahead_d} by distance"
    );
    for e in [side_d_err, side_p_err, ahead_d_err, ahead_p_err] {
        assert!(e < 0.02, "{e}");
    }
}

/// A feature's history ([`ExplorationConfig::feature_history`]) on a forward drive: a feature
/// started in a keyframe takes in its track's first measurement since the keyframe before, so
/// the points a keyframe makes are measured in the keyframe before too (their anchors' elder
/// neighbours), the filters converge sooner (fewer run at a time), the frames measure more map
/// points, and the path is recovered as well.
#[test]
fn features_take_in_their_tracks_measurements_since_the_last_keyframe() {
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let (truth, frames) = street(7, 80, 0.5, 1000, 25.0);
    let run = |feature_history| {
        let mut explorer = MonoExplorer::new(
            camera,
            ExplorationConfig {
                feature_history,
                ..map_reuse(0.5)
            },
        );
        let mut graph = SlamGraph::new();
        let (mut tracked, mut filters) = (Vec::new(), Vec::new());
        for (f, m) in frames.iter().enumerate() {
            let o = explorer
                .process(&mut graph, f, m)
                .unwrap_or_else(|e| panic!("frame {f}: {e}"));
            if o.camera_from_world.is_some() {
                tracked.push(o.tracked as f64);
                filters.push(o.filters as f64);
            }
        }
        // Points measured in a keyframe older than their anchor.
        let elder = graph
            .points()
            .filter(|(_, pt)| pt.observers().iter().any(|&k| k < pt.anchor()))
            .count();
        let poses = explorer.frame_poses(&graph);
        let c = |t: &Se3| t.inverse().act(&Vector3::zeros());
        let (e0, g0) = (c(&poses[0].1), c(&truth[poses[0].0]));
        let (last, t_last) = poses.last().unwrap();
        let scale = (c(&truth[*last]) - g0).norm() / (c(t_last) - e0).norm();
        let error = poses
            .iter()
            .map(|(f, t)| ((c(t) - e0) * scale - (c(&truth[*f]) - g0)).norm())
            .fold(0.0, f64::max)
            / (c(&truth[*last]) - g0).norm();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        (elder, mean(&tracked), mean(&filters), error)
    };
    let (elder_without, tracked_without, filters_without, error_without) = run(false);
    let (elder_with, tracked_with, filters_with, error_with) = run(true);
    println!(
        "points measured before their anchor {elder_without} / {elder_with}, map points per \
         frame {tracked_without:.1} / {tracked_with:.1}, filters {filters_without:.1} / \
         {filters_with:.1}, worst error {error_without:.4} / {error_with:.4} of the path \
         (without / with the history)"
    );
    assert_eq!(elder_without, 0);
    assert!(elder_with >= 100, "{elder_with}");
    // The filters converge sooner: fewer run at a time, and the map points they become are
    // measured sooner.
    assert!(
        filters_with <= 0.75 * filters_without,
        "{filters_with} {filters_without}"
    );
    assert!(
        tracked_with > tracked_without,
        "{tracked_with} {tracked_without}"
    );
    assert!(
        error_with < 0.02 && error_without < 0.02,
        "{error_with} {error_without}"
    );
}

/// A correction that rescales the whole map by `a` (every keyframe `S ← S·diag(1/a)`, the
/// points follow their anchors): the motion model follows it exactly, and exploring on
/// gives the trajectory of the uncorrected run scaled by `a`.
#[test]
fn exploration_goes_on_in_a_corrected_map() {
    let (_, frames) = sideways(2, 120, 0.5);
    let a = 2.0;
    let (plain, plain_graph) = explore(&frames, 0.5);
    let (mut explorer, mut graph) = explore(&frames[..60], 0.5);
    let before = explorer.predicted_pose(60).unwrap();
    explorer
        .correct_map(&mut graph, |g| {
            let ids: Vec<KeyframeId> = g.keyframes().map(|(k, _)| k).collect();
            for k in ids {
                let s = g
                    .pose(k)?
                    .compose(&Sim3::new(lie::So3::identity(), Vector3::zeros(), 1.0 / a).unwrap());
                g.set_pose(k, s)?;
            }
            Ok::<(), crate::map::GraphError>(())
        })
        .unwrap();
    assert_eq!(explorer.num_filters(), 0);
    let after = explorer.predicted_pose(60).unwrap();
    assert!((centre(&after) - a * centre(&before)).norm() < 1e-9);
    assert!((after.rotation().log() - before.rotation().log()).norm() < 1e-12);
    for (f, m) in frames.iter().enumerate().skip(60) {
        explorer.process(&mut graph, f, m).unwrap();
    }
    let (p, q) = (
        plain.frame_poses(&plain_graph),
        explorer.frame_poses(&graph),
    );
    assert_eq!(p.len(), q.len());
    let path = (centre(&p[p.len() - 1].1) - centre(&p[0].1)).norm();
    for ((f, x), (g, y)) in p.iter().zip(&q).filter(|((f, _), _)| *f >= 60) {
        assert_eq!(f, g);
        let error = (centre(y) / a - centre(x)).norm();
        assert!(error < 0.02 * path, "{error} of a {path} path");
    }
}

/// Bootstrap, tracking, keyframes, feature initialisation and window BA on a sideways
/// motion: the trajectory is recovered up to the monocular scale, features are promoted to
/// the map, and the same input gives the same output.
#[test]
fn sideways_exploration_recovers_the_trajectory_up_to_scale() {
    let (truth, frames) = sideways(1, 120, 0.5);
    let (explorer, graph) = explore(&frames, 0.5);
    let poses = explorer.frame_poses(&graph);
    assert!(poses.len() > 100, "{} frames tracked", poses.len());
    assert!(explorer.map().keyframes.len() >= 10);
    // Map points beyond the bootstrap's: promoted by the filters.
    let promoted = graph
        .points()
        .filter(|(_, p)| p.anchor() != KeyframeId(0))
        .count();
    assert!(promoted > 50, "{promoted} promoted features");
    // Camera centres relative to the first, best scale: small error.
    let first = poses[0].0;
    let c_true: Vec<Vector3<f64>> = poses
        .iter()
        .map(|(f, _)| centre(&truth[*f]) - centre(&truth[first]))
        .collect();
    let c_est: Vec<Vector3<f64>> = poses
        .iter()
        .map(|(_, t)| centre(t) - centre(&poses[0].1))
        .collect();
    let s = c_true
        .iter()
        .zip(&c_est)
        .map(|(a, b)| a.dot(b))
        .sum::<f64>()
        / c_est.iter().map(|b| b.norm_squared()).sum::<f64>();
    let rmse = (c_true
        .iter()
        .zip(&c_est)
        .map(|(a, b)| (a - s * b).norm_squared())
        .sum::<f64>()
        / c_true.len() as f64)
        .sqrt();
    let length = (c_true.last().unwrap()).norm();
    assert!(rmse < 0.01 * length, "rmse {rmse} over {length} m");
    // Deterministic.
    let (again, again_graph) = explore(&frames, 0.5);
    assert_eq!(again.frame_poses(&again_graph), poses);
    let points = |g: &SlamGraph<2>| -> Vec<_> {
        g.points()
            .map(|(p, pt)| (p, pt.anchor(), *pt.inverse_depth()))
            .collect()
    };
    assert_eq!(points(&again_graph), points(&graph));
    graph.check_invariants().unwrap();
}

#[test]
fn frames_out_of_order_and_lost_tracking_are_errors() {
    let (_, frames) = sideways(2, 30, 0.5);
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let mut explorer = MonoExplorer::new(camera, ExplorationConfig::default());
    let mut graph = SlamGraph::new();
    for (f, m) in frames.iter().enumerate() {
        explorer.process(&mut graph, f, m).unwrap();
    }
    assert!(matches!(
        explorer.process(&mut graph, 3, &frames[3]),
        Err(ExplorationError::FrameOrder { .. })
    ));
    assert!(matches!(
        explorer.process(&mut graph, 100, &[]),
        Err(ExplorationError::TrackingLost { .. })
    ));
    // No parallax at all: the bootstrap gives up with a reason.
    let mut still = MonoExplorer::new(
        camera,
        ExplorationConfig {
            max_bootstrap_frames: 5,
            ..ExplorationConfig::default()
        },
    );
    let mut result = Ok(());
    let mut graph = SlamGraph::new();
    for f in 0..10 {
        if let Err(e) = still.process(&mut graph, f, &frames[0]) {
            result = Err(e);
            break;
        }
    }
    assert!(matches!(
        result,
        Err(ExplorationError::BootstrapFailed { .. })
    ));
}

/// A graph that logs how the exploration takes it: `w` for a write, `r` for a read.
struct Logged<'a> {
    graph: &'a mut SlamGraph<2>,
    log: String,
}

impl GraphAccess<2> for Logged<'_> {
    fn read(&mut self) -> impl std::ops::Deref<Target = SlamGraph<2>> + '_ {
        self.log.push('r');
        &*self.graph
    }

    fn write(&mut self) -> impl std::ops::DerefMut<Target = SlamGraph<2>> + '_ {
        self.log.push('w');
        &mut *self.graph
    }
}

/// A keyframe's window — the keyframe BA or the double window — is solved with no lock on
/// the graph: a frame is tracked and a keyframe registered under one write, the window copied
/// out under a read and written back under a write (so that the loop closer and a viewer read
/// the graph meanwhile); on a shared graph, with another thread reading it all along, the map
/// is the same as on a graph the explorer owns.
#[test]
fn a_keyframe_window_is_solved_with_no_lock_held() {
    let (_, frames) = sideways(3, 60, 0.5);
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let double_window = ExplorationConfig {
        double_window: Some(crate::dwo::DwoParams::new(10, 20, 500.0, 0.5)),
        ..map_reuse(0.5)
    };
    for config in [map_reuse(0.5), double_window] {
        let dwo = config.double_window.is_some();
        let mut owned = SlamGraph::new();
        let mut explorer = MonoExplorer::new(camera, config.clone());
        let mut keyframes = 0;
        for (f, m) in frames.iter().enumerate() {
            let mut logged = Logged {
                graph: &mut owned,
                log: String::new(),
            };
            let outcome = explorer.process(&mut logged, f, m).unwrap();
            let after_bootstrap = explorer.map().keyframes.len() > 2;
            match outcome.keyframe {
                Some(_) if after_bootstrap => {
                    keyframes += 1;
                    // The tracking's write; the window read, solved, written back (the double
                    // window writes its optimum back itself, then removes outliers and moves
                    // the filters' anchors under one more write).
                    let expected = if dwo { "wrww" } else { "wrw" };
                    assert_eq!(logged.log, expected, "frame {f}");
                }
                None if outcome.camera_from_world.is_some() => {
                    assert_eq!(logged.log, "w", "frame {f}")
                }
                _ => {}
            }
        }
        assert!(keyframes >= 5, "{keyframes} keyframes");
        let shared = SharedGraph::new(SlamGraph::new());
        let mut explorer = MonoExplorer::new(camera, config);
        let done = std::sync::atomic::AtomicBool::new(false);
        let reads = std::thread::scope(|s| {
            let reader = s.spawn(|| {
                let mut reads = 0usize;
                while !done.load(std::sync::atomic::Ordering::SeqCst) {
                    reads += shared.read().num_points().min(1);
                    std::thread::yield_now();
                }
                reads
            });
            for (f, m) in frames.iter().enumerate() {
                explorer.process(&shared, f, m).unwrap();
            }
            done.store(true, std::sync::atomic::Ordering::SeqCst);
            reader.join().unwrap()
        });
        assert!(reads > 0, "the reader never saw the map");
        let points = |g: &SlamGraph<2>| -> Vec<_> {
            g.points()
                .map(|(p, pt)| (p, pt.anchor(), *pt.inverse_depth()))
                .collect()
        };
        let shared = shared.into_inner();
        assert_eq!(points(&shared), points(&owned), "double window: {dwo}");
        let poses = |g: &SlamGraph<2>| -> Vec<_> {
            g.keyframes()
                .map(|(k, kf)| (k, *kf.camera_from_world()))
                .collect()
        };
        assert_eq!(poses(&shared), poses(&owned), "double window: {dwo}");
    }
}

/// A keyframe's window — its BA or the double window — left to the caller (`defer_windows`)
/// and solved in another thread gives the same map as the one the explorer solves itself; a
/// BA window whose keyframes moved meanwhile (a loop corrected) is stale and writes nothing.
#[test]
fn a_deferred_window_solved_in_another_thread_gives_the_same_map() {
    let (_, frames) = sideways(3, 60, 0.5);
    let camera = PinholeCamera::new(500.0, 500.0, 320.0, 240.0);
    let map = |g: &SlamGraph<2>| -> (Vec<_>, Vec<_>) {
        (
            g.keyframes()
                .map(|(k, kf)| (k, *kf.camera_from_world()))
                .collect(),
            g.points()
                .map(|(p, pt)| (p, pt.anchor(), *pt.inverse_depth()))
                .collect(),
        )
    };
    let double_window = ExplorationConfig {
        double_window: Some(crate::dwo::DwoParams::new(10, 20, 500.0, 0.5)),
        ..map_reuse(0.5)
    };
    for config in [map_reuse(0.5), double_window] {
        deferred_windows_give_the_same_map(camera, &frames, config, map);
    }

    // A window whose keyframe moved between reading and writing back is stale.
    let mut graph = SlamGraph::new();
    let mut explorer = MonoExplorer::new(camera, map_reuse(0.5));
    explorer.defer_windows(true);
    let mut stale = 0;
    for (f, m) in frames.iter().enumerate() {
        let o = explorer.process(&mut graph, f, m).unwrap();
        let Some(job) = o.window else {
            continue;
        };
        let solved = job.solve(&mut graph).unwrap();
        if explorer.map().keyframes.len() > 4 {
            let k = job.keyframe();
            let moved = Sim3::from_se3(&Se3::exp(&nalgebra::Vector6::new(
                0.01, 0.0, 0.0, 0.0, 0.0, 0.0,
            )))
            .compose(&graph.pose(k).unwrap());
            graph.set_pose(k, moved).unwrap();
            let before = map(&graph);
            assert_eq!(explorer.apply_window(&mut graph, solved).unwrap(), None);
            assert_eq!(map(&graph), before, "a stale window writes nothing");
            stale += 1;
        } else {
            explorer.apply_window(&mut graph, solved).unwrap();
        }
    }
    assert!(stale >= 3, "{stale} stale windows");
}

/// The map of `frames` with `config`, its windows solved by the explorer and, deferred, in
/// another thread: the same frames' poses and the same `map`.
fn deferred_windows_give_the_same_map<M: PartialEq + std::fmt::Debug>(
    camera: PinholeCamera,
    frames: &[Vec<(TrackId, Vector2<f64>)>],
    config: ExplorationConfig,
    map: impl Fn(&SlamGraph<2>) -> M,
) {
    let mut owned = SlamGraph::new();
    let mut explorer = MonoExplorer::new(camera, config.clone());
    let mut inline_poses = Vec::new();
    for (f, m) in frames.iter().enumerate() {
        let o = explorer.process(&mut owned, f, m).unwrap();
        assert!(o.window.is_none());
        inline_poses.push(o.camera_from_world);
    }
    let shared = SharedGraph::new(SlamGraph::new());
    let mut deferred = MonoExplorer::new(camera, config);
    deferred.defer_windows(true);
    let mut solved_elsewhere = 0;
    for (f, m) in frames.iter().enumerate() {
        let mut o = deferred.process(&shared, f, m).unwrap();
        if let Some(job) = o.window.take() {
            assert_eq!(Some(job.keyframe()), o.keyframe);
            let solved = std::thread::scope(|s| s.spawn(|| job.solve(&shared)).join())
                .unwrap()
                .unwrap();
            let pose = deferred
                .apply_window(&mut shared.write(), solved)
                .unwrap()
                .expect("nothing moved the window meanwhile");
            o.camera_from_world = Some(pose);
            solved_elsewhere += 1;
        }
        assert_eq!(o.camera_from_world, inline_poses[f], "frame {f}");
    }
    assert!(solved_elsewhere >= 5, "{solved_elsewhere} windows");
    let shared = shared.into_inner();
    assert_eq!(map(&shared), map(&owned));
}
