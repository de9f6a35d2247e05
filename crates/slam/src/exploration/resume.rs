//! An exploration resumed on a map made before (a map file loaded by the live system): the
//! explorer's records of the graph's keyframes and points rebuilt, tracking started by a
//! relocalisation, and a mode that only localises.

use super::{ExplorationConfig, KeyframeFrame, MonoExplorer, State};
use crate::map::{KeyframeId, SlamGraph};
use crate::tracking::TrackId;
use geom::PinholeCamera;

impl MonoExplorer {
    /// An explorer that goes on in `graph`, a map made before (loaded from a file): every
    /// keyframe's record from `frame_of` (the frame it was made from; the measurements of its
    /// tracks are gone with them), every point's track a number no corner track of this run
    /// reaches. Nothing is tracked until the camera is [`relocalise`](Self::relocalise)d in
    /// the current map. With `localise`, frames are only tracked against the map's points: no
    /// keyframe, no feature filter, the graph unchanged.
    pub fn resume(
        camera: PinholeCamera,
        config: ExplorationConfig,
        graph: &SlamGraph<2>,
        frame_of: impl Fn(KeyframeId) -> usize,
        localise: bool,
    ) -> Self {
        let mut explorer = Self::new(camera, config);
        let parts = graph.to_parts();
        let (keyframe_ids, point_ids) = parts.ids_issued;
        explorer.map.keyframes = (0..keyframe_ids)
            .map(|i| KeyframeFrame {
                frame: frame_of(KeyframeId::from_index(i)),
                measurements: Vec::new(),
            })
            .collect();
        explorer.map.tracks = (0..point_ids)
            .map(|i| TrackId::MAX - i as TrackId)
            .collect();
        let current = graph.current_map();
        explorer.map_start = graph
            .keyframes()
            .find(|(_, k)| k.map() == current)
            .map_or(keyframe_ids, |(k, _)| k.index());
        explorer.localise = localise;
        explorer
    }

    /// Whether frames are being tracked (after a bootstrap or a relocalisation).
    pub fn is_tracking(&self) -> bool {
        matches!(self.state, State::Tracking { .. })
    }
}
