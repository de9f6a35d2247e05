//! Property tests for every group: axioms, exp/log round trips (including near-singular
//! tangents), adjoint identities, the matrix-exponential series, and every analytic Jacobian
//! against numeric differentiation through the optimiser's left update.

use lie::numeric::{jacobian_left, jacobian_vector};
use lie::{LieGroup, LogJacobian, Se2, Se3, Sim3, So2, So3};
use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector2, Vector3};
use proptest::prelude::*;
use std::f64::consts::PI;

/// What the generic checks need to know about a group beyond [`LieGroup`].
trait Harness<const D: usize>: LieGroup<D> {
    /// Indices of the rotation part of a tangent vector.
    const ROTATION: &'static [usize];
    /// Index of the log-scale σ, if any.
    const SCALE: Option<usize>;
    fn mat(m: &Self::Matrix) -> DMatrix<f64>;
    fn point(p: &[f64]) -> Self::Point;
    fn point_vec(p: &Self::Point) -> DVector<f64>;
    fn point_jac(j: &Self::PointJacobian) -> DMatrix<f64>;
    fn point_mat(m: &Self::PointMatrix) -> DMatrix<f64>;
}

macro_rules! harness {
    ($g:ty, $d:literal, $rot:expr, $scale:expr, $p:literal, $pt:ty) => {
        impl Harness<$d> for $g {
            const ROTATION: &'static [usize] = $rot;
            const SCALE: Option<usize> = $scale;
            fn mat(m: &Self::Matrix) -> DMatrix<f64> {
                DMatrix::from_column_slice(m.nrows(), m.ncols(), m.as_slice())
            }
            fn point(p: &[f64]) -> Self::Point {
                <$pt>::from_column_slice(&p[..$p])
            }
            fn point_vec(p: &Self::Point) -> DVector<f64> {
                DVector::from_column_slice(p.as_slice())
            }
            fn point_jac(j: &Self::PointJacobian) -> DMatrix<f64> {
                DMatrix::from_column_slice(j.nrows(), j.ncols(), j.as_slice())
            }
            fn point_mat(m: &Self::PointMatrix) -> DMatrix<f64> {
                DMatrix::from_column_slice(m.nrows(), m.ncols(), m.as_slice())
            }
        }
    };
}

harness!(So2, 1, &[0], None, 2, Vector2<f64>);
harness!(Se2, 3, &[2], None, 2, Vector2<f64>);
harness!(So3, 3, &[0, 1, 2], None, 3, Vector3<f64>);
harness!(Se3, 6, &[3, 4, 5], None, 3, Vector3<f64>);
harness!(Sim3, 7, &[3, 4, 5], Some(6), 3, Vector3<f64>);

/// `exp(X) = Σ Xᵏ/k!` by scaling and squaring with a 30-term Taylor series: the reference
/// for the closed forms.
fn expm_series(x: &DMatrix<f64>) -> DMatrix<f64> {
    let n = x.nrows();
    let norm = x.norm();
    let squarings = if norm > 0.25 {
        (norm / 0.25).log2().ceil() as i32
    } else {
        0
    };
    let scaled = x / 2f64.powi(squarings);
    let mut sum = DMatrix::identity(n, n);
    let mut term = DMatrix::identity(n, n);
    for k in 1..30 {
        term = &term * &scaled / k as f64;
        sum += &term;
    }
    for _ in 0..squarings {
        sum = &sum * &sum;
    }
    sum
}

fn max_abs(m: &DMatrix<f64>) -> f64 {
    m.iter().fold(0.0, |a, &b| a.max(b.abs()))
}

fn close_groups<G: Harness<D>, const D: usize>(a: &G, b: &G, tol: f64) -> bool {
    let (ma, mb) = (G::mat(&a.matrix()), G::mat(&b.matrix()));
    max_abs(&(&ma - &mb)) <= tol * (1.0 + max_abs(&ma))
}

/// A tangent vector from uniform components, with the rotation rescaled to one of the
/// near-singular angles (0, tiny, π − tiny, π) or left as is, and the same for σ.
fn shaped_tangent<G: Harness<D>, const D: usize>(
    raw: &[f64],
    rot_case: u8,
    scale_case: u8,
) -> SVector<f64, D> {
    let mut x = SVector::<f64, D>::from_column_slice(&raw[..D]);
    let rot_norm: f64 = G::ROTATION.iter().map(|&i| x[i] * x[i]).sum::<f64>().sqrt();
    let target = match rot_case {
        0 => Some(0.0),
        1 => Some(1e-12),
        2 => Some(1e-7),
        3 => Some(1e-3),
        4 => Some(PI - 1e-9),
        5 => Some(PI - 1e-4),
        _ => None,
    };
    if let Some(t) = target {
        let factor = if rot_norm > 0.0 { t / rot_norm } else { 0.0 };
        for &i in G::ROTATION {
            x[i] = if rot_norm > 0.0 { x[i] * factor } else { 0.0 };
        }
    }
    if let Some(s) = G::SCALE {
        x[s] = match scale_case {
            0 => 0.0,
            1 => 1e-12 * x[s].signum(),
            2 => 1e-7 * x[s].signum(),
            3 => 1e-3 * x[s].signum(),
            _ => x[s],
        };
    }
    x
}

/// The rotation shapes of [`shaped_tangent`] except those next to θ = π.
fn away_from_pi() -> impl Strategy<Value = u8> {
    proptest::sample::select(vec![0u8, 1, 2, 3, 6, 7])
}

fn raw() -> impl Strategy<Value = Vec<f64>> {
    proptest::collection::vec(-2.0f64..2.0, 7)
}

fn check_axioms<G: Harness<D>, const D: usize>(a: &G, b: &G, c: &G) {
    let tol = 1e-10;
    assert!(
        close_groups(&a.compose(&b.compose(c)), &a.compose(b).compose(c), tol),
        "associativity"
    );
    assert!(
        close_groups(&a.compose(&G::identity()), a, tol),
        "right identity"
    );
    assert!(
        close_groups(&G::identity().compose(a), a, tol),
        "left identity"
    );
    assert!(
        close_groups(&a.compose(&a.inverse()), &G::identity(), tol),
        "right inverse"
    );
    assert!(
        close_groups(&a.inverse().compose(a), &G::identity(), tol),
        "left inverse"
    );
    // The composition is the matrix product, the inverse the matrix inverse.
    let prod = G::mat(&a.matrix()) * G::mat(&b.matrix());
    assert!(
        max_abs(&(prod.clone() - G::mat(&a.compose(b).matrix()))) < 1e-10 * (1.0 + max_abs(&prod))
    );
    let inv = G::mat(&a.matrix()).try_inverse().unwrap();
    assert!(
        max_abs(&(inv.clone() - G::mat(&a.inverse().matrix()))) < 1e-10 * (1.0 + max_abs(&inv))
    );
}

fn check_exp_log<G: Harness<D>, const D: usize>(x: &SVector<f64, D>) {
    let g = G::exp(x);
    assert!(g.is_finite());
    // exp against the matrix-exponential series of x̂.
    let reference = expm_series(&G::mat(&G::hat(x)));
    let err = max_abs(&(&reference - G::mat(&g.matrix())));
    assert!(
        err < 1e-12 * (1.0 + max_abs(&reference)),
        "exp vs series: {err:e} at {x:?}"
    );
    // log ∘ exp = id on the principal domain (rotation angle < π).
    let rot_norm: f64 = G::ROTATION.iter().map(|&i| x[i] * x[i]).sum::<f64>().sqrt();
    let y = g.log();
    let y_rot: f64 = G::ROTATION.iter().map(|&i| y[i] * y[i]).sum::<f64>().sqrt();
    assert!(y_rot <= PI + 1e-12, "log angle {y_rot} outside [0, π]");
    if rot_norm < PI - 1e-6 {
        let e = (y - x).amax();
        assert!(
            e < 1e-12 * (1.0 + x.amax() * x.amax()),
            "log(exp(x)) − x = {e:e} at {x:?}"
        );
    }
    // exp ∘ log = id everywhere, including θ = π.
    assert!(
        close_groups(&G::exp(&y), &g, 1e-12),
        "exp(log(g)) ≠ g at {x:?}"
    );
}

fn check_hat_vee_bracket_adjoint<G: Harness<D>, const D: usize>(
    a: &SVector<f64, D>,
    b: &SVector<f64, D>,
    g: &G,
) {
    let ha = G::mat(&G::hat(a));
    let hb = G::mat(&G::hat(b));
    assert!((G::vee(&G::hat(a)) - a).amax() < 1e-15 * (1.0 + a.amax()));
    let commutator = &ha * &hb - &hb * &ha;
    let bracket = G::lie_bracket(a, b);
    assert!(
        max_abs(&(G::mat(&G::hat(&bracket)) - &commutator)) < 1e-12 * (1.0 + max_abs(&commutator))
    );
    // ∂[y, b]/∂y against numeric differentiation.
    let analytic = G::d_lie_bracket(b);
    let numeric = jacobian_vector(a, |y| G::lie_bracket(y, b));
    assert!(
        (analytic - numeric).amax() < 1e-9 * (1.0 + b.amax()),
        "d_lie_bracket"
    );
    // (Ad_g·a)^ = g·â·g⁻¹ (thesis eq. 2.77) and exp(Ad_g·a) = g·exp(a)·g⁻¹ (eq. 2.78).
    let gm = G::mat(&g.matrix());
    let conj = &gm * &ha * gm.clone().try_inverse().unwrap();
    let ad_a = g.adjoint() * a;
    assert!(
        max_abs(&(G::mat(&G::hat(&ad_a)) - &conj)) < 1e-10 * (1.0 + max_abs(&conj)),
        "adjoint"
    );
    assert!(
        close_groups(
            &G::exp(&ad_a),
            &g.compose(&G::exp(a)).compose(&g.inverse()),
            1e-10
        ),
        "exp(Ad·x)"
    );
}

fn check_action<G: Harness<D>, const D: usize>(g: &G, p_raw: &[f64]) {
    let p = G::point(p_raw);
    let pv = G::point_vec(&p);
    let n = pv.len();
    // The action equals the homogeneous matrix product (or plain product for SO(n)).
    let m = G::mat(&g.matrix());
    let acted = G::point_vec(&g.act(&p));
    let expected = if m.nrows() == n {
        &m * &pv
    } else {
        let mut h = DVector::from_element(n + 1, 1.0);
        h.rows_mut(0, n).copy_from(&pv);
        (&m * h).rows(0, n).into_owned()
    };
    assert!((&acted - &expected).amax() < 1e-10 * (1.0 + expected.amax()));
    // ∂(g·p)/∂p and ∂(exp(ε)·g·p)/∂ε against numeric differentiation.
    let f_point = |q: &SVector<f64, 3>| {
        let out = G::point_vec(&g.act(&G::point(q.as_slice())));
        let mut v = SVector::<f64, 3>::zeros();
        v.rows_mut(0, n).copy_from(&out);
        v
    };
    let mut p3 = SVector::<f64, 3>::zeros();
    p3.rows_mut(0, n).copy_from(&pv);
    let num_point = jacobian_vector(&p3, f_point);
    let ana_point = G::point_mat(&g.d_act_d_point());
    assert!(
        (num_point.view((0, 0), (n, n)) - &ana_point).amax() < 1e-8 * (1.0 + ana_point.amax()),
        "d_act_d_point"
    );
    let f_group = |h: &G| {
        let out = G::point_vec(&h.act(&p));
        let mut v = SVector::<f64, 3>::zeros();
        v.rows_mut(0, n).copy_from(&out);
        v
    };
    let num_left = jacobian_left(g, f_group);
    let ana_left = G::point_jac(&g.d_act_d_left(&p));
    assert!(
        (num_left.view((0, 0), (n, D)) - &ana_left).amax() < 1e-8 * (1.0 + ana_left.amax()),
        "d_act_d_left"
    );
}

fn check_left_jacobians<G: Harness<D>, const D: usize>(x: &SVector<f64, D>) {
    let jl = G::left_jacobian(x);
    let jl_inv = G::left_jacobian_inverse(x);
    assert!(
        (jl * jl_inv - SMatrix::<f64, D, D>::identity()).amax() < 1e-9,
        "J·J⁻¹ ≠ I"
    );
    // J_l(x) = ∂ log(exp(x + δ)·exp(x)⁻¹)/∂δ and J_l(x)⁻¹ = ∂ log(exp(δ)·exp(x))/∂δ at δ = 0.
    let ex_inv = G::exp(x).inverse();
    let num = jacobian_vector(&SVector::<f64, D>::zeros(), |d| {
        G::exp(&(x + d)).compose(&ex_inv).log()
    });
    assert!(
        (num - jl).amax() < 1e-8 * (1.0 + jl.amax()),
        "left Jacobian: {:e}",
        (num - jl).amax()
    );
    let ex = G::exp(x);
    let num_inv = jacobian_vector(&SVector::<f64, D>::zeros(), |d| {
        G::exp(d).compose(&ex).log()
    });
    assert!(
        (num_inv - jl_inv).amax() < 1e-8 * (1.0 + jl_inv.amax()),
        "inverse left Jacobian"
    );
}

fn check_log_jacobians<G: Harness<D>, const D: usize>(a: &G, b: &G) {
    let numeric = lie::numeric::d_log_left(a, b);
    let exact = G::d_log_left(a, b, LogJacobian::Exact);
    let scale = 1.0 + numeric.amax();
    assert!(
        (exact - numeric).amax() < 1e-8 * scale,
        "exact log Jacobian: {:e}",
        (exact - numeric).amax()
    );
}

fn check_from_matrix<G: Harness<D>, const D: usize>(g: &G) {
    let back = G::from_matrix(&g.matrix()).expect("a group element's matrix is valid");
    assert!(close_groups(&back, g, 1e-12));
}

macro_rules! group_properties {
    ($name:ident, $g:ty, $d:literal) => {
        mod $name {
            use super::*;
            proptest! {
                #![proptest_config(ProptestConfig::with_cases(256))]

                #[test]
                fn axioms(x in raw(), y in raw(), z in raw(), c in 0u8..8, s in 0u8..6) {
                    let a = <$g>::exp(&shaped_tangent::<$g, $d>(&x, c, s));
                    let b = <$g>::exp(&shaped_tangent::<$g, $d>(&y, 7, 7));
                    let cc = <$g>::exp(&shaped_tangent::<$g, $d>(&z, c, s));
                    check_axioms(&a, &b, &cc);
                }

                #[test]
                fn exp_log_round_trip(x in raw(), c in 0u8..8, s in 0u8..6) {
                    check_exp_log::<$g, $d>(&shaped_tangent::<$g, $d>(&x, c, s));
                }

                #[test]
                fn hat_vee_bracket_adjoint(x in raw(), y in raw(), z in raw(), c in 0u8..8) {
                    let a = shaped_tangent::<$g, $d>(&x, c, 7);
                    let b = shaped_tangent::<$g, $d>(&y, 7, 7);
                    let g = <$g>::exp(&shaped_tangent::<$g, $d>(&z, 7, 7));
                    check_hat_vee_bracket_adjoint::<$g, $d>(&a, &b, &g);
                }

                #[test]
                fn action_and_its_jacobians(x in raw(), p in raw(), c in 0u8..8, s in 0u8..6) {
                    check_action::<$g, $d>(&<$g>::exp(&shaped_tangent::<$g, $d>(&x, c, s)), &p);
                }

                #[test]
                fn left_jacobians(x in raw(), c in away_from_pi(), s in 0u8..6) {
                    let t = shaped_tangent::<$g, $d>(&x, c, s);
                    // Away from θ = π, where J_l⁻¹ has a pole at 2π only, but numeric
                    // differentiation of log across the cut at π is meaningless.
                    let rot: f64 = <$g as Harness<$d>>::ROTATION.iter().map(|&i| t[i] * t[i]).sum::<f64>().sqrt();
                    prop_assume!(rot < PI - 1e-2);
                    check_left_jacobians::<$g, $d>(&t);
                }

                #[test]
                fn exact_log_jacobian(x in raw(), y in raw(), c in away_from_pi(), s in 0u8..6) {
                    let a = <$g>::exp(&shaped_tangent::<$g, $d>(&x, 7, 7));
                    let b = <$g>::exp(&shaped_tangent::<$g, $d>(&y, c, s));
                    let d = a.compose(&b).log();
                    let rot: f64 = <$g as Harness<$d>>::ROTATION.iter().map(|&i| d[i] * d[i]).sum::<f64>().sqrt();
                    prop_assume!(rot < PI - 1e-2);
                    check_log_jacobians::<$g, $d>(&a, &b);
                }

                #[test]
                fn matrix_round_trip(x in raw(), c in 0u8..8, s in 0u8..6) {
                    check_from_matrix::<$g, $d>(&<$g>::exp(&shaped_tangent::<$g, $d>(&x, c, s)));
                }
            }
        }
    };
}

group_properties!(so2, So2, 1);
group_properties!(se2, Se2, 3);
group_properties!(so3, So3, 3);
group_properties!(se3, Se3, 6);
group_properties!(sim3, Sim3, 7);

/// Sim(3) exp in all four combinations of σ → 0 and θ → 0 (thesis eq. 5.6–5.8), against the
/// matrix-exponential series, and log recovering the tangent to rounding.
#[test]
fn sim3_exp_log_near_sigma_and_theta_zero() {
    let small = [0.0, 1e-14, 1e-9, 1e-6, 1e-3, 0.2, 0.49, 0.51, 1.5];
    for &sigma in &small {
        for &theta in &small {
            for &sign in &[1.0, -1.0] {
                let axis = Vector3::new(0.3, -0.5, 0.8).normalize();
                let w = axis * theta;
                let x = SVector::<f64, 7>::from_column_slice(&[
                    0.7,
                    -1.1,
                    0.4,
                    w.x,
                    w.y,
                    w.z,
                    sign * sigma,
                ]);
                let reference = expm_series(&Sim3::mat(&Sim3::hat(&x)));
                let got = Sim3::mat(&Sim3::exp(&x).matrix());
                let err = max_abs(&(&reference - &got));
                // The reference itself carries ~1e-15 of rounding; the coefficients are checked to
                // 2 ulp against 50-digit values in the crate's unit tests.
                assert!(
                    err < 1e-14 * max_abs(&reference),
                    "exp σ={sigma} θ={theta}: {err:e}"
                );
                let back = Sim3::exp(&x).log();
                assert!(
                    (back - x).amax() < 2e-15,
                    "log σ={sigma} θ={theta}: {:e}",
                    (back - x).amax()
                );
            }
        }
    }
}

/// SO(3) and SE(3) log near θ = π: the angle stays in [0, π] and exp(log) reproduces the
/// element to rounding.
#[test]
fn log_near_pi() {
    let axis = Vector3::new(1.0, 2.0, -2.0).normalize();
    for &delta in &[0.0, 1e-15, 1e-12, 1e-9, 1e-6] {
        for &theta in &[PI - delta, PI + delta] {
            let r = So3::exp(&(axis * theta));
            let w = r.log();
            assert!(w.norm() <= PI + 1e-15);
            let expected = if theta <= PI {
                axis * theta
            } else {
                -axis * (2.0 * PI - theta)
            };
            if delta > 0.0 {
                assert!(
                    (w - expected).amax() < 1e-12,
                    "θ = π ± {delta}: {w:?} vs {expected:?}"
                );
            }
            assert!((So3::exp(&w).rotation_matrix() - r.rotation_matrix()).amax() < 1e-15 * 4.0);
            let t = Se3::new(r, Vector3::new(1.0, -2.0, 3.0));
            let back = Se3::exp(&t.log());
            assert!((back.matrix() - t.matrix()).amax() < 1e-13);
        }
    }
}

/// A rotation matrix at exactly θ = π converts and logs to an angle of π.
#[test]
fn rotation_by_pi_from_matrix() {
    let r = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
    let so3 = So3::from_matrix(&r).unwrap();
    let w = so3.log();
    assert!((w.norm() - PI).abs() < 1e-15);
    assert!((w.normalize().x.abs() - 1.0).abs() < 1e-15);
}
