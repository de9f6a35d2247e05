//! Whether a loop's correction is one the odometry's drift explains: odometry drifts with the
//! distance it travels, so a loop that moves a keyframe by more than a fraction of the path
//! since the old place joins two places that only look alike (repeated façades, corridors).
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
    /// Length of the keyframe chain from the old keyframe to the new one: the keyframes made
    /// between them, in order (map units).
    pub path: f64,
    /// Median depth of the old keyframe's map points in its frame (0 if it has none).
    pub scene_depth: f64,
}

/// The largest correction a loop may make: the larger of a fraction of the path and a fraction
/// of the scene depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriftLimits {
    /// Fraction of the path since the old place.
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
}
