//! Where a ring's memory lives: the control block (head, tail, wake signals, counters) and the
//! slot words. The protocol in `spsc` and `overwrite` only sees a [`RingMem`], so the same code
//! runs on heap memory (unit tests, loom, Miri) and inside a shared-memory segment.

use std::any::Any;
use std::ptr::NonNull;
use std::sync::Arc;

/// Process-private corruption counter shared by every ring of one mapping (and by the
/// segment's audit): a hostile peer cannot touch it, so the owner can trust it to decide
/// that the segment must be re-created. Plain std atomic: not part of the loom models.
pub(crate) type CorruptSink = Arc<std::sync::atomic::AtomicU64>;

use crate::ring::sync::{AtomicU32, AtomicU64, Ordering};
use crate::ring::wait::notify;

/// One endpoint's count of corruption it found (private to the endpoint); every count is
/// also added to the segment's process-private total ([`RingMem::note_corrupt`]).
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct CorruptCount(u64);

impl CorruptCount {
    #[cold]
    pub(crate) fn note(&mut self, mem: &RingMem) {
        self.0 += 1;
        mem.note_corrupt();
    }

    pub(crate) fn get(self) -> u64 {
        self.0
    }
}

/// Cache-line padding: 128 bytes, because Intel's adjacent-line prefetcher pulls lines in
/// pairs, so two hot words 64 bytes apart still ping-pong between cores.
#[repr(C, align(128))]
pub(crate) struct Padded<T>(pub(crate) T);

/// A futex-backed event count that one side parks on and the other side bumps.
#[repr(C)]
pub(crate) struct Signal {
    /// Bumped by the notifier before a wake; the futex word the waiter sleeps on.
    pub(crate) epoch: AtomicU32,
    /// 1 while the (single) waiter is parked or about to park; the notifier skips the
    /// syscall when 0 and clears it when it wakes the waiter.
    pub(crate) parked: AtomicU32,
}

/// The shared control block of one ring. `#[repr(C)]` and made only of atomics, so its
/// layout is fixed across builds and every access to it is an atomic access.
#[repr(C)]
pub(crate) struct RingControl {
    /// Next position the producer writes (only the producer stores it).
    pub(crate) tail: Padded<AtomicU64>,
    /// Next position the consumer reads (only the consumer stores it).
    pub(crate) head: Padded<AtomicU64>,
    /// The consumer parks here waiting for data; the producer notifies.
    pub(crate) data: Padded<Signal>,
    /// The producer parks here waiting for space; the consumer notifies.
    pub(crate) space: Padded<Signal>,
    /// Producer-owned counter: pushes refused because the ring was full.
    pub(crate) full: Padded<AtomicU64>,
    /// Consumer-owned counter: messages lost to overwriting (overwrite rings only).
    pub(crate) dropped: Padded<AtomicU64>,
}

impl RingControl {
    #[cfg(not(loom))]
    pub(crate) const SIZE: usize = std::mem::size_of::<RingControl>();
    #[cfg(not(loom))]
    pub(crate) const ALIGN: usize = std::mem::align_of::<RingControl>();

    fn new_zeroed() -> Self {
        let signal = || Signal {
            epoch: AtomicU32::new(0),
            parked: AtomicU32::new(0),
        };
        RingControl {
            tail: Padded(AtomicU64::new(0)),
            head: Padded(AtomicU64::new(0)),
            data: Padded(signal()),
            space: Padded(signal()),
            full: Padded(AtomicU64::new(0)),
            dropped: Padded(AtomicU64::new(0)),
        }
    }
}

/// Words per slot for a message of `payload_words`: one sequence word plus the payload,
/// rounded up to whole 64-byte lines so neighbouring slots never share a cache line.
pub const fn slot_words(payload_words: usize) -> usize {
    (1 + payload_words).div_ceil(8) * 8
}

/// A view of one ring's memory plus whatever keeps that memory alive.
///
/// Invariant: `ctrl` points to a valid `RingControl` and `slots` to `capacity * stride` valid
/// `AtomicU64`s for as long as `_owner` is alive; both are only accessed through `&` (atomics).
/// `capacity` (a power of two >= 2), `mask` and `stride` are private copies fixed when the
/// view is made (from a validated layout): nothing in shared memory is ever re-read to find a
/// slot, so a peer rewriting the header cannot move an access outside the slot array.
pub(crate) struct RingMem {
    ctrl: NonNull<RingControl>,
    slots: NonNull<AtomicU64>,
    capacity: u64,
    mask: u64,
    stride: usize,
    corrupt: CorruptSink,
    _owner: Arc<dyn Any + Send + Sync>,
}

// SAFETY: the pointed-to memory is made only of atomics (Sync) and kept alive by `_owner`
// (Send + Sync), so the view may move to and be shared with other threads.
unsafe impl Send for RingMem {}
unsafe impl Sync for RingMem {}

/// Heap storage for a ring: what the unit tests, loom and Miri run on.
struct HeapStorage {
    ctrl: Box<RingControl>,
    slots: Box<[AtomicU64]>,
}

impl RingMem {
    /// Allocates a zeroed ring on the heap. `capacity` must be a power of two.
    pub(crate) fn heap(capacity: usize, payload_words: usize) -> RingMem {
        assert!(
            capacity.is_power_of_two(),
            "ring capacity must be a power of two"
        );
        let stride = slot_words(payload_words);
        let slots: Box<[AtomicU64]> = (0..capacity * stride).map(|_| AtomicU64::new(0)).collect();
        let storage = Arc::new(HeapStorage {
            ctrl: Box::new(RingControl::new_zeroed()),
            slots,
        });
        let ctrl = NonNull::from(&*storage.ctrl);
        // From the whole slice, so the pointer's provenance covers every slot (Miri-clean).
        let slots = NonNull::from(&storage.slots[..]).cast::<AtomicU64>();
        RingMem {
            ctrl,
            slots,
            capacity: capacity as u64,
            mask: capacity as u64 - 1,
            stride,
            corrupt: CorruptSink::default(),
            _owner: storage,
        }
    }

    /// A view of a ring placed in foreign memory (the shared segment). `capacity` must be a
    /// power of two >= 2 (checked here, always: a wrong one would make `slot` index outside
    /// the array; the segment passes its validated private copy, never a shared-memory value).
    ///
    /// # Safety
    /// `ctrl` must point to a `RingControl` and `slots` to `capacity * slot_words(payload)`
    /// `AtomicU64`s, both properly aligned, that stay mapped while `owner` lives and that are
    /// only ever accessed atomically (by this process or any other).
    #[cfg(not(loom))]
    pub(crate) unsafe fn foreign(
        ctrl: NonNull<RingControl>,
        slots: NonNull<AtomicU64>,
        capacity: usize,
        payload_words: usize,
        corrupt: CorruptSink,
        owner: Arc<dyn Any + Send + Sync>,
    ) -> RingMem {
        assert!(
            capacity.is_power_of_two() && capacity >= 2,
            "ring capacity {capacity} must be a power of two >= 2"
        );
        RingMem {
            ctrl,
            slots,
            capacity: capacity as u64,
            mask: capacity as u64 - 1,
            stride: slot_words(payload_words),
            corrupt,
            _owner: owner,
        }
    }

    /// A second view of the same ring (for the other end), sharing the owner.
    pub(crate) fn twin(&self) -> RingMem {
        RingMem {
            corrupt: Arc::clone(&self.corrupt),
            _owner: Arc::clone(&self._owner),
            ..*self
        }
    }

    #[inline]
    pub(crate) fn ctrl(&self) -> &RingControl {
        // SAFETY: valid while `_owner` lives (struct invariant), shared access only.
        unsafe { self.ctrl.as_ref() }
    }

    /// The words of the slot that holds position `pos` (sequence word first).
    #[inline]
    pub(crate) fn slot(&self, pos: u64) -> &[AtomicU64] {
        let index = (pos & self.mask) as usize;
        // SAFETY: index < capacity, so the range lies inside the slot array (invariant).
        unsafe {
            std::slice::from_raw_parts(self.slots.as_ptr().add(index * self.stride), self.stride)
        }
    }

    /// Stores a message's payload `words` into `slot` after its sequence word. Relaxed: the
    /// producer's release store that follows (sequence word, then tail) publishes them.
    #[inline]
    pub(crate) fn store_payload(slot: &[AtomicU64], words: &[u64]) {
        for (cell, word) in slot[1..=words.len()].iter().zip(words) {
            cell.store(*word, Ordering::Relaxed);
        }
    }

    /// Publishes the producer's `tail` (release: the slots written before it are visible to
    /// a consumer that loads the tail with acquire) and wakes a parked consumer.
    #[inline]
    pub(crate) fn publish_tail(&self, tail: u64) {
        self.ctrl().tail.0.store(tail, Ordering::Release);
        notify(&self.ctrl().data.0);
    }

    #[inline]
    pub(crate) fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Records one corruption found in this ring (off the normal path: only when found).
    #[cold]
    pub(crate) fn note_corrupt(&self) {
        self.corrupt
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    /// Whether `(head, tail)` can be a lossless ring's indices: `head <= tail <= head + capacity`.
    #[inline]
    pub(crate) fn plausible(&self, head: u64, tail: u64) -> bool {
        tail >= head && tail - head <= self.capacity
    }
}
