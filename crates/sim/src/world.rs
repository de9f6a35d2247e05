//! Synthetic worlds: sets of 3D points (thesis §4.3.1, §4.6.1, §5.4, §6.5.1).

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// A regular grid on the fronto-parallel plane `z = depth`, `columns × rows` points spanning
/// `width × height` metres centred on the optical axis, ordered coarse-to-fine so that the
/// first `n` points of the list form a regular pattern for every `n` and a denser pattern
/// always contains every point of a sparser one (thesis §4.3.1, Figure 4.2(b)).
///
/// The order: points on the grid of stride `2ᵏ` (largest `k` first), then the points added
/// by halving the stride, and so on; within a level, row-major.
pub fn nested_plane_grid(
    columns: usize,
    rows: usize,
    width: f64,
    height: f64,
    depth: f64,
) -> Vec<Vector3<f64>> {
    let position = |c: usize, r: usize| {
        let x = if columns > 1 {
            -width / 2.0 + width * c as f64 / (columns - 1) as f64
        } else {
            0.0
        };
        let y = if rows > 1 {
            -height / 2.0 + height * r as f64 / (rows - 1) as f64
        } else {
            0.0
        };
        Vector3::new(x, y, depth)
    };
    let mut level_of = vec![0u32; columns * rows];
    let max_level = usize::BITS - columns.max(rows).leading_zeros();
    for r in 0..rows {
        for c in 0..columns {
            // The coarsest stride 2ᵏ dividing both indices.
            let k = (c.trailing_zeros().min(r.trailing_zeros())).min(max_level);
            level_of[r * columns + c] = k;
        }
    }
    let mut order: Vec<usize> = (0..columns * rows).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(level_of[i]), i));
    order
        .into_iter()
        .map(|i| position(i % columns, i / columns))
        .collect()
}

/// `n` points uniform in the box `[min, max]`.
pub fn random_box(
    rng: &mut ChaCha8Rng,
    min: Vector3<f64>,
    max: Vector3<f64>,
    n: usize,
) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|_| {
            Vector3::new(
                rng.random_range(min.x..=max.x),
                rng.random_range(min.y..=max.y),
                rng.random_range(min.z..=max.z),
            )
        })
        .collect()
}

/// `n` points uniform on the ring (cylinder band) of radius `radius` about the world `z` axis
/// with heights in `[z_min, z_max]` (thesis §5.4: 5000 points on a ring of radius 11 m).
pub fn ring(
    rng: &mut ChaCha8Rng,
    radius: f64,
    z_min: f64,
    z_max: f64,
    n: usize,
) -> Vec<Vector3<f64>> {
    thick_ring(rng, radius, 0.0, z_min, z_max, n)
}

/// `n` points uniform in angle, height (`[z_min, z_max]`) and radius
/// (`[radius − thickness/2, radius + thickness/2]`) about the world `z` axis: a ring-shaped
/// distribution with depth relief, so that a camera inside it does not see a (nearly) planar
/// scene, which is degenerate for the 8-point algorithm. `thickness = 0` is [`ring`].
pub fn thick_ring(
    rng: &mut ChaCha8Rng,
    radius: f64,
    thickness: f64,
    z_min: f64,
    z_max: f64,
    n: usize,
) -> Vec<Vector3<f64>> {
    let half = 0.5 * thickness.abs();
    (0..n)
        .map(|_| {
            let a = rng.random_range(0.0..std::f64::consts::TAU);
            let r = if half > 0.0 {
                rng.random_range(radius - half..=radius + half)
            } else {
                radius
            };
            Vector3::new(r * a.cos(), r * a.sin(), rng.random_range(z_min..=z_max))
        })
        .collect()
}

/// `n` points uniform on the sphere of radius `radius` about the origin (thesis §5.4, the flight
/// over a sphere).
pub fn sphere(rng: &mut ChaCha8Rng, radius: f64, n: usize) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|_| {
            // Uniform direction from a normalised Gaussian-free construction: z uniform, angle uniform.
            let z: f64 = rng.random_range(-1.0..=1.0);
            let a = rng.random_range(0.0..std::f64::consts::TAU);
            let s = (1.0 - z * z).max(0.0).sqrt();
            Vector3::new(radius * s * a.cos(), radius * s * a.sin(), radius * z)
        })
        .collect()
}

/// `n` points uniform in the slab `{x_min ≤ x ≤ x_max, y_min ≤ y ≤ y_max, |z − depth| ≤
/// thickness/2}`: an approximately planar scene (thesis §4.6.1, settings (i)–(iv)).
pub fn planar_slab(
    rng: &mut ChaCha8Rng,
    (x_min, x_max): (f64, f64),
    (y_min, y_max): (f64, f64),
    depth: f64,
    thickness: f64,
    n: usize,
) -> Vec<Vector3<f64>> {
    random_box(
        rng,
        Vector3::new(x_min, y_min, depth - thickness / 2.0),
        Vector3::new(x_max, y_max, depth + thickness / 2.0),
        n,
    )
}

/// Points uniform on the four vertical faces (`x = min.x`, `x = max.x`, `y = min.y`,
/// `y = max.y`) of the axis-aligned box `[min, max]`, `density` points per square metre: the
/// walls of a room or corridor around a trajectory (thesis §6.5.1, the spiral).
pub fn box_walls(
    rng: &mut ChaCha8Rng,
    min: Vector3<f64>,
    max: Vector3<f64>,
    density: f64,
) -> Vec<Vector3<f64>> {
    let (dx, dy, dz) = (max.x - min.x, max.y - min.y, max.z - min.z);
    let count = |area: f64| (area * density).round().max(0.0) as usize;
    let mut out = Vec::new();
    for (y, n) in [(min.y, count(dx * dz)), (max.y, count(dx * dz))] {
        out.extend((0..n).map(|_| {
            Vector3::new(
                rng.random_range(min.x..=max.x),
                y,
                rng.random_range(min.z..=max.z),
            )
        }));
    }
    for (x, n) in [(min.x, count(dy * dz)), (max.x, count(dy * dz))] {
        out.extend((0..n).map(|_| {
            Vector3::new(
                x,
                rng.random_range(min.y..=max.y),
                rng.random_range(min.z..=max.z),
            )
        }));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn nested_grid_prefixes_are_nested_and_cover_the_plane() {
        let pts = nested_plane_grid(25, 17, 2.4, 1.6, 3.0);
        assert_eq!(pts.len(), 425);
        assert!(pts.iter().all(|p| p.z == 3.0));
        // The first points are the coarse grid: corners are among the first few.
        let first: Vec<_> = pts[..12].to_vec();
        assert!(
            first
                .iter()
                .any(|p| (p.x + 1.2).abs() < 1e-12 && (p.y + 0.8).abs() < 1e-12)
        );
        // Every prefix spans the plane in x (well spread), not one corner.
        for n in [12, 30, 60, 120, 240, 425] {
            let xs: Vec<f64> = pts[..n].iter().map(|p| p.x).collect();
            let (lo, hi) = xs
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            assert!(hi - lo > 2.0, "prefix {n} spans only {}", hi - lo);
        }
        // All distinct.
        for i in 0..pts.len() {
            for j in i + 1..pts.len() {
                assert!((pts[i] - pts[j]).norm() > 1e-9);
            }
        }
    }

    #[test]
    fn box_walls_lie_on_the_vertical_faces() {
        let (min, max) = (Vector3::new(-1.0, -2.0, -0.5), Vector3::new(3.0, 2.0, 0.5));
        let pts = box_walls(&mut ChaCha8Rng::seed_from_u64(3), min, max, 10.0);
        // 2·(4·1) + 2·(4·1) m² at 10 points per m².
        assert_eq!(pts.len(), 160);
        for p in &pts {
            let on_x = (p.x - min.x).abs() < 1e-12 || (p.x - max.x).abs() < 1e-12;
            let on_y = (p.y - min.y).abs() < 1e-12 || (p.y - max.y).abs() < 1e-12;
            assert!(on_x || on_y);
            assert!(p.z >= min.z && p.z <= max.z);
        }
    }

    #[test]
    fn generators_are_seeded() {
        let a = ring(&mut ChaCha8Rng::seed_from_u64(1), 11.0, -1.0, 1.0, 10);
        let b = ring(&mut ChaCha8Rng::seed_from_u64(1), 11.0, -1.0, 1.0, 10);
        assert_eq!(a, b);
        for p in &a {
            assert!(((p.x * p.x + p.y * p.y).sqrt() - 11.0).abs() < 1e-9);
        }
        for p in sphere(&mut ChaCha8Rng::seed_from_u64(2), 5.0, 100) {
            assert!((p.norm() - 5.0).abs() < 1e-9);
        }
    }
}
