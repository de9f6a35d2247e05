//! The monocular live system (issue 20; thesis ch. 3, §6.2.7): one camera's frames in, every
//! frame's pose and the map out, at the arbitrary scale a single camera has.
//!
//! Per frame, in the calling thread:
//!
//! 1. **Corner tracks** ([`CornerTracks`], the image side): the live tracks are followed from
//!    the previous frame by pyramidal LK, forward-backward checked; where they have thinned
//!    out, new FAST corners are selected in the quadtree's equi-distributed order (thesis
//!    Alg. 2) at least `track_spacing` pixels from every live track. Each track keeps its id
//!    while it lives; a lost track never comes back (a corner seen again is a new track).
//! 2. **Exploration** (`slam::exploration::MonoExplorer`, the same stage the simulated
//!    scale-drift studies run on simulated tracks): the two-view bootstrap with model
//!    selection between homography and essential matrix (`geom::bootstrap`), motion-only BA
//!    from a constant-velocity prior, keyframes by distance relative to the scene depth,
//!    inverse-depth feature filters (thesis eq. 3.35–3.37) started at quadtree-selected tracks
//!    of keyframes and promoted when converged, sliding-window BA.
//!
//! When the bootstrap finds no geometry within `max_bootstrap_frames`, or tracking loses the
//! map, the system starts again from the current frame: the frames in between are `lost` with
//! the reason, and the new map has its own frame and scale (there is no relocalisation yet;
//! the run says how often it restarted).

use crate::config::{MonoConfig, SystemConfig};
use crate::keyframes::{KeyframeReason, KeyframeStore};
use crate::live::{FrameReport, LiveRun, RunResult, SystemError};
use crate::tracker::TrackerStats;
use data::output::{FrameRecord, KeyframeRecord, MapPoint, RunRecord, TrackingState};
use data::trajectory::Trajectory;
use geom::PinholeCamera;
use lie::{LieGroup, Se3};
use nalgebra::Vector2;
use slam::exploration::{ExplorationConfig, ExplorationError, MonoExplorer, TrackId};
use std::time::{Duration, Instant};
use vision::image::{GrayImage, ImageError};
use vision::lk::{LkParams, track_forward_backward};
use vision::pyramid::Pyramid;
use vision::quadtree::select_corners;

/// Corner tracks through an image sequence (module docs, step 1).
#[derive(Debug)]
pub struct CornerTracks {
    config: MonoConfig,
    /// The previous frame's pyramid and its live tracks.
    previous: Option<(Pyramid, Vec<(TrackId, [f32; 2])>)>,
    next: TrackId,
    /// Scratch of the spacing test: per grid cell, the tracks in it.
    grid: Vec<Vec<[f32; 2]>>,
}

/// A frame in which fewer than this fraction of the previous frame's tracks survive is refused
/// (0.2: between two frames of a moving camera most corners stay in view and LK follows them;
/// losing four fifths at once is a broken frame — black, corrupt, textureless — or a jump);
/// the tracks wait for the next frame in the last good one.
pub const MIN_SURVIVING_FRACTION: f64 = 0.2;

/// Replenish when fewer than this fraction of the wanted tracks live (0.9: the selection costs
/// a FAST pass over the image, a few milliseconds, so it runs every few frames rather than in
/// every one, and the tracks stay within 10 % of their number).
const REPLENISH_FRACTION: f64 = 0.9;

impl CornerTracks {
    /// Tracks with `config`'s parameters.
    pub fn new(config: &MonoConfig) -> Self {
        CornerTracks {
            config: config.clone(),
            previous: None,
            next: 0,
            grid: Vec::new(),
        }
    }

    /// Forgets every track: the next frame starts afresh (ids keep increasing).
    pub fn reset(&mut self) {
        self.previous = None;
    }

    /// Follows the tracks into `image` and replenishes them; returns the live tracks with their
    /// positions (pixels), or `Ok(Err((survived, of)))` when too few survived
    /// ([`MIN_SURVIVING_FRACTION`]): the frame is refused and the tracks stay in the previous
    /// one.
    pub fn push(
        &mut self,
        image: &GrayImage,
    ) -> Result<Result<&[(TrackId, [f32; 2])], (usize, usize)>, ImageError> {
        let levels = self.config.levels;
        let pyramid = Pyramid::new(image, levels, 16)?;
        let (w, h) = (image.width() as f32, image.height() as f32);
        let mut live = Vec::new();
        if let Some((previous, tracks)) = &self.previous {
            let from: Vec<[f32; 2]> = tracks.iter().map(|t| t.1).collect();
            let to = track_forward_backward(
                &previous,
                &pyramid,
                &from,
                &LkParams {
                    levels,
                    ..LkParams::default()
                },
                self.config.max_forward_backward,
            );
            live.reserve(tracks.len());
            for ((id, _), p) in tracks.iter().zip(to) {
                if let Some(p) = p
                    && p[0] >= 0.0
                    && p[1] >= 0.0
                    && p[0] <= w - 1.0
                    && p[1] <= h - 1.0
                {
                    live.push((*id, p));
                }
            }
            let of = tracks.len();
            if (live.len() as f64) < MIN_SURVIVING_FRACTION * of as f64 {
                return Ok(Err((live.len(), of)));
            }
        }
        if (live.len() as f64) < REPLENISH_FRACTION * self.config.tracks as f64 {
            self.replenish(image, &mut live);
        }
        let (_, tracks) = self.previous.insert((pyramid, live));
        Ok(Ok(tracks))
    }

    /// New corners, in the quadtree's order, at least `track_spacing` from every track, until
    /// `tracks` live.
    fn replenish(&mut self, image: &GrayImage, live: &mut Vec<(TrackId, [f32; 2])>) {
        let (_, selected) = select_corners(
            image,
            self.config.fast_threshold,
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

/// The exploration's parameters for a `width`×`height` camera from the system's.
pub fn exploration_config(config: &SystemConfig, width: usize, height: usize) -> ExplorationConfig {
    let m = &config.mono;
    ExplorationConfig {
        sigma: config.pixel_noise,
        window: m.window,
        keyframe_distance: m.keyframe_distance,
        max_features: m.max_features,
        feature_spacing: m.feature_spacing,
        image_width: width as f64,
        image_height: height as f64,
        bootstrap_depth_error: m.bootstrap_depth_error,
        // The depth error alone decides when the bootstrap has parallax enough.
        min_bootstrap_parallax: 0.0,
        max_bootstrap_frames: m.max_bootstrap_frames,
        ..ExplorationConfig::default()
    }
}

/// The monocular live system (see the [module docs](self)).
pub struct MonoSystem {
    config: SystemConfig,
    camera: PinholeCamera,
    tracks: CornerTracks,
    explorer: Option<MonoExplorer>,
    record: RunRecord,
    reports: Vec<FrameReport>,
    /// Every earlier map's final frame poses `(frame, camera_from_world)`.
    finished: Vec<(usize, Se3)>,
    /// Maps lost after their bootstrap (tracking lost, a new map started).
    lost_maps: usize,
    /// Frames refused in a row by the corner tracks.
    refused: usize,
    warnings: Vec<String>,
}

impl MonoSystem {
    /// A system for `camera` with `config`; `sequence` names the input in the outputs.
    pub fn new(
        camera: PinholeCamera,
        config: SystemConfig,
        sequence: &str,
    ) -> Result<Self, SystemError> {
        config.validate()?;
        Ok(MonoSystem {
            tracks: CornerTracks::new(&config.mono),
            camera,
            config,
            explorer: None,
            record: RunRecord {
                sequence: sequence.to_string(),
                sensor: "mono".into(),
                ..RunRecord::default()
            },
            reports: Vec::new(),
            finished: Vec::new(),
            lost_maps: 0,
            refused: 0,
            warnings: Vec::new(),
        })
    }

    /// Ends the current map and starts again at the next frame.
    fn restart(&mut self, why: String) {
        if let Some(explorer) = self.explorer.take() {
            if !explorer.map().keyframes.is_empty() {
                self.lost_maps += 1;
            }
            self.finished.extend(explorer.frame_poses());
            self.warnings.push(why);
        }
        self.tracks.reset();
    }

    fn push(&mut self, report: FrameReport, frame: &data::sequence::Frame, pose: Option<Se3>) {
        self.record.frames.push(FrameRecord {
            index: frame.index,
            timestamp: frame.timestamp,
            world_from_camera: pose.map(|t| t.inverse()),
            state: report.state.clone(),
        });
        self.record.timings.record("frame: total", report.time);
        self.reports.push(report);
    }
}

impl LiveRun<2> for MonoSystem {
    fn process(&mut self, frame: data::sequence::Frame) -> Result<FrameReport, SystemError> {
        let start = Instant::now();
        let image = frame.gray();
        let (width, height) = (image.width(), image.height());
        let t = Instant::now();
        let measurements: Result<Vec<(TrackId, Vector2<f64>)>, _> = self
            .tracks
            .push(image)
            .map_err(|e| SystemError::Frame(e.into()))?
            .map(|tracks| {
                tracks
                    .iter()
                    .map(|&(id, p)| (id, Vector2::new(p[0] as f64, p[1] as f64)))
                    .collect()
            });
        self.record
            .timings
            .record("frame: pyramid, LK tracks", t.elapsed());
        let measurements = match measurements {
            Ok(m) => {
                self.refused = 0;
                m
            }
            Err((survived, of)) => {
                self.refused += 1;
                let mut why = format!(
                    "only {survived} of {of} corner tracks followed into this frame: refused"
                );
                if self.refused >= self.config.mono.max_refused {
                    self.restart(format!(
                        "frame {}: {} frames in a row refused: a new map starts",
                        frame.index, self.refused
                    ));
                    self.refused = 0;
                    why.push_str("; a new map starts");
                }
                let report = FrameReport {
                    index: frame.index,
                    state: TrackingState::Lost(why),
                    keyframe: None,
                    stats: None,
                    time: start.elapsed(),
                    time_tracking: start.elapsed(),
                };
                self.push(report.clone(), &frame, None);
                return Ok(report);
            }
        };
        let n_tracks = measurements.len();
        let t = Instant::now();
        let camera = self.camera;
        let config = exploration_config(&self.config, width, height);
        let explorer = self
            .explorer
            .get_or_insert_with(|| MonoExplorer::new(camera, config));
        let outcome = explorer.process(frame.index, &measurements);
        let time_tracking = start.elapsed();
        self.record.timings.record("mono: exploration", t.elapsed());
        let (state, pose, keyframe, stats) = match outcome {
            Ok(o) => {
                let state = match o.camera_from_world {
                    None => TrackingState::Lost(format!(
                        "initialising: {n_tracks} corner tracks, waiting for parallax"
                    )),
                    Some(_) if o.tracked < self.config.tracker.min_good => {
                        TrackingState::Weak(format!("{} map points tracked", o.tracked))
                    }
                    Some(_) => TrackingState::Good,
                };
                let reason = if self
                    .explorer
                    .as_ref()
                    .is_some_and(|e| e.map().keyframes.len() <= 2)
                {
                    KeyframeReason::First
                } else {
                    KeyframeReason::Exploration
                };
                let stats = o.camera_from_world.map(|_| TrackerStats {
                    // The tracks are the candidates; the map points among them are searched
                    // (LK already found them) and the motion-only BA keeps them all (Huber).
                    candidates: n_tracks,
                    visible: n_tracks,
                    searched: o.tracked,
                    found: o.tracked,
                    inliers: o.tracked,
                });
                (
                    state,
                    o.camera_from_world,
                    o.keyframe.map(|k| (k, reason)),
                    stats,
                )
            }
            Err(e) => {
                let reason = match &e {
                    ExplorationError::BootstrapFailed { .. } => {
                        format!("{e}: initialising again")
                    }
                    _ => format!("{e}: a new map starts"),
                };
                self.restart(format!("frame {}: {reason}", frame.index));
                (TrackingState::Lost(reason), None, None, None)
            }
        };
        if let Some((_, r)) = &keyframe {
            self.record.timings.record(
                match r {
                    KeyframeReason::First => "keyframe: bootstrap",
                    _ => "keyframe: window BA",
                },
                time_tracking,
            );
        }
        let report = FrameReport {
            index: frame.index,
            state,
            keyframe,
            stats,
            time: start.elapsed(),
            time_tracking,
        };
        self.record.timings.record("track: total", time_tracking);
        self.push(report.clone(), &frame, pose);
        Ok(report)
    }

    fn skip_frame(&mut self, index: usize, timestamp: f64, reason: String) {
        self.record.frames.push(FrameRecord {
            index,
            timestamp,
            world_from_camera: None,
            state: TrackingState::Lost(reason.clone()),
        });
        self.reports.push(FrameReport {
            index,
            state: TrackingState::Lost(reason),
            keyframe: None,
            stats: None,
            time: Duration::ZERO,
            time_tracking: Duration::ZERO,
        });
    }

    fn record(&self) -> &RunRecord {
        &self.record
    }

    fn record_timing(&mut self, stage: &str, d: Duration) {
        self.record.timings.record(stage, d);
    }

    fn finish(mut self, interrupted: bool) -> Result<RunResult<2>, SystemError> {
        self.record.interrupted = interrupted;
        let timestamp: std::collections::HashMap<usize, f64> = self
            .record
            .frames
            .iter()
            .map(|f| (f.index, f.timestamp))
            .collect();
        let mut poses = std::mem::take(&mut self.finished);
        let graph = match &self.explorer {
            Some(explorer) => {
                poses.extend(explorer.frame_poses());
                let map = explorer.map();
                self.record.keyframes = map
                    .keyframe_ids()
                    .map(|k| {
                        let frame = map.keyframe(k).frame;
                        KeyframeRecord {
                            id: k.index(),
                            frame_index: frame,
                            timestamp: timestamp.get(&frame).copied().unwrap_or(f64::NAN),
                            world_from_camera: map.rigid_pose(k).inverse(),
                        }
                    })
                    .collect();
                self.record.points = map
                    .graph
                    .points()
                    .filter_map(|(p, _)| {
                        Some(MapPoint {
                            position: map.graph.point_world(p).ok()?,
                            colour: None,
                        })
                    })
                    .collect();
                map.graph.clone()
            }
            None => Default::default(),
        };
        let mut final_trajectory = Trajectory::default();
        for (frame, camera_from_world) in poses {
            if let Some(&t) = timestamp.get(&frame) {
                final_trajectory.timestamps.push(t);
                final_trajectory
                    .world_from_body
                    .push(camera_from_world.inverse());
            }
        }
        let mut warnings = std::mem::take(&mut self.warnings);
        if self.lost_maps > 0 {
            warnings.push(format!(
                "tracking lost its map {} times and started a new one; the outputs hold the \
                 last map, every frame's pose in the map it was tracked in",
                self.lost_maps
            ));
        }
        Ok(RunResult {
            record: self.record,
            final_trajectory,
            frames: self.reports,
            loops: Vec::new(),
            optimisations: Vec::new(),
            graph,
            keyframes: KeyframeStore::new(),
            warnings,
        })
    }
}
