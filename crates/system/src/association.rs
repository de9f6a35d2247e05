//! The live front-end's side of the keyframe pipeline (`slam::mapping::FrontEnd`): data
//! association from images for a new keyframe — its tracked matches and pose, the guided search
//! of metric loop closure (thesis §6.4.1: a 10-pixel radius), the new points where the quadtree
//! finds room (§3.4.3, §6.3) — optionally only where no point of the map lies on the same
//! surface (`keyframes.reuse_map_points`). Appearance-based loops are not closed here but by the loop
//! closer ([`crate::loops`]), in its own thread (§6.5.2).

use crate::frame::{FrameData, SensorFrontEnd};
use crate::keyframes::{KeyframeImages, KeyframeStore};
use crate::search::{SearchPoint, SearchScratch, predict, search, view_angle};
use lie::{Se3, Sim3};
use nalgebra::{SVector, Vector2, Vector3};
use slam::map::{KeyframeId, PointId, SlamGraph, Version};
use slam::mapping::{AppearanceMatch, FrontEnd};
use slam::tracking::TrackId;
use std::collections::BTreeSet;
use vision::quadtree::{QuadPoint, QuadTree};

/// One new keyframe's association.
pub struct KeyframeAssociation<'a> {
    /// The keyframe's frame.
    pub frame: &'a FrameData,
    /// Its images (already in the store under its id once inserted: templates for the guided
    /// search come from the anchor keyframes).
    pub store: &'a KeyframeStore,
    /// The sensor.
    pub sensor: &'a SensorFrontEnd,
    /// The tracked pose.
    pub camera_from_world: Sim3,
    /// The tracked inlier matches.
    pub matches: Vec<(PointId, Vector3<f64>)>,
    /// Guided-search radius of metric loop closure (pixels).
    pub loop_radius: f64,
    /// The visibility test's largest viewing-angle change (radians).
    pub max_view_angle: f64,
    /// Correlation a patch match needs.
    pub min_ncc: f32,
    /// New points per keyframe at most.
    pub max_new_points: usize,
    /// A new point needs this much room from the keyframe's observations (pixels).
    pub spacing: f64,
    /// Smallest disparity for a new point (pixels).
    pub min_disparity: f64,
    /// A map point projected near a corner is on the corner's surface when their depths
    /// differ by at most this fraction (`keyframes.parallax`: the depth fraction at which
    /// the keyframe criterion tells views apart).
    pub same_surface: f64,
    /// New points only where no map point of `N1` lies on the same surface
    /// (`keyframes.reuse_map_points`).
    pub reuse_map_points: bool,
    /// The next free track id (new points each get one).
    pub next_track: &'a mut TrackId,
    /// Points created.
    pub created: Vec<(TrackId, PointId)>,
    /// The keyframe the pose was tracked against, its pose then and the graph's version then
    /// (`crate::tracker::TrackedThen`): a pose tracked before another thread moved the map is
    /// rebased at insertion. `None`: the pose is as of the graph at insertion.
    pub tracked_against: Option<(KeyframeId, Sim3, Version)>,
    /// The keyframe is the first of a new map (`slam::mapping::FrontEnd::new_map`).
    pub new_map: bool,
    scratch: SearchScratch,
}

impl<'a> KeyframeAssociation<'a> {
    /// The association of a keyframe made from `frame`, tracked at `camera_from_world` with
    /// `matches`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        frame: &'a FrameData,
        store: &'a KeyframeStore,
        sensor: &'a SensorFrontEnd,
        camera_from_world: Sim3,
        matches: Vec<(PointId, Vector3<f64>)>,
        config: &crate::config::SystemConfig,
        min_disparity: f64,
        next_track: &'a mut TrackId,
    ) -> Self {
        KeyframeAssociation {
            frame,
            store,
            sensor,
            camera_from_world,
            matches,
            loop_radius: config.mapping.loop_search_radius,
            max_view_angle: config.tracker.max_view_angle_deg.to_radians(),
            min_ncc: config.tracker.min_ncc,
            max_new_points: config.keyframes.max_new_points,
            spacing: config.keyframes.new_point_spacing,
            min_disparity,
            same_surface: config.keyframes.parallax,
            reuse_map_points: config.keyframes.reuse_map_points,
            next_track,
            created: Vec::new(),
            tracked_against: None,
            new_map: false,
            scratch: SearchScratch::default(),
        }
    }

    /// The images of the keyframe being made (to insert into the store).
    pub fn images(&self) -> KeyframeImages {
        KeyframeImages::from_frame(self.frame)
    }

    fn stereo_measurement(&self, u: Vector2<f64>) -> Option<Vector3<f64>> {
        stereo_measurement(self.frame, self.sensor, u, self.min_disparity)
    }

    /// The points the keyframe's neighbours (`N1`) measure that it does not, projected at its
    /// pose: in front of it and inside the image.
    fn known_points(&self, graph: &SlamGraph<3>, keyframe: KeyframeId) -> KnownPoints {
        let (w, h) = (self.frame.gray().width(), self.frame.gray().height());
        let mut known = KnownPoints::new(w, h, self.spacing, self.same_surface);
        let Some(kf) = graph.keyframe(keyframe) else {
            return known;
        };
        let pinhole = self.sensor.pinhole();
        for p in graph.points_visible_from(&graph.n1(keyframe)) {
            if kf.observations().contains_key(&p) {
                continue;
            }
            let Ok(y) = graph.point_in_frame(p, keyframe) else {
                continue;
            };
            if y.z <= 0.0 {
                continue;
            }
            let u = pinhole.pixel_from_normalised(&Vector2::new(y.x / y.z, y.y / y.z));
            if u.x >= 0.0 && u.y >= 0.0 && u.x < w as f64 && u.y < h as f64 {
                known.insert(u.x as f32, u.y as f32, y.z);
            }
        }
        known
    }
}

/// Map points projected into a keyframe, bucketed by `spacing`-pixel cells.
struct KnownPoints {
    cells: Vec<Vec<(f32, f32, f64)>>,
    columns: usize,
    spacing: f32,
    same_surface: f64,
}

impl KnownPoints {
    fn new(width: usize, height: usize, spacing: f64, same_surface: f64) -> Self {
        let spacing = spacing.max(1.0) as f32;
        let columns = (width as f32 / spacing).ceil() as usize + 1;
        let rows = (height as f32 / spacing).ceil() as usize + 1;
        KnownPoints {
            cells: vec![Vec::new(); columns * rows],
            columns,
            spacing,
            same_surface,
        }
    }

    fn cell(&self, u: f32, v: f32) -> (usize, usize) {
        ((u / self.spacing) as usize, (v / self.spacing) as usize)
    }

    fn insert(&mut self, u: f32, v: f32, depth: f64) {
        let (c, r) = self.cell(u, v);
        if let Some(cell) = self.cells.get_mut(r * self.columns + c) {
            cell.push((u, v, depth));
        }
    }

    /// Whether a known point lies within `spacing` pixels of `(u, v)` at a depth within
    /// `same_surface` of `depth` (relative).
    fn near(&self, u: f32, v: f32, depth: f64) -> bool {
        let (c, r) = self.cell(u, v);
        let rows = self.cells.len() / self.columns;
        (r.saturating_sub(1)..=(r + 1).min(rows - 1)).any(|r| {
            (c.saturating_sub(1)..=(c + 1).min(self.columns - 1)).any(|c| {
                self.cells[r * self.columns + c].iter().any(|&(x, y, d)| {
                    (x - u).abs() <= self.spacing
                        && (y - v).abs() <= self.spacing
                        && (d - depth).abs() <= self.same_surface * depth
                })
            })
        })
    }
}

/// The stereo measurement of a pixel of `frame` where its depth is known off depth edges and
/// gives at least `min_disparity` pixels of disparity.
fn stereo_measurement(
    frame: &FrameData,
    sensor: &SensorFrontEnd,
    u: Vector2<f64>,
    min_disparity: f64,
) -> Option<Vector3<f64>> {
    let z = frame.stereo_measurement(u, sensor.camera())?;
    (z.x - z.z >= min_disparity).then_some(z)
}

/// The guided search of map points in a keyframe's frame at a predicted pose: metric loop
/// closure's (thesis §6.4.1, the keyframe's tracked pose) and the guided matching of an
/// appearance loop (§6.4.2, the pose the loop implies). Each point that projects inside the
/// image and passes PTAM's viewing-angle test is searched within `radius` pixels
/// ([`search`]); a match with a depth becomes a stereo measurement.
pub struct GuidedSearch<'a> {
    /// The frame searched.
    pub frame: &'a FrameData,
    /// The keyframes' images (the templates come from the points' anchors).
    pub store: &'a KeyframeStore,
    /// The sensor.
    pub sensor: &'a SensorFrontEnd,
    /// Search radius (pixels).
    pub radius: f64,
    /// Correlation a patch match needs.
    pub min_ncc: f32,
    /// The visibility test's largest viewing-angle change (radians).
    pub max_view_angle: f64,
    /// Smallest disparity of a measurement (pixels).
    pub min_disparity: f64,
}

/// What guided search needs of `points` of `graph` (copied out under its read lock).
pub fn search_points(
    graph: &SlamGraph<3>,
    points: impl IntoIterator<Item = PointId>,
) -> Vec<SearchPoint> {
    points
        .into_iter()
        .filter_map(|p| SearchPoint::from_graph(graph, p))
        .collect()
}

impl GuidedSearch<'_> {
    /// Searches `points` ([`search_points`]) with the frame at `camera_from_world`; returns
    /// the found points' measurements, and the number of points predicted visible (searched):
    /// how much of what should be there was found.
    pub fn run_counted(
        &self,
        camera_from_world: &Se3,
        points: &[SearchPoint],
        scratch: &mut SearchScratch,
    ) -> (Vec<(PointId, Vector3<f64>)>, usize) {
        let camera = *self.sensor.pinhole();
        let (w, h) = (self.frame.gray().width(), self.frame.gray().height());
        let mut found = Vec::new();
        let mut predicted = 0;
        for point in points {
            let p = point.point;
            let visible = predict(&camera, camera_from_world, point, w, h, 6.0).is_some()
                && view_angle(camera_from_world, point) < self.max_view_angle;
            let Some(anchor) = self.store.get(point.anchor).filter(|_| visible) else {
                continue;
            };
            predicted += 1;
            let Some(u) = search(
                &camera,
                camera_from_world,
                point,
                anchor,
                self.frame.gray(),
                &self.frame.corners,
                self.radius,
                self.min_ncc,
                scratch,
            ) else {
                continue;
            };
            if let Some(z) = stereo_measurement(self.frame, self.sensor, u, self.min_disparity) {
                found.push((p, z));
            }
        }
        (found, predicted)
    }
}

impl FrontEnd<3> for KeyframeAssociation<'_> {
    fn match_candidates(
        &mut self,
        _: &SlamGraph<3>,
        candidates: &BTreeSet<PointId>,
    ) -> Vec<(PointId, SVector<f64, 3>)> {
        self.matches
            .iter()
            .filter(|(p, _)| candidates.contains(p))
            .copied()
            .collect()
    }

    fn given_pose(&mut self, _: &SlamGraph<3>, _: &[(PointId, SVector<f64, 3>)]) -> Option<Sim3> {
        Some(self.camera_from_world)
    }

    fn given_pose_tracked_against(&self) -> Option<(KeyframeId, Sim3, Version)> {
        self.tracked_against
    }

    /// None: the loop closer ([`crate::loops`]) recognises places in its own thread and
    /// closes their loops through the same `Mapper::close_appearance_loop`.
    fn recognise_place(&mut self, _: &SlamGraph<3>, _: KeyframeId) -> Option<AppearanceMatch<3>> {
        None
    }

    /// The keyframe's pose and the predicted points.
    type GuidedSearch = Option<(Se3, Vec<SearchPoint>)>;

    fn plan_guided_search(
        &mut self,
        graph: &SlamGraph<3>,
        keyframe: KeyframeId,
        predictions: &[(PointId, SVector<f64, 3>)],
    ) -> Self::GuidedSearch {
        let pose = graph.pose(keyframe).ok()?;
        Some((
            pose.rigid_part(),
            search_points(graph, predictions.iter().map(|(p, _)| *p)),
        ))
    }

    fn guided_search(&mut self, plan: Self::GuidedSearch) -> Vec<(PointId, SVector<f64, 3>)> {
        let Some((pose, points)) = plan else {
            return Vec::new();
        };
        // Every candidate of N2 \ N1 (thesis §6.4.1) that passes PTAM's visibility test.
        GuidedSearch {
            frame: self.frame,
            store: self.store,
            sensor: self.sensor,
            radius: self.loop_radius,
            min_ncc: self.min_ncc,
            max_view_angle: self.max_view_angle,
            min_disparity: self.min_disparity,
        }
        .run_counted(&pose, &points, &mut self.scratch)
        .0
    }

    fn new_map(&self) -> bool {
        self.new_map
    }

    fn measurements(
        &mut self,
        graph: &SlamGraph<3>,
        keyframe: KeyframeId,
    ) -> Vec<(TrackId, SVector<f64, 3>, bool)> {
        // New points where the keyframe has none within `spacing`: the quadtree's
        // equi-distributed order over its FAST corners with depth (thesis §3.4.3).
        let (w, h) = (self.frame.gray().width(), self.frame.gray().height());
        let min_cell = (self.spacing as f32 * 0.5).max(1.0);
        let mut occupied = QuadTree::new(w as f32, h as f32, min_cell);
        if let Some(kf) = graph.keyframe(keyframe) {
            for (i, z) in kf.observations().values().enumerate() {
                occupied.insert(QuadPoint {
                    u: z.x as f32,
                    v: z.y as f32,
                    score: 0.0,
                    index: i,
                });
            }
        }
        // With `reuse_map_points`, the map's points already in view (those the keyframe's
        // neighbours measure, projected at its pose): a corner where one of them lies on the
        // same surface is that point, not a new one, even if tracking did not find it (a view
        // seen again does not add its surfaces' points once more).
        let known = if self.reuse_map_points {
            self.known_points(graph, keyframe)
        } else {
            KnownPoints::new(w, h, self.spacing, self.same_surface)
        };
        let corners = self.frame.corners.corners();
        let candidates = vision::quadtree::quad_points(corners);
        let tree = QuadTree::from_points(w as f32, h as f32, min_cell, &candidates);
        let r = self.spacing as f32;
        let mut out = Vec::new();
        for c in tree.traverse(self.frame.index as u64) {
            if out.len() >= self.max_new_points {
                break;
            }
            if occupied.count_in_box(c.u - r, c.v - r, c.u + r, c.v + r) > 0 {
                continue;
            }
            let Some(z) = self.stereo_measurement(Vector2::new(c.u as f64, c.v as f64)) else {
                continue;
            };
            let depth = self.sensor.camera().depth_from_disparity(z.x - z.z);
            if depth.is_ok_and(|d| known.near(c.u, c.v, d)) {
                continue;
            }
            occupied.insert(c);
            let track = *self.next_track;
            *self.next_track += 1;
            out.push((track, z, false));
        }
        out
    }

    fn points_created(&mut self, created: &[(TrackId, PointId)]) {
        self.created.extend_from_slice(created);
    }
}
