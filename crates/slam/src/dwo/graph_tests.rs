//! The double window on graphs: windows, marginalisation, the optimum, concurrency with
//! tracking and loop corrections.

use super::*;
use crate::map::SharedGraph;
use geom::{PinholeCamera, StereoCamera};
use lie::Se3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// `n` stereo keyframes moving sideways in front of a wall of points, perturbed; every
/// point anchored in the first keyframe that sees it; edges by covisibility.
fn wall_graph(seed: u64, n: usize) -> (SlamGraph<3>, StereoCamera, Vec<Se3>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let cam = StereoCamera::new(PinholeCamera::new(300.0, 300.0, 320.0, 240.0), 0.1);
    let truth: Vec<Se3> = (0..n)
        .map(|k| Se3::from_translation(Vector3::new(-0.2 * k as f64, 0.0, 0.0)))
        .collect();
    let points: Vec<Vector3<f64>> = (0..400)
        .map(|_| {
            Vector3::new(
                rng.random_range(-2.0..0.5 * n as f64 + 2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(2.5..3.5),
            )
        })
        .collect();
    let mut g = SlamGraph::<3>::new();
    let mut ids: Vec<Option<PointId>> = vec![None; points.len()];
    for t in truth.iter() {
        let noise = SVector::<f64, 7>::from_fn(|i, _| {
            if i < 6 {
                rng.random_range(-0.01..0.01)
            } else {
                0.0
            }
        });
        let kf = g.add_keyframe(Sim3::exp(&noise).compose(&Sim3::from_se3(t)));
        for (w, p) in points.iter().enumerate() {
            let x = t.act(p);
            let Some((z, _)) = Projector::<3>::project(&cam, &x) else {
                continue;
            };
            if !(0.0..640.0).contains(&z.x)
                || !(0.0..480.0).contains(&z.y)
                || !(0.0..640.0).contains(&z.z)
            {
                continue;
            }
            let z = z + Vector3::from_fn(|_, _| rng.random_range(-0.5..0.5));
            match ids[w] {
                Some(id) => g.add_observation(kf, id, z).unwrap(),
                None => {
                    let psi = Vector3::new(x.x / x.z, x.y / x.z, 1.0 / x.z)
                        * (1.0 + rng.random_range(-0.05..0.05));
                    ids[w] = Some(g.add_point(kf, psi, z).unwrap());
                }
            }
        }
        let previous = kf.index().checked_sub(1).map(KeyframeId::from_index);
        crate::mapping::register_locally(&mut g, kf, 15, previous).unwrap();
        g.set_reference(kf).unwrap();
    }
    g.check_invariants().unwrap();
    (g, cam, truth)
}

#[test]
fn windows_constraints_and_marginalisation_follow_the_thesis() {
    let (mut g, cam, _) = wall_graph(1, 30);
    let mut dwo = DoubleWindowOptimiser::new(DwoParams::new(5, 10, 300.0, 0.5));
    let stats = dwo.optimise(&mut g, &cam).unwrap();
    assert_eq!(stats.inner_frames, 5);
    assert!(stats.outer_frames >= 10);
    assert!(stats.pose_constraints > 0 && stats.point_constraints > 0);
    assert!(stats.cost_after < stats.cost_before);
    g.check_invariants().unwrap();
    // Inner-window edges are not marginalised; edges with an end outside the inner window
    // of this optimisation that were inner before keep a stored pose.
    for &a in &dwo.previous.inner {
        for &b in &dwo.previous.inner {
            if let Some(e) = g.edge(a, b) {
                assert!(
                    e.relative.is_none(),
                    "edge {a}–{b} inside W1 is marginalised"
                );
            }
        }
    }
    // Move the reference back: the old inner window's edges leaving W1 are marginalised.
    let old_inner = dwo.previous.inner.clone();
    g.set_reference(KeyframeId(3)).unwrap();
    let plan = dwo.plan(&g).unwrap();
    // Every keyframe entering the window (and not the root) is re-initialised along the
    // spanning tree (thesis eq. 6.3).
    for k in &plan.tree.order {
        if !dwo.previous.contains(*k) && plan.tree.parent[k].is_some() {
            assert!(
                plan.reinitialised.contains(k),
                "keyframe {k} entered the window but was not re-initialised"
            );
        }
    }
    dwo.optimise(&mut g, &cam).unwrap();
    for &a in &old_inner {
        for &b in &old_inner {
            if let Some(e) = g.edge(a, b) {
                let now_inner = dwo.previous.inner.contains(&a) && dwo.previous.inner.contains(&b);
                assert_eq!(e.relative.is_none(), now_inner, "edge {a}–{b}");
            }
        }
    }
    g.check_invariants().unwrap();
}

#[test]
fn marginal_constraint_information_is_the_inverse_covariance_of_a_two_view_problem() {
    // An independent path: the least-squares engine's marginal covariance of `T_j` in the
    // problem of the constraint's points observed from `T_i` (fixed) and `T_j`, through
    // the window's own factors (anchored inverse depth; anchors other than `i`, `j`
    // fixed), each point's observations with information `w/σ²`.
    let (mut g, cam, _) = wall_graph(4, 30);
    let mut params = DwoParams::new(5, 10, 300.0, 0.5);
    params.information = ConstraintInformation::Marginal;
    let mut dwo = DoubleWindowOptimiser::new(params);
    dwo.optimise(&mut g, &cam).unwrap();
    g.set_reference(KeyframeId(3)).unwrap();
    let plan = dwo.plan(&g).unwrap();
    let mut checked = 0;
    for c in plan
        .constraints
        .iter()
        .filter(|c| c.points.len() >= 10)
        .take(5)
    {
        let inputs = dwo.inputs(&g, &plan).unwrap();
        let Some(Information::Full(ours)) = dwo.marginal_information(&inputs, &plan, c, &cam)
        else {
            panic!("no marginal information");
        };
        let pose = |k| {
            plan.initial_poses
                .get(&k)
                .copied()
                .unwrap_or(g.pose(k).unwrap())
        };
        let mut problem = Problem::new();
        let mut vars = BTreeMap::new();
        for k in [c.from, c.to] {
            vars.insert(k, problem.add_variable(FixedScaleSim3(pose(k))));
        }
        problem.set_fixed(vars[&c.from].key(), true);
        for &(pid, w) in &c.points {
            let pt = g.point(pid).unwrap();
            let anchor = *vars.entry(pt.anchor()).or_insert_with(|| {
                let v = problem.add_variable(FixedScaleSim3(pose(pt.anchor())));
                problem.set_fixed(v.key(), true);
                v
            });
            let psi = problem.add_variable(*pt.inverse_depth());
            let info = Information::Isotropic(0.5 / w.sqrt());
            for k in [c.from, c.to] {
                let z = g.keyframe(k).unwrap().observations()[&pid];
                if k == pt.anchor() {
                    let f = InverseDepthObservation {
                        observer_from_anchor: None,
                        inverse_depth_point: psi,
                        measurement: z,
                        projector: cam,
                    };
                    problem.add_factor(f, info.clone(), None).unwrap();
                } else {
                    let f = AnchoredObservation {
                        observer_from_world: vars[&k],
                        anchor_from_world: anchor,
                        inverse_depth_point: psi,
                        measurement: z,
                        projector: cam,
                    };
                    problem.add_factor(f, info.clone(), None).unwrap();
                }
            }
        }
        let covariance = problem.covariance(&[vars[&c.to].key()]).unwrap();
        let theirs = covariance.try_inverse().unwrap();
        let ours = ours.view((0, 0), (6, 6)).into_owned();
        // Ours has a ridge of 1e-6 of its largest diagonal entry (before the ridge).
        let ridge = 1e-6 * ours.diagonal().max() / (1.0 + 1e-6);
        let ours_without_ridge = &ours - nalgebra::DMatrix::<f64>::identity(6, 6) * ridge;
        let diff = (&ours_without_ridge - &theirs).abs().max();
        assert!(
            diff <= 1e-9 * theirs.abs().max(),
            "{diff:e}: ours\n{ours}theirs\n{theirs}"
        );
        checked += 1;
    }
    assert!(checked > 0);
    // And the window optimises with it.
    let stats = dwo.optimise(&mut g, &cam).unwrap();
    assert!(stats.cost_after < stats.cost_before);
    g.check_invariants().unwrap();
}

#[test]
fn full_window_optimisation_reduces_the_error_without_a_fixed_origin() {
    let (mut g, cam, truth) = wall_graph(2, 12);
    let err = |g: &SlamGraph<3>| {
        (1..truth.len())
            .map(|k| {
                let (a, b) = (KeyframeId::from_index(k - 1), KeyframeId::from_index(k));
                let est = g.pose(b).unwrap().compose(&g.pose(a).unwrap().inverse());
                let tru = Sim3::from_se3(&truth[k].compose(&truth[k - 1].inverse()));
                (est.translation() - tru.translation()).norm()
            })
            .sum::<f64>()
    };
    let before = err(&g);
    let mut params = DwoParams::new(usize::MAX, 0, 300.0, 0.5);
    params.iterations = 10;
    let mut dwo = DoubleWindowOptimiser::new(params);
    dwo.optimise(&mut g, &cam).unwrap();
    assert!(err(&g) < 0.3 * before, "{} → {}", before, err(&g));
}

/// The optimisations that end a run start from the poses as they are: an edge whose
/// stored relative pose is stale by a metre (marginalised before a loop moved one end)
/// neither chains the keyframes behind it a metre off (as the re-initialisation along the
/// spanning tree of a fresh optimiser does) nor pulls them there.
#[test]
fn the_end_of_run_optimisations_start_from_the_poses_as_they_are() {
    let (g0, cam, truth) = wall_graph(3, 20);
    let k = KeyframeId::from_index;
    let mut g = g0.clone();
    let stale = g
        .relative_pose(k(9), k(10))
        .unwrap()
        .compose(&Sim3::from_se3(&Se3::from_translation(Vector3::new(
            1.0, 0.0, 0.0,
        ))));
    assert!(g.set_edge_relative(k(9), k(10), Some(stale)));
    // Each keyframe's error relative to keyframe 19 (the reference; no origin is fixed).
    let worst = |g: &SlamGraph<3>| {
        (0..20)
            .map(|i| {
                let est = g
                    .pose(k(i))
                    .unwrap()
                    .compose(&g.pose(k(19)).unwrap().inverse());
                let tru = Sim3::from_se3(&truth[i].compose(&truth[19].inverse()));
                (est.translation() - tru.translation()).norm()
            })
            .fold(0.0, f64::max)
    };
    let before = worst(&g);
    let mut params = DwoParams::new(5, 10, 300.0, 0.5);
    params.iterations = 5;
    let [mut global, mut full] = DoubleWindowOptimiser::finishing(params.clone(), &g);
    global.optimise(&mut g, &cam).unwrap();
    full.optimise(&mut g, &cam).unwrap();
    assert!(worst(&g) < before.max(0.05), "{before} → {}", worst(&g));
    // Neither re-initialises a keyframe or re-computes a stored relative pose (a fresh
    // optimiser re-initialises every keyframe but the reference along the tree).
    let mut h = g0.clone();
    assert!(h.set_edge_relative(k(9), k(10), Some(stale)));
    for dwo in DoubleWindowOptimiser::finishing(params.clone(), &h) {
        let plan = dwo.plan(&h).unwrap();
        assert!(plan.reinitialised.is_empty(), "{:?}", plan.reinitialised);
        assert!(plan.edge_updates.iter().all(|u| u.2.is_none()));
    }
    let fresh = DoubleWindowOptimiser::new(DwoParams {
        inner: usize::MAX,
        ..params
    });
    assert_eq!(fresh.plan(&h).unwrap().reinitialised.len(), 19);
}

#[test]
fn tracking_reads_the_graph_while_the_optimiser_runs() {
    let (g, cam, _) = wall_graph(3, 40);
    let shared = SharedGraph::new(g);
    let running = AtomicBool::new(true);
    let reads_during = AtomicUsize::new(0);
    let mut params = DwoParams::new(usize::MAX, 0, 300.0, 0.5);
    params.iterations = 30;
    let mut dwo = DoubleWindowOptimiser::new(params);
    std::thread::scope(|s| {
        let optimiser = s.spawn(|| {
            let r = dwo.optimise(&shared, &cam);
            running.store(false, Ordering::SeqCst);
            r
        });
        // The "tracking thread": candidate points of N1 and the reference pose, and a new
        // keyframe with an observation, all while the optimisation runs.
        let mut added = false;
        while running.load(Ordering::SeqCst) {
            let started = std::time::Instant::now();
            {
                let g = shared.read();
                let r = g.reference().unwrap();
                let candidates = crate::tracking::tracking_candidates(&g, r);
                assert!(!candidates.is_empty());
                assert!(g.pose(r).is_ok());
            }
            assert!(
                started.elapsed() < std::time::Duration::from_millis(200),
                "a read waited for the optimiser"
            );
            if running.load(Ordering::SeqCst) {
                reads_during.fetch_add(1, Ordering::SeqCst);
            }
            if !added {
                let mut g = shared.write();
                let r = g.reference().unwrap();
                let pose = g.pose(r).unwrap();
                let kf = g.add_keyframe(pose);
                let p = *g.keyframe(r).unwrap().observations().keys().next().unwrap();
                let z = g.keyframe(r).unwrap().observations()[&p];
                g.add_observation(kf, p, z).unwrap();
                added = true;
            }
        }
        let stats = optimiser.join().unwrap().unwrap();
        assert!(stats.cost_after < stats.cost_before);
    });
    assert!(
        reads_during.load(Ordering::SeqCst) > 0,
        "no read overlapped the optimisation"
    );
    let g = shared.into_inner();
    g.check_invariants().unwrap();
    assert_eq!(g.num_keyframes(), 41);
}

/// A loop correction lands between the plan and the write-back (the loop-closure thread
/// corrected the graph while the optimiser worked without the lock): the write-back
/// detects that the window's poses moved, writes nothing, and the graph keeps the
/// correction; the next optimisation re-plans from the corrected graph.
#[test]
fn a_loop_correction_during_an_optimisation_supersedes_its_result() {
    use crate::loop_closure::{CorrectionGroup, LoopEdge, correction::correct_graph};
    use crate::pose_graph::PoseGraphJacobian;
    let (g, cam, _) = wall_graph(5, 30);
    let shared = SharedGraph::new(g);
    let mut dwo = DoubleWindowOptimiser::new(DwoParams::new(5, 10, 300.0, 0.5));
    // Plan and build under the read lock.
    let (plan, mut problem) = {
        let g = shared.read();
        let plan = dwo.plan(&g).unwrap();
        let problem = dwo
            .build(&dwo.inputs(&g, &plan).unwrap(), &plan, &cam)
            .unwrap();
        (plan, problem)
    };
    // Meanwhile: a Sim(3) loop correction between the newest and the first keyframe,
    // whose measured loop disagrees with the chain by 2 % in scale and 3 cm.
    let correction = {
        let mut g = shared.write();
        let (first, last) = (KeyframeId(0), KeyframeId(29));
        let chain_loop = g
            .pose(first)
            .unwrap()
            .compose(&g.pose(last).unwrap().inverse());
        let disagreement =
            Sim3::new(lie::So3::identity(), Vector3::new(0.03, 0.0, 0.0), 1.02).unwrap();
        let loops = [LoopEdge {
            old: 0,
            current: 29,
            old_from_current: disagreement.compose(&chain_loop),
            information: None,
        }];
        correct_graph(
            &mut g,
            &loops,
            CorrectionGroup::Sim3,
            PoseGraphJacobian::Analytic(lie::LogJacobian::Exact),
            &SolverOptions::default(),
        )
        .unwrap();
        g.check_invariants().unwrap();
        g.snapshot_state()
    };
    // The optimisation ran on the old poses...
    let mut stats = DwoStats::default();
    dwo.solve(&mut problem, &mut stats).unwrap();
    // ...so its write-back is refused and changes nothing.
    let result = dwo.apply(&mut shared.write(), &plan, &problem);
    let Err(DwoError::Superseded { keyframes }) = result else {
        panic!("a stale result was written: {result:?}");
    };
    assert!(keyframes.len() >= plan.window.len() - 1, "{keyframes:?}");
    {
        let g = shared.read();
        g.check_invariants().unwrap();
        assert_eq!(
            g.snapshot_state(),
            correction,
            "the write-back changed the graph"
        );
    }
    // The next optimisation re-plans from the corrected graph and succeeds.
    let stats = dwo.optimise(&shared, &cam).unwrap();
    assert!(stats.cost_after <= stats.cost_before);
    assert_eq!(
        stats.write_back.poses,
        stats.inner_frames + stats.outer_frames
    );
    shared.read().check_invariants().unwrap();
}

/// Tracking changes the window between plan and write-back without moving its poses (a new
/// keyframe, new observations, a removed point, a re-anchored point): the write-back
/// writes the rest and reports what it left alone.
#[test]
fn concurrent_tracking_changes_are_kept_and_reported() {
    let (mut g, cam, _) = wall_graph(6, 30);
    let mut dwo = DoubleWindowOptimiser::new(DwoParams::new(5, 10, 300.0, 0.5));
    let plan = dwo.plan(&g).unwrap();
    let mut problem = dwo
        .build(&dwo.inputs(&g, &plan).unwrap(), &plan, &cam)
        .unwrap();
    let (removed, reanchored) = (plan.points[0], plan.points[1]);
    let r = g.reference().unwrap();
    let kf = g.add_keyframe(g.pose(r).unwrap());
    let z = g.keyframe(r).unwrap().observations()[&plan.points[2]];
    g.add_observation(kf, plan.points[2], z).unwrap();
    g.remove_point(removed).unwrap();
    let anchor = g.point(reanchored).unwrap().anchor();
    g.remove_observation(anchor, reanchored).unwrap();
    let mut stats = DwoStats::default();
    dwo.solve(&mut problem, &mut stats).unwrap();
    let report = dwo.apply(&mut g, &plan, &problem).unwrap();
    g.check_invariants().unwrap();
    assert_eq!(report.superseded_points, 2, "{report:?}");
    assert_eq!(report.points + 2, plan.points.len());
    assert_eq!(report.poses, plan.initial_poses.len());
    assert_eq!(g.keyframe(kf).unwrap().observations().len(), 1);
}
