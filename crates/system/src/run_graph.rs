//! The final graph of a run ([`RunGraph`]: of the sensor's measurement dimension) and what
//! the outputs read of it. A leaf: the result and the map file both hold one.

use lie::Sim3;
use slam::map::{KeyframeId, SlamGraph};

/// The final graph of a run, of the sensor's measurement dimension.
#[derive(Clone, Debug)]
pub enum RunGraph {
    /// Stereo and RGB-D: measurements `(u, v, u_r)`.
    Depth(SlamGraph<3>),
    /// Monocular: measurements `(u, v)`.
    Mono(SlamGraph<2>),
}

/// A keyframe of [`RunGraph::keyframes`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeyframeNode {
    /// Its id.
    pub id: KeyframeId,
    /// Its pose.
    pub camera_from_world: Sim3,
    /// Its map.
    pub map: usize,
}

impl RunGraph {
    /// Every keyframe with its pose and map, in id order.
    pub fn keyframes(&self) -> Vec<KeyframeNode> {
        fn of<const N: usize>(g: &SlamGraph<N>) -> Vec<KeyframeNode> {
            g.keyframes()
                .map(|(id, k)| KeyframeNode {
                    id,
                    camera_from_world: *k.camera_from_world(),
                    map: k.map(),
                })
                .collect()
        }
        match self {
            RunGraph::Depth(g) => of(g),
            RunGraph::Mono(g) => of(g),
        }
    }

    /// The covisibility edges `(a, b)` with `a < b`.
    pub fn edges(&self) -> Vec<(KeyframeId, KeyframeId)> {
        fn of<const N: usize>(g: &SlamGraph<N>) -> Vec<(KeyframeId, KeyframeId)> {
            g.keyframes()
                .flat_map(|(a, k)| {
                    k.edges()
                        .keys()
                        .filter(move |&&b| a < b)
                        .map(move |&b| (a, b))
                })
                .collect()
        }
        match self {
            RunGraph::Depth(g) => of(g),
            RunGraph::Mono(g) => of(g),
        }
    }

    /// Points in the graph.
    pub fn num_points(&self) -> usize {
        match self {
            RunGraph::Depth(g) => g.num_points(),
            RunGraph::Mono(g) => g.num_points(),
        }
    }
}
