//! The served model's path, from the loop's side: [`model`] is the hook (each step the loop asks
//! a `ForceModel` for F_pred and renders `F_cmd = -F_pred`); [`shm_model`] asks infer-server
//! over shared memory; [`ladder`] decides what is rendered when that answer is late, missing or
//! invalid (it never jumps); [`shm_io`] is the rest of the side channel (telemetry, heartbeat,
//! mailbox, status block), [`shm_renew`] re-creates a damaged segment, and [`sink`] is the
//! trait through which a run hands its per-step output to that side channel. The per-step calls
//! are the REAL-TIME PATH: no allocation, no lock, no blocking (docs/rt-loop.md).

pub mod ladder;
pub mod model;
pub mod shm_io;
pub mod shm_model;
pub mod shm_renew;
pub mod sink;
