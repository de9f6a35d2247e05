//! Every solver on problems with a known answer.

use lie::{LieGroup, Se3, So3};
use lsq::numeric::check_jacobians;
use lsq::{
    Algorithm, CholeskyMethod, Factor, Information, Jacobians, LinearSolver, Problem, ProblemError,
    RobustKernel, SolverOptions, Termination, Values, Var, VarKey,
};
use nalgebra::{DMatrix, DVector, SMatrix, Vector2, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `r = A·x + B·y − b` over two Euclidean 3-vectors: a linear residual.
struct Linear2 {
    x: Var<Vector3<f64>>,
    y: Option<Var<Vector3<f64>>>,
    a: SMatrix<f64, 2, 3>,
    b: SMatrix<f64, 2, 3>,
    rhs: Vector2<f64>,
}

impl Factor for Linear2 {
    fn residual_dim(&self) -> usize {
        2
    }
    fn variables(&self) -> Vec<VarKey> {
        let mut v = vec![self.x.key()];
        if let Some(y) = self.y {
            v.push(y.key());
        }
        v
    }
    fn evaluate(
        &self,
        values: &Values,
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) -> bool {
        let mut r = self.a * values.get(self.x) - self.rhs;
        if let Some(y) = self.y {
            r += self.b * values.get(y);
        }
        residual.copy_from_slice(r.as_slice());
        if let Some(j) = jacobians {
            j.set(0, &self.a);
            if self.y.is_some() {
                j.set(1, &self.b);
            }
        }
        true
    }
}

/// A random sparse linear least-squares problem (a chain plus random links, with a prior on
/// the first variable) and its exact solution from the dense normal equations.
type LinearProblem = (Problem, Vec<Var<Vector3<f64>>>, DVector<f64>, DMatrix<f64>);

fn linear_problem(seed: u64, n: usize, information: bool) -> LinearProblem {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut p = Problem::new();
    let vars: Vec<_> = (0..n)
        .map(|_| p.add_variable(Vector3::new(rng.random(), rng.random(), rng.random())))
        .collect();
    // Per factor: its (variable, block) pairs, right-hand side and information.
    type Row = (
        Vec<(usize, SMatrix<f64, 2, 3>)>,
        Vector2<f64>,
        SMatrix<f64, 2, 2>,
    );
    let mut rows: Vec<Row> = Vec::new();
    let mut add = |p: &mut Problem, i: usize, j: Option<usize>, rng: &mut ChaCha8Rng| {
        let a = SMatrix::<f64, 2, 3>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let b = SMatrix::<f64, 2, 3>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let rhs = Vector2::new(rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0));
        let info = if information {
            let l = SMatrix::<f64, 2, 2>::new(
                rng.random_range(0.5..2.0),
                0.0,
                rng.random_range(-0.5..0.5),
                rng.random_range(0.5..2.0),
            );
            l * l.transpose()
        } else {
            SMatrix::<f64, 2, 2>::identity()
        };
        p.add_factor(
            Linear2 {
                x: vars[i],
                y: j.map(|j| vars[j]),
                a,
                b,
                rhs,
            },
            Information::Full(DMatrix::from_column_slice(2, 2, info.as_slice())),
            None,
        )
        .unwrap();
        let mut blocks = vec![(i, a)];
        if let Some(j) = j {
            blocks.push((j, b));
        }
        rows.push((blocks, rhs, info));
    };
    for i in 0..n {
        // Two unary rows per variable make the problem well-posed on its own.
        add(&mut p, i, None, &mut rng);
        add(&mut p, i, None, &mut rng);
        if i + 1 < n {
            add(&mut p, i, Some(i + 1), &mut rng);
        }
        if i >= 3 && rng.random_bool(0.5) {
            let j = rng.random_range(0..i - 1);
            add(&mut p, i, Some(j), &mut rng);
        }
    }
    // Dense normal equations: (Σ AᵀΛA) x = Σ AᵀΛ b.
    let dim = 3 * n;
    let mut h = DMatrix::<f64>::zeros(dim, dim);
    let mut rhs = DVector::<f64>::zeros(dim);
    for (blocks, b, info) in &rows {
        let mut a = DMatrix::<f64>::zeros(2, dim);
        for (i, m) in blocks {
            a.view_mut((0, 3 * i), (2, 3)).copy_from(m);
        }
        let info = DMatrix::from_column_slice(2, 2, info.as_slice());
        h += a.transpose() * &info * &a;
        rhs += a.transpose() * &info * DVector::from_column_slice(b.as_slice());
    }
    let solution = h.clone().cholesky().unwrap().solve(&rhs);
    (p, vars, solution, h)
}

fn max_error(p: &Problem, vars: &[Var<Vector3<f64>>], solution: &DVector<f64>) -> f64 {
    vars.iter()
        .enumerate()
        .map(|(i, v)| (p.value(*v) - solution.rows(3 * i, 3)).amax())
        .fold(0.0, f64::max)
}

#[test]
fn every_cholesky_organisation_finds_the_least_squares_solution() {
    for method in [
        CholeskyMethod::Auto,
        CholeskyMethod::Simplicial,
        CholeskyMethod::Supernodal,
    ] {
        let (mut p, vars, solution, _) = linear_problem(3, 40, true);
        let options = SolverOptions {
            algorithm: Algorithm::GaussNewton,
            linear_solver: LinearSolver::SparseCholesky,
            cholesky_method: method,
            max_iterations: 5,
            function_tolerance: 1e-14,
            ..Default::default()
        };
        p.optimise(&options).unwrap();
        let err = max_error(&p, &vars, &solution);
        assert!(err < 1e-9, "{method:?}: error {err:e}");
    }
}

#[test]
fn every_linear_solver_finds_the_least_squares_solution() {
    for solver in [
        LinearSolver::Dense,
        LinearSolver::SparseCholesky,
        LinearSolver::Pcg,
        LinearSolver::Auto,
    ] {
        for algorithm in [Algorithm::GaussNewton, Algorithm::LevenbergMarquardt] {
            let (mut p, vars, solution, _) = linear_problem(3, 40, true);
            let options = SolverOptions {
                algorithm,
                linear_solver: solver,
                pcg_tolerance: 1e-12,
                max_iterations: 50,
                // Exactness is the point here; the default stops at a 1e-6 relative decrease.
                function_tolerance: 1e-14,
                ..Default::default()
            };
            let summary = p.optimise(&options).unwrap();
            let err = max_error(&p, &vars, &solution);
            assert!(
                err < 1e-7,
                "{solver:?}/{algorithm:?}: error {err:e} ({:?})",
                summary.termination
            );
            assert!(summary.final_cost <= summary.initial_cost);
            // Gauss-Newton solves a linear problem in one step.
            if algorithm == Algorithm::GaussNewton && solver != LinearSolver::Pcg {
                assert!(
                    summary.iterations.len() <= 2,
                    "{solver:?}: {} iterations",
                    summary.iterations.len()
                );
            }
        }
    }
}

#[test]
fn schur_solvers_agree_with_the_full_system() {
    // Elimination needs a block-diagonal kind: use Vector3 "points" seen only by Vector6
    // "cameras" through linear residuals, like bundle adjustment.
    struct Obs {
        cam: Var<Vector6<f64>>,
        pt: Var<Vector3<f64>>,
        a: SMatrix<f64, 2, 6>,
        b: SMatrix<f64, 2, 3>,
        z: Vector2<f64>,
    }
    impl Factor for Obs {
        fn residual_dim(&self) -> usize {
            2
        }
        fn variables(&self) -> Vec<VarKey> {
            vec![self.cam.key(), self.pt.key()]
        }
        fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
            let res = self.a * v.get(self.cam) + self.b * v.get(self.pt) - self.z;
            r.copy_from_slice(res.as_slice());
            if let Some(j) = j {
                j.set(0, &self.a);
                j.set(1, &self.b);
            }
            true
        }
    }
    let build = |rng: &mut ChaCha8Rng| {
        let mut p = Problem::new();
        let cams: Vec<_> = (0..6).map(|_| p.add_variable(Vector6::zeros())).collect();
        let pts: Vec<_> = (0..40).map(|_| p.add_variable(Vector3::zeros())).collect();
        for (k, pt) in pts.iter().enumerate() {
            for (c, cam) in cams.iter().enumerate() {
                if (k + c) % 3 != 0 {
                    p.add_factor(
                        Obs {
                            cam: *cam,
                            pt: *pt,
                            a: SMatrix::from_fn(|_, _| rng.random_range(-1.0..1.0)),
                            b: SMatrix::from_fn(|_, _| rng.random_range(-1.0..1.0)),
                            z: Vector2::new(
                                rng.random_range(-1.0..1.0),
                                rng.random_range(-1.0..1.0),
                            ),
                        },
                        Information::Identity,
                        None,
                    )
                    .unwrap();
                }
            }
        }
        (p, cams, pts)
    };
    let mut results = Vec::new();
    for solver in [
        LinearSolver::SparseCholesky,
        LinearSolver::SchurCholesky,
        LinearSolver::SchurPcg,
    ] {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (mut p, cams, pts) = build(&mut rng);
        if solver != LinearSolver::SparseCholesky {
            p.set_eliminated::<Vector3<f64>>(true);
        }
        let options = SolverOptions {
            algorithm: Algorithm::GaussNewton,
            linear_solver: solver,
            pcg_tolerance: 1e-13,
            pcg_max_iterations: 1000,
            ..Default::default()
        };
        let summary = p.optimise(&options).unwrap();
        let x: Vec<f64> = cams
            .iter()
            .flat_map(|c| p.value(*c).iter().copied().collect::<Vec<_>>())
            .chain(
                pts.iter()
                    .flat_map(|q| p.value(*q).iter().copied().collect::<Vec<_>>()),
            )
            .collect();
        results.push((solver, summary.final_cost, x));
    }
    let (_, cost0, x0) = &results[0];
    for (solver, cost, x) in &results[1..] {
        let err = x
            .iter()
            .zip(x0)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-7, "{solver:?} differs by {err:e}");
        assert!((cost - cost0).abs() < 1e-9 * (1.0 + cost0));
    }
}

#[test]
fn elimination_of_a_kind_that_is_not_block_diagonal_is_refused() {
    let (mut p, _, _, _) = linear_problem(1, 5, false);
    p.set_eliminated::<Vector3<f64>>(true);
    let err = p.optimise(&SolverOptions::default()).unwrap_err();
    assert!(err.to_string().contains("cannot be eliminated"), "{err}");
}

#[test]
fn covariance_is_the_inverse_of_the_information_for_a_linear_problem() {
    let (mut p, vars, _, h) = linear_problem(5, 6, true);
    // Exact answer: the inverse of H = Σ AᵀΛA (a linear problem's H does not depend on x).
    p.optimise(&SolverOptions::default()).unwrap();
    let keys: Vec<VarKey> = vars.iter().map(|v| v.key()).collect();
    let cov = p.covariance(&keys).unwrap();
    let expected = h.try_inverse().unwrap();
    assert!(
        (&cov - &expected).amax() < 1e-10 * expected.amax(),
        "{:e}",
        (&cov - &expected).amax()
    );
    // A marginal is the sub-block of the joint, in the order asked for.
    let cov_sub = p.covariance(&[keys[3], keys[2]]).unwrap();
    assert!(
        (cov_sub.view((3, 3), (3, 3)) - expected.view((6, 6), (3, 3))).amax()
            < 1e-10 * expected.amax()
    );
    assert!(
        (cov_sub.view((0, 3), (3, 3)) - expected.view((9, 6), (3, 3))).amax()
            < 1e-10 * expected.amax()
    );
}

#[test]
fn covariance_matches_monte_carlo_of_a_linear_gaussian_problem() {
    // x ∈ R³ observed directly three times with known covariances: Σ_x = (Σ Λᵢ)⁻¹.
    struct Direct {
        x: Var<Vector3<f64>>,
        z: Vector3<f64>,
    }
    impl Factor for Direct {
        fn residual_dim(&self) -> usize {
            3
        }
        fn variables(&self) -> Vec<VarKey> {
            vec![self.x.key()]
        }
        fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
            r.copy_from_slice((v.get(self.x) - self.z).as_slice());
            if let Some(j) = j {
                j.set(0, &SMatrix::<f64, 3, 3>::identity());
            }
            true
        }
    }
    let lambdas = [
        DMatrix::from_row_slice(3, 3, &[4.0, 1.0, 0.0, 1.0, 3.0, 0.5, 0.0, 0.5, 2.0]),
        DMatrix::from_row_slice(3, 3, &[1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 5.0]),
        DMatrix::from_row_slice(3, 3, &[2.0, -0.5, 0.2, -0.5, 1.0, 0.0, 0.2, 0.0, 1.0]),
    ];
    let mut p = Problem::new();
    let x = p.add_variable(Vector3::new(0.3, 0.1, -0.2));
    for l in &lambdas {
        p.add_factor(
            Direct {
                x,
                z: Vector3::new(1.0, 2.0, 3.0),
            },
            Information::Full(l.clone()),
            None,
        )
        .unwrap();
    }
    p.optimise(&SolverOptions::default()).unwrap();
    let cov = p.covariance(&[x.key()]).unwrap();
    let expected = (&lambdas[0] + &lambdas[1] + &lambdas[2])
        .try_inverse()
        .unwrap();
    assert!((cov - expected).amax() < 1e-12);
}

/// A unary SE(3) prior `r = log(T·Z⁻¹)`.
struct Prior {
    x: Var<Se3>,
    z_inv: Se3,
}

impl Factor for Prior {
    fn residual_dim(&self) -> usize {
        6
    }
    fn variables(&self) -> Vec<VarKey> {
        vec![self.x.key()]
    }
    fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
        let d = v.get(self.x).compose(&self.z_inv).log();
        r.copy_from_slice(d.as_slice());
        if let Some(j) = j {
            // ∂ log(exp(ε)·T·Z⁻¹)/∂ε = J_l(d)⁻¹.
            j.set(0, &Se3::left_jacobian_inverse(&d));
        }
        true
    }
}

#[test]
fn manifold_prior_converges_to_its_measurement_from_far_away() {
    let z = Se3::exp(&Vector6::new(1.0, -2.0, 0.5, 0.3, -1.2, 2.0));
    for solver in [
        LinearSolver::Dense,
        LinearSolver::SparseCholesky,
        LinearSolver::Pcg,
    ] {
        let mut p = Problem::new();
        let x = p.add_variable(Se3::exp(&Vector6::new(-3.0, 1.0, 2.0, 1.5, 0.4, -0.3)));
        p.add_factor(
            Prior {
                x,
                z_inv: z.inverse(),
            },
            Information::Identity,
            None,
        )
        .unwrap();
        let summary = p
            .optimise(&SolverOptions {
                linear_solver: solver,
                function_tolerance: 1e-15,
                ..Default::default()
            })
            .unwrap();
        let err = p.value(x).compose(&z.inverse()).log().amax();
        assert!(err < 1e-9, "{solver:?}: {err:e}, {:?}", summary.termination);
        assert!(summary.final_cost < 1e-18);
    }
}

#[test]
fn jacobian_checker_accepts_correct_and_rejects_wrong_jacobians() {
    let mut values = Values::new();
    let x = values.add(Se3::exp(&Vector6::new(0.1, 0.2, 0.3, 0.4, 0.5, 0.6)));
    let z = Se3::exp(&Vector6::new(-0.3, 0.1, 0.2, 0.0, 0.7, -0.2));
    let good = Prior {
        x,
        z_inv: z.inverse(),
    };
    assert!(check_jacobians(&good, &values, 1e-4).unwrap().passes(1e-8));
    struct Wrong(Prior);
    impl Factor for Wrong {
        fn residual_dim(&self) -> usize {
            6
        }
        fn variables(&self) -> Vec<VarKey> {
            self.0.variables()
        }
        fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
            let d = v.get(self.0.x).compose(&self.0.z_inv).log();
            r.copy_from_slice(d.as_slice());
            if let Some(j) = j {
                // First-order approximation: identity. Wrong away from d = 0.
                j.set(0, &SMatrix::<f64, 6, 6>::identity());
            }
            true
        }
    }
    let check = check_jacobians(
        &Wrong(Prior {
            x,
            z_inv: z.inverse(),
        }),
        &values,
        1e-4,
    )
    .unwrap();
    assert!(!check.passes(1e-6), "a wrong Jacobian passed: {check:?}");
}

/// `r = y − (a·t + b)`, a line fit with scalar parameters as a 2-vector.
struct LinePoint {
    ab: Var<Vector2<f64>>,
    t: f64,
    y: f64,
}

impl Factor for LinePoint {
    fn residual_dim(&self) -> usize {
        1
    }
    fn variables(&self) -> Vec<VarKey> {
        vec![self.ab.key()]
    }
    fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
        let ab = v.get(self.ab);
        r[0] = ab.x * self.t + ab.y - self.y;
        if let Some(j) = j {
            j.set(0, &SMatrix::<f64, 1, 2>::new(self.t, 1.0));
        }
        true
    }
}

#[test]
fn robust_kernels_resist_outliers() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (a, b) = (2.0, -1.0);
    let data: Vec<(f64, f64)> = (0..200)
        .map(|i| {
            let t = i as f64 * 0.05;
            let outlier = i % 5 == 0;
            let noise = if outlier {
                rng.random_range(20.0..60.0)
            } else {
                rng.random_range(-0.1..0.1)
            };
            (t, a * t + b + noise)
        })
        .collect();
    let fit = |kernel: Option<RobustKernel>, start: Option<Vector2<f64>>| {
        let mut p = Problem::new();
        let ab = p.add_variable(Vector2::new(0.0, 0.0));
        for &(t, y) in &data {
            p.add_factor(LinePoint { ab, t, y }, Information::Isotropic(0.1), kernel)
                .unwrap();
        }
        // Start robust fits from the least-squares fit, as one would in practice.
        let mut q = Problem::new();
        let ab0 = q.add_variable(Vector2::new(0.0, 0.0));
        for &(t, y) in &data {
            q.add_factor(
                LinePoint { ab: ab0, t, y },
                Information::Isotropic(0.1),
                None,
            )
            .unwrap();
        }
        q.optimise(&SolverOptions::default()).unwrap();
        p.values_mut().set(ab, start.unwrap_or(*q.value(ab0)));
        p.optimise(&SolverOptions {
            max_iterations: 200,
            ..Default::default()
        })
        .unwrap();
        *p.value(ab)
    };
    let plain = fit(None, None);
    assert!(
        (plain.x - a).abs() > 0.2 || (plain.y - b).abs() > 5.0,
        "outliers should bias least squares: {plain:?}"
    );
    let huber = fit(Some(RobustKernel::Huber(1.0)), None);
    let cauchy = fit(Some(RobustKernel::Cauchy(1.0)), None);
    // Tukey's kernel redescends: started from the biased least-squares fit, every inlier is
    // beyond its support and gets zero weight. As in practice, start it from the Huber fit.
    let tukey = fit(Some(RobustKernel::Tukey(4.0)), Some(huber));
    for (name, robust) in [("Huber", huber), ("Cauchy", cauchy), ("Tukey", tukey)] {
        assert!(
            (robust.x - a).abs() < 0.05 && (robust.y - b).abs() < 0.5,
            "{name}: {robust:?}"
        );
    }
}

#[test]
fn gauge_freedom_is_handled_by_fixing_or_by_damping() {
    // Relative SE(3) constraints only: the absolute pose is unobservable.
    struct Between {
        a: Var<Se3>,
        b: Var<Se3>,
        z: Se3,
    }
    impl Factor for Between {
        fn residual_dim(&self) -> usize {
            6
        }
        fn variables(&self) -> Vec<VarKey> {
            vec![self.a.key(), self.b.key()]
        }
        fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
            // d = log(Z·A·B⁻¹)
            let (ta, tb) = (v.get(self.a), v.get(self.b));
            let d = self.z.compose(ta).compose(&tb.inverse()).log();
            r.copy_from_slice(d.as_slice());
            if let Some(j) = j {
                let jl_inv = Se3::left_jacobian_inverse(&d);
                j.set(0, &(jl_inv * self.z.adjoint()));
                j.set(1, &(-Se3::left_jacobian_inverse(&(-d))));
            }
            true
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let truth: Vec<Se3> = (0..10)
        .map(|_| Se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-1.0..1.0))))
        .collect();
    let build = |fix: bool, rng: &mut ChaCha8Rng| {
        let mut p = Problem::new();
        let vars: Vec<_> = truth
            .iter()
            .map(|t| {
                p.add_variable(
                    Se3::exp(&Vector6::from_fn(|_, _| rng.random_range(-0.1..0.1))).compose(t),
                )
            })
            .collect();
        for i in 0..10 {
            for k in [1, 3] {
                let j = (i + k) % 10;
                let z = truth[j].compose(&truth[i].inverse());
                p.add_factor(
                    Between {
                        a: vars[i],
                        b: vars[j],
                        z,
                    },
                    Information::Identity,
                    None,
                )
                .unwrap();
            }
        }
        if fix {
            p.set_fixed(vars[0].key(), true);
            p.values_mut().set(vars[0], truth[0]);
        }
        (p, vars)
    };
    // Fixed first pose: the truth is recovered exactly.
    let (mut p, vars) = build(true, &mut rng);
    let s = p.optimise(&SolverOptions::default()).unwrap();
    assert!(s.final_cost < 1e-20, "{}", s.final_cost);
    for (v, t) in vars.iter().zip(&truth) {
        assert!(p.value(*v).compose(&t.inverse()).log().amax() < 1e-9);
    }
    // Nothing fixed: LM damping alone handles the gauge; relative poses are recovered.
    let (mut p, vars) = build(false, &mut rng);
    let s = p.optimise(&SolverOptions::default()).unwrap();
    assert!(s.final_cost < 1e-18, "{}", s.final_cost);
    let rel = |a: &Se3, b: &Se3| b.compose(&a.inverse());
    for i in 1..10 {
        let est = rel(p.value(vars[0]), p.value(vars[i]));
        let tru = rel(&truth[0], &truth[i]);
        assert!(est.compose(&tru.inverse()).log().amax() < 1e-8);
    }
    // Gauss-Newton without a fixed gauge faces a singular system and says so.
    let (mut p, _) = build(false, &mut rng);
    let r = p.optimise(&SolverOptions {
        algorithm: Algorithm::GaussNewton,
        linear_solver: LinearSolver::SparseCholesky,
        ..Default::default()
    });
    assert!(
        r.is_err(),
        "GN on a gauge-free problem must fail loudly: {r:?}"
    );
}

#[test]
fn invalid_input_is_refused_with_a_reason() {
    let mut p = Problem::new();
    let x = p.add_variable(Vector3::new(0.0, 0.0, 0.0));
    let mut other = Values::new();
    let foreign: Var<Vector3<f64>> = {
        other.add(Vector3::zeros());
        other.add(Vector3::zeros())
    };
    let f = |y: Var<Vector3<f64>>| Linear2 {
        x,
        y: Some(y),
        a: SMatrix::identity(),
        b: SMatrix::identity(),
        rhs: Vector2::zeros(),
    };
    assert!(matches!(
        p.add_factor(f(foreign), Information::Identity, None),
        Err(ProblemError::UnknownVariable(_))
    ));
    assert!(matches!(
        p.add_factor(f(x), Information::Identity, None),
        Err(ProblemError::DuplicateVariable(_))
    ));
    let unary = || Linear2 {
        x,
        y: None,
        a: SMatrix::identity(),
        b: SMatrix::identity(),
        rhs: Vector2::zeros(),
    };
    assert!(matches!(
        p.add_factor(unary(), Information::Diagonal(vec![1.0, -1.0]), None),
        Err(ProblemError::Information(_))
    ));
    assert!(matches!(
        p.add_factor(unary(), Information::Diagonal(vec![1.0]), None),
        Err(ProblemError::Information(_))
    ));
    assert!(matches!(
        p.add_factor(
            unary(),
            Information::Full(DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0])),
            None
        ),
        Err(ProblemError::Information(_))
    ));
    assert!(matches!(
        p.add_factor(
            unary(),
            Information::Identity,
            Some(RobustKernel::Huber(-1.0))
        ),
        Err(ProblemError::InvalidKernel(_))
    ));
    assert!(
        p.add_factor(
            unary(),
            Information::Isotropic(0.5),
            Some(RobustKernel::Huber(1.0))
        )
        .is_ok()
    );
}

#[test]
fn undefined_residuals_are_rejected_observations_not_nans() {
    // r = 1/x − 2 is undefined at x ≤ 0; the factor says so, and the optimiser never steps
    // into a region where more factors are undefined.
    struct Inverse {
        x: Var<nalgebra::Vector1<f64>>,
    }
    impl Factor for Inverse {
        fn residual_dim(&self) -> usize {
            1
        }
        fn variables(&self) -> Vec<VarKey> {
            vec![self.x.key()]
        }
        fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
            let x = v.get(self.x)[0];
            if x <= 0.0 {
                return false;
            }
            r[0] = 1.0 / x - 2.0;
            if let Some(j) = j {
                j.block_mut(0)[0] = -1.0 / (x * x);
            }
            true
        }
    }
    let mut p = Problem::new();
    let x = p.add_variable(nalgebra::Vector1::new(3.0));
    p.add_factor(Inverse { x }, Information::Identity, None)
        .unwrap();
    let s = p.optimise(&SolverOptions::default()).unwrap();
    assert!(
        (p.value(x)[0] - 0.5).abs() < 1e-6,
        "{:?} {:?}",
        p.value(x),
        s.termination
    );
    assert_eq!(s.invalid_factors, 0);
    let mut q = Problem::new();
    let y = q.add_variable(nalgebra::Vector1::new(-1.0));
    q.add_factor(Inverse { x: y }, Information::Identity, None)
        .unwrap();
    let s = q.optimise(&SolverOptions::default()).unwrap();
    assert_eq!(s.invalid_factors, 1);
    assert!(q.value(y)[0].is_finite() && s.final_cost.is_finite());
}

#[test]
fn iteration_and_time_budgets_stop_the_solver() {
    let (mut p, _, _, _) = linear_problem(8, 30, true);
    let s = p
        .optimise(&SolverOptions {
            max_iterations: 1,
            initial_lambda: 1e3,
            ..Default::default()
        })
        .unwrap();
    assert_eq!(s.iterations.len(), 1);
    assert_eq!(s.termination, Termination::MaxIterations);
    let (mut p, _, _, _) = linear_problem(8, 30, true);
    let s = p
        .optimise(&SolverOptions {
            max_time: Some(std::time::Duration::ZERO),
            ..Default::default()
        })
        .unwrap();
    assert_eq!(s.termination, Termination::TimeBudget);
    assert!(s.iterations.is_empty());
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let mut costs = Vec::new();
    for threads in [1, 2, 4] {
        let (mut p, vars, _, _) = linear_problem(21, 60, true);
        let s = p
            .optimise(&SolverOptions {
                threads: Some(threads),
                ..Default::default()
            })
            .unwrap();
        costs.push((s.final_cost, *p.value(vars[7])));
    }
    assert_eq!(costs[0], costs[1]);
    assert_eq!(costs[0], costs[2]);
}

#[test]
fn rotation_averaging_on_so3() {
    // Unary SO(3) measurements of one rotation: the optimum is their Karcher mean, which for
    // symmetric perturbations ±δ about R is R itself.
    struct RotPrior {
        x: Var<So3>,
        z_inv: So3,
    }
    impl Factor for RotPrior {
        fn residual_dim(&self) -> usize {
            3
        }
        fn variables(&self) -> Vec<VarKey> {
            vec![self.x.key()]
        }
        fn evaluate(&self, v: &Values, r: &mut [f64], j: Option<&mut Jacobians<'_>>) -> bool {
            let d = v.get(self.x).compose(&self.z_inv).log();
            r.copy_from_slice(d.as_slice());
            if let Some(j) = j {
                j.set(0, &So3::left_jacobian_inverse(&d));
            }
            true
        }
    }
    let truth = So3::exp(&Vector3::new(0.4, -1.0, 2.0));
    let mut p = Problem::new();
    let x = p.add_variable(So3::identity());
    for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
        for sign in [1.0, -1.0] {
            let z = So3::exp(&(axis * 0.3 * sign)).compose(&truth);
            p.add_factor(
                RotPrior {
                    x,
                    z_inv: z.inverse(),
                },
                Information::Identity,
                None,
            )
            .unwrap();
        }
    }
    p.optimise(&SolverOptions {
        function_tolerance: 1e-14,
        ..Default::default()
    })
    .unwrap();
    assert!(p.value(x).compose(&truth.inverse()).log().amax() < 1e-9);
}
