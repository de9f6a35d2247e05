//! A pose graph of 10⁴ nodes optimises without growing memory across iterations: the
//! structure, the symbolic factorisation and every buffer are made once, before the first
//! iteration.

use lie::{LieGroup, LogJacobian, Se2};
use lsq::{LinearSolver, SolverOptions};
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use slam::pose_graph::{Constraint, PoseGraphProblem};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicIsize, AtomicUsize, Ordering};

struct Counting;
static LIVE_BYTES: AtomicIsize = AtomicIsize::new(0);
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        LIVE_BYTES.fetch_add(layout.size() as isize, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE_BYTES.fetch_sub(layout.size() as isize, Ordering::Relaxed);
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        LIVE_BYTES.fetch_add(
            new_size as isize - layout.size() as isize,
            Ordering::Relaxed,
        );
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// A Manhattan-like 2D graph: a noisy odometry chain of `n` poses with loop closures between
/// poses whose true positions are close.
fn grid_world(n: usize, seed: u64) -> (Vec<Se2>, Vec<Constraint<Se2, 3>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut truth = vec![Se2::identity()];
    for i in 1..n {
        let turn = if rng.random_bool(0.1) {
            std::f64::consts::FRAC_PI_2 * if rng.random_bool(0.5) { 1.0 } else { -1.0 }
        } else {
            0.0
        };
        let step = Se2::from_xy_angle(1.0, 0.0, turn);
        truth.push(truth[i - 1].compose(&step));
    }
    // T_i = camera_from_world = truth⁻¹ (truth is world_from_body).
    let info = Matrix3::from_diagonal(&Vector3::new(100.0, 100.0, 1000.0));
    let noise = |rng: &mut ChaCha8Rng| {
        Se2::exp(&Vector3::new(
            rng.random_range(-0.05..0.05),
            rng.random_range(-0.05..0.05),
            rng.random_range(-0.01..0.01),
        ))
    };
    let mut constraints = Vec::new();
    let mut odometry = vec![Se2::identity()];
    for i in 1..n {
        // T_ji = T_j·T_i⁻¹ = truth_j⁻¹·truth_i.
        let measured = noise(&mut rng).compose(&truth[i].inverse().compose(&truth[i - 1]));
        odometry.push(odometry[i - 1].compose(&measured.inverse()));
        constraints.push(Constraint {
            i: i - 1,
            j: i,
            measured,
            information: info,
        });
    }
    // Revisits: every pose is linked to up to two earlier poses in the same 2 m cell.
    let mut cells: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
    for j in 0..n {
        let t = truth[j].translation();
        let cell = ((t.x / 2.0).floor() as i64, (t.y / 2.0).floor() as i64);
        let earlier = cells.entry(cell).or_default();
        {
            for &i in earlier.iter().filter(|&&i| i + 20 < j).take(2) {
                let measured = noise(&mut rng).compose(&truth[j].inverse().compose(&truth[i]));
                constraints.push(Constraint {
                    i,
                    j,
                    measured,
                    information: info,
                });
            }
        }
        earlier.push(j);
    }
    let initial = odometry.iter().map(|p| p.inverse()).collect();
    (initial, constraints)
}

#[test]
fn ten_thousand_nodes_optimise_without_growing_memory() {
    let (initial, constraints) = grid_world(10_000, 3);
    assert!(
        constraints.len() > 11_000,
        "only {} loop closures",
        constraints.len() - 9_999
    );
    let mut pg = PoseGraphProblem::new(&initial, &constraints, &[0], LogJacobian::Exact).unwrap();
    let options = SolverOptions {
        linear_solver: LinearSolver::SparseCholesky,
        damping: lsq::Damping::Levenberg,
        initial_lambda: 1e-5,
        lambda_decrease_floor: 0.1,
        max_iterations: 12,
        function_tolerance: 0.0,
        threads: Some(1),
        ..Default::default()
    };
    // Preallocated, so that recording a sample does not itself allocate.
    let mut samples: Vec<(isize, usize)> = Vec::with_capacity(64);
    let summary = pg
        .problem
        .optimise_with(&options, |_| {
            samples.push((
                LIVE_BYTES.load(Ordering::Relaxed),
                ALLOCATIONS.load(Ordering::Relaxed),
            ));
        })
        .unwrap();
    assert!(
        summary.final_cost < 1e-3 * summary.initial_cost,
        "{} → {}",
        summary.initial_cost,
        summary.final_cost
    );
    assert!(samples.len() >= 5, "{} iterations", samples.len());
    // After the first iteration (which may still grow lazily sized scratch), live memory is
    // flat and no allocation happens at all.
    let (base_bytes, base_count) = samples[1];
    for (k, &(bytes, count)) in samples.iter().enumerate().skip(2) {
        assert_eq!(
            bytes,
            base_bytes,
            "live heap changed by {} bytes at iteration {}",
            bytes - base_bytes,
            k + 1
        );
        assert_eq!(
            count,
            base_count,
            "{} allocations during iteration {}",
            count - base_count,
            k + 1
        );
    }
    eprintln!(
        "10⁴ poses, {} constraints: {} iterations, ½χ² {:.3e} → {:.3e}, live heap {:.1} MB, flat after iteration 2",
        constraints.len(),
        samples.len(),
        summary.initial_cost,
        summary.final_cost,
        base_bytes as f64 / 1e6
    );
}
