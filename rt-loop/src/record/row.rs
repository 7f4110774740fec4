//! One recorded control step: haptics-proto's `TelemetryRow`, the one row type of the
//! recorder, the telemetry ring and the server. The recorder writes its
//! [`COLUMNS`] (docs/recording-format.md, in that order); `run_id`, `model_id` and
//! `f_previous` are telemetry only.

/// Column names in file order (docs/recording-format.md).
pub use haptics_proto::telemetry::RECORDING_COLUMNS as COLUMNS;
/// A plain `Copy` struct: pushing it through the SPSC ring copies bytes, nothing more.
pub use haptics_proto::TelemetryRow as Row;
