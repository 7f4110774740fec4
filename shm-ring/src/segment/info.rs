//! What a segment's header says (`SegmentInfo`), read without trusting it: for `inspect`,
//! diagnostics and the messages of a refused attach.

use std::sync::atomic::Ordering;

use super::channel::{Role, CHANNELS};
use super::header::{Header, MAGIC};
use super::name::SegmentName;
use super::shared::Shared;
use crate::os::{self, Mapping};

/// What the header says about a segment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SegmentInfo {
    pub name: String,
    pub layout_version: u64,
    pub total_size: u64,
    pub creator_pid: u32,
    pub creator_start_ticks: u64,
    pub created_unix_ns: u64,
    pub server_pid: u32,
    pub server_attachments: u64,
    pub feature_names: Vec<String>,
    /// Capacities, in the protocol's channel order.
    pub capacities: [usize; CHANNELS],
    /// Byte offsets of each channel's control block (head, tail, signals) and slot array,
    /// in the same order (for diagnostics and the corruption tests).
    pub control_offsets: [u64; CHANNELS],
    pub slots_offsets: [u64; CHANNELS],
    /// Whether the loop holds its liveness lock (filled by
    /// [`Segment::inspect`](super::Segment::inspect); `info()` on a handle reports its own side
    /// as alive and asks for the peer).
    pub loop_alive: bool,
    /// Whether a server holds its liveness lock (as above).
    pub server_alive: bool,
}

impl SegmentInfo {
    /// Whether the creator process (pid plus start time, so a reused pid does not count)
    /// still runs. Diagnostic only: liveness proper is the lock (`Link::peer_alive`).
    pub fn creator_process_alive(&self) -> bool {
        os::process_alive(self.creator_pid, self.creator_start_ticks)
    }
}

/// A stale segment that `create` found and replaced.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StaleSegment {
    pub creator_pid: u32,
}

pub(super) fn info_of(header: &Header, name: &SegmentName) -> SegmentInfo {
    let r = Ordering::Relaxed;
    SegmentInfo {
        name: name.to_string(),
        layout_version: header.layout_version.load(r),
        total_size: header.total_size.load(r),
        creator_pid: header.creator_pid.load(r) as u32,
        creator_start_ticks: header.creator_start_ticks.load(r),
        created_unix_ns: header.created_unix_ns.load(r),
        server_pid: header.server_pid.load(r) as u32,
        server_attachments: header.server_attachments.load(Ordering::Acquire),
        feature_names: header.schema().unwrap_or_default(),
        capacities: header.capacities(),
        control_offsets: header.channels.each_ref().map(|d| d.control_offset.load(r)),
        slots_offsets: header.channels.each_ref().map(|d| d.slots_offset.load(r)),
        loop_alive: false,
        server_alive: false,
    }
}

/// `info_of` plus liveness as seen from a handle of `role`; the shape (capacities, schema)
/// is this process's validated copy, not what the header says now.
pub(super) fn info_with_liveness(shared: &Shared) -> SegmentInfo {
    let mut info = info_of(shared.header(), &shared.name);
    info.capacities = shared.layout.capacities;
    info.control_offsets = shared.layout.control_offsets.map(|o| o as u64);
    info.slots_offsets = shared.layout.slots_offsets.map(|o| o as u64);
    info.feature_names = shared.schema.clone();
    let peer = shared.peer_alive();
    match shared.role {
        Role::Loop => (info.loop_alive, info.server_alive) = (true, peer),
        Role::Server => (info.loop_alive, info.server_alive) = (peer, true),
    }
    info
}

/// Best effort: the pid recorded in an existing segment's header, for error messages.
pub(super) fn peek_creator_pid(name: &SegmentName) -> Option<u32> {
    let fd = os::shm_open(name.as_str(), false).ok()?;
    let stat = os::fstat(&fd).ok()?;
    if stat.size < std::mem::size_of::<Header>() as u64 {
        return None;
    }
    let mapping = Mapping::map(&fd, std::mem::size_of::<Header>()).ok()?;
    // SAFETY: mapped at least a header; atomics only.
    let header = unsafe { mapping.base().cast::<Header>().as_ref() };
    (header.magic.load(Ordering::Acquire) == MAGIC)
        .then(|| header.creator_pid.load(Ordering::Relaxed) as u32)
}
