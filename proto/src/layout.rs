//! The haptics segment: which message type each of shm-ring's four channels carries, in which
//! direction, with which default capacity, and the two sides' endpoint bundles built from a
//! segment with those typed channels. rt-loop and infer-server name their segment types from
//! here; shm-ring's segment never names them.

use shm_ring::{
    Config, Consumer, Error, Link, Lossless, Overwrite, OverwriteConsumer, OverwriteProducer,
    Producer, Protocol, Role, CHANNELS,
};

use crate::command::Command;
use crate::features::THESIS_FEATURES;
use crate::messages::{FeatureMsg, ForceMsg};
use crate::telemetry::TelemetryRow;

/// Feature vectors, loop to server, lossless.
pub const FEATURES: Lossless<FeatureMsg> = Lossless::at(0);
/// Predicted forces, server to loop, lossless.
pub const FORCES: Lossless<ForceMsg> = Lossless::at(1);
/// Every step's state, loop to server, overwriting the oldest.
pub const TELEMETRY: Overwrite<TelemetryRow> = Overwrite::at(2);
/// Commands, server to loop, lossless (a mailbox).
pub const COMMANDS: Lossless<Command> = Lossless::at(3);

/// The haptics protocol: features loop to server, forces back, telemetry rows (overwriting),
/// commands to the loop.
#[derive(Debug, Clone, Copy)]
pub struct Haptics;

impl Protocol for Haptics {
    /// 1024 requests/answers in flight (a second at 1 kHz), 8192 telemetry rows (8 s of plots
    /// at 1 kHz), 64 commands.
    const CHANNELS: [shm_ring::ChannelSpec; CHANNELS] = [
        FEATURES.spec("features", Role::Loop, 1024),
        FORCES.spec("forces", Role::Server, 1024),
        TELEMETRY.spec("telemetry", Role::Loop, 8192),
        COMMANDS.spec("commands", Role::Server, 64),
    ];
    type LoopSide = LoopSide;
    type ServerSide = ServerSide;

    fn loop_side(segment: shm_ring::Segment<Haptics>) -> Result<LoopSide, Error> {
        Ok(LoopSide {
            features_tx: segment.producer(FEATURES)?,
            forces_rx: segment.consumer(FORCES)?,
            telemetry_tx: segment.overwrite_producer(TELEMETRY)?,
            commands_rx: segment.consumer(COMMANDS)?,
            link: segment.link(),
        })
    }

    fn server_side(segment: shm_ring::Segment<Haptics>) -> Result<ServerSide, Error> {
        let mut features_rx = segment.consumer(FEATURES)?;
        let skipped_on_attach = features_rx.skip_pending();
        Ok(ServerSide {
            features_rx,
            forces_tx: segment.producer(FORCES)?,
            telemetry_rx: segment.overwrite_consumer(TELEMETRY)?,
            commands_tx: segment.producer(COMMANDS)?,
            link: segment.link(),
            skipped_on_attach,
        })
    }
}

/// A haptics segment handle.
pub type Segment = shm_ring::Segment<Haptics>;

/// rt-loop's ends of the segment. Fields are public so the loop can hand each end to the
/// thread that uses it; every end keeps the mapping alive on its own.
///
/// Real-time rules: `features_tx.try_send`, `telemetry_tx.send`, `forces_rx.try_recv`,
/// `commands_rx.try_recv` and `link.heartbeat` never block, allocate or make a syscall (except
/// one `FUTEX_WAKE` when the server is parked). `forces_rx.recv_deadline` waits at most until
/// its deadline: the loop never blocks on the server.
pub struct LoopSide {
    /// Feature vectors to the server. Full ring: `try_send` hands the message back
    /// (`SendError::Full`) and counts it; nothing is dropped silently.
    pub features_tx: Producer<FeatureMsg>,
    /// Predicted forces from the server, tagged with the step they answer.
    pub forces_rx: Consumer<ForceMsg>,
    /// Every step's state for plots; overwrites the oldest row when the server lags.
    pub telemetry_tx: OverwriteProducer<TelemetryRow>,
    /// Commands from the server (start/stop experiment, set parameter).
    pub commands_rx: Consumer<Command>,
    /// Liveness, heartbeats, schema.
    pub link: Link,
}

impl LoopSide {
    /// Whether a server process is attached and alive (one syscall; not per step).
    pub fn peer_alive(&self) -> bool {
        self.link.peer_alive()
    }

    /// Bumps the loop's heartbeat (one atomic store).
    pub fn heartbeat(&self) {
        self.link.heartbeat()
    }
}

/// infer-server's ends of the segment.
pub struct ServerSide {
    /// Feature vectors from the loop, in step order.
    pub features_rx: Consumer<FeatureMsg>,
    /// Answers to the loop.
    pub forces_tx: Producer<ForceMsg>,
    /// The loop's per-step state; `dropped()` counts rows lost because we lagged.
    pub telemetry_rx: OverwriteConsumer<TelemetryRow>,
    /// Commands to the loop.
    pub commands_tx: Producer<Command>,
    /// Liveness, heartbeats, schema.
    pub link: Link,
    /// Feature messages that were waiting when we attached and were skipped: they were
    /// requests to a previous server, already rendered by the loop's fallback.
    pub skipped_on_attach: u64,
}

impl ServerSide {
    /// Whether the loop process that created this segment is alive (one syscall).
    /// When it is not, drop this side and re-attach with `Segment::attach_timeout`.
    pub fn peer_alive(&self) -> bool {
        self.link.peer_alive()
    }

    /// Bumps the server's heartbeat (one atomic store).
    pub fn heartbeat(&self) {
        self.link.heartbeat()
    }
}

/// The default segment configuration: the thesis's nine features as the schema, the channels'
/// default capacities.
pub fn config() -> Config {
    Config {
        feature_names: THESIS_FEATURES.iter().map(|s| s.to_string()).collect(),
        ..Config::default()
    }
}
