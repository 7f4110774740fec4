//! The haptics system's vocabulary: everything rt-loop, infer-server and their clients say to
//! each other, written once. The gRPC schema stands beside it (`proto/haptics/v1/`); the
//! Python (`train/`) and TypeScript (`web-ui/`) copies of the name lists are generated from
//! it. Built on shm-ring's generic rings and segment; shm-ring never depends on this crate.
//!
//! - [`features`]: the feature names and the segment's feature schema.
//! - [`messages`]: `FeatureMsg` and `ForceMsg`, the per-step request and answer.
//! - [`telemetry`]: `TelemetryRow`, one loop step's state.
//! - [`command`]: commands to the loop.
//! - [`status`]: the loop-status block (`LoopStatus`).
//! - [`phase`]: `Phase`, the loop's phases, and their names.
//! - [`series`]: the names of the series telemetry plots show.
//! - [`vocab_gen`]: the generated Python and TypeScript name lists (`haptics-vocab`).
//! - [`layout`]: the haptics segment (its channels' message types, default config).
//! - `grpc` (cargo feature `grpc`): the tonic/prost types of `proto/haptics/v1/haptics.proto`.

#[cfg(feature = "args")]
pub mod cli_parse;
pub mod command;
#[cfg(feature = "connection")]
pub mod connection;
pub mod experiment_args;
pub mod features;
#[cfg(feature = "grpc")]
pub mod grpc;
pub mod layout;
pub mod messages;
pub mod phase;
pub mod series;
pub mod status;
pub mod telemetry;
pub mod vocab_gen;

pub use command::Command;
pub use features::{MAX_FEATURES, SCHEMA_NAMES, THESIS_FEATURES};
pub use layout::{Haptics, LoopSide, Segment, ServerSide};
pub use messages::{FeatureMsg, ForceMsg};
pub use phase::{Phase, PHASE_NAMES};
pub use status::{
    LoopClock, LoopStatus, LoopStatusLink, Quantiles, StatusText, BOARD_BYTES, EXPERIMENT_BYTES,
    RECORDER_BYTES, SCHEDULING_BYTES,
};
pub use telemetry::{TelemetryRow, RECORDING_COLUMNS};
