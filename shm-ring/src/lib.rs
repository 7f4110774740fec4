//! Lock-free shared-memory rings between `rt-loop` and `infer-server`.
//!
//! See `../shared/DESIGN.md`, section "Shared memory"; filled in by the shm-ring issue.
