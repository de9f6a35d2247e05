//! Levenberg-Marquardt and Gauss-Newton on manifolds (thesis §2.2.3–2.2.4, §2.4.10).

use crate::linear::{CholeskyMethod, DenseCholesky, LinearError, LinearSolve, Pcg, SparseCholesky};
use crate::problem::{Problem, ProblemError};
use crate::schur::{SchurCholesky, SchurPcg};
use crate::values::VarKey;
use std::time::{Duration, Instant};

/// The non-linear optimisation algorithm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Algorithm {
    /// Levenberg-Marquardt (thesis §2.2.4): damped steps, accepted only if they reduce the
    /// cost.
    LevenbergMarquardt,
    /// Gauss-Newton (thesis §2.2.3): undamped steps, always taken.
    GaussNewton,
}

/// How the normal equations are solved.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinearSolver {
    /// `SchurCholesky` if variables are marked for elimination, `Dense` for systems of at most
    /// 120 unknowns, otherwise `SparseCholesky`.
    Auto,
    /// Supernodal sparse Cholesky (faer) with an AMD ordering on the block graph; the
    /// symbolic factorisation is reused across iterations.
    SparseCholesky,
    /// Dense Cholesky.
    Dense,
    /// Conjugate gradients with a block-Jacobi preconditioner.
    Pcg,
    /// Schur complement (thesis §3.3.5), reduced system by sparse Cholesky.
    SchurCholesky,
    /// Schur complement without forming the reduced system, solved by conjugate gradients with
    /// a block-Jacobi preconditioner (implicit Schur).
    SchurPcg,
}

/// How the damping `D` of `(H + λD)·δ = −g` is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Damping {
    /// `D = diag(H)`, clamped to `[1e-6, 1e32]` (Marquardt; invariant to variable scaling).
    Marquardt,
    /// `D = I` (Levenberg).
    Levenberg,
}

/// Options of [`Problem::optimise`].
#[derive(Clone, Debug)]
pub struct SolverOptions {
    /// The algorithm.
    pub algorithm: Algorithm,
    /// The linear solver.
    pub linear_solver: LinearSolver,
    /// The damping of Levenberg-Marquardt.
    pub damping: Damping,
    /// Stop after this many iterations (linear solves).
    pub max_iterations: usize,
    /// Stop when an accepted step reduces the cost by less than this fraction.
    pub function_tolerance: f64,
    /// Stop when an accepted step reduces the cost by less than this amount (GTSAM's
    /// `absoluteErrorTol`; 0 disables it).
    pub absolute_function_tolerance: f64,
    /// Stop when `max |g| ≤ gradient_tolerance`.
    pub gradient_tolerance: f64,
    /// Stop when `‖δ‖ ≤ parameter_tolerance`.
    pub parameter_tolerance: f64,
    /// Stop when this much time has passed.
    pub max_time: Option<Duration>,
    /// The initial damping `λ` of Levenberg-Marquardt.
    pub initial_lambda: f64,
    /// After a step with gain ratio `ρ`, `λ ← λ·max(c, 1 − (2ρ − 1)³)` (Nielsen's rule with
    /// this floor `c`): how fast damping may fall after steps the quadratic model predicted well.
    pub lambda_decrease_floor: f64,
    /// Worker threads (`None`: rayon's global pool).
    pub threads: Option<usize>,
    /// Maximum conjugate-gradient iterations per solve.
    pub pcg_max_iterations: usize,
    /// Relative residual at which conjugate gradients stop.
    pub pcg_tolerance: f64,
    /// Organisation of the sparse Cholesky factorisation (`SparseCholesky`, `SchurCholesky`).
    pub cholesky_method: CholeskyMethod,
}

impl Default for SolverOptions {
    fn default() -> Self {
        SolverOptions {
            algorithm: Algorithm::LevenbergMarquardt,
            linear_solver: LinearSolver::Auto,
            damping: Damping::Marquardt,
            max_iterations: 100,
            function_tolerance: 1e-6,
            absolute_function_tolerance: 0.0,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-10,
            max_time: None,
            initial_lambda: 1e-4,
            lambda_decrease_floor: 1.0 / 3.0,
            threads: None,
            pcg_max_iterations: 500,
            pcg_tolerance: 1e-6,
            cholesky_method: CholeskyMethod::Auto,
        }
    }
}

/// Statistics of one iteration.
#[derive(Clone, Debug, Default)]
pub struct IterationStats {
    /// Iteration number, from 1.
    pub iteration: usize,
    /// Cost `½Σρ` after the iteration (unchanged if the step was rejected).
    pub cost: f64,
    /// `χ² = ΣrᵀΛr` after the iteration.
    pub chi2: f64,
    /// The damping `λ` used for this step (0 for Gauss-Newton).
    pub lambda: f64,
    /// `‖δ‖`.
    pub step_norm: f64,
    /// Whether the step was taken.
    pub accepted: bool,
    /// Gain ratio: actual over predicted cost decrease.
    pub gain_ratio: f64,
    /// Inner iterations of the linear solver.
    pub linear_iterations: usize,
    /// Factors whose residual was undefined at the candidate.
    pub invalid_factors: usize,
    /// Time evaluating residuals and Jacobians.
    pub time_linearize: Duration,
    /// Time assembling the normal equations.
    pub time_build: Duration,
    /// Time solving them.
    pub time_solve: Duration,
    /// Wall time since the start of the optimisation.
    pub elapsed: Duration,
}

/// Why the optimisation stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// The relative cost decrease fell below the function tolerance.
    FunctionTolerance,
    /// The gradient fell below the gradient tolerance.
    GradientTolerance,
    /// The step fell below the parameter tolerance.
    ParameterTolerance,
    /// The iteration limit was reached.
    MaxIterations,
    /// The time budget ran out.
    TimeBudget,
    /// No step reduced the cost however strongly damped.
    NoProgress,
    /// There is nothing to optimise (no free variable in any factor).
    NothingToOptimise,
}

impl Termination {
    /// Whether this counts as convergence.
    pub fn converged(self) -> bool {
        matches!(
            self,
            Termination::FunctionTolerance
                | Termination::GradientTolerance
                | Termination::ParameterTolerance
        )
    }
}

/// The outcome of [`Problem::optimise`].
#[derive(Clone, Debug)]
pub struct Summary {
    /// Cost `½Σρ` before.
    pub initial_cost: f64,
    /// Cost `½Σρ` after.
    pub final_cost: f64,
    /// `χ²` before.
    pub initial_chi2: f64,
    /// `χ²` after.
    pub final_chi2: f64,
    /// Per-iteration statistics.
    pub iterations: Vec<IterationStats>,
    /// Why it stopped.
    pub termination: Termination,
    /// Time to analyse the structure (ordering, symbolic factorisation).
    pub time_structure: Duration,
    /// Total wall time.
    pub time_total: Duration,
    /// Scalar unknowns of the (full) normal equations.
    pub num_unknowns: usize,
    /// Factors whose residual was undefined at the final values.
    pub invalid_factors: usize,
    /// The linear solver used.
    pub linear_solver: LinearSolver,
}

impl Summary {
    /// Number of accepted steps.
    pub fn accepted_steps(&self) -> usize {
        self.iterations.iter().filter(|i| i.accepted).count()
    }
}

/// Why an optimisation could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolveError {
    /// The problem's structure is invalid.
    #[error(transparent)]
    Problem(#[from] ProblemError),
    /// The linear solver failed where no damping can help (Gauss-Newton on a singular
    /// system, or symbolic analysis).
    #[error(transparent)]
    Linear(#[from] LinearError),
    /// The initial values give a non-finite cost.
    #[error("the cost at the initial values is not finite")]
    NonFiniteInitialCost,
    /// The thread pool could not be created.
    #[error("could not create a thread pool: {0}")]
    ThreadPool(String),
}

impl Problem {
    /// Minimises the cost from the current values, which hold the result afterwards.
    pub fn optimise(&mut self, options: &SolverOptions) -> Result<Summary, SolveError> {
        self.optimise_with(options, |_| {})
    }

    /// [`optimise`](Self::optimise), calling `on_iteration` after each iteration (for progress
    /// output).
    pub fn optimise_with(
        &mut self,
        options: &SolverOptions,
        on_iteration: impl FnMut(&IterationStats) + Send,
    ) -> Result<Summary, SolveError> {
        match options.threads {
            Some(n) => {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(n.max(1))
                    .build()
                    .map_err(|e| SolveError::ThreadPool(e.to_string()))?;
                pool.install(|| self.optimise_inner(options, on_iteration))
            }
            None => self.optimise_inner(options, on_iteration),
        }
    }

    fn optimise_inner(
        &mut self,
        options: &SolverOptions,
        mut on_iteration: impl FnMut(&IterationStats),
    ) -> Result<Summary, SolveError> {
        let start = Instant::now();
        self.ensure_structure()?;
        let (n, num_reduced, num_blocks) = {
            let s = self.structure.as_ref().expect("built");
            (s.hessian.dim(), s.num_reduced, s.hessian.num_blocks())
        };
        let kind = match options.linear_solver {
            LinearSolver::Auto if num_reduced < num_blocks => LinearSolver::SchurCholesky,
            LinearSolver::Auto if n <= 120 => LinearSolver::Dense,
            LinearSolver::Auto => LinearSolver::SparseCholesky,
            other => other,
        };
        let mut solver: Box<dyn LinearSolve> = {
            let s = self.structure.as_ref().expect("built");
            match kind {
                LinearSolver::SparseCholesky => {
                    Box::new(SparseCholesky::new(&s.hessian, options.cholesky_method)?)
                }
                LinearSolver::Dense => Box::new(DenseCholesky),
                LinearSolver::Pcg => {
                    Box::new(Pcg::new(options.pcg_max_iterations, options.pcg_tolerance))
                }
                LinearSolver::SchurCholesky => Box::new(SchurCholesky::new(
                    &s.hessian,
                    num_reduced,
                    options.cholesky_method,
                )?),
                LinearSolver::SchurPcg => Box::new(SchurPcg::new(
                    &s.hessian,
                    num_reduced,
                    options.pcg_max_iterations,
                    options.pcg_tolerance,
                )),
                LinearSolver::Auto => unreachable!("resolved above"),
            }
        };
        let time_structure = start.elapsed();
        let exact_solve = !matches!(kind, LinearSolver::Pcg | LinearSolver::SchurPcg);

        let t = Instant::now();
        let mut current = self.evaluate(true);
        let mut time_linearize = t.elapsed();
        if !current.cost.is_finite() {
            return Err(SolveError::NonFiniteInitialCost);
        }
        let initial = current;
        let mut summary = Summary {
            initial_cost: initial.cost,
            final_cost: initial.cost,
            initial_chi2: initial.chi2,
            final_chi2: initial.chi2,
            // Reserved up front so that the iteration loop allocates nothing.
            iterations: Vec::with_capacity(options.max_iterations.min(100_000)),
            termination: Termination::MaxIterations,
            time_structure,
            time_total: Duration::ZERO,
            num_unknowns: n,
            invalid_factors: initial.invalid,
            linear_solver: kind,
        };
        if n == 0 {
            summary.termination = Termination::NothingToOptimise;
            summary.time_total = start.elapsed();
            return Ok(summary);
        }

        let lm = options.algorithm == Algorithm::LevenbergMarquardt;
        let mut lambda = if lm { options.initial_lambda } else { 0.0 };
        let mut nu = 2.0;
        let mut delta = vec![0.0; n];
        let mut diag_add = vec![0.0; n];
        let mut h_delta = vec![0.0; n];
        let mut needs_assembly = true;
        let mut time_build = Duration::ZERO;

        for iteration in 1..=options.max_iterations {
            if let Some(budget) = options.max_time
                && start.elapsed() >= budget
            {
                summary.termination = Termination::TimeBudget;
                break;
            }
            if needs_assembly {
                let t = Instant::now();
                self.assemble();
                time_build = t.elapsed();
                needs_assembly = false;
                let g_max = self.gradient().iter().fold(0.0f64, |a, b| a.max(b.abs()));
                if g_max <= options.gradient_tolerance {
                    summary.termination = Termination::GradientTolerance;
                    break;
                }
            }
            let structure = self.structure.as_ref().expect("built");
            let h = &structure.hessian;
            // Damping D: diag(H) clamped (Marquardt) or I (Levenberg).
            for j in 0..h.num_blocks() {
                let (o, d) = (h.offsets[j], h.dims[j]);
                let block = h.diagonal_block(j);
                for k in 0..d {
                    let dk = match options.damping {
                        Damping::Marquardt => block[k * d + k].clamp(1e-6, 1e32),
                        Damping::Levenberg => 1.0,
                    };
                    diag_add[o + k] = lambda * dk;
                }
            }
            let t = Instant::now();
            let solved = solver.solve(
                h,
                &self.workspace.as_ref().expect("built").gradient,
                &diag_add,
                &mut delta,
            );
            let time_solve = t.elapsed();
            let mut stats = IterationStats {
                iteration,
                cost: current.cost,
                chi2: current.chi2,
                lambda,
                time_build,
                time_solve,
                ..Default::default()
            };
            time_build = Duration::ZERO;
            let linear_iterations = match solved {
                Ok(it) => it,
                Err(LinearError::NotPositiveDefinite) if lm => {
                    lambda *= nu;
                    nu *= 2.0;
                    stats.elapsed = start.elapsed();
                    stats.time_linearize = std::mem::take(&mut time_linearize);
                    on_iteration(&stats);
                    summary.iterations.push(stats);
                    if lambda > 1e32 {
                        summary.termination = Termination::NoProgress;
                        break;
                    }
                    continue;
                }
                Err(e) => return Err(e.into()),
            };
            stats.linear_iterations = linear_iterations;
            let step_norm = delta.iter().map(|x| x * x).sum::<f64>().sqrt();
            stats.step_norm = step_norm;
            if !step_norm.is_finite() {
                return Err(SolveError::Linear(LinearError::NotPositiveDefinite));
            }
            if step_norm <= options.parameter_tolerance {
                stats.elapsed = start.elapsed();
                stats.time_linearize = std::mem::take(&mut time_linearize);
                on_iteration(&stats);
                summary.iterations.push(stats);
                summary.termination = Termination::ParameterTolerance;
                break;
            }
            // Predicted decrease of the quadratic model: −(gᵀδ + ½δᵀHδ). A direct solve makes
            // (H + D)δ = −g hold to rounding, so δᵀHδ = −gᵀδ − δᵀDδ and no product is needed;
            // an inexact (iterative) step needs the product itself.
            let g = &self.workspace.as_ref().expect("built").gradient;
            let g_delta: f64 = g.iter().zip(&delta).map(|(a, b)| a * b).sum();
            let d_h_d = if exact_solve {
                let d_d_d: f64 = delta.iter().zip(&diag_add).map(|(x, d)| d * x * x).sum();
                -g_delta - d_d_d
            } else {
                h.multiply(&delta, &mut h_delta);
                delta.iter().zip(&h_delta).map(|(a, b)| a * b).sum()
            };
            let predicted = -(g_delta + 0.5 * d_h_d);

            // Candidate: linearise there directly (its Jacobians are needed if it is taken;
            // the assembled H and g of the current point stay intact if it is not).
            self.values.save();
            self.apply_step(&delta);
            let t = Instant::now();
            let candidate = self.evaluate(true);
            time_linearize += t.elapsed();
            stats.invalid_factors = candidate.invalid;
            let actual = current.cost - candidate.cost;
            let gain = if predicted > 0.0 {
                actual / predicted
            } else {
                f64::NEG_INFINITY
            };
            stats.gain_ratio = gain;
            let valid = candidate.cost.is_finite() && candidate.invalid <= current.invalid;
            let accept = valid && (!lm || gain > 1e-3);
            if accept {
                let relative = actual / current.cost.max(f64::MIN_POSITIVE);
                current = candidate;
                needs_assembly = true;
                if lm {
                    lambda *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(options.lambda_decrease_floor);
                    nu = 2.0;
                }
                stats.accepted = true;
                stats.cost = current.cost;
                stats.chi2 = current.chi2;
                stats.elapsed = start.elapsed();
                stats.time_linearize = std::mem::take(&mut time_linearize);
                on_iteration(&stats);
                summary.iterations.push(stats);
                if relative.abs() < options.function_tolerance
                    || actual.abs() < options.absolute_function_tolerance
                {
                    summary.termination = Termination::FunctionTolerance;
                    break;
                }
            } else {
                self.values.restore();
                if lm {
                    lambda *= nu;
                    nu *= 2.0;
                }
                stats.elapsed = start.elapsed();
                stats.time_linearize = std::mem::take(&mut time_linearize);
                on_iteration(&stats);
                summary.iterations.push(stats);
                if !lm || lambda > 1e32 {
                    summary.termination = Termination::NoProgress;
                    break;
                }
            }
        }
        // The workspace's per-factor residuals belong to the last evaluated point; if the last
        // candidate was rejected they are stale, which only matters to the next call, which
        // evaluates afresh.
        summary.final_cost = current.cost;
        summary.final_chi2 = current.chi2;
        summary.invalid_factors = current.invalid;
        summary.time_total = start.elapsed();
        Ok(summary)
    }

    fn gradient(&self) -> &[f64] {
        &self.workspace.as_ref().expect("built").gradient
    }

    /// The joint marginal covariance of the given variables at the current values: the
    /// corresponding block of `H⁻¹` with `H = J̃ᵀJ̃` (thesis §2.3.3; Laplace approximation).
    /// Rows and columns follow `keys` in order, each variable taking its tangent dimension.
    /// Fixed variables have zero covariance. The gauge must be fixed (or the problem otherwise
    /// well-posed), else `H` is singular and this is an error.
    pub fn covariance(&mut self, keys: &[VarKey]) -> Result<nalgebra::DMatrix<f64>, SolveError> {
        // Covariances are taken on the full system (no elimination).
        let eliminated = self.take_eliminated();
        self.ensure_structure()?;
        self.evaluate(true);
        self.assemble();
        let s = self.structure.as_ref().expect("built");
        let h = &s.hessian;
        let mut chol = SparseCholesky::new(h, CholeskyMethod::Auto)?;
        chol.factorize(h, &vec![0.0; h.dim()])?;
        let dims: Vec<usize> = keys.iter().map(|k| self.values.dim(*k)).collect();
        let total: usize = dims.iter().sum();
        let mut cov = nalgebra::DMatrix::zeros(total, total);
        let location = |key: &VarKey| -> Option<usize> {
            let b = s.block_of[key.kind as usize][key.index as usize];
            (b != crate::problem::NONE).then(|| h.offsets[b as usize])
        };
        let mut col = 0;
        let mut rhs = vec![0.0; h.dim()];
        for (k, key) in keys.iter().enumerate() {
            for c in 0..dims[k] {
                if let Some(o) = location(key) {
                    rhs.iter_mut().for_each(|x| *x = 0.0);
                    rhs[o + c] = 1.0;
                    chol.solve_in_place(&mut rhs);
                    let mut row = 0;
                    for (k2, key2) in keys.iter().enumerate() {
                        if let Some(o2) = location(key2) {
                            for r in 0..dims[k2] {
                                cov[(row + r, col)] = rhs[o2 + r];
                            }
                        }
                        row += dims[k2];
                    }
                }
                col += 1;
            }
        }
        self.restore_eliminated(eliminated);
        Ok(cov)
    }
}
