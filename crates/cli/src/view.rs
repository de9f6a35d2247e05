//! `--view`, `--view-save FILE.rrd`: the run logged to Rerun as it goes (`runner::Observer`)
//! — every frame's image with the points the tracker looked at (coloured by what became of
//! them), the camera's frustum and the live trajectory, the ground truth, the keyframes, the
//! map points in their images' colours, the covisibility and loop edges, and per-frame
//! timings and states as time series; at the end, the map and trajectory after the run.
//!
//! The Rerun SDK is behind the cargo feature `view` (its build takes ~10 minutes here): a
//! `dwslam` built without it says how to get it when asked for a view.

use anyhow::Result;
use clap::Args;
use runner::{Observer, Source};
use std::path::PathBuf;

/// The live view's options (`dwslam run`, `dwslam demo`).
#[derive(Args, Debug, Clone, Default)]
pub struct ViewArgs {
    /// Watch the run as it goes in the Rerun viewer, spawned for it (`pip install
    /// rerun-sdk==0.36.3` installs the viewer). Needs a dwslam built with `--features view`.
    #[arg(long)]
    pub view: bool,
    /// Write the live view to a Rerun file instead (`rerun FILE.rrd` replays it). Needs a
    /// dwslam built with `--features view`.
    #[arg(long, value_name = "FILE.rrd", conflicts_with = "view")]
    pub view_save: Option<PathBuf>,
}

impl ViewArgs {
    fn wanted(&self) -> bool {
        self.view || self.view_save.is_some()
    }
}

/// The observer of `--view` / `--view-save` for a run of `source`, or none when no view was
/// asked for.
pub fn open(args: &ViewArgs, source: &Source) -> Result<Option<Box<dyn Observer>>> {
    if !args.wanted() {
        return Ok(None);
    }
    if let Some(path) = &args.view_save {
        crate::args::output_file(path, "--view-save")?;
    }
    open_view(args, source)
}

#[cfg(not(feature = "view"))]
fn open_view(_: &ViewArgs, _: &Source) -> Result<Option<Box<dyn Observer>>> {
    anyhow::bail!(
        "--view and --view-save need a dwslam built with the live view (the Rerun SDK): \
         cargo build --release -p dwslam --features view"
    )
}

#[cfg(feature = "view")]
fn open_view(args: &ViewArgs, source: &Source) -> Result<Option<Box<dyn Observer>>> {
    Ok(Some(Box::new(rerun_view::RerunView::open(args, source)?)))
}

#[cfg(feature = "view")]
mod rerun_view {
    use super::ViewArgs;
    use anyhow::{Context, Result};
    use data::camera::SensorModel;
    use data::eval::{Alignment, ate};
    use data::output::{FrameRecord, TrackingState};
    use data::sequence::Frame;
    use data::trajectory::{Trajectory, associate};
    use lie::{LieGroup, Se3, Sim3};
    use runner::{Observer, Source};
    use system::{FrameReport, MapSnapshot, ObservedState, RunResult};

    /// Sequence seconds between two logs of the whole map while the run goes on (and at
    /// every loop closure): a map is tens of thousands of points, and a copy of it each
    /// frame would cost more than the frame.
    const MAP_EVERY_S: f64 = 1.0;

    /// Frames between two logs of the live trajectory's whole line (the camera's pose is
    /// logged every frame).
    const TRAJECTORY_EVERY: usize = 10;

    /// Colours of the points the tracker looked at: kept (green), rejected by the
    /// motion-only BA (orange), not found where predicted (grey), a monocular corner track
    /// that is not a map point (blue).
    fn colour(state: ObservedState) -> rerun::Color {
        match state {
            ObservedState::Inlier => rerun::Color::from_rgb(40, 200, 80),
            ObservedState::Outlier => rerun::Color::from_rgb(255, 140, 0),
            ObservedState::NotFound => rerun::Color::from_rgb(150, 150, 150),
            ObservedState::Track => rerun::Color::from_rgb(80, 160, 255),
        }
    }

    /// The image the view shows: the frame's grey image at half size (2×2 means). At full
    /// size the images were the whole cost of the view — a threaded 7-Scenes run on two cores
    /// 13.6 % slower with them, no slower without, and 270 KB per frame in the file —; at half
    /// size a quarter of that (bench/README.md, "The live view").
    fn half(image: &vision::image::GrayImage) -> (Vec<u8>, [u32; 2]) {
        let (w, h) = (image.width() / 2, image.height() / 2);
        let mut bytes = Vec::with_capacity(w * h);
        for v in 0..h {
            let (a, b) = (image.row(2 * v), image.row(2 * v + 1));
            bytes.extend((0..w).map(|u| {
                let sum =
                    a[2 * u] as u16 + a[2 * u + 1] as u16 + b[2 * u] as u16 + b[2 * u + 1] as u16;
                ((sum + 2) / 4) as u8
            }));
        }
        (bytes, [w as u32, h as u32])
    }

    /// A full-size pixel position in the half-size image (pixel centres at integers).
    fn half_uv([u, v]: [f32; 2]) -> [f32; 2] {
        [(u + 0.5) / 2.0 - 0.5, (v + 0.5) / 2.0 - 0.5]
    }

    fn position(world_from_camera: &Se3) -> [f32; 3] {
        let t = world_from_camera.translation();
        [t.x as f32, t.y as f32, t.z as f32]
    }

    pub struct RerunView {
        rec: rerun::RecordingStream,
        pinhole: geom::PinholeCamera,
        /// The images' size, once a frame has shown it (the frustum is logged then).
        size: Option<(usize, usize)>,
        /// The live trajectory so far.
        trajectory: Vec<[f32; 3]>,
        /// The ground truth so far, in the run's world (a metric camera: aligned at the first
        /// frame with both; a monocular one's scale is only known after the run).
        ground_truth: Vec<[f32; 3]>,
        /// `T_run_gt`: the ground truth's world into the run's.
        gt_into_run: Option<Se3>,
        /// The frame in hand's ground-truth pose.
        gt_pose: Option<Se3>,
        free_scale: bool,
        /// Sequence time of the last map logged, and the loops then.
        map_logged: Option<(f64, usize)>,
        timestamp: f64,
        frames: usize,
    }

    impl RerunView {
        pub fn open(args: &ViewArgs, source: &Source) -> Result<Self> {
            let builder = rerun::RecordingStreamBuilder::new("dwslam");
            let rec = match &args.view_save {
                Some(path) => builder
                    .save(path)
                    .with_context(|| format!("--view-save {}", path.display()))?,
                None => builder.spawn().context(
                    "--view: the Rerun viewer could not be started (install it: pip install \
                     rerun-sdk==0.36.3, or cargo install rerun-cli@0.36.3 --locked; or write a \
                     file with --view-save FILE.rrd)",
                )?,
            };
            // The run's world is its first camera's frame: x right, y down, z forward.
            rec.log_static("world", &rerun::ViewCoordinates::RDF())?;
            // The time series, named (one plot each for the points and the times).
            rec.log_static(
                "tracking/points",
                &rerun::SeriesLines::new().with_names(["searched", "found", "kept (inliers)"]),
            )?;
            rec.log_static(
                "timing/ms",
                &rerun::SeriesLines::new().with_names(["frame", "tracking"]),
            )?;
            rec.log_static(
                "tracking/state",
                &rerun::SeriesLines::new().with_names(["state (2 good, 1 weak, 0 lost)"]),
            )?;
            rec.log_static(
                "description",
                &rerun::TextDocument::new(format!(
                    "dwslam on {} ({}): image with the tracked points (green kept, orange \
                     rejected, grey not found, blue corner tracks), camera, live trajectory \
                     (white), ground truth (magenta), keyframes (yellow), map points, \
                     covisibility (grey) and pose-constraint (blue) edges, loops (red).",
                    source.name,
                    runner::sensor_name(&source.sensor)
                )),
            )?;
            Ok(RerunView {
                rec,
                pinhole: *source.sensor.pinhole(),
                size: None,
                trajectory: Vec::new(),
                ground_truth: Vec::new(),
                gt_into_run: None,
                gt_pose: None,
                free_scale: matches!(source.sensor, SensorModel::Mono(_)),
                map_logged: None,
                timestamp: 0.0,
                frames: 0,
            })
        }

        fn log<A: ?Sized + rerun::AsComponents>(&self, path: &str, what: &A) {
            // A view that cannot be written (a viewer closed) must not stop the run.
            let _ = self.rec.log(path, what);
        }

        fn log_map(&self, map: &MapSnapshot) {
            let kf: std::collections::HashMap<usize, [f32; 3]> = map
                .keyframes
                .iter()
                .map(|k| (k.id, position(&k.world_from_camera)))
                .collect();
            self.log(
                "world/keyframes",
                &rerun::Points3D::new(kf.values().copied())
                    .with_colors([rerun::Color::from_rgb(255, 220, 0)])
                    .with_radii([rerun::Radius::new_ui_points(4.0)]),
            );
            self.log(
                "world/points",
                &rerun::Points3D::new(map.points.iter().map(|p| {
                    [
                        p.position.x as f32,
                        p.position.y as f32,
                        p.position.z as f32,
                    ]
                }))
                .with_colors(map.points.iter().map(|p| {
                    let [r, g, b] = p.colour.unwrap_or([128; 3]);
                    rerun::Color::from_rgb(r, g, b)
                }))
                .with_radii([rerun::Radius::new_ui_points(1.5)]),
            );
            let strips = |marginalised: bool| -> Vec<[[f32; 3]; 2]> {
                map.edges
                    .iter()
                    .filter(|e| e.2 == marginalised)
                    .filter_map(|(a, b, _)| Some([*kf.get(a)?, *kf.get(b)?]))
                    .collect()
            };
            self.log(
                "world/covisibility",
                &rerun::LineStrips3D::new(strips(false))
                    .with_colors([rerun::Color::from_unmultiplied_rgba(160, 160, 160, 90)])
                    .with_radii([rerun::Radius::new_ui_points(0.5)]),
            );
            self.log(
                "world/pose_constraints",
                &rerun::LineStrips3D::new(strips(true))
                    .with_colors([rerun::Color::from_rgb(90, 130, 255)])
                    .with_radii([rerun::Radius::new_ui_points(0.7)]),
            );
            let loops: Vec<_> = map
                .loops
                .iter()
                .filter_map(|(a, b, s)| Some(([*kf.get(a)?, *kf.get(b)?], *s)))
                .collect();
            self.log(
                "world/loops",
                &rerun::LineStrips3D::new(loops.iter().map(|(l, _)| *l))
                    .with_colors([rerun::Color::from_rgb(255, 40, 40)])
                    .with_radii([rerun::Radius::new_ui_points(1.2)])
                    .with_labels(loops.iter().map(|(_, s)| match s {
                        Some(s) => format!("loop, scale drift {s:.3}"),
                        None => "loop".to_string(),
                    })),
            );
        }

        fn log_lines(&self) {
            self.log(
                "world/trajectory",
                &rerun::LineStrips3D::new([self.trajectory.clone()])
                    .with_colors([rerun::Color::from_rgb(255, 255, 255)])
                    .with_radii([rerun::Radius::new_ui_points(1.5)]),
            );
            if !self.ground_truth.is_empty() {
                self.log(
                    "world/ground_truth",
                    &rerun::LineStrips3D::new([self.ground_truth.clone()])
                        .with_colors([rerun::Color::from_rgb(230, 60, 230)])
                        .with_radii([rerun::Radius::new_ui_points(1.0)]),
                );
            }
        }
    }

    impl Observer for RerunView {
        fn frame(&mut self, frame: &Frame) {
            self.rec.set_time_sequence("frame", frame.index as i64);
            self.rec.set_duration_secs("time", frame.timestamp);
            self.timestamp = frame.timestamp;
            let image = frame.gray();
            let (w, h) = (image.width(), image.height());
            if self.size != Some((w, h)) {
                self.size = Some((w, h));
                // The camera of the half-size image the view shows.
                let p = &self.pinhole;
                let _ = self.rec.log_static(
                    "world/camera/image",
                    &rerun::Pinhole::from_focal_length_and_resolution(
                        [(p.fx / 2.0) as f32, (p.fy / 2.0) as f32],
                        [(w / 2) as f32, (h / 2) as f32],
                    )
                    .with_principal_point(half_uv([p.cx as f32, p.cy as f32]))
                    .with_image_plane_distance(0.3),
                );
            }
            let (bytes, [w2, h2]) = half(image);
            self.log(
                "world/camera/image",
                &rerun::Image::from_l8(bytes, [w2, h2]),
            );
            self.gt_pose = frame.world_from_camera;
        }

        fn tracked(
            &mut self,
            report: &FrameReport,
            record: &FrameRecord,
            map: &dyn Fn() -> MapSnapshot,
        ) {
            self.frames += 1;
            self.log(
                "world/camera/image/tracked",
                &rerun::Points2D::new(report.observed.iter().map(|o| half_uv(o.uv)))
                    .with_colors(report.observed.iter().map(|o| colour(o.state)))
                    .with_radii([rerun::Radius::new_ui_points(2.5)]),
            );
            if let Some(pose) = &record.world_from_camera {
                let r = pose.rotation().rotation_matrix();
                let t = pose.translation();
                let columns = [
                    [r[(0, 0)] as f32, r[(1, 0)] as f32, r[(2, 0)] as f32],
                    [r[(0, 1)] as f32, r[(1, 1)] as f32, r[(2, 1)] as f32],
                    [r[(0, 2)] as f32, r[(1, 2)] as f32, r[(2, 2)] as f32],
                ];
                self.log(
                    "world/camera",
                    &rerun::Transform3D::from_translation_mat3x3(
                        [t.x as f32, t.y as f32, t.z as f32],
                        rerun::datatypes::Mat3x3::from(columns),
                    ),
                );
                self.trajectory.push(position(pose));
                if let Some(gt) = &self.gt_pose
                    && !self.free_scale
                {
                    let into_run = *self
                        .gt_into_run
                        .get_or_insert_with(|| pose.compose(&gt.inverse()));
                    self.ground_truth.push(position(&into_run.compose(gt)));
                }
            }
            if self.frames.is_multiple_of(TRAJECTORY_EVERY) || report.keyframe.is_some() {
                self.log_lines();
            }
            let state = match &record.state {
                TrackingState::Good => 2.0,
                TrackingState::Weak(_) => 1.0,
                TrackingState::Lost(_) => 0.0,
            };
            self.log("tracking/state", &rerun::Scalars::single(state));
            if let Some(reason) = record.state.reason() {
                self.log(
                    "tracking/log",
                    &rerun::TextLog::new(format!("{}: {reason}", record.state.name()))
                        .with_level(rerun::TextLogLevel::WARN),
                );
            }
            if let Some(s) = &report.stats {
                self.log(
                    "tracking/points",
                    &rerun::Scalars::new([s.searched as f64, s.found as f64, s.inliers as f64]),
                );
            }
            self.log(
                "timing/ms",
                &rerun::Scalars::new([
                    report.time.as_secs_f64() * 1e3,
                    report.time_tracking.as_secs_f64() * 1e3,
                ]),
            );
            if let Some((k, reason)) = &report.keyframe {
                self.log(
                    "tracking/log",
                    &rerun::TextLog::new(format!("keyframe {} ({})", k.index(), reason.name()))
                        .with_level(rerun::TextLogLevel::INFO),
                );
                let due = self
                    .map_logged
                    .is_none_or(|(t, _)| self.timestamp - t >= MAP_EVERY_S);
                if due {
                    let snapshot = map();
                    self.log_map(&snapshot);
                    self.map_logged = Some((self.timestamp, snapshot.loops.len()));
                }
            }
        }

        fn finished(
            &mut self,
            result: &RunResult,
            ground_truth: Option<&Trajectory>,
            alignment: Alignment,
        ) {
            // The map and the trajectory after the run, at the last frame's time.
            self.log_map(&result.snapshot());
            let fin = &result.final_trajectory;
            self.log(
                "world/trajectory_final",
                &rerun::LineStrips3D::new([fin
                    .world_from_body
                    .iter()
                    .map(position)
                    .collect::<Vec<_>>()])
                .with_colors([rerun::Color::from_rgb(80, 220, 255)])
                .with_radii([rerun::Radius::new_ui_points(1.5)]),
            );
            self.log_lines();
            // The ground truth in the run's world after the evaluation's alignment (a
            // monocular run's only now: its scale is the run's own).
            if let Some(gt) = ground_truth {
                let pairs = associate(&gt.timestamps, &fin.timestamps, 0.02, 0.0);
                let reference: Vec<Se3> =
                    pairs.iter().map(|&(i, _)| gt.world_from_body[i]).collect();
                let estimate: Vec<Se3> =
                    pairs.iter().map(|&(_, j)| fin.world_from_body[j]).collect();
                if let Ok(a) = ate(&reference, &estimate, alignment) {
                    let into_run: Sim3 = a.reference_from_estimate.inverse();
                    self.log(
                        "world/ground_truth",
                        &rerun::LineStrips3D::new([gt
                            .world_from_body
                            .iter()
                            .map(|p| {
                                let x = into_run.act(p.translation());
                                [x.x as f32, x.y as f32, x.z as f32]
                            })
                            .collect::<Vec<_>>()])
                        .with_colors([rerun::Color::from_rgb(230, 60, 230)])
                        .with_radii([rerun::Radius::new_ui_points(1.0)]),
                    );
                }
            }
            if let Err(e) = self.rec.flush_blocking() {
                eprintln!("warning: the live view was not written whole: {e}");
            }
        }
    }
}
