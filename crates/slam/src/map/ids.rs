//! Typed ids of the SLAM graph: a keyframe id cannot be passed where a point id is expected.
//! Both wrap the same integer type, [`IdInt`]; ids are never reused after a removal.

use std::fmt;

/// The integer inside every id (4 · 10⁹ keyframes or points are beyond any run).
pub type IdInt = u32;

macro_rules! id_type {
    ($(#[$doc:meta])* $name:ident, $prefix:literal) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name(pub IdInt);

        impl $name {
            /// The id as an index into a dense table (ids are allocated densely from 0).
            #[inline]
            pub fn index(self) -> usize {
                self.0 as usize
            }

            /// The id of index `i`.
            ///
            /// # Panics
            /// If `i` does not fit an [`IdInt`] (more than 4 · 10⁹ elements).
            #[inline]
            pub fn from_index(i: usize) -> Self {
                $name(IdInt::try_from(i).expect("id space exhausted"))
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, concat!($prefix, "{}"), self.0)
            }
        }
    };
}

id_type!(
    /// Id of a keyframe vertex.
    KeyframeId,
    "keyframe "
);
id_type!(
    /// Id of a map point.
    PointId,
    "point "
);
