//! Closed-form alignment of two 3D point sets: the similarity (Umeyama 1991) or rigid motion
//! (Arun et al. 1987, Kabsch) that best maps one set onto the other in the least-squares sense.
//!
//! This is the thesis's three-point similarity of eq. 5.9–5.14 generalised to `N ≥ 3`
//! correspondences `x_i ↔ x̄_i` (`target_i ≈ S·source_i`). With centroids and centred points
//! (eq. 5.11–5.12)
//!
//! `c = (1/N) Σ x_i`, `c̄ = (1/N) Σ x̄_i`, `y_i = x_i − c`, `ȳ_i = x̄_i − c̄`,
//!
//! the cross-covariance `H = (1/N) Σ y_i ȳ_iᵀ = U Σ Vᵀ` (eq. 5.13) gives
//!
//! `R = U · diag(1, 1, det(U)·det(V)) · Vᵀ`,
//!
//! where the middle factor is the *reflection fix*: without it an SVD of nearly planar or
//! noisy points can return a reflection (`det R = −1`). Note the order: with `H = Σ y ȳᵀ`
//! (target times source transposed) as eq. 5.13 writes it, the maximiser of `Σ y_iᵀ R ȳ_i` is
//! `U Vᵀ`; eq. 5.14's `R = V Uᵀ` is the same rotation for Arun's `H = Σ ȳ yᵀ`.
//!
//! Scale (Sim(3) only), see [`ScaleEstimate`]:
//! * least squares (Umeyama): `s = tr(Σ·D) / σ̄²` with `σ̄² = (1/N) Σ ‖ȳ_i‖²` and `D` the
//!   reflection fix, minimising `Σ ‖x_i − (sR x̄_i + t)‖²` — what `evo` uses;
//! * symmetric (thesis eq. 5.14, Horn 1987): `s = √(Σ‖y_i‖² / Σ‖ȳ_i‖²)`, which does not
//!   depend on which set is the source;
//!
//! and the translation `t = c − s R c̄` (eq. 5.14).
//!
//! Degenerate input is an error, never a NaN: fewer than 3 points, sets of different sizes,
//! non-finite coordinates, coincident points, collinear points (the rotation about the line is
//! then undetermined), and a cross-covariance of rank < 2.

use lie::{Se3, Sim3, So3};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// Relative tolerance for the degeneracy tests: a set whose second-largest spread eigenvalue
/// is below `DEGENERACY_TOLERANCE` times its largest (lengths below ~1e-6 of the extent) is
/// collinear; a cross-covariance whose second singular value is below this fraction of its
/// largest has rank < 2.
pub const DEGENERACY_TOLERANCE: f64 = 1e-12;

/// Why two point sets cannot be aligned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// Fewer than three correspondences.
    #[error("alignment needs at least 3 point pairs, got {count}")]
    TooFewPoints {
        /// Number of pairs given.
        count: usize,
    },
    /// The two sets differ in size.
    #[error(
        "point sets differ in size: {target_count} target points, {source_count} source points"
    )]
    LengthMismatch {
        /// Number of target points.
        target_count: usize,
        /// Number of source points.
        source_count: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("point {index} of the {set} set is not finite")]
    NotFinite {
        /// `"target"` or `"source"`.
        set: &'static str,
        /// The index of the point.
        index: usize,
    },
    /// All points of one set coincide.
    #[error("the {set} points all coincide")]
    Coincident {
        /// `"target"` or `"source"`.
        set: &'static str,
    },
    /// The points of one set lie on a line.
    #[error("the {set} points are collinear")]
    Collinear {
        /// `"target"` or `"source"`.
        set: &'static str,
    },
    /// The cross-covariance has rank below 2, so the rotation is not determined.
    #[error(
        "the cross-covariance of the point sets has rank < 2 (singular values {singular_values:?})"
    )]
    RankDeficient {
        /// Its singular values, largest first.
        singular_values: [f64; 3],
    },
}

/// How [`align_sim3_with`] estimates the scale.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScaleEstimate {
    /// Umeyama's least-squares scale `tr(ΣD)/σ̄²`, minimising `Σ‖x − (sRx̄ + t)‖²`.
    LeastSquares,
    /// The thesis's (eq. 5.14) and Horn's symmetric scale `√(Σ‖y‖²/Σ‖ȳ‖²)`.
    Symmetric,
}

struct Moments {
    target_centroid: Vector3<f64>,
    source_centroid: Vector3<f64>,
    rotation: Matrix3<f64>,
    /// `tr(Σ·D)`, the sum of singular values with the reflection fix applied.
    trace_sd: f64,
    target_variance: f64,
    source_variance: f64,
}

fn check_set(
    set: &'static str,
    points: &[Vector3<f64>],
) -> Result<(Vector3<f64>, f64), AlignError> {
    for (index, p) in points.iter().enumerate() {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(AlignError::NotFinite { set, index });
        }
    }
    let n = points.len() as f64;
    let centroid = points.iter().sum::<Vector3<f64>>() / n;
    let mut covariance = Matrix3::zeros();
    for p in points {
        let y = p - centroid;
        covariance += y * y.transpose();
    }
    covariance /= n;
    let variance = covariance.trace();
    let extent = points
        .iter()
        .map(|p| p.amax())
        .fold(0.0_f64, f64::max)
        .max(f64::MIN_POSITIVE);
    // Coincident: the spread is at the level of rounding of the coordinates.
    if variance <= (1e-14 * extent).powi(2) {
        return Err(AlignError::Coincident { set });
    }
    let mut eigenvalues: Vec<f64> = covariance.symmetric_eigenvalues().iter().copied().collect();
    eigenvalues.sort_by(|a, b| b.total_cmp(a));
    if eigenvalues[1] <= DEGENERACY_TOLERANCE * eigenvalues[0] {
        return Err(AlignError::Collinear { set });
    }
    Ok((centroid, variance))
}

fn moments(target: &[Vector3<f64>], source: &[Vector3<f64>]) -> Result<Moments, AlignError> {
    if target.len() != source.len() {
        return Err(AlignError::LengthMismatch {
            target_count: target.len(),
            source_count: source.len(),
        });
    }
    if target.len() < 3 {
        return Err(AlignError::TooFewPoints {
            count: target.len(),
        });
    }
    let (target_centroid, target_variance) = check_set("target", target)?;
    let (source_centroid, source_variance) = check_set("source", source)?;
    let n = target.len() as f64;
    let mut h = Matrix3::zeros();
    for (x, x_bar) in target.iter().zip(source) {
        h += (x - target_centroid) * (x_bar - source_centroid).transpose();
    }
    h /= n;
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut sv = [
        svd.singular_values[0],
        svd.singular_values[1],
        svd.singular_values[2],
    ];
    sv.sort_by(|a, b| b.total_cmp(a));
    if sv[1] <= DEGENERACY_TOLERANCE * sv[0] || sv[1].is_nan() {
        return Err(AlignError::RankDeficient {
            singular_values: sv,
        });
    }
    // nalgebra does not sort singular values; find the smallest for the reflection fix.
    let smallest = (0..3)
        .min_by(|&a, &b| svd.singular_values[a].total_cmp(&svd.singular_values[b]))
        .expect("three values");
    let mut d = Vector3::new(1.0, 1.0, 1.0);
    if (u.determinant() * v_t.determinant()) < 0.0 {
        d[smallest] = -1.0;
    }
    let rotation = u * Matrix3::from_diagonal(&d) * v_t;
    let trace_sd = svd.singular_values.dot(&d);
    Ok(Moments {
        target_centroid,
        source_centroid,
        rotation,
        trace_sd,
        target_variance,
        source_variance,
    })
}

fn so3_of(m: &Matrix3<f64>) -> So3 {
    So3::from_unit_quaternion(UnitQuaternion::from_rotation_matrix(
        &Rotation3::from_matrix_unchecked(*m),
    ))
}

/// The similarity `target_from_source = (s, R, t)` minimising `Σ‖target_i − (sR·source_i + t)‖²`
/// (Umeyama's least-squares scale; see the [module docs](self)).
pub fn align_sim3(target: &[Vector3<f64>], source: &[Vector3<f64>]) -> Result<Sim3, AlignError> {
    align_sim3_with(target, source, ScaleEstimate::LeastSquares)
}

/// [`align_sim3`] with a choice of scale estimate (thesis eq. 5.11–5.14).
pub fn align_sim3_with(
    target: &[Vector3<f64>],
    source: &[Vector3<f64>],
    scale: ScaleEstimate,
) -> Result<Sim3, AlignError> {
    let m = moments(target, source)?;
    let s = match scale {
        ScaleEstimate::LeastSquares => m.trace_sd / m.source_variance,
        ScaleEstimate::Symmetric => (m.target_variance / m.source_variance).sqrt(),
    };
    let t = m.target_centroid - s * m.rotation * m.source_centroid;
    let rotation = so3_of(&m.rotation);
    // s > 0: trace_sd > 0 because the two largest singular values are positive and dominate
    // a possibly negated smallest one; variances are positive after the degeneracy checks.
    Sim3::new(rotation, t, s).map_err(|_| AlignError::RankDeficient {
        singular_values: [m.trace_sd, m.source_variance, m.target_variance],
    })
}

/// The rigid motion `target_from_source = (R, t)` minimising `Σ‖target_i − (R·source_i + t)‖²`
/// (thesis eq. 6.9: eq. 5.11–5.14 with the scale fixed to one).
pub fn align_se3(target: &[Vector3<f64>], source: &[Vector3<f64>]) -> Result<Se3, AlignError> {
    let m = moments(target, source)?;
    let t = m.target_centroid - m.rotation * m.source_centroid;
    Ok(Se3::new(so3_of(&m.rotation), t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::LieGroup;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_points(rng: &mut ChaCha8Rng, n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                )
            })
            .collect()
    }

    fn random_sim3(rng: &mut ChaCha8Rng) -> Sim3 {
        let omega = Vector3::new(
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
            rng.random_range(-2.0..2.0),
        );
        let t = Vector3::new(
            rng.random_range(-10.0..10.0),
            rng.random_range(-10.0..10.0),
            rng.random_range(-10.0..10.0),
        );
        Sim3::new(So3::exp(&omega), t, rng.random_range(0.2..5.0)).unwrap()
    }

    fn distance(a: &Sim3, b: &Sim3) -> f64 {
        a.inverse().compose(b).log().norm()
    }

    #[test]
    fn recovers_known_similarity_exactly_from_three_and_many_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for n in [3, 4, 10, 200] {
            for _ in 0..20 {
                let truth = random_sim3(&mut rng);
                let source = random_points(&mut rng, n);
                let target: Vec<_> = source.iter().map(|p| truth.act(p)).collect();
                for method in [ScaleEstimate::LeastSquares, ScaleEstimate::Symmetric] {
                    let est = align_sim3_with(&target, &source, method).unwrap();
                    assert!(
                        distance(&est, &truth) < 1e-9,
                        "n={n} {method:?}: {est:?} vs {truth:?}"
                    );
                }
                let rigid = Sim3::from_se3(&truth.rigid_part());
                let target: Vec<_> = source.iter().map(|p| rigid.act(p)).collect();
                let est = align_se3(&target, &source).unwrap();
                assert!(distance(&Sim3::from_se3(&est), &rigid) < 1e-9);
            }
        }
    }

    #[test]
    fn noisy_points_give_the_least_squares_optimum() {
        use rand_distr::{Distribution, Normal};
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let noise = Normal::new(0.0, 0.05).unwrap();
        let truth = random_sim3(&mut rng);
        let source = random_points(&mut rng, 500);
        let target: Vec<_> = source
            .iter()
            .map(|p| truth.act(p) + Vector3::from_fn(|_, _| noise.sample(&mut rng)))
            .collect();
        let est = align_sim3(&target, &source).unwrap();
        // Close to the truth…
        assert!(distance(&est, &truth) < 0.02, "{}", distance(&est, &truth));
        // …and a stationary point of the cost: no small perturbation lowers it.
        let cost = |s: &Sim3| -> f64 {
            target
                .iter()
                .zip(&source)
                .map(|(x, y)| (x - s.act(y)).norm_squared())
                .sum()
        };
        let best = cost(&est);
        for k in 0..7 {
            for sign in [-1.0, 1.0] {
                let mut delta = nalgebra::SVector::<f64, 7>::zeros();
                delta[k] = sign * 1e-4;
                assert!(cost(&est.retract_left(&delta)) >= best, "direction {k}");
            }
        }
    }

    #[test]
    fn planar_points_and_reflections_still_give_a_rotation() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth = random_sim3(&mut rng);
        let source: Vec<_> = (0..20)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    0.0,
                )
            })
            .collect();
        let target: Vec<_> = source.iter().map(|p| truth.act(p)).collect();
        let est = align_sim3(&target, &source).unwrap();
        assert!(distance(&est, &truth) < 1e-9);
        // A mirrored target: the best proper rotation, never a reflection.
        let mirrored: Vec<_> = random_points(&mut rng, 30);
        let target: Vec<_> = mirrored
            .iter()
            .map(|p| Vector3::new(-p.x, p.y, p.z))
            .collect();
        let est = align_se3(&target, &mirrored).unwrap();
        assert!((est.rotation().rotation_matrix().determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn degenerate_input_is_an_error_not_nan() {
        let p = |x: f64, y: f64, z: f64| Vector3::new(x, y, z);
        let good = vec![p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0)];
        assert_eq!(
            align_sim3(&good[..2], &good[..2]),
            Err(AlignError::TooFewPoints { count: 2 })
        );
        assert_eq!(
            align_se3(&[], &[]).unwrap_err(),
            AlignError::TooFewPoints { count: 0 }
        );
        assert!(matches!(
            align_sim3(&good, &good[..2]),
            Err(AlignError::LengthMismatch { .. })
        ));
        let coincident = vec![p(1.0, 2.0, 3.0); 5];
        assert_eq!(
            align_sim3(&coincident, &coincident),
            Err(AlignError::Coincident { set: "target" })
        );
        assert_eq!(
            align_sim3(&good, &[p(1.0, 2.0, 3.0); 3]),
            Err(AlignError::Coincident { set: "source" })
        );
        let line: Vec<_> = (0..6).map(|i| p(i as f64, 2.0 * i as f64, -1.0)).collect();
        assert_eq!(
            align_se3(&line, &line),
            Err(AlignError::Collinear { set: "target" })
        );
        let mut nan = good.clone();
        nan[1].y = f64::NAN;
        assert_eq!(
            align_sim3(&good, &nan),
            Err(AlignError::NotFinite {
                set: "source",
                index: 1
            })
        );
        nan[1].y = f64::INFINITY;
        assert!(align_se3(&nan, &good).is_err());
        // Uncorrelated sets: the cross-covariance has rank 1.
        let a = vec![
            p(1.0, 0.0, 0.0),
            p(-1.0, 0.0, 0.0),
            p(0.0, 1.0, 0.0),
            p(0.0, -1.0, 0.0),
        ];
        let b = vec![
            p(1.0, 0.0, 0.0),
            p(-1.0, 0.0, 0.0),
            p(0.0, 0.0, 1.0),
            p(0.0, 0.0, 1.0),
        ];
        assert!(matches!(
            align_sim3(&a, &b),
            Err(AlignError::RankDeficient { .. })
        ));
    }
}
