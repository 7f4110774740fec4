//! A malloc interposer: counts the C-level allocations (`malloc` & co., which ONNX Runtime's
//! C++ `new` and Rust's system allocator end in) made by any thread of the process while
//! [`COUNTING`] is on. Included by the benchmarks that report allocations per step
//! (`#[path = "common/malloc_count.rs"] mod malloc_count;`).

// The interposers below are `unsafe extern "C"` with the libc contracts; no per-function docs.
#![allow(clippy::missing_safety_doc)]
// Each bench uses a part of this module.
#![allow(dead_code)]

use std::ffi::c_void;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

// ---- malloc interposer: counts allocations while COUNTING is on -------------------------------
// SAFETY (all six): same contracts as the libc functions they replace, which they call.
// Symbols defined in the executable take precedence over glibc's for every shared library in
// the process, libonnxruntime.so included. Each forwards to glibc's real implementation.

pub static COUNTING: AtomicBool = AtomicBool::new(false);
pub static C_ALLOCS: AtomicU64 = AtomicU64::new(0);

extern "C" {
    fn __libc_malloc(size: usize) -> *mut c_void;
    fn __libc_calloc(n: usize, size: usize) -> *mut c_void;
    fn __libc_realloc(p: *mut c_void, size: usize) -> *mut c_void;
    fn __libc_memalign(align: usize, size: usize) -> *mut c_void;
}

#[inline(always)]
fn count() {
    if COUNTING.load(Ordering::Relaxed) {
        C_ALLOCS.fetch_add(1, Ordering::Relaxed);
    }
}

#[no_mangle]
pub unsafe extern "C" fn malloc(size: usize) -> *mut c_void {
    count();
    unsafe { __libc_malloc(size) }
}

#[no_mangle]
pub unsafe extern "C" fn calloc(n: usize, size: usize) -> *mut c_void {
    count();
    unsafe { __libc_calloc(n, size) }
}

#[no_mangle]
pub unsafe extern "C" fn realloc(p: *mut c_void, size: usize) -> *mut c_void {
    count();
    unsafe { __libc_realloc(p, size) }
}

#[no_mangle]
pub unsafe extern "C" fn posix_memalign(out: *mut *mut c_void, align: usize, size: usize) -> i32 {
    count();
    let p = unsafe { __libc_memalign(align, size) };
    if p.is_null() {
        return libc::ENOMEM;
    }
    unsafe { *out = p };
    0
}

#[no_mangle]
pub unsafe extern "C" fn aligned_alloc(align: usize, size: usize) -> *mut c_void {
    count();
    unsafe { __libc_memalign(align, size) }
}

#[no_mangle]
pub unsafe extern "C" fn memalign(align: usize, size: usize) -> *mut c_void {
    count();
    unsafe { __libc_memalign(align, size) }
}

/// Starts counting from zero.
pub fn start() {
    C_ALLOCS.store(0, Ordering::Relaxed);
    COUNTING.store(true, Ordering::Relaxed);
}

/// Stops counting; the allocations counted since [`start`].
pub fn stop() -> u64 {
    COUNTING.store(false, Ordering::Relaxed);
    C_ALLOCS.load(Ordering::Relaxed)
}
