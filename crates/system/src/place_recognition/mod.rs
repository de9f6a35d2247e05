//! Place recognition for large-scale loop closure (thesis §6.4.2).
//!
//! Small loops are closed metrically (§6.4.1: the points of `N2` searched for again); a large
//! loop, after which the camera returns with a pose estimate too far off for a guided search,
//! is found by appearance. As in the thesis:
//!
//! 1. **Words.** Every keyframe's ORB descriptors are quantised with a vocabulary trained
//!    offline on other images ([`vocabulary`]) into a tf-idf bag-of-words vector
//!    (`vision::bow`, Sivic & Zisserman 2003; binary words as in Gálvez-López & Tardós 2012,
//!    where the thesis used SURF), and the keyframe enters a database with an inverted file.
//! 2. **Hypotheses.** A query keyframe is scored against the database (`s = 1 − ½‖v − w‖₁`)
//!    except for the keyframes the caller excludes: the thesis "never [tries] to detect an
//!    appearance-based loop closure between two keyframes which are topologically close" —
//!    there metric loop closure is the better tool. Scores are normalised by the query's
//!    score against its best neighbour among the excluded keyframes (DBoW2's normalised
//!    similarity `η = s(v_q, v_j) / s(v_q, v_{q−Δt})`): the raw score of one place against
//!    another depends on how many and how common its words are — a textured view scores high
//!    against everything, a bland one low against its own revisit — while its score against
//!    a keyframe known to show the same place a moment earlier says what "the same place"
//!    scores here. Hypotheses need `η ≥ α`.
//! 3. **Verification.** The best hypotheses are checked geometrically ([`verify`]): ORB
//!    matches (ratio test, cross-check), 3D–3D correspondences from the keyframes' depths,
//!    the rigid motion of eq. 6.9 in a 3-point RANSAC, then guided matching under it; the loop
//!    is accepted with at least Θ RANSAC inliers. For monocular maps the depths come from
//!    kNN regression and the motion is a similarity (§5.3.1, [`Alignment::Sim3`]).
//!
//! The live system calls [`PlaceRecognition::add_keyframe`] for each new keyframe and
//! [`PlaceRecognition::detect`] with the keyframe's topological neighbourhood; an accepted
//! [`LoopCandidate`] goes into the graph through `slam::loop_closure::close_appearance_loop`.

pub mod features;
pub mod verify;
pub mod vocabulary;

pub use features::KeyframeFeatures;
pub use verify::Verification;
pub use vocabulary::{LoadedVocabulary, VocabularyError, VocabularyOrigin, load_vocabulary};

use geom::PinholeCamera;
use lie::Sim3;
use nalgebra::Vector2;
use slam::map::KeyframeId;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use vision::bow::{BowVector, Database, Vocabulary, score_l1};
use vision::image::GrayImage;
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
    /// relative spread (0.05; see [`features::depth_off_edges`]).
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
/// [`KeyframeFeatures`], their pixels and the descriptors' Hamming distance.
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

/// One hypothesis of a detection: a keyframe, its scores and, if it was verified, the result.
#[derive(Clone, Debug, PartialEq)]
pub struct Hypothesis {
    /// The old keyframe.
    pub old: KeyframeId,
    /// tf-idf score against the query.
    pub score: f64,
    /// Normalised score `η`.
    pub normalised_score: f64,
    /// The geometric check, if this hypothesis was among the best verified.
    pub verification: Option<Verification>,
}

/// Everything a detection looked at (for logs and evaluation); [`PlaceRecognition::detect`]
/// returns only its candidate.
#[derive(Clone, Debug, PartialEq)]
pub struct Detection {
    /// The neighbour that normalised the scores and its score; `None`: no neighbour in the
    /// database, or its score below `min_normaliser` (then nothing was tried).
    pub normaliser: Option<(KeyframeId, f64)>,
    /// The hypotheses with `η ≥ α`, best first (verified ones carry their result).
    pub hypotheses: Vec<Hypothesis>,
    /// The accepted loop: of the verified hypotheses, the one with the most inliers.
    pub candidate: Option<LoopCandidate>,
}

struct Entry {
    features: KeyframeFeatures,
    bow: BowVector,
}

/// The keyframe database of large-scale loop closure (see the [module docs](self)).
pub struct PlaceRecognition {
    vocabulary: Arc<Vocabulary>,
    config: PlaceRecognitionConfig,
    database: Database,
    /// Database entry → keyframe (`None` once removed).
    entry_keyframe: Vec<Option<KeyframeId>>,
    keyframes: BTreeMap<KeyframeId, Entry>,
}

impl PlaceRecognition {
    /// An empty database over a vocabulary (see [`load_vocabulary`]).
    pub fn new(
        vocabulary: Arc<Vocabulary>,
        config: PlaceRecognitionConfig,
    ) -> Result<Self, PlaceRecognitionError> {
        config.validate()?;
        Ok(PlaceRecognition {
            vocabulary,
            config,
            database: Database::new(),
            entry_keyframe: Vec::new(),
            keyframes: BTreeMap::new(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &PlaceRecognitionConfig {
        &self.config
    }

    /// The vocabulary.
    pub fn vocabulary(&self) -> &Arc<Vocabulary> {
        &self.vocabulary
    }

    /// Keyframes in the database.
    pub fn len(&self) -> usize {
        self.keyframes.len()
    }

    /// `true` when no keyframe was added.
    pub fn is_empty(&self) -> bool {
        self.keyframes.is_empty()
    }

    /// The features stored for a keyframe.
    pub fn features(&self, id: KeyframeId) -> Option<&KeyframeFeatures> {
        self.keyframes.get(&id).map(|e| &e.features)
    }

    /// Extracts a keyframe's features (ORB, and the back-projected point of every keypoint
    /// where `depth(u, v)` gives metres; see [`features::extract`]) and adds it to the
    /// database. Returns the number of keypoints with a 3D point.
    pub fn add_keyframe(
        &mut self,
        id: KeyframeId,
        image: &GrayImage,
        depth: impl Fn(usize, usize) -> Option<f64>,
        camera: &PinholeCamera,
    ) -> Result<usize, PlaceRecognitionError> {
        if self.keyframes.contains_key(&id) {
            return Err(PlaceRecognitionError::Duplicate(id));
        }
        let f = features::extract(image, depth, Vec::new(), camera, &self.config)?;
        let n = f.with_depth();
        self.insert(id, f)?;
        Ok(n)
    }

    /// [`add_keyframe`](Self::add_keyframe) for a monocular keyframe: no depth image, its map
    /// points' `(pixel, depth)` samples for the depth regression of [`Alignment::Sim3`].
    pub fn add_monocular_keyframe(
        &mut self,
        id: KeyframeId,
        image: &GrayImage,
        depth_samples: Vec<(Vector2<f64>, f64)>,
        camera: &PinholeCamera,
    ) -> Result<(), PlaceRecognitionError> {
        if self.keyframes.contains_key(&id) {
            return Err(PlaceRecognitionError::Duplicate(id));
        }
        let f = features::extract(image, |_, _| None, depth_samples, camera, &self.config)?;
        self.insert(id, f)
    }

    /// Adds features extracted elsewhere (e.g. by the tracking thread with
    /// [`features::extract`]).
    pub fn insert(
        &mut self,
        id: KeyframeId,
        features: KeyframeFeatures,
    ) -> Result<(), PlaceRecognitionError> {
        if self.keyframes.contains_key(&id) {
            return Err(PlaceRecognitionError::Duplicate(id));
        }
        let bow = self.vocabulary.transform(&features.descriptors);
        let entry = self.database.add(bow.clone());
        debug_assert_eq!(entry, self.entry_keyframe.len());
        self.entry_keyframe.push(Some(id));
        self.keyframes.insert(id, Entry { features, bow });
        Ok(())
    }

    /// Removes a keyframe (culled from the map): it is never proposed again. `false` if it was
    /// not in the database.
    pub fn remove_keyframe(&mut self, id: KeyframeId) -> bool {
        if self.keyframes.remove(&id).is_none() {
            return false;
        }
        for e in self.entry_keyframe.iter_mut() {
            if *e == Some(id) {
                *e = None;
            }
        }
        true
    }

    /// The loop of keyframe `query` with an old keyframe outside `excluded` (its topological
    /// neighbourhood; see the [module docs](self)), if one is verified.
    pub fn detect(
        &self,
        query: KeyframeId,
        excluded: &BTreeSet<KeyframeId>,
    ) -> Result<Option<LoopCandidate>, PlaceRecognitionError> {
        Ok(self.detect_with_report(query, excluded)?.candidate)
    }

    /// [`detect`](Self::detect) with everything it looked at.
    pub fn detect_with_report(
        &self,
        query: KeyframeId,
        excluded: &BTreeSet<KeyframeId>,
    ) -> Result<Detection, PlaceRecognitionError> {
        let q = self
            .keyframes
            .get(&query)
            .ok_or(PlaceRecognitionError::Unknown(query))?;
        let normaliser = excluded
            .iter()
            .filter(|&&k| k != query)
            .filter_map(|k| {
                self.keyframes
                    .get(k)
                    .map(|e| (*k, score_l1(&q.bow, &e.bow)))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
            .filter(|(_, s)| *s >= self.config.min_normaliser && *s > 0.0);
        let Some((_, eta)) = normaliser else {
            return Ok(Detection {
                normaliser: None,
                hypotheses: Vec::new(),
                candidate: None,
            });
        };
        let mut hypotheses: Vec<Hypothesis> = self
            .database
            .query(&q.bow, usize::MAX)
            .into_iter()
            .filter_map(|(entry, score)| {
                let id = self.entry_keyframe[entry]?;
                (id != query && !excluded.contains(&id)).then_some((id, score))
            })
            .map(|(old, score)| Hypothesis {
                old,
                score,
                normalised_score: score / eta,
                verification: None,
            })
            .filter(|h| h.normalised_score >= self.config.min_normalised_score)
            .collect();
        let candidate = self.verify_best(query.0, &q.features, &mut hypotheses);
        Ok(Detection {
            normaliser,
            hypotheses,
            candidate,
        })
    }

    /// Relocalisation of a frame the tracker lost (ORB-SLAM's, Mur-Artal et al. 2015, with
    /// this module's verification): the keyframes scored against the frame's words, the best
    /// [`max_verifications`](PlaceRecognitionConfig::max_verifications) verified as a loop's
    /// hypotheses are, and the one with the most inliers returned (`query_from_old` is then
    /// `camera_from_old`). No normalisation: a lost frame has no neighbour known to show its
    /// place, and there is no neighbourhood to exclude; the geometric check (Θ inliers of the
    /// 3-point RANSAC) is the test. `seed` makes the RANSAC reproducible (the frame's index).
    /// A frame without depth (a monocular camera: no 3D points, no depth samples) is verified
    /// 2D–3D, by P3P RANSAC against the old keyframe's points ([`verify::verify_absolute`]);
    /// `query_from_old` is then rigid in the old keyframe's camera units.
    pub fn relocalise(&self, seed: u32, features: &KeyframeFeatures) -> Option<LoopCandidate> {
        let bow = self.vocabulary.transform(&features.descriptors);
        let mut hypotheses: Vec<Hypothesis> = self
            .database
            .query(&bow, usize::MAX)
            .into_iter()
            .filter_map(|(entry, score)| {
                Some(Hypothesis {
                    old: self.entry_keyframe[entry]?,
                    score,
                    normalised_score: score,
                    verification: None,
                })
            })
            .collect();
        if features.with_depth() == 0 && features.depth_samples.is_empty() {
            self.verify_best_with(seed, features, &mut hypotheses, verify::verify_absolute)
        } else {
            self.verify_best(seed, features, &mut hypotheses)
        }
    }

    /// Verifies the best [`max_verifications`](PlaceRecognitionConfig::max_verifications) of
    /// `hypotheses` (best first) against the `query` features, recording each result; returns
    /// the accepted one with the most inliers.
    fn verify_best(
        &self,
        seed: u32,
        query: &KeyframeFeatures,
        hypotheses: &mut [Hypothesis],
    ) -> Option<LoopCandidate> {
        self.verify_best_with(seed, query, hypotheses, verify::verify)
    }

    /// [`verify_best`](Self::verify_best) with the verification `verify`.
    fn verify_best_with(
        &self,
        seed: u32,
        query: &KeyframeFeatures,
        hypotheses: &mut [Hypothesis],
        verify: impl Fn(
            (u32, &KeyframeFeatures),
            (u32, &KeyframeFeatures),
            &PlaceRecognitionConfig,
        ) -> Verification,
    ) -> Option<LoopCandidate> {
        let mut candidate: Option<LoopCandidate> = None;
        for h in hypotheses.iter_mut().take(self.config.max_verifications) {
            let old = &self.keyframes[&h.old].features;
            let v = verify((seed, query), (h.old.0, old), &self.config);
            if let Verification::Accepted {
                query_from_old,
                ransac_inliers,
                inliers,
            } = &v
                && candidate
                    .as_ref()
                    .is_none_or(|c| inliers.len() > c.inliers.len())
            {
                candidate = Some(LoopCandidate {
                    old: h.old,
                    query_from_old: *query_from_old,
                    inliers: inliers.clone(),
                    ransac_inliers: *ransac_inliers,
                    score: h.score,
                    normalised_score: h.normalised_score,
                });
            }
            h.verification = Some(v);
        }
        candidate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loop-closure thread owns the database; the vocabulary is shared.
    #[test]
    fn the_database_can_move_to_another_thread() {
        fn send_sync<T: Send + Sync>() {}
        send_sync::<PlaceRecognition>();
        send_sync::<LoopCandidate>();
    }

    #[test]
    fn config_deserialises_with_defaults_and_rejects_unknown_fields() {
        let c: PlaceRecognitionConfig =
            serde_saphyr::from_str("min_inliers: 25\norb:\n  features: 1500\nalignment: sim3\n")
                .unwrap();
        assert_eq!(c.min_inliers, 25);
        assert_eq!(c.orb.features, 1500);
        assert_eq!(c.orb.levels, 8);
        assert_eq!(c.alignment, Alignment::Sim3);
        assert_eq!(c.ratio, PlaceRecognitionConfig::default().ratio);
        assert!(serde_saphyr::from_str::<PlaceRecognitionConfig>("min_inlier: 3\n").is_err());
        assert!(
            PlaceRecognitionConfig {
                min_inliers: 2,
                ..c.clone()
            }
            .validate()
            .is_err()
        );
        assert!(c.validate().is_ok());
        assert!((PlaceRecognitionConfig::default().inlier_gate() - 11.345f64.sqrt()).abs() < 1e-3);
    }
}
