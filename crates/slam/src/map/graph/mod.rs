//! The SLAM graph of double window optimisation (thesis §6.2.2, Figure 6.3).
//!
//! - **Keyframe vertices** `V_i` hold their *absolute* pose `T_i = camera_from_world` (a
//!   similarity: for stereo and RGB-D its scale stays 1; for monocular SLAM it changes only at
//!   large loop closures, thesis §6.2.7), the points visible from them and the corresponding
//!   measurements `z_ik`.
//! - **Points** are anchored inverse-depth features (thesis §6.2.4): `ψ_k = (x/z, y/z, 1/z)` in
//!   the frame of their anchor keyframe `T_a(k)` (the one that first saw them), so that
//!   `y_k^[world] = T_a(k)⁻¹·Π(ψ_k)` (thesis eq. 6.4).
//! - **Edges** `E_ij` connect covisible keyframes; each carries the covisibility weight `w_ij`,
//!   the number of points seen by both, and is either *marginalised* — it then stores the
//!   relative pose `T_ji` (frame `i` into frame `j`) used as a pose-pose constraint — or not, in
//!   which case the relative pose is implicit, `T_ji = T_j·T_i⁻¹`, and the point-pose
//!   constraints of the inner window define it.
//! - Exactly one keyframe is the **reference keyframe** `V_ref` (the centre of interest),
//!   usually the newest one.
//!
//! Neighbourhoods are found by weighted breadth-first search ([`SlamGraph::weighted_bfs`]):
//! breadth first from the root, and among the neighbours of a vertex those with the highest
//! covisibility weight first (thesis §6.2.3); `N1` (thesis eq. 6.5) and `N2` (§6.4.1) are
//! [`SlamGraph::n1`] and [`SlamGraph::n2`].
//!
//! Invariants (checked by [`SlamGraph::check_invariants`], kept by every mutation, including
//! removals): every point's anchor is a keyframe of the graph that observes it; a point's
//! observer set and the keyframes' observation maps agree; edges are symmetric with equal
//! weights and mutually inverse stored poses; every edge weight equals the number of points
//! the two keyframes share; the reference keyframe exists.
//!
//! ## Versions
//!
//! Every mutation advances the graph's [`Version`] ([`SlamGraph::version`]); each keyframe
//! records the version at which its pose last changed ([`Keyframe::pose_version`]) and each
//! point the version at which its position (`ψ` or anchor) last changed
//! ([`MapPoint::version`]). A writer that planned on the graph at version `v` (an optimiser
//! running without the lock, [`crate::map::shared`]) finds what moved since: a pose with
//! `pose_version > v` was changed by someone else (a loop correction) and must not be
//! overwritten with a result computed from the old one.

use lie::{LieGroup, Sim3};
use nalgebra::{SVector, Vector3};
use std::collections::{BTreeMap, BTreeSet, VecDeque};

use super::ids::{KeyframeId, PointId};
use super::maps::{self, MapJoin};
use crate::factors::{MIN_INVERSE_DEPTH, inverse_depth_to_point, point_to_inverse_depth};

mod parts;
pub use parts::{GraphParts, KeyframePart, PointPart};

/// A count of the mutations of a graph (see the module docs on versions).
pub type Version = u64;

/// An edge `E_ij` as stored at vertex `i` (thesis §6.2.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Edge {
    /// Covisibility weight `w_ij`: the number of points seen by both keyframes.
    pub weight: usize,
    /// `Some(T_ji)` (frame `i` into frame `j`, `j` being the other end) when the edge is
    /// marginalised; `None` when its relative pose is implicit (`T_j·T_i⁻¹`).
    pub relative: Option<Sim3>,
}

/// A keyframe vertex `V_i`.
#[derive(Clone, Debug)]
pub struct Keyframe<const N: usize> {
    camera_from_world: Sim3,
    pose_version: Version,
    /// The map it belongs to ([`SlamGraph::start_map`]).
    map: usize,
    observations: BTreeMap<PointId, SVector<f64, N>>,
    edges: BTreeMap<KeyframeId, Edge>,
}

impl<const N: usize> Keyframe<N> {
    /// The map the keyframe belongs to ([`SlamGraph::start_map`]; 0 unless a live system
    /// started another).
    pub fn map(&self) -> usize {
        self.map
    }

    /// The absolute pose `T_i` (scale 1 except after monocular loop closures).
    pub fn camera_from_world(&self) -> &Sim3 {
        &self.camera_from_world
    }

    /// The graph version at which the pose last changed.
    pub fn pose_version(&self) -> Version {
        self.pose_version
    }

    /// The measurements `z_ik` of the points visible from this keyframe.
    pub fn observations(&self) -> &BTreeMap<PointId, SVector<f64, N>> {
        &self.observations
    }

    /// The edges of this keyframe, by the other end.
    pub fn edges(&self) -> &BTreeMap<KeyframeId, Edge> {
        &self.edges
    }
}

/// A map point: an anchored inverse-depth feature (thesis §6.2.4).
#[derive(Clone, Debug)]
pub struct MapPoint {
    anchor: KeyframeId,
    inverse_depth: Vector3<f64>,
    version: Version,
    observers: BTreeSet<KeyframeId>,
}

impl MapPoint {
    /// The anchor keyframe `a(k)`.
    pub fn anchor(&self) -> KeyframeId {
        self.anchor
    }

    /// `ψ = (x/z, y/z, 1/z)` of the point in the anchor frame.
    pub fn inverse_depth(&self) -> &Vector3<f64> {
        &self.inverse_depth
    }

    /// The graph version at which `ψ` or the anchor last changed.
    pub fn version(&self) -> Version {
        self.version
    }

    /// The keyframes observing this point (the anchor among them).
    pub fn observers(&self) -> &BTreeSet<KeyframeId> {
        &self.observers
    }
}

/// Why a graph operation was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphError {
    /// No keyframe with this id.
    #[error("keyframe {0} is not in the graph")]
    UnknownKeyframe(KeyframeId),
    /// No point with this id.
    #[error("point {0} is not in the graph")]
    UnknownPoint(PointId),
    /// An edge from a keyframe to itself.
    #[error("an edge must join two different keyframes (got {0} twice)")]
    SelfEdge(KeyframeId),
    /// An inverse depth that does not describe a point in front of the anchor.
    #[error("inverse depth {0} is not positive and finite")]
    BadInverseDepth(f64),
    /// An invariant does not hold (see [`SlamGraph::check_invariants`]).
    #[error("graph invariant violated: {0}")]
    Invariant(String),
    /// Two keyframes of one map where two maps were expected ([`SlamGraph::join_maps`]).
    #[error("keyframes {0} and {1} are in one map: nothing to join")]
    SameMap(KeyframeId, KeyframeId),
}

/// The result of a weighted breadth-first search: the visiting order and the spanning tree.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BfsTree {
    /// Keyframes in the order visited, the root first.
    pub order: Vec<KeyframeId>,
    /// The parent of each visited keyframe in the BFS spanning tree (`None` for the root).
    pub parent: BTreeMap<KeyframeId, Option<KeyframeId>>,
}

/// The SLAM graph (thesis §6.2.2), generic in the measurement dimension `N` (2 for monocular,
/// 3 for stereo and RGB-D measurements `(u_l, v_l, u_r)`).
#[derive(Clone, Debug, Default)]
pub struct SlamGraph<const N: usize> {
    keyframes: Vec<Option<Keyframe<N>>>,
    points: Vec<Option<MapPoint>>,
    reference: Option<KeyframeId>,
    num_keyframes: usize,
    num_points: usize,
    version: Version,
    /// The map new keyframes join.
    current_map: usize,
    /// The number of maps started (the first included).
    maps_started: usize,
    /// The merges so far, oldest first.
    merges: Vec<MapMerge>,
    /// The joins so far, oldest first ([`SlamGraph::join_maps`]).
    joins: Vec<MapJoin>,
}

/// The map a graph starts with (the world: the frame of the first keyframe).
pub const FIRST_MAP: usize = 0;

/// A merge of one map into another ([`SlamGraph::merge_map`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapMerge {
    /// The map merged (it exists no more).
    pub from: usize,
    /// The map it joined.
    pub into: usize,
    /// How its poses moved: every `camera_from_world` `T ← T·moved`. A pose kept outside the
    /// graph in the merged map's frame (a tracker's last pose) follows alike.
    pub moved: Sim3,
}

impl<const N: usize> SlamGraph<N> {
    /// An empty graph.
    pub fn new() -> Self {
        SlamGraph {
            keyframes: Vec::new(),
            points: Vec::new(),
            reference: None,
            num_keyframes: 0,
            num_points: 0,
            version: 0,
            current_map: FIRST_MAP,
            maps_started: FIRST_MAP + 1,
            merges: Vec::new(),
            joins: Vec::new(),
        }
    }

    /// The current version: the number of mutations so far.
    pub fn version(&self) -> Version {
        self.version
    }

    /// Advances the version (every mutation calls this first) and returns the new one.
    fn bump(&mut self) -> Version {
        self.version += 1;
        self.version
    }

    /// Number of keyframes.
    pub fn num_keyframes(&self) -> usize {
        self.num_keyframes
    }

    /// Number of points.
    pub fn num_points(&self) -> usize {
        self.num_points
    }

    /// Number of (undirected) edges.
    pub fn num_edges(&self) -> usize {
        self.keyframes().map(|(_, k)| k.edges.len()).sum::<usize>() / 2
    }

    /// The keyframe `id`, if present.
    pub fn keyframe(&self, id: KeyframeId) -> Option<&Keyframe<N>> {
        self.keyframes.get(id.index()).and_then(Option::as_ref)
    }

    /// The point `id`, if present.
    pub fn point(&self, id: PointId) -> Option<&MapPoint> {
        self.points.get(id.index()).and_then(Option::as_ref)
    }

    /// All keyframes in id order.
    pub fn keyframes(&self) -> impl Iterator<Item = (KeyframeId, &Keyframe<N>)> {
        self.keyframes
            .iter()
            .enumerate()
            .filter_map(|(i, k)| k.as_ref().map(|k| (KeyframeId::from_index(i), k)))
    }

    /// All points in id order.
    pub fn points(&self) -> impl Iterator<Item = (PointId, &MapPoint)> {
        self.points
            .iter()
            .enumerate()
            .filter_map(|(i, p)| p.as_ref().map(|p| (PointId::from_index(i), p)))
    }

    /// The upper bound of keyframe id indices (every id's [`KeyframeId::index`] is below it).
    pub fn keyframe_id_bound(&self) -> usize {
        self.keyframes.len()
    }

    /// The upper bound of point id indices.
    pub fn point_id_bound(&self) -> usize {
        self.points.len()
    }

    fn kf(&self, id: KeyframeId) -> Result<&Keyframe<N>, GraphError> {
        self.keyframe(id).ok_or(GraphError::UnknownKeyframe(id))
    }

    fn kf_mut(&mut self, id: KeyframeId) -> Result<&mut Keyframe<N>, GraphError> {
        self.keyframes
            .get_mut(id.index())
            .and_then(Option::as_mut)
            .ok_or(GraphError::UnknownKeyframe(id))
    }

    fn pt_mut(&mut self, id: PointId) -> Result<&mut MapPoint, GraphError> {
        self.points
            .get_mut(id.index())
            .and_then(Option::as_mut)
            .ok_or(GraphError::UnknownPoint(id))
    }

    /// The absolute pose `T_i` of keyframe `id`.
    pub fn pose(&self, id: KeyframeId) -> Result<Sim3, GraphError> {
        Ok(self.kf(id)?.camera_from_world)
    }

    /// Sets the absolute pose of keyframe `id`.
    pub fn set_pose(&mut self, id: KeyframeId, camera_from_world: Sim3) -> Result<(), GraphError> {
        self.kf(id)?;
        let v = self.bump();
        let k = self.kf_mut(id)?;
        k.camera_from_world = camera_from_world;
        k.pose_version = v;
        Ok(())
    }

    /// Starts a new map: the keyframes added from now on belong to it, with poses in a frame
    /// of their own, joined to the older maps by no edge until [`SlamGraph::merge_map`] (a
    /// live system that lost its camera and could not find it again in the map goes on in a
    /// new one, as ORB-SLAM3's atlas does). Returns its number.
    ///
    /// The graph has no reference keyframe until the new map's first keyframe is made one
    /// (the old reference is in another map: a keyframe registered to it would join the maps
    /// by an edge measuring the guessed offset between their frames).
    pub fn start_map(&mut self) -> usize {
        self.bump();
        self.reference = None;
        self.current_map = self.maps_started;
        self.maps_started += 1;
        self.current_map
    }

    /// The map new keyframes join.
    pub fn current_map(&self) -> usize {
        self.current_map
    }

    /// The map of keyframe `id`.
    pub fn map_of(&self, id: KeyframeId) -> Result<usize, GraphError> {
        Ok(self.kf(id)?.map)
    }

    /// Merges the map of `keyframe` into the map of `into`: its keyframes move as one rigid
    /// body (a similarity) so that `keyframe` comes to `camera_from_world` (every keyframe
    /// `T ← T·T_k⁻¹·T'_k`; the points, anchored in keyframes, move with them) and belong to
    /// `into`'s map from then on. Returns how many keyframes moved (none if the two are in
    /// one map already).
    ///
    /// What joining two maps needs before the edge between them goes in: the newer map's
    /// poses are relative to a guessed start, metres off the old map, and an edge measuring
    /// the true relative pose would meet that offset in the next optimisation.
    pub fn merge_map(
        &mut self,
        keyframe: KeyframeId,
        camera_from_world: &Sim3,
        into: KeyframeId,
    ) -> Result<usize, GraphError> {
        let (from, to) = (self.map_of(keyframe)?, self.map_of(into)?);
        if from == to {
            // One map: nothing to join (and moving it would move `into` too).
            return Ok(0);
        }
        let moved = self.pose(keyframe)?.inverse().compose(camera_from_world);
        let v = self.bump();
        let mut count = 0;
        for k in self
            .keyframes
            .iter_mut()
            .flatten()
            .filter(|k| k.map == from)
        {
            k.camera_from_world = k.camera_from_world.compose(&moved);
            k.pose_version = v;
            k.map = to;
            count += 1;
        }
        if self.current_map == from {
            self.current_map = to;
        }
        self.merges.push(MapMerge {
            from,
            into: to,
            moved,
        });
        Ok(count)
    }

    /// The merges so far, oldest first ([`SlamGraph::merge_map`]): a holder of poses in a map's
    /// frame applies those after the last it saw.
    pub fn merges(&self) -> &[MapMerge] {
        &self.merges
    }

    /// What the merges after the first `seen` did to the poses of map `map`: the transform
    /// `moved` they took (`T ← T·moved`) and the map they are in now; `None` if none moved it.
    pub fn moved_since(&self, seen: usize, mut map: usize) -> Option<(Sim3, usize)> {
        let mut moved: Option<Sim3> = None;
        for merge in self.merges.iter().skip(seen) {
            if merge.from == map {
                moved = Some(moved.map_or(merge.moved, |m| m.compose(&merge.moved)));
                map = merge.into;
            }
        }
        moved.map(|m| (m, map))
    }

    /// Records that keyframe `current` sees the place of keyframe `old` of another map, with
    /// `x_current = S·x_old` for camera-frame points, verified by `inliers` matches: the two
    /// maps are joined, and stay apart in the graph ([`super::maps`]; the monocular system's
    /// maps have scales of their own). The outputs put the joined maps into one world
    /// ([`SlamGraph::written_maps`]).
    pub fn join_maps(
        &mut self,
        current: KeyframeId,
        old: KeyframeId,
        current_from_old: Sim3,
        inliers: usize,
    ) -> Result<(), GraphError> {
        if self.map_of(current)? == self.map_of(old)? {
            return Err(GraphError::SameMap(current, old));
        }
        self.bump();
        self.joins.push(MapJoin {
            current,
            old,
            current_from_old,
            inliers,
        });
        Ok(())
    }

    /// The joins so far, oldest first ([`SlamGraph::join_maps`]).
    pub fn joins(&self) -> &[MapJoin] {
        &self.joins
    }

    /// `(map, keyframes)` of every map with keyframes, in map order.
    pub fn keyframes_per_map(&self) -> Vec<(usize, usize)> {
        let mut count = BTreeMap::<usize, usize>::new();
        for (_, k) in self.keyframes() {
            *count.entry(k.map).or_default() += 1;
        }
        count.into_iter().collect()
    }

    /// The maps a run writes ([`maps::written_maps`]): the group of maps joined together with
    /// the most keyframes, in the world of its map with the most keyframes. Returns that map
    /// and every map of the group with `x_map = W·x_world` (the links from each pair's best
    /// join, with the keyframes' poses as they are now: [`maps::map_links`]).
    pub fn written_maps(&self) -> (usize, BTreeMap<usize, Sim3>) {
        let links = maps::map_links(&self.joins, |k| self.map_of(k).ok(), |k| self.pose(k).ok());
        maps::written_maps(&self.keyframes_per_map(), &links, FIRST_MAP)
    }

    /// The reference keyframe `V_ref`.
    pub fn reference(&self) -> Option<KeyframeId> {
        self.reference
    }

    /// Makes `id` the reference keyframe.
    pub fn set_reference(&mut self, id: KeyframeId) -> Result<(), GraphError> {
        let map = self.kf(id)?.map;
        self.bump();
        self.reference = Some(id);
        // New keyframes join the map the camera is tracked in (a relocalisation may have found
        // it in an older map than the one started last).
        self.current_map = map;
        Ok(())
    }

    /// Adds a keyframe vertex with absolute pose `camera_from_world`; the first keyframe
    /// becomes the reference.
    pub fn add_keyframe(&mut self, camera_from_world: Sim3) -> KeyframeId {
        let pose_version = self.bump();
        let id = KeyframeId::from_index(self.keyframes.len());
        self.keyframes.push(Some(Keyframe {
            camera_from_world,
            pose_version,
            map: self.current_map,
            observations: BTreeMap::new(),
            edges: BTreeMap::new(),
        }));
        self.num_keyframes += 1;
        if self.reference.is_none() {
            self.reference = Some(id);
        }
        id
    }

    /// Adds a point anchored at `anchor` with inverse depth `ψ`, observed there as `z`.
    pub fn add_point(
        &mut self,
        anchor: KeyframeId,
        inverse_depth: Vector3<f64>,
        measurement: SVector<f64, N>,
    ) -> Result<PointId, GraphError> {
        self.kf(anchor)?;
        if !(inverse_depth.iter().all(|v| v.is_finite()) && inverse_depth.z > MIN_INVERSE_DEPTH) {
            return Err(GraphError::BadInverseDepth(inverse_depth.z));
        }
        let version = self.bump();
        let id = PointId::from_index(self.points.len());
        self.points.push(Some(MapPoint {
            anchor,
            inverse_depth,
            version,
            observers: BTreeSet::new(),
        }));
        self.num_points += 1;
        self.add_observation(anchor, id, measurement)?;
        Ok(id)
    }

    /// Records that keyframe `keyframe` measures point `point` as `z` (replacing an earlier
    /// measurement); the weights of the keyframe's edges to the point's other observers grow
    /// by one.
    pub fn add_observation(
        &mut self,
        keyframe: KeyframeId,
        point: PointId,
        measurement: SVector<f64, N>,
    ) -> Result<(), GraphError> {
        self.kf(keyframe)?;
        self.point(point).ok_or(GraphError::UnknownPoint(point))?;
        self.bump();
        let observers: Vec<KeyframeId> = {
            let p = self.pt_mut(point)?;
            if !p.observers.insert(keyframe) {
                // Already observed: only the measurement changes.
                self.kf_mut(keyframe)?
                    .observations
                    .insert(point, measurement);
                return Ok(());
            }
            p.observers
                .iter()
                .copied()
                .filter(|&o| o != keyframe)
                .collect()
        };
        self.kf_mut(keyframe)?
            .observations
            .insert(point, measurement);
        for o in observers {
            self.bump_weight(keyframe, o, 1);
        }
        Ok(())
    }

    fn bump_weight(&mut self, a: KeyframeId, b: KeyframeId, delta: isize) {
        for (x, y) in [(a, b), (b, a)] {
            if let Some(e) = self.keyframes[x.index()]
                .as_mut()
                .and_then(|k| k.edges.get_mut(&y))
            {
                e.weight = e.weight.saturating_add_signed(delta);
            }
        }
    }

    /// Removes the observation of `point` from `keyframe`. If `keyframe` is the anchor, the
    /// point is re-anchored at its oldest remaining observer (`ψ` re-expressed there:
    /// `y' = T_new·T_a⁻¹·Π(ψ)`); a point left without observers is removed.
    pub fn remove_observation(
        &mut self,
        keyframe: KeyframeId,
        point: PointId,
    ) -> Result<(), GraphError> {
        self.kf(keyframe)?;
        if !self
            .point(point)
            .ok_or(GraphError::UnknownPoint(point))?
            .observers
            .contains(&keyframe)
        {
            return Ok(());
        }
        let version = self.bump();
        let (was_anchor, others) = {
            let p = self.pt_mut(point)?;
            p.observers.remove(&keyframe);
            (
                p.anchor == keyframe,
                p.observers.iter().copied().collect::<Vec<_>>(),
            )
        };
        self.kf_mut(keyframe)?.observations.remove(&point);
        for &o in &others {
            self.bump_weight(keyframe, o, -1);
        }
        if others.is_empty() {
            self.points[point.index()] = None;
            self.num_points -= 1;
            return Ok(());
        }
        if was_anchor {
            let new_anchor = others[0];
            let y_old = self.point_in_anchor(point)?;
            let t_old = self.pose(keyframe)?;
            let t_new = self.pose(new_anchor)?;
            match point_to_inverse_depth(&t_new.compose(&t_old.inverse()).act(&y_old)) {
                Some(psi) => {
                    let p = self.pt_mut(point)?;
                    p.anchor = new_anchor;
                    p.inverse_depth = psi;
                    p.version = version;
                }
                // Behind the new anchor: the point cannot be represented there; drop it.
                None => self.remove_point(point)?,
            }
        }
        Ok(())
    }

    /// Removes a point and all its observations.
    pub fn remove_point(&mut self, point: PointId) -> Result<(), GraphError> {
        let observers: Vec<KeyframeId> = self
            .point(point)
            .ok_or(GraphError::UnknownPoint(point))?
            .observers
            .iter()
            .copied()
            .collect();
        self.bump();
        for (n, &a) in observers.iter().enumerate() {
            self.kf_mut(a)?.observations.remove(&point);
            for &b in &observers[n + 1..] {
                self.bump_weight(a, b, -1);
            }
        }
        self.points[point.index()] = None;
        self.num_points -= 1;
        Ok(())
    }

    /// Removes a keyframe: its observations (re-anchoring or removing its points), its edges;
    /// if it was the reference, its strongest neighbour (or any keyframe) becomes the reference.
    pub fn remove_keyframe(&mut self, id: KeyframeId) -> Result<(), GraphError> {
        let points: Vec<PointId> = self.kf(id)?.observations.keys().copied().collect();
        for p in points {
            self.remove_observation(id, p)?;
        }
        let neighbours: Vec<KeyframeId> = self.kf(id)?.edges.keys().copied().collect();
        let strongest = self.neighbours_by_weight(id).first().map(|&(n, _)| n);
        self.bump();
        for n in neighbours {
            self.kf_mut(n)?.edges.remove(&id);
        }
        self.keyframes[id.index()] = None;
        self.num_keyframes -= 1;
        if self.reference == Some(id) {
            self.reference = strongest.or_else(|| self.keyframes().map(|(k, _)| k).last());
        }
        Ok(())
    }

    /// The number of points seen by both keyframes.
    pub fn shared_points(&self, a: KeyframeId, b: KeyframeId) -> usize {
        match (self.keyframe(a), self.keyframe(b)) {
            (Some(ka), Some(kb)) => {
                let (small, large) = if ka.observations.len() <= kb.observations.len() {
                    (ka, kb)
                } else {
                    (kb, ka)
                };
                small
                    .observations
                    .keys()
                    .filter(|p| large.observations.contains_key(p))
                    .count()
            }
            _ => 0,
        }
    }

    /// Adds (or updates) the edge `E_ab` with weight = shared points; `relative_ba` is
    /// `Some(T_ba)` (frame `a` into frame `b`) for a marginalised edge.
    pub fn add_edge(
        &mut self,
        a: KeyframeId,
        b: KeyframeId,
        relative_ba: Option<Sim3>,
    ) -> Result<(), GraphError> {
        if a == b {
            return Err(GraphError::SelfEdge(a));
        }
        self.kf(a)?;
        self.kf(b)?;
        self.bump();
        let weight = self.shared_points(a, b);
        self.kf_mut(a)?.edges.insert(
            b,
            Edge {
                weight,
                relative: relative_ba,
            },
        );
        self.kf_mut(b)?.edges.insert(
            a,
            Edge {
                weight,
                relative: relative_ba.map(|t| t.inverse()),
            },
        );
        Ok(())
    }

    /// Removes the edge `E_ab` if present.
    pub fn remove_edge(&mut self, a: KeyframeId, b: KeyframeId) -> Result<(), GraphError> {
        self.kf(a)?;
        self.kf(b)?;
        self.bump();
        self.kf_mut(a)?.edges.remove(&b);
        self.kf_mut(b)?.edges.remove(&a);
        Ok(())
    }

    /// The edge `E_ab` as seen from `a` (its stored pose, if any, is `T_ba`).
    pub fn edge(&self, a: KeyframeId, b: KeyframeId) -> Option<&Edge> {
        self.keyframe(a)?.edges.get(&b)
    }

    /// Marks `E_ab` marginalised with relative pose `T_ba` (`Some`) or not marginalised
    /// (`None`); `false` (and nothing changes) if the edge does not exist.
    pub fn set_edge_relative(
        &mut self,
        a: KeyframeId,
        b: KeyframeId,
        relative_ba: Option<Sim3>,
    ) -> bool {
        if self.edge(a, b).is_none() {
            return false;
        }
        self.bump();
        for (x, y, t) in [
            (a, b, relative_ba),
            (b, a, relative_ba.map(|t| t.inverse())),
        ] {
            if let Some(e) = self.keyframes[x.index()]
                .as_mut()
                .and_then(|k| k.edges.get_mut(&y))
            {
                e.relative = t;
            }
        }
        true
    }

    /// The relative pose `T_ba` (frame `a` into frame `b`): the stored constraint of a
    /// marginalised edge, otherwise the implicit `T_b·T_a⁻¹` of the absolute poses.
    pub fn relative_pose(&self, a: KeyframeId, b: KeyframeId) -> Result<Sim3, GraphError> {
        if let Some(t) = self.edge(a, b).and_then(|e| e.relative) {
            return Ok(t);
        }
        Ok(self.pose(b)?.compose(&self.pose(a)?.inverse()))
    }

    /// The neighbours of `id`, strongest (highest covisibility weight) first, ties by id.
    pub fn neighbours_by_weight(&self, id: KeyframeId) -> Vec<(KeyframeId, usize)> {
        let Some(k) = self.keyframe(id) else {
            return Vec::new();
        };
        let mut n: Vec<(KeyframeId, usize)> = k.edges.iter().map(|(&j, e)| (j, e.weight)).collect();
        n.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        n
    }

    /// Weighted breadth-first search from `root` (thesis §6.2.3): vertices are visited in FIFO
    /// order, the neighbours of each pushed strongest first; stops after `limit` vertices.
    /// Returns the visiting order and the BFS spanning tree rooted at `root`.
    pub fn weighted_bfs(&self, root: KeyframeId, limit: usize) -> BfsTree {
        self.weighted_bfs_within(root, limit, |_| true)
    }

    /// [`SlamGraph::weighted_bfs`] through the keyframes `within` accepts only (the root is
    /// always visited): the spanning tree of a window (`crate::dwo`).
    pub fn weighted_bfs_within(
        &self,
        root: KeyframeId,
        limit: usize,
        within: impl Fn(KeyframeId) -> bool,
    ) -> BfsTree {
        let mut tree = BfsTree::default();
        if self.keyframe(root).is_none() || limit == 0 {
            return tree;
        }
        let mut queue = VecDeque::from([(root, None)]);
        while let Some((v, parent)) = queue.pop_front() {
            if tree.parent.contains_key(&v) {
                continue;
            }
            tree.parent.insert(v, parent);
            tree.order.push(v);
            if tree.order.len() >= limit {
                break;
            }
            for (n, _) in self.neighbours_by_weight(v) {
                if within(n) && !tree.parent.contains_key(&n) {
                    queue.push_back((n, Some(v)));
                }
            }
        }
        tree
    }

    /// `N1 = {V_i : E_ref,i ∈ E} ∪ {V_ref}` (thesis eq. 6.5), the root first.
    pub fn n1(&self, root: KeyframeId) -> Vec<KeyframeId> {
        let mut out = vec![root];
        out.extend(self.neighbours_by_weight(root).into_iter().map(|(n, _)| n));
        out
    }

    /// `N2`: the first `size` keyframes of the weighted BFS from `root` (thesis §6.4.1).
    pub fn n2(&self, root: KeyframeId, size: usize) -> Vec<KeyframeId> {
        self.weighted_bfs(root, size).order
    }

    /// The points visible from a set of keyframes (sorted, without duplicates).
    pub fn points_visible_from(&self, keyframes: &[KeyframeId]) -> BTreeSet<PointId> {
        keyframes
            .iter()
            .filter_map(|&k| self.keyframe(k))
            .flat_map(|k| k.observations.keys().copied())
            .collect()
    }

    /// The point in the frame of its anchor, `Π(ψ)`.
    pub fn point_in_anchor(&self, point: PointId) -> Result<Vector3<f64>, GraphError> {
        let p = self.point(point).ok_or(GraphError::UnknownPoint(point))?;
        Ok(inverse_depth_to_point(&p.inverse_depth))
    }

    /// The point in the frame of keyframe `frame`: `T_frame·T_a⁻¹·Π(ψ)`.
    pub fn point_in_frame(
        &self,
        point: PointId,
        frame: KeyframeId,
    ) -> Result<Vector3<f64>, GraphError> {
        let anchor = self
            .point(point)
            .ok_or(GraphError::UnknownPoint(point))?
            .anchor;
        let t = self.pose(frame)?.compose(&self.pose(anchor)?.inverse());
        Ok(t.act(&self.point_in_anchor(point)?))
    }

    /// The point in world coordinates: `T_a⁻¹·Π(ψ)`.
    pub fn point_world(&self, point: PointId) -> Result<Vector3<f64>, GraphError> {
        let anchor = self
            .point(point)
            .ok_or(GraphError::UnknownPoint(point))?
            .anchor;
        Ok(self
            .pose(anchor)?
            .inverse()
            .act(&self.point_in_anchor(point)?))
    }

    /// Sets the inverse depth `ψ` of a point.
    pub fn set_inverse_depth(
        &mut self,
        point: PointId,
        inverse_depth: Vector3<f64>,
    ) -> Result<(), GraphError> {
        if !(inverse_depth.iter().all(|v| v.is_finite()) && inverse_depth.z > MIN_INVERSE_DEPTH) {
            return Err(GraphError::BadInverseDepth(inverse_depth.z));
        }
        self.point(point).ok_or(GraphError::UnknownPoint(point))?;
        let version = self.bump();
        let p = self.pt_mut(point)?;
        p.inverse_depth = inverse_depth;
        p.version = version;
        Ok(())
    }

    /// The poses and points of the graph, for comparing two states of it (tests, and writers
    /// that check what changed): `(keyframe, pose)` and `(point, anchor, ψ)` in id order.
    #[allow(clippy::type_complexity)]
    pub fn snapshot_state(
        &self,
    ) -> (
        Vec<(KeyframeId, Sim3)>,
        Vec<(PointId, KeyframeId, Vector3<f64>)>,
    ) {
        (
            self.keyframes()
                .map(|(k, kf)| (k, kf.camera_from_world))
                .collect(),
            self.points()
                .map(|(p, pt)| (p, pt.anchor, pt.inverse_depth))
                .collect(),
        )
    }

    /// Checks every invariant of the module docs; the first violation is the error.
    pub fn check_invariants(&self) -> Result<(), GraphError> {
        let bad = |s: String| Err(GraphError::Invariant(s));
        let mut keyframe_count = 0;
        for (i, k) in self.keyframes() {
            keyframe_count += 1;
            for &p in k.observations.keys() {
                match self.point(p) {
                    None => return bad(format!("keyframe {i} observes missing point {p}")),
                    Some(pt) if !pt.observers.contains(&i) => {
                        return bad(format!("point {p} does not list observer {i}"));
                    }
                    _ => {}
                }
            }
            for (&j, e) in &k.edges {
                if i == j {
                    return bad(format!("self edge at {i}"));
                }
                let Some(back) = self.edge(j, i) else {
                    return bad(format!("edge {i}→{j} has no reverse"));
                };
                if back.weight != e.weight {
                    return bad(format!(
                        "edge {i}–{j} weights {} ≠ {}",
                        e.weight, back.weight
                    ));
                }
                let shared = self.shared_points(i, j);
                if e.weight != shared {
                    return bad(format!(
                        "edge {i}–{j} weight {} but {shared} shared points",
                        e.weight
                    ));
                }
                match (e.relative, back.relative) {
                    (None, None) => {}
                    (Some(a), Some(b)) => {
                        let d = a.compose(&b).log().amax();
                        if d > 1e-9 {
                            return bad(format!("edge {i}–{j} stored poses not inverse ({d:e})"));
                        }
                    }
                    _ => return bad(format!("edge {i}–{j} marginalised on one side only")),
                }
            }
        }
        if keyframe_count != self.num_keyframes {
            return bad("keyframe count".into());
        }
        let mut point_count = 0;
        for (p, pt) in self.points() {
            point_count += 1;
            if self.keyframe(pt.anchor).is_none() {
                return bad(format!(
                    "point {p} anchored at missing keyframe {}",
                    pt.anchor
                ));
            }
            if !pt.observers.contains(&pt.anchor) {
                return bad(format!(
                    "point {p} not observed by its anchor {}",
                    pt.anchor
                ));
            }
            for &o in &pt.observers {
                if !self
                    .keyframe(o)
                    .is_some_and(|k| k.observations.contains_key(&p))
                {
                    return bad(format!("point {p} lists observer {o} without observation"));
                }
            }
        }
        if point_count != self.num_points {
            return bad("point count".into());
        }
        match self.reference {
            None if self.num_keyframes > 0 => bad("no reference keyframe".into()),
            Some(r) if self.keyframe(r).is_none() => bad(format!("reference {r} missing")),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests;
