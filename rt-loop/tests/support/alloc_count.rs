//! The counting global allocator of the "allocates nothing" tests, written once: a test binary has
//! exactly one global allocator, so each test file that needs it includes this file
//! (`#[path = "support/alloc_count.rs"] mod alloc_count;`) instead of declaring its own.
//!
//! Counting is per thread: only the allocations and reallocations made by the thread that called
//! [`start`], until it calls [`stop`]. An echo-server thread or the test harness beside it never
//! counts, so a test measures exactly the code it runs on its own thread (the loop's side).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    // Const-initialised and without a destructor: safe to touch from inside the allocator.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<u64> = const { Cell::new(0) };
}

struct Counting;

impl Counting {
    fn note() {
        if COUNTING.with(Cell::get) {
            COUNT.with(|c| c.set(c.get() + 1));
        }
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        Self::note();
        System.alloc(l)
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l)
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        Self::note();
        System.realloc(p, l, n)
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Starts counting this thread's allocations from zero.
pub fn start() {
    COUNT.with(|c| c.set(0));
    COUNTING.with(|c| c.set(true));
}

/// Stops counting on this thread and returns how many allocations were made since [`start`].
pub fn stop() -> u64 {
    COUNTING.with(|c| c.set(false));
    COUNT.with(Cell::get)
}
