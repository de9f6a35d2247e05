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
//! other targets run the scalar paths.
//!
//! Tests run both paths: [`scalar_only`] makes the calling thread use the scalar reference, so a
//! test can compute a result both ways on the same input and compare (see the kernels' tests and
//! `tests/real_data.rs`).

use std::cell::Cell;

thread_local! {
    static SCALAR_ONLY: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` with every kernel of this crate on its scalar reference path (on this thread only),
/// e.g. to compare SIMD and scalar results in a test, or to rule SIMD out when debugging.
pub fn scalar_only<R>(f: impl FnOnce() -> R) -> R {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            SCALAR_ONLY.with(|s| s.set(self.0));
        }
    }
    let _restore = Restore(SCALAR_ONLY.with(|s| s.replace(true)));
    f()
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
}
