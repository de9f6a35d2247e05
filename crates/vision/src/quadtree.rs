//! Region quadtree over image points with the equi-distributed traversal of thesis Alg. 2
//! (§3.4.3): selecting `n` well-spread points out of many unevenly distributed ones.
//!
//! Each node covers a rectangle; a node has zero or four children (top-left, top-right,
//! bottom-left, bottom-right quarters). Points are stored only at leaves, at most one per leaf:
//! a leaf receiving a second point splits, unless it is already at the minimum cell size, in
//! which case it keeps the higher-scoring point (this bounds the point density, thesis §3.4.3).

use crate::fast::{Corner, fast9, with_shi_tomasi};
use crate::image::GrayImage;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A point stored in the tree: position and score (higher is better), plus a caller index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QuadPoint {
    /// Column.
    pub u: f32,
    /// Row.
    pub v: f32,
    /// Score used to pick one point per minimum-size cell.
    pub score: f32,
    /// Index into the caller's collection.
    pub index: usize,
}

#[derive(Debug, Clone)]
struct Node {
    x0: f32,
    y0: f32,
    x1: f32,
    y1: f32,
    children: Option<[usize; 4]>,
    point: Option<QuadPoint>,
}

/// A region quadtree over the rectangle `[0, width) × [0, height)`.
#[derive(Debug, Clone)]
pub struct QuadTree {
    nodes: Vec<Node>,
    min_cell: f32,
}

impl QuadTree {
    /// An empty tree over `width×height` whose cells are never split below `min_cell` pixels.
    pub fn new(width: f32, height: f32, min_cell: f32) -> Self {
        Self {
            nodes: vec![Node {
                x0: 0.0,
                y0: 0.0,
                x1: width.max(0.0),
                y1: height.max(0.0),
                children: None,
                point: None,
            }],
            min_cell: min_cell.max(1e-3),
        }
    }

    /// Builds a tree holding `points` (points outside the rectangle or with non-finite
    /// coordinates are ignored).
    pub fn from_points(width: f32, height: f32, min_cell: f32, points: &[QuadPoint]) -> Self {
        let mut t = Self::new(width, height, min_cell);
        for p in points {
            t.insert(*p);
        }
        t
    }

    /// Number of nodes (inner nodes and leaves).
    pub fn num_nodes(&self) -> usize {
        self.nodes.len()
    }

    /// Number of stored points.
    pub fn len(&self) -> usize {
        self.nodes.iter().filter(|n| n.point.is_some()).count()
    }

    /// True if no point is stored.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn quadrant(n: &Node, u: f32, v: f32) -> usize {
        let mx = 0.5 * (n.x0 + n.x1);
        let my = 0.5 * (n.y0 + n.y1);
        (if u >= mx { 1 } else { 0 }) + (if v >= my { 2 } else { 0 })
    }

    fn split(&mut self, i: usize) {
        let n = self.nodes[i].clone();
        let mx = 0.5 * (n.x0 + n.x1);
        let my = 0.5 * (n.y0 + n.y1);
        let rects = [
            (n.x0, n.y0, mx, my),
            (mx, n.y0, n.x1, my),
            (n.x0, my, mx, n.y1),
            (mx, my, n.x1, n.y1),
        ];
        let base = self.nodes.len();
        for (x0, y0, x1, y1) in rects {
            self.nodes.push(Node {
                x0,
                y0,
                x1,
                y1,
                children: None,
                point: None,
            });
        }
        self.nodes[i].children = Some([base, base + 1, base + 2, base + 3]);
        if let Some(p) = self.nodes[i].point.take() {
            let q = Self::quadrant(&self.nodes[i], p.u, p.v);
            self.nodes[base + q].point = Some(p);
        }
    }

    /// Inserts a point; returns false if it lies outside the tree or was dropped in favour of a
    /// better point in the same minimum-size cell.
    pub fn insert(&mut self, p: QuadPoint) -> bool {
        let root = &self.nodes[0];
        if !(p.u >= root.x0 && p.u < root.x1 && p.v >= root.y0 && p.v < root.y1) {
            return false;
        }
        let mut i = 0;
        loop {
            if let Some(ch) = self.nodes[i].children {
                i = ch[Self::quadrant(&self.nodes[i], p.u, p.v)];
                continue;
            }
            let n = &self.nodes[i];
            match n.point {
                None => {
                    self.nodes[i].point = Some(p);
                    return true;
                }
                Some(old) => {
                    let small = (n.x1 - n.x0) <= self.min_cell || (n.y1 - n.y0) <= self.min_cell;
                    if small {
                        if p.score > old.score {
                            self.nodes[i].point = Some(p);
                            return true;
                        }
                        return false;
                    }
                    self.split(i);
                }
            }
        }
    }

    /// Number of stored points inside the axis-aligned box `[u0, u1) × [v0, v1)` (the density
    /// test used before initialising new features, thesis Fig. 3.7).
    pub fn count_in_box(&self, u0: f32, v0: f32, u1: f32, v1: f32) -> usize {
        let mut stack = vec![0usize];
        let mut count = 0;
        while let Some(i) = stack.pop() {
            let n = &self.nodes[i];
            if n.x1 <= u0 || n.x0 >= u1 || n.y1 <= v0 || n.y0 >= v1 {
                continue;
            }
            if let Some(ch) = n.children {
                stack.extend_from_slice(&ch);
            } else if let Some(p) = n.point
                && p.u >= u0
                && p.u < u1
                && p.v >= v0
                && p.v < v1
            {
                count += 1;
            }
        }
        count
    }

    /// The equi-distributed traversal of thesis Alg. 2 with a seeded random generator.
    pub fn traverse(&self, seed: u64) -> EquiDistributedTraversal<'_> {
        let mut levels = std::collections::BTreeMap::new();
        levels.insert(0usize, vec![0usize]);
        EquiDistributedTraversal {
            tree: self,
            levels,
            visited: vec![false; self.nodes.len()],
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// The first `n` points of the equi-distributed traversal.
    pub fn select(&self, n: usize, seed: u64) -> Vec<QuadPoint> {
        self.traverse(seed).take(n).collect()
    }
}

/// Iterator of thesis Alg. 2: breadth-first over levels with random sibling order; when BFS
/// pops an inner node, a depth-first search with random child order returns one not yet
/// returned point from that node's region. Every stored point is returned exactly once.
pub struct EquiDistributedTraversal<'a> {
    tree: &'a QuadTree,
    levels: std::collections::BTreeMap<usize, Vec<usize>>,
    visited: Vec<bool>,
    rng: ChaCha8Rng,
}

impl Iterator for EquiDistributedTraversal<'_> {
    type Item = QuadPoint;

    fn next(&mut self) -> Option<QuadPoint> {
        loop {
            // level := map.getSmallestKey(); erase empty levels.
            let (&level, list) = self.levels.iter_mut().next()?;
            if list.is_empty() {
                self.levels.remove(&level);
                continue;
            }
            let k = self.rng.random_range(0..list.len());
            let node_i = list.swap_remove(k);
            let node = &self.tree.nodes[node_i];
            match node.children {
                None => {
                    if let Some(p) = node.point
                        && !self.visited[node_i]
                    {
                        self.visited[node_i] = true;
                        return Some(p);
                    }
                }
                Some(ch) => {
                    self.levels
                        .entry(level + 1)
                        .or_default()
                        .extend_from_slice(&ch);
                    // DFS with random child order for one unreturned point in this region.
                    let mut stack: Vec<usize> = Vec::new();
                    let mut c = ch;
                    c.shuffle(&mut self.rng);
                    stack.extend_from_slice(&c);
                    while let Some(d) = stack.pop() {
                        let dn = &self.tree.nodes[d];
                        match dn.children {
                            None => {
                                if let Some(p) = dn.point
                                    && !self.visited[d]
                                {
                                    self.visited[d] = true;
                                    return Some(p);
                                }
                            }
                            Some(dc) => {
                                let mut dc = dc;
                                dc.shuffle(&mut self.rng);
                                stack.extend_from_slice(&dc);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Corners as quadtree points: position and score, `index` their position in `corners`.
pub fn quad_points(corners: &[Corner]) -> Vec<QuadPoint> {
    corners
        .iter()
        .enumerate()
        .map(|(i, c)| QuadPoint {
            u: c.u,
            v: c.v,
            score: c.score,
            index: i,
        })
        .collect()
}

/// Corners to track: FAST-9 at `threshold` on the full image (non-maximum suppressed), scored
/// by Shi-Tomasi (3 × 3 window radius), spread by the equi-distributed traversal (thesis Alg. 2,
/// cells ≥ `min_cell` pixels) to at most `count`. Returns the number of FAST corners and the
/// selection (`index` is the corner's position among the FAST corners).
pub fn select_corners(
    img: &GrayImage,
    threshold: u8,
    count: usize,
    min_cell: f32,
) -> (usize, Vec<QuadPoint>) {
    select_among(img, &fast9(img, threshold, true), count, min_cell)
}

/// [`select_corners`] among FAST corners `corners` of `img` already detected.
pub fn select_among(
    img: &GrayImage,
    corners: &[Corner],
    count: usize,
    min_cell: f32,
) -> (usize, Vec<QuadPoint>) {
    let points = quad_points(&with_shi_tomasi(img, corners, 3));
    let tree = QuadTree::from_points(img.width() as f32, img.height() as f32, min_cell, &points);
    (corners.len(), tree.select(count, 0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pts(v: &[(f32, f32)]) -> Vec<QuadPoint> {
        v.iter()
            .enumerate()
            .map(|(i, &(u, v))| QuadPoint {
                u,
                v,
                score: i as f32,
                index: i,
            })
            .collect()
    }

    #[test]
    fn every_point_is_returned_once() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let p: Vec<(f32, f32)> = (0..300)
            .map(|_| (rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)))
            .collect();
        let t = QuadTree::from_points(640.0, 480.0, 1e-3, &pts(&p));
        assert_eq!(t.len(), 300);
        let mut got: Vec<usize> = t.traverse(1).map(|q| q.index).collect();
        got.sort();
        assert_eq!(got, (0..300).collect::<Vec<_>>());
        // Deterministic for a seed.
        let a: Vec<usize> = t.traverse(9).map(|q| q.index).collect();
        let b: Vec<usize> = t.traverse(9).map(|q| q.index).collect();
        assert_eq!(a, b);
    }

    #[test]
    fn selection_is_spread_out_despite_a_dense_cluster() {
        // 400 points crowded into the top-left 64×64 corner, one point in each other quarter.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut p: Vec<(f32, f32)> = (0..400)
            .map(|_| (rng.random_range(0.0..64.0), rng.random_range(0.0..64.0)))
            .collect();
        p.extend_from_slice(&[(500.0, 100.0), (100.0, 400.0), (600.0, 450.0)]);
        let t = QuadTree::from_points(640.0, 480.0, 1.0, &pts(&p));
        let first: Vec<usize> = t.select(4, 0).iter().map(|q| q.index).collect();
        for lonely in 400..403 {
            assert!(first.contains(&lonely), "{first:?}");
        }
    }

    #[test]
    fn min_cell_keeps_best_and_counts_boxes() {
        let mut t = QuadTree::new(100.0, 100.0, 10.0);
        assert!(t.insert(QuadPoint {
            u: 1.0,
            v: 1.0,
            score: 1.0,
            index: 0
        }));
        assert!(t.insert(QuadPoint {
            u: 2.0,
            v: 2.0,
            score: 5.0,
            index: 1
        }));
        assert!(!t.insert(QuadPoint {
            u: 2.5,
            v: 2.0,
            score: 0.5,
            index: 2
        }));
        assert!(!t.insert(QuadPoint {
            u: 200.0,
            v: 2.0,
            score: 9.0,
            index: 3
        }));
        assert_eq!(t.len(), 1);
        assert_eq!(t.traverse(0).next().unwrap().index, 1);
        assert!(t.insert(QuadPoint {
            u: 60.0,
            v: 60.0,
            score: 0.0,
            index: 4
        }));
        assert_eq!(t.count_in_box(0.0, 0.0, 50.0, 50.0), 1);
        assert_eq!(t.count_in_box(0.0, 0.0, 100.0, 100.0), 2);
        assert_eq!(QuadTree::new(0.0, 0.0, 1.0).traverse(0).count(), 0);
    }
}
