//! The preliminary experiment of thesis §4.3: how the accuracy of the end pose of a short
//! stereo motion grows with the number of keyframes `M` and of points `N`, by covariance
//! back-propagation at the ground truth (eq. 4.3) and entropy reduction (eq. 4.9–4.11).
//!
//! Setup (§4.3.1): a stereo camera (640×480, `f = 500`, baseline 0.1 m, `σ = ½` px) moves 1 m
//! sideways in 36 frames after `T_0`; a fronto-parallel plane 3 m ahead holds 425 regularly
//! arranged points (25 × 17, 0.1 m apart), visible from every frame; `N` points are taken from
//! the nested pattern ([`crate::world::nested_plane_grid`]) so that denser patterns contain the
//! sparser ones, and `M` keyframes are the frames `round(k·36/M)`, `k = 1…M`, besides `T_0`,
//! which is fixed.
//!
//! The information of the BA problem (eq. 4.1) at the truth is `Λ = Jᵀ Σ_z⁻¹ J`; the points
//! are eliminated by the Schur complement (their blocks are 3 × 3 diagonal), and the 6 × 6
//! covariance `Σ_T` of `T_M` is the last block of the inverse of the reduced camera system. Its
//! translation block `Σ_v` and rotation block `Σ_ω` (eq. 4.4) give the entropy reduction
//! against the minimal setting `⟨1, 12⟩`, `E = (ln det Σ_⟨1,12⟩ − ln det Σ_⟨M,N⟩) / (2 ln 2)`
//! bits (eq. 4.11).

use crate::sensor::{Sensor, StereoSensor};
use crate::trajectory::sideways;
use crate::world::nested_plane_grid;
use lie::{LieGroup, Se3};
use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3};
use slam::factors::Projector;

/// Frames captured after `T_0` (thesis §4.3.1).
pub const FRAMES: usize = 36;
/// Points of the full pattern.
pub const MAX_POINTS: usize = 425;

/// The scene of §4.3.1: the 425 points in nested order, centred on the middle of the 1 m
/// trajectory, 3 m ahead.
pub fn scene() -> Vec<Vector3<f64>> {
    nested_plane_grid(25, 17, 2.4, 1.6, 3.0)
        .iter()
        .map(|p| p + Vector3::new(0.5, 0.0, 0.0))
        .collect()
}

/// The sensor of §4.3.1.
pub fn sensor() -> StereoSensor {
    StereoSensor::vga(500.0, 0.1, 0.5)
}

/// The keyframes `T_0, T_{k_1}, …, T_{k_M}` for `M` keyframes out of the 36 frames.
pub fn keyframes(m: usize) -> Vec<Se3> {
    let all = sideways(1.0, FRAMES);
    let m = m.clamp(1, FRAMES);
    (0..=m)
        .map(|k| all[((k * FRAMES) as f64 / m as f64).round() as usize])
        .collect()
}

/// The 6 × 6 covariance `(v, ω)` of the last pose of `poses` (the first is fixed) observing
/// `points` with stereo noise `σ`, by covariance back-propagation at the truth (eq. 4.3) with
/// the points eliminated by the Schur complement. `None` if the problem is singular or a
/// point is not visible from every pose.
pub fn end_pose_covariance(
    sensor: &StereoSensor,
    poses: &[Se3],
    points: &[Vector3<f64>],
) -> Option<SMatrix<f64, 6, 6>> {
    let m = poses.len() - 1;
    if m == 0 {
        return None;
    }
    let w = 1.0 / (sensor.sigma * sensor.sigma);
    let dim = 6 * m;
    let mut s = DMatrix::<f64>::zeros(dim, dim);
    // Per point: H_jj and the column blocks W_ij = J_iᵀΛJ_j of the free poses.
    let mut w_blocks: Vec<SMatrix<f64, 6, 3>> = vec![SMatrix::zeros(); m];
    for y in points {
        let mut h_jj = Matrix3::zeros();
        for (i, t) in poses.iter().enumerate() {
            let x = t.act(y);
            sensor.predict(t, y)?;
            let (_, dz_dx) = Projector::<3>::project(&sensor.camera, &x)?;
            let j_point = dz_dx * t.d_act_d_point();
            h_jj += j_point.transpose() * j_point * w;
            if i > 0 {
                let j_pose = dz_dx * t.d_act_d_left(y);
                let mut block = s.fixed_view_mut::<6, 6>(6 * (i - 1), 6 * (i - 1));
                block += j_pose.transpose() * j_pose * w;
                w_blocks[i - 1] = j_pose.transpose() * j_point * w;
            }
        }
        let h_inv = h_jj.try_inverse()?;
        for a in 0..m {
            let wa = w_blocks[a] * h_inv;
            for (b, wb) in w_blocks.iter().enumerate() {
                let mut block = s.fixed_view_mut::<6, 6>(6 * a, 6 * b);
                block -= wa * wb.transpose();
            }
        }
    }
    let cov = lsq::dense::spd_inverse(&s)?;
    Some(cov.fixed_view::<6, 6>(dim - 6, dim - 6).into_owned())
}

/// One cell of the Figure 4.3 surfaces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    /// Keyframes.
    pub m: usize,
    /// Points.
    pub n: usize,
    /// `ln det Σ_v` (translation).
    pub ln_det_translation: f64,
    /// `ln det Σ_ω` (rotation).
    pub ln_det_rotation: f64,
    /// Entropy reduction of the translation against `⟨1, 12⟩` in bits (eq. 4.11).
    pub entropy_translation: f64,
    /// Entropy reduction of the rotation against `⟨1, 12⟩` in bits.
    pub entropy_rotation: f64,
}

/// `N` values of the surfaces: `12·2^{k/4}` rounded, up to 425, and 425 — doubling `N` is
/// four grid steps.
pub fn n_grid() -> Vec<usize> {
    let mut v: Vec<usize> = (0..)
        .map(|k| (12.0 * 2f64.powf(k as f64 / 4.0)).round() as usize)
        .take_while(|&n| n < MAX_POINTS)
        .collect();
    v.push(MAX_POINTS);
    v
}

/// `ln|det|` of the 3 × 3 block at `o`.
fn ln_det3(c: &SMatrix<f64, 6, 6>, o: usize) -> f64 {
    c.fixed_view::<3, 3>(o, o).determinant().abs().ln()
}

/// The surfaces of Figure 4.3 over `m_values × n_values` (thesis §4.3.3), row-major in `m`.
pub fn surfaces(m_values: &[usize], n_values: &[usize]) -> Vec<Cell> {
    let sensor = sensor();
    let scene = scene();
    let base = end_pose_covariance(&sensor, &keyframes(1), &scene[..12])
        .expect("the minimal setting is well-posed");
    let (base_v, base_w) = (ln_det3(&base, 0), ln_det3(&base, 3));
    let bits = 1.0 / (2.0 * std::f64::consts::LN_2);
    let mut out = Vec::with_capacity(m_values.len() * n_values.len());
    for &m in m_values {
        let poses = keyframes(m);
        for &n in n_values {
            let c = end_pose_covariance(&sensor, &poses, &scene[..n.min(MAX_POINTS)])
                .expect("every setting of §4.3.1 is well-posed");
            let (v, w) = (ln_det3(&c, 0), ln_det3(&c, 3));
            out.push(Cell {
                m,
                n,
                ln_det_translation: v,
                ln_det_rotation: w,
                entropy_translation: (base_v - v) * bits,
                entropy_rotation: (base_w - w) * bits,
            });
        }
    }
    out
}

/// The thesis's claim at one grid point: the entropy gained by doubling `N` and by doubling
/// `M`, for translation and rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Doubling {
    /// Keyframes.
    pub m: usize,
    /// Points.
    pub n: usize,
    /// `E⟨M, 2N⟩ − E⟨M, N⟩` (translation).
    pub gain_n_translation: f64,
    /// `E⟨2M, N⟩ − E⟨M, N⟩` (translation).
    pub gain_m_translation: f64,
    /// `E⟨M, 2N⟩ − E⟨M, N⟩` (rotation).
    pub gain_n_rotation: f64,
    /// `E⟨2M, N⟩ − E⟨M, N⟩` (rotation).
    pub gain_m_rotation: f64,
}

impl Doubling {
    /// Doubling `N` gains more than doubling `M`, for translation and rotation.
    pub fn points_win(&self) -> bool {
        self.gain_n_translation > self.gain_m_translation
            && self.gain_n_rotation > self.gain_m_rotation
    }
}

/// The doubling comparison at every grid point where both `2M` and `2N` (to within the grid:
/// the `N` four steps up) are on the grid.
pub fn doublings(cells: &[Cell], n_values: &[usize]) -> Vec<Doubling> {
    let get = |m: usize, n: usize| cells.iter().find(|c| c.m == m && c.n == n);
    let mut out = Vec::new();
    for c in cells {
        let Some(k) = n_values.iter().position(|&n| n == c.n) else {
            continue;
        };
        let Some(&n2) = n_values.get(k + 4) else {
            continue;
        };
        // The last grid value (425) is not a doubling of its predecessor four steps down.
        if n2 != (12.0 * 2f64.powf((k + 4) as f64 / 4.0)).round() as usize {
            continue;
        }
        let (Some(dn), Some(dm)) = (get(c.m, n2), get(2 * c.m, c.n)) else {
            continue;
        };
        out.push(Doubling {
            m: c.m,
            n: c.n,
            gain_n_translation: dn.entropy_translation - c.entropy_translation,
            gain_m_translation: dm.entropy_translation - c.entropy_translation,
            gain_n_rotation: dn.entropy_rotation - c.entropy_rotation,
            gain_m_rotation: dm.entropy_rotation - c.entropy_rotation,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use lsq::{Information, Problem};
    use slam::factors::PointObservation;

    #[test]
    fn schur_covariance_equals_the_full_systems_marginal() {
        let sensor = sensor();
        let poses = keyframes(3);
        let points = &scene()[..20];
        let ours = end_pose_covariance(&sensor, &poses, points).unwrap();
        let mut problem = Problem::new();
        let pv: Vec<_> = poses.iter().map(|t| problem.add_variable(*t)).collect();
        problem.set_fixed(pv[0].key(), true);
        for y in points {
            let yv = problem.add_variable(*y);
            for (i, t) in poses.iter().enumerate() {
                let z = sensor.predict(t, y).unwrap();
                problem
                    .add_factor(
                        PointObservation {
                            camera_from_world: pv[i],
                            point_world: yv,
                            measurement: z,
                            projector: sensor.camera,
                        },
                        Information::Isotropic(sensor.sigma),
                        None,
                    )
                    .unwrap();
            }
        }
        let reference = problem.covariance(&[pv[3].key()]).unwrap();
        let diff = (DMatrix::from_column_slice(6, 6, ours.as_slice()) - &reference).amax();
        assert!(diff < 1e-9 * reference.amax(), "difference {diff}");
    }

    #[test]
    fn more_points_help_more_than_more_frames_on_a_small_grid() {
        let ns = n_grid();
        assert_eq!(ns[..5], [12, 14, 17, 20, 24]);
        assert_eq!(*ns.last().unwrap(), 425);
        let cells = surfaces(&[1, 2, 4], &ns[..9]);
        assert!(cells[0].entropy_translation.abs() < 1e-12);
        let d = doublings(&cells, &ns[..9]);
        assert_eq!(d.len(), 2 * 5);
        assert!(d.iter().all(Doubling::points_win), "{d:?}");
        // Same inputs, same bits.
        assert_eq!(cells, surfaces(&[1, 2, 4], &ns[..9]));
    }
}
