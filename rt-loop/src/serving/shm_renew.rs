//! Recovery from a corrupt shared-memory segment (issue 13 item 2): the loop owns the segment,
//! so the loop re-creates it when it finds it damaged, and the server re-attaches.
//!
//! Any process of the same user can write the segment. shm-ring keeps every access inside the
//! mapping whatever is written, skips a slot whose sequence word is wrong and refuses impossible
//! indices, counting each in the segment's process-private total (`Link::corrupt`). What it
//! cannot do alone is bring a ring whose indices were rewritten back into step with the peer:
//! that takes a fresh segment. So a keeper thread, off the real-time path, every
//! [`AUDIT_EVERY`]:
//! - audits the segment (`Link::audit`: the header's fixed fields against the loop's private
//!   copies, each ring's indices against what the protocol allows) and reads the corruption the
//!   loop's own endpoints counted;
//! - on anything found, re-creates the segment (`Link::recreate`: same name, capacities and
//!   schema; the old one's loop lock released at once, so the server sees "loop gone", drops
//!   its side and attaches to the new one), builds the new endpoints and leaves them in a
//!   hand-off for the loop thread;
//! - drops the endpoints the loop thread handed back (unmapping is a syscall: not on the loop
//!   thread).
//!
//! The loop thread's side ([`Renewal::swap_client`], [`Renewal::swap_io`]) costs one relaxed
//! atomic load per call while nothing is pending; taking fresh endpoints is a `try_lock` that
//! never waits (the keeper holds the lock only to move a value) and moves a few pointers: no
//! allocation, no syscall. Until the server attaches to the new segment the loop has no server,
//! so its steps are rendered by the degradation ladder's fallback, which keeps the current
//! within its limits.

use haptics_proto::{Command, FeatureMsg, ForceMsg, TelemetryRow};
use shm_ring::{Consumer, Link, OverwriteProducer, Producer, WaitStrategy};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// How often the keeper audits the segment and collects handed-back endpoints.
pub const AUDIT_EVERY: Duration = Duration::from_millis(20);

/// The model client's endpoints of one segment.
pub struct ClientEnds {
    pub features_tx: Producer<FeatureMsg>,
    pub forces_rx: Consumer<ForceMsg>,
    pub link: Link,
}

/// The side channel's endpoints of one segment.
pub struct IoEnds {
    pub telemetry_tx: OverwriteProducer<TelemetryRow>,
    pub commands_rx: Consumer<Command>,
    pub link: Link,
}

/// One direction of the hand-off: fresh endpoints for the loop, old ones back to the keeper.
struct Slot<T> {
    fresh: Option<T>,
    old: Vec<T>,
}

impl<T> Default for Slot<T> {
    fn default() -> Self {
        Slot {
            fresh: None,
            old: Vec::with_capacity(4),
        }
    }
}

/// What the keeper and the loop thread share.
#[derive(Default)]
struct Handoff {
    /// Bumped (release) each time fresh endpoints are left in both slots.
    generation: AtomicU64,
    client: Mutex<Slot<ClientEnds>>,
    io: Mutex<Slot<IoEnds>>,
    /// Corruption found, over every segment this loop created (process-private counts).
    corrupt: AtomicU64,
    /// Segments re-created.
    recoveries: AtomicU64,
    stop: AtomicBool,
}

/// Stops and joins the keeper when the last [`Renewal`] goes (so the keeper's handle on the
/// segment is gone before the process can exit: the last handle unlinks the segment).
struct KeeperThread {
    handoff: Arc<Handoff>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for KeeperThread {
    fn drop(&mut self) {
        self.handoff.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            t.thread().unpark();
            let _ = t.join();
        }
    }
}

/// A loop-side handle on the segment's keeper: one for the model client, one for the side
/// channel. Each remembers which generation of endpoints it has.
pub struct Renewal {
    handoff: Arc<Handoff>,
    _keeper: Arc<KeeperThread>,
    seen: u64,
}

impl Renewal {
    /// Starts the keeper for the segment behind `link` (the loop's side). The fresh model
    /// client's answers are waited for with `answer_wait`, like the first ones. Returns the
    /// handles for the model client and the side channel.
    pub fn start(link: Link, answer_wait: WaitStrategy) -> std::io::Result<(Renewal, Renewal)> {
        let handoff = Arc::new(Handoff::default());
        let keeper = {
            let handoff = Arc::clone(&handoff);
            std::thread::Builder::new()
                .name("shm-keeper".into())
                .spawn(move || keep(link, &handoff, answer_wait))?
        };
        let keeper = Arc::new(KeeperThread {
            handoff: Arc::clone(&handoff),
            thread: Some(keeper),
        });
        let handle = || Renewal {
            handoff: Arc::clone(&handoff),
            _keeper: Arc::clone(&keeper),
            seen: 0,
        };
        Ok((handle(), handle()))
    }

    /// Whether fresh endpoints wait for this side. One relaxed load: fine per step.
    #[inline]
    pub fn pending(&self) -> bool {
        self.handoff.generation.load(Ordering::Relaxed) != self.seen
    }

    /// Fresh model-client endpoints, if the keeper re-created the segment since this handle
    /// last looked: `install` puts them in place and returns the caller's current ones, which
    /// go back to the keeper to be dropped there. Never waits: returns false also when the
    /// keeper happens to hold the lock (the caller tries again later).
    pub fn swap_client(&mut self, install: impl FnOnce(ClientEnds) -> ClientEnds) -> bool {
        self.swap(|h| &h.client, install)
    }

    /// As [`Renewal::swap_client`], for the side channel.
    pub fn swap_io(&mut self, install: impl FnOnce(IoEnds) -> IoEnds) -> bool {
        self.swap(|h| &h.io, install)
    }

    fn swap<T>(
        &mut self,
        slot: impl FnOnce(&Handoff) -> &Mutex<Slot<T>>,
        install: impl FnOnce(T) -> T,
    ) -> bool {
        let generation = self.handoff.generation.load(Ordering::Acquire);
        if generation == self.seen {
            return false;
        }
        let Ok(mut slot) = slot(&self.handoff).try_lock() else {
            return false;
        };
        self.seen = generation;
        let Some(fresh) = slot.fresh.take() else {
            return false;
        };
        let previous = install(fresh);
        // Within the capacity the keeper reserved (it collects every AUDIT_EVERY, and
        // re-creates at most that often): no allocation here.
        slot.old.push(previous);
        true
    }

    /// Corruption found so far, over every segment this loop created.
    pub fn corrupt(&self) -> u64 {
        self.handoff.corrupt.load(Ordering::Relaxed)
    }

    /// Segments re-created so far.
    pub fn recoveries(&self) -> u64 {
        self.handoff.recoveries.load(Ordering::Relaxed)
    }
}

/// The keeper thread: audit, re-create on damage, drop what the loop handed back.
fn keep(mut link: Link, handoff: &Handoff, answer_wait: WaitStrategy) {
    // Corruption counted by segments already replaced (their final counts).
    let mut before = 0;
    while !handoff.stop.load(Ordering::Acquire) {
        std::thread::park_timeout(AUDIT_EVERY);
        collect_old(handoff);
        if handoff.stop.load(Ordering::Acquire) {
            break;
        }
        let audit = link.audit();
        let found = link.corrupt();
        handoff.corrupt.store(before + found, Ordering::Relaxed);
        if found == 0 {
            continue;
        }
        let why = match &audit {
            Err(e) => e.to_string(),
            Ok(()) => format!("its endpoints found {found} corrupt slots or indices"),
        };
        match renew(&link, handoff, answer_wait) {
            Ok(new_link) => {
                before += found;
                link = new_link;
                let n = handoff.recoveries.fetch_add(1, Ordering::Relaxed) + 1;
                eprintln!(
                    "rt-loop: segment {} corrupt ({why}); re-created it (recovery {n}), the server re-attaches",
                    link.name()
                );
            }
            Err(e) => {
                // Keep the damaged one (its accesses stay inside the mapping; the loop renders
                // its fallback) and try again at the next audit.
                eprintln!(
                    "rt-loop: segment {} corrupt ({why}); re-creating it failed: {e}",
                    link.name()
                );
            }
        }
    }
}

/// Drops the endpoints the loop thread handed back (here, off the real-time path), leaving
/// spare capacity for the next ones.
fn collect_old(handoff: &Handoff) {
    // Most audits find nothing handed back: then nothing is allocated or moved. What was
    // handed back is dropped after the lock is released (unmapping takes a while).
    fn take<T>(slot: &Mutex<Slot<T>>) -> Vec<T> {
        match slot.lock() {
            Ok(mut s) if !s.old.is_empty() => std::mem::replace(&mut s.old, Vec::with_capacity(4)),
            _ => Vec::new(),
        }
    }
    drop(take(&handoff.client));
    drop(take(&handoff.io));
}

/// Why a corrupt segment could not be re-created.
#[derive(Debug, thiserror::Error)]
enum RenewError {
    #[error("{0}")]
    Segment(#[from] shm_ring::Error),
    /// A thread panicked while holding the hand-off of fresh endpoints.
    #[error("hand-off poisoned")]
    Poisoned,
}

/// Re-creates the segment and leaves its endpoints in the hand-off; returns the new link.
fn renew(link: &Link, handoff: &Handoff, answer_wait: WaitStrategy) -> Result<Link, RenewError> {
    let side = link
        .recreate::<haptics_proto::Haptics>()
        .and_then(|s| s.loop_side())?;
    let mut features_tx = side.features_tx;
    features_tx.set_wait_strategy(WaitStrategy::Park);
    let mut forces_rx = side.forces_rx;
    forces_rx.set_wait_strategy(answer_wait);
    let new_link = side.link.clone();
    let client = ClientEnds {
        features_tx,
        forces_rx,
        link: side.link.clone(),
    };
    let io = IoEnds {
        telemetry_tx: side.telemetry_tx,
        commands_rx: side.commands_rx,
        link: side.link,
    };
    // Un-taken fresh endpoints of an earlier re-creation are replaced (and dropped here).
    fn leave<T>(slot: &Mutex<Slot<T>>, fresh: T) -> Result<Option<T>, RenewError> {
        let mut s = slot.lock().map_err(|_| RenewError::Poisoned)?;
        Ok(s.fresh.replace(fresh))
    }
    let stale_client = leave(&handoff.client, client)?;
    let stale_io = leave(&handoff.io, io)?;
    handoff.generation.fetch_add(1, Ordering::Release);
    drop((stale_client, stale_io));
    Ok(new_link)
}
