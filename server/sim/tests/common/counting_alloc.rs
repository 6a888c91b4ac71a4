//! A global allocator that counts the allocations of each thread, for the tests that prove
//! a real-time path allocation-free after warm-up. Shared by test crates with
//! `#[path = ".../common/counting_alloc.rs"] mod counting_alloc;` (the crate must allow
//! `unsafe_code`: a global allocator is an `unsafe impl`).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

thread_local! {
    /// Allocations made by this thread (the test harness runs tests on several threads).
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    /// This thread's allocations also count in [`GROUP`] (a pool's workers, whose own
    /// counters no other thread can read).
    static IN_GROUP: Cell<bool> = const { Cell::new(false) };
}

/// Allocations made by the threads that called [`count_in_group`].
static GROUP: AtomicU64 = AtomicU64::new(0);

fn count() {
    ALLOCATIONS.with(|c| c.set(c.get() + 1));
    if IN_GROUP.with(Cell::get) {
        GROUP.fetch_add(1, Ordering::Relaxed);
    }
}

struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations (and reallocations) this thread has made so far.
pub fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

/// From now on this thread's allocations also count in [`group_allocations`].
#[allow(dead_code)] // only the test crates with a worker pool count a group
pub fn count_in_group() {
    IN_GROUP.with(|g| g.set(true));
}

/// Allocations made so far by the threads that called [`count_in_group`].
#[allow(dead_code)]
pub fn group_allocations() -> u64 {
    GROUP.load(Ordering::Relaxed)
}

#[test]
fn the_counter_counts() {
    let before = allocations();
    let v = std::hint::black_box(vec![1u8; 64]);
    assert!(allocations() > before);
    drop(v);
}
