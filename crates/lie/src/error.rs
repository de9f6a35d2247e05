//! Errors of conversions into group elements.

use thiserror::Error;

/// Why a matrix, quaternion or scale does not describe a group element.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LieError {
    /// An entry is NaN or infinite.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// What was being converted.
        what: &'static str,
    },
    /// The quaternion has (almost) zero norm and represents no rotation.
    #[error("quaternion has norm {norm:e}, which represents no rotation")]
    ZeroQuaternion {
        /// The quaternion's norm.
        norm: f64,
    },
    /// The complex number has (almost) zero norm and represents no rotation.
    #[error("complex number has norm {norm:e}, which represents no rotation")]
    ZeroComplex {
        /// The complex number's norm.
        norm: f64,
    },
    /// The rotation block is not orthonormal: `max |RᵀR − I|` exceeds the tolerance.
    #[error(
        "rotation matrix is not orthonormal: max |RᵀR − I| = {error:e} > tolerance {tolerance:e}"
    )]
    NotOrthonormal {
        /// The largest entry of `RᵀR − I`.
        error: f64,
        /// The accepted tolerance.
        tolerance: f64,
    },
    /// The rotation block has a negative determinant (a reflection).
    #[error("rotation matrix has determinant {determinant}, it is a reflection, not a rotation")]
    Reflection {
        /// The determinant.
        determinant: f64,
    },
    /// The last row of a homogeneous matrix is not `(0, …, 0, 1)`.
    #[error("last row of the homogeneous matrix is not (0, …, 0, 1): max deviation {deviation:e}")]
    NotHomogeneous {
        /// The largest deviation of the last row from `(0, …, 0, 1)`.
        deviation: f64,
    },
    /// The scale of a similarity is not a positive finite number.
    #[error("similarity scale must be positive and finite, got {scale}")]
    InvalidScale {
        /// The offending scale.
        scale: f64,
    },
}
