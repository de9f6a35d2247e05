//! Whether a loop's correction is one the odometry's drift explains: odometry drifts with the
//! distance it travels, so a loop that moves a keyframe by more than a fraction of the path
//! the graph relates it to the old place through (the camera's path, or a shorter one through
//! loops already closed) joins two places that only look alike (repeated façades, corridors).
//! Such a loop, once in the graph, bends the map by metres; refusing it costs a loop.

use crate::map::{KeyframeId, SlamGraph};
use lie::{LieGroup, Sim3};
use nalgebra::Vector3;

/// How far a loop moves its new keyframe, against the path the map travelled between the two
/// places and the old place's scene depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopDrift {
    /// Distance between where the loop puts the new keyframe's centre and where the map has it
    /// (map units).
    pub displacement: f64,
    /// Length of the shortest chain of graph edges between the two keyframes, each edge as
    /// long as the distance between its keyframes' centres (map units): the path the relative
    /// pose of the two is known through. Before any loop that is the keyframes made between
    /// them, in order; once a loop joins the two places, the way through it. Keyframes the
    /// edges do not join: the chain of the keyframes made between them.
    pub path: f64,
    /// Median depth of the old keyframe's map points in its frame (0 if it has none).
    pub scene_depth: f64,
}

/// The largest correction a loop may make: the larger of a fraction of the path and a fraction
/// of the scene depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriftLimits {
    /// Fraction of the path between the two places ([`LoopDrift::path`]).
    pub of_path: f64,
    /// Fraction of the old place's scene depth: a correction within it keeps the new keyframe
    /// inside the old one's view, whatever the path (for loops over a short path, where the
    /// loop's own pose error is larger than the path's drift).
    pub of_scene_depth: f64,
}

impl LoopDrift {
    /// The correction of the loop that puts keyframe `k` at `implied_camera_from_world`, seen
    /// from keyframe `old`; `None` if either keyframe is not in `graph`.
    pub fn of<const N: usize>(
        graph: &SlamGraph<N>,
        old: KeyframeId,
        k: KeyframeId,
        implied_camera_from_world: &Sim3,
    ) -> Option<Self> {
        let centre = |t: &Sim3| t.inverse().act(&Vector3::zeros());
        let t_k = graph.pose(k).ok()?;
        graph.pose(old).ok()?;
        let path = shortest_path(graph, old, k).unwrap_or_else(|| {
            let mut path = 0.0;
            let mut previous: Option<Vector3<f64>> = None;
            for i in old.index().min(k.index())..=old.index().max(k.index()) {
                if let Ok(t) = graph.pose(KeyframeId::from_index(i)) {
                    let c = centre(&t);
                    if let Some(p) = previous {
                        path += (c - p).norm();
                    }
                    previous = Some(c);
                }
            }
            path
        });
        let mut depths: Vec<f64> = graph.keyframe(old).map_or_else(Vec::new, |kf| {
            kf.observations()
                .keys()
                .filter_map(|&p| graph.point_in_frame(p, old).ok().map(|x| x.z))
                .filter(|z| *z > 0.0)
                .collect()
        });
        depths.sort_by(f64::total_cmp);
        Some(LoopDrift {
            displacement: (centre(implied_camera_from_world) - centre(&t_k)).norm(),
            path,
            scene_depth: depths.get(depths.len() / 2).copied().unwrap_or(0.0),
        })
    }

    /// The largest displacement `limits` allow for this path and scene.
    pub fn allowed(&self, limits: &DriftLimits) -> f64 {
        (limits.of_path * self.path).max(limits.of_scene_depth * self.scene_depth)
    }

    /// Whether the displacement is within what `limits` allow.
    pub fn within(&self, limits: &DriftLimits) -> bool {
        self.displacement <= self.allowed(limits)
    }
}

/// The length of the shortest chain of edges from `a` to `b` (Dijkstra), an edge as long as
/// the distance between its keyframes' centres; `None` if no chain joins them. Why the graph's
/// path and not the camera's: odometry drifts along the path the two poses are related
/// through, and a loop already closed shortens it — a second loop at the same place that
/// disagrees with the first by metres is a place that looks like another (repeated façades),
/// however long the camera walked in between.
fn shortest_path<const N: usize>(
    graph: &SlamGraph<N>,
    a: KeyframeId,
    b: KeyframeId,
) -> Option<f64> {
    use std::cmp::Reverse;
    use std::collections::{BTreeMap, BinaryHeap};
    /// A distance ordered by `total_cmp` (the heap needs `Ord`).
    #[derive(PartialEq)]
    struct Dist(f64);
    impl Eq for Dist {}
    impl PartialOrd for Dist {
        fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(o))
        }
    }
    impl Ord for Dist {
        fn cmp(&self, o: &Self) -> std::cmp::Ordering {
            self.0.total_cmp(&o.0)
        }
    }
    let centre = |k: KeyframeId| -> Option<Vector3<f64>> {
        Some(graph.pose(k).ok()?.inverse().act(&Vector3::zeros()))
    };
    let mut best: BTreeMap<KeyframeId, f64> = BTreeMap::from([(a, 0.0)]);
    let mut heap = BinaryHeap::from([(Reverse(Dist(0.0)), a)]);
    while let Some((Reverse(Dist(d)), v)) = heap.pop() {
        if v == b {
            return Some(d);
        }
        if best.get(&v).is_some_and(|&x| x < d) {
            continue;
        }
        let cv = centre(v)?;
        for &n in graph.keyframe(v)?.edges().keys() {
            let Some(cn) = centre(n) else { continue };
            let dn = d + (cn - cv).norm();
            if best.get(&n).is_none_or(|&x| dn < x) {
                best.insert(n, dn);
                heap.push((Reverse(Dist(dn)), n));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::SlamGraph;
    use lie::{Se3, So3};

    /// Keyframes every metre along x, looking along z, each seeing one point 4 m ahead.
    fn corridor(n: usize) -> SlamGraph<3> {
        let mut g = SlamGraph::<3>::new();
        for i in 0..n {
            let world_from_camera = Se3::new(So3::identity(), Vector3::new(i as f64, 0.0, 0.0));
            let k = g.add_keyframe(Sim3::from_se3(&world_from_camera.inverse()));
            g.add_point(k, Vector3::new(0.0, 0.0, 0.25), Vector3::zeros())
                .unwrap();
        }
        g
    }

    #[test]
    fn the_correction_is_measured_against_the_path_and_the_scene_depth() {
        let g = corridor(41);
        let (old, k) = (KeyframeId::from_index(0), KeyframeId::from_index(40));
        let at = |x: f64| {
            Sim3::from_se3(&Se3::new(So3::identity(), Vector3::new(x, 0.0, 0.0)).inverse())
        };
        let limits = DriftLimits {
            of_path: 0.05,
            of_scene_depth: 0.1,
        };
        // The loop says keyframe 40 is at x = 42 (2 m, 5 % of the 40 m path): allowed; at
        // x = 43 (3 m, 7.5 %): refused.
        let d = LoopDrift::of(&g, old, k, &at(42.0)).unwrap();
        assert!((d.path - 40.0).abs() < 1e-9 && (d.displacement - 2.0).abs() < 1e-9);
        assert!((d.scene_depth - 4.0).abs() < 1e-9);
        assert!(d.within(&limits));
        assert!(
            !LoopDrift::of(&g, old, k, &at(43.0))
                .unwrap()
                .within(&limits)
        );
        // Over a 2 m path the scene depth's tenth (0.4 m) is the limit, not 5 % of the path.
        let k2 = KeyframeId::from_index(2);
        assert!(
            LoopDrift::of(&g, old, k2, &at(2.35))
                .unwrap()
                .within(&limits)
        );
        assert!(
            !LoopDrift::of(&g, old, k2, &at(2.45))
                .unwrap()
                .within(&limits)
        );
        // The same in either order of the keyframes, and None for an unknown keyframe.
        let back = LoopDrift::of(&g, k, old, &at(0.0)).unwrap();
        assert!((back.path - 40.0).abs() < 1e-9 && back.displacement < 1e-9);
        assert!(LoopDrift::of(&g, old, KeyframeId::from_index(99), &at(0.0)).is_none());
    }

    /// Keyframes 1 m apart round a circle of 40 m, each joined to the next, each seeing one
    /// point 4 m ahead (the camera looks along z, the circle lies in the x-y plane).
    fn ring() -> SlamGraph<3> {
        let mut g = SlamGraph::<3>::new();
        let r = 40.0 / std::f64::consts::TAU;
        for i in 0..40 {
            let a = i as f64 / 40.0 * std::f64::consts::TAU;
            let world_from_camera =
                Se3::new(So3::identity(), Vector3::new(r * a.cos(), r * a.sin(), 0.0));
            let k = g.add_keyframe(Sim3::from_se3(&world_from_camera.inverse()));
            g.add_point(k, Vector3::new(0.0, 0.0, 0.25), Vector3::zeros())
                .unwrap();
            if i > 0 {
                g.add_edge(KeyframeId::from_index(i - 1), k, None).unwrap();
            }
        }
        g
    }

    #[test]
    fn a_closed_loop_shortens_the_path_a_second_loop_is_measured_against() {
        let mut g = ring();
        let (first, last) = (KeyframeId::from_index(1), KeyframeId::from_index(39));
        let limits = DriftLimits {
            of_path: 0.05,
            of_scene_depth: 0.1,
        };
        // A loop from keyframe 39 to keyframe 1 that moves 39 by 1.5 m: within 5 % of the 38 m
        // the camera went round (1.9 m).
        let t = g.pose(last).unwrap();
        let moved =
            Sim3::from_se3(&Se3::new(So3::identity(), Vector3::new(0.0, 0.0, 1.5))).compose(&t);
        let d = LoopDrift::of(&g, first, last, &moved).unwrap();
        assert!((d.path - 38.0).abs() < 0.1, "{}", d.path);
        assert!(d.within(&limits));
        // Once a loop joins keyframes 39 and 0, the two places are 2 m apart through it: the
        // same 1.5 m is more than 5 % of that (0.1 m) and than a tenth of the scene depth
        // (0.4 m).
        g.add_edge(KeyframeId::from_index(0), last, None).unwrap();
        let d = LoopDrift::of(&g, first, last, &moved).unwrap();
        assert!((d.path - 2.0).abs() < 0.01, "{}", d.path);
        assert!(!d.within(&limits));
    }
}
