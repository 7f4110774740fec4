//! `Shared`: the mapping and the descriptor whose OFD locks carry liveness, shared (`Arc`) by
//! every endpoint of one handle, with this process's private copies of the segment's shape.
//! Apart from `mod.rs` so that the checks (`check`) and the header's reading (`info`) can take
//! it without importing the module that creates segments (no module imports one that imports
//! it back: docs/shm-ring.md).

use std::os::fd::OwnedFd;
use std::ptr::NonNull;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::Arc;

use super::channel::{ChannelSpec, Role, CHANNELS};
use super::header::{Header, Layout};
use super::name::SegmentName;
use crate::os::{self, Mapping};
use crate::ring::mem::{CorruptSink, RingControl, RingMem};
use crate::ring::spsc::PeerProbe;

/// The byte of the segment whose OFD lock says the loop is alive, and the server's.
pub(super) const LOOP_LOCK_BYTE: u64 = 0;
pub(super) const SERVER_LOCK_BYTE: u64 = 1;

/// The mapping plus the descriptor whose OFD locks carry liveness. Shared (via `Arc`) by every
/// endpoint of one handle, so the memory stays mapped until the last endpoint is dropped.
///
/// Everything this process needs to know about the segment's shape (capacities, offsets,
/// schema, creator) is a private copy made when the segment was created or validated; the
/// header is only read again by [`Link::audit`](super::Link::audit), to compare.
pub(crate) struct Shared {
    pub(super) mapping: Mapping,
    pub(super) fd: OwnedFd,
    pub(super) name: SegmentName,
    pub(super) role: Role,
    pub(super) layout: Layout,
    /// The protocol's channels, in order (what the header was checked against).
    pub(super) specs: [ChannelSpec; CHANNELS],
    /// Which channels' ends this handle has given out (bit per channel): one producer and one
    /// consumer per ring in all, each on its writer's or reader's side.
    pub(super) taken: AtomicU32,
    pub(super) schema: Vec<String>,
    pub(super) creator_pid: u64,
    /// Corruption found by this process's endpoints and audits (process-private).
    pub(super) corrupt: CorruptSink,
    /// Set by [`Link::recreate`](super::Link::recreate): a newer segment owns the name, so
    /// dropping this one must neither unlink the name nor remove the lock file.
    pub(super) superseded: AtomicBool,
    /// The creator's instance lock; kept open (locked) for the loop's lifetime.
    pub(super) _instance_lock: Option<std::fs::File>,
}

impl Shared {
    pub(crate) fn header(&self) -> &Header {
        // SAFETY: the mapping is at least `size_of::<Header>()` bytes (checked before this
        // struct is built), page-aligned, and only accessed through the header's atomics.
        unsafe { self.mapping.base().cast::<Header>().as_ref() }
    }

    pub(super) fn ring(self: &Arc<Self>, i: usize) -> RingMem {
        let base = self.mapping.base().as_ptr();
        // The private, validated copy: never the header's word, which another process can
        // rewrite at any time (a capacity of 0 there would make the mask u64::MAX).
        let capacity = self.layout.capacities[i];
        let payload = self.specs[i].shape.words;
        // SAFETY: capacities and offsets are this process's `Layout::compute` result (checked
        // against the header and the file size when attaching; the mapping is `layout.total`
        // bytes, so every ring lies inside it); control blocks are aligned to
        // RingControl::ALIGN and slots to SLOT_ALIGN; the memory is only used through atomics
        // and stays mapped while the `Arc<Shared>` owner passed along lives.
        unsafe {
            let ctrl = NonNull::new_unchecked(base.add(self.layout.control_offsets[i]))
                .cast::<RingControl>();
            let slots =
                NonNull::new_unchecked(base.add(self.layout.slots_offsets[i])).cast::<AtomicU64>();
            RingMem::foreign(
                ctrl,
                slots,
                capacity,
                payload,
                Arc::clone(&self.corrupt),
                self.clone(),
            )
        }
    }

    pub(super) fn probe(self: &Arc<Self>) -> PeerProbe {
        let shared = Arc::clone(self);
        Some(Arc::new(move || shared.peer_alive()))
    }

    pub(super) fn peer_byte(&self) -> u64 {
        match self.role {
            Role::Loop => SERVER_LOCK_BYTE,
            Role::Server => LOOP_LOCK_BYTE,
        }
    }

    /// Whether the other side's process holds its liveness lock on this segment.
    /// One `fcntl` syscall: call it from the slow path, not every real-time step.
    pub(crate) fn peer_alive(&self) -> bool {
        // An error here (it cannot happen on a valid fd) reads as "not alive": the safe side.
        os::byte_is_locked(&self.fd, self.peer_byte()).unwrap_or(false)
    }

    pub(super) fn own_heartbeat(&self) -> &AtomicU64 {
        match self.role {
            Role::Loop => &self.header().loop_heartbeat.0,
            Role::Server => &self.header().server_heartbeat.0,
        }
    }

    pub(super) fn peer_heartbeat(&self) -> &AtomicU64 {
        match self.role {
            Role::Loop => &self.header().server_heartbeat.0,
            Role::Server => &self.header().loop_heartbeat.0,
        }
    }
}

impl Drop for Shared {
    fn drop(&mut self) {
        // A clean loop exit removes its segment; it still holds the instance lock here, so the
        // name cannot belong to anyone else. A server that stays mapped keeps its memory and
        // sees the loop's lock released.
        if self.role == Role::Loop && !self.superseded.load(Ordering::Acquire) {
            let _ = os::shm_unlink(self.name.as_str());
            // Removing the lock file while still holding its lock is safe because
            // `lock_instance` re-checks, after locking, that the path still names its file.
            let _ = std::fs::remove_file(self.name.lock_path());
        }
    }
}
