//! What a front-end looked at in a frame ([`Observed`]): for a live view
//! (`crate::Options::observe`).

/// A map point or corner track the front-end looked at in a frame, where it was in the image
/// and what became of it (a live view colours them; `Options::observe`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observed {
    /// Image position (pixels): where it was found, or predicted where it was not.
    pub uv: [f32; 2],
    /// What became of it.
    pub state: ObservedState,
}

/// What became of an [`Observed`] point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ObservedState {
    /// A map point found and kept by the motion-only BA (monocular: a map point's track).
    Inlier,
    /// Found, but rejected by the motion-only BA.
    Outlier,
    /// Searched for where it was predicted, not found.
    NotFound,
    /// A monocular corner track that is not (yet) a map point.
    Track,
}

impl ObservedState {
    /// `"inlier"`, `"outlier"`, `"not found"` or `"track"`.
    pub fn name(self) -> &'static str {
        match self {
            ObservedState::Inlier => "inlier",
            ObservedState::Outlier => "outlier",
            ObservedState::NotFound => "not found",
            ObservedState::Track => "track",
        }
    }
}
