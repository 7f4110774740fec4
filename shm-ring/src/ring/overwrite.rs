//! The overwrite ring (telemetry): the producer never waits and never fails; when the consumer
//! falls a whole ring behind, the oldest messages are overwritten and the consumer counts them
//! as dropped.
//!
//! "Drop oldest" cannot be done by the consumer's index alone (the producer would have to
//! move the consumer's head), so each slot is a seqlock: the producer writing position `p`
//! stores `2p + 1` (odd: being written) in the slot's sequence word, then a release fence,
//! the payload words (relaxed atomic stores), then `2p + 2` (even: complete, release), then
//! the shared tail `p + 1` (release). The consumer reading position `p` loads the sequence
//! word (acquire), the payload words (relaxed atomic loads), an acquire fence and the sequence
//! word again: the read is good only if both loads gave `2p + 2`. If the producer lapped the
//! consumer during the read, the fences guarantee the second load sees the newer odd/even
//! value, so a torn read is always detected and counted as a drop, never returned.
//! The payload is atomics throughout, so the racing reads are not data races (no UB).
//!
//! Against a corrupt peer: the sequence arithmetic wraps instead of overflowing, the slot index
//! uses the private mask, and a shared tail behind the consumer (impossible: the producer
//! never moves back) is counted as corrupt and the consumer re-synchronises on it.

use std::marker::PhantomData;

use crate::ring::mem::{CorruptCount, RingMem};
use crate::ring::message::{Message, MAX_WORDS};
use crate::ring::spsc::RecvError;
use crate::ring::sync::{fence, Ordering};

#[cfg(not(loom))]
use crate::ring::spsc::PeerProbe;
#[cfg(not(loom))]
use crate::ring::wait::{wait_for, WaitEnd, WaitStrategy};
#[cfg(not(loom))]
use std::time::{Duration, Instant};

/// Producing end of an overwrite ring: `send` always succeeds at once.
pub struct OverwriteProducer<M: Message> {
    mem: RingMem,
    tail: u64,
    _msg: PhantomData<fn(M)>,
}

/// Consuming end of an overwrite ring: receives in order, skipping (and counting) what the
/// producer overwrote before it was read.
pub struct OverwriteConsumer<M: Message> {
    mem: RingMem,
    head: u64,
    dropped: u64,
    corrupt: CorruptCount,
    #[cfg(not(loom))]
    wait: WaitStrategy,
    #[cfg(not(loom))]
    peer: PeerProbe,
    _msg: PhantomData<fn() -> M>,
}

/// An overwrite ring on the heap, for in-process use and tests. `capacity`: a power of two.
pub fn heap_overwrite_channel<M: Message>(
    capacity: usize,
) -> (OverwriteProducer<M>, OverwriteConsumer<M>) {
    let mem = RingMem::heap(capacity, M::WORDS);
    let twin = mem.twin();
    #[cfg(not(loom))]
    let consumer = OverwriteConsumer::new(twin, None);
    #[cfg(loom)]
    let consumer = OverwriteConsumer::new(twin);
    (OverwriteProducer::new(mem), consumer)
}

/// Sequence word of a slot being written at position `pos` (odd). Wrapping: only a corrupt
/// position is that large, and the reader's comparison catches it.
#[inline]
fn seq_writing(pos: u64) -> u64 {
    pos.wrapping_mul(2).wrapping_add(1)
}

/// Sequence word of a slot whose write at `pos` is complete (even).
#[inline]
fn seq_written(pos: u64) -> u64 {
    pos.wrapping_mul(2).wrapping_add(2)
}

impl<M: Message> OverwriteProducer<M> {
    pub(crate) fn new(mem: RingMem) -> Self {
        assert!(M::WORDS <= MAX_WORDS);
        let tail = mem.ctrl().tail.0.load(Ordering::Relaxed);
        OverwriteProducer {
            mem,
            tail,
            _msg: PhantomData,
        }
    }

    /// Publishes `msg`, overwriting the oldest message if the ring is full. Never blocks,
    /// never allocates, no syscall unless the consumer is parked (then one `FUTEX_WAKE`).
    #[inline]
    pub fn send(&mut self, msg: &M) {
        let mut words = [0u64; MAX_WORDS];
        msg.encode(&mut words[..M::WORDS]);
        let pos = self.tail;
        let slot = self.mem.slot(pos);
        slot[0].store(seq_writing(pos), Ordering::Relaxed);
        fence(Ordering::Release);
        RingMem::store_payload(slot, &words[..M::WORDS]);
        slot[0].store(seq_written(pos), Ordering::Release);
        self.tail = pos.wrapping_add(1);
        self.mem.publish_tail(self.tail);
    }

    /// Messages published so far.
    pub fn position(&self) -> u64 {
        self.tail
    }

    /// Messages the consumer reported lost so far (it counts them as it notices).
    pub fn dropped(&self) -> u64 {
        self.mem.ctrl().dropped.0.load(Ordering::Relaxed)
    }
}

impl<M: Message> OverwriteConsumer<M> {
    pub(crate) fn new(mem: RingMem, #[cfg(not(loom))] peer: PeerProbe) -> Self {
        assert!(M::WORDS <= MAX_WORDS);
        let head = mem.ctrl().head.0.load(Ordering::Relaxed);
        let dropped = mem.ctrl().dropped.0.load(Ordering::Relaxed);
        OverwriteConsumer {
            mem,
            head,
            dropped,
            corrupt: CorruptCount::default(),
            #[cfg(not(loom))]
            wait: WaitStrategy::default(),
            #[cfg(not(loom))]
            peer,
            _msg: PhantomData,
        }
    }

    /// The oldest message still available, if any. Never blocks.
    pub fn try_recv(&mut self) -> Result<Option<M>, RecvError> {
        let capacity = self.mem.capacity();
        loop {
            let tail = self.mem.ctrl().tail.0.load(Ordering::Acquire);
            if tail < self.head {
                // The producer never moves back: someone else wrote the tail. Count it and
                // follow the tail (the rows in between are not ours to trust).
                let head = self.head;
                self.corrupt.note(&self.mem);
                self.head = tail;
                self.mem.ctrl().head.0.store(tail, Ordering::Release);
                return Err(crate::ring::spsc::CorruptRing::Indices {
                    head,
                    tail,
                    capacity,
                }
                .into());
            }
            if tail == self.head {
                return Ok(None);
            }
            if tail - self.head > capacity {
                // Lapped: everything older than the last `capacity` messages is gone.
                self.lose(tail - capacity - self.head);
            }
            let pos = self.head;
            let expected = seq_written(pos);
            let slot = self.mem.slot(pos);
            let first = slot[0].load(Ordering::Acquire);
            let mut words = [0u64; MAX_WORDS];
            for (word, cell) in words[..M::WORDS].iter_mut().zip(&slot[1..=M::WORDS]) {
                *word = cell.load(Ordering::Relaxed);
            }
            fence(Ordering::Acquire);
            let second = slot[0].load(Ordering::Relaxed);
            if first != expected || second != expected {
                // Overwritten before or while we read it: a newer lap owns the slot.
                self.lose(1);
                continue;
            }
            self.head = pos + 1;
            self.mem.ctrl().head.0.store(self.head, Ordering::Release);
            return Ok(Some(M::decode(&words[..M::WORDS])?));
        }
    }

    /// Impossible tails seen by this consumer, over its life.
    pub fn corrupt(&self) -> u64 {
        self.corrupt.get()
    }

    fn lose(&mut self, count: u64) {
        self.head += count;
        self.dropped = self.dropped.wrapping_add(count);
        self.mem
            .ctrl()
            .dropped
            .0
            .store(self.dropped, Ordering::Relaxed);
    }

    /// Messages lost to overwriting so far.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Position of the next message this consumer will read.
    pub fn position(&self) -> u64 {
        self.head
    }
}

#[cfg(not(loom))]
impl<M: Message> OverwriteConsumer<M> {
    /// How [`OverwriteConsumer::recv`] waits for data.
    pub fn set_wait_strategy(&mut self, wait: WaitStrategy) {
        self.wait = wait;
    }

    /// Waits for the next available message (or the producer's death).
    pub fn recv(&mut self) -> Result<M, RecvError> {
        self.recv_until(None)
    }

    /// As [`OverwriteConsumer::recv`], giving up after `timeout`.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Result<M, RecvError> {
        self.recv_until(Some(Instant::now() + timeout))
    }

    fn recv_until(&mut self, deadline: Option<Instant>) -> Result<M, RecvError> {
        loop {
            if let Some(msg) = self.try_recv()? {
                return Ok(msg);
            }
            let mem = &self.mem;
            let head = self.head;
            let waited = wait_for(
                &mem.ctrl().data.0,
                self.wait,
                deadline,
                self.peer.as_deref(),
                || (mem.ctrl().tail.0.load(Ordering::Acquire) != head).then_some(()),
            );
            match waited {
                Ok(()) => {}
                Err(WaitEnd::Timeout) => return Err(RecvError::Timeout),
                Err(WaitEnd::PeerGone) => return Err(RecvError::PeerGone),
            }
        }
    }
}
