//! A graph taken apart into plain parts and put together again: what a map file stores
//! (`system::map_file`). [`SlamGraph::to_parts`] gives every keyframe and point with its id
//! (ids of removed elements stay unused, as in the graph); [`SlamGraph::from_parts`] checks
//! every part — ids in range and unique, poses and inverse depths valid, observations of
//! existing points, maps that were started — and then the graph's invariants, so that a
//! corrupted or hand-edited map is refused with its reason instead of breaking a later stage.

use super::{Edge, GraphError, Keyframe, MapMerge, MapPoint, SlamGraph, Version};
use crate::factors::MIN_INVERSE_DEPTH;
use crate::map::ids::{KeyframeId, PointId};
use crate::map::maps::MapJoin;
use lie::Sim3;
use nalgebra::{SVector, Vector3};
use std::collections::{BTreeMap, BTreeSet};

/// A keyframe vertex as a part.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframePart<const N: usize> {
    /// Its id.
    pub id: KeyframeId,
    /// `T_i = camera_from_world`.
    pub camera_from_world: Sim3,
    /// The version at which the pose last changed.
    pub pose_version: Version,
    /// Its map.
    pub map: usize,
    /// Its measurements, by point (ascending).
    pub observations: Vec<(PointId, SVector<f64, N>)>,
    /// Its edges, by the other end (ascending); each edge is stored at both ends.
    pub edges: Vec<(KeyframeId, Edge)>,
}

/// A map point as a part (its observers are the keyframes that observe it).
#[derive(Clone, Debug, PartialEq)]
pub struct PointPart {
    /// Its id.
    pub id: PointId,
    /// The anchor keyframe.
    pub anchor: KeyframeId,
    /// `ψ` in the anchor's frame.
    pub inverse_depth: Vector3<f64>,
    /// The version at which `ψ` or the anchor last changed.
    pub version: Version,
}

/// A whole graph as parts ([`SlamGraph::to_parts`]).
#[derive(Clone, Debug, PartialEq)]
pub struct GraphParts<const N: usize> {
    /// The keyframes, by id.
    pub keyframes: Vec<KeyframePart<N>>,
    /// The points, by id.
    pub points: Vec<PointPart>,
    /// The ids the graph has handed out: `(keyframes, points)` (removed ones included).
    pub ids_issued: (usize, usize),
    /// The reference keyframe.
    pub reference: Option<KeyframeId>,
    /// The graph's version.
    pub version: Version,
    /// The map new keyframes join.
    pub current_map: usize,
    /// The maps started.
    pub maps_started: usize,
    /// The merges, oldest first.
    pub merges: Vec<MapMerge>,
    /// The joins, oldest first.
    pub joins: Vec<MapJoin>,
}

impl<const N: usize> SlamGraph<N> {
    /// The graph as plain parts (see the [module docs](self)).
    pub fn to_parts(&self) -> GraphParts<N> {
        GraphParts {
            keyframes: self
                .keyframes()
                .map(|(id, k)| KeyframePart {
                    id,
                    camera_from_world: k.camera_from_world,
                    pose_version: k.pose_version,
                    map: k.map,
                    observations: k.observations.iter().map(|(&p, z)| (p, *z)).collect(),
                    edges: k.edges.iter().map(|(&j, e)| (j, *e)).collect(),
                })
                .collect(),
            points: self
                .points()
                .map(|(id, p)| PointPart {
                    id,
                    anchor: p.anchor,
                    inverse_depth: p.inverse_depth,
                    version: p.version,
                })
                .collect(),
            ids_issued: (self.keyframes.len(), self.points.len()),
            reference: self.reference,
            version: self.version,
            current_map: self.current_map,
            maps_started: self.maps_started,
            merges: self.merges.clone(),
            joins: self.joins.clone(),
        }
    }

    /// The graph of `parts`, each part checked (see the [module docs](self)).
    pub fn from_parts(parts: GraphParts<N>) -> Result<Self, GraphError> {
        let bad = |s: String| Err(GraphError::Invariant(s));
        let GraphParts {
            keyframes,
            points,
            ids_issued: (keyframe_ids, point_ids),
            reference,
            version,
            current_map,
            maps_started,
            merges,
            joins,
        } = parts;
        if keyframes.len() > keyframe_ids || points.len() > point_ids {
            return bad("more keyframes or points than ids issued".into());
        }
        if maps_started <= current_map {
            return bad(format!(
                "current map {current_map} of {maps_started} started"
            ));
        }
        let mut graph = SlamGraph {
            keyframes: vec![None; keyframe_ids],
            points: vec![None; point_ids],
            reference,
            num_keyframes: keyframes.len(),
            num_points: points.len(),
            version,
            current_map,
            maps_started,
            merges,
            joins,
        };
        for p in points {
            let slot = graph.points.get_mut(p.id.index());
            let Some(slot @ None) = slot else {
                return bad(format!("{} out of range or given twice", p.id));
            };
            let psi = p.inverse_depth;
            if !(psi.iter().all(|v| v.is_finite()) && psi.z > MIN_INVERSE_DEPTH) {
                return Err(GraphError::BadInverseDepth(psi.z));
            }
            if p.version > version {
                return bad(format!("{} changed after the graph's version", p.id));
            }
            *slot = Some(MapPoint {
                anchor: p.anchor,
                inverse_depth: psi,
                version: p.version,
                observers: BTreeSet::new(),
            });
        }
        for k in keyframes {
            if k.map >= maps_started {
                return bad(format!("{} in map {} never started", k.id, k.map));
            }
            if k.pose_version > version {
                return bad(format!("{} moved after the graph's version", k.id));
            }
            let mut observations = BTreeMap::new();
            for (p, z) in k.observations {
                if !z.iter().all(|v| v.is_finite()) {
                    return bad(format!("{} measures {p} at a non-finite pixel", k.id));
                }
                let Some(Some(point)) = graph.points.get_mut(p.index()) else {
                    return Err(GraphError::UnknownPoint(p));
                };
                point.observers.insert(k.id);
                if observations.insert(p, z).is_some() {
                    return bad(format!("{} measures {p} twice", k.id));
                }
            }
            let edges: BTreeMap<KeyframeId, Edge> = k.edges.into_iter().collect();
            let slot = graph.keyframes.get_mut(k.id.index());
            let Some(slot @ None) = slot else {
                return bad(format!("{} out of range or given twice", k.id));
            };
            *slot = Some(Keyframe {
                camera_from_world: k.camera_from_world,
                pose_version: k.pose_version,
                map: k.map,
                observations,
                edges,
            });
        }
        for m in &graph.merges {
            if m.from >= maps_started || m.into >= maps_started {
                return bad(format!(
                    "merge of map {} into {} never started",
                    m.from, m.into
                ));
            }
        }
        for j in &graph.joins {
            for k in [j.current, j.old] {
                // A join's keyframes may have been removed since; their ids were issued.
                if k.index() >= keyframe_ids {
                    return Err(GraphError::UnknownKeyframe(k));
                }
            }
        }
        for (id, k) in graph.keyframes() {
            if let Some((&j, _)) = k.edges.iter().find(|(j, _)| graph.keyframe(**j).is_none()) {
                return bad(format!("edge {id}–{j} to a missing keyframe"));
            }
        }
        graph.check_invariants()?;
        Ok(graph)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lie::{LieGroup, Se3};
    use nalgebra::Vector2;

    fn graph() -> SlamGraph<2> {
        let mut g = SlamGraph::<2>::new();
        let a = g.add_keyframe(Sim3::identity());
        let b = g.add_keyframe(Sim3::from_se3(&Se3::exp(&nalgebra::Vector6::new(
            0.1, 0.0, 0.0, 0.0, 0.02, 0.0,
        ))));
        let c = g.add_keyframe(Sim3::identity());
        for i in 0..5 {
            let p = g
                .add_point(
                    a,
                    Vector3::new(0.01 * i as f64, 0.0, 0.5),
                    Vector2::new(1.0, 2.0),
                )
                .unwrap();
            g.add_observation(b, p, Vector2::new(3.0, i as f64))
                .unwrap();
        }
        let relative = g.pose(b).unwrap().compose(&g.pose(a).unwrap().inverse());
        g.add_edge(a, b, Some(relative)).unwrap();
        // A removed keyframe leaves its id unused.
        g.remove_keyframe(c).unwrap();
        g
    }

    /// A graph taken apart and put together is the same graph, ids and versions included.
    #[test]
    fn parts_put_together_give_the_same_graph() {
        let g = graph();
        let parts = g.to_parts();
        assert_eq!(parts.ids_issued, (3, 5));
        let back = SlamGraph::from_parts(parts.clone()).unwrap();
        assert_eq!(back.to_parts(), parts);
        assert_eq!(back.version(), g.version());
        assert_eq!(back.num_keyframes(), 2);
        back.check_invariants().unwrap();
    }

    /// Parts that cannot make a graph are refused with the reason.
    #[test]
    fn bad_parts_are_refused_with_the_reason() {
        let good = graph().to_parts();
        let mut p = good.clone();
        p.points[0].inverse_depth.z = f64::NAN;
        assert!(matches!(
            SlamGraph::from_parts(p),
            Err(GraphError::BadInverseDepth(_))
        ));
        let mut p = good.clone();
        p.keyframes[1]
            .observations
            .push((PointId(99), Vector2::zeros()));
        assert!(matches!(
            SlamGraph::from_parts(p),
            Err(GraphError::UnknownPoint(_))
        ));
        let mut p = good.clone();
        p.keyframes[0].edges[0].1.weight += 1;
        assert!(SlamGraph::from_parts(p).is_err());
        let mut p = good.clone();
        p.keyframes[1].id = p.keyframes[0].id;
        assert!(SlamGraph::from_parts(p).is_err());
        let mut p = good.clone();
        p.keyframes[0].map = 7;
        assert!(SlamGraph::from_parts(p).is_err());
        let mut p = good;
        p.points[1].anchor = KeyframeId(2);
        assert!(SlamGraph::from_parts(p).is_err());
    }
}
