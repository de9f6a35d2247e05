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
mod types;
pub mod verify;
pub mod vocabulary;

pub use features::KeyframeFeatures;
pub use types::{
    Alignment, LoopCandidate, OrbConfig, PlaceRecognitionConfig, PlaceRecognitionError,
};
pub use verify::Verification;

use geom::PinholeCamera;
use nalgebra::Vector2;
use slam::map::KeyframeId;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use vision::bow::{BowVector, Database, Vocabulary, score_l1};
use vision::image::GrayImage;

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
    /// Its id in the database.
    entry: usize,
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

    /// The features stored for a keyframe.
    pub fn features(&self, id: KeyframeId) -> Option<&KeyframeFeatures> {
        self.keyframes.get(&id).map(|e| &e.features)
    }

    /// Every keyframe's features, in id order (a map file stores them).
    pub fn entries(&self) -> impl Iterator<Item = (KeyframeId, &KeyframeFeatures)> {
        self.keyframes.iter().map(|(&k, e)| (k, &e.features))
    }

    /// Extracts a keyframe's features (ORB, and the back-projected point of every keypoint
    /// where `depth(u, v)` gives metres; see [`features::extract`]) and adds it to the
    /// database. Returns the number of keypoints with a 3D point. (The live system extracts
    /// features outside the database's lock and [`insert`](Self::insert)s them.)
    #[cfg(test)]
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
        let depth = features::off_edges(depth, self.config.depth_edge_ratio);
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
        self.keyframes.insert(
            id,
            Entry {
                features,
                bow,
                entry,
            },
        );
        Ok(())
    }

    /// Removes a keyframe (culled from the map): it is never detected or relocalised again.
    /// Returns whether it was there.
    pub fn remove(&mut self, id: KeyframeId) -> bool {
        let Some(e) = self.keyframes.remove(&id) else {
            return false;
        };
        self.database.remove(e.entry);
        self.entry_keyframe[e.entry] = None;
        true
    }

    /// Whether keyframe `id` is in the database.
    pub fn contains(&self, id: KeyframeId) -> bool {
        self.keyframes.contains_key(&id)
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
