//! Test support for shm-ring, kept out of the library: deterministic message contents
//! ([`pattern`]) for the ring and segment tests, the peer tool and the benchmark, and the
//! `shm-ring-peer` binary the multi-process tests (`tests/multiprocess.rs`) drive.

pub mod pattern;
