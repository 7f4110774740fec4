//! Errors of creating, attaching to and validating a segment.

use std::io;

/// Why a segment could not be created or attached.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("invalid segment name `{name}`: {reason}")]
    InvalidName { name: String, reason: &'static str },
    #[error("invalid segment configuration: {0}")]
    InvalidConfig(String),
    #[error("no segment `{name}` exists (is rt-loop running with this instance name?)")]
    NotFound { name: String },
    #[error("segment `{name}` belongs to a live rt-loop (pid {pid}); it is never taken over")]
    InstanceInUse { name: String, pid: u32 },
    #[error("segment `{name}` already has a live server attached (pid {pid})")]
    ServerAlreadyAttached { name: String, pid: u32 },
    #[error("segment `{name}` was left by a dead rt-loop (pid {pid}); wait for a new one")]
    CreatorDead { name: String, pid: u32 },
    #[error("segment `{name}` is still being initialised by its creator")]
    Initializing { name: String },
    #[error("segment `{name}` is not a haptics segment: magic {found:#018x}")]
    BadMagic { name: String, found: u64 },
    #[error("segment `{name}` has layout version {found}, this build speaks {expected}")]
    VersionMismatch {
        name: String,
        found: u64,
        expected: u64,
    },
    #[error(
        "segment `{name}` layout differs from this build: {what} is {found}, expected {expected}"
    )]
    LayoutMismatch {
        name: String,
        what: String,
        found: u64,
        expected: u64,
    },
    #[error("segment `{name}` belongs to uid {uid}, not to us; refusing it")]
    ForeignOwner { name: String, uid: u32 },
    #[error("segment `{name}` has mode {mode:o}: group/other may access it; refusing it")]
    InsecureMode { name: String, mode: u32 },
    #[error("channel `{channel}` refused: {reason}")]
    Channel {
        channel: &'static str,
        reason: String,
    },
    #[error("this segment handle was {actual}, it cannot become the {wanted} side")]
    WrongRole {
        actual: &'static str,
        wanted: &'static str,
    },
    #[error("{op} failed for segment `{name}`: {source}")]
    Os {
        op: &'static str,
        name: String,
        source: io::Error,
    },
}

impl Error {
    /// Whether waiting and retrying may succeed (no segment yet, a dead creator's segment
    /// awaiting replacement, initialisation in progress).
    pub fn is_transient(&self) -> bool {
        matches!(
            self,
            Error::NotFound { .. } | Error::CreatorDead { .. } | Error::Initializing { .. }
        )
    }
}
