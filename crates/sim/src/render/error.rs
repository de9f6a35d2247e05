//! The renderer's error, in a module of its own: every part of the renderer returns it, and it
//! uses none of them.

/// Errors of the renderer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    /// The camera cannot be rendered (size, intrinsics, distortion).
    #[error("invalid render camera: {0}")]
    InvalidCamera(String),
    /// A sensor or sequence parameter is out of its range.
    #[error("invalid parameter {name}: {reason}")]
    InvalidParameter {
        /// The parameter.
        name: &'static str,
        /// What was expected.
        reason: String,
    },
}
