//! Why exploration stopped.

/// Why exploration stopped.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExplorationError {
    /// No frame pair had enough parallax to bootstrap.
    #[error("bootstrap failed after {frames} frames: {reason}")]
    BootstrapFailed {
        /// Frames tried.
        frames: usize,
        /// The last reason.
        reason: String,
    },
    /// Too few map points were measured to track the pose.
    #[error("tracking lost at frame {frame}: {tracked} map points measured")]
    TrackingLost {
        /// The frame.
        frame: usize,
        /// Map points measured.
        tracked: usize,
    },
    /// Frames must be given in increasing order.
    #[error("frame {frame} given after frame {last}")]
    FrameOrder {
        /// The frame.
        frame: usize,
        /// The previous one.
        last: usize,
    },
    /// An optimisation failed.
    #[error("optimisation failed: {0}")]
    Optimisation(String),
}
