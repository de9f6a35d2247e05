//! Small dense kernels of assembly and elimination, specialised on the short inner dimension
//! (the residual size in `JᵀJ`, the point size in the Schur complement) so the compiler
//! unrolls and vectorises them. Matrices are column-major slices.

/// Dispatches `$f::<R>` for common small `R`, else `$dynamic`.
macro_rules! dispatch {
    ($r:expr, $f:ident, ($($arg:expr),*), $dynamic:expr) => {
        match $r {
            1 => $f::<1>($($arg),*),
            2 => $f::<2>($($arg),*),
            3 => $f::<3>($($arg),*),
            4 => $f::<4>($($arg),*),
            6 => $f::<6>($($arg),*),
            7 => $f::<7>($($arg),*),
            9 => $f::<9>($($arg),*),
            _ => $dynamic,
        }
    };
}

#[inline(always)]
fn at_b_fixed<const R: usize>(
    out: &mut [f64],
    a: &[f64],
    b: &[f64],
    di: usize,
    dj: usize,
    sign: f64,
) {
    for cc in 0..dj {
        let colb: &[f64; R] = b[cc * R..cc * R + R]
            .try_into()
            .expect("column of length R");
        for rr in 0..di {
            let cola: &[f64; R] = a[rr * R..rr * R + R]
                .try_into()
                .expect("column of length R");
            let mut acc = 0.0;
            for t in 0..R {
                acc += cola[t] * colb[t];
            }
            out[cc * di + rr] += sign * acc;
        }
    }
}

fn at_b_dynamic(out: &mut [f64], a: &[f64], b: &[f64], r: usize, di: usize, dj: usize, sign: f64) {
    for cc in 0..dj {
        let colb = &b[cc * r..(cc + 1) * r];
        for rr in 0..di {
            let cola = &a[rr * r..(rr + 1) * r];
            out[cc * di + rr] += sign * cola.iter().zip(colb).map(|(x, y)| x * y).sum::<f64>();
        }
    }
}

/// Fully specialised `out (DI×DJ) += sign·Aᵀ·B`: every loop bound is a constant, so the
/// compiler unrolls the loops and drops the bounds checks.
#[inline(always)]
fn at_b_const<const R: usize, const DI: usize, const DJ: usize>(
    out: &mut [f64],
    a: &[f64],
    b: &[f64],
    sign: f64,
) {
    let a = &a[..R * DI];
    let b = &b[..R * DJ];
    let out = &mut out[..DI * DJ];
    for cc in 0..DJ {
        for rr in 0..DI {
            let mut acc = 0.0;
            for t in 0..R {
                acc += a[rr * R + t] * b[cc * R + t];
            }
            out[cc * DI + rr] += sign * acc;
        }
    }
}

/// `out (di×dj) += sign·Aᵀ·B` for `A` (r×di) and `B` (r×dj).
#[inline(always)]
pub(crate) fn add_at_b(
    out: &mut [f64],
    a: &[f64],
    b: &[f64],
    r: usize,
    di: usize,
    dj: usize,
    sign: f64,
) {
    // The block sizes of bundle adjustment (residuals of 2 or 3, points of 3, poses of 6 or 7,
    // BAL cameras of 9) and pose graphs get fully specialised kernels; others the generic ones.
    match (r, di, dj) {
        (1, 1, 1) => at_b_const::<1, 1, 1>(out, a, b, sign),
        (2, 3, 3) => at_b_const::<2, 3, 3>(out, a, b, sign),
        (2, 3, 6) => at_b_const::<2, 3, 6>(out, a, b, sign),
        (2, 3, 7) => at_b_const::<2, 3, 7>(out, a, b, sign),
        (2, 3, 9) => at_b_const::<2, 3, 9>(out, a, b, sign),
        (2, 6, 3) => at_b_const::<2, 6, 3>(out, a, b, sign),
        (2, 6, 6) => at_b_const::<2, 6, 6>(out, a, b, sign),
        (2, 6, 7) => at_b_const::<2, 6, 7>(out, a, b, sign),
        (2, 6, 9) => at_b_const::<2, 6, 9>(out, a, b, sign),
        (2, 7, 3) => at_b_const::<2, 7, 3>(out, a, b, sign),
        (2, 7, 6) => at_b_const::<2, 7, 6>(out, a, b, sign),
        (2, 7, 7) => at_b_const::<2, 7, 7>(out, a, b, sign),
        (2, 7, 9) => at_b_const::<2, 7, 9>(out, a, b, sign),
        (2, 9, 3) => at_b_const::<2, 9, 3>(out, a, b, sign),
        (2, 9, 6) => at_b_const::<2, 9, 6>(out, a, b, sign),
        (2, 9, 7) => at_b_const::<2, 9, 7>(out, a, b, sign),
        (2, 9, 9) => at_b_const::<2, 9, 9>(out, a, b, sign),
        (3, 3, 3) => at_b_const::<3, 3, 3>(out, a, b, sign),
        (3, 3, 6) => at_b_const::<3, 3, 6>(out, a, b, sign),
        (3, 3, 7) => at_b_const::<3, 3, 7>(out, a, b, sign),
        (3, 3, 9) => at_b_const::<3, 3, 9>(out, a, b, sign),
        (3, 6, 3) => at_b_const::<3, 6, 3>(out, a, b, sign),
        (3, 6, 6) => at_b_const::<3, 6, 6>(out, a, b, sign),
        (3, 6, 7) => at_b_const::<3, 6, 7>(out, a, b, sign),
        (3, 6, 9) => at_b_const::<3, 6, 9>(out, a, b, sign),
        (3, 7, 3) => at_b_const::<3, 7, 3>(out, a, b, sign),
        (3, 7, 6) => at_b_const::<3, 7, 6>(out, a, b, sign),
        (3, 7, 7) => at_b_const::<3, 7, 7>(out, a, b, sign),
        (3, 7, 9) => at_b_const::<3, 7, 9>(out, a, b, sign),
        (3, 9, 3) => at_b_const::<3, 9, 3>(out, a, b, sign),
        (3, 9, 6) => at_b_const::<3, 9, 6>(out, a, b, sign),
        (3, 9, 7) => at_b_const::<3, 9, 7>(out, a, b, sign),
        (3, 9, 9) => at_b_const::<3, 9, 9>(out, a, b, sign),
        (6, 6, 6) => at_b_const::<6, 6, 6>(out, a, b, sign),
        (7, 7, 7) => at_b_const::<7, 7, 7>(out, a, b, sign),
        _ => dispatch!(
            r,
            at_b_fixed,
            (out, a, b, di, dj, sign),
            at_b_dynamic(out, a, b, r, di, dj, sign)
        ),
    }
}

#[inline(always)]
fn at_x_fixed<const R: usize>(out: &mut [f64], a: &[f64], x: &[f64], d: usize, sign: f64) {
    let x: &[f64; R] = x[..R].try_into().expect("vector of length R");
    for c in 0..d {
        let col: &[f64; R] = a[c * R..c * R + R].try_into().expect("column of length R");
        let mut acc = 0.0;
        for t in 0..R {
            acc += col[t] * x[t];
        }
        out[c] += sign * acc;
    }
}

fn at_x_dynamic(out: &mut [f64], a: &[f64], x: &[f64], r: usize, d: usize, sign: f64) {
    for c in 0..d {
        out[c] += sign
            * a[c * r..(c + 1) * r]
                .iter()
                .zip(x)
                .map(|(p, q)| p * q)
                .sum::<f64>();
    }
}

/// `out (d) += sign·Aᵀ·x` for `A` (r×d) and `x` (r).
#[inline(always)]
pub(crate) fn add_at_x(out: &mut [f64], a: &[f64], x: &[f64], r: usize, d: usize, sign: f64) {
    dispatch!(
        r,
        at_x_fixed,
        (out, a, x, d, sign),
        at_x_dynamic(out, a, x, r, d, sign)
    )
}

#[inline(always)]
fn a_x_fixed<const R: usize>(out: &mut [f64], a: &[f64], x: &[f64], d: usize, sign: f64) {
    // out (R) += sign·A·x for A (R×d).
    let mut acc = [0.0f64; R];
    for c in 0..d {
        let col: &[f64; R] = a[c * R..c * R + R].try_into().expect("column of length R");
        let xc = x[c];
        for t in 0..R {
            acc[t] += col[t] * xc;
        }
    }
    for t in 0..R {
        out[t] += sign * acc[t];
    }
}

fn a_x_dynamic(out: &mut [f64], a: &[f64], x: &[f64], r: usize, d: usize, sign: f64) {
    for c in 0..d {
        let xc = x[c];
        for t in 0..r {
            out[t] += sign * a[c * r + t] * xc;
        }
    }
}

/// `out (r) += sign·A·x` for `A` (r×d) and `x` (d).
#[inline(always)]
pub(crate) fn add_a_x(out: &mut [f64], a: &[f64], x: &[f64], r: usize, d: usize, sign: f64) {
    dispatch!(
        r,
        a_x_fixed,
        (out, a, x, d, sign),
        a_x_dynamic(out, a, x, r, d, sign)
    )
}

#[inline(always)]
fn a_b_fixed<const R: usize>(out: &mut [f64], a: &[f64], b: &[f64], dj: usize) {
    // out (R×dj) = A (R×R)·B (R×dj).
    for k in 0..dj {
        let colb: &[f64; R] = b[k * R..k * R + R].try_into().expect("column of length R");
        let mut acc = [0.0f64; R];
        for t in 0..R {
            let cola: &[f64; R] = a[t * R..t * R + R].try_into().expect("column of length R");
            for r in 0..R {
                acc[r] += cola[r] * colb[t];
            }
        }
        out[k * R..k * R + R].copy_from_slice(&acc);
    }
}

fn a_b_dynamic(out: &mut [f64], a: &[f64], b: &[f64], r: usize, dj: usize) {
    for k in 0..dj {
        for row in 0..r {
            out[k * r + row] = (0..r).map(|t| a[t * r + row] * b[k * r + t]).sum();
        }
    }
}

/// `out (r×dj) = A (r×r)·B (r×dj)`.
#[inline(always)]
pub(crate) fn square_times(out: &mut [f64], a: &[f64], b: &[f64], r: usize, dj: usize) {
    dispatch!(r, a_b_fixed, (out, a, b, dj), a_b_dynamic(out, a, b, r, dj))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    #[test]
    fn kernels_match_nalgebra_for_fixed_and_dynamic_sizes() {
        for r in [1, 2, 3, 5, 6, 9, 11] {
            for (di, dj) in [
                (1, 1),
                (3, 9),
                (9, 3),
                (6, 6),
                (9, 9),
                (3, 3),
                (7, 7),
                (6, 3),
            ] {
                let a = DMatrix::<f64>::from_fn(r, di, |i, j| ((i * 3 + j) as f64 * 0.7).sin());
                let b = DMatrix::<f64>::from_fn(r, dj, |i, j| ((i + j * 5) as f64 * 0.3).cos());
                let mut out = vec![1.0; di * dj];
                add_at_b(&mut out, a.as_slice(), b.as_slice(), r, di, dj, -1.0);
                let expected = DMatrix::from_element(di, dj, 1.0) - a.transpose() * &b;
                assert!(
                    out.iter()
                        .zip(expected.as_slice())
                        .all(|(x, y)| (x - y).abs() < 1e-12),
                    "AᵀB r={r}"
                );
                let x = DMatrix::<f64>::from_fn(r, 1, |i, _| i as f64 - 1.5);
                let mut y = vec![0.0; di];
                add_at_x(&mut y, a.as_slice(), x.as_slice(), r, di, 1.0);
                let expected = a.transpose() * &x;
                assert!(
                    y.iter()
                        .zip(expected.as_slice())
                        .all(|(p, q)| (p - q).abs() < 1e-12),
                    "Aᵀx r={r}"
                );
                let v = DMatrix::<f64>::from_fn(di, 1, |i, _| i as f64 * 0.5 - 1.0);
                let mut w = vec![0.0; r];
                add_a_x(&mut w, a.as_slice(), v.as_slice(), r, di, 2.0);
                let expected = (&a * &v) * 2.0;
                assert!(
                    w.iter()
                        .zip(expected.as_slice())
                        .all(|(p, q)| (p - q).abs() < 1e-12),
                    "Ax r={r}"
                );
            }
            let sq = DMatrix::<f64>::from_fn(r, r, |i, j| ((i * 7 + j) as f64).sin());
            let b = DMatrix::<f64>::from_fn(r, 4, |i, j| ((i + 2 * j) as f64).cos());
            let mut out = vec![0.0; r * 4];
            square_times(&mut out, sq.as_slice(), b.as_slice(), r, 4);
            let expected = &sq * &b;
            assert!(
                out.iter()
                    .zip(expected.as_slice())
                    .all(|(p, q)| (p - q).abs() < 1e-12),
                "AB r={r}"
            );
        }
    }
}
