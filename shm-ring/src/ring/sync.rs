//! Atomics shim: the ring protocol is written once against these names and runs on std
//! atomics in production and on loom's model-checked atomics under `--cfg loom`.

#[cfg(loom)]
pub(crate) use loom::sync::atomic::{fence, AtomicU32, AtomicU64, Ordering};

#[cfg(not(loom))]
pub(crate) use std::sync::atomic::{fence, AtomicU32, AtomicU64, Ordering};

/// Spin-loop hint (the waiting loops exist only outside loom; the models poll with
/// `loom::thread::yield_now` themselves).
#[cfg(not(loom))]
#[inline]
pub(crate) fn spin_hint() {
    std::hint::spin_loop();
}
