//! The operating-system layer: the Linux calls everything above it needs, in one place.
//!
//! - [`keep_awake`]: a `SCHED_IDLE` spinner that keeps a real-time thread's CPU from halting
//!   while work flows (infer-server's inference CPU, rt-loop's loop CPU).
//! - [`rt_thread`]: real-time thread set-up (memory locking, CPU affinity, `SCHED_FIFO`) with
//!   what was obtained, used by rt-loop's loop thread and infer-server's inference thread.
//! - [`shutdown`]: SIGINT/SIGTERM as one stop request that a real-time loop polls, a thread
//!   blocks on and async code awaits.
//! - `shm` (crate-private): POSIX shared memory, `mmap`, OFD liveness locks, `/proc` start
//!   times, for the segment.
//!
//! This layer imports nothing else of the crate.

pub mod keep_awake;
pub mod rt_thread;
mod shm;
pub mod shutdown;

pub(crate) use shm::*;
