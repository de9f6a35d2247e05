//! AVX2 kernels of the census matcher; `matcher.rs` holds their scalar references (same
//! results, tested bit for bit). Every function here needs a CPU with AVX2
//! (`crate::simd::avx2()`).

use std::arch::x86_64::*;

use super::row::{DecideIo, INVALID_COST, LANES, RIGHT_WAYS, RowIo, Shape, Step, decide_pixel};

/// Census byte planes of row `y` from the padded image (`c` replicated columns on either side,
/// rows `stride` apart, every pixel's top bit flipped so that signed byte compares order them as
/// unsigned), 32 pixels per step (the last step overlapping the one before): for each
/// neighbour, one signed byte compare against the centres and `acc = 2·acc − mask`, the neighbours of a plane taken from its
/// highest bit down, so bit `t` of plane `p` is neighbour `8p + t` in
/// [`super::census_transform`]'s order. `reversed` stores pixel `x` at `w − 1 − x`.
///
/// # Safety
/// AVX2; `w ≥ 32`, `planes·8 = (2c + 1)² − 1`, `out` holds `planes` planes `out_stride` apart
/// (checked).
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn census_row(
    padded: &[u8],
    stride: usize,
    w: usize,
    h: usize,
    c: usize,
    y: usize,
    planes: usize,
    out: &mut [u8],
    out_stride: usize,
    reversed: bool,
) {
    assert!(c <= 3 && planes * 8 == (2 * c + 1) * (2 * c + 1) - 1 && w >= 32 && y < h);
    assert!(stride >= w + 2 * c && padded.len() >= (h - 1) * stride + w + 2 * c);
    assert!(planes == 0 || (out.len() >= (planes - 1) * out_stride + w && out_stride >= w));
    // Start of neighbour k's bytes relative to the pixel's column (rows clamped).
    let mut nb = [0usize; 48];
    let mut k = 0;
    for dv in -(c as isize)..=c as isize {
        let row = (y as isize + dv).clamp(0, h as isize - 1) as usize * stride;
        for du in 0..=2 * c {
            if du != c || dv != 0 {
                nb[k] = row + du;
                k += 1;
            }
        }
    }
    let last = w - 32;
    // SAFETY: loads read padded[row + xs + du .. + 32] with du ≤ 2c and xs ≤ w − 32, inside
    // the padded row; stores write out[p·out_stride + (xs or w − 32 − xs) .. + 32] inside plane
    // p's first w bytes.
    unsafe {
        let rev = _mm256_setr_epi8(
            15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0, 15, 14, 13, 12, 11, 10, 9, 8, 7,
            6, 5, 4, 3, 2, 1, 0,
        );
        let p0 = padded.as_ptr();
        let mut x = 0;
        loop {
            let xs = x.min(last);
            let centre = _mm256_loadu_si256(p0.add(y * stride + xs + c) as *const __m256i);
            for p in 0..planes {
                let mut acc = _mm256_setzero_si256();
                for t in (0..8).rev() {
                    let v = _mm256_loadu_si256(p0.add(nb[8 * p + t] + xs) as *const __m256i);
                    let lt = _mm256_cmpgt_epi8(centre, v);
                    acc = _mm256_sub_epi8(_mm256_add_epi8(acc, acc), lt);
                }
                let o = out.as_mut_ptr().add(p * out_stride);
                if reversed {
                    let r =
                        _mm256_permute4x64_epi64::<0b01_00_11_10>(_mm256_shuffle_epi8(acc, rev));
                    _mm256_storeu_si256(o.add(w - 32 - xs) as *mut __m256i, r);
                } else {
                    _mm256_storeu_si256(o.add(xs) as *mut __m256i, acc);
                }
            }
            if xs == last {
                break;
            }
            x += 32;
        }
    }
}

/// Pixel costs of one row, `out[x·ndp + d] = popcount(L(x) ⊕ R(x − d))` for `d ≤ x`, `d < nd`,
/// [`INVALID_COST`] for the other `d < ndp` (past the left border, padding), 32 disparities per
/// step: per census plane, the right plane's 32 bytes (contiguous in `d`, the plane being
/// reversed) XOR the left byte broadcast, byte popcounts by the `pshufb` nibble table, summed
/// over the planes. A 16-lane tail is computed 32 wide and spills into the next pixel's lanes,
/// which are written after it (`out` has 16 bytes of room past the row).
///
/// # Safety
/// AVX2; sizes checked.
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn costs(
    lp: &[u8],
    rp: &[u8],
    rs: usize,
    planes: usize,
    w: usize,
    nd: usize,
    ndp: usize,
    out: &mut [u8],
    skip: std::ops::Range<usize>,
) {
    // SAFETY: forwarded (AVX2).
    unsafe {
        match planes {
            6 => costs_n::<6>(lp, rp, rs, w, nd, ndp, out, skip),
            3 => costs_n::<3>(lp, rp, rs, w, nd, ndp, out, skip),
            1 => costs_n::<1>(lp, rp, rs, w, nd, ndp, out, skip),
            0 => costs_n::<0>(lp, rp, rs, w, nd, ndp, out, skip),
            _ => unreachable!("census planes: 0, 1, 3 or 6"),
        }
    }
}

#[target_feature(enable = "avx2")]
#[inline]
#[allow(clippy::too_many_arguments)]
unsafe fn costs_n<const P: usize>(
    lp: &[u8],
    rp: &[u8],
    rs: usize,
    w: usize,
    nd: usize,
    ndp: usize,
    out: &mut [u8],
    skip: std::ops::Range<usize>,
) {
    assert!(ndp.is_multiple_of(LANES) && nd <= ndp && ndp < nd + LANES);
    assert!(lp.len() >= P * w && out.len() >= w * ndp + 16);
    assert!(P == 0 || (rs >= w + ndp + 16 && rp.len() >= (P - 1) * rs + w + ndp + 16));
    let b = nd.min(w);
    // (The skipped pixels lie among the ones without disparities past the border.)
    assert!(skip.is_empty() || (skip.start >= b && skip.end <= w));
    let (s0, s1) = if skip.is_empty() {
        (w, w)
    } else {
        (skip.start, skip.end)
    };
    // SAFETY: forwarded (AVX2, sizes checked).
    unsafe {
        costs_range::<P, true>(lp, rp, rs, w, nd, ndp, out, 0..b);
        costs_range::<P, false>(lp, rp, rs, w, nd, ndp, out, b..s0);
        costs_range::<P, false>(lp, rp, rs, w, nd, ndp, out, s1..w);
    }
}

/// [`costs`] of the pixels `xs` (`BORDER`: `x < nd`, some disparities past the left border).
///
/// # Safety
/// AVX2; the sizes checked by [`costs_n`].
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn costs_range<const P: usize, const BORDER: bool>(
    lp: &[u8],
    rp: &[u8],
    rs: usize,
    w: usize,
    nd: usize,
    ndp: usize,
    out: &mut [u8],
    xs: std::ops::Range<usize>,
) {
    // Start of the last chunk, which holds the padding lanes.
    let last = (ndp - 1) / 32 * 32;
    let padded = nd < ndp;
    // SAFETY: loads read rp[p·rs + w − 1 − x + k .. + 32] with k ≤ ndp − 16, inside
    // rp[p·rs .. p·rs + w + ndp + 16]; stores write out[x·ndp + k .. + 32] ⊂ out[.. w·ndp + 16].
    unsafe {
        let lut = _mm256_setr_epi8(
            0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2,
            3, 3, 4,
        );
        let low = _mm256_set1_epi8(0x0f);
        let invalid = _mm256_set1_epi8(INVALID_COST as i8);
        let byte_lanes = || {
            _mm256_setr_epi8(
                0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22,
                23, 24, 25, 26, 27, 28, 29, 30, 31,
            )
        };
        let mut xs = xs;
        if ndp == 16 && !BORDER {
            // 16 disparities: two pixels per vector (x in the low half, x + 1 in the high).
            let pair = _mm256_setr_epi8(
                0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1,
                1, 1, 1, 1,
            );
            // Padding lanes of both halves: d = j mod 16 ≥ nd.
            let pad = _mm256_cmpgt_epi8(
                _mm256_and_si256(byte_lanes(), _mm256_set1_epi8(15)),
                _mm256_set1_epi8(nd as i8 - 1),
            );
            while xs.start + 2 <= xs.end {
                let x = xs.start;
                let lb: [__m256i; P] = std::array::from_fn(|p| {
                    let two = (lp.as_ptr().add(p * w + x) as *const u16).read_unaligned();
                    _mm256_shuffle_epi8(_mm256_set1_epi16(two as i16), pair)
                });
                let base = rp.as_ptr().add(w - 2 - x);
                let mut acc = _mm256_setzero_si256();
                for (p, &l) in lb.iter().enumerate() {
                    let q = base.add(p * rs);
                    let v = _mm256_xor_si256(
                        _mm256_loadu2_m128i(q as *const __m128i, q.add(1) as *const __m128i),
                        l,
                    );
                    let lo = _mm256_shuffle_epi8(lut, _mm256_and_si256(v, low));
                    let hi =
                        _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16::<4>(v), low));
                    acc = _mm256_add_epi8(acc, _mm256_add_epi8(lo, hi));
                }
                if padded {
                    acc = _mm256_blendv_epi8(acc, invalid, pad);
                }
                _mm256_storeu_si256(out.as_mut_ptr().add(x * 16) as *mut __m256i, acc);
                xs.start += 2;
            }
        }
        for x in xs {
            let lb: [__m256i; P] = std::array::from_fn(|p| _mm256_set1_epi8(lp[p * w + x] as i8));
            let base = rp.as_ptr().add(w - 1 - x);
            let o = out.as_mut_ptr().add(x * ndp);
            let mut k = 0;
            while k < ndp {
                let mut acc = _mm256_setzero_si256();
                for (p, &l) in lb.iter().enumerate() {
                    let v = _mm256_xor_si256(
                        _mm256_loadu_si256(base.add(p * rs + k) as *const __m256i),
                        l,
                    );
                    let lo = _mm256_shuffle_epi8(lut, _mm256_and_si256(v, low));
                    let hi =
                        _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16::<4>(v), low));
                    acc = _mm256_add_epi8(acc, _mm256_add_epi8(lo, hi));
                }
                if padded && k == last {
                    // Lanes d = last + j ≥ nd (nd − last − 1 ∈ −1 … 30).
                    let t = _mm256_set1_epi8((nd - last) as i8 - 1);
                    acc = _mm256_blendv_epi8(acc, invalid, _mm256_cmpgt_epi8(byte_lanes(), t));
                }
                // Lanes d = k + j > x reach past the left border.
                let t = x as isize - k as isize;
                if BORDER && t < 31 {
                    let past = if t < 0 {
                        _mm256_set1_epi8(-1)
                    } else {
                        _mm256_cmpgt_epi8(byte_lanes(), _mm256_set1_epi8(t as i8))
                    };
                    acc = _mm256_blendv_epi8(acc, invalid, past);
                }
                _mm256_storeu_si256(o.add(k) as *mut __m256i, acc);
                k += 32;
            }
        }
    }
}

/// `matcher::row_scalar` with vectors: one row pass, `LANES` disparities per vector; `wide`:
/// the interior columns by `super::avx512`'s kernels (32 disparities per vector).
///
/// # Safety
/// AVX2 (and AVX-512 F/BW/VL/BITALG if `wide`); sizes checked (`RowIo::check`; every offset of
/// a `Step` lies inside them).
#[target_feature(enable = "avx2")]
pub(super) unsafe fn row(io: RowIo, wide: bool) {
    // SAFETY: forwarded (AVX2, and AVX-512 if wide).
    unsafe {
        match (io.shape.n(), wide) {
            (5, false) => row_n::<5, false>(io),
            (3, false) => row_n::<3, false>(io),
            (1, false) => row_n::<1, false>(io),
            (5, true) => row_n::<5, true>(io),
            (3, true) => row_n::<3, true>(io),
            (1, true) => row_n::<1, true>(io),
            _ => row_n::<0, false>(io),
        }
    }
}

/// [`row`] with `N = 2s + 1` known (`0`: any), `WIDE` its `wide`.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn row_n<const N: usize, const WIDE: bool>(mut io: RowIo) {
    io.check();
    io.prepare();
    let Shape { w, ndp, s, .. } = io.shape;
    let n = if N > 0 { N } else { io.shape.n() };
    assert!(n == io.shape.n());
    let mut a_slot = 2 * s % n;
    let [masked, plain] = io.interior();
    let mut x = 0;
    while x < w {
        if x == masked.start && x < plain.end && N > 0 {
            // The columns whose steps are all alike, with the disparity range known.
            let fused = io.fused.is_some();
            macro_rules! run {
                ($($k:literal)*) => {
                    match ndp / LANES {
                        $($k if WIDE => {
                            // SAFETY: AVX-512 (WIDE); the ranges are io.interior()'s, a_slot
                            // follows.
                            unsafe {
                                use super::avx512 as wide;
                                let a = wide::interior_n::<N, $k, true>(
                                    &mut io,
                                    masked.clone(),
                                    a_slot,
                                );
                                Some(if fused {
                                    wide::interior_fused::<N, $k>(&mut io, plain.clone(), a)
                                } else {
                                    wide::interior_n::<N, $k, false>(&mut io, plain.clone(), a)
                                })
                            }
                        })*
                        $($k => {
                            // SAFETY: AVX2; the ranges are io.interior()'s, a_slot follows.
                            unsafe {
                                let a = interior_n::<N, $k, true>(&mut io, masked.clone(), a_slot);
                                Some(if fused {
                                    interior_fused::<N, $k>(&mut io, plain.clone(), a)
                                } else {
                                    interior_n::<N, $k, false>(&mut io, plain.clone(), a)
                                })
                            }
                        })*
                        _ => None,
                    }
                };
            }
            if let Some(slot) = run!(1 2 3 4 5 6 7 8 9) {
                a_slot = slot;
                x = plain.end;
                continue;
            }
        }
        // (Its column x + s + r is not among the fused ones: those follow the plain interior.)
        // SAFETY: AVX2; a_slot is the ring slot of column x + s.
        unsafe { general_column::<N>(&mut io, x, a_slot) };
        a_slot = if a_slot + 1 == n { 0 } else { a_slot + 1 };
        x += 1;
    }
}

/// One column of [`row_n`] outside the interior (any row, any column, all cases by branches).
///
/// # Safety
/// AVX2; `io` checked, `a_slot` the ring slot of column `x + s`.
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn general_column<const N: usize>(io: &mut RowIo, x: usize, a_slot: usize) {
    let Shape { ndp, .. } = io.shape;
    let n = if N > 0 { N } else { io.shape.n() };
    let row_len = io.shape.row_len();
    let step = Step::new(io, x, a_slot);
    debug_assert!(step.a_out.max(step.a_prev) + ndp <= n * ndp);
    debug_assert!(step.h_column + n * ndp <= n * row_len && step.x_at + ndp <= row_len);
    debug_assert!(!step.update_v || step.v_add == step.v_col);
    // SAFETY: RowIo::check bounds every buffer; Step::new's offsets plus k + 16 ≤ ndp lie
    // inside them (slots < n, columns < w, right_at + ndp ≤ RIGHT_WAYS·right_len).
    unsafe {
        let ld = |p: *const u16| _mm256_loadu_si256(p as *const __m256i);
        let st = |p: *mut u16, v: __m256i| _mm256_storeu_si256(p as *mut __m256i, v);
        let ld8 = |p: *const u8| _mm_loadu_si128(p as *const __m128i);
        let (cp_add, cp_sub) = match io.v_rows {
            Some((a, s)) => (io.costs.as_ptr().add(a), io.costs.as_ptr().add(s)),
            None => (std::ptr::null(), std::ptr::null()),
        };
        let vp = io.vsum.as_mut_ptr();
        let bp = io.blocks.as_mut_ptr();
        let sp = io.shifted.as_mut_ptr();
        let (mp, lp) = (io.block.as_mut_ptr(), io.lanes.as_ptr());
        let (rc, ri) = (io.right_cost.as_mut_ptr(), io.right_index.as_mut_ptr());
        let mask = _mm256_set1_epi16((step.dmax + 1) as u16 as i16);
        let mut key = _mm256_set1_epi32(-1);
        let mut k = 0;
        while k < ndp {
            // H(y, x) of this chunk, when computed.
            let mut h = _mm256_setzero_si256();
            if io.do_h {
                let v_add = if step.update_v {
                    let at = step.v_col + k;
                    let diff = _mm_sub_epi8(ld8(cp_add.add(at)), ld8(cp_sub.add(at)));
                    // (v_add = v_col here.)
                    let v = _mm256_add_epi16(ld(vp.add(at)), _mm256_cvtepi8_epi16(diff));
                    st(vp.add(at), v);
                    v
                } else {
                    ld(vp.add(step.v_add + k))
                };
                let a = _mm256_sub_epi16(
                    _mm256_add_epi16(ld(bp.add(step.a_prev + k)), v_add),
                    ld(vp.add(step.v_sub + k)),
                );
                st(bp.add(step.a_out + k), a);
                h = a;
                for i in 0..n {
                    h = _mm256_min_epu16(h, ld(bp.add(i * ndp + k)));
                }
                st(sp.add(step.h_at + k), h);
            }
            if io.do_m {
                let at = step.x_at + k;
                // All n rows of the column (this row's just stored, if computed).
                let col = sp.add(step.h_column + k);
                let mut m = if io.do_h { h } else { ld(col) };
                for i in 0..n {
                    m = _mm256_min_epu16(m, ld(col.add(i * ndp)));
                }
                st(mp.add(at), m);
                let d = ld(lp.add(k));
                // Right winners: replace where m is strictly lower (the earlier, smaller
                // disparity kept on ties).
                let (rcost, rindex) = (rc.add(step.right_at + k), ri.add(step.right_at + k));
                let old = ld(rcost);
                let best = _mm256_min_epu16(old, m);
                let keep = _mm256_cmpeq_epi16(best, old);
                st(rcost, best);
                st(rindex, _mm256_blendv_epi8(d, ld(rindex), keep));
                if step.decide {
                    let mm = if step.mask {
                        // Lanes d > dmax get cost 0xffff: keys above every candidate's.
                        _mm256_or_si256(m, _mm256_cmpeq_epi16(_mm256_max_epu16(d, mask), d))
                    } else {
                        m
                    };
                    // (d, cost) word pairs are the u32 keys (cost ≪ 16) | d.
                    key = _mm256_min_epu32(key, _mm256_unpacklo_epi16(d, mm));
                    key = _mm256_min_epu32(key, _mm256_unpackhi_epi16(d, mm));
                }
            }
            k += LANES;
        }
        if io.do_m {
            // (u32::MAX when there is no decision: no lane competed.)
            *io.left_key.get_unchecked_mut(x) = min_key(key);
        }
    }
}

/// The lowest of the eight `u32` lanes.
#[target_feature(enable = "avx2")]
#[inline]
fn min_key(key: __m256i) -> u32 {
    let k4 = _mm_min_epu32(
        _mm256_castsi256_si128(key),
        _mm256_extracti128_si256::<1>(key),
    );
    let k2 = _mm_min_epu32(k4, _mm_shuffle_epi32::<0b01_00_11_10>(k4));
    let k1 = _mm_min_epu32(k2, _mm_shuffle_epi32::<0b10_11_00_01>(k2));
    _mm_cvtsi128_si32(k1) as u32
}

/// The interior columns of a row (`RowIo::interior`; `MASK`: the first part, where the
/// disparities above `x − r` do not compete), with `n = N` and `ndp = 16·K` known: every stage
/// of [`row_n`]'s column step, no branches, constant offsets into the block-sum ring and the
/// chunk loop unrolled. Returns the block-sum slot after the last column.
///
/// # Safety
/// AVX2; `io` checked, `xs` inside `io.interior()[MASK as usize ^ 1]`, `a_slot` the ring slot
/// of column `xs.start + s`.
#[target_feature(enable = "avx2")]
unsafe fn interior_n<const N: usize, const K: usize, const MASK: bool>(
    io: &mut RowIo,
    xs: std::ops::Range<usize>,
    mut a_slot: usize,
) -> usize {
    let ndp = K * LANES;
    let Shape { w, r, s, .. } = io.shape;
    assert!(N == io.shape.n() && ndp == io.shape.ndp && N > 0 && K > 0);
    let inside = &io.interior()[if MASK { 0 } else { 1 }];
    assert!(xs.is_empty() || (xs.start >= inside.start && xs.end <= inside.end));
    assert!(a_slot < N);
    let (c_add, c_sub) = io.v_rows.expect("interior rows have cost rows");
    let way = io.shape.right_len();
    // SAFETY: with x in the interior, every column index below is < w (x + s + r ≤ w − 1,
    // x + s − r − 1 ≥ 0), ring slots < N, and RowIo::check bounds the buffers.
    unsafe {
        let ld = |p: *const u16| _mm256_loadu_si256(p as *const __m256i);
        let st = |p: *mut u16, v: __m256i| _mm256_storeu_si256(p as *mut __m256i, v);
        let ld8 = |p: *const u8| _mm_loadu_si128(p as *const __m128i);
        let (ca, cs) = (io.costs.as_ptr().add(c_add), io.costs.as_ptr().add(c_sub));
        let vp = io.vsum.as_mut_ptr();
        let bp = io.blocks.as_mut_ptr();
        let sp = io.shifted.as_mut_ptr();
        let mp = io.block.as_mut_ptr();
        let (rc, ri) = (io.right_cost.as_mut_ptr(), io.right_index.as_mut_ptr());
        // (Locals, so that the stores through the buffers' pointers cannot be thought to
        // change them.)
        let (kp, h_slot) = (io.left_key.as_mut_ptr(), io.h_slot);
        let lanes = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        for x in xs {
            let vc = (x + s + r) * ndp;
            let vs = (x + s - r - 1) * ndp;
            let a_out = a_slot * ndp;
            let a_prev = if a_slot == 0 { N - 1 } else { a_slot - 1 } * ndp;
            a_slot = if a_slot + 1 == N { 0 } else { a_slot + 1 };
            let column = x * N * ndp;
            let h_at = column + h_slot * ndp;
            let at = x * ndp;
            let right = (x % RIGHT_WAYS) * way + (w - 1 - x);
            // (MASK: lanes d > x − r get cost 0xffff: keys above every candidate's.)
            let first_masked = _mm256_set1_epi16((x - r + 1) as u16 as i16);
            let mut key = _mm256_set1_epi32(-1);
            for c in 0..K {
                let k = c * LANES;
                let diff = _mm_sub_epi8(ld8(ca.add(vc + k)), ld8(cs.add(vc + k)));
                let v = _mm256_add_epi16(ld(vp.add(vc + k)), _mm256_cvtepi8_epi16(diff));
                st(vp.add(vc + k), v);
                let a = _mm256_sub_epi16(
                    _mm256_add_epi16(ld(bp.add(a_prev + k)), v),
                    ld(vp.add(vs + k)),
                );
                st(bp.add(a_out + k), a);
                let mut h = a;
                for i in 0..N {
                    h = _mm256_min_epu16(h, ld(bp.add(i * ndp + k)));
                }
                st(sp.add(h_at + k), h);
                // All N rows of the column at constant offsets (this row's just stored: the
                // minimum does not mind, and no offsets need registers).
                let mut m = h;
                for i in 0..N {
                    m = _mm256_min_epu16(m, ld(sp.add(column + i * ndp + k)));
                }
                st(mp.add(at + k), m);
                let d = _mm256_add_epi16(lanes, _mm256_set1_epi16(k as i16));
                let (rcost, rindex) = (rc.add(right + k), ri.add(right + k));
                let old = ld(rcost);
                let best = _mm256_min_epu16(old, m);
                let keep = _mm256_cmpeq_epi16(best, old);
                st(rcost, best);
                st(rindex, _mm256_blendv_epi8(d, ld(rindex), keep));
                let mm = if MASK {
                    _mm256_or_si256(m, _mm256_cmpeq_epi16(_mm256_max_epu16(d, first_masked), d))
                } else {
                    m
                };
                key = _mm256_min_epu32(key, _mm256_unpacklo_epi16(d, mm));
                key = _mm256_min_epu32(key, _mm256_unpackhi_epi16(d, mm));
            }
            *kp.add(x) = min_key(key);
        }
    }
    a_slot
}

/// `matcher::decide_row` eight pixels per step: the keys' disparities and costs, the costs
/// beside the winner and the right winners gathered, the parabola and the left-right check
/// as masks, the same floating-point operations in the same order; the last `w mod 8` pixels
/// through `row::decide_pixel`.
///
/// # Safety
/// AVX2; sizes checked.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn decide_row(io: DecideIo) {
    let Shape { w, nd, ndp, r, .. } = io.shape;
    assert!(io.left_key.len() >= w && io.dst.len() >= w);
    // The gathers read 32 bits at each 16-bit element.
    assert!(io.block.len() > w * ndp && io.right_best.len() > w);
    assert!(w * ndp < i32::MAX as usize / 2);
    let w8 = w / 8 * 8;
    // SAFETY: gathered indices: x·ndp + max(d_L − 1, 0) and x·ndp + min(d_L + 1, ndp − 1)
    // (d_L = 0 where there is no key) < w·ndp, read with one element to spare;
    // w − 1 − x + d_L ≤ w − 1 (d_L ≤ x − r) likewise; loads and stores at x + 8 ≤ w.
    unsafe {
        let lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let none = _mm256_set1_epi32(-1);
        let low = _mm256_set1_epi32(0xffff);
        let one = _mm256_set1_epi32(1);
        let zero = _mm256_setzero_si256();
        let nan = _mm256_set1_ps(f32::NAN);
        let (half, minus_half, two) = (
            _mm256_set1_ps(0.5),
            _mm256_set1_ps(-0.5),
            _mm256_set1_ps(2.0),
        );
        let check = io.max_lr_difference >= 0.0;
        let max_lr = _mm256_set1_ps(io.max_lr_difference);
        let sign = _mm256_set1_ps(-0.0);
        let block = io.block.as_ptr() as *const i32;
        let right = io.right_best.as_ptr() as *const i32;
        let mut x = 0;
        while x < w8 {
            let key = _mm256_loadu_si256(io.left_key.as_ptr().add(x) as *const __m256i);
            let valid = _mm256_xor_si256(_mm256_cmpeq_epi32(key, none), none);
            let bd = _mm256_and_si256(_mm256_and_si256(key, low), valid);
            let best = _mm256_srli_epi32::<16>(key);
            let xs = _mm256_add_epi32(_mm256_set1_epi32(x as i32), lanes);
            let dmax = _mm256_min_epi32(
                _mm256_max_epi32(_mm256_sub_epi32(xs, _mm256_set1_epi32(r as i32)), zero),
                _mm256_set1_epi32(nd as i32 - 1),
            );
            let at = _mm256_mullo_epi32(xs, _mm256_set1_epi32(ndp as i32));
            let lo = _mm256_add_epi32(at, _mm256_max_epi32(_mm256_sub_epi32(bd, one), zero));
            let hi = _mm256_add_epi32(
                at,
                _mm256_min_epi32(_mm256_add_epi32(bd, one), _mm256_set1_epi32(ndp as i32 - 1)),
            );
            let c0 = _mm256_cvtepi32_ps(_mm256_and_si256(
                _mm256_i32gather_epi32::<2>(block, lo),
                low,
            ));
            let c2 = _mm256_cvtepi32_ps(_mm256_and_si256(
                _mm256_i32gather_epi32::<2>(block, hi),
                low,
            ));
            let c1 = _mm256_cvtepi32_ps(best);
            let bdf = _mm256_cvtepi32_ps(bd);
            let den = _mm256_add_ps(_mm256_sub_ps(c0, _mm256_mul_ps(two, c1)), c2);
            let q = _mm256_div_ps(_mm256_sub_ps(c0, c2), _mm256_mul_ps(two, den));
            // clamp(−0.5, 0.5) (q is finite where it is used).
            let q = _mm256_max_ps(_mm256_min_ps(q, half), minus_half);
            let fit = _mm256_and_si256(
                _mm256_and_si256(_mm256_cmpgt_epi32(bd, zero), _mm256_cmpgt_epi32(dmax, bd)),
                _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GT_OQ>(den, _mm256_setzero_ps())),
            );
            let dsub = _mm256_blendv_ps(bdf, _mm256_add_ps(bdf, q), _mm256_castsi256_ps(fit));
            let mut ok = valid;
            if check {
                let ri =
                    _mm256_add_epi32(_mm256_sub_epi32(_mm256_set1_epi32(w as i32 - 1), xs), bd);
                let rb = _mm256_cvtepi32_ps(_mm256_and_si256(
                    _mm256_i32gather_epi32::<2>(right, ri),
                    low,
                ));
                let diff = _mm256_andnot_ps(sign, _mm256_sub_ps(rb, bdf));
                let within = _mm256_cmp_ps::<_CMP_LE_OQ>(diff, max_lr);
                ok = _mm256_and_si256(ok, _mm256_castps_si256(within));
            }
            let out = _mm256_blendv_ps(nan, dsub, _mm256_castsi256_ps(ok));
            _mm256_storeu_ps(io.dst.as_mut_ptr().add(x), out);
            x += 8;
        }
    }
    for x in w8..w {
        io.dst[x] = decide_pixel(
            &io.shape,
            x,
            io.left_key[x],
            io.block,
            io.right_best,
            io.max_lr_difference,
        );
    }
}

/// [`interior_n`]'s plain columns on a row with a new cost row: each column first computes
/// the pixel costs of column `x + s + r` of that row from the census planes (`RowIo::fused`)
/// into the ring, which the vertical sums then read straight back (from L1); the byte-heavy
/// cost arithmetic and the load-heavy aggregation share the column.
///
/// # Safety
/// AVX2; `io` checked, `xs` = `io.interior()[1]`, `io.fused` its columns shifted by `s + r`,
/// `a_slot` the ring slot of column `xs.start + s`.
#[target_feature(enable = "avx2")]
unsafe fn interior_fused<const N: usize, const K: usize>(
    io: &mut RowIo,
    xs: std::ops::Range<usize>,
    mut a_slot: usize,
) -> usize {
    let ndp = K * LANES;
    let Shape { w, r, s, .. } = io.shape;
    assert!(N == io.shape.n() && ndp == io.shape.ndp && N > 0 && K > 0);
    let inside = &io.interior()[1];
    assert!(xs.is_empty() || (xs.start >= inside.start && xs.end <= inside.end));
    assert!(a_slot < N);
    let (c_add, c_sub) = io.v_rows.expect("interior rows have cost rows");
    let nd = io.shape.nd;
    let census = io.fused.as_ref().expect("fused costs");
    assert!(census.columns == (xs.start + s + r..xs.end + s + r) && xs.start + s + r >= nd);
    let (lp, rp, rs) = (
        census.left_planes.as_ptr(),
        census.right_planes.as_ptr(),
        census.right_stride,
    );
    // The last 32-lane group of a pixel's costs holds the padding lanes d ≥ nd.
    let groups = K.div_ceil(2);
    let pad_from = nd as isize - (groups as isize - 1) * 32;
    let way = io.shape.right_len();
    // SAFETY: with x in the interior, every column index below is < w (x + s + r ≤ w − 1,
    // x + s − r − 1 ≥ 0), ring slots < N, and RowIo::check bounds the buffers.
    unsafe {
        let ld = |p: *const u16| _mm256_loadu_si256(p as *const __m256i);
        let st = |p: *mut u16, v: __m256i| _mm256_storeu_si256(p as *mut __m256i, v);
        let ld8 = |p: *const u8| _mm_loadu_si128(p as *const __m128i);
        let ca = io.costs.as_mut_ptr().add(c_add);
        let cs = io.costs.as_ptr().add(c_sub);
        let vp = io.vsum.as_mut_ptr();
        let bp = io.blocks.as_mut_ptr();
        let sp = io.shifted.as_mut_ptr();
        let mp = io.block.as_mut_ptr();
        let (rc, ri) = (io.right_cost.as_mut_ptr(), io.right_index.as_mut_ptr());
        // (Locals, so that the stores through the buffers' pointers cannot be thought to
        // change them.)
        let (kp, h_slot) = (io.left_key.as_mut_ptr(), io.h_slot);
        let lanes = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let byte_lanes = _mm256_setr_epi8(
            0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23,
            24, 25, 26, 27, 28, 29, 30, 31,
        );
        for x in xs {
            // The costs of pixel x + s + r of the new row (no disparity past the border:
            // x + s + r ≥ nd), 32 disparities per group as `costs` does, into the ring.
            let xc = x + s + r;
            let lb: [__m256i; 6] =
                std::array::from_fn(|p| _mm256_set1_epi8(*lp.add(p * w + xc) as i8));
            let base = rp.add(w - 1 - xc);
            for g in 0..groups {
                let mut acc = _mm256_setzero_si256();
                for (p, &l) in lb.iter().enumerate() {
                    let v = _mm256_xor_si256(
                        _mm256_loadu_si256(base.add(p * rs + 32 * g) as *const __m256i),
                        l,
                    );
                    acc = _mm256_add_epi8(acc, popcount_bytes(v));
                }
                if g + 1 == groups && pad_from < 32 {
                    let past = _mm256_cmpgt_epi8(byte_lanes, _mm256_set1_epi8(pad_from as i8 - 1));
                    acc = _mm256_blendv_epi8(acc, _mm256_set1_epi8(INVALID_COST as i8), past);
                }
                let o = ca.add(xc * ndp + 32 * g);
                if 2 * g + 1 < K {
                    _mm256_storeu_si256(o as *mut __m256i, acc);
                } else {
                    _mm_storeu_si128(o as *mut __m128i, _mm256_castsi256_si128(acc));
                }
            }
            let vc = (x + s + r) * ndp;
            let vs = (x + s - r - 1) * ndp;
            let a_out = a_slot * ndp;
            let a_prev = if a_slot == 0 { N - 1 } else { a_slot - 1 } * ndp;
            a_slot = if a_slot + 1 == N { 0 } else { a_slot + 1 };
            let column = x * N * ndp;
            let h_at = column + h_slot * ndp;
            let at = x * ndp;
            let right = (x % RIGHT_WAYS) * way + (w - 1 - x);
            let mut key = _mm256_set1_epi32(-1);
            for c in 0..K {
                let k = c * LANES;
                let diff = _mm_sub_epi8(ld8(ca.add(vc + k)), ld8(cs.add(vc + k)));
                let v = _mm256_add_epi16(ld(vp.add(vc + k)), _mm256_cvtepi8_epi16(diff));
                st(vp.add(vc + k), v);
                let a = _mm256_sub_epi16(
                    _mm256_add_epi16(ld(bp.add(a_prev + k)), v),
                    ld(vp.add(vs + k)),
                );
                st(bp.add(a_out + k), a);
                let mut h = a;
                for i in 0..N {
                    h = _mm256_min_epu16(h, ld(bp.add(i * ndp + k)));
                }
                st(sp.add(h_at + k), h);
                // All N rows of the column at constant offsets (this row's just stored: the
                // minimum does not mind, and no offsets need registers).
                let mut m = h;
                for i in 0..N {
                    m = _mm256_min_epu16(m, ld(sp.add(column + i * ndp + k)));
                }
                st(mp.add(at + k), m);
                let d = _mm256_add_epi16(lanes, _mm256_set1_epi16(k as i16));
                let (rcost, rindex) = (rc.add(right + k), ri.add(right + k));
                let old = ld(rcost);
                let best = _mm256_min_epu16(old, m);
                let keep = _mm256_cmpeq_epi16(best, old);
                st(rcost, best);
                st(rindex, _mm256_blendv_epi8(d, ld(rindex), keep));
                key = _mm256_min_epu32(key, _mm256_unpacklo_epi16(d, m));
                key = _mm256_min_epu32(key, _mm256_unpackhi_epi16(d, m));
            }
            *kp.add(x) = min_key(key);
        }
    }
    a_slot
}

/// Byte popcounts by the `pshufb` nibble table.
#[target_feature(enable = "avx2")]
#[inline]
fn popcount_bytes(v: __m256i) -> __m256i {
    let lut = _mm256_setr_epi8(
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3,
        3, 4,
    );
    let low = _mm256_set1_epi8(0x0f);
    _mm256_add_epi8(
        _mm256_shuffle_epi8(lut, _mm256_and_si256(v, low)),
        _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16::<4>(v), low)),
    )
}
