//! AVX-512 kernels of the census matcher's interior columns: [`super::avx2`]'s `interior_n`
//! and `interior_fused` with 32 disparities per vector instead of 16, and the fused pixel
//! costs 64 per vector with BITALG's byte popcount instead of the nibble table. The row
//! driver, the border columns and the decisions stay AVX2's. Same operations on the same
//! integers, so the same results bit for bit (tested against the AVX2 and scalar paths).
//!
//! Why only these: they are half of a stereo frame's cycles (KITTI, `perf`), load- and
//! store-bound on `u16` lanes, so twice the lanes is nearly half the instructions (measured:
//! a KITTI pair 1.3× faster, the rings of the shifted windows and pixel costs living in L2).
//! An odd number of 16-lane chunks ends in one 256-bit chunk (plain loads and stores, not
//! masked ones, which the next column's loads could not forward from).
//!
//! Every function here needs a CPU with AVX-512 F, BW, VL and BITALG (`crate::simd::avx512()`).

use std::arch::x86_64::*;

use super::row::{INVALID_COST, LANES, RIGHT_WAYS, RowIo, Shape};

/// The buffers and constants of a row's interior columns, as raw pointers (the kernels' loads
/// and stores alias nothing the borrow checker would see).
struct Interior {
    /// Cost rows entering and leaving the vertical sums (one base pointer: the fused kernel
    /// writes the entering row through `ca`).
    ca: *mut u8,
    cs: *const u8,
    vp: *mut u16,
    bp: *mut u16,
    sp: *mut u16,
    mp: *mut u16,
    rc: *mut u16,
    ri: *mut u16,
    kp: *mut u32,
    h_slot: usize,
    way: usize,
}

impl Interior {
    /// `io`'s pointers, for the interior columns `xs` (`MASK`: the first part); the checks of
    /// `avx2::interior_n`.
    fn new<const N: usize, const K: usize>(
        io: &mut RowIo,
        xs: &std::ops::Range<usize>,
        mask: bool,
        a_slot: usize,
    ) -> Self {
        assert!(N == io.shape.n() && K * LANES == io.shape.ndp && N > 0 && K > 0);
        let inside = &io.interior()[if mask { 0 } else { 1 }];
        assert!(xs.is_empty() || (xs.start >= inside.start && xs.end <= inside.end));
        assert!(a_slot < N);
        let (c_add, c_sub) = io.v_rows.expect("interior rows have cost rows");
        let row = io.shape.row_len();
        assert!(c_add.max(c_sub) + row <= io.costs.len());
        let costs = io.costs.as_mut_ptr();
        Interior {
            // SAFETY: inside the ring (asserted just above).
            ca: unsafe { costs.add(c_add) },
            cs: unsafe { costs.add(c_sub) },
            vp: io.vsum.as_mut_ptr(),
            bp: io.blocks.as_mut_ptr(),
            sp: io.shifted.as_mut_ptr(),
            mp: io.block.as_mut_ptr(),
            rc: io.right_cost.as_mut_ptr(),
            ri: io.right_index.as_mut_ptr(),
            kp: io.left_key.as_mut_ptr(),
            h_slot: io.h_slot,
            way: io.shape.right_len(),
        }
    }
}

/// `avx2::interior_n` 32 disparities per vector.
///
/// # Safety
/// AVX-512 F/BW/VL/BITALG; as `avx2::interior_n`.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bitalg")]
pub(super) unsafe fn interior_n<const N: usize, const K: usize, const MASK: bool>(
    io: &mut RowIo,
    xs: std::ops::Range<usize>,
    a_slot: usize,
) -> usize {
    // SAFETY: forwarded.
    unsafe { columns::<N, K, MASK, false>(io, xs, a_slot) }
}

/// `avx2::interior_fused` 32 disparities per vector, the pixel costs of the new row 64 per
/// vector (BITALG's byte popcount).
///
/// # Safety
/// AVX-512 F/BW/VL/BITALG; as `avx2::interior_fused`.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bitalg")]
pub(super) unsafe fn interior_fused<const N: usize, const K: usize>(
    io: &mut RowIo,
    xs: std::ops::Range<usize>,
    a_slot: usize,
) -> usize {
    // SAFETY: forwarded.
    unsafe { columns::<N, K, false, true>(io, xs, a_slot) }
}

/// The interior columns `xs` (one loop, so that the column step is compiled into it with its
/// constant offsets), `a_slot` the block-sum ring slot of column `xs.start + s`; `FUSED`: each
/// column first computes the pixel costs of column `x + s + r` of the new row into the ring.
///
/// # Safety
/// AVX-512 F/BW/VL/BITALG; as [`interior_n`] / [`interior_fused`].
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bitalg")]
unsafe fn columns<const N: usize, const K: usize, const MASK: bool, const FUSED: bool>(
    io: &mut RowIo,
    xs: std::ops::Range<usize>,
    mut a_slot: usize,
) -> usize {
    let ndp = K * LANES;
    let Shape { w, r, s, nd, .. } = io.shape;
    let (lp, rp, rs) = match (FUSED, io.fused.as_ref()) {
        (true, Some(census)) => {
            assert!(census.columns == (xs.start + s + r..xs.end + s + r) && xs.start + s + r >= nd);
            (
                census.left_planes.as_ptr(),
                census.right_planes.as_ptr(),
                census.right_stride,
            )
        }
        (true, None) => panic!("fused costs"),
        (false, _) => (std::ptr::null(), std::ptr::null(), 0),
    };
    let p = Interior::new::<N, K>(io, &xs, MASK, a_slot);
    let ca = p.ca;
    // The costs come in 64-lane groups, then 32-lane ones as avx2::interior_fused's (the last
    // stores 16 lanes where ndp is odd in 16s); the padding lanes d ≥ nd (in the last group)
    // get the invalid cost.
    let full = ndp / 64;
    // SAFETY: (FUSED) as avx2::interior_fused's: pixel xc = x + s + r < w of the new row, its
    // ndp cost bytes in the ring; the right planes are read up to ndp bytes past w − 1 − xc,
    // which RowIo::check bounds. The column step below: see there.
    unsafe {
        let byte_lanes = _mm512_set_epi8(
            63, 62, 61, 60, 59, 58, 57, 56, 55, 54, 53, 52, 51, 50, 49, 48, 47, 46, 45, 44, 43, 42,
            41, 40, 39, 38, 37, 36, 35, 34, 33, 32, 31, 30, 29, 28, 27, 26, 25, 24, 23, 22, 21, 20,
            19, 18, 17, 16, 15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0,
        );
        let invalid = _mm512_set1_epi8(INVALID_COST as i8);
        // Lanes at or past nd, relative to a group starting at disparity o.
        let padding = |o: usize| {
            _mm512_cmpgt_epi8_mask(
                byte_lanes,
                _mm512_set1_epi8((nd as isize - o as isize - 1).clamp(-1, 127) as i8),
            )
        };
        for x in xs {
            if FUSED {
                let xc = x + s + r;
                let lb: [__m512i; 6] =
                    std::array::from_fn(|q| _mm512_set1_epi8(*lp.add(q * w + xc) as i8));
                let base = rp.add(w - 1 - xc);
                for g in 0..full {
                    let o = 64 * g;
                    let mut acc = _mm512_setzero_si512();
                    for (q, &l) in lb.iter().enumerate() {
                        let v = _mm512_xor_si512(
                            _mm512_loadu_si512(base.add(q * rs + o) as *const _),
                            l,
                        );
                        acc = _mm512_add_epi8(acc, _mm512_popcnt_epi8(v));
                    }
                    if nd < o + 64 {
                        acc = _mm512_mask_blend_epi8(padding(o), acc, invalid);
                    }
                    _mm512_storeu_si512(ca.add(xc * ndp + o) as *mut _, acc);
                }
                for o in (64 * full..ndp).step_by(32) {
                    let mut acc = _mm256_setzero_si256();
                    for (q, &l) in lb.iter().enumerate() {
                        let v = _mm256_xor_si256(
                            _mm256_loadu_si256(base.add(q * rs + o) as *const __m256i),
                            _mm512_castsi512_si256(l),
                        );
                        acc = _mm256_add_epi8(acc, _mm256_popcnt_epi8(v));
                    }
                    if nd < o + 32 {
                        let pad = padding(o) as u32;
                        acc = _mm256_mask_blend_epi8(pad, acc, _mm512_castsi512_si256(invalid));
                    }
                    let to = ca.add(xc * ndp + o);
                    if o + 32 <= ndp {
                        _mm256_storeu_si256(to as *mut __m256i, acc);
                    } else {
                        _mm_storeu_si128(to as *mut __m128i, _mm256_castsi256_si128(acc));
                    }
                }
            }
            let vc = (x + s + r) * ndp;
            let vs = (x + s - r - 1) * ndp;
            let a_out = a_slot * ndp;
            let a_prev = if a_slot == 0 { N - 1 } else { a_slot - 1 } * ndp;
            let column = x * N * ndp;
            let h_at = column + p.h_slot * ndp;
            let at = x * ndp;
            let right = (x % RIGHT_WAYS) * p.way + (w - 1 - x);
            // The column step: the offsets are avx2::interior_n's (every column index < w, ring
            // slots < N, RowIo::check bounds the buffers), read and written 32 lanes at a time
            // up to ndp.
            {
                let ld = |p: *const u16| _mm512_loadu_si512(p as *const _);
                let st = |p: *mut u16, v: __m512i| _mm512_storeu_si512(p as *mut _, v);
                let ld8 = |p: *const u8| _mm256_loadu_si256(p as *const __m256i);
                let lanes = _mm512_set_epi16(
                    31, 30, 29, 28, 27, 26, 25, 24, 23, 22, 21, 20, 19, 18, 17, 16, 15, 14, 13, 12,
                    11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0,
                );
                // (MASK: lanes d > x − r get cost 0xffff: keys above every candidate's.)
                let first_masked = _mm512_set1_epi16((x - r + 1) as u16 as i16);
                let mut key = _mm512_set1_epi32(-1);
                for c in 0..K / 2 {
                    let k = c * 2 * LANES;
                    let diff = _mm256_sub_epi8(ld8(p.ca.add(vc + k)), ld8(p.cs.add(vc + k)));
                    let v = _mm512_add_epi16(ld(p.vp.add(vc + k)), _mm512_cvtepi8_epi16(diff));
                    st(p.vp.add(vc + k), v);
                    let a = _mm512_sub_epi16(
                        _mm512_add_epi16(ld(p.bp.add(a_prev + k)), v),
                        ld(p.vp.add(vs + k)),
                    );
                    st(p.bp.add(a_out + k), a);
                    let mut h = a;
                    for i in 0..N {
                        h = _mm512_min_epu16(h, ld(p.bp.add(i * ndp + k)));
                    }
                    st(p.sp.add(h_at + k), h);
                    let mut m = h;
                    for i in 0..N {
                        m = _mm512_min_epu16(m, ld(p.sp.add(column + i * ndp + k)));
                    }
                    st(p.mp.add(at + k), m);
                    let d = _mm512_add_epi16(lanes, _mm512_set1_epi16(k as i16));
                    let (rcost, rindex) = (p.rc.add(right + k), p.ri.add(right + k));
                    let old = ld(rcost);
                    let best = _mm512_min_epu16(old, m);
                    // Replace where m is strictly lower (the earlier, smaller disparity kept on
                    // ties).
                    let keep = _mm512_cmpeq_epi16_mask(best, old);
                    st(rcost, best);
                    st(rindex, _mm512_mask_blend_epi16(keep, d, ld(rindex)));
                    let mm = if MASK {
                        let over = _mm512_cmpge_epu16_mask(d, first_masked);
                        _mm512_mask_mov_epi16(m, over, _mm512_set1_epi16(-1))
                    } else {
                        m
                    };
                    // (d, cost) word pairs are the u32 keys (cost ≪ 16) | d.
                    key = _mm512_min_epu32(key, _mm512_unpacklo_epi16(d, mm));
                    key = _mm512_min_epu32(key, _mm512_unpackhi_epi16(d, mm));
                }
                if K % 2 == 1 {
                    // The last 16 lanes, as avx2::interior_n does them.
                    let k = (K - 1) * LANES;
                    let ld = |p: *const u16| _mm256_loadu_si256(p as *const __m256i);
                    let st = |p: *mut u16, v: __m256i| _mm256_storeu_si256(p as *mut __m256i, v);
                    let ld8 = |p: *const u8| _mm_loadu_si128(p as *const __m128i);
                    let diff = _mm_sub_epi8(ld8(p.ca.add(vc + k)), ld8(p.cs.add(vc + k)));
                    let v = _mm256_add_epi16(ld(p.vp.add(vc + k)), _mm256_cvtepi8_epi16(diff));
                    st(p.vp.add(vc + k), v);
                    let a = _mm256_sub_epi16(
                        _mm256_add_epi16(ld(p.bp.add(a_prev + k)), v),
                        ld(p.vp.add(vs + k)),
                    );
                    st(p.bp.add(a_out + k), a);
                    let mut h = a;
                    for i in 0..N {
                        h = _mm256_min_epu16(h, ld(p.bp.add(i * ndp + k)));
                    }
                    st(p.sp.add(h_at + k), h);
                    let mut m = h;
                    for i in 0..N {
                        m = _mm256_min_epu16(m, ld(p.sp.add(column + i * ndp + k)));
                    }
                    st(p.mp.add(at + k), m);
                    let d = _mm256_add_epi16(
                        _mm512_castsi512_si256(lanes),
                        _mm256_set1_epi16(k as i16),
                    );
                    let (rcost, rindex) = (p.rc.add(right + k), p.ri.add(right + k));
                    let old = ld(rcost);
                    let best = _mm256_min_epu16(old, m);
                    let keep = _mm256_cmpeq_epi16_mask(best, old);
                    st(rcost, best);
                    st(rindex, _mm256_mask_blend_epi16(keep, d, ld(rindex)));
                    let mm = if MASK {
                        let over = _mm256_cmpge_epu16_mask(d, _mm512_castsi512_si256(first_masked));
                        _mm256_mask_mov_epi16(m, over, _mm256_set1_epi16(-1))
                    } else {
                        m
                    };
                    let tail = _mm256_min_epu32(
                        _mm256_unpacklo_epi16(d, mm),
                        _mm256_unpackhi_epi16(d, mm),
                    );
                    key =
                        _mm512_min_epu32(key, _mm512_inserti64x4::<0>(_mm512_set1_epi32(-1), tail));
                }
                *p.kp.add(x) = _mm512_reduce_min_epu32(key);
            }
            a_slot = if a_slot + 1 == N { 0 } else { a_slot + 1 };
        }
    }
    a_slot
}
