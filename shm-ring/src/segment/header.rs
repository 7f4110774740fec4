//! The segment header: a `#[repr(C)]` struct made only of atomics, written by the creator
//! before it publishes `magic` (release) and validated by every attacher (acquire).

use std::sync::atomic::{AtomicU64, Ordering};

use super::channel::{MessageShape, CHANNELS};
use crate::fixed_str::{FixedStr, FIXED_STR_WORDS};
use crate::ring::mem::{slot_words, Padded, RingControl};
use crate::status_block::{StatusBlock, STATUS_WORDS};

/// Most names the header's schema holds (the names of the first channel's values; the
/// protocol's message must carry at most as many values).
pub const MAX_SCHEMA_NAMES: usize = 16;

// The status block's size is part of the layout (LAYOUT_VERSION 5: 78 words; 4 added the
// saturated steps, the board's fault counters and the passivity layer's figures, 5 the
// features' filter gains).
const _: () = assert!(std::mem::size_of::<StatusBlock>() == (1 + STATUS_WORDS) * 8);

/// "HAPTSHM1" little-endian: the first word of every segment.
pub const MAGIC: u64 = u64::from_le_bytes(*b"HAPTSHM1");
/// Bumped whenever the header or ring protocol changes incompatibly.
/// 2: the loop-status block (`loop_status`) was added after the heartbeats.
/// 3: the loop-status block gained the degradation ladder's counters and the experiment name.
/// 4: the loop-status block gained the saturated steps' count (issue 23), the board's fault
///    counters and last fault, and the passivity layer's figures (issue 20).
/// 5: the loop-status block gained the filter gains of the loop's velocity and acceleration
///    features (a model fitted on other ones is named when it is activated).
pub const LAYOUT_VERSION: u64 = 5;

/// Per-channel description in the header.
#[repr(C)]
pub(crate) struct ChannelDesc {
    pub(crate) capacity: AtomicU64,
    pub(crate) payload_words: AtomicU64,
    pub(crate) slot_bytes: AtomicU64,
    pub(crate) slot_align: AtomicU64,
    pub(crate) layout_id: AtomicU64,
    pub(crate) control_offset: AtomicU64,
    pub(crate) slots_offset: AtomicU64,
}

/// The header at offset 0 of the segment.
#[repr(C)]
pub(crate) struct Header {
    pub(crate) magic: AtomicU64,
    pub(crate) layout_version: AtomicU64,
    pub(crate) header_size: AtomicU64,
    pub(crate) control_size: AtomicU64,
    pub(crate) control_align: AtomicU64,
    pub(crate) total_size: AtomicU64,
    pub(crate) creator_pid: AtomicU64,
    pub(crate) creator_start_ticks: AtomicU64,
    pub(crate) created_unix_ns: AtomicU64,
    pub(crate) server_pid: AtomicU64,
    /// How many times a server attached; the loop sees a new server come as a change.
    pub(crate) server_attachments: AtomicU64,
    pub(crate) schema_len: AtomicU64,
    pub(crate) schema: [[AtomicU64; FIXED_STR_WORDS]; MAX_SCHEMA_NAMES],
    pub(crate) channels: [ChannelDesc; CHANNELS],
    pub(crate) loop_heartbeat: Padded<AtomicU64>,
    pub(crate) server_heartbeat: Padded<AtomicU64>,
    /// Written by the loop about every 100 ms (a seqlock; see `status_block`).
    pub(crate) loop_status: Padded<StatusBlock>,
}

/// Where everything sits in a segment of given capacities. Each process keeps its own copy
/// (computed by the creator, recomputed and compared by an attacher): rings are placed from
/// it, never from the header, which any process with the segment mapped can rewrite.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Layout {
    /// Slots per ring (validated: powers of two in 2..=MAX_CAPACITY).
    pub(crate) capacities: [usize; CHANNELS],
    pub(crate) control_offsets: [usize; CHANNELS],
    pub(crate) slots_offsets: [usize; CHANNELS],
    pub(crate) total: usize,
}

const fn align_up(x: usize, a: usize) -> usize {
    x.div_ceil(a) * a
}

/// Slots start on 128-byte boundaries (a slot is a whole number of 64-byte lines).
pub(crate) const SLOT_ALIGN: usize = 128;

impl Layout {
    pub(crate) fn compute(
        capacities: [usize; CHANNELS],
        shapes: &[MessageShape; CHANNELS],
    ) -> Layout {
        let mut at = align_up(std::mem::size_of::<Header>(), RingControl::ALIGN);
        let mut control_offsets = [0; CHANNELS];
        for off in &mut control_offsets {
            *off = at;
            at += RingControl::SIZE;
        }
        let mut slots_offsets = [0; CHANNELS];
        for (i, shape) in shapes.iter().enumerate() {
            at = align_up(at, SLOT_ALIGN);
            slots_offsets[i] = at;
            at += capacities[i] * slot_words(shape.words) * 8;
        }
        Layout {
            capacities,
            control_offsets,
            slots_offsets,
            total: align_up(at, 4096),
        }
    }
}

impl Header {
    /// Writes every field but `magic`, for a freshly zeroed segment.
    pub(crate) fn init(
        &self,
        capacities: [usize; CHANNELS],
        schema: &[FixedStr],
        layout: &Layout,
        shapes: &[MessageShape; CHANNELS],
        created_unix_ns: u64,
    ) {
        let r = Ordering::Relaxed;
        self.layout_version.store(LAYOUT_VERSION, r);
        self.header_size
            .store(std::mem::size_of::<Header>() as u64, r);
        self.control_size.store(RingControl::SIZE as u64, r);
        self.control_align.store(RingControl::ALIGN as u64, r);
        self.total_size.store(layout.total as u64, r);
        let pid = crate::os::pid();
        self.creator_pid.store(pid as u64, r);
        self.creator_start_ticks
            .store(crate::os::process_start_ticks(pid).unwrap_or(0), r);
        self.created_unix_ns.store(created_unix_ns, r);
        self.schema_len.store(schema.len() as u64, r);
        for (cells, name) in self.schema.iter().zip(schema) {
            for (cell, word) in cells.iter().zip(name.to_words()) {
                cell.store(word, r);
            }
        }
        for (i, shape) in shapes.iter().enumerate() {
            let (words, id) = (shape.words, shape.layout_id);
            let desc = &self.channels[i];
            desc.capacity.store(capacities[i] as u64, r);
            desc.payload_words.store(words as u64, r);
            desc.slot_bytes.store(slot_words(words) as u64 * 8, r);
            desc.slot_align.store(SLOT_ALIGN as u64, r);
            desc.layout_id.store(id, r);
            desc.control_offset
                .store(layout.control_offsets[i] as u64, r);
            desc.slots_offset.store(layout.slots_offsets[i] as u64, r);
        }
    }

    pub(crate) fn capacities(&self) -> [usize; CHANNELS] {
        let mut caps = [0; CHANNELS];
        for (cap, desc) in caps.iter_mut().zip(&self.channels) {
            *cap = desc.capacity.load(Ordering::Relaxed) as usize;
        }
        caps
    }

    pub(crate) fn schema(&self) -> Option<Vec<String>> {
        let len = self.schema_len.load(Ordering::Relaxed) as usize;
        if len > MAX_SCHEMA_NAMES {
            return None;
        }
        let mut names = Vec::with_capacity(len);
        for cells in &self.schema[..len] {
            let mut words = [0u64; FIXED_STR_WORDS];
            for (w, c) in words.iter_mut().zip(cells) {
                *w = c.load(Ordering::Relaxed);
            }
            names.push(FixedStr::from_words(&words)?.as_str().to_owned());
        }
        Some(names)
    }
}
