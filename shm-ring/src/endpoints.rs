//! The two sides' endpoint bundles: what rt-loop and infer-server actually hold, generic over
//! the protocol's message types (haptics-proto's `layout` names them: `LoopSide<Haptics>`).

use std::sync::Arc;

use crate::header::Channel;
use crate::overwrite::{OverwriteConsumer, OverwriteProducer};
use crate::protocol::Protocol;
use crate::segment::{Link, Shared};
use crate::spsc::{Consumer, Producer};

/// rt-loop's ends of the segment. Fields are public so the loop can hand each end to the
/// thread that uses it; every end keeps the mapping alive on its own.
///
/// Real-time rules: `features_tx.try_send`, `telemetry_tx.send`, `forces_rx.try_recv`,
/// `commands_rx.try_recv` and `link.heartbeat` never block, allocate or make a syscall (except
/// one `FUTEX_WAKE` when the server is parked). `forces_rx.recv_deadline` waits at most until
/// its deadline: the loop never blocks on the server.
pub struct LoopSide<P: Protocol> {
    /// Feature vectors to the server. Full ring: `try_send` hands the message back
    /// (`SendError::Full`) and counts it; nothing is dropped silently.
    pub features_tx: Producer<P::Features>,
    /// Predicted forces from the server, tagged with the step they answer.
    pub forces_rx: Consumer<P::Forces>,
    /// Every step's state for plots; overwrites the oldest row when the server lags.
    pub telemetry_tx: OverwriteProducer<P::Telemetry>,
    /// Commands from the server (start/stop experiment, set parameter).
    pub commands_rx: Consumer<P::Commands>,
    /// Liveness, heartbeats, schema.
    pub link: Link,
}

impl<P: Protocol> LoopSide<P> {
    pub(crate) fn new(shared: Arc<Shared>) -> LoopSide<P> {
        let link = Link { shared };
        LoopSide {
            features_tx: Producer::new(link.ring(Channel::Features), link.probe()),
            forces_rx: Consumer::new(link.ring(Channel::Forces), link.probe()),
            telemetry_tx: OverwriteProducer::new(link.ring(Channel::Telemetry)),
            commands_rx: Consumer::new(link.ring(Channel::Commands), link.probe()),
            link,
        }
    }

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
pub struct ServerSide<P: Protocol> {
    /// Feature vectors from the loop, in step order.
    pub features_rx: Consumer<P::Features>,
    /// Answers to the loop.
    pub forces_tx: Producer<P::Forces>,
    /// The loop's per-step state; `dropped()` counts rows lost because we lagged.
    pub telemetry_rx: OverwriteConsumer<P::Telemetry>,
    /// Commands to the loop.
    pub commands_tx: Producer<P::Commands>,
    /// Liveness, heartbeats, schema.
    pub link: Link,
    /// Feature messages that were waiting when we attached and were skipped: they were
    /// requests to a previous server, already rendered by the loop's fallback.
    pub skipped_on_attach: u64,
}

impl<P: Protocol> ServerSide<P> {
    pub(crate) fn new(shared: Arc<Shared>) -> ServerSide<P> {
        let link = Link { shared };
        let mut features_rx = Consumer::new(link.ring(Channel::Features), link.probe());
        let skipped_on_attach = features_rx.skip_pending();
        // A previous server that died while parked left its waiter registrations behind; the
        // loop would then pay for a FUTEX_WAKE on every step. We are the only server now
        // (we hold the server lock) and not parked yet, so they can only be stale.
        for channel in [Channel::Features, Channel::Telemetry] {
            crate::spsc::clear_data_waiters(&link.ring(channel));
        }
        for channel in [Channel::Forces, Channel::Commands] {
            crate::spsc::clear_space_waiters(&link.ring(channel));
        }
        ServerSide {
            features_rx,
            forces_tx: Producer::new(link.ring(Channel::Forces), link.probe()),
            telemetry_rx: OverwriteConsumer::new(link.ring(Channel::Telemetry), link.probe()),
            commands_tx: Producer::new(link.ring(Channel::Commands), link.probe()),
            link,
            skipped_on_attach,
        }
    }

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
