//! What the live system keeps of each keyframe beside the SLAM graph: its images (the patch
//! templates of the guided search are warped from the anchor keyframe's image, PTAM-style; the
//! dense model fuses its depth), and the keyframe criterion (thesis §6.2.6).

use crate::config::KeyframeConfig;
use crate::frame::FrameData;
use data::sequence::RgbPlanes;
use lie::{LieGroup, Sim3};
use slam::exploration::ExplorationKeyframe;
use slam::map::{KeyframeId, SlamGraph};
use std::collections::BTreeMap;
use std::sync::Arc;
use vision::image::{GrayImage, Image};

/// A keyframe's images and where it came from.
#[derive(Clone, Debug)]
pub struct KeyframeImages {
    /// The frame it was made from.
    pub frame_index: usize,
    /// That frame's timestamp.
    pub timestamp: f64,
    /// Grey image (level 0).
    pub gray: GrayImage,
    /// Depth in metres (`NaN` unknown).
    pub depth: Option<Image<f32>>,
    /// Colour planes, where the images have colour.
    pub colour: Option<RgbPlanes>,
}

impl KeyframeImages {
    /// The keyframe's images from its frame, without depth: a keyframe keeps a depth image
    /// only for the dense model (`SensorFrontEnd::keyframe_depth`, set by the caller).
    pub fn from_frame(frame: &FrameData) -> Self {
        KeyframeImages {
            frame_index: frame.index,
            timestamp: frame.timestamp,
            gray: frame.gray().clone(),
            depth: None,
            colour: frame.colour.clone(),
        }
    }

    /// The colour at pixel `(u, v)`: from the colour planes, or grey.
    pub fn colour_at(&self, u: f64, v: f64) -> [u8; 3] {
        let (x, y) = (
            (u.round().max(0.0) as usize).min(self.gray.width() - 1),
            (v.round().max(0.0) as usize).min(self.gray.height() - 1),
        );
        match &self.colour {
            Some([r, g, b]) => [r.get(x, y), g.get(x, y), b.get(x, y)],
            None => {
                let g = self.gray.get(x, y);
                [g, g, g]
            }
        }
    }
}

/// The keyframes' images, by id. Shared between the tracker, the keyframe pipeline's
/// front-end and the loop closer; written only when a keyframe is added.
#[derive(Clone, Debug, Default)]
pub struct KeyframeStore {
    images: BTreeMap<KeyframeId, Arc<KeyframeImages>>,
}

impl KeyframeStore {
    /// An empty store.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds keyframe `id`'s images.
    pub fn insert(&mut self, id: KeyframeId, images: KeyframeImages) {
        self.images.insert(id, Arc::new(images));
    }

    /// Removes keyframe `id`'s images.
    pub fn remove(&mut self, id: KeyframeId) {
        self.images.remove(&id);
    }

    /// Keyframe `id`'s images.
    pub fn get(&self, id: KeyframeId) -> Option<&Arc<KeyframeImages>> {
        self.images.get(&id)
    }

    /// Number of keyframes.
    pub fn len(&self) -> usize {
        self.images.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.images.is_empty()
    }

    /// All keyframes in id order.
    pub fn iter(&self) -> impl Iterator<Item = (KeyframeId, &Arc<KeyframeImages>)> {
        self.images.iter().map(|(&k, v)| (k, v))
    }
}

/// Why a frame becomes a keyframe (thesis §6.2.6: "the incremental translation/parallax
/// exceeded a threshold, or the number of tracked features dropped below a critical limit").
#[derive(Clone, Debug, PartialEq)]
pub enum KeyframeReason {
    /// The first frame.
    First,
    /// The first frame of a new map, started after the camera was lost
    /// (`tracker.new_map_after`).
    NewMap,
    /// The camera moved `distance / depth` of the scene depth away from every keyframe of
    /// `N1`.
    Parallax(f64),
    /// The camera rotated this many degrees away from every keyframe of `N1`.
    Rotation(f64),
    /// Only this fraction of the candidate points was found (monocular: of the map points the
    /// last keyframe measures).
    FewFound(f64),
    /// Monocular: only this many map points were tracked (`slam::exploration`'s
    /// `min_tracked_for_keyframe`).
    FewTracked(usize),
}

impl KeyframeReason {
    /// The reason of the monocular exploration's keyframe, `keyframe_distance` the unit of its
    /// baseline: a baseline is reported as a parallax (the distance over the scene depth, or
    /// the tracked points' median parallax in radians, as the baseline is measured).
    pub fn of_exploration(reason: ExplorationKeyframe, keyframe_distance: f64) -> Self {
        match reason {
            ExplorationKeyframe::Baseline(b) => KeyframeReason::Parallax(b * keyframe_distance),
            ExplorationKeyframe::Rotation(r) => KeyframeReason::Rotation(r.to_degrees()),
            ExplorationKeyframe::Thinning(f) => KeyframeReason::FewFound(f),
            ExplorationKeyframe::FewTracked(n) => KeyframeReason::FewTracked(n),
        }
    }

    /// A short name.
    pub fn name(&self) -> &'static str {
        match self {
            KeyframeReason::First => "first",
            KeyframeReason::NewMap => "new map",
            KeyframeReason::Parallax(_) => "parallax",
            KeyframeReason::Rotation(_) => "rotation",
            KeyframeReason::FewFound(_) => "few found",
            KeyframeReason::FewTracked(_) => "few tracked",
        }
    }
}

/// The keyframe nearest to a view, in the keyframe criterion's measure.
#[derive(Clone, Debug, PartialEq)]
pub struct NearestKeyframe {
    /// The keyframe.
    pub keyframe: KeyframeId,
    /// `max(parallax / config.parallax, rotation / config.rotation_deg)`: ≤ 1 when the
    /// keyframe covers the view.
    pub score: f64,
    /// Distance between the camera centres over the scene depth.
    pub parallax: f64,
    /// Angle between the viewing directions, degrees.
    pub rotation_deg: f64,
}

/// Of `keyframes`, the one nearest to the camera `camera_from_world` looking at a scene
/// `median_depth` away: a keyframe covers the view when the camera is within `parallax` of the
/// scene depth of it *and* within `rotation_deg` of its viewing direction, so the distance to a
/// keyframe is the larger of the two ratios. `None` when none has a pose.
pub fn nearest_keyframe<const N: usize>(
    config: &KeyframeConfig,
    graph: &SlamGraph<N>,
    keyframes: &[KeyframeId],
    camera_from_world: &Sim3,
    median_depth: f64,
) -> Option<NearestKeyframe> {
    let centre = |t: &Sim3| t.inverse().act(&nalgebra::Vector3::zeros());
    let here = centre(camera_from_world);
    let depth = median_depth.max(1e-3);
    keyframes
        .iter()
        .filter_map(|&k| graph.pose(k).ok().map(|t| (k, t)))
        .map(|(keyframe, t)| {
            let parallax = (centre(&t) - here).norm() / depth;
            let rotation_deg = camera_from_world
                .rotation()
                .compose(&t.rotation().inverse())
                .log()
                .norm()
                .to_degrees();
            NearestKeyframe {
                keyframe,
                score: (parallax / config.parallax).max(rotation_deg / config.rotation_deg),
                parallax,
                rotation_deg,
            }
        })
        .min_by(|a, b| a.score.total_cmp(&b.score))
}

/// The keyframe criterion for a tracked frame whose nearest keyframe is `nearest`
/// ([`nearest_keyframe`] over the reference's neighbourhood): `found` of the `searched`
/// candidate points were found. (Only frames with depth become keyframes, new points need it:
/// the caller checks.)
///
/// A new keyframe is added only when no keyframe near the reference covers the view (thesis
/// §3.3.3: "only add a new keyframe to the back-end if the distance to the closest keyframe
/// exceeds a threshold", which bounds the map while the camera browses a bounded place,
/// §6.5.2): a camera that turned away from its reference but looks where another nearby
/// keyframe looked adds nothing.
pub fn keyframe_reason(
    config: &KeyframeConfig,
    nearest: &NearestKeyframe,
    found: usize,
    searched: usize,
) -> Option<KeyframeReason> {
    if nearest.score > 1.0 {
        return Some(
            if nearest.parallax / config.parallax >= nearest.rotation_deg / config.rotation_deg {
                KeyframeReason::Parallax(nearest.parallax)
            } else {
                KeyframeReason::Rotation(nearest.rotation_deg)
            },
        );
    }
    // Few found points call for a keyframe only once the camera moved a little (a quarter of
    // either threshold from the nearest keyframe): a still camera would otherwise add the same
    // keyframe over and over.
    if searched > 0 && nearest.score > 0.25 {
        let fraction = found as f64 / searched as f64;
        if fraction < config.min_found_fraction {
            return Some(KeyframeReason::FewFound(fraction));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::So3;
    use nalgebra::Vector3;

    /// A camera at `centre` turned `yaw_deg` about the vertical: its `camera_from_world`.
    fn camera(centre: [f64; 3], yaw_deg: f64) -> Sim3 {
        let r = So3::exp(&Vector3::new(0.0, yaw_deg.to_radians(), 0.0));
        let c = Vector3::from(centre);
        let world_from_camera = Sim3::new(r, c, 1.0).unwrap();
        world_from_camera.inverse()
    }

    #[test]
    fn a_view_another_keyframe_covers_adds_no_keyframe() {
        let config = KeyframeConfig::default();
        let mut graph = SlamGraph::<3>::new();
        let reference = graph.add_keyframe(camera([0.0; 3], 0.0));
        let other = graph.add_keyframe(camera([0.05, 0.0, 0.0], 30.0));
        let both = [reference, other];
        // Turned 28° away from the reference, but 2° from the other keyframe, 2.5 cm from it at
        // 2 m depth: covered, nothing added.
        let here = camera([0.1, 0.0, 0.0], 28.0);
        let n = nearest_keyframe(&config, &graph, &both, &here, 2.0).unwrap();
        assert_eq!(n.keyframe, other);
        assert!(n.score < 1.0, "{n:?}");
        assert_eq!(keyframe_reason(&config, &n, 100, 100), None);
        // Without the other keyframe, the rotation calls for one.
        let n = nearest_keyframe(&config, &graph, &[reference], &here, 2.0).unwrap();
        assert!(matches!(
            keyframe_reason(&config, &n, 100, 100),
            Some(KeyframeReason::Rotation(r)) if (r - 28.0).abs() < 1e-6
        ));
        // Far from both (0.5 m at 2 m depth: 25 % parallax): a parallax keyframe.
        let far = camera([0.55, 0.0, 0.0], 30.0);
        let n = nearest_keyframe(&config, &graph, &both, &far, 2.0).unwrap();
        assert!(matches!(
            keyframe_reason(&config, &n, 100, 100),
            Some(KeyframeReason::Parallax(p)) if (p - 0.25).abs() < 1e-9
        ));
        // Few points found: a keyframe once the camera moved a little, not when it is still.
        let moved = camera([0.0; 3], 4.0);
        let n = nearest_keyframe(&config, &graph, &[reference], &moved, 2.0).unwrap();
        assert!(matches!(
            keyframe_reason(&config, &n, 10, 100),
            Some(KeyframeReason::FewFound(_))
        ));
        let n =
            nearest_keyframe(&config, &graph, &[reference], &camera([0.0; 3], 1.0), 2.0).unwrap();
        assert_eq!(keyframe_reason(&config, &n, 10, 100), None);
    }
}
