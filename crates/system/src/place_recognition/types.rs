//! The types of place recognition that every part of it shares — its configuration, its
//! errors, a verified loop — in a leaf module that imports none of the others.

use lie::Sim3;
use nalgebra::Vector2;
use slam::map::KeyframeId;
use vision::orb::OrbParams;

/// The ORB extractor of place recognition (the vocabulary must be trained with the same).
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OrbConfig {
    /// Features per image: 1000, ORB-SLAM's choice for 640×480 images (enough matches for Θ
    /// inliers after a viewpoint change that keeps a third of them).
    pub features: usize,
    /// Scale between pyramid levels (OpenCV's and ORB-SLAM's 1.2).
    pub scale_factor: f32,
    /// Pyramid levels (8: scale changes up to 1.2⁷ ≈ 3.6, a revisit from 3.6× the distance).
    pub levels: usize,
    /// FAST threshold (OpenCV's 20).
    pub fast_threshold: u8,
}

impl Default for OrbConfig {
    fn default() -> Self {
        OrbConfig {
            features: 1000,
            scale_factor: 1.2,
            levels: 8,
            fast_threshold: 20,
        }
    }
}

impl OrbConfig {
    /// The extractor's parameters (edge threshold 31: the BRIEF patch).
    pub fn params(&self) -> OrbParams {
        OrbParams {
            num_features: self.features,
            scale_factor: self.scale_factor,
            num_levels: self.levels,
            fast_threshold: self.fast_threshold,
            ..OrbParams::default()
        }
    }
}

/// The motion a loop is verified with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// Rigid (stereo, RGB-D: metric depths; thesis eq. 6.9).
    #[default]
    Se3,
    /// Similarity (monocular maps: regressed depths, scale drift; thesis §5.3.1).
    Sim3,
}

/// Every threshold of place recognition, with its reason. Deserialises from the live system's
/// YAML config (missing fields keep their defaults).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlaceRecognitionConfig {
    /// The feature extractor.
    pub orb: OrbConfig,
    /// A keypoint's depth is used only if its 3×3 neighbourhood's depths lie within this
    /// relative spread (0.05; see `crate::frame::depth_off_edges`).
    pub depth_edge_ratio: f64,
    /// No detection when the query's best score against its neighbours is below this
    /// (0.005: DLoopDetector's `min_nss_factor`; the normalisation is meaningless then).
    pub min_normaliser: f64,
    /// Normalised score `η` a hypothesis needs (0.3: DLoopDetector's `α`).
    pub min_normalised_score: f64,
    /// Hypotheses verified per query, best `η` first (3: verification costs a few ms; a true
    /// revisit is among the best few scores, and more rarely adds loops, only cost).
    pub max_verifications: usize,
    /// Largest Hamming distance of a descriptor match (64 of 256 bits: random BRIEF pairs
    /// differ in 128 ± 8 bits, so 64 is 8σ from chance, while true matches under a revisit's
    /// viewpoint change typically stay below 50).
    pub max_hamming: u32,
    /// Lowe's ratio of the best to the second-best distance (0.8: Lowe 2004 — discards 90 % of
    /// false matches while losing under 5 % of the correct ones).
    pub ratio: f32,
    /// Keypoint position noise at pyramid level 0, pixels (1 px; scaled by the level's scale).
    pub pixel_sigma: f64,
    /// Depth noise coefficient `c` of `σ_z = c·z²`, 1/m. Default 1.425·10⁻³ /m: the Kinect's
    /// measured depth noise (Khoshelham & Elberink 2012; 5.7 mm at 2 m). A stereo camera has
    /// `c = σ_d/(f·b)` (disparity noise σ_d pixels, focal length f pixels, baseline b metres):
    /// see [`PlaceRecognitionConfig::for_stereo`]. Not read from the live system's config file:
    /// the system sets it from its sensor (`SystemConfig::depth_noise`).
    #[serde(skip)]
    pub depth_noise: f64,
    /// Probability mass of the inlier gate on the 3D Mahalanobis distance (0.99: χ²₃ gate
    /// √11.34 = 3.37σ, a true correspondence is rejected once in a hundred).
    pub inlier_probability: f64,
    /// RANSAC's probability of drawing one all-inlier sample (0.999).
    pub ransac_confidence: f64,
    /// RANSAC's sample bound (2000: at 20 % inliers, p = 0.999 needs ⌈ln 0.001 / ln(1 −
    /// 0.2³)⌉ = 861 samples; fewer inliers than that cannot reach Θ among ~100 matches).
    pub ransac_max_iterations: usize,
    /// RANSAC seed (mixed with the keyframe ids per hypothesis).
    pub seed: u64,
    /// Θ: RANSAC inliers a loop needs (20: the thesis's 15–30; three points define the motion,
    /// twenty agreeing make a chance agreement of outliers negligible).
    pub min_inliers: usize,
    /// Radius of guided matching around a prediction, pixels at level 0 (4 px × the level's
    /// scale: a motion from ≥ Θ inliers predicts to ~1–2 px).
    pub guided_radius: f64,
    /// Rigid (stereo, RGB-D) or similarity (monocular) verification.
    pub alignment: Alignment,
}

impl Default for PlaceRecognitionConfig {
    fn default() -> Self {
        PlaceRecognitionConfig {
            orb: OrbConfig::default(),
            depth_edge_ratio: 0.05,
            min_normaliser: 0.005,
            min_normalised_score: 0.3,
            max_verifications: 3,
            max_hamming: 64,
            ratio: 0.8,
            pixel_sigma: 1.0,
            depth_noise: 1.425e-3,
            inlier_probability: 0.99,
            ransac_confidence: 0.999,
            ransac_max_iterations: 2000,
            seed: 0,
            min_inliers: 20,
            guided_radius: 4.0,
            alignment: Alignment::Se3,
        }
    }
}

impl PlaceRecognitionConfig {
    /// The defaults for a rectified stereo camera: `c = σ_d/(f·b)` with a disparity noise of
    /// σ_d = 0.5 px (sub-pixel block matching), focal length `fx` pixels and baseline metres.
    pub fn for_stereo(fx: f64, baseline: f64) -> Self {
        PlaceRecognitionConfig {
            depth_noise: 0.5 / (fx * baseline),
            ..Self::default()
        }
    }

    /// The inlier gate on the Mahalanobis distance, `√χ²₃(inlier_probability)`.
    pub fn inlier_gate(&self) -> f64 {
        lsq::chi2_quantile(3, self.inlier_probability).sqrt()
    }

    /// Checks every value's range; the message names the field.
    pub fn validate(&self) -> Result<(), PlaceRecognitionError> {
        let bad =
            |field: &str, why: &str| Err(PlaceRecognitionError::Config(format!("{field}: {why}")));
        let positive = |x: f64| x.is_finite() && x > 0.0;
        let probability = |x: f64| x > 0.0 && x < 1.0;
        if self.orb.features == 0 || self.orb.levels == 0 {
            return bad("orb", "features and levels must be positive");
        }
        if !(self.orb.scale_factor > 1.0 && self.orb.scale_factor.is_finite()) {
            return bad("orb.scale_factor", "must be > 1");
        }
        if !positive(self.depth_edge_ratio) {
            return bad("depth_edge_ratio", "must be positive");
        }
        if !(self.min_normaliser.is_finite() && self.min_normaliser >= 0.0) {
            return bad("min_normaliser", "must be ≥ 0");
        }
        if !(self.min_normalised_score.is_finite() && self.min_normalised_score >= 0.0) {
            return bad("min_normalised_score", "must be ≥ 0");
        }
        if self.max_verifications == 0 {
            return bad("max_verifications", "must be positive");
        }
        if !(self.ratio > 0.0 && self.ratio <= 1.0) {
            return bad("ratio", "must lie in (0, 1]");
        }
        if !positive(self.pixel_sigma) || !positive(self.depth_noise) {
            return bad("pixel_sigma, depth_noise", "must be positive");
        }
        if !probability(self.inlier_probability) || !probability(self.ransac_confidence) {
            return bad(
                "inlier_probability, ransac_confidence",
                "must lie in (0, 1)",
            );
        }
        if self.ransac_max_iterations == 0 {
            return bad("ransac_max_iterations", "must be positive");
        }
        if self.min_inliers < 3 {
            return bad("min_inliers", "must be at least 3 (a minimal sample)");
        }
        if !positive(self.guided_radius) {
            return bad("guided_radius", "must be positive");
        }
        Ok(())
    }
}

/// Why place recognition failed (a failed detection is not an error: `Ok(None)`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlaceRecognitionError {
    /// A configuration value is out of range.
    #[error("place recognition config: {0}")]
    Config(String),
    /// The keyframe is already in the database.
    #[error("{0} is already in the place-recognition database")]
    Duplicate(KeyframeId),
    /// The keyframe is not in the database.
    #[error("{0} is not in the place-recognition database")]
    Unknown(KeyframeId),
    /// The image cannot be described (empty).
    #[error("cannot extract ORB features: {0}")]
    Image(String),
}

/// One verified correspondence of a loop: keypoint indices into the two keyframes'
/// `KeyframeFeatures`, their pixels and the descriptors' Hamming distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopMatch {
    /// Keypoint index in the query keyframe.
    pub query: usize,
    /// Keypoint index in the old keyframe.
    pub old: usize,
    /// The query keypoint (level-0 pixels).
    pub query_pixel: Vector2<f64>,
    /// The old keypoint.
    pub old_pixel: Vector2<f64>,
    /// Hamming distance of their descriptors.
    pub distance: u32,
}

/// An accepted large loop: the query keyframe sees the place of `old`.
#[derive(Clone, Debug, PartialEq)]
pub struct LoopCandidate {
    /// The old keyframe.
    pub old: KeyframeId,
    /// `x_query = S·x_old` for camera-frame points (scale 1 for SE(3)): the measurement of
    /// the graph edge `E_old,query` (thesis §6.4.2).
    pub query_from_old: Sim3,
    /// The correspondences consistent with it (after guided matching).
    pub inliers: Vec<LoopMatch>,
    /// Inliers of the RANSAC on the appearance matches alone (≥ Θ).
    pub ransac_inliers: usize,
    /// Its tf-idf score against the query.
    pub score: f64,
    /// Its normalised score `η`.
    pub normalised_score: f64,
}
