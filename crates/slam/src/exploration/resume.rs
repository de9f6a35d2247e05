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
    /// the current map. With `localise`, frames are tracked against the map's points, and where
    /// the map does not cover the view (the keyframe criterion) a *temporary* keyframe starts
    /// feature filters whose converged points bridge the gap, as ORB-SLAM3's localisation mode
    /// keeps visual-odometry points: nothing is optimised (the map's keyframes and points stay
    /// as loaded; the temporary keyframes' poses are tracking's, their points the filters'),
    /// and [`remove_temporary`](Self::remove_temporary) takes them out at the end.
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

    /// Removes the temporary keyframes of a localisation ([`resume`](Self::resume)) from
    /// `graph`, newest first, with their points and their measurements of the map's points:
    /// the map is as loaded again. Their frames keep the poses tracking gave them. Returns the
    /// keyframes removed.
    pub fn remove_temporary(&mut self, graph: &mut SlamGraph<2>) -> Vec<KeyframeId> {
        let removed = std::mem::take(&mut self.temporary);
        for &k in removed.iter().rev() {
            // A keyframe of this run: it is in the graph unless something removed it already.
            let _ = graph.remove_keyframe(k);
        }
        let gone: std::collections::HashSet<KeyframeId> = removed.iter().copied().collect();
        self.keyframe_of_frame.retain(|_, k| !gone.contains(k));
        self.active.retain(|_, p| graph.point(*p).is_some());
        // Every filter started in a temporary keyframe.
        self.filters.retain(|_, _| false);
        self.filter_of_track.clear();
        removed
    }

    /// Whether frames are being tracked (after a bootstrap or a relocalisation).
    pub fn is_tracking(&self) -> bool {
        matches!(self.state, State::Tracking { .. })
    }
}
