//! Creating, replacing, attaching and validating the shared-memory segment: a named segment of
//! channels, the concept built on the rings (`ring::spsc`, `ring::overwrite`), its header
//! (`header`), the channel descriptions (`channel`) and the OS layer.
//! What the channels carry is the [`Protocol`]'s: the layer above names the message types and
//! builds its endpoints from [`Segment::producer`], [`Segment::consumer`] and their overwrite
//! twins; this module never names an endpoint type.
//!
//! Segment = `shm_open` object `/haptics-<instance>` (mode 0600) = header + four ring control
//! blocks + four slot arrays, mapped whole in both processes. Plain `libc::shm_open` + `mmap`
//! is used instead of the `shared_memory` crate because liveness needs OFD locks on the
//! segment's own descriptor, and that crate neither exposes the descriptor nor lets the
//! creator decide when a stale segment is unlinked (it unlinks on the owner's drop).
//!
//! The files: `name` (the segment's name and its lock file), `config` (what a creator asks
//! for), `header` and `channel` (the memory's layout and what each ring carries), `shared`
//! (the mapping and liveness descriptor every endpoint holds), `check` (the header validated
//! at attach, the live audit), `info` (what a header says), `error`; this file creates,
//! attaches and maps a segment, and holds [`Link`] (what every endpoint of a side shares:
//! liveness, the audit, recreate). None of them imports this file, so no module imports one
//! that imports it back (docs/shm-ring.md).
//!
//! Locks (see `os`): the loop holds an instance lock file `/dev/shm/.shm-ring.<name>.lock`
//! (serialises creators, so a replaced segment can never be unlinked by a second creator) and
//! byte 0 of the segment; the server holds byte 1. "Peer alive" = the peer's byte is locked.

pub(crate) mod channel;
mod check;
mod config;
pub(crate) mod error;
pub(crate) mod header;
mod info;
mod name;
mod shared;

use self::check::audit;
pub(crate) use self::check::validate;
pub use self::check::Corruption;
pub use self::config::{Config, MAX_CAPACITY};
use self::info::{info_of, info_with_liveness, peek_creator_pid};
pub use self::info::{SegmentInfo, StaleSegment};
pub use self::name::SegmentName;
use self::shared::{Shared, LOOP_LOCK_BYTE, SERVER_LOCK_BYTE};

use std::marker::PhantomData;
use std::os::fd::OwnedFd;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use self::channel::{ChannelKind, ChannelSpec, Lossless, MessageShape, Overwrite, Role, CHANNELS};
use self::error::Error;
use self::header::{Header, Layout, MAGIC};
use crate::fixed_str::FixedStr;
use crate::os::{self, Mapping};
use crate::ring::mem::{CorruptSink, RingMem};
use crate::ring::message::Message;
use crate::ring::overwrite::{OverwriteConsumer, OverwriteProducer};
use crate::ring::spsc::{Consumer, Producer};
use crate::status_block::STATUS_WORDS;

/// What a segment carries: its channels (in header order) and the endpoints each side holds.
/// The layer above implements it (haptics-proto's `layout::Haptics`); the segment only reads
/// [`Protocol::CHANNELS`] and hands itself to [`Protocol::loop_side`] / [`Protocol::server_side`],
/// which build the sides from [`Segment::producer`] and friends. So the segment never knows
/// its endpoints' types, and nothing in this crate imports the protocol's.
pub trait Protocol: Sized + 'static {
    /// The channels, in header order. Each side's ends must match its `writer`.
    const CHANNELS: [ChannelSpec; CHANNELS];
    /// What the creator holds (rt-loop's ends).
    type LoopSide;
    /// What the attached side holds (infer-server's ends).
    type ServerSide;
    /// Builds the creator's ends (called by [`Segment::loop_side`] on a creator's handle).
    fn loop_side(segment: Segment<Self>) -> Result<Self::LoopSide, Error>;
    /// Builds the attached side's ends (called by [`Segment::server_side`] on an attached
    /// handle).
    fn server_side(segment: Segment<Self>) -> Result<Self::ServerSide, Error>;
}

/// The shapes of `P`'s channels, in header order.
pub(crate) fn shapes<P: Protocol>() -> [MessageShape; CHANNELS] {
    P::CHANNELS.map(|c| c.shape)
}

/// A mapped segment carrying protocol `P`'s messages, as created by the loop or attached by
/// the server.
pub struct Segment<P: Protocol> {
    shared: Arc<Shared>,
    replaced: Option<StaleSegment>,
    _protocol: PhantomData<fn() -> P>,
}

fn os_err<'a>(
    op: &'static str,
    name: &'a SegmentName,
) -> impl FnOnce(std::io::Error) -> Error + 'a {
    move |source| Error::Os {
        op,
        name: name.to_string(),
        source,
    }
}

/// Opens a segment that must already exist (attach, inspect): a missing name is
/// [`Error::NotFound`], any other failure an [`Error::Os`] naming `shm_open`.
fn open_existing(name: &SegmentName) -> Result<OwnedFd, Error> {
    os::shm_open(name.as_str(), false).map_err(|e| {
        if e.raw_os_error() == Some(libc::ENOENT) {
            Error::NotFound {
                name: name.to_string(),
            }
        } else {
            os_err("shm_open", name)(e)
        }
    })
}

impl<P: Protocol> Segment<P> {
    /// Creates the segment (the loop's side). Replaces a segment left by a dead loop; refuses
    /// with [`Error::InstanceInUse`] if a live loop owns the name.
    pub fn create(name: &SegmentName, config: &Config) -> Result<Segment<P>, Error> {
        let schema = config.validate(&P::CHANNELS)?;

        // 1. The instance lock: one creator per name at a time, for the creator's lifetime.
        let lock = lock_instance(name)?;
        Segment::create_locked(name, config, schema, lock)
    }

    /// [`Segment::create`] once the instance lock is held (also [`Link::recreate`]'s path).
    fn create_locked(
        name: &SegmentName,
        config: &Config,
        schema: Vec<FixedStr>,
        lock: std::fs::File,
    ) -> Result<Segment<P>, Error> {
        let capacities = config.resolved_capacities(&P::CHANNELS);
        let shapes = shapes::<P>();
        // 2. Create exclusively; a leftover is stale by construction (its creator released the
        //    instance lock, i.e. died) unless its loop byte is still locked (defensive check).
        let mut replaced = None;
        let fd = match os::shm_open(name.as_str(), true) {
            Ok(fd) => fd,
            Err(e) if e.raw_os_error() == Some(libc::EEXIST) => {
                let old = os::shm_open(name.as_str(), false)
                    .map_err(os_err("open stale segment", name))?;
                let pid = peek_creator_pid(name).unwrap_or(0);
                if os::byte_is_locked(&old, LOOP_LOCK_BYTE)
                    .map_err(os_err("probe stale segment", name))?
                {
                    return Err(Error::InstanceInUse {
                        name: name.to_string(),
                        pid,
                    });
                }
                drop(old);
                os::shm_unlink(name.as_str()).map_err(os_err("unlink stale segment", name))?;
                replaced = Some(StaleSegment { creator_pid: pid });
                os::shm_open(name.as_str(), true).map_err(os_err("shm_open", name))?
            }
            Err(e) => return Err(os_err("shm_open", name)(e)),
        };
        os::set_mode_0600(&fd).map_err(os_err("fchmod", name))?;
        if !os::try_lock_byte(&fd, LOOP_LOCK_BYTE).map_err(os_err("lock loop byte", name))? {
            return Err(Error::InstanceInUse {
                name: name.to_string(),
                pid: 0,
            });
        }

        // 3. Size, map (zero-filled by the kernel), write the header, publish the magic last.
        let layout = Layout::compute(capacities, &shapes);
        os::ftruncate(&fd, layout.total as u64).map_err(os_err("ftruncate", name))?;
        let mapping = Mapping::map(&fd, layout.total).map_err(os_err("mmap", name))?;
        let shared = Arc::new(Shared {
            mapping,
            fd,
            name: name.clone(),
            role: Role::Loop,
            layout: layout.clone(),
            specs: P::CHANNELS,
            taken: AtomicU32::new(0),
            schema: config.feature_names.clone(),
            creator_pid: u64::from(os::pid()),
            corrupt: CorruptSink::default(),
            superseded: AtomicBool::new(false),
            _instance_lock: Some(lock),
        });
        let now_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        shared
            .header()
            .init(capacities, &schema, &layout, &shapes, now_ns);
        shared.header().magic.store(MAGIC, Ordering::Release);
        Ok(Segment {
            shared,
            replaced,
            _protocol: PhantomData,
        })
    }

    /// Attaches to a live loop's segment (the server's side), validating the header.
    pub fn attach(name: &SegmentName) -> Result<Segment<P>, Error> {
        let fd = open_existing(name)?;
        let stat = os::fstat(&fd).map_err(os_err("fstat", name))?;
        if stat.uid != os::euid() {
            return Err(Error::ForeignOwner {
                name: name.to_string(),
                uid: stat.uid,
            });
        }
        if stat.mode & 0o077 != 0 {
            return Err(Error::InsecureMode {
                name: name.to_string(),
                mode: stat.mode,
            });
        }
        let loop_alive = || os::byte_is_locked(&fd, LOOP_LOCK_BYTE).unwrap_or(false);
        // No header yet: the creator is at work (its loop byte locked) or died before writing it.
        let unfinished = || {
            if loop_alive() {
                Error::Initializing {
                    name: name.to_string(),
                }
            } else {
                Error::CreatorDead {
                    name: name.to_string(),
                    pid: 0,
                }
            }
        };
        let header_size = std::mem::size_of::<Header>() as u64;
        if stat.size < header_size {
            // Either mid-creation (loop byte locked) or a creator that died right away.
            return Err(unfinished());
        }
        let mapping = Mapping::map(&fd, stat.size as usize).map_err(os_err("mmap", name))?;
        // SAFETY: the mapping holds at least a header (checked above); atomics only.
        let header = unsafe { mapping.base().cast::<Header>().as_ref() };
        let magic = header.magic.load(Ordering::Acquire);
        if magic == 0 {
            return Err(unfinished());
        }
        let (layout, schema) = validate(header, name, stat.size, &P::CHANNELS)?;
        let creator_pid = header.creator_pid.load(Ordering::Relaxed) as u32;
        if !loop_alive() {
            return Err(Error::CreatorDead {
                name: name.to_string(),
                pid: creator_pid,
            });
        }
        if !os::try_lock_byte(&fd, SERVER_LOCK_BYTE).map_err(os_err("lock server byte", name))? {
            let pid = header.server_pid.load(Ordering::Relaxed) as u32;
            return Err(Error::ServerAlreadyAttached {
                name: name.to_string(),
                pid,
            });
        }
        header.server_pid.store(os::pid() as u64, Ordering::Relaxed);
        header.server_attachments.fetch_add(1, Ordering::AcqRel);
        let shared = Arc::new(Shared {
            mapping,
            fd,
            name: name.clone(),
            role: Role::Server,
            layout,
            specs: P::CHANNELS,
            taken: AtomicU32::new(0),
            schema,
            creator_pid: u64::from(creator_pid),
            corrupt: CorruptSink::default(),
            superseded: AtomicBool::new(false),
            _instance_lock: None,
        });
        // A previous server that died while parked left its waiter registrations behind; the
        // loop would then pay for a FUTEX_WAKE on every step. We are the only server now (we
        // hold the server lock) and not parked yet, so they can only be stale.
        for (i, spec) in P::CHANNELS.iter().enumerate() {
            let ring = shared.ring(i);
            if spec.writer == Role::Server {
                crate::ring::spsc::clear_space_waiters(&ring);
            } else {
                crate::ring::spsc::clear_data_waiters(&ring);
            }
        }
        Ok(Segment {
            shared,
            replaced: None,
            _protocol: PhantomData,
        })
    }

    /// Reads and validates a segment's header without attaching: takes no lock, changes
    /// nothing (no attachment counted, no request skipped), works while a server is attached.
    /// For tools and diagnostics.
    pub fn inspect(name: &SegmentName) -> Result<SegmentInfo, Error> {
        let fd = open_existing(name)?;
        let stat = os::fstat(&fd).map_err(os_err("fstat", name))?;
        if stat.size < std::mem::size_of::<Header>() as u64 {
            return Err(Error::Initializing {
                name: name.to_string(),
            });
        }
        let mapping = Mapping::map(&fd, stat.size as usize).map_err(os_err("mmap", name))?;
        // SAFETY: the mapping holds at least a header (checked above); atomics only.
        let header = unsafe { mapping.base().cast::<Header>().as_ref() };
        if header.magic.load(Ordering::Acquire) == 0 {
            return Err(Error::Initializing {
                name: name.to_string(),
            });
        }
        validate(header, name, stat.size, &P::CHANNELS)?;
        let mut info = info_of(header, name);
        info.loop_alive = os::byte_is_locked(&fd, LOOP_LOCK_BYTE).unwrap_or(false);
        info.server_alive = os::byte_is_locked(&fd, SERVER_LOCK_BYTE).unwrap_or(false);
        Ok(info)
    }

    /// [`Segment::attach`], retrying transient failures (no segment yet, a dead loop's
    /// segment not yet replaced, initialisation in progress) until `timeout`.
    pub fn attach_timeout(name: &SegmentName, timeout: Duration) -> Result<Segment<P>, Error> {
        let deadline = Instant::now() + timeout;
        loop {
            match Segment::attach(name) {
                Err(e) if e.is_transient() && Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(5));
                }
                other => return other,
            }
        }
    }

    /// Whether this handle is the loop's (creator) or the server's.
    pub fn role(&self) -> Role {
        self.shared.role
    }

    /// The stale segment `create` replaced, if it did.
    pub fn replaced_stale(&self) -> Option<&StaleSegment> {
        self.replaced.as_ref()
    }

    /// What the header says.
    pub fn info(&self) -> SegmentInfo {
        info_with_liveness(&self.shared)
    }

    /// Whether the other side's process is alive (holds its lock on this segment).
    pub fn peer_alive(&self) -> bool {
        self.shared.peer_alive()
    }

    /// The loop's endpoints, as the protocol builds them. Fails if this handle was attached
    /// (the server's).
    pub fn loop_side(self) -> Result<P::LoopSide, Error> {
        self.check_role(Role::Loop)?;
        P::loop_side(self)
    }

    /// The server's endpoints, as the protocol builds them. Fails if this handle created the
    /// segment (the loop's).
    pub fn server_side(self) -> Result<P::ServerSide, Error> {
        self.check_role(Role::Server)?;
        P::server_side(self)
    }

    fn check_role(&self, wanted: Role) -> Result<(), Error> {
        if self.shared.role == wanted {
            Ok(())
        } else {
            Err(Error::WrongRole {
                actual: self.shared.role.name(),
                wanted: wanted.name(),
            })
        }
    }

    /// Liveness, heartbeats, schema and status of this handle's side (for the endpoints).
    pub fn link(&self) -> Link {
        Link {
            shared: Arc::clone(&self.shared),
        }
    }

    /// Checks that channel `index` is of `kind`, carries `M`, and that this side is its writer
    /// (`write`) or reader, and that its end was not given out before; then the ring.
    fn take<M: Message>(
        &self,
        index: usize,
        kind: ChannelKind,
        write: bool,
    ) -> Result<RingMem, Error> {
        let spec = &self.shared.specs[index];
        let refuse = |reason: String| {
            Err(Error::Channel {
                channel: spec.name,
                reason,
            })
        };
        if spec.kind != kind {
            return refuse(format!("it is {:?}, not {kind:?}", spec.kind));
        }
        if spec.shape != MessageShape::of::<M>() {
            return refuse("the message type is not the protocol's for it".into());
        }
        if (self.shared.role == spec.writer) != write {
            let (end, side) = if write {
                ("written", spec.writer)
            } else {
                ("read", spec.writer.peer())
            };
            return refuse(format!("it is {end} by the {} side only", side.name()));
        }
        let bit = 1 << index;
        if self.shared.taken.fetch_or(bit, Ordering::AcqRel) & bit != 0 {
            return refuse("its end was given out already (one producer, one consumer)".into());
        }
        Ok(self.shared.ring(index))
    }

    /// The producer of lossless channel `ch` (this side must be its writer).
    pub fn producer<M: Message>(&self, ch: Lossless<M>) -> Result<Producer<M>, Error> {
        let ring = self.take::<M>(ch.index(), ChannelKind::Lossless, true)?;
        Ok(Producer::new(ring, self.shared.probe()))
    }

    /// The consumer of lossless channel `ch` (this side must be its reader).
    pub fn consumer<M: Message>(&self, ch: Lossless<M>) -> Result<Consumer<M>, Error> {
        let ring = self.take::<M>(ch.index(), ChannelKind::Lossless, false)?;
        Ok(Consumer::new(ring, self.shared.probe()))
    }

    /// The producer of overwriting channel `ch` (this side must be its writer).
    pub fn overwrite_producer<M: Message>(
        &self,
        ch: Overwrite<M>,
    ) -> Result<OverwriteProducer<M>, Error> {
        let ring = self.take::<M>(ch.index(), ChannelKind::Overwrite, true)?;
        Ok(OverwriteProducer::new(ring))
    }

    /// The consumer of overwriting channel `ch` (this side must be its reader).
    pub fn overwrite_consumer<M: Message>(
        &self,
        ch: Overwrite<M>,
    ) -> Result<OverwriteConsumer<M>, Error> {
        let ring = self.take::<M>(ch.index(), ChannelKind::Overwrite, false)?;
        Ok(OverwriteConsumer::new(ring, self.shared.probe()))
    }
}

/// Takes the creator's instance lock. The lock file may be removed by a previous owner
/// between our open and our lock, so after locking we check that the path still names the
/// file we locked (same inode), and start over if not.
fn lock_instance(name: &SegmentName) -> Result<std::fs::File, Error> {
    use std::os::unix::fs::MetadataExt;
    let path = name.lock_path();
    loop {
        let lock = os::open_lock_file(&path).map_err(os_err("open instance lock", name))?;
        if !os::try_lock_byte(&lock, 0).map_err(os_err("lock instance", name))? {
            return Err(Error::InstanceInUse {
                name: name.to_string(),
                pid: peek_creator_pid(name).unwrap_or(0),
            });
        }
        let ours = lock
            .metadata()
            .map_err(os_err("stat instance lock", name))?;
        match std::fs::metadata(&path) {
            Ok(now) if now.ino() == ours.ino() && now.dev() == ours.dev() => return Ok(lock),
            _ => continue,
        }
    }
}

/// Liveness and identity shared by all endpoints of one side. Cheap to clone.
#[derive(Clone)]
pub struct Link {
    pub(crate) shared: Arc<Shared>,
}

impl Link {
    /// Whether the other side's process is alive. One syscall: not for every real-time step
    /// (use [`Link::peer_heartbeat`] there, a plain atomic load).
    pub fn peer_alive(&self) -> bool {
        self.shared.peer_alive()
    }

    /// Bumps this side's heartbeat counter (one atomic store; only this side writes it).
    #[inline]
    pub fn heartbeat(&self) {
        let hb = self.shared.own_heartbeat();
        hb.store(
            hb.load(Ordering::Relaxed).wrapping_add(1),
            Ordering::Relaxed,
        );
    }

    /// This side's heartbeat counter.
    pub fn own_heartbeat(&self) -> u64 {
        self.shared.own_heartbeat().load(Ordering::Relaxed)
    }

    /// The other side's heartbeat counter: if it stops moving while `peer_alive`, the peer is
    /// alive but stuck.
    #[inline]
    pub fn peer_heartbeat(&self) -> u64 {
        self.shared.peer_heartbeat().load(Ordering::Relaxed)
    }

    /// How many times a server attached to this segment; a change means a new server came.
    #[inline]
    pub fn server_attachments(&self) -> u64 {
        self.shared
            .header()
            .server_attachments
            .load(Ordering::Acquire)
    }

    /// Publishes the loop's status words in the header's status block (a seqlock; readers
    /// never see a torn snapshot; what the words mean is the protocol's: haptics-proto's
    /// `status::LoopStatusLink` wraps this). Loop side only (the single writer): returns
    /// `None` on a server's handle, else the generation written. Call it about every 100 ms,
    /// not per step; it allocates nothing, takes no lock and makes no syscall.
    pub fn publish_status(&self, words: &[u64; STATUS_WORDS]) -> Option<u64> {
        (self.shared.role == Role::Loop).then(|| self.shared.header().loop_status.0.publish(words))
    }

    /// The loop's last published status words and their generation, `None` if it never
    /// published (or died mid-write).
    pub fn status(&self) -> Option<(u64, [u64; STATUS_WORDS])> {
        self.shared.header().loop_status.0.read()
    }

    /// The feature schema (names in `FeatureMsg::values` order): the copy validated when the
    /// segment was created or attached.
    pub fn feature_names(&self) -> Vec<String> {
        self.shared.schema.clone()
    }

    /// Corruption this process found in the segment so far: corrupt slots and impossible
    /// indices seen by any of its endpoints, plus failed [`Link::audit`]s. Process-private
    /// (another process cannot change it), so the owner can act on it.
    pub fn corrupt(&self) -> u64 {
        self.shared.corrupt.load(Ordering::Relaxed)
    }

    /// Checks the segment for damage another process may have done: the header's fixed
    /// fields (magic, version, sizes, capacities, offsets, layout ids, creator, schema) against
    /// this process's private copies, and each ring's shared indices against what the
    /// protocol allows (`head <= tail <= head + capacity`; checked without false alarms while
    /// both sides run). A failure is counted in [`Link::corrupt`]. A few hundred atomic loads
    /// and one schema decode (allocates): for a supervisor thread, not the real-time step.
    pub fn audit(&self) -> Result<(), Corruption> {
        let found = audit(&self.shared);
        if found.is_err() {
            self.shared.corrupt.fetch_add(1, Ordering::Relaxed);
        }
        found
    }

    /// Replaces a corrupt segment with a fresh one under the same name (loop side only: the
    /// owner). This segment is marked superseded (dropping it no longer unlinks the name), its
    /// loop liveness lock is released at once (so the server's next probe says "loop gone"
    /// and it re-attaches, finding the new segment), and its name is unlinked; the new one has
    /// the same capacities and schema. The instance lock is kept throughout (a duplicate of
    /// its descriptor moves to the new segment), so no other loop can take the name meanwhile.
    /// Endpoints of this segment keep working on the old memory until dropped, but nobody
    /// serves them any more. Off the real-time path: several syscalls and a 2 MB mapping.
    pub fn recreate<P: Protocol>(&self) -> Result<Segment<P>, Error> {
        let s = &self.shared;
        if P::CHANNELS != s.specs {
            return Err(Error::InvalidConfig(
                "recreate with another protocol than the segment's".into(),
            ));
        }
        let Some(lock) = s._instance_lock.as_ref().filter(|_| s.role == Role::Loop) else {
            return Err(Error::WrongRole {
                actual: s.role.name(),
                wanted: "loop",
            });
        };
        let lock = lock
            .try_clone()
            .map_err(os_err("duplicate instance lock", &s.name))?;
        let config = Config {
            feature_names: s.schema.clone(),
            capacities: s.layout.capacities,
        };
        let schema = config.validate(&P::CHANNELS)?;
        s.superseded.store(true, Ordering::Release);
        let _ = os::unlock_byte(&s.fd, LOOP_LOCK_BYTE);
        match os::shm_unlink(s.name.as_str()) {
            Ok(()) => {}
            Err(e) if e.raw_os_error() == Some(libc::ENOENT) => {}
            Err(e) => return Err(os_err("unlink corrupt segment", &s.name)(e)),
        }
        Segment::<P>::create_locked(&s.name, &config, schema, lock)
    }

    /// What the header says.
    pub fn info(&self) -> SegmentInfo {
        info_with_liveness(&self.shared)
    }

    /// The segment's name.
    pub fn name(&self) -> &SegmentName {
        &self.shared.name
    }
}
