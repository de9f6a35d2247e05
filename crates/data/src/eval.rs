//! Trajectory evaluation: absolute trajectory error (ATE) after SE(3) or Sim(3) alignment and
//! relative pose error (RPE), defined as `evo` defines them so that the numbers can be checked
//! against it (`evo_ape`, `evo_rpe`, default pose relation "translation part").
//!
//! * **Alignment** ([`Alignment`]): the estimate's positions `p̂_i` are aligned to the
//!   reference positions `p_i` by the closed-form least-squares similarity / rigid motion
//!   `S = argmin Σ‖p_i − S·p̂_i‖²` ([`geom::align`], Umeyama; thesis eq. 5.11–5.14 for `N`
//!   points), and every estimated pose becomes `S·P̂_i`.
//! * **ATE** ([`ate`]): `e_i = ‖t(P_i⁻¹·S·P̂_i)‖ = ‖p_i − S·p̂_i‖`, summarised by
//!   [`Statistics`] (RMSE first).
//! * **RPE** ([`rpe`]): for index pairs `(i, j)` — consecutive multiples of `delta` (evo's
//!   default), or all `(i, i + delta)` — the error
//!   `E_ij = (P_i⁻¹·P_j)⁻¹ · (P̂_i⁻¹·P̂_j)` (after alignment), with translation error `‖t(E_ij)‖`
//!   and rotation error `angle(R(E_ij))` in radians.
//! * **Drift per distance** ([`drift`]): the KITTI odometry benchmark's relative error — for
//!   segments starting every 10th pose and `L` metres of ground-truth path long
//!   (100, 200, …, 800 m), `E = (P_i⁻¹·P_j)⁻¹·(P̂_i⁻¹·P̂_j)` with `j` the first pose `L` metres
//!   beyond `i`; the translation error `‖t(E)‖/L` (as a percentage) and the rotation error
//!   `angle(R(E))/L` (degrees per 100 m), averaged over every segment of every length (after
//!   `alignment`, which acts through its scale alone).
//!
//! The inputs are already associated pose lists of equal length (see
//! [`trajectory::associate_trajectories`](crate::trajectory::associate_trajectories)).

use geom::align::{AlignError, align_se3, align_sim3};
use lie::{LieGroup, Se3, Sim3};
use nalgebra::Vector3;

/// How the estimate is aligned to the reference before computing errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Alignment {
    /// No alignment.
    None,
    /// Rigid motion (evo's `--align`).
    Se3,
    /// Similarity, i.e. also the scale (evo's `--align --correct_scale`), for monocular SLAM.
    Sim3,
}

/// Why an evaluation failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvalError {
    /// The reference and the estimate have different numbers of poses.
    #[error(
        "reference has {reference_count} poses, estimate {estimate_count}: associate them first"
    )]
    LengthMismatch {
        /// Reference poses.
        reference_count: usize,
        /// Estimated poses.
        estimate_count: usize,
    },
    /// No poses, or no pose pairs for RPE.
    #[error("nothing to evaluate: {what}")]
    Empty {
        /// What was missing.
        what: String,
    },
    /// The alignment is undetermined (too few, coincident or collinear positions).
    #[error("alignment failed: {0}")]
    Align(#[from] AlignError),
}

/// Summary statistics of a list of errors, as evo reports them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Statistics {
    /// `√(Σeᵢ²/n)`.
    pub rmse: f64,
    /// `Σeᵢ/n`.
    pub mean: f64,
    /// The median (mean of the two middle values for even `n`, as numpy).
    pub median: f64,
    /// Population standard deviation `√(Σ(eᵢ − mean)²/n)` (numpy's default).
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
    /// Number of errors.
    pub count: usize,
}

impl Statistics {
    /// Statistics of `errors`; `None` if empty.
    pub fn of(errors: &[f64]) -> Option<Statistics> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let m = sorted.len();
        let median = if m % 2 == 1 {
            sorted[m / 2]
        } else {
            0.5 * (sorted[m / 2 - 1] + sorted[m / 2])
        };
        Some(Statistics {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[m - 1],
            sse,
            count: errors.len(),
        })
    }
}

/// The result of [`ate`].
#[derive(Clone, Debug, PartialEq)]
pub struct AteResult {
    /// Statistics of the per-pose translation errors (metres, or the reference's unit).
    pub translation: Statistics,
    /// The per-pose errors `‖p_i − S·p̂_i‖`.
    pub errors: Vec<f64>,
    /// The alignment applied, `reference_from_estimate` (identity for [`Alignment::None`],
    /// scale 1 for [`Alignment::Se3`]).
    pub reference_from_estimate: Sim3,
}

/// The result of [`rpe`].
#[derive(Clone, Debug, PartialEq)]
pub struct RpeResult {
    /// Statistics of `‖t(E_ij)‖`.
    pub translation: Statistics,
    /// Statistics of the rotation angle of `E_ij`, radians.
    pub rotation_rad: Statistics,
    /// The index pairs used.
    pub pairs: Vec<(usize, usize)>,
    /// `‖t(E_ij)‖` per pair, in the order of `pairs`.
    pub translation_errors: Vec<f64>,
    /// `angle(R(E_ij))` per pair, radians.
    pub rotation_errors_rad: Vec<f64>,
}

/// The result of [`drift`].
#[derive(Clone, Debug, PartialEq)]
pub struct DriftResult {
    /// Mean translation error over every segment, percent of the segment's length.
    pub translation_percent: f64,
    /// Mean rotation error over every segment, degrees per 100 m.
    pub rotation_deg_per_100m: f64,
    /// Per segment length: `(length m, segments, translation %, rotation °/100 m)`.
    pub per_length: Vec<(f64, usize, f64, f64)>,
}

/// The segment lengths of the KITTI odometry benchmark (m).
pub const KITTI_SEGMENT_LENGTHS: [f64; 8] =
    [100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0];

/// Drift per distance travelled, the KITTI odometry benchmark's relative error (see the
/// [module docs](self)): segments start every `step` poses (KITTI: 10 frames); the lengths
/// without any segment (longer than the path) are left out. An error if no length fits.
pub fn drift(
    reference: &[Se3],
    estimate: &[Se3],
    lengths: &[f64],
    step: usize,
    alignment: Alignment,
) -> Result<DriftResult, EvalError> {
    let s = align(reference, estimate, alignment)?;
    let aligned: Vec<Se3> = estimate.iter().map(|e| apply_similarity(&s, e)).collect();
    let mut path = Vec::with_capacity(reference.len());
    let mut d = 0.0;
    for (k, r) in reference.iter().enumerate() {
        if k > 0 {
            d += (r.translation() - reference[k - 1].translation()).norm();
        }
        path.push(d);
    }
    let (mut t_all, mut r_all, mut n_all) = (0.0, 0.0, 0usize);
    let mut per_length = Vec::new();
    for &length in lengths {
        let (mut t_sum, mut r_sum, mut n) = (0.0, 0.0, 0usize);
        for i in (0..reference.len()).step_by(step.max(1)) {
            let j = i + path[i..].partition_point(|&x| x <= path[i] + length);
            if j >= reference.len() {
                break;
            }
            let truth = reference[i].inverse().compose(&reference[j]);
            let est = aligned[i].inverse().compose(&aligned[j]);
            let e = truth.inverse().compose(&est);
            t_sum += e.translation().norm() / length;
            r_sum += e.rotation().angle().to_degrees() / length;
            n += 1;
        }
        if n > 0 {
            per_length.push((
                length,
                n,
                100.0 * t_sum / n as f64,
                100.0 * r_sum / n as f64,
            ));
            (t_all, r_all, n_all) = (t_all + t_sum, r_all + r_sum, n_all + n);
        }
    }
    if n_all == 0 {
        return Err(EvalError::Empty {
            what: format!(
                "no segment of {} m on a path of {:.1} m",
                lengths.first().copied().unwrap_or(0.0),
                path.last().copied().unwrap_or(0.0)
            ),
        });
    }
    Ok(DriftResult {
        translation_percent: 100.0 * t_all / n_all as f64,
        rotation_deg_per_100m: 100.0 * r_all / n_all as f64,
        per_length,
    })
}

/// `S·P`: a similarity applied to a rigid pose (rotation `R_S·R_P`, translation
/// `s·R_S·t_P + t_S`), as evo's `scale` + `transform` do.
pub fn apply_similarity(s: &Sim3, pose: &Se3) -> Se3 {
    Se3::new(
        s.rotation().compose(pose.rotation()),
        s.act(pose.translation()),
    )
}

fn check(reference: &[Se3], estimate: &[Se3]) -> Result<(), EvalError> {
    if reference.len() != estimate.len() {
        return Err(EvalError::LengthMismatch {
            reference_count: reference.len(),
            estimate_count: estimate.len(),
        });
    }
    if reference.is_empty() {
        return Err(EvalError::Empty {
            what: "no poses".into(),
        });
    }
    Ok(())
}

/// The alignment `reference_from_estimate` of the estimate's positions onto the reference's.
pub fn align(reference: &[Se3], estimate: &[Se3], alignment: Alignment) -> Result<Sim3, EvalError> {
    check(reference, estimate)?;
    let p: Vec<Vector3<f64>> = reference.iter().map(|x| *x.translation()).collect();
    let q: Vec<Vector3<f64>> = estimate.iter().map(|x| *x.translation()).collect();
    Ok(match alignment {
        Alignment::None => Sim3::identity(),
        Alignment::Se3 => Sim3::from_se3(&align_se3(&p, &q)?),
        Alignment::Sim3 => align_sim3(&p, &q)?,
    })
}

/// Absolute trajectory error (translation part) after `alignment` (see the
/// [module docs](self)).
pub fn ate(
    reference: &[Se3],
    estimate: &[Se3],
    alignment: Alignment,
) -> Result<AteResult, EvalError> {
    let s = align(reference, estimate, alignment)?;
    let errors: Vec<f64> = reference
        .iter()
        .zip(estimate)
        .map(|(r, e)| (r.translation() - s.act(e.translation())).norm())
        .collect();
    Ok(AteResult {
        translation: Statistics::of(&errors).expect("non-empty"),
        errors,
        reference_from_estimate: s,
    })
}

/// The index pairs evo uses for RPE with a frame delta: `(0, δ), (δ, 2δ), …` or, with
/// `all_pairs`, every `(i, i + δ)`.
pub fn rpe_pairs(count: usize, delta: usize, all_pairs: bool) -> Vec<(usize, usize)> {
    let delta = delta.max(1);
    if all_pairs {
        (0..count.saturating_sub(delta))
            .map(|i| (i, i + delta))
            .collect()
    } else {
        let ids: Vec<usize> = (0..count).step_by(delta).collect();
        ids.windows(2).map(|w| (w[0], w[1])).collect()
    }
}

/// Relative pose error over pose pairs `delta` frames apart, after `alignment` (which matters
/// only through the scale of [`Alignment::Sim3`]); see the [module docs](self).
pub fn rpe(
    reference: &[Se3],
    estimate: &[Se3],
    delta: usize,
    all_pairs: bool,
    alignment: Alignment,
) -> Result<RpeResult, EvalError> {
    let s = align(reference, estimate, alignment)?;
    let aligned: Vec<Se3> = estimate.iter().map(|e| apply_similarity(&s, e)).collect();
    let pairs = rpe_pairs(reference.len(), delta, all_pairs);
    if pairs.is_empty() {
        return Err(EvalError::Empty {
            what: format!("no pose pairs {delta} frames apart"),
        });
    }
    let mut translation = Vec::with_capacity(pairs.len());
    let mut rotation = Vec::with_capacity(pairs.len());
    for &(i, j) in &pairs {
        let truth = reference[i].inverse().compose(&reference[j]);
        let est = aligned[i].inverse().compose(&aligned[j]);
        let e = truth.inverse().compose(&est);
        translation.push(e.translation().norm());
        rotation.push(e.rotation().angle());
    }
    Ok(RpeResult {
        translation: Statistics::of(&translation).expect("non-empty"),
        rotation_rad: Statistics::of(&rotation).expect("non-empty"),
        pairs,
        translation_errors: translation,
        rotation_errors_rad: rotation,
    })
}

/// The rotation angle of a 3×3 matrix as scipy's `Rotation.from_matrix(m).magnitude()`
/// computes it (evo's `so3_log_angle`): the quaternion by Shepperd's choice of the largest of
/// `(m₀₀, m₁₁, m₂₂, tr m)`, normalised, then `2·atan2(‖q_xyz‖, |q_w|)`. For a matrix that is
/// not exactly orthonormal this is the angle evo reports.
pub fn matrix_rotation_angle(m: &nalgebra::Matrix3<f64>) -> f64 {
    let d = [
        m[(0, 0)],
        m[(1, 1)],
        m[(2, 2)],
        m[(0, 0)] + m[(1, 1)] + m[(2, 2)],
    ];
    let mut choice = 0;
    for k in 1..4 {
        if d[k] > d[choice] {
            choice = k;
        }
    }
    let mut q = [0.0f64; 4]; // x y z w
    if choice != 3 {
        let i = choice;
        let j = (i + 1) % 3;
        let k = (j + 1) % 3;
        q[i] = 1.0 - d[3] + 2.0 * m[(i, i)];
        q[j] = m[(j, i)] + m[(i, j)];
        q[k] = m[(k, i)] + m[(i, k)];
        q[3] = m[(k, j)] - m[(j, k)];
    } else {
        q[0] = m[(2, 1)] - m[(1, 2)];
        q[1] = m[(0, 2)] - m[(2, 0)];
        q[2] = m[(1, 0)] - m[(0, 1)];
        q[3] = 1.0 + d[3];
    }
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let v = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() / n;
    2.0 * v.atan2((q[3] / n).abs())
}

/// `[Rᵀ | −Rᵀt]`: the inverse of a rigid 4×4 matrix as evo takes it (`se3_inverse`, with the
/// transpose also for a rotation block that is not exactly orthonormal).
fn inverse_by_transpose(m: &nalgebra::Matrix4<f64>) -> nalgebra::Matrix4<f64> {
    let r = m.fixed_view::<3, 3>(0, 0).transpose();
    let t = -(r * m.fixed_view::<3, 1>(0, 3));
    let mut out = nalgebra::Matrix4::identity();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    out.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
    out
}

/// [`rpe`] on poses given as the 4×4 matrices of a file (KITTI), computed as evo computes it on
/// such matrices: the alignment `S` (from the positions, as [`align`]) applied as `scale`
/// then left multiplication, `E_ij = inv(P_i⁻¹P_j)·(P̂_i⁻¹P̂_j)` with [`inverse_by_transpose`],
/// and the angle of `R(E_ij)` by [`matrix_rotation_angle`]. On exactly orthonormal poses it
/// equals [`rpe`]; on KITTI's 7-digit matrices the two differ by ~1e-7 of the angle, which is
/// up to 3e-4 relative on the smallest frame-to-frame errors.
pub fn rpe_matrices(
    reference: &[nalgebra::Matrix4<f64>],
    estimate: &[nalgebra::Matrix4<f64>],
    similarity: &Sim3,
    delta: usize,
    all_pairs: bool,
) -> Result<RpeResult, EvalError> {
    if reference.len() != estimate.len() {
        return Err(EvalError::LengthMismatch {
            reference_count: reference.len(),
            estimate_count: estimate.len(),
        });
    }
    let rs = similarity.rotation().rotation_matrix();
    let ts = *similarity.translation();
    let s = similarity.scale();
    let aligned: Vec<nalgebra::Matrix4<f64>> = estimate
        .iter()
        .map(|m| {
            let mut scaled = *m;
            for k in 0..3 {
                scaled[(k, 3)] *= s;
            }
            let mut t = nalgebra::Matrix4::identity();
            t.fixed_view_mut::<3, 3>(0, 0).copy_from(&rs);
            t.fixed_view_mut::<3, 1>(0, 3).copy_from(&ts);
            t * scaled
        })
        .collect();
    let pairs = rpe_pairs(reference.len(), delta, all_pairs);
    if pairs.is_empty() {
        return Err(EvalError::Empty {
            what: format!("no pose pairs {delta} frames apart"),
        });
    }
    let mut translation = Vec::with_capacity(pairs.len());
    let mut rotation = Vec::with_capacity(pairs.len());
    for &(i, j) in &pairs {
        let truth = inverse_by_transpose(&reference[i]) * reference[j];
        let est = inverse_by_transpose(&aligned[i]) * aligned[j];
        let e = inverse_by_transpose(&truth) * est;
        translation.push(e.fixed_view::<3, 1>(0, 3).norm());
        rotation.push(matrix_rotation_angle(
            &e.fixed_view::<3, 3>(0, 0).into_owned(),
        ));
    }
    Ok(RpeResult {
        translation: Statistics::of(&translation).expect("non-empty"),
        rotation_rad: Statistics::of(&rotation).expect("non-empty"),
        pairs,
        translation_errors: translation,
        rotation_errors_rad: rotation,
    })
}

#[cfg(test)]
mod drift_tests {
    use super::*;
    use lie::So3;

    /// A straight drive along x at 1 m per pose, looking along x.
    fn straight(n: usize) -> Vec<Se3> {
        (0..n)
            .map(|k| Se3::new(So3::identity(), Vector3::new(k as f64, 0.0, 0.0)))
            .collect()
    }

    #[test]
    fn drift_of_known_scale_and_heading_errors() {
        let truth = straight(1001);
        // 2 % too long, unaligned: every segment 2 % off, no rotation error.
        let long: Vec<Se3> = truth
            .iter()
            .map(|p| Se3::new(*p.rotation(), p.translation() * 1.02))
            .collect();
        // (KITTI divides by the nominal length L; the segment's end, the first pose beyond
        // L metres, is L + 1 metres on: 2 %·(1 + 1/L).)
        let d = drift(&truth, &long, &KITTI_SEGMENT_LENGTHS, 10, Alignment::None).unwrap();
        for &(length, _, t, r) in &d.per_length {
            assert!((t - 2.0 * (1.0 + 1.0 / length)).abs() < 1e-9, "{d:?}");
            assert!(r.abs() < 1e-9);
        }
        assert!(
            d.translation_percent > 2.0 && d.translation_percent < 2.02,
            "{d:?}"
        );
        assert_eq!(d.per_length.len(), 8);
        // Segments of 100 m start every 10 poses until 100 m before the end: 90 of them
        // (j, the first pose beyond i + L, is i + L + 1).
        assert_eq!(d.per_length[0].1, 90);
        // With a Sim(3) alignment a scale error is gone (on a curved drive: a straight one has
        // no alignment).
        let curved: Vec<Se3> = (0..1001)
            .map(|k| {
                let a = k as f64 / 300.0;
                Se3::new(
                    So3::rot_z(a),
                    Vector3::new(300.0 * a.sin(), 300.0 * (1.0 - a.cos()), 0.0),
                )
            })
            .collect();
        let scaled: Vec<Se3> = curved
            .iter()
            .map(|p| Se3::new(*p.rotation(), p.translation() * 1.02))
            .collect();
        let d = drift(
            &curved,
            &scaled,
            &KITTI_SEGMENT_LENGTHS,
            10,
            Alignment::Sim3,
        )
        .unwrap();
        assert!(d.translation_percent < 1e-6, "{d:?}");
        let d = drift(&curved, &scaled, &KITTI_SEGMENT_LENGTHS, 10, Alignment::Se3).unwrap();
        // (2 % of each chord, shorter than the L metres of arc it is divided by.)
        assert!(
            d.translation_percent > 1.4 && d.translation_percent < 2.02,
            "{d:?}"
        );
        // A heading that turns 0.01° per metre: a segment of L metres ends turned by 0.01·(L+1)°
        // (j is one pose beyond L), 1°(1 + 1/L) per 100 m; positions unchanged.
        let turning: Vec<Se3> = truth
            .iter()
            .enumerate()
            .map(|(k, p)| Se3::new(So3::rot_z((0.01 * k as f64).to_radians()), *p.translation()))
            .collect();
        let d = drift(&truth, &turning, &[100.0], 10, Alignment::None).unwrap();
        assert!((d.rotation_deg_per_100m - 1.01).abs() < 1e-9, "{d:?}");
        // A path shorter than every length: an error, not a zero.
        assert!(drift(&truth[..50], &long[..50], &[100.0], 10, Alignment::None).is_err());
    }
}
