//! Building block: single-producer single-consumer rings in any memory (the heap, or a
//! mapping another process shares), with their wake-ups. Knows nothing of segments, headers or
//! the OS beyond the futex; `segment` places these rings in shared memory.
//!
//! Inside: `sync` (atomics, std or loom's) <- `mem` (a ring's control block and slots) <-
//! `wait` (strategies, the futex event count) <- `spsc` (lossless) <- `overwrite`; `message`
//! (a message as words) beside them.

pub(crate) mod mem;
pub(crate) mod message;
pub(crate) mod overwrite;
pub(crate) mod spsc;
pub(crate) mod sync;
pub(crate) mod wait;
