//! Quantiles of the χ² distribution, for gating whitened residuals: a measurement with `k`
//! components whose squared whitened residual `‖r‖²_Λ` exceeds the `p` quantile of `χ²_k` is
//! an outlier at confidence `p` (thesis §3.4.4, §6.4.1).

/// The `p` quantile of the χ² distribution with `dof` degrees of freedom: the `x` with
/// `P(dof/2, x/2) = p`, `P` the regularised lower incomplete gamma function, found by Newton's
/// method from the Wilson–Hilferty approximation (exact to ~1e-12 relative). `NaN` unless
/// `dof ≥ 1` and `0 < p < 1`.
pub fn chi2_quantile(dof: usize, p: f64) -> f64 {
    if dof == 0 || !(p > 0.0 && p < 1.0) {
        return f64::NAN;
    }
    let k = dof as f64;
    let a = 0.5 * k;
    // Wilson–Hilferty: χ²_k ≈ k·(1 − 2/(9k) + z·√(2/(9k)))³.
    let z = normal_quantile(p);
    let c = 2.0 / (9.0 * k);
    let mut x = (k * (1.0 - c + z * c.sqrt()).powi(3)).max(1e-3);
    let ln_gamma_a = ln_gamma(a);
    for _ in 0..100 {
        let f = lower_regularised_gamma(a, 0.5 * x) - p;
        // d/dx P(a, x/2) = (x/2)^(a−1)·e^(−x/2) / (2Γ(a)).
        let density = ((a - 1.0) * (0.5 * x).ln() - 0.5 * x - ln_gamma_a).exp() * 0.5;
        if density <= 0.0 || !density.is_finite() {
            break;
        }
        let step = f / density;
        let next = (x - step).max(0.5 * x);
        let done = (next - x).abs() <= 1e-14 * x;
        x = next;
        if done {
            break;
        }
    }
    x
}

/// `P(a, x)`, the regularised lower incomplete gamma function: the series for `x < a + 1`,
/// Lentz's continued fraction for `Q = 1 − P` otherwise (Numerical Recipes §6.2).
fn lower_regularised_gamma(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let ln_prefix = a * x.ln() - x - ln_gamma(a);
    if x < a + 1.0 {
        let (mut sum, mut term, mut n) = (1.0 / a, 1.0 / a, a);
        for _ in 0..1000 {
            n += 1.0;
            term *= x / n;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        sum * ln_prefix.exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..1000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-16 {
                break;
            }
        }
        1.0 - ln_prefix.exp() * h
    }
}

/// `ln Γ(x)` for `x > 0` (Lanczos, g = 7, n = 9; ~1e-15 relative).
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection: Γ(x)Γ(1 − x) = π / sin(πx).
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut s = G[0];
    for (i, g) in G.iter().enumerate().skip(1) {
        s += g / (x + i as f64);
    }
    let t = x + 7.5;
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + s.ln()
}

/// The standard normal quantile (Acklam's rational approximation, ~1e-9 relative): the start
/// of the Newton iteration only.
fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_published_tables() {
        // R's qchisq(p, k), to 7 significant digits.
        let table = [
            (1, 0.95, 3.841459),
            (2, 0.95, 5.991465),
            (3, 0.95, 7.814728),
            (6, 0.95, 12.59159),
            (2, 0.99, 9.210340),
            (1, 0.999, 10.82757),
            (3, 0.999, 16.26624),
            (6, 0.999, 22.45774),
            (10, 0.5, 9.341818),
            (30, 0.999, 59.70306),
            (1, 0.01, 1.570879e-4),
        ];
        for (k, p, want) in table {
            let got = chi2_quantile(k, p);
            assert!(
                ((got - want) / want).abs() < 1e-6,
                "χ²({k}) at {p}: {got} vs {want}"
            );
        }
        // The closed form for two degrees of freedom: x = −2·ln(1 − p).
        for p in [0.1, 0.5, 0.9, 0.95, 0.999] {
            let exact = -2.0 * (1.0f64 - p).ln();
            assert!((chi2_quantile(2, p) - exact).abs() < 1e-12 * exact);
        }
        assert!(chi2_quantile(0, 0.5).is_nan());
        assert!(chi2_quantile(3, 1.0).is_nan());
        assert!(chi2_quantile(3, f64::NAN).is_nan());
    }
}
