//! The process's exit codes, shared by the one-shot subcommands ([`crate::commands`]) and
//! `serve` ([`crate::app::AppError::exit_code`]); scripts and tests read them.

/// The model (or the input, or a setting the server refused at start) was refused.
pub const EXIT_REFUSED: u8 = 1;
/// A usage error (clap's own, or a flag's value out of range).
pub const EXIT_USAGE: u8 = 2;
/// ONNX Runtime is missing or cannot be loaded.
pub const EXIT_RUNTIME: u8 = 3;
