//! Random sample consensus (Fischler & Bolles 1981) with a seeded random number generator,
//! generic over the minimal solver (thesis §3.5: 8-point RANSAC for bootstrapping; §5.3.1:
//! 3-point similarity RANSAC for loop closure).
//!
//! An [`Estimator`] knows its data, fits models to minimal samples (none when the sample is
//! degenerate, several when the minimal problem has several solutions) and measures the error
//! of each datum under a model. [`ransac`] draws minimal samples uniformly without replacement,
//! scores every hypothesis by the truncated quadratic loss of MSAC (Torr & Zisserman 2000),
//!
//! `C(M) = Σᵢ min(eᵢ(M), τ)²`,
//!
//! re-fits each hypothesis that beats the best minimal-sample hypothesis so far to its inliers
//! while that lowers the cost (the local optimisation of LO-RANSAC, Chum, Matas & Kittler 2003:
//! minimal samples of noisy data give poor models, their inlier sets good ones), keeps the best
//! optimised model, and stops after
//!
//! `k = ⌈log(1 − p) / log(1 − wˢ)⌉`
//!
//! iterations, where `w` is the best inlier ratio found so far, `s` the sample size and `p` the
//! required confidence of having drawn one all-inlier sample (bounded by
//! [`RansacConfig::max_iterations`]). The same seed gives the same result.

use crate::align::{AlignError, ScaleEstimate, align_sim3_with};
use lie::{LieGroup, Sim3};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A model-fitting problem for [`ransac`].
pub trait Estimator {
    /// The model type.
    type Model: Clone;

    /// Number of data (correspondences).
    fn num_data(&self) -> usize;

    /// Size of a minimal sample.
    fn sample_size(&self) -> usize;

    /// Appends the models that fit the minimal sample (indices into the data) to `models`;
    /// appends nothing when the sample is degenerate.
    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Self::Model>);

    /// A model fitted to a larger set of inliers (least squares, starting from or near
    /// `current`, the model whose inliers they are), or `None` (the default) if the estimator
    /// has no such refinement or the set is degenerate.
    fn fit_inliers(&self, _inliers: &[usize], _current: &Self::Model) -> Option<Self::Model> {
        None
    }

    /// The error of datum `i` under `model`, a non-negative distance compared with
    /// [`RansacConfig::threshold`] (`∞` when undefined, e.g. a point behind a camera).
    fn error(&self, model: &Self::Model, i: usize) -> f64;

    /// [`Estimator::error`] where it is at most `threshold`, and any value above `threshold`
    /// where it is not: all RANSAC asks of a datum (MSAC charges an outlier `τ²` whatever its
    /// error). An estimator whose error is costly overrides it with a cheap bound that settles
    /// most outliers of a wrong model without computing their error.
    fn error_within(&self, model: &Self::Model, i: usize, _threshold: f64) -> f64 {
        self.error(model, i)
    }
}

/// Parameters of [`ransac`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RansacConfig {
    /// Inlier threshold `τ` on [`Estimator::error`].
    pub threshold: f64,
    /// Required probability `p` of drawing at least one all-inlier sample.
    pub confidence: f64,
    /// Upper bound on the number of samples drawn.
    pub max_iterations: usize,
    /// Lower bound on the number of samples drawn.
    pub min_iterations: usize,
    /// Seed of the sampler.
    pub seed: u64,
}

impl Default for RansacConfig {
    /// `τ = 1`, `p = 0.999`, between 10 and 10 000 samples, seed 0.
    fn default() -> Self {
        RansacConfig {
            threshold: 1.0,
            confidence: 0.999,
            max_iterations: 10_000,
            min_iterations: 10,
            seed: 0,
        }
    }
}

/// The outcome of [`ransac`].
#[derive(Clone, Debug, PartialEq)]
pub struct RansacResult<M> {
    /// The best model (re-estimated from its inliers when that lowered the cost).
    pub model: M,
    /// Indices of the data within the threshold, ascending.
    pub inliers: Vec<usize>,
    /// Samples drawn.
    pub iterations: usize,
    /// Samples that gave no model (degenerate).
    pub degenerate_samples: usize,
}

/// Why [`ransac`] found no model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RansacError {
    /// Fewer data than a minimal sample.
    #[error("RANSAC needs at least {needed} data, got {got}")]
    TooFewData {
        /// The sample size.
        needed: usize,
        /// The number of data.
        got: usize,
    },
    /// The configuration is unusable (non-positive threshold, confidence outside (0, 1), no
    /// iterations).
    #[error("invalid RANSAC configuration: {0}")]
    InvalidConfig(&'static str),
    /// Every sample drawn was degenerate, or no model had a single inlier.
    #[error("no model found in {iterations} samples ({degenerate} degenerate)")]
    NoModel {
        /// Samples drawn.
        iterations: usize,
        /// Of which degenerate.
        degenerate: usize,
    },
}

fn msac_cost<E: Estimator>(estimator: &E, model: &E::Model, threshold: f64) -> (f64, usize) {
    let mut cost = 0.0;
    let mut inliers = 0;
    for i in 0..estimator.num_data() {
        let e = estimator.error_within(model, i, threshold);
        if e <= threshold {
            inliers += 1;
            cost += e * e;
        } else {
            cost += threshold * threshold;
        }
    }
    (cost, inliers)
}

fn inlier_set<E: Estimator>(estimator: &E, model: &E::Model, threshold: f64) -> Vec<usize> {
    (0..estimator.num_data())
        .filter(|&i| estimator.error_within(model, i, threshold) <= threshold)
        .collect()
}

/// The number of samples needed to draw an all-inlier sample of size `sample_size` with
/// probability `confidence` when a fraction `inlier_ratio` of the data are inliers.
pub fn required_iterations(inlier_ratio: f64, sample_size: usize, confidence: f64) -> usize {
    let good = inlier_ratio.clamp(0.0, 1.0).powi(sample_size as i32);
    if good >= 1.0 {
        return 1;
    }
    if good <= 0.0 {
        return usize::MAX;
    }
    let k = (1.0 - confidence).ln() / (1.0 - good).ln();
    if k.is_finite() {
        k.ceil().max(1.0) as usize
    } else {
        usize::MAX
    }
}

/// Re-fits `model` to its inliers ([`Estimator::fit_inliers`]) while that lowers the MSAC cost,
/// at most 10 times.
fn local_optimisation<E: Estimator>(
    estimator: &E,
    mut model: E::Model,
    mut cost: f64,
    mut inliers: usize,
    config: &RansacConfig,
) -> (E::Model, f64, usize) {
    for _ in 0..10 {
        let set = inlier_set(estimator, &model, config.threshold);
        let Some(refined) = estimator.fit_inliers(&set, &model) else {
            break;
        };
        let (c, i) = msac_cost(estimator, &refined, config.threshold);
        if c >= cost {
            break;
        }
        let converged = cost - c <= 1e-12 * cost;
        (model, cost, inliers) = (refined, c, i);
        if converged {
            break;
        }
    }
    (model, cost, inliers)
}

/// Robustly fits a model (see the [module docs](self)).
pub fn ransac<E: Estimator>(
    estimator: &E,
    config: &RansacConfig,
) -> Result<RansacResult<E::Model>, RansacError> {
    search(estimator, config, None)
}

/// When [`ransac_or_give_up`] gives up: after `after` samples, if the best hypothesis so far
/// has fewer than `below` inliers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GiveUp {
    /// Samples drawn before the check.
    pub after: usize,
    /// Inliers the best hypothesis needs by then for the search to go on.
    pub below: usize,
}

/// [`ransac`], except that the search ends early where `give_up` says (a verification that
/// needs a consensus of some size refusing data that show no sign of one). Where it does not
/// give up, the result is [`ransac`]'s with the same configuration: the same samples in the
/// same order. Where it does, the best hypothesis so far.
pub fn ransac_or_give_up<E: Estimator>(
    estimator: &E,
    config: &RansacConfig,
    give_up: GiveUp,
) -> Result<RansacResult<E::Model>, RansacError> {
    search(estimator, config, Some(give_up))
}

fn search<E: Estimator>(
    estimator: &E,
    config: &RansacConfig,
    give_up: Option<GiveUp>,
) -> Result<RansacResult<E::Model>, RansacError> {
    let n = estimator.num_data();
    let s = estimator.sample_size();
    if !(config.threshold > 0.0 && config.threshold.is_finite()) {
        return Err(RansacError::InvalidConfig("threshold must be positive"));
    }
    if !(config.confidence > 0.0 && config.confidence < 1.0) {
        return Err(RansacError::InvalidConfig("confidence must lie in (0, 1)"));
    }
    if config.max_iterations == 0 {
        return Err(RansacError::InvalidConfig(
            "max_iterations must be positive",
        ));
    }
    if s == 0 || n < s {
        return Err(RansacError::TooFewData { needed: s, got: n });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut best: Option<(E::Model, f64, usize)> = None;
    let mut best_raw = f64::INFINITY;
    let mut models = Vec::new();
    let mut needed = config.max_iterations;
    let mut iterations = 0;
    let mut degenerate = 0;
    while iterations < needed.max(config.min_iterations).min(config.max_iterations) {
        if let Some(g) = give_up
            && iterations == g.after
            && best.as_ref().is_none_or(|b| b.2 < g.below)
        {
            break;
        }
        iterations += 1;
        let sample = rand::seq::index::sample(&mut rng, n, s).into_vec();
        models.clear();
        estimator.fit_minimal(&sample, &mut models);
        if models.is_empty() {
            degenerate += 1;
            continue;
        }
        for m in models.drain(..) {
            let (cost, inliers) = msac_cost(estimator, &m, config.threshold);
            // Local optimisation (LO-RANSAC, Chum et al. 2003): each hypothesis that is the
            // best *minimal-sample* model so far is re-fitted to its inliers while that lowers
            // the cost; the optimised model replaces the best one if it is better. Comparing
            // raw hypotheses with the best raw one (not the optimised one) keeps giving new
            // basins a chance: a minimal sample of noisy points rarely beats an optimised model.
            if inliers > 0 && cost < best_raw {
                best_raw = cost;
                let (m, cost, inliers) = local_optimisation(estimator, m, cost, inliers, config);
                if best.as_ref().is_none_or(|b| cost < b.1) {
                    needed = required_iterations(inliers as f64 / n as f64, s, config.confidence);
                    best = Some((m, cost, inliers));
                }
            }
        }
    }
    let Some((model, _, _)) = best else {
        return Err(RansacError::NoModel {
            iterations,
            degenerate,
        });
    };
    let inliers = inlier_set(estimator, &model, config.threshold);
    Ok(RansacResult {
        model,
        inliers,
        iterations,
        degenerate_samples: degenerate,
    })
}

/// The 3-point similarity of thesis eq. 5.9–5.14 as a RANSAC problem: correspondences
/// `target_i ≈ S·source_i`, minimal samples of 3 solved in closed form (Arun / Umeyama, via
/// [`crate::align`]), error `‖target_i − S·source_i‖`. Degenerate samples (coincident or
/// collinear points) give no model, never a division by zero.
#[derive(Clone, Copy, Debug)]
pub struct Sim3Estimator<'a> {
    /// The points `x_i` in the target frame.
    pub target: &'a [Vector3<f64>],
    /// The points `x̄_i` in the source frame.
    pub source: &'a [Vector3<f64>],
}

impl Sim3Estimator<'_> {
    fn fit(&self, indices: &[usize], scale: ScaleEstimate) -> Result<Sim3, AlignError> {
        let t: Vec<Vector3<f64>> = indices.iter().map(|&i| self.target[i]).collect();
        let s: Vec<Vector3<f64>> = indices.iter().map(|&i| self.source[i]).collect();
        align_sim3_with(&t, &s, scale)
    }
}

impl Estimator for Sim3Estimator<'_> {
    type Model = Sim3;

    fn num_data(&self) -> usize {
        self.target.len().min(self.source.len())
    }

    fn sample_size(&self) -> usize {
        3
    }

    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Sim3>) {
        // Thesis eq. 5.14: the symmetric scale.
        if let Ok(s) = self.fit(sample, ScaleEstimate::Symmetric) {
            models.push(s);
        }
    }

    fn fit_inliers(&self, inliers: &[usize], _current: &Sim3) -> Option<Sim3> {
        self.fit(inliers, ScaleEstimate::LeastSquares).ok()
    }

    fn error(&self, model: &Sim3, i: usize) -> f64 {
        (self.target[i] - model.act(&self.source[i])).norm()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::So3;
    use rand::Rng;

    fn random_points(rng: &mut ChaCha8Rng, n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-3.0..3.0),
                    rng.random_range(2.0..8.0),
                )
            })
            .collect()
    }

    /// Half the correspondences replaced by random points: the 3-point similarity RANSAC
    /// recovers the true similarity and exactly the true inliers.
    #[test]
    fn sim3_ransac_recovers_a_known_similarity_with_half_outliers() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for trial in 0..10 {
            let truth = Sim3::new(
                So3::exp(&Vector3::new(0.3, -1.2, 0.7)),
                Vector3::new(1.0, -2.0, 0.5),
                0.37 + 0.2 * trial as f64,
            )
            .unwrap();
            let source = random_points(&mut rng, 200);
            let mut target: Vec<_> = source
                .iter()
                .map(|p| {
                    truth.act(p)
                        + Vector3::new(
                            rng.random_range(-0.005..0.005),
                            rng.random_range(-0.005..0.005),
                            rng.random_range(-0.005..0.005),
                        )
                })
                .collect();
            let mut outliers = Vec::new();
            for (i, t) in target.iter_mut().enumerate() {
                if i % 2 == 1 {
                    *t = random_points(&mut rng, 1)[0] * 3.0;
                    outliers.push(i);
                }
            }
            let est = Sim3Estimator {
                target: &target,
                source: &source,
            };
            let config = RansacConfig {
                threshold: 0.05,
                seed: trial,
                ..RansacConfig::default()
            };
            let r = ransac(&est, &config).unwrap();
            let err = (r.model.compose(&truth.inverse())).log().norm();
            assert!(err < 1e-2, "trial {trial}: tangent error {err}");
            assert!((r.model.scale() / truth.scale() - 1.0).abs() < 1e-2);
            let expected_inliers: Vec<usize> = (0..200).step_by(2).collect();
            assert_eq!(r.inliers, expected_inliers, "trial {trial}");
            // At 50 % inliers, p = 0.999 needs ⌈ln(0.001)/ln(1 − 0.125)⌉ = 52 samples.
            assert!(r.iterations <= 200, "{}", r.iterations);
        }
    }

    /// `ransac_or_give_up`: where it does not give up, [`ransac`]'s result (same model,
    /// inliers and samples); where it does, after exactly `after` samples.
    #[test]
    fn giving_up_early_changes_nothing_else() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth = Sim3::new(So3::exp(&Vector3::new(0.2, 0.5, -0.1)), Vector3::x(), 1.3).unwrap();
        let source = random_points(&mut rng, 120);
        // Half inliers: RANSAC needs 52 samples (p = 0.999).
        let target: Vec<_> = source
            .iter()
            .enumerate()
            .map(|(i, p)| {
                if i % 2 == 0 {
                    truth.act(p)
                } else {
                    random_points(&mut rng, 1)[0] * 3.0
                }
            })
            .collect();
        let est = Sim3Estimator {
            target: &target,
            source: &source,
        };
        for seed in 0..5 {
            let config = RansacConfig {
                threshold: 0.05,
                seed,
                ..RansacConfig::default()
            };
            let full = ransac(&est, &config).unwrap();
            assert!(full.iterations > 30, "{}", full.iterations);
            // By 30 samples an all-inlier one has been drawn (1 − 0.875³⁰ = 98 %; these seeds
            // draw one): it goes on.
            let kept = ransac_or_give_up(
                &est,
                &config,
                GiveUp {
                    after: 30,
                    below: 10,
                },
            );
            assert_eq!(kept.unwrap(), full);
            // Asking for more inliers than there are: it gives up after 30 samples.
            let given_up = ransac_or_give_up(
                &est,
                &config,
                GiveUp {
                    after: 30,
                    below: 1000,
                },
            )
            .unwrap();
            assert_eq!(given_up.iterations, 30);
        }
    }

    #[test]
    fn degenerate_samples_are_rejected_not_divided_by_zero() {
        // Collinear and coincident minimal samples give no model.
        let line: Vec<_> = (0..10)
            .map(|k| Vector3::new(1.0, 2.0, 3.0) * k as f64)
            .collect();
        let est = Sim3Estimator {
            target: &line,
            source: &line,
        };
        let mut models = Vec::new();
        est.fit_minimal(&[0, 3, 7], &mut models);
        assert!(models.is_empty());
        let same = vec![Vector3::new(1.0, 1.0, 1.0); 5];
        let est2 = Sim3Estimator {
            target: &same,
            source: &same,
        };
        est2.fit_minimal(&[0, 1, 2], &mut models);
        assert!(models.is_empty());
        // All data degenerate: an error naming the degenerate samples, not a NaN model.
        match ransac(&est, &RansacConfig::default()) {
            Err(RansacError::NoModel {
                iterations,
                degenerate,
            }) => assert_eq!(iterations, degenerate),
            other => panic!("{other:?}"),
        }
        // Mostly collinear data with a few good points still works.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut source = line.clone();
        source.extend(random_points(&mut rng, 10));
        let s = Sim3::new(So3::rot_z(0.4), Vector3::new(0.1, 0.2, 0.3), 2.0).unwrap();
        let target: Vec<_> = source.iter().map(|p| s.act(p)).collect();
        let r = ransac(
            &Sim3Estimator {
                target: &target,
                source: &source,
            },
            &RansacConfig {
                threshold: 1e-6,
                // Enough samples that some fall on the line (probability ≈ 0.1 each).
                min_iterations: 100,
                ..RansacConfig::default()
            },
        )
        .unwrap();
        assert_eq!(r.inliers.len(), 20);
        assert!(r.degenerate_samples > 0);
    }

    #[test]
    fn same_seed_same_result_and_bad_input_is_an_error() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let source = random_points(&mut rng, 60);
        let s = Sim3::new(So3::rot_x(0.2), Vector3::new(0.0, 1.0, 0.0), 1.5).unwrap();
        let target: Vec<_> = source
            .iter()
            .enumerate()
            .map(|(i, p)| {
                if i % 3 == 0 {
                    -p
                } else {
                    s.act(p) + Vector3::new(rng.random_range(-0.01..0.01), 0.0, 0.0)
                }
            })
            .collect();
        let est = Sim3Estimator {
            target: &target,
            source: &source,
        };
        let config = RansacConfig {
            threshold: 0.05,
            seed: 42,
            ..RansacConfig::default()
        };
        let a = ransac(&est, &config).unwrap();
        let b = ransac(&est, &config).unwrap();
        assert_eq!(a, b);
        assert!(matches!(
            ransac(
                &Sim3Estimator {
                    target: &target[..2],
                    source: &source[..2]
                },
                &config
            ),
            Err(RansacError::TooFewData { needed: 3, got: 2 })
        ));
        for bad in [
            RansacConfig {
                threshold: 0.0,
                ..config
            },
            RansacConfig {
                confidence: 1.0,
                ..config
            },
            RansacConfig {
                max_iterations: 0,
                ..config
            },
        ] {
            assert!(matches!(
                ransac(&est, &bad),
                Err(RansacError::InvalidConfig(_))
            ));
        }
    }

    #[test]
    fn required_iterations_follow_the_formula() {
        assert_eq!(required_iterations(1.0, 3, 0.99), 1);
        assert_eq!(required_iterations(0.5, 3, 0.999), 52);
        assert_eq!(required_iterations(0.0, 3, 0.999), usize::MAX);
    }
}
