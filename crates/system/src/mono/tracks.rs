//! Corner tracks through an image sequence (the monocular front-end's image side): the live
//! tracks are followed from the previous frame by pyramidal LK, forward-backward checked;
//! where they have thinned out, new FAST corners are selected in the quadtree's
//! equi-distributed order (thesis Alg. 2) at least `track_spacing` pixels from every live
//! track. Each track keeps its id while it lives; a lost track never comes back (a corner seen
//! again is a new track).

use crate::config::MonoConfig;
use slam::exploration::TrackId;
use vision::fast::FrameCorners;
use vision::image::ImageError;
use vision::lk::{Affine, IDENTITY, LkParams, track_forward_backward_warps};
use vision::pyramid::Pyramid;
use vision::quadtree::select_among;

/// A live track: its id and its position in the last frame (pixels).
pub type Track = (TrackId, [f32; 2]);

/// The live tracks.
pub type Tracks = Vec<Track>;

/// A frame the tracks could not follow into: `(survived, of)` tracks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Refused {
    /// Tracks that survived.
    pub survived: usize,
    /// Tracks of the previous frame.
    pub of: usize,
}

/// Corner tracks through an image sequence (see the [module docs](self)).
#[derive(Debug)]
pub struct CornerTracks {
    config: MonoConfig,
    /// The previous frame's pyramid and its live tracks.
    previous: Option<(Pyramid, Tracks)>,
    /// Each live track's warp part into the previous frame (`mono.lk_affine_levels`; the
    /// identity for a new track), in the order of the tracks: the next frame's prediction.
    warps: Vec<Affine>,
    next: TrackId,
    /// Scratch of the spacing test: per grid cell, the tracks in it.
    grid: Vec<Vec<[f32; 2]>>,
}

impl CornerTracks {
    /// Tracks with `config`'s parameters.
    pub fn new(config: &MonoConfig) -> Self {
        CornerTracks {
            config: config.clone(),
            previous: None,
            warps: Vec::new(),
            next: 0,
            grid: Vec::new(),
        }
    }

    /// A new track at `p` in the last frame (a map point found there by guided search).
    pub fn adopt(&mut self, p: [f32; 2]) -> Option<TrackId> {
        let (_, live) = self.previous.as_mut()?;
        let id = self.next;
        self.next += 1;
        live.push((id, p));
        self.warps.push(IDENTITY);
        Some(id)
    }

    /// Moves track `id` to `p` in the last frame (its measurement re-located on the point's
    /// template): the next frame follows it from there.
    pub fn correct(&mut self, id: TrackId, p: [f32; 2]) {
        if let Some((_, live)) = self.previous.as_mut()
            && let Some(t) = live.iter_mut().find(|t| t.0 == id)
        {
            t.1 = p;
        }
    }

    /// Forgets every track: the next frame starts afresh (ids keep increasing).
    pub fn reset(&mut self) {
        self.previous = None;
        self.warps.clear();
    }

    /// Follows the tracks into the image of `corners` and replenishes them (among its FAST
    /// corners at `mono.fast_threshold`); returns the live tracks with their
    /// positions (pixels), or `Ok(Err(Refused))` when too few survived
    /// (`mono.min_surviving_fraction`): the frame is refused and the tracks stay in the previous
    /// one.
    pub fn push(
        &mut self,
        corners: &FrameCorners,
    ) -> Result<Result<&[Track], Refused>, ImageError> {
        let image = corners.image();
        let levels = self.config.levels;
        let pyramid = Pyramid::new(image, levels, 16)?;
        let (w, h) = (image.width() as f32, image.height() as f32);
        let mut live = Vec::new();
        let mut warps = Vec::new();
        if let Some((previous, tracks)) = &self.previous {
            let from: Vec<[f32; 2]> = tracks.iter().map(|t| t.1).collect();
            let to = track_forward_backward_warps(
                previous,
                &pyramid,
                &from,
                Some(&self.warps),
                &LkParams {
                    levels,
                    affine_levels: self.config.lk_affine_levels,
                    ..LkParams::default()
                },
                self.config.max_forward_backward,
            );
            live.reserve(tracks.len());
            warps.reserve(tracks.len());
            for ((id, _), t) in tracks.iter().zip(to) {
                if let Some((p, a)) = t
                    && p[0] >= 0.0
                    && p[1] >= 0.0
                    && p[0] <= w - 1.0
                    && p[1] <= h - 1.0
                {
                    live.push((*id, p));
                    warps.push(a);
                }
            }
            let of = tracks.len();
            if (live.len() as f64) < self.config.min_surviving_fraction * of as f64 {
                return Ok(Err(Refused {
                    survived: live.len(),
                    of,
                }));
            }
        }
        if (live.len() as f64) < self.config.replenish_fraction * self.config.tracks as f64 {
            self.replenish(corners, &mut live);
        }
        warps.resize(live.len(), IDENTITY);
        self.warps = warps;
        let (_, tracks) = self.previous.insert((pyramid, live));
        Ok(Ok(tracks))
    }

    /// New corners, in the quadtree's order, at least `track_spacing` from every track, until
    /// `tracks` live.
    fn replenish(&mut self, corners: &FrameCorners, live: &mut Tracks) {
        let image = corners.image();
        let (_, selected) = select_among(
            image,
            &corners.at(self.config.fast_threshold),
            self.config.tracks,
            self.config.min_cell,
        );
        let spacing = self.config.track_spacing.max(1.0) as f32;
        let cols = (image.width() as f32 / spacing).ceil() as usize + 1;
        let rows = (image.height() as f32 / spacing).ceil() as usize + 1;
        self.grid.iter_mut().for_each(Vec::clear);
        self.grid.resize(cols * rows, Vec::new());
        let cell = |p: [f32; 2]| ((p[0] / spacing) as usize, (p[1] / spacing) as usize);
        for (_, p) in live.iter() {
            let (c, r) = cell(*p);
            self.grid[r.min(rows - 1) * cols + c.min(cols - 1)].push(*p);
        }
        for q in selected {
            if live.len() >= self.config.tracks {
                break;
            }
            let p = [q.u, q.v];
            let (c, r) = cell(p);
            let free = (r.saturating_sub(1)..=(r + 1).min(rows - 1)).all(|rr| {
                (c.saturating_sub(1)..=(c + 1).min(cols - 1)).all(|cc| {
                    self.grid[rr * cols + cc].iter().all(|o| {
                        let (du, dv) = (o[0] - p[0], o[1] - p[1]);
                        du * du + dv * dv >= spacing * spacing
                    })
                })
            });
            if free {
                self.grid[r.min(rows - 1) * cols + c.min(cols - 1)].push(p);
                live.push((self.next, p));
                self.next += 1;
            }
        }
    }
}
