//! Test support for shm-ring, kept out of the library: deterministic message contents
//! ([`pattern`]) for the ring and segment tests, the peer tool and the benchmark, the
//! `shm-ring-peer` binary the multi-process tests (`tests/multiprocess.rs`) drive, and the
//! entry points of the shared-memory fuzz targets in `fuzz/` (`fuzzing`, hidden from the docs).

#[doc(hidden)]
pub mod fuzzing;
pub mod pattern;
