//! The haptics segment: which message type each of shm-ring's four channels carries, and the
//! segment configuration the loop creates it with (the feature schema, ring capacities).
//! rt-loop and infer-server name their segment types from here.

use shm_ring::{Config, Protocol};

use crate::command::Command;
use crate::features::THESIS_FEATURES;
use crate::messages::{FeatureMsg, ForceMsg};
use crate::telemetry::TelemetryRow;

/// The haptics protocol: features loop to server, forces back, telemetry rows (overwriting),
/// commands to the loop.
#[derive(Debug, Clone, Copy)]
pub struct Haptics;

impl Protocol for Haptics {
    type Features = FeatureMsg;
    type Forces = ForceMsg;
    type Telemetry = TelemetryRow;
    type Commands = Command;
}

/// A haptics segment handle.
pub type Segment = shm_ring::Segment<Haptics>;
/// rt-loop's ends of a haptics segment.
pub type LoopSide = shm_ring::LoopSide<Haptics>;
/// infer-server's ends of a haptics segment.
pub type ServerSide = shm_ring::ServerSide<Haptics>;

/// The default segment configuration: the thesis's nine features as the schema; 1024
/// requests/answers in flight (a second at 1 kHz), 8192 telemetry rows (8 s of plots at
/// 1 kHz), 64 commands.
pub fn config() -> Config {
    Config {
        feature_names: THESIS_FEATURES.iter().map(|s| s.to_string()).collect(),
        ..Config::default()
    }
}
