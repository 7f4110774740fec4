//! What the control plane reaches: the models in memory and on disk, the control side of the
//! inference thread, and what the telemetry ring says about the loop. All of it runs off the
//! real-time path (it may allocate and wait); it talks to the inference thread only through
//! [`crate::serving::handoff`] and atomics.

pub mod control_backend;
pub mod inference_control;
pub mod registry;
pub mod telemetry;
