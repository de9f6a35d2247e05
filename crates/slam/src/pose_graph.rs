//! Pose-graph optimisation (thesis §5.3.2–5.3.3, app. B.6) over SE(2), SE(3) or Sim(3).
//!
//! Variables are absolute poses `T_i = camera_from_world` (the thesis's `T_iw`); a constraint
//! between `i` and `j` is a measured relative pose `T_ji` (mapping frame `i` into frame `j`).
//! Its residual lives in the tangent space (thesis eq. 5.15, 5.17):
//!
//! `d_ij = log(T_ji · T_i · T_j⁻¹)^∨`.
//!
//! With world-from-body poses `P_i = T_i⁻¹` and a g2o/GTSAM measurement `Z_ij = P_i⁻¹·P_j`,
//! `T_ji = Z_ij⁻¹` and `d_ij = log(Z_ij⁻¹·P_i⁻¹·P_j)`: exactly GTSAM's `BetweenFactor` error.
//!
//! Jacobians (thesis eq. 5.18–5.22): with respect to `T_i` it is
//! `J_A^B = ∂ log(A·exp(ε)·B)/∂ε` with `A = T_ji`, `B = T_i·T_j⁻¹`, and with respect to `T_j`
//! it is `−J_I^{B'}` with `B' = T_j·T_i⁻¹·T_ji⁻¹ = exp(−d)`. Both are computed exactly
//! (`J_l(d)⁻¹·Ad_{T_ji}` and `−J_l(−d)⁻¹`) or by the CBH approximations of
//! [`lie::LogJacobian`].

use lie::{LieGroup, LogJacobian, log_jacobian_factors};
use lsq::{Factor, Jacobians, Manifold, Values, Var, VarKey};
use nalgebra::SMatrix;

/// A relative-pose constraint `d = log(T_ji·T_i·T_j⁻¹)` between two absolute poses of group
/// `G` (SE(2), SE(3) or Sim(3)).
pub struct BetweenFactor<G, const D: usize> {
    /// `T_i = camera_from_world` of the first pose.
    pub from: Var<G>,
    /// `T_j` of the second pose.
    pub to: Var<G>,
    /// The measured `T_ji` (frame `i` into frame `j`).
    pub measured: G,
    /// How the Jacobians are computed.
    pub jacobian: LogJacobian,
}

impl<G: LieGroup<D> + Manifold, const D: usize> BetweenFactor<G, D> {
    /// The constraint `T_ji` between `from` and `to`, with exact Jacobians.
    pub fn new(from: Var<G>, to: Var<G>, measured: G) -> Self {
        BetweenFactor {
            from,
            to,
            measured,
            jacobian: LogJacobian::Exact,
        }
    }

    /// The residual at given poses.
    pub fn residual(&self, t_i: &G, t_j: &G) -> nalgebra::SVector<f64, D> {
        self.measured.compose(t_i).compose(&t_j.inverse()).log()
    }
}

impl<G: LieGroup<D> + Manifold, const D: usize> Factor for BetweenFactor<G, D> {
    fn residual_dim(&self) -> usize {
        D
    }

    fn variables(&self) -> Vec<VarKey> {
        vec![self.from.key(), self.to.key()]
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let d = self.residual(values.get(self.from), values.get(self.to));
        residual.copy_from_slice(d.as_slice());
        if let Some(j) = jacobians {
            // ∂d/∂ε_i = M(d)·Ad_{T_ji}, ∂d/∂ε_j = −M(−d), sharing the CBH terms.
            let (m_plus, m_minus) = log_jacobian_factors::<G, D>(&d, self.jacobian);
            if j.wants(0) {
                let ad = self.measured.adjoint();
                if self.jacobian == LogJacobian::Cbh1 {
                    j.set(0, &ad);
                } else {
                    j.set(0, &(m_plus * ad));
                }
            }
            if j.wants(1) {
                j.set(1, &(-m_minus));
            }
        }
        true
    }
}

/// How the Jacobians of pose-graph constraints are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseGraphJacobian {
    /// Analytic: exact or CBH ([`BetweenFactor`]).
    Analytic(LogJacobian),
    /// Central differences ([`NumericBetweenFactor`]), the reference of thesis Fig. 5.4.
    Numeric,
}

/// The step of [`NumericBetweenFactor`]'s central differences: near the cube root of the
/// machine epsilon, balancing truncation (`O(h²)`) against rounding (`O(ε/h)`) errors.
pub const NUMERIC_STEP: f64 = 1e-5;

/// [`BetweenFactor`]'s residual `d = log(T_ji·T_i·T_j⁻¹)` with numeric Jacobians: central
/// differences through the optimiser's left update, column `k` of `∂d/∂ε_i` being
/// `(d(exp(h·e_k)·T_i) − d(exp(−h·e_k)·T_i)) / 2h` (and likewise for `T_j`): `4·D` residual
/// evaluations per linearisation (thesis §5.4, Fig. 5.4's "numerical Jacobian").
pub struct NumericBetweenFactor<G, const D: usize> {
    /// `T_i`.
    pub from: Var<G>,
    /// `T_j`.
    pub to: Var<G>,
    /// The measured `T_ji`.
    pub measured: G,
}

impl<G: LieGroup<D> + Manifold, const D: usize> Factor for NumericBetweenFactor<G, D> {
    fn residual_dim(&self) -> usize {
        D
    }

    fn variables(&self) -> Vec<VarKey> {
        vec![self.from.key(), self.to.key()]
    }

    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let (t_i, t_j) = (values.get(self.from), values.get(self.to));
        let r = |a: &G, b: &G| self.measured.compose(a).compose(&b.inverse()).log();
        residual.copy_from_slice(r(t_i, t_j).as_slice());
        if let Some(j) = jacobians {
            for slot in 0..2 {
                if !j.wants(slot) {
                    continue;
                }
                let mut block = SMatrix::<f64, D, D>::zeros();
                for k in 0..D {
                    let mut e = nalgebra::SVector::<f64, D>::zeros();
                    e[k] = NUMERIC_STEP;
                    let (plus, minus) = if slot == 0 {
                        (
                            r(&t_i.retract_left(&e), t_j),
                            r(&t_i.retract_left(&(-e)), t_j),
                        )
                    } else {
                        (
                            r(t_i, &t_j.retract_left(&e)),
                            r(t_i, &t_j.retract_left(&(-e))),
                        )
                    };
                    block
                        .column_mut(k)
                        .copy_from(&((plus - minus) / (2.0 * NUMERIC_STEP)));
                }
                j.set(slot, &block);
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::{Se2, Se3, Sim3};
    use lsq::numeric::check_jacobians;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn check<G: LieGroup<D> + Manifold, const D: usize>(seed: u64, spread: f64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut tangent =
            || nalgebra::SVector::<f64, D>::from_fn(|_, _| rng.random_range(-spread..spread));
        for _ in 0..50 {
            let mut values = Values::new();
            let a = values.add(G::exp(&tangent()));
            let b = values.add(G::exp(&tangent()));
            let measured = G::exp(&tangent());
            let factor = BetweenFactor {
                from: a,
                to: b,
                measured,
                jacobian: LogJacobian::Exact,
            };
            let result = check_jacobians(&factor, &values, 1e-4).expect("defined everywhere");
            assert!(
                result.passes(1e-7),
                "{}: {result:?}",
                <G as LieGroup<D>>::NAME
            );
        }
    }

    #[test]
    fn exact_jacobians_match_numeric_ones_for_se2_se3_sim3() {
        check::<Se2, 3>(1, 1.0);
        check::<Se3, 6>(2, 1.0);
        check::<Sim3, 7>(3, 0.8);
    }

    #[test]
    fn cbh_jacobians_approach_the_exact_one_as_the_residual_vanishes() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let t_i = Sim3::exp(&nalgebra::SVector::<f64, 7>::from_fn(|_, _| {
            rng.random_range(-1.0..1.0)
        }));
        let t_j = Sim3::exp(&nalgebra::SVector::<f64, 7>::from_fn(|_, _| {
            rng.random_range(-1.0..1.0)
        }));
        for &noise in &[0.3, 0.03, 0.003] {
            // T_ji close to the consistent value, so d is of order `noise`.
            let consistent = t_j.compose(&t_i.inverse());
            let perturb = Sim3::exp(&nalgebra::SVector::<f64, 7>::from_fn(|_, _| {
                rng.random_range(-noise..noise)
            }));
            let measured = perturb.compose(&consistent);
            let mut errs = Vec::new();
            let mut values = Values::new();
            let a = values.add(t_i);
            let b = values.add(t_j);
            for method in [LogJacobian::Cbh1, LogJacobian::Cbh2, LogJacobian::Cbh3] {
                let f = BetweenFactor {
                    from: a,
                    to: b,
                    measured,
                    jacobian: method,
                };
                errs.push(check_jacobians(&f, &values, 1e-4).unwrap().max_abs_error);
            }
            assert!(
                errs[2] < errs[1] && errs[1] < errs[0],
                "noise {noise}: {errs:?}"
            );
        }
    }

    #[test]
    fn numeric_jacobians_match_the_exact_ones() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for _ in 0..20 {
            let mut tangent =
                || nalgebra::SVector::<f64, 7>::from_fn(|_, _| rng.random_range(-0.8..0.8));
            let mut values = Values::new();
            let a = values.add(Sim3::exp(&tangent()));
            let b = values.add(Sim3::exp(&tangent()));
            let measured = Sim3::exp(&tangent());
            let numeric = NumericBetweenFactor {
                from: a,
                to: b,
                measured,
            };
            let check = check_jacobians(&numeric, &values, 1e-4).unwrap();
            assert!(check.passes(1e-7), "{check:?}");
            // Same residual as the analytic factor.
            let mut r1 = [0.0; 7];
            let mut r2 = [0.0; 7];
            numeric.evaluate(&values, &mut r1, None);
            BetweenFactor::new(a, b, measured).evaluate(&values, &mut r2, None);
            assert_eq!(r1, r2);
        }
    }

    #[test]
    fn residual_matches_gtsam_between_factor_convention() {
        // With P = world_from_body and Z = P_i⁻¹·P_j, d = log(Z⁻¹·P_i⁻¹·P_j).
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut t = || {
            Se3::exp(&nalgebra::Vector6::from_fn(|_, _| {
                rng.random_range(-1.0..1.0)
            }))
        };
        let (p_i, p_j, z) = (t(), t(), t());
        let mut values = Values::new();
        let a = values.add(p_i.inverse());
        let b = values.add(p_j.inverse());
        let f = BetweenFactor::new(a, b, z.inverse());
        let ours = f.residual(values.get(a), values.get(b));
        let gtsam = z.inverse().compose(&p_i.inverse()).compose(&p_j).log();
        assert!((ours - gtsam).amax() < 1e-12);
    }
}

/// A pose-graph optimisation problem over group `G`, built from absolute poses and relative
/// constraints in the thesis's convention.
pub struct PoseGraphProblem<G, const D: usize> {
    /// The least-squares problem.
    pub problem: lsq::Problem,
    /// The pose variables `T_i = camera_from_world`, in input order.
    pub poses: Vec<Var<G>>,
}

/// A relative constraint for [`PoseGraphProblem::new`]: poses `i` and `j` (indices into the
/// pose list), the measured `T_ji`, and the information matrix over the residual's tangent.
#[derive(Clone, Debug)]
pub struct Constraint<G, const D: usize> {
    /// Index of `T_i`.
    pub i: usize,
    /// Index of `T_j`.
    pub j: usize,
    /// The measured `T_ji`.
    pub measured: G,
    /// `Λ` over `d = log(T_ji·T_i·T_j⁻¹)`.
    pub information: SMatrix<f64, D, D>,
}

/// Why a pose graph could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseGraphError {
    /// A constraint names a pose that does not exist.
    #[error("constraint {constraint} refers to pose {pose}, but there are only {count} poses")]
    UnknownPose {
        /// Index of the constraint.
        constraint: usize,
        /// The missing pose index.
        pose: usize,
        /// Number of poses.
        count: usize,
    },
    /// The problem refused a factor.
    #[error("constraint {constraint}: {source}")]
    Factor {
        /// Index of the constraint.
        constraint: usize,
        /// Why.
        source: lsq::ProblemError,
    },
}

impl<G: LieGroup<D> + Manifold, const D: usize> PoseGraphProblem<G, D> {
    /// Builds the problem: one variable per pose (initial `camera_from_world`), one
    /// [`BetweenFactor`] per constraint with the given Jacobian method, and the listed poses
    /// fixed (none: the gauge is left to the damping, thesis §6.2.3).
    pub fn new(
        camera_from_world: &[G],
        constraints: &[Constraint<G, D>],
        fixed: &[usize],
        jacobian: LogJacobian,
    ) -> Result<Self, PoseGraphError> {
        Self::with_jacobian(
            camera_from_world,
            constraints,
            fixed,
            PoseGraphJacobian::Analytic(jacobian),
        )
    }

    /// [`new`](Self::new) with analytic ([`BetweenFactor`]) or numeric
    /// ([`NumericBetweenFactor`]) Jacobians.
    pub fn with_jacobian(
        camera_from_world: &[G],
        constraints: &[Constraint<G, D>],
        fixed: &[usize],
        jacobian: PoseGraphJacobian,
    ) -> Result<Self, PoseGraphError> {
        let mut problem = lsq::Problem::new();
        let poses: Vec<Var<G>> = camera_from_world
            .iter()
            .map(|t| problem.add_variable(*t))
            .collect();
        for (k, c) in constraints.iter().enumerate() {
            for pose in [c.i, c.j] {
                if pose >= poses.len() {
                    return Err(PoseGraphError::UnknownPose {
                        constraint: k,
                        pose,
                        count: poses.len(),
                    });
                }
            }
            let info = lsq::Information::Full(nalgebra::DMatrix::from_column_slice(
                D,
                D,
                c.information.as_slice(),
            ));
            let added = match jacobian {
                PoseGraphJacobian::Analytic(method) => problem.add_factor(
                    BetweenFactor {
                        from: poses[c.i],
                        to: poses[c.j],
                        measured: c.measured,
                        jacobian: method,
                    },
                    info,
                    None,
                ),
                PoseGraphJacobian::Numeric => problem.add_factor(
                    NumericBetweenFactor {
                        from: poses[c.i],
                        to: poses[c.j],
                        measured: c.measured,
                    },
                    info,
                    None,
                ),
            };
            added.map_err(|source| PoseGraphError::Factor {
                constraint: k,
                source,
            })?;
        }
        for &f in fixed {
            if let Some(v) = poses.get(f) {
                problem.set_fixed(v.key(), true);
            }
        }
        Ok(PoseGraphProblem { problem, poses })
    }

    /// The current `camera_from_world` poses, in input order.
    pub fn camera_from_world(&self) -> Vec<G> {
        self.poses.iter().map(|v| *self.problem.value(*v)).collect()
    }
}

/// The rigid pose with the same camera centre and orientation as a similarity
/// `camera_from_world` `x_c = s·R·x_w + t`: `(R, t/s)`. Used to return from a Sim(3) pose graph
/// to rigid poses in the corrected (rescaled) world (thesis §5.3.2).
pub fn rigid_from_similarity(camera_from_world: &lie::Sim3) -> lie::Se3 {
    lie::Se3::new(
        *camera_from_world.rotation(),
        camera_from_world.translation() / camera_from_world.scale(),
    )
}
