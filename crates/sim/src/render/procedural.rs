//! Procedural primitives for the textures: integer hashing, band-limited value noise and
//! fractal sums of it, anti-aliased step functions.
//!
//! Everything here is a pure function of its arguments and a seed, so a texel evaluated in any
//! order, on any thread, has the same value (the renderer's determinism rests on that).
//!
//! Band-limiting: a texel of size `τ` (metres) can only represent detail of wavelength `≥ 2τ`
//! (Nyquist). [`fbm`] drops octaves whose wavelength is below `2τ` and fades the last one in
//! over one octave, so every mip level of a texture is the same function, low-pass filtered to
//! that level; [`smooth_step_aa`] blurs an edge over one texel (the box filter of a step).

/// SplitMix64 finaliser: a bijective 64-bit mix with good avalanche (Steele et al. 2014).
#[inline(always)]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Hash of a seed and two lattice coordinates.
#[inline(always)]
pub fn hash2(seed: u64, x: i64, y: i64) -> u64 {
    mix64(
        seed ^ (x as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ (y as u64)
                .wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
                .rotate_left(31),
    )
}

/// `⌊x⌋` as an integer, without a call into libm (the default x86-64 target has no `roundsd`);
/// exact for `|x| < 2⁶³`.
#[inline(always)]
pub fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x { i - 1 } else { i }
}

/// A fast `log₂ x` for `x > 0`: the exponent plus a cubic fit of `log₂ m` on the mantissa
/// `m ∈ [1, 2)`, exact at `m = 1` and `m = 2` (maximum error 0.9·10⁻³; used only to pick and blend
/// mip levels).
#[inline(always)]
pub fn fast_log2(x: f64) -> f64 {
    let bits = x.to_bits();
    let e = ((bits >> 52) & 0x7ff) as i64 - 1023;
    let m = f64::from_bits((bits & 0x000f_ffff_ffff_ffff) | 0x3ff0_0000_0000_0000) - 1.0;
    // log₂(1 + m) ≈ m·(c₁ + m·(c₂ + m·c₃)), exact at m = 0 and m = 1.
    let p = m * (1.422_865 + m * (-0.582_085 + m * 0.159_220));
    e as f64 + p
}

/// Hash of a seed and one integer.
#[inline(always)]
pub fn hash1(seed: u64, x: u64) -> u64 {
    mix64(seed ^ mix64(x.wrapping_add(0x632b_e59b_d9b4_e019)))
}

/// The upper 53 bits of a hash as a number in `[0, 1)`.
#[inline(always)]
pub fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A number in `[lo, hi)` from a hash.
#[inline(always)]
pub fn range(h: u64, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * unit(h)
}

/// Quintic fade `6t⁵ − 15t⁴ + 10t³` (C² continuous interpolation weights, Perlin 2002).
#[inline(always)]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Value noise with unit lattice spacing: lattice values uniform in `[−1, 1]`, interpolated
/// with the quintic fade. Its spectrum is concentrated at wavelengths `≳ 1`.
#[inline]
pub fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (ix, iy) = (floor_i64(x), floor_i64(y));
    let (fx, fy) = (fade(x - ix as f64), fade(y - iy as f64));
    // A lattice hash with the products shared between the four corners: one multiply and two
    // xor-shifts per corner on top of `x·K₁ + y·K₂ + seed` (half of `mix64`'s work; good
    // enough for noise, whose lattice values need no cryptographic independence).
    let (hx0, hy0) = (
        (ix as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
        (iy as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f),
    );
    let (hx1, hy1) = (
        hx0.wrapping_add(0x9e37_79b9_7f4a_7c15),
        hy0.wrapping_add(0xc2b2_ae3d_27d4_eb4f),
    );
    let v = |hx: u64, hy: u64| {
        let mut h = hx.wrapping_add(hy).wrapping_add(seed);
        h = (h ^ (h >> 29)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        h ^= h >> 32;
        2.0 * unit(h) - 1.0
    };
    let (v00, v10, v01, v11) = (v(hx0, hy0), v(hx1, hy0), v(hx0, hy1), v(hx1, hy1));
    let a = v00 + fx * (v10 - v00);
    let b = v01 + fx * (v11 - v01);
    a + fy * (b - a)
}

/// Fractal sum of value noise ("fBm") from wavelength `largest` down to `smallest` (metres),
/// each octave half the wavelength of the previous with amplitude multiplied by `gain`;
/// octaves shorter than `2·texel` are dropped and the shortest kept one is faded in (see the
/// module notes). Returns a value of roughly unit variance scale in `[−1, 1]`.
pub fn fbm(seed: u64, s: f64, t: f64, largest: f64, smallest: f64, gain: f64, texel: f64) -> f64 {
    let mut wavelength = largest;
    let mut amplitude = 1.0;
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut octave = 0u64;
    let nyquist = 2.0 * texel;
    while wavelength >= smallest * 0.999 {
        // Weight 1 for wavelengths ≥ 2 Nyquist, fading linearly to 0 at the Nyquist limit.
        let w = ((wavelength / nyquist) - 1.0).clamp(0.0, 1.0);
        norm += amplitude;
        if w <= 0.0 {
            break;
        }
        let f = 1.0 / wavelength;
        sum += w
            * amplitude
            * value_noise(
                seed.wrapping_add(octave.wrapping_mul(0x51_7cc1_b727_220a)),
                s * f,
                t * f,
            );
        wavelength *= 0.5;
        amplitude *= gain;
        octave += 1;
    }
    while wavelength >= smallest * 0.999 {
        norm += amplitude;
        wavelength *= 0.5;
        amplitude *= gain;
    }
    if norm > 0.0 { sum / norm } else { 0.0 }
}

/// An anti-aliased step: 0 for `x ≤ −w/2`, 1 for `x ≥ w/2`, linear in between (the box filter
/// of width `w` applied to the unit step at 0).
#[inline(always)]
pub fn smooth_step_aa(x: f64, w: f64) -> f64 {
    (x / w + 0.5).clamp(0.0, 1.0)
}

/// Anti-aliased indicator of the interval `[a, b]` (coverage of the box of width `w` at `x`).
#[inline(always)]
pub fn interval_aa(x: f64, a: f64, b: f64, w: f64) -> f64 {
    (smooth_step_aa(x - a, w) - smooth_step_aa(x - b, w)).max(0.0)
}

/// Anti-aliased indicator of the axis-aligned rectangle `[s0, s1] × [t0, t1]`.
#[inline(always)]
pub fn rect_aa(s: f64, t: f64, s0: f64, t0: f64, s1: f64, t1: f64, w: f64) -> f64 {
    interval_aa(s, s0, s1, w) * interval_aa(t, t0, t1, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_deterministic_bounded_and_seed_dependent() {
        let mut differs = 0;
        for i in 0..1000 {
            let (x, y) = (i as f64 * 0.137, i as f64 * -0.291);
            let a = value_noise(7, x, y);
            assert_eq!(a.to_bits(), value_noise(7, x, y).to_bits());
            assert!((-1.0..=1.0).contains(&a));
            if (a - value_noise(8, x, y)).abs() > 1e-9 {
                differs += 1;
            }
        }
        assert!(differs > 990);
    }

    #[test]
    fn fbm_drops_octaves_below_nyquist() {
        // With a texel as large as the largest wavelength nothing is representable.
        assert_eq!(fbm(1, 0.3, 0.4, 1.0, 0.01, 0.5, 1.0), 0.0);
        // A fine texel keeps detail: values vary between nearby points 1 cm apart.
        let a = fbm(1, 0.30, 0.4, 1.0, 0.01, 0.6, 0.001);
        let b = fbm(1, 0.31, 0.4, 1.0, 0.01, 0.6, 0.001);
        assert!((a - b).abs() > 1e-4);
    }

    #[test]
    fn value_noise_lattice_values_are_uniform_and_uncorrelated() {
        // Lattice values: mean ≈ 0, variance ≈ 1/3 (uniform on [−1, 1]), neighbours
        // uncorrelated.
        let n = 200i64;
        let (mut sum, mut sq, mut cross) = (0.0, 0.0, 0.0);
        for y in 0..n {
            for x in 0..n {
                let v = value_noise(9, x as f64, y as f64);
                sum += v;
                sq += v * v;
                cross += v * value_noise(9, (x + 1) as f64, y as f64);
            }
        }
        let m = (n * n) as f64;
        assert!((sum / m).abs() < 0.01, "{}", sum / m);
        assert!((sq / m - 1.0 / 3.0).abs() < 0.01, "{}", sq / m);
        assert!((cross / m).abs() < 0.01, "{}", cross / m);
    }

    #[test]
    fn fast_functions_agree_with_libm() {
        for i in 0..10_000 {
            let x = (i as f64 - 5000.0) * 0.0173;
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
            let y = 1e-6 * 1.0037f64.powi(i);
            assert!((fast_log2(y) - y.log2()).abs() < 0.9e-3, "{y}");
        }
        assert_eq!(floor_i64(-1.0), -1);
        assert_eq!(floor_i64(2.0), 2);
    }

    #[test]
    fn aa_step_is_the_box_filtered_step() {
        assert_eq!(smooth_step_aa(-1.0, 1.0), 0.0);
        assert_eq!(smooth_step_aa(1.0, 1.0), 1.0);
        assert_eq!(smooth_step_aa(0.0, 1.0), 0.5);
        assert!((smooth_step_aa(0.25, 1.0) - 0.75).abs() < 1e-12);
        assert!((interval_aa(0.5, 0.0, 1.0, 0.1) - 1.0).abs() < 1e-12);
        assert_eq!(rect_aa(2.0, 0.5, 0.0, 0.0, 1.0, 1.0, 0.1), 0.0);
    }
}
