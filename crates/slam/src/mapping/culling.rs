//! Keyframe culling: bounded maps on revisits (thesis chapter 7, lifelong mapping: a camera
//! that browses the same place again and again keeps a map of constant size).
//!
//! The keyframe criterion (a new keyframe only where no keyframe near the reference covers the
//! view, thesis §3.3.3, §6.5.2) bounds the map by the *poses* a camera takes. A hand-held camera
//! that returns to a view never returns to quite the same pose, and the poses of a long browse
//! fill a six-dimensional volume keyframe by keyframe: the rendered room browsed for 9000
//! frames kept adding 3.5 keyframes per 100 frames long after every surface was mapped. What
//! bounds a map by the *scene* is dropping the keyframes whose measurements others repeat.
//!
//! A keyframe is **redundant** when nearly all of its points ([`CullingConfig::kept_fraction`])
//! are measured by at least [`CullingConfig::other_observers`] other keyframes: without it
//! each of those points still ties two keyframes' poses together, so the double window loses
//! no constraint that another keyframe does not hold, and tracking finds the same points from
//! their other keyframes' templates. This is ORB-SLAM's and stella_vslam's rule (90 % of the
//! points seen by three others there; see [`CullingConfig`] for ours and why).
//!
//! Only the neighbours of the newest keyframe are examined (`N1`: constant time per keyframe,
//! as the windows are). A culled keyframe's points are re-anchored at another observer or, with
//! no other, removed ([`SlamGraph::remove_keyframe`]); its **heir**, the neighbour sharing most
//! points with it, takes over its edges that carried a pose (marginalised edges, thesis §6.2.2)
//! and its covisibility with keyframes the heir shares points with, so neither a constraint nor
//! the windows' connectivity is lost; the caller moves what it kept relative to the culled
//! keyframe (a frame's pose, an image) onto the heir with the returned relative pose.

use crate::map::{GraphError, KeyframeId, SlamGraph};
use lie::{LieGroup, Sim3};

/// What [`cull`] drops (see the [module docs](self)).
#[derive(Clone, Debug, PartialEq)]
pub struct CullingConfig {
    /// Cull at all.
    pub enabled: bool,
    /// A keyframe is redundant when at least this fraction of its points is kept by others.
    pub kept_fraction: f64,
    /// A point is kept by others when at least this many other keyframes measure it.
    pub other_observers: usize,
}

impl Default for CullingConfig {
    /// `other_observers` 2: the fewest with which a point still constrains a relative pose
    /// once the keyframe is gone (ORB-SLAM asks for three because its monocular points need
    /// two views to exist at all; a stereo or RGB-D point is measured in 3D by one).
    /// `kept_fraction` 0.9: the peers' (ORB-SLAM, stella_vslam) fraction. Measured
    /// (bench/README "Bounded maps"): the rendered room browsed for 9000 frames with new
    /// points beside the map's keeps 160 keyframes instead of 324 at ATE 0.13 / 0.09 cm; with
    /// `other_observers` 1, 78 keyframes but 0.19 / 0.13 cm; on 7-Scenes, the KITTI snippet
    /// and EuRoC culling removes 0–10 keyframes and the ATE stays within 0.1 cm.
    fn default() -> Self {
        CullingConfig {
            enabled: true,
            kept_fraction: 0.9,
            other_observers: 2,
        }
    }
}

/// A keyframe culled, and where what was kept relative to it goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Retired {
    /// The culled keyframe.
    pub keyframe: KeyframeId,
    /// Its heir: the neighbour that shared most points with it.
    pub heir: KeyframeId,
    /// `T_k·T_h⁻¹` when it was culled (frame heir into frame keyframe): a pose `T = R·T_k`
    /// kept relative to the keyframe is `R·keyframe_from_heir·T_h`.
    pub keyframe_from_heir: Sim3,
}

/// Whether keyframe `k` is redundant (see the [module docs](self)).
pub fn is_redundant<const N: usize>(
    graph: &SlamGraph<N>,
    k: KeyframeId,
    config: &CullingConfig,
) -> bool {
    let Some(kf) = graph.keyframe(k) else {
        return false;
    };
    let points = kf.observations();
    if points.is_empty() {
        return false;
    }
    let kept = points
        .keys()
        .filter(|&&p| {
            graph
                .point(p)
                .is_some_and(|pt| pt.observers().len() > config.other_observers)
        })
        .count();
    kept as f64 >= config.kept_fraction * points.len() as f64
}

/// Culls the redundant neighbours of keyframe `newest` (its covisible keyframes in its map,
/// strongest first; not `newest` itself, nor any keyframe `protected` names, nor a keyframe a
/// map join names, nor the first keyframe of a map). Each is decided on the graph as the ones
/// before it left it. Returns the keyframes culled with their heirs, in order.
pub fn cull<const N: usize>(
    graph: &mut SlamGraph<N>,
    newest: KeyframeId,
    protected: impl Fn(KeyframeId) -> bool,
    config: &CullingConfig,
) -> Result<Vec<Retired>, GraphError> {
    if !config.enabled {
        return Ok(Vec::new());
    }
    let map = graph.map_of(newest)?;
    let first_of_map = graph
        .keyframes()
        .find(|(_, kf)| kf.map() == map)
        .map(|(k, _)| k);
    let joined: Vec<KeyframeId> = graph
        .joins()
        .iter()
        .flat_map(|j| [j.current, j.old])
        .collect();
    let mut retired = Vec::new();
    for (k, _) in graph.neighbours_by_weight(newest) {
        if k == newest
            || protected(k)
            || Some(k) == first_of_map
            || joined.contains(&k)
            || graph.map_of(k) != Ok(map)
            || !is_redundant(graph, k, config)
        {
            continue;
        }
        if let Some(r) = retire(graph, k)? {
            retired.push(r);
        }
    }
    Ok(retired)
}

/// Removes keyframe `k` (see the [module docs](self)); `None` (and nothing changes) when it has
/// no neighbour in its map to hand over to.
pub fn retire<const N: usize>(
    graph: &mut SlamGraph<N>,
    k: KeyframeId,
) -> Result<Option<Retired>, GraphError> {
    let map = graph.map_of(k)?;
    let Some(heir) = graph
        .neighbours_by_weight(k)
        .into_iter()
        .map(|(n, _)| n)
        .find(|&n| graph.map_of(n) == Ok(map))
    else {
        return Ok(None);
    };
    let keyframe_from_heir = graph.relative_pose(heir, k)?;
    // The edges the heir takes over: those carrying a pose, composed through `k`
    // (`T_xh = T_xk·T_kh`), and plain covisibility where the heir shares points.
    let handed: Vec<(KeyframeId, Option<Sim3>)> = graph
        .keyframe(k)
        .map(|kf| {
            kf.edges()
                .iter()
                .filter(|&(&x, _)| x != heir && graph.edge(heir, x).is_none())
                .map(|(&x, e)| (x, e.relative.map(|t_xk| t_xk.compose(&keyframe_from_heir))))
                .collect()
        })
        .unwrap_or_default();
    graph.remove_keyframe(k)?;
    for (x, relative) in handed {
        if relative.is_some() || graph.shared_points(heir, x) > 0 {
            graph.add_edge(heir, x, relative)?;
        }
    }
    Ok(Some(Retired {
        keyframe: k,
        heir,
        keyframe_from_heir,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::So3;
    use nalgebra::{Vector3, vector};

    fn at(x: f64) -> Sim3 {
        Sim3::new(So3::identity(), Vector3::new(-x, 0.0, 0.0), 1.0).unwrap()
    }

    /// Four keyframes in a row; keyframe 1 sees only points that 0, 2 and 3 see too (and anchors
    /// them), keyframe 3 has points of its own.
    fn graph() -> (SlamGraph<3>, Vec<KeyframeId>) {
        let mut g = SlamGraph::<3>::new();
        let k: Vec<KeyframeId> = (0..4).map(|i| g.add_keyframe(at(0.1 * i as f64))).collect();
        let z = vector![320.0, 240.0, 300.0];
        for i in 0..20 {
            let psi = vector![0.01 * i as f64, 0.0, 0.5];
            let p = g.add_point(k[1], psi, z).unwrap();
            for &o in [k[0], k[2], k[3]].iter() {
                g.add_observation(o, p, z).unwrap();
            }
        }
        for i in 0..20 {
            let psi = vector![0.01 * i as f64, 0.1, 0.5];
            g.add_point(k[3], psi, z).unwrap();
        }
        for a in 0..4 {
            for b in a + 1..4 {
                g.add_edge(k[a], k[b], None).unwrap();
            }
        }
        (g, k)
    }

    #[test]
    fn a_keyframe_whose_points_others_measure_is_culled_and_its_heir_takes_over() {
        let (mut g, k) = graph();
        let config = CullingConfig::default();
        assert!(is_redundant(&g, k[1], &config));
        assert!(is_redundant(&g, k[2], &config));
        // Keyframe 3's own points have no other observer: not redundant.
        assert!(!is_redundant(&g, k[3], &config));
        let first = g.points().next().unwrap().0;
        let before = g.point_world(first).unwrap();
        let retired = cull(&mut g, k[3], |_| false, &config).unwrap();
        // Then keyframe 2's points still have two other observers (0 and 3): culled too; with
        // it gone they have two observers in all, and keyframe 3 its own points: kept.
        assert_eq!(retired.len(), 2, "{retired:?}");
        assert_eq!(retired[1].keyframe, k[2]);
        assert!(!is_redundant(&g, k[3], &config));
        let r = retired[0];
        // Keyframe 0 is the map's first; 1 is the strongest (ties by id) other neighbour.
        assert_eq!(r.keyframe, k[1]);
        assert!(g.keyframe(r.keyframe).is_none());
        assert_ne!(r.heir, r.keyframe);
        // T_k·T_h⁻¹ as the poses were.
        let expected =
            at(0.1 * r.keyframe.index() as f64).compose(&g.pose(r.heir).unwrap().inverse());
        assert!((r.keyframe_from_heir.log() - expected.log()).norm() < 1e-12);
        g.check_invariants().unwrap();
        assert_eq!(g.num_points(), 40);
        // Re-anchored at another observer, where it was.
        assert_ne!(g.point(first).unwrap().anchor(), k[1]);
        let after = g.point_world(first).unwrap();
        assert!((before - after).norm() < 1e-9);
        // Protected keyframes stay.
        let (mut g, k) = graph();
        let retired = cull(&mut g, k[3], |x| x == k[1] || x == k[2], &config).unwrap();
        assert!(retired.is_empty());
        assert_eq!(g.num_keyframes(), 4);
        // Disabled: nothing.
        let off = CullingConfig {
            enabled: false,
            ..config
        };
        assert!(cull(&mut g, k[3], |_| false, &off).unwrap().is_empty());
    }

    #[test]
    fn a_marginalised_edge_is_handed_to_the_heir_composed() {
        let mut g = SlamGraph::<3>::new();
        let a = g.add_keyframe(at(0.0));
        let k = g.add_keyframe(at(0.1));
        let x = g.add_keyframe(at(0.2));
        let z = vector![320.0, 240.0, 300.0];
        let p = g.add_point(a, vector![0.0, 0.0, 0.5], z).unwrap();
        g.add_observation(k, p, z).unwrap();
        g.add_edge(a, k, None).unwrap();
        // A pose constraint k → x, measured 1 cm off the poses.
        let t_xk = at(0.2).compose(&at(0.1).inverse());
        let measured = Sim3::new(So3::identity(), Vector3::new(-0.11, 0.0, 0.0), 1.0).unwrap();
        assert!((*t_xk.translation() - Vector3::new(-0.1, 0.0, 0.0)).norm() < 1e-12);
        g.add_edge(k, x, Some(measured)).unwrap();
        let r = retire(&mut g, k).unwrap().unwrap();
        assert_eq!(r.heir, a);
        // T_xa = T_xk·T_ka: the measurement composed with the relative pose k ← a.
        let t_xa = g.edge(a, x).unwrap().relative.unwrap();
        let expected = measured.compose(&at(0.1).compose(&at(0.0).inverse()));
        assert!((t_xa.log() - expected.log()).norm() < 1e-12);
        g.check_invariants().unwrap();
    }
}
