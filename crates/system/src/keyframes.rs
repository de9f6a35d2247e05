//! What the live system keeps of each keyframe beside the SLAM graph: its images (the patch
//! templates of the guided search are warped from the anchor keyframe's image, PTAM-style; the
//! dense model fuses its depth), and the keyframe criterion (thesis §6.2.6).

use crate::config::KeyframeConfig;
use crate::frame::FrameData;
use data::sequence::RgbPlanes;
use lie::{LieGroup, Sim3};
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
    /// The keyframe's images from its frame.
    pub fn from_frame(frame: &FrameData) -> Self {
        KeyframeImages {
            frame_index: frame.index,
            timestamp: frame.timestamp,
            gray: frame.gray().clone(),
            depth: frame.depth.clone(),
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
    /// The camera moved `distance / depth` of the scene depth away from every keyframe of
    /// `N1`.
    Parallax(f64),
    /// The camera rotated this many degrees away from the reference.
    Rotation(f64),
    /// Only this fraction of the candidate points was found.
    FewFound(f64),
}

impl KeyframeReason {
    /// A short name.
    pub fn name(&self) -> &'static str {
        match self {
            KeyframeReason::First => "first",
            KeyframeReason::Parallax(_) => "parallax",
            KeyframeReason::Rotation(_) => "rotation",
            KeyframeReason::FewFound(_) => "few found",
        }
    }
}

/// The keyframe criterion for a tracked frame with pose `camera_from_world`: `found` of the
/// `searched` candidate points were found; `median_depth` is the median depth of the found
/// points. (Only frames with depth become keyframes, new points need it: the caller checks.)
pub fn keyframe_reason<const N: usize>(
    config: &KeyframeConfig,
    graph: &SlamGraph<N>,
    camera_from_world: &Sim3,
    found: usize,
    searched: usize,
    median_depth: f64,
) -> Option<KeyframeReason> {
    let reference = graph.reference()?;
    let centre = |t: &Sim3| t.inverse().act(&nalgebra::Vector3::zeros());
    let here = centre(camera_from_world);
    let nearest = graph
        .n1(reference)
        .into_iter()
        .filter_map(|k| graph.pose(k).ok())
        .map(|t| (centre(&t) - here).norm())
        .fold(f64::INFINITY, f64::min);
    let t_ref = graph.pose(reference).ok()?;
    let rotation = camera_from_world
        .rotation()
        .compose(&t_ref.rotation().inverse())
        .log()
        .norm()
        .to_degrees();
    let parallax = nearest / median_depth.max(1e-3);
    if parallax > config.parallax {
        return Some(KeyframeReason::Parallax(parallax));
    }
    if rotation > config.rotation_deg {
        return Some(KeyframeReason::Rotation(rotation));
    }
    // Few found points call for a keyframe only once the camera moved a little (a quarter of
    // either threshold): a still camera would otherwise add the same keyframe over and over.
    let moved = parallax > 0.25 * config.parallax || rotation > 0.25 * config.rotation_deg;
    if searched > 0 && moved {
        let fraction = found as f64 / searched as f64;
        if fraction < config.min_found_fraction {
            return Some(KeyframeReason::FewFound(fraction));
        }
    }
    None
}
