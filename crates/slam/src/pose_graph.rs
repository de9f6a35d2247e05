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

use lie::{LieGroup, LogJacobian, d_log_from_parts};
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
            if j.wants(0) {
                let ad = self.measured.adjoint();
                j.set(0, &d_log_from_parts::<G, D>(&d, &ad, self.jacobian));
            }
            if j.wants(1) {
                let identity = SMatrix::<f64, D, D>::identity();
                j.set(
                    1,
                    &(-d_log_from_parts::<G, D>(&(-d), &identity, self.jacobian)),
                );
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
