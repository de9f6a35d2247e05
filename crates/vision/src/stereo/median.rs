//! The 3×3 median of the valid disparities, the matcher's last step.

use crate::image::Image;

/// Buffers of [`median3_valid_into`] (total-order keys and validity of every pixel, the median
/// and count of one row).
#[derive(Default)]
pub(super) struct MedianScratch {
    keys: Vec<u32>,
    valid: Vec<u8>,
    med: Vec<u32>,
    cnt: Vec<u8>,
}

/// [`median3_valid_into`] into a new image (tests).
#[cfg(test)]
pub(super) fn median3_valid(d: &Image<f32>) -> Image<f32> {
    let mut out = Image::filled(d.width(), d.height(), f32::NAN);
    median3_valid_into(d, &mut MedianScratch::default(), &mut out);
    out
}

/// A sorting network for 9 elements (25 compare-exchanges): the three rows sorted, then the
/// three columns, then the remaining inversions; checked on all 2⁹ 0-1 inputs in the tests
/// (a network sorting every 0-1 sequence sorts every sequence).
/// (`median3_valid_into` performs these exchanges written out, in this order.)
#[cfg_attr(not(test), allow(dead_code))]
pub(super) const SORT9: [(usize, usize); 25] = [
    (0, 1),
    (3, 4),
    (6, 7),
    (1, 2),
    (4, 5),
    (7, 8),
    (0, 1),
    (3, 4),
    (6, 7),
    (0, 3),
    (3, 6),
    (0, 3),
    (1, 4),
    (4, 7),
    (1, 4),
    (2, 5),
    (5, 8),
    (2, 5),
    (1, 3),
    (5, 7),
    (2, 6),
    (4, 6),
    (2, 4),
    (2, 3),
    (5, 6),
];

/// 3×3 median over the valid (finite) values of the neighbourhood; invalid pixels with at least
/// 5 valid neighbours are filled, pixels with fewer valid neighbours become invalid.
///
/// Interior pixels take the median from a sorting network on the values' total-order keys (the
/// order `f32::total_cmp` sorts by; invalid values last), which vectorises across the row; the
/// border pixels go through [`median3_valid_pixel`]. Identical results.
/// Inlined into the matcher's instances, so the AVX2 one compares with `vpminud`/`vpmaxud`
/// (the baseline x86-64 build has no unsigned 32-bit min/max and emulates them).
///
/// Writes every pixel of `out` (the size of `d`); the key, validity and row buffers are
/// `scratch`'s, kept by the caller so that nothing is allocated per call.
#[inline(always)]
pub(super) fn median3_valid_into(
    d: &Image<f32>,
    scratch: &mut MedianScratch,
    out: &mut Image<f32>,
) {
    let (w, h) = (d.width(), d.height());
    assert!(out.width() == w && out.height() == h);
    if w < 3 || h < 3 {
        for v in 0..h {
            for u in 0..w {
                out.set(u, v, median3_valid_pixel(d, u, v));
            }
        }
        return;
    }
    // total_cmp's key: flip the magnitude bits of negative values; invalid (NaN, ±∞: not
    // finite) → u32::MAX, after every valid key.
    let key = |x: f32| {
        let b = x.to_bits();
        if x.is_finite() {
            b ^ ((((b as i32) >> 31) as u32) >> 1) ^ 0x8000_0000
        } else {
            u32::MAX
        }
    };
    let unkey = |k: u32| {
        let b = k ^ 0x8000_0000;
        f32::from_bits(b ^ ((((b as i32) >> 31) as u32) >> 1))
    };
    let MedianScratch {
        keys,
        valid,
        med,
        cnt,
    } = scratch;
    keys.clear();
    keys.extend(d.data().iter().map(|&x| key(x)));
    valid.clear();
    valid.extend(d.data().iter().map(|x| x.is_finite() as u8));
    med.resize(w, 0);
    cnt.resize(w, 0);
    let st = d.stride();
    for v in 0..h {
        let o = out.row_mut(v);
        if v == 0 || v == h - 1 {
            for (u, px) in o.iter_mut().enumerate() {
                *px = median3_valid_pixel(d, u, v);
            }
            continue;
        }
        let rows: [&[u32]; 3] =
            std::array::from_fn(|r| &keys[(v + r - 1) * st..(v + r - 1) * st + w]);
        let vrows: [&[u8]; 3] =
            std::array::from_fn(|r| &valid[(v + r - 1) * st..(v + r - 1) * st + w]);
        median_row(rows, vrows, med, cnt);
        // (A select on the bits, so that the loop vectorises.)
        for ((o, &m), &c) in o[1..w - 1]
            .iter_mut()
            .zip(&med[1..w - 1])
            .zip(&cnt[1..w - 1])
        {
            *o = f32::from_bits(if c >= 5 {
                unkey(m).to_bits()
            } else {
                f32::NAN.to_bits()
            });
        }
        o[0] = median3_valid_pixel(d, 0, v);
        o[w - 1] = median3_valid_pixel(d, w - 1, v);
    }
}

/// The interior pixels `1 … w − 2` of one row of [`median3_valid_into`]: the median key and the
/// count of valid values of each 3×3 neighbourhood. (A function of its own so that the
/// compiler knows the buffers apart and vectorises across the row.)
#[inline(always)]
fn median_row(rows: [&[u32]; 3], vrows: [&[u8]; 3], med: &mut [u32], cnt: &mut [u8]) {
    let w = med.len();
    for u in 1..w - 1 {
        let mut p = [
            rows[0][u - 1],
            rows[0][u],
            rows[0][u + 1],
            rows[1][u - 1],
            rows[1][u],
            rows[1][u + 1],
            rows[2][u - 1],
            rows[2][u],
            rows[2][u + 1],
        ];
        // A 25-exchange sorting network of 9 (invalid keys are u32::MAX, so they sort
        // last): the valid values come first, in total order, and the median of the `n`
        // valid ones is element `n / 2` — index 2, 3 or 4 for n = 5 … 9, picked without a
        // branch so the loop stays vectorised.
        macro_rules! s {
            ($a:expr, $b:expr) => {{
                let (x, y) = (p[$a], p[$b]);
                p[$a] = x.min(y);
                p[$b] = x.max(y);
            }};
        }
        // SORT9, written out (a loop over the table keeps `p` in memory, unvectorised).
        s!(0, 1);
        s!(3, 4);
        s!(6, 7);
        s!(1, 2);
        s!(4, 5);
        s!(7, 8);
        s!(0, 1);
        s!(3, 4);
        s!(6, 7);
        s!(0, 3);
        s!(3, 6);
        s!(0, 3);
        s!(1, 4);
        s!(4, 7);
        s!(1, 4);
        s!(2, 5);
        s!(5, 8);
        s!(2, 5);
        s!(1, 3);
        s!(5, 7);
        s!(2, 6);
        s!(4, 6);
        s!(2, 4);
        s!(2, 3);
        s!(5, 6);
        let n = vrows[0][u - 1]
            + vrows[0][u]
            + vrows[0][u + 1]
            + vrows[1][u - 1]
            + vrows[1][u]
            + vrows[1][u + 1]
            + vrows[2][u - 1]
            + vrows[2][u]
            + vrows[2][u + 1];
        med[u] = if n >= 8 {
            p[4]
        } else if n >= 6 {
            p[3]
        } else {
            p[2]
        };
        cnt[u] = n;
    }
}

/// [`median3_valid_into`] pixel by pixel (the reference of its fast path).
#[cfg(test)]
pub(super) fn median3_valid_slow(d: &Image<f32>) -> Image<f32> {
    Image::from_fn(d.width(), d.height(), |u, v| median3_valid_pixel(d, u, v))
}

/// One pixel of [`median3_valid_into`] (its border pixels and small images): sort the valid neighbours, take the middle one.
fn median3_valid_pixel(d: &Image<f32>, u: usize, v: usize) -> f32 {
    let (w, h) = (d.width() as i64, d.height() as i64);
    let mut a = [0.0f32; 9];
    let mut n = 0;
    for dv in -1..=1i64 {
        for du in -1..=1i64 {
            let (x, y) = (u as i64 + du, v as i64 + dv);
            if x >= 0 && y >= 0 && x < w && y < h {
                let val = d.get(x as usize, y as usize);
                if val.is_finite() {
                    a[n] = val;
                    n += 1;
                }
            }
        }
    }
    if n < 5 {
        return f32::NAN;
    }
    a[..n].sort_by(|x, y| x.total_cmp(y));
    a[n / 2]
}
