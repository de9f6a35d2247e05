//! Which features a keyframe SLAM pipeline tracks (thesis §3.4.3, §4.5.1): equi-distributed
//! selection of the initial features by the quadtree of thesis Alg. 2, and replacement of
//! features that left the field of view by new ones where the feature density is low
//! (thesis Fig. 3.7).
//!
//! A frame's measurements are `(feature id, z)` pairs for every visible feature (perfect data
//! association, as in the thesis's simulations); the first two coordinates of `z` are the
//! (left) image position `(u, v)`.

use lie::{LieGroup, Se3};
use nalgebra::{SVector, Vector3};
use vision::quadtree::{QuadPoint, QuadTree};

/// All measurements of one frame: `(feature id, z)`.
pub type FrameMeasurements<const N: usize> = [(usize, SVector<f64, N>)];

/// The image rectangle in which features are selected.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageArea {
    /// Width in pixels.
    pub width: f64,
    /// Height in pixels.
    pub height: f64,
}

/// The measurement of feature `id` in `frame`, if visible.
pub fn find<const N: usize>(frame: &FrameMeasurements<N>, id: usize) -> Option<SVector<f64, N>> {
    frame.iter().find(|(i, _)| *i == id).map(|(_, z)| *z)
}

/// The median inverse depth `1/z` of `points_world` in the frame `camera_from_world` (points
/// behind the camera ignored), or 1 if none is in front: the start value of the depth of a
/// new feature (thesis §4.5.1, as in PTAM and ORB-SLAM's median scene depth).
pub fn median_inverse_depth(
    camera_from_world: &Se3,
    points_world: impl Iterator<Item = Vector3<f64>>,
) -> f64 {
    let mut q: Vec<f64> = points_world
        .map(|y| 1.0 / camera_from_world.act(&y).z)
        .filter(|q| q.is_finite() && *q > 0.0)
        .collect();
    if q.is_empty() {
        return 1.0;
    }
    q.sort_by(f64::total_cmp);
    q[q.len() / 2]
}

/// Selects up to `n` of `candidates` (feature ids measured in `frame`) spread evenly over the
/// image and away from the `occupied` image positions: the candidates are visited in the
/// equi-distributed order of thesis Alg. 2 (seeded), and one is taken when no occupied or
/// already taken position lies within the box of half-size `r = ½·√(w·h/n_total)` around
/// it, `n_total = n + |occupied|` (the spacing of `n_total` evenly spread features); if that
/// leaves fewer than `n`, the rest are filled in traversal order.
pub fn select_spread<const N: usize>(
    frame: &FrameMeasurements<N>,
    candidates: &[usize],
    occupied: &[(f64, f64)],
    n: usize,
    area: ImageArea,
    seed: u64,
) -> Vec<usize> {
    if n == 0 || candidates.is_empty() {
        return Vec::new();
    }
    let points: Vec<QuadPoint> = candidates
        .iter()
        .enumerate()
        .filter_map(|(k, id)| {
            let z = find(frame, *id)?;
            Some(QuadPoint {
                u: z[0] as f32,
                v: z[1] as f32,
                score: 0.0,
                index: k,
            })
        })
        .collect();
    let (w, h) = (area.width as f32, area.height as f32);
    // Minimum cell of one pixel: distinct candidates closer than that are interchangeable.
    let tree = QuadTree::from_points(w, h, 1.0, &points);
    let order: Vec<QuadPoint> = tree.traverse(seed).collect();
    let r = 0.5 * ((area.width * area.height) / (n + occupied.len()) as f64).sqrt();
    let mut density = QuadTree::new(w, h, 1.0);
    for (k, &(u, v)) in occupied.iter().enumerate() {
        density.insert(QuadPoint {
            u: u as f32,
            v: v as f32,
            score: 0.0,
            index: k,
        });
    }
    let mut taken = vec![false; order.len()];
    let mut out = Vec::with_capacity(n);
    for (k, p) in order.iter().enumerate() {
        if out.len() == n {
            break;
        }
        let rf = r as f32;
        if density.count_in_box(p.u - rf, p.v - rf, p.u + rf, p.v + rf) == 0 {
            taken[k] = true;
            out.push(candidates[p.index]);
            density.insert(*p);
        }
    }
    for (k, p) in order.iter().enumerate() {
        if out.len() == n {
            break;
        }
        if !taken[k] {
            out.push(candidates[p.index]);
        }
    }
    out
}

/// The features to track: `tracked` without those not measured in `frame` (they left the
/// field of view), and the lost ones.
pub fn split_lost<const N: usize>(
    tracked: &[usize],
    frame: &FrameMeasurements<N>,
) -> (Vec<usize>, Vec<usize>) {
    tracked.iter().partition(|id| find(frame, **id).is_some())
}

/// Replacements for `count` lost features (thesis Alg. 3 and 5, "initialise n new points"):
/// features measured in both the previous frame (where they are initialised) and the current
/// one (where they are tracked to), not tracked now and never used before, spread away from
/// the kept features in the previous image ([`select_spread`]).
pub fn select_replacements<const N: usize>(
    previous: &FrameMeasurements<N>,
    current: &FrameMeasurements<N>,
    kept: &[usize],
    used: &dyn Fn(usize) -> bool,
    count: usize,
    area: ImageArea,
    seed: u64,
) -> Vec<usize> {
    let candidates: Vec<usize> = previous
        .iter()
        .map(|(id, _)| *id)
        .filter(|id| !used(*id) && find(current, *id).is_some())
        .collect();
    let occupied: Vec<(f64, f64)> = kept
        .iter()
        .filter_map(|id| find(previous, *id).map(|z| (z[0], z[1])))
        .collect();
    select_spread(previous, &candidates, &occupied, count, area, seed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector2;

    #[test]
    fn selection_is_spread_seeded_and_avoids_occupied_regions() {
        // A dense cluster in the left half and a sparse grid in the right half.
        let mut frame = Vec::new();
        for k in 0..400 {
            let (u, v) = ((k % 20) as f64 * 5.0 + 10.0, (k / 20) as f64 * 5.0 + 10.0);
            frame.push((k, Vector2::new(u, v)));
        }
        for k in 0..64 {
            let (u, v) = (330.0 + (k % 8) as f64 * 38.0, 10.0 + (k / 8) as f64 * 58.0);
            frame.push((1000 + k, Vector2::new(u, v)));
        }
        let ids: Vec<usize> = frame.iter().map(|(i, _)| *i).collect();
        let area = ImageArea {
            width: 640.0,
            height: 480.0,
        };
        let a = select_spread(&frame, &ids, &[], 40, area, 7);
        let b = select_spread(&frame, &ids, &[], 40, area, 7);
        assert_eq!(a, b);
        assert_eq!(a.len(), 40);
        // Spread: the sparse right half gets a fair share although it has 64 of 464.
        let right = a.iter().filter(|id| **id >= 1000).count();
        assert!(right >= 15, "right half got {right} of 40");
        // Occupying the right half pushes selections to the left.
        let occupied: Vec<(f64, f64)> = (0..64)
            .map(|k| (330.0 + (k % 8) as f64 * 38.0, 10.0 + (k / 8) as f64 * 58.0))
            .collect();
        let c = select_spread(&frame, &ids[..400], &occupied, 10, area, 7);
        assert_eq!(c.len(), 10);
        let (kept, lost) = split_lost(&[1, 2, 5000], &frame);
        assert_eq!((kept, lost), (vec![1, 2], vec![5000]));
    }
}
