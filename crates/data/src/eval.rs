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
