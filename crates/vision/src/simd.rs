//! Runtime choice between the SIMD kernels and their scalar reference paths.
//!
//! # Why `std::arch` with runtime detection
//!
//! The front-end kernels work on bytes (FAST's saturating compares and `movemask`, half-sampling
//! by `vpmaddubsw`, census XOR + popcount, fixed-point interpolation) and on small f32 windows
//! (LK, patch scores). Portable SIMD crates were weighed against that: `wide` (1.7) has no
//! saturating u8 arithmetic with byte masks nor `pmaddubsw`/`psadbw`, `pulp` (0.22, already in
//! the tree through faer) is built around f32/f64 lanes, and `multiversion` only recompiles the
//! same scalar code per target (which `#[target_feature]` on an `#[inline(always)]` body already
//! gives us, as in `lk.rs` and `pyramid.rs`). So the integer kernels are written with
//! `std::arch::x86_64` intrinsics behind `is_x86_feature_detected!("avx2")` (cached by std after
//! the first call), the float kernels are the scalar code compiled a second time for AVX2
//! (`#[target_feature(enable = "avx2")]` without FMA; Rust never contracts `a·b + c`, so the
//! results are bit-identical to the scalar build), and every kernel keeps a scalar path that is
//! the reference. AVX2 rather
//! than AVX-512: it is on every x86-64 CPU of the last decade (the development machine has both);
//! other targets run the scalar paths. The one exception is the stereo matcher's row kernel,
//! half of a stereo frame's cycles: where the CPU has AVX-512 (F, BW, VL and BITALG's byte
//! popcount, [`avx512`]) its interior columns run 32 disparities per vector instead of 16
//! (`stereo::avx512`), with the same results.
//!
//! Tests run every path: [`scalar_only`] makes the calling thread use the scalar reference, and
//! [`without_avx512`] the AVX2 kernels, so a test can compute a result each way on the same
//! input and compare (see the kernels' tests and `tests/real_data.rs`).

use std::cell::Cell;

thread_local! {
    static SCALAR_ONLY: Cell<bool> = const { Cell::new(false) };
    static NO_AVX512: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` with `cell` set on this thread, restored afterwards (also after a panic).
fn with_flag<R>(cell: &'static std::thread::LocalKey<Cell<bool>>, f: impl FnOnce() -> R) -> R {
    struct Restore(&'static std::thread::LocalKey<Cell<bool>>, bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            self.0.with(|s| s.set(self.1));
        }
    }
    let _restore = Restore(cell, cell.with(|s| s.replace(true)));
    f()
}

/// Runs `f` with every kernel of this crate on its scalar reference path (on this thread only),
/// e.g. to compare SIMD and scalar results in a test, or to rule SIMD out when debugging.
pub fn scalar_only<R>(f: impl FnOnce() -> R) -> R {
    with_flag(&SCALAR_ONLY, f)
}

/// Runs `f` with the AVX-512 kernels off (on this thread only): the AVX2 ones run instead, e.g.
/// to compare the two in a test on a CPU that has both.
pub fn without_avx512<R>(f: impl FnOnce() -> R) -> R {
    with_flag(&NO_AVX512, f)
}

/// True when SIMD kernels may be used on this thread (not inside [`scalar_only`]).
#[inline]
pub fn enabled() -> bool {
    !SCALAR_ONLY.with(|s| s.get())
}

/// True when the AVX2 kernels are to be used: SIMD [`enabled`] and the CPU has AVX2.
#[inline]
pub fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        enabled() && std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// True when the AVX-512 kernels are to be used: [`avx2`], not inside [`without_avx512`], and
/// the CPU has AVX-512 F, BW, VL and BITALG.
#[inline]
pub fn avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        avx2()
            && !NO_AVX512.with(|s| s.get())
            && std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512bitalg")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scalar_only_is_scoped_and_nests() {
        assert!(enabled());
        scalar_only(|| {
            assert!(!enabled() && !avx2());
            scalar_only(|| assert!(!enabled()));
            assert!(!enabled());
        });
        assert!(enabled());
        let r = std::panic::catch_unwind(|| scalar_only(|| panic!("x")));
        assert!(r.is_err());
        assert!(enabled(), "restored after a panic");
    }

    #[test]
    fn without_avx512_is_scoped() {
        let had = avx512();
        let avx2_before = avx2();
        without_avx512(|| assert!(!avx512() && avx2() == avx2_before));
        assert_eq!(avx512(), had);
        scalar_only(|| assert!(!avx512()));
    }
}
