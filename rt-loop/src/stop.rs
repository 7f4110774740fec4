//! How a run ends ([`StopReason`], compared as a value, written as the summary's `stop` text)
//! and how it is asked to end: a [`Shutdown`] (`shm_ring::os::shutdown`, the one stop request
//! of both processes: SIGINT/SIGTERM, or a call in tests), which the step polls with one relaxed
//! atomic load. A module of its own so that the run, the served model's waits and the daemon
//! share these without importing one another.

use serde::{Serialize, Serializer};
use std::fmt;

pub use shm_ring::os::shutdown::Shutdown;

/// Why a run ended. Its text (the summary's `stop`, the JSON summary's `"stop"`) is stable:
/// scripts and tests read it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// The experiment ran to its end.
    Finished,
    /// The probe reached the position limit (the loop wrote 0 A).
    PositionLimit,
    /// The watchdog expired.
    Watchdog,
    /// The board reported a fault (its message).
    BoardFault(&'static str),
    /// The board is gone (its message).
    BoardGone(&'static str),
    /// The recorder failed: nothing more could be recorded, so the run ended at 0 A.
    RecorderFailed,
    /// `--duration` (loop time) was reached.
    TimeLimit,
    /// The run's [`Shutdown`] was requested (SIGINT/SIGTERM).
    Interrupted,
    /// A stop command from the mailbox (infer-server, hapticctl, the page).
    Stopped,
}

impl StopReason {
    /// Whether the run ended as planned or as asked (not by a fault or a safety stop).
    pub fn planned(&self) -> bool {
        matches!(
            self,
            StopReason::Finished
                | StopReason::TimeLimit
                | StopReason::Interrupted
                | StopReason::Stopped
        )
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            StopReason::Finished => "finished",
            StopReason::PositionLimit => "position-limit",
            StopReason::Watchdog => "watchdog",
            StopReason::BoardFault(m) => return write!(f, "board-fault: {m}"),
            StopReason::BoardGone(m) => return write!(f, "board-gone: {m}"),
            StopReason::RecorderFailed => "recorder-failed",
            StopReason::TimeLimit => "time-limit",
            StopReason::Interrupted => "interrupted",
            StopReason::Stopped => "stopped",
        })
    }
}

impl Serialize for StopReason {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reasons_keep_their_summary_text_and_say_whether_planned() {
        let all = [
            (StopReason::Finished, "finished", true),
            (StopReason::PositionLimit, "position-limit", false),
            (StopReason::Watchdog, "watchdog", false),
            (StopReason::BoardFault("x"), "board-fault: x", false),
            (StopReason::BoardGone("y"), "board-gone: y", false),
            (StopReason::RecorderFailed, "recorder-failed", false),
            (StopReason::TimeLimit, "time-limit", true),
            (StopReason::Interrupted, "interrupted", true),
            (StopReason::Stopped, "stopped", true),
        ];
        for (r, text, planned) in all {
            assert_eq!(r.to_string(), text);
            assert_eq!(serde_json::to_value(r).unwrap(), text);
            assert_eq!(r.planned(), planned, "{r}");
        }
    }
}
