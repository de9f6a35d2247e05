//! Scalar coefficient functions of the closed-form exp/log maps, each accurate to rounding
//! near zero (where the closed forms divide 0 by 0) by switching to its Taylor series.

/// A rotation angle `θ` with `sin(θ/2)` and `cos(θ/2)`, from which every coefficient function
/// of the closed-form exp/log maps follows without further trigonometry. A unit quaternion
/// `(cos(θ/2), sin(θ/2)·u)` carries both halves already, so the logarithms need none at all.
///
/// Each function is accurate to rounding near `θ = 0`, where its closed form divides 0 by 0,
/// by switching to its Taylor series.
#[derive(Clone, Copy, Debug)]
pub(crate) struct HalfAngle {
    pub theta: f64,
    pub sin_half: f64,
    pub cos_half: f64,
}

impl HalfAngle {
    /// From the angle.
    #[inline]
    pub(crate) fn new(theta: f64) -> Self {
        let (sin_half, cos_half) = (0.5 * theta).sin_cos();
        HalfAngle {
            theta,
            sin_half,
            cos_half,
        }
    }

    /// `sin(θ/2)/(θ/2)`.
    #[inline]
    pub(crate) fn sinc_half(&self) -> f64 {
        let half = 0.5 * self.theta;
        if half.abs() < 1e-4 {
            let h2 = half * half;
            1.0 - h2 / 6.0 + h2 * h2 / 120.0
        } else {
            self.sin_half / half
        }
    }

    /// `sin θ = 2·sin(θ/2)·cos(θ/2)`.
    #[inline]
    pub(crate) fn sin(&self) -> f64 {
        2.0 * self.sin_half * self.cos_half
    }

    /// `cos θ = cos²(θ/2) − sin²(θ/2)`.
    #[inline]
    pub(crate) fn cos(&self) -> f64 {
        self.cos_half * self.cos_half - self.sin_half * self.sin_half
    }

    /// `sin(θ)/θ`, `→ 1` for `θ → 0`.
    #[inline]
    pub(crate) fn sinc(&self) -> f64 {
        self.sinc_half() * self.cos_half
    }

    /// `(1 − cos θ)/θ² = ½·sinc²(θ/2)`, `→ ½` for `θ → 0` (thesis eq. 2.71, 2.100).
    #[inline]
    pub(crate) fn one_minus_cos_over_sq(&self) -> f64 {
        let s = self.sinc_half();
        0.5 * s * s
    }

    /// `(θ − sin θ)/θ³`, `→ 1/6` for `θ → 0` (thesis eq. 2.100).
    #[inline]
    pub(crate) fn theta_minus_sin_over_cube(&self) -> f64 {
        let t2 = self.theta * self.theta;
        if t2 < 0.25 {
            // Σ_k (−1)^k θ^{2k} / (2k+3)!, k = 0..7: truncation below 1e-19 for |θ| < 0.5.
            let mut term = 1.0 / 6.0;
            let mut sum = term;
            for k in 1..8 {
                let n = (2 * k + 3) as f64;
                term *= -t2 / ((n - 1.0) * n);
                sum += term;
            }
            sum
        } else {
            (self.theta - self.sin()) / (t2 * self.theta)
        }
    }

    /// `(1 − (θ/2)·cot(θ/2))/θ²`, the `[ω]×²` coefficient of `J_l(ω)⁻¹` for SO(3) and of
    /// `V⁻¹` in the SE(3) logarithm; `→ 1/12` for `θ → 0`.
    #[inline]
    pub(crate) fn inv_left_jacobian_coeff(&self) -> f64 {
        let t2 = self.theta * self.theta;
        if t2 < 0.01 {
            // 1/12 + θ²/720 + θ⁴/30240 + θ⁶/1209600 + θ⁸/47900160 (Bernoulli series of x·cot x).
            1.0 / 12.0
                + t2 * (1.0 / 720.0
                    + t2 * (1.0 / 30240.0 + t2 * (1.0 / 1_209_600.0 + t2 / 47_900_160.0)))
        } else {
            (1.0 - 0.5 * self.theta * self.cos_half / self.sin_half) / t2
        }
    }
}

/// The coefficients `(C, a, b)` of `W = C·I + a·[ω]× + b·[ω]×²`, the matrix that maps the
/// translational tangent `v` of Sim(3) to the translation of `exp(v, ω, σ)` (thesis eq. 5.7,
/// A.29), written without divisions by `θ` or `σ`:
///
/// * `C = (e^σ − 1)/σ`,
/// * `a = (e^σ·σ·sinc θ + 1 − e^σ·cos θ) / (σ² + θ²)`,
/// * `b = (C + e^σ·(σ·(1 − cos θ)/θ² − sinc θ)) / (σ² + θ²)`.
///
/// These are `a = Im f(z)/θ` and `b = (C − Re f(z))/θ²` with `f(z) = (e^z − 1)/z`,
/// `z = σ + iθ` (the thesis's proof of A.29). For `|z|² < ¼` both cancel, so the power series
/// `f(z) = Σ zᵏ/(k+1)!` is summed with the real recursions `zᵏ = pₖ + iθ·qₖ`,
/// `(σᵏ − pₖ)/θ² = rₖ`, giving `a = Σ qₖ/(k+1)!`, `b = Σ rₖ/(k+1)!`.
///
/// With `σ = 0` this is SE(3)'s `V` (thesis eq. 2.100): `C = 1`, `a = (1 − cos θ)/θ²`,
/// `b = (θ − sin θ)/θ³`.
#[inline]
pub(crate) fn sim3_w_coefficients(sigma: f64, angle: &HalfAngle) -> (f64, f64, f64) {
    let theta = angle.theta;
    let c = if sigma == 0.0 {
        1.0
    } else {
        sigma.exp_m1() / sigma
    };
    let t2 = theta * theta;
    let z2 = sigma * sigma + t2;
    if z2 < 0.25 {
        // |z| < ½: 18 terms leave a truncation error below 1e-22.
        let (mut p, mut q, mut r) = (1.0_f64, 0.0_f64, 0.0_f64);
        let mut inv_fact = 1.0_f64; // 1/(k+1)!
        let (mut a, mut b) = (0.0, 0.0);
        for k in 0..18 {
            a += q * inv_fact;
            b += r * inv_fact;
            let p_next = sigma * p - t2 * q;
            let q_next = p + sigma * q;
            r = sigma * r + q;
            p = p_next;
            q = q_next;
            inv_fact /= (k + 2) as f64;
        }
        (c, a, b)
    } else {
        let es = sigma.exp();
        let sc = angle.sinc();
        let a = (es * sigma * sc + 1.0 - es * angle.cos()) / z2;
        let b = (c + es * (sigma * angle.one_minus_cos_over_sq() - sc)) / z2;
        (c, a, b)
    }
}

/// The coefficients `(x, y, z)` of `W⁻¹ = x·I + y·[ω]× + z·[ω]×²` for
/// `W = C·I + a·[ω]× + b·[ω]×²` and `θ = ‖ω‖` (thesis eq. 5.8).
///
/// Uses `[ω]×³ = −θ²[ω]×`: with `P = C − θ²b`, `det = P² + θ²a²` (`= |f(σ + iθ)|² > 0` for
/// `θ ≤ π`), `x = 1/C`, `y = −a/det`, `z = (a² − P·b)/(C·det)`.
#[inline]
pub(crate) fn inverse_w_coefficients(c: f64, a: f64, b: f64, theta: f64) -> (f64, f64, f64) {
    let t2 = theta * theta;
    let p = c - t2 * b;
    let det = p * p + t2 * a * a;
    (1.0 / c, -a / det, (a * a - p * b) / (c * det))
}

/// Gauss–Legendre nodes and weights on `[0, 1]`, `N` points, by Newton iteration on `P_N`.
pub(crate) fn gauss_legendre_01<const N: usize>() -> ([f64; N], [f64; N]) {
    let mut nodes = [0.0; N];
    let mut weights = [0.0; N];
    let n = N as f64;
    for i in 0..N {
        // Initial guess (Tricomi), then Newton on P_N(x).
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for k in 2..=N {
                let kf = k as f64;
                let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
                p0 = p1;
                p1 = p2;
            }
            // p1 = P_N(x), p0 = P_{N-1}(x).
            dp = n * (x * p1 - p0) / (x * x - 1.0);
            let step = p1 / dp;
            x -= step;
            if step.abs() < 1e-16 {
                break;
            }
        }
        nodes[i] = 0.5 * (1.0 - x);
        weights[i] = 1.0 / ((1.0 - x * x) * dp * dp);
    }
    (nodes, weights)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coefficient_functions_are_continuous_across_their_switch_points() {
        for &t in &[2e-4, 0.1, 0.5, 1e-2] {
            let functions: [fn(&HalfAngle) -> f64; 4] = [
                HalfAngle::sinc,
                HalfAngle::one_minus_cos_over_sq,
                HalfAngle::theta_minus_sin_over_cube,
                HalfAngle::inv_left_jacobian_coeff,
            ];
            for f in functions {
                let below = f(&HalfAngle::new(t * (1.0 - 1e-15)));
                let above = f(&HalfAngle::new(t * (1.0 + 1e-15)));
                assert!(
                    (below - above).abs() < 1e-13,
                    "jump at {t}: {below} vs {above}"
                );
            }
        }
    }

    #[test]
    fn sim3_w_series_and_closed_form_agree_at_the_switch() {
        for angle in 0..16 {
            let phi = angle as f64 * std::f64::consts::PI / 8.0;
            let (s, t) = (0.5 * phi.cos(), 0.5 * phi.sin().abs());
            let inside = sim3_w_coefficients(s * (1.0 - 1e-15), &HalfAngle::new(t * (1.0 - 1e-15)));
            let outside =
                sim3_w_coefficients(s * (1.0 + 1e-15), &HalfAngle::new(t * (1.0 + 1e-15)));
            assert!((inside.1 - outside.1).abs() < 1e-14, "a at {s},{t}");
            assert!((inside.2 - outside.2).abs() < 1e-14, "b at {s},{t}");
        }
    }

    #[test]
    fn sim3_w_at_sigma_zero_is_se3_v() {
        for &t in &[0.0, 1e-6, 0.3, 1.0, 3.0] {
            let angle = HalfAngle::new(t);
            let (c, a, b) = sim3_w_coefficients(0.0, &angle);
            assert_eq!(c, 1.0);
            assert!((a - angle.one_minus_cos_over_sq()).abs() < 1e-15);
            assert!((b - angle.theta_minus_sin_over_cube()).abs() < 1e-15);
        }
    }

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        let (x, w) = gauss_legendre_01::<12>();
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-14);
        // ∫₀¹ t^k dt = 1/(k+1) for k ≤ 2N−1.
        for k in 0..24 {
            let integral: f64 = x.iter().zip(&w).map(|(xi, wi)| wi * xi.powi(k)).sum();
            assert!((integral - 1.0 / (k as f64 + 1.0)).abs() < 1e-14, "k = {k}");
        }
    }
}

#[cfg(test)]
#[allow(clippy::excessive_precision)] // 20-digit mpmath values, kept as printed.
mod reference_values {
    use super::{HalfAngle, sim3_w_coefficients};

    /// `(C, a, b)` against 50-digit values computed with mpmath from the closed form of thesis
    /// eq. A.29 (`a = Im f(z)/θ`, `b = (C − Re f(z))/θ²`).
    #[test]
    fn sim3_w_coefficients_match_high_precision_values() {
        let cases = [
            (
                0.2,
                1e-6,
                [
                    1.107013790800849176,
                    0.57194483679655440381,
                    0.19378271141739813,
                ],
            ),
            (
                1e-3,
                1e-3,
                [
                    1.0005001667083416681,
                    0.50033341666666110953,
                    0.16679170834027797602,
                ],
            ),
            (
                0.49,
                1e-4,
                [
                    1.2904412652150591165,
                    0.69770398864739560632,
                    0.24174310336767778684,
                ],
            ),
            (
                1.5,
                1e-9,
                [
                    2.3211260468920432151,
                    1.4403753489640144049,
                    0.53364612413667867082,
                ],
            ),
            (
                1e-9,
                1.5,
                [
                    1.0000000005000000002,
                    0.41300568841180290942,
                    0.14889037444976566365,
                ],
            ),
        ];
        for (sigma, theta, expected) in cases {
            let (c, a, b) = sim3_w_coefficients(sigma, &HalfAngle::new(theta));
            for (got, want) in [c, a, b].into_iter().zip(expected) {
                assert!(
                    (got - want).abs() <= 2.0 * f64::EPSILON * want,
                    "σ={sigma} θ={theta}: {got} vs {want}"
                );
            }
        }
    }
}
