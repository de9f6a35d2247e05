//! The SLAM graph's tests: keyframes, points, edges, maps and invariants.

use super::*;
use nalgebra::Vector2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn k(i: usize) -> KeyframeId {
    KeyframeId::from_index(i)
}

fn random_graph(seed: u64, keyframes: usize, points: usize) -> SlamGraph<2> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut g = SlamGraph::<2>::new();
    for k in 0..keyframes {
        g.add_keyframe(Sim3::from_se3(&lie::Se3::from_translation(Vector3::new(
            k as f64 * 0.1,
            0.0,
            0.0,
        ))));
    }
    for _ in 0..points {
        let anchor = rng.random_range(0..keyframes);
        let psi = Vector3::new(
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(0.2..1.0),
        );
        let p = g.add_point(k(anchor), psi, Vector2::new(1.0, 2.0)).unwrap();
        for _ in 0..rng.random_range(0..5) {
            let o = (anchor + rng.random_range(0..4)).min(keyframes - 1);
            g.add_observation(k(o), p, Vector2::new(3.0, 4.0)).unwrap();
        }
    }
    for a in 0..keyframes {
        for b in a + 1..keyframes.min(a + 4) {
            let (a, b) = (k(a), k(b));
            if g.shared_points(a, b) > 0 {
                let rel = if (a.index() + b.index()) % 2 == 0 {
                    Some(g.pose(b).unwrap().compose(&g.pose(a).unwrap().inverse()))
                } else {
                    None
                };
                g.add_edge(a, b, rel).unwrap();
            }
        }
    }
    g
}

#[test]
fn invariants_hold_after_additions_and_removals() {
    for seed in 0..4 {
        let mut g = random_graph(seed, 12, 200);
        g.check_invariants().unwrap();
        assert!(g.num_edges() > 5);
        // Observations added after the edges keep the weights equal to shared counts.
        let p = g.points().map(|(p, _)| p).nth(3).unwrap();
        g.add_observation(k(5), p, Vector2::zeros()).unwrap();
        g.check_invariants().unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
        for _ in 0..40 {
            let ids: Vec<PointId> = g.points().map(|(p, _)| p).collect();
            let p = ids[rng.random_range(0..ids.len())];
            let obs: Vec<KeyframeId> = g.point(p).unwrap().observers().iter().copied().collect();
            g.remove_observation(obs[rng.random_range(0..obs.len())], p)
                .unwrap();
            g.check_invariants().unwrap();
        }
        for _ in 0..20 {
            let ids: Vec<PointId> = g.points().map(|(p, _)| p).collect();
            g.remove_point(ids[rng.random_range(0..ids.len())]).unwrap();
            g.check_invariants().unwrap();
        }
        let r = g.reference().unwrap();
        g.remove_keyframe(r).unwrap();
        g.check_invariants().unwrap();
        assert_ne!(g.reference(), Some(r));
        g.remove_keyframe(k(7)).unwrap();
        g.check_invariants().unwrap();
        assert_eq!(g.num_keyframes(), 10);
        assert!(
            g.points()
                .all(|(_, p)| p.anchor() != k(7) && p.anchor() != r)
        );
        assert_eq!(
            g.remove_keyframe(k(7)),
            Err(GraphError::UnknownKeyframe(k(7)))
        );
    }
}

#[test]
fn re_anchoring_keeps_the_world_point() {
    let mut g = SlamGraph::<2>::new();
    let a = g.add_keyframe(Sim3::identity());
    let b = g.add_keyframe(
        Sim3::new(
            lie::So3::exp(&Vector3::new(0.0, 0.2, 0.0)),
            Vector3::new(-0.3, 0.1, 0.0),
            1.3,
        )
        .unwrap(),
    );
    let p = g
        .add_point(a, Vector3::new(0.1, -0.2, 0.5), Vector2::zeros())
        .unwrap();
    g.add_observation(b, p, Vector2::zeros()).unwrap();
    let before = g.point_world(p).unwrap();
    g.remove_observation(a, p).unwrap();
    assert_eq!(g.point(p).unwrap().anchor(), b);
    assert!((g.point_world(p).unwrap() - before).norm() < 1e-12);
    g.remove_observation(b, p).unwrap();
    assert!(g.point(p).is_none(), "a point without observers is removed");
    g.check_invariants().unwrap();
}

#[test]
fn weighted_bfs_visits_strongest_first_and_builds_a_tree() {
    let mut g = SlamGraph::<2>::new();
    for _ in 0..5 {
        g.add_keyframe(Sim3::identity());
    }
    // Shared points: 0–1: 1, 0–2: 3, 2–3: 2, 1–4: 1.
    let mut share = |a: usize, b: usize, n: usize| {
        for _ in 0..n {
            let p = g
                .add_point(k(a), Vector3::new(0.0, 0.0, 1.0), Vector2::zeros())
                .unwrap();
            g.add_observation(k(b), p, Vector2::zeros()).unwrap();
        }
    };
    share(0, 1, 1);
    share(0, 2, 3);
    share(2, 3, 2);
    share(1, 4, 1);
    for (a, b) in [(0, 1), (0, 2), (2, 3), (1, 4)] {
        g.add_edge(k(a), k(b), None).unwrap();
    }
    g.check_invariants().unwrap();
    assert_eq!(g.edge(k(0), k(2)).unwrap().weight, 3);
    let ks = |v: &[usize]| v.iter().map(|&i| k(i)).collect::<Vec<_>>();
    let t = g.weighted_bfs(k(0), 10);
    assert_eq!(t.order, ks(&[0, 2, 1, 3, 4]));
    assert_eq!(t.parent[&k(3)], Some(k(2)));
    assert_eq!(t.parent[&k(4)], Some(k(1)));
    assert_eq!(g.weighted_bfs(k(0), 2).order, ks(&[0, 2]));
    assert_eq!(g.n1(k(0)), ks(&[0, 2, 1]));
    assert_eq!(g.n2(k(0), 4), ks(&[0, 2, 1, 3]));
}

#[test]
fn bad_input_is_an_error() {
    let mut g = SlamGraph::<2>::new();
    let a = g.add_keyframe(Sim3::identity());
    assert!(matches!(
        g.add_point(a, Vector3::new(0.0, 0.0, -1.0), Vector2::zeros()),
        Err(GraphError::BadInverseDepth(_))
    ));
    assert_eq!(
        g.add_point(k(9), Vector3::new(0.0, 0.0, 1.0), Vector2::zeros()),
        Err(GraphError::UnknownKeyframe(k(9)))
    );
    assert!(matches!(
        g.add_edge(a, a, None),
        Err(GraphError::SelfEdge(_))
    ));
    assert_eq!(
        g.add_observation(a, PointId(4), Vector2::zeros()),
        Err(GraphError::UnknownPoint(PointId(4)))
    );
}

#[test]
fn versions_record_what_changed_when() {
    let mut g = SlamGraph::<2>::new();
    let a = g.add_keyframe(Sim3::identity());
    let b = g.add_keyframe(Sim3::identity());
    let p = g
        .add_point(a, Vector3::new(0.1, 0.0, 0.5), Vector2::zeros())
        .unwrap();
    let planned = g.version();
    assert!(g.keyframe(a).unwrap().pose_version() <= planned);
    // Adding observations and edges moves the graph, not the poses or the point.
    g.add_observation(b, p, Vector2::zeros()).unwrap();
    g.add_edge(a, b, None).unwrap();
    assert!(g.version() > planned);
    assert!(g.keyframe(a).unwrap().pose_version() <= planned);
    assert!(g.point(p).unwrap().version() <= planned);
    // A pose or point that is set is newer than the plan.
    g.set_pose(b, Sim3::identity()).unwrap();
    assert!(g.keyframe(b).unwrap().pose_version() > planned);
    g.set_inverse_depth(p, Vector3::new(0.1, 0.0, 0.4)).unwrap();
    assert!(g.point(p).unwrap().version() > planned);
    // Re-anchoring changes what ψ means: the point is newer too.
    let before = g.point(p).unwrap().version();
    g.remove_observation(a, p).unwrap();
    assert_eq!(g.point(p).unwrap().anchor(), b);
    assert!(g.point(p).unwrap().version() > before);
    // Refused mutations do not count.
    let v = g.version();
    assert!(g.set_pose(k(9), Sim3::identity()).is_err());
    assert!(!g.set_edge_relative(a, k(9), None));
    assert_eq!(g.version(), v);
}

/// Maps: keyframes join the map started last or the reference's; a merge moves the merged
/// map's keyframes (and so their points) as one body, relabels them, and is logged, so
/// that a pose kept outside the graph can follow a chain of merges; a merge within one map
/// does nothing.
#[test]
fn maps_start_merge_and_log_their_moves() {
    use lie::{Se3, So3};
    let mut g = SlamGraph::<2>::new();
    let pose =
        |x: f64, yaw: f64| Sim3::from_se3(&Se3::new(So3::rot_y(yaw), Vector3::new(x, 0.0, 0.0)));
    let a = g.add_keyframe(pose(0.0, 0.0));
    assert_eq!(
        (g.current_map(), g.map_of(a).unwrap()),
        (FIRST_MAP, FIRST_MAP)
    );
    assert_eq!(g.start_map(), 1);
    let b = g.add_keyframe(pose(5.0, 0.3));
    let p = g
        .add_point(b, Vector3::new(0.1, 0.0, 0.5), Vector2::zeros())
        .unwrap();
    let p_before = g.point_world(p).unwrap();
    assert_eq!(g.map_of(b).unwrap(), 1);
    // The reference decides the map new keyframes join.
    g.set_reference(a).unwrap();
    assert_eq!(g.current_map(), FIRST_MAP);
    g.set_reference(b).unwrap();
    assert_eq!(g.start_map(), 2);
    let c = g.add_keyframe(pose(9.0, -0.2));
    // Map 2 into map 1, then map 1 into the first.
    let target_c = pose(7.0, 0.1);
    assert_eq!(g.merge_map(c, &target_c, b).unwrap(), 1);
    assert_eq!(g.map_of(c).unwrap(), 1);
    let target_b = pose(1.0, 0.05);
    let moved_b = g.pose(b).unwrap().inverse().compose(&target_b);
    let c_before = g.pose(c).unwrap();
    assert_eq!(g.merge_map(b, &target_b, a).unwrap(), 2);
    assert!((g.pose(b).unwrap().log() - target_b.log()).norm() < 1e-12);
    assert!((g.pose(c).unwrap().log() - c_before.compose(&moved_b).log()).norm() < 1e-12);
    assert_eq!(
        [g.map_of(b).unwrap(), g.map_of(c).unwrap()],
        [FIRST_MAP, FIRST_MAP]
    );
    assert_eq!(g.current_map(), FIRST_MAP);
    // The point moved with its anchor.
    let p_after = g.point_world(p).unwrap();
    assert!((p_after - moved_b.inverse().act(&p_before)).norm() < 1e-9);
    // The log: a pose of map 2 from before both merges follows both.
    assert_eq!(g.merges().len(), 2);
    let (moved, into) = g.moved_since(0, 2).unwrap();
    assert_eq!(into, FIRST_MAP);
    let original_c = pose(9.0, -0.2);
    assert!((original_c.compose(&moved).log() - g.pose(c).unwrap().log()).norm() < 1e-9);
    assert!(
        g.moved_since(1, 2).is_none(),
        "the second merge moved map 1, not 2"
    );
    assert!(g.moved_since(0, FIRST_MAP).is_none());
    // Within one map: nothing moves, nothing is logged.
    assert_eq!(g.merge_map(c, &pose(50.0, 0.0), a).unwrap(), 0);
    assert_eq!(g.merges().len(), 2);
    assert!((g.pose(b).unwrap().log() - target_b.log()).norm() < 1e-12);
}
