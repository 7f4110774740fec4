//! The real-time side: the inference thread, how it waits for each step and where it runs, and
//! what it shares with the rest of the server without ever waiting on it (a lock-free latency
//! histogram, the handoff of a new model, the segment's other endpoints).
//!
//! Everything on the per-step path here allocates nothing and takes no lock; the comments at
//! each such place say how (docs/infer-server.md, "The inference thread").

pub mod attachment;
pub mod handoff;
pub mod inference_thread;
pub mod keep_awake;
pub mod latency;
pub mod period_sync;
pub mod profile;
