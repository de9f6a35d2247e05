//! Variables live on manifolds: Lie groups updated by `exp(δ)·x` (thesis eq. 2.104) or
//! Euclidean vectors updated by `x + δ`.

use lie::{LieGroup, Se2, Se3, Sim3, So2, So3};
use nalgebra::SVector;

/// A manifold a variable block lives on: its tangent dimension and the update
/// `x ← x ⊞ δ` the optimiser applies (thesis eq. 2.104 for groups).
pub trait Manifold: Copy + Send + Sync + std::fmt::Debug + 'static {
    /// Dimension of the tangent space (the block size in the normal equations).
    const DIM: usize;
    /// A short name for messages, e.g. `"SE(3)"`.
    const NAME: &'static str;
    /// Applies the update `δ` (length [`DIM`](Self::DIM)).
    fn retract(&mut self, delta: &[f64]);
    /// `true` when every stored number is finite.
    fn is_finite(&self) -> bool;
}

macro_rules! group_manifold {
    ($g:ty, $d:literal) => {
        impl Manifold for $g {
            const DIM: usize = $d;
            const NAME: &'static str = <$g as LieGroup<$d>>::NAME;
            /// The left update `x ← exp(δ)·x` (thesis eq. 2.104).
            #[inline]
            fn retract(&mut self, delta: &[f64]) {
                let d = SVector::<f64, $d>::from_column_slice(delta);
                *self = <$g as LieGroup<$d>>::exp(&d).compose(self);
            }
            fn is_finite(&self) -> bool {
                LieGroup::<$d>::is_finite(self)
            }
        }
    };
}

group_manifold!(So2, 1);
group_manifold!(Se2, 3);
group_manifold!(So3, 3);
group_manifold!(Se3, 6);
group_manifold!(Sim3, 7);

macro_rules! vector_manifold {
    ($($n:literal),*) => {$(
        impl Manifold for SVector<f64, $n> {
            const DIM: usize = $n;
            const NAME: &'static str = concat!("R^", $n);
            /// The Euclidean update `x ← x + δ` (thesis eq. 2.13).
            #[inline]
            fn retract(&mut self, delta: &[f64]) {
                for (x, d) in self.iter_mut().zip(delta) {
                    *x += d;
                }
            }
            fn is_finite(&self) -> bool {
                self.iter().all(|x| x.is_finite())
            }
        }
    )*};
}

vector_manifold!(1, 2, 3, 4, 5, 6, 7, 8, 9);
