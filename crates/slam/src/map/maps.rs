//! The maps of one graph (ORB-SLAM3's atlas in one [`SlamGraph`](super::SlamGraph)): the first
//! map, the maps a live system starts after losing its camera, how they were put together
//! again, and which of them a run writes.
//!
//! Two maps come together in one of two ways:
//!
//! - **merged** ([`SlamGraph::merge_map`](super::SlamGraph::merge_map)): the younger map's
//!   keyframes are moved as one body onto the older map and belong to it from then on (a loop
//!   between them then holds them together; the stereo and RGB-D system);
//! - **joined** ([`SlamGraph::join_maps`](super::SlamGraph::join_maps)): a place of one map was
//!   recognised from a keyframe of the other ([`MapJoin`]), which gives the similarity between
//!   their worlds; the two stay apart in the graph, and the outputs put the joined maps into
//!   one world (the monocular system, whose maps have scales of their own).
//!
//! A run writes one group of joined maps ([`written_maps`]): the group with the most
//! keyframes, in the world of its map with the most keyframes (a lone map is a group of one:
//! the map with the most keyframes, the first on a tie, as ORB-SLAM3 saves its biggest map).

use super::KeyframeId;
use lie::{LieGroup, Sim3};
use std::collections::BTreeMap;

/// A place of one map seen from a keyframe of another ([`SlamGraph::join_maps`]): keyframe
/// `current` sees the place of keyframe `old` with `x_current = S·x_old` for camera-frame
/// points (`current_from_old`), verified by `inliers` matches.
///
/// [`SlamGraph::join_maps`]: super::SlamGraph::join_maps
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapJoin {
    /// The keyframe that recognised the place.
    pub current: KeyframeId,
    /// The keyframe whose place it recognised.
    pub old: KeyframeId,
    /// `x_current = S·x_old`.
    pub current_from_old: Sim3,
    /// Inliers of its verification: of several joins between the same two maps, the one with
    /// the most is the best measured ([`map_links`]).
    pub inliers: usize,
}

impl MapJoin {
    /// `x_map = W·x_other` between the worlds of `current`'s map and `old`'s, from the two
    /// keyframes' poses `current_pose`, `old_pose`: `W = T_current⁻¹·S·T_old`.
    pub fn map_from_other(&self, current_pose: &Sim3, old_pose: &Sim3) -> Sim3 {
        current_pose
            .inverse()
            .compose(&self.current_from_old)
            .compose(old_pose)
    }
}

/// A link between two maps' worlds: `(map, other, W)` with `x_map = W·x_other`.
pub type MapLink = (usize, usize, Sim3);

/// The links between maps that `joins` make: one per pair of maps, from its join with the most
/// inliers (the last of them on a tie), in the order the pairs were first joined. `map_of` and
/// `pose` read the graph (a join whose keyframes are gone makes no link).
pub fn map_links(
    joins: &[MapJoin],
    map_of: impl Fn(KeyframeId) -> Option<usize>,
    pose: impl Fn(KeyframeId) -> Option<Sim3>,
) -> Vec<MapLink> {
    let pair = |j: &MapJoin| Some((map_of(j.current)?, map_of(j.old)?));
    let mut links: Vec<MapLink> = Vec::new();
    for j in joins {
        let Some((map, other)) = pair(j) else {
            continue;
        };
        if map == other || links.iter().any(|l| (l.0, l.1) == (map, other)) {
            continue;
        }
        let best = joins
            .iter()
            .filter(|o| pair(o) == Some((map, other)))
            .max_by_key(|o| o.inliers)
            .expect("j itself");
        if let (Some(current), Some(old)) = (pose(best.current), pose(best.old)) {
            links.push((map, other, best.map_from_other(&current, &old)));
        }
    }
    links
}

/// Each map joined to `world` through `links`, with `x_map = W·x_world`; `world` itself with
/// the identity.
pub fn joined_to(world: usize, links: &[MapLink]) -> BTreeMap<usize, Sim3> {
    let mut from_world = BTreeMap::from([(world, Sim3::identity())]);
    loop {
        let mut grown = false;
        for &(later, earlier, w) in links {
            match (
                from_world.get(&later).copied(),
                from_world.get(&earlier).copied(),
            ) {
                (Some(l), None) => {
                    from_world.insert(earlier, w.inverse().compose(&l));
                    grown = true;
                }
                (None, Some(e)) => {
                    from_world.insert(later, w.compose(&e));
                    grown = true;
                }
                _ => {}
            }
        }
        if !grown {
            return from_world;
        }
    }
}

/// The map with the most keyframes of `(map, keyframes)`, the first on a tie; `None` if there
/// is none.
pub fn largest_map(keyframes: impl IntoIterator<Item = (usize, usize)>) -> Option<usize> {
    keyframes
        .into_iter()
        .max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0)))
        .map(|(m, _)| m)
}

/// The maps a run writes: of the groups of maps joined together by `links` ([`joined_to`]),
/// the one with the most keyframes (of `keyframes`: `(map, keyframes)` in map order; the
/// first group on a tie); its world is its map with the most keyframes ([`largest_map`]).
/// Returns that map and every map of the group with `x_map = W·x_world`; `first` alone if
/// there are no keyframes.
pub fn written_maps(
    keyframes: &[(usize, usize)],
    links: &[MapLink],
    first: usize,
) -> (usize, BTreeMap<usize, Sim3>) {
    let mut best: Option<(usize, usize)> = None;
    for &(m, _) in keyframes {
        let group = joined_to(m, links);
        let total: usize = keyframes
            .iter()
            .filter(|(o, _)| group.contains_key(o))
            .map(|(_, n)| n)
            .sum();
        if best.is_none_or(|(_, t)| total > t) {
            best = Some((m, total));
        }
    }
    let Some((m, _)) = best else {
        return (first, joined_to(first, links));
    };
    let group = joined_to(m, links);
    let world = largest_map(
        keyframes
            .iter()
            .copied()
            .filter(|(o, _)| group.contains_key(o)),
    )
    .unwrap_or(m);
    (world, joined_to(world, links))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn sim(x: f64, s: f64) -> Sim3 {
        Sim3::new(
            lie::So3::exp(&Vector3::new(0.1, -0.2, x)),
            Vector3::new(x, 1.0, -2.0),
            s,
        )
        .unwrap()
    }

    #[test]
    fn the_maps_written_are_the_joined_group_with_the_most_keyframes() {
        // Map 1 joined to 0, map 2 to 1; map 3 alone.
        let (w10, w21) = (sim(0.3, 0.8), sim(-0.5, 1.7));
        let links = [(1, 0, w10), (2, 1, w21)];
        let (world, group) = written_maps(&[(0, 20), (1, 45), (2, 10), (3, 30)], &links, 0);
        assert_eq!(world, 1);
        assert_eq!(group.keys().copied().collect::<Vec<_>>(), vec![0, 1, 2]);
        // x_map = W·x_world for each, composed through the links.
        let x = Vector3::new(0.4, -1.2, 3.0);
        let close = |a: Vector3<f64>, b: Vector3<f64>| (a - b).norm() < 1e-9;
        assert!(close(group[&1].act(&x), x));
        assert!(close(w10.act(&group[&0].act(&x)), x));
        assert!(close(group[&2].act(&x), w21.act(&x)));
        // A lone map with more keyframes than the joined group is written alone.
        let (world, group) = written_maps(&[(0, 20), (1, 20), (2, 50)], &[(1, 0, w10)], 0);
        assert_eq!((world, group.len()), (2, 1));
        // Without links: the largest map, the first on a tie; none at all: the first map.
        assert_eq!(written_maps(&[(0, 20), (1, 20)], &[], 0).0, 0);
        assert_eq!(written_maps(&[(0, 20), (3, 21)], &[], 0).0, 3);
        assert_eq!(written_maps(&[], &[], 0).0, 0);
    }

    #[test]
    fn a_pair_of_maps_is_linked_by_its_join_with_the_most_inliers() {
        let k = KeyframeId::from_index;
        // Keyframes 0–4 in map 0, 5–9 in map 1; every pose the identity but keyframe 7's.
        let map_of = |id: KeyframeId| Some(usize::from(id.index() >= 5));
        let t7 = sim(0.2, 1.0);
        let pose = |id: KeyframeId| Some(if id == k(7) { t7 } else { Sim3::identity() });
        let join = |current: usize, old: usize, s: Sim3, inliers: usize| MapJoin {
            current: k(current),
            old: k(old),
            current_from_old: s,
            inliers,
        };
        let joins = [
            join(6, 1, sim(0.1, 0.9), 30),
            join(7, 2, sim(0.4, 1.1), 45),
            join(8, 3, sim(0.9, 1.3), 45),
            // Within one map: no link.
            join(9, 8, sim(0.5, 1.0), 90),
        ];
        let links = map_links(&joins, map_of, pose);
        assert_eq!(links.len(), 1);
        let (map, other, w) = links[0];
        assert_eq!((map, other), (1, 0));
        // The last of the two with 45 inliers: keyframe 8's, whose pose is the identity.
        assert!((w.log() - sim(0.9, 1.3).log()).norm() < 1e-12);
        // W = T_current⁻¹·S·T_old.
        let expected = t7.inverse().compose(&sim(0.4, 1.1));
        assert!(
            (joins[1].map_from_other(&t7, &Sim3::identity()).log() - expected.log()).norm() < 1e-12
        );
    }
}
