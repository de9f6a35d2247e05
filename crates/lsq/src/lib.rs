//! `lsq`: sparse non-linear least squares on manifolds, the optimisation engine of dwslam
//! (thesis §2.2–2.3, §3.3; the class of g2o, §3.3.8).
//!
//! A [`Problem`] holds variables on manifolds ([`Manifold`]: any `lie` group, updated by
//! `exp(δ)·x`, or a Euclidean vector of size 1–9) and [`Factor`]s of any arity, each with an
//! information matrix and an optional [`RobustKernel`]. [`Problem::optimise`] minimises
//!
//! `F(x) = ½ Σₖ ρₖ(rₖ(x)ᵀ Λₖ rₖ(x))`
//!
//! by Levenberg-Marquardt or Gauss-Newton. The normal equations `H·δ = −g`, `H = J̃ᵀJ̃`,
//! `g = J̃ᵀr̃` (thesis eq. 2.27, 3.17) are assembled block-sparse; they are solved by sparse
//! Cholesky (faer, AMD ordering on the block graph, symbolic factorisation reused), dense
//! Cholesky, block-Jacobi preconditioned conjugate gradients, or — for variables marked
//! for elimination, such as the points of bundle adjustment — by the Schur complement
//! (thesis §3.3.5), explicit or implicit.
//!
//! Gauge freedom is handled either by fixing variables ([`Problem::set_fixed`]) or by
//! leaving all free and relying on Levenberg-Marquardt's damping (thesis §6.2.3).
//! Linearisation and assembly run in parallel (rayon) into buffers allocated once per
//! structure: no allocation per factor per iteration.

#![warn(missing_docs)]
// Index loops are the clearer form for the block linear algebra here.
#![allow(clippy::needless_range_loop)]

mod block;
mod chi2;
pub mod dense;
mod factor;
mod kernels;
mod linear;
mod manifold;
pub mod numeric;
mod problem;
mod robust;
mod schur;
mod solver;
mod values;

pub use block::BlockSymmetric;
pub use chi2::chi2_quantile;
pub use factor::{Factor, Information, InformationError, Jacobians, MAX_ARITY};
pub use linear::{CholeskyMethod, LinearError};
pub use manifold::Manifold;
pub use problem::{FactorId, Problem, ProblemError};
pub use robust::RobustKernel;
pub use solver::{
    Algorithm, Damping, IterationStats, LinearSolver, SolveError, SolverOptions, Summary,
    Termination,
};
pub use values::{Values, Var, VarKey};
