//! exp, log, compose, inverse and the point action never allocate on the heap.

use lie::{LieGroup, Se3, Sim3, So3};
use nalgebra::{SVector, Vector3, Vector6};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Counts the allocations of the threads that asked for it: the test harness's own thread
/// allocates concurrently now and then (it once made this test fail with 4 allocations that
/// were not ours), and the group operations run on the test's thread only.
struct CountingAllocator;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    static COUNTED: Cell<bool> = const { Cell::new(false) };
}

unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTED.try_with(Cell::get).unwrap_or(false) {
            ALLOCATIONS.fetch_add(1, Ordering::SeqCst);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn group_operations_do_not_allocate() {
    let x6 = Vector6::new(0.1, -0.2, 0.3, 0.4, -0.5, 0.6);
    let x7 = SVector::<f64, 7>::from_column_slice(&[0.1, -0.2, 0.3, 0.4, -0.5, 0.6, 0.2]);
    let p = Vector3::new(1.0, 2.0, 3.0);
    // Warm up the quadrature-node cache of Sim(3)'s left Jacobian (allocated once, lazily).
    let _ = Sim3::left_jacobian(&x7);
    COUNTED.with(|c| c.set(true));
    // The counter itself works: an allocation on this thread is seen.
    let probe = ALLOCATIONS.load(Ordering::SeqCst);
    drop(std::hint::black_box(vec![1u8; 16]));
    assert!(
        ALLOCATIONS.load(Ordering::SeqCst) > probe,
        "the counter sees nothing"
    );
    let before = ALLOCATIONS.load(Ordering::SeqCst);
    let mut acc = 0.0;
    for _ in 0..1000 {
        let a = Se3::exp(&x6);
        let b = a.compose(&a).inverse();
        acc += b.log()[0] + a.act(&p).x + (a * p).y;
        let s = Sim3::exp(&x7);
        let t = s.compose(&s).inverse();
        acc += t.log()[6] + s.act(&p).z;
        let r = So3::exp(&Vector3::new(0.1, 0.2, 0.3));
        acc += r.log()[0] + r.act(&p).x;
        acc += a.adjoint()[(0, 0)] + s.adjoint()[(0, 0)];
        acc += Se3::left_jacobian_inverse(&x6)[(0, 0)] + Sim3::left_jacobian(&x7)[(0, 0)];
    }
    let after = ALLOCATIONS.load(Ordering::SeqCst);
    COUNTED.with(|c| c.set(false));
    assert!(acc.is_finite());
    assert_eq!(
        after - before,
        0,
        "group operations allocated {} times",
        after - before
    );
}
