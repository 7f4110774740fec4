//! Entry points for the `cargo fuzz` targets in `fuzz/` (not a stable API): shm-ring's
//! generic header, ring and decoder fuzzers run with the haptics messages.

use shm_ring::fuzzing::FuzzProtocol;
use shm_ring::FixedStr;

use crate::command::{Command, CommandKind};
use crate::features::{MAX_FEATURES, THESIS_FEATURES};
use crate::layout::Haptics;
use crate::messages::{FeatureMsg, ForceMsg};
use crate::telemetry::TelemetryRow;

impl FuzzProtocol for Haptics {
    fn features(n: u64) -> FeatureMsg {
        FeatureMsg {
            seq: n,
            len: (n % (MAX_FEATURES as u64 + 1)) as u8,
            values: [n as f64; MAX_FEATURES],
            ..FeatureMsg::default()
        }
    }

    fn forces(n: u64) -> ForceMsg {
        ForceMsg {
            seq: n,
            force: n as f64 * 0.5,
            ..ForceMsg::default()
        }
    }

    fn commands(n: u64) -> Command {
        Command {
            id: n,
            kind: CommandKind::StopExperiment,
            name: FixedStr::new("stop").expect("valid"),
            values: [n as f64; 4],
        }
    }

    fn telemetry(step: u64) -> TelemetryRow {
        TelemetryRow {
            step,
            ..TelemetryRow::default()
        }
    }

    fn telemetry_step(row: &TelemetryRow) -> u64 {
        row.step
    }
}

/// What an attacher does with a haptics segment's header (see `shm_ring::fuzzing::header`).
pub fn header(data: &[u8]) {
    shm_ring::fuzzing::header::<Haptics>(data, &THESIS_FEATURES);
}

/// The four rings under arbitrary operations and hostile pokes.
pub fn rings(data: &[u8]) {
    shm_ring::fuzzing::rings::<Haptics>(data);
}

/// The four message decoders on arbitrary words.
pub fn messages(data: &[u8]) {
    shm_ring::fuzzing::messages::<Haptics>(data);
}
