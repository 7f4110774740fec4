//! The lossless single-producer single-consumer ring (features, forces, commands).
//!
//! Protocol (positions are u64 and never wrap in practice: 2^64 messages):
//! - producer at `tail`: if `tail - head == capacity` the ring is full and the push is refused
//!   (never overwritten, never dropped silently). Otherwise it stores the payload words
//!   (relaxed), the slot's sequence word `tail + 1` (release) and then `tail + 1` into the
//!   shared tail (release).
//! - consumer at `head`: if `head == tail` (tail loaded with acquire) the ring is empty.
//!   Otherwise it checks the slot's sequence word is `head + 1` (a torn or stale slot would
//!   show another value), loads the payload words, then stores `head + 1` (release), which
//!   hands the slot back to the producer (whose acquire load of `head` orders its next
//!   overwrite after our reads).
//!
//! Each side keeps a private copy of the other side's index and only re-reads the shared one
//! when the copy says full/empty, so the hot path touches the peer's cache line rarely.

use std::fmt;
use std::marker::PhantomData;

use crate::message::{DecodeError, Message, MAX_WORDS};
use crate::ring_mem::RingMem;
use crate::sync::Ordering;
use crate::wait::{notify, notify_if};

#[cfg(not(loom))]
use crate::wait::{wait_for, WaitEnd, WaitStrategy};
#[cfg(not(loom))]
use std::time::{Duration, Instant};

/// A shared check "is the process on the other side still alive?" (None: in-process rings).
#[cfg(not(loom))]
pub(crate) type PeerProbe = Option<std::sync::Arc<dyn Fn() -> bool + Send + Sync>>;

/// The ring's memory does not hold what the protocol says it must: another writer, a
/// corrupted segment, or a bug. The consumer stops rather than return garbage.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CorruptRing {
    #[error("slot for position {position} has sequence word {found}, expected {expected}")]
    SlotSequence {
        position: u64,
        expected: u64,
        found: u64,
    },
    #[error("indices out of range: head {head}, tail {tail}, capacity {capacity}")]
    Indices { head: u64, tail: u64, capacity: u64 },
}

/// Why a receive returned no message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RecvError {
    #[error("no message before the deadline")]
    Timeout,
    #[error("the peer process is gone (its liveness lock was released)")]
    PeerGone,
    #[error("ring corrupt: {0}")]
    Corrupt(#[from] CorruptRing),
    #[error("message rejected: {0}")]
    Decode(#[from] DecodeError),
}

/// Why a send did not happen. The message is handed back: nothing is lost silently.
#[derive(PartialEq, Eq)]
pub enum SendError<M> {
    /// The ring is full (`try_send`), so the consumer is behind.
    Full(M),
    /// Still full at the deadline.
    Timeout(M),
    /// The peer process is gone.
    PeerGone(M),
}

impl<M> SendError<M> {
    /// The message that was not sent.
    pub fn into_inner(self) -> M {
        match self {
            SendError::Full(m) | SendError::Timeout(m) | SendError::PeerGone(m) => m,
        }
    }
}

impl<M> fmt::Debug for SendError<M> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

impl<M> fmt::Display for SendError<M> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SendError::Full(_) => "ring full",
            SendError::Timeout(_) => "ring still full at the deadline",
            SendError::PeerGone(_) => "the peer process is gone",
        })
    }
}

impl<M> std::error::Error for SendError<M> {}

/// Free slots a blocked `send` waits for before it resumes (hysteresis against one wake-up
/// per slot when the producer is faster than the consumer).
#[inline]
fn space_wanted(capacity: u64) -> u64 {
    (capacity / 4).max(1)
}

/// Producing end of a lossless ring. Not `Clone`: exactly one producer exists per ring.
pub struct Producer<M: Message> {
    mem: RingMem,
    tail: u64,
    cached_head: u64,
    #[cfg(not(loom))]
    wait: WaitStrategy,
    #[cfg(not(loom))]
    peer: PeerProbe,
    _msg: PhantomData<fn(M)>,
}

/// Consuming end of a lossless ring. Not `Clone`: exactly one consumer exists per ring.
pub struct Consumer<M: Message> {
    mem: RingMem,
    head: u64,
    cached_tail: u64,
    #[cfg(not(loom))]
    wait: WaitStrategy,
    #[cfg(not(loom))]
    peer: PeerProbe,
    _msg: PhantomData<fn() -> M>,
}

/// A lossless ring on the heap, for in-process use and tests. `capacity`: a power of two.
#[cfg(not(loom))]
pub fn heap_channel<M: Message>(capacity: usize) -> (Producer<M>, Consumer<M>) {
    let mem = RingMem::heap(capacity, M::WORDS);
    let twin = mem_twin(&mem);
    (Producer::new(mem, None), Consumer::new(twin, None))
}

/// A lossless ring on the heap (loom build: no wait strategies).
#[cfg(loom)]
pub fn heap_channel<M: Message>(capacity: usize) -> (Producer<M>, Consumer<M>) {
    let mem = RingMem::heap(capacity, M::WORDS);
    let twin = mem_twin(&mem);
    (Producer::new(mem), Consumer::new(twin))
}

/// Forgets consumer waiters that a dead process left registered on a ring's "data" signal
/// (it died parked), so the producer's `notify` stops paying for a futex wake on every push.
/// Only valid while no live consumer can be parked: called when a new consumer attaches.
#[cfg(not(loom))]
pub(crate) fn clear_data_waiters(mem: &RingMem) {
    mem.ctrl().data.0.parked.store(0, Ordering::Relaxed);
}

/// As [`clear_data_waiters`], for a dead producer parked on the "space" signal.
#[cfg(not(loom))]
pub(crate) fn clear_space_waiters(mem: &RingMem) {
    mem.ctrl().space.0.parked.store(0, Ordering::Relaxed);
}

fn mem_twin(mem: &RingMem) -> RingMem {
    mem.twin()
}

impl<M: Message> Producer<M> {
    #[cfg(not(loom))]
    pub(crate) fn new(mem: RingMem, peer: PeerProbe) -> Self {
        assert!(M::WORDS <= MAX_WORDS);
        let tail = mem.ctrl().tail.0.load(Ordering::Relaxed);
        let cached_head = mem.ctrl().head.0.load(Ordering::Acquire);
        Producer {
            mem,
            tail,
            cached_head,
            wait: WaitStrategy::default(),
            peer,
            _msg: PhantomData,
        }
    }

    #[cfg(loom)]
    pub(crate) fn new(mem: RingMem) -> Self {
        let tail = mem.ctrl().tail.0.load(Ordering::Relaxed);
        let cached_head = mem.ctrl().head.0.load(Ordering::Acquire);
        Producer {
            mem,
            tail,
            cached_head,
            _msg: PhantomData,
        }
    }

    /// Pushes `msg` if there is room; otherwise hands it back in `SendError::Full` and counts
    /// the refusal (see [`Producer::full_count`]). Never blocks, never allocates, no syscall
    /// unless the consumer is parked (then one `FUTEX_WAKE`).
    #[inline]
    pub fn try_send(&mut self, msg: M) -> Result<(), SendError<M>> {
        if !self.has_room() {
            let full = &self.mem.ctrl().full.0;
            full.store(full.load(Ordering::Relaxed) + 1, Ordering::Relaxed);
            return Err(SendError::Full(msg));
        }
        self.write(&msg);
        Ok(())
    }

    #[inline]
    fn has_room(&mut self) -> bool {
        let capacity = self.mem.capacity();
        if self.tail - self.cached_head < capacity {
            return true;
        }
        self.cached_head = self.mem.ctrl().head.0.load(Ordering::Acquire);
        self.tail - self.cached_head < capacity
    }

    #[inline]
    fn write(&mut self, msg: &M) {
        let mut words = [0u64; MAX_WORDS];
        msg.encode(&mut words[..M::WORDS]);
        let slot = self.mem.slot(self.tail);
        for (cell, word) in slot[1..=M::WORDS].iter().zip(&words[..M::WORDS]) {
            cell.store(*word, Ordering::Relaxed);
        }
        slot[0].store(self.tail + 1, Ordering::Release);
        self.tail += 1;
        self.mem.ctrl().tail.0.store(self.tail, Ordering::Release);
        notify(&self.mem.ctrl().data.0);
    }

    /// Messages pushed so far (the shared tail position).
    pub fn position(&self) -> u64 {
        self.tail
    }

    /// Pushes refused because the ring was full, over the ring's life.
    pub fn full_count(&self) -> u64 {
        self.mem.ctrl().full.0.load(Ordering::Relaxed)
    }

    /// Free slots as of now.
    pub fn free(&self) -> u64 {
        self.mem.capacity() - (self.tail - self.mem.ctrl().head.0.load(Ordering::Acquire))
    }
}

#[cfg(not(loom))]
impl<M: Message> Producer<M> {
    /// How [`Producer::send`] waits for room.
    pub fn set_wait_strategy(&mut self, wait: WaitStrategy) {
        self.wait = wait;
    }

    /// Pushes `msg`, waiting for room with the wait strategy; gives up (handing the message
    /// back) if the consumer's process dies. Not for the real-time side.
    pub fn send(&mut self, msg: M) -> Result<(), SendError<M>> {
        self.send_until(msg, None)
    }

    /// As [`Producer::send`], giving up after `timeout`.
    pub fn send_timeout(&mut self, msg: M, timeout: Duration) -> Result<(), SendError<M>> {
        self.send_until(msg, Some(Instant::now() + timeout))
    }

    fn send_until(&mut self, msg: M, deadline: Option<Instant>) -> Result<(), SendError<M>> {
        if !self.has_room() {
            let mem = &self.mem;
            let capacity = mem.capacity();
            let tail = self.tail;
            let mut cached_head = self.cached_head;
            let wanted = space_wanted(capacity);
            let waited = wait_for(
                &mem.ctrl().space.0,
                self.wait,
                deadline,
                self.peer.as_deref(),
                || {
                    cached_head = mem.ctrl().head.0.load(Ordering::Acquire);
                    (capacity - (tail - cached_head) >= wanted).then_some(())
                },
            );
            self.cached_head = cached_head;
            match waited {
                Ok(()) => {}
                Err(WaitEnd::Timeout) => return Err(SendError::Timeout(msg)),
                Err(WaitEnd::PeerGone) => return Err(SendError::PeerGone(msg)),
            }
        }
        self.write(&msg);
        Ok(())
    }
}

impl<M: Message> Consumer<M> {
    #[cfg(not(loom))]
    pub(crate) fn new(mem: RingMem, peer: PeerProbe) -> Self {
        assert!(M::WORDS <= MAX_WORDS);
        let head = mem.ctrl().head.0.load(Ordering::Relaxed);
        let cached_tail = head;
        Consumer {
            mem,
            head,
            cached_tail,
            wait: WaitStrategy::default(),
            peer,
            _msg: PhantomData,
        }
    }

    #[cfg(loom)]
    pub(crate) fn new(mem: RingMem) -> Self {
        let head = mem.ctrl().head.0.load(Ordering::Relaxed);
        Consumer {
            mem,
            head,
            cached_tail: head,
            _msg: PhantomData,
        }
    }

    /// Pops the oldest message if there is one. Never blocks, never allocates, no syscall
    /// unless the producer is parked waiting for room (then one `FUTEX_WAKE`).
    #[inline]
    pub fn try_recv(&mut self) -> Result<Option<M>, RecvError> {
        if !self.has_data()? {
            return Ok(None);
        }
        self.read().map(Some)
    }

    #[inline]
    fn has_data(&mut self) -> Result<bool, CorruptRing> {
        if self.head != self.cached_tail {
            return Ok(true);
        }
        self.cached_tail = self.mem.ctrl().tail.0.load(Ordering::Acquire);
        let (head, tail, capacity) = (self.head, self.cached_tail, self.mem.capacity());
        if tail < head || tail - head > capacity {
            return Err(CorruptRing::Indices {
                head,
                tail,
                capacity,
            });
        }
        Ok(head != tail)
    }

    #[inline]
    fn read(&mut self) -> Result<M, RecvError> {
        let slot = self.mem.slot(self.head);
        let found = slot[0].load(Ordering::Acquire);
        if found != self.head + 1 {
            return Err(CorruptRing::SlotSequence {
                position: self.head,
                expected: self.head + 1,
                found,
            }
            .into());
        }
        let mut words = [0u64; MAX_WORDS];
        for (word, cell) in words[..M::WORDS].iter_mut().zip(&slot[1..=M::WORDS]) {
            *word = cell.load(Ordering::Relaxed);
        }
        self.head += 1;
        self.mem.ctrl().head.0.store(self.head, Ordering::Release);
        // A producer parked on a full ring waits for a quarter of the ring to free up
        // (`space_wanted`), so it is not woken (one syscall each side) for every single slot.
        // `cached_tail` may be behind the real tail, which over-estimates the free space:
        // a spurious wake at worst, never a missed one.
        let free_at_least = self.mem.capacity() - (self.cached_tail - self.head);
        notify_if(
            &self.mem.ctrl().space.0,
            free_at_least >= space_wanted(self.mem.capacity()),
        );
        Ok(M::decode(&words[..M::WORDS])?)
    }

    /// Messages consumed so far (the shared head position).
    pub fn position(&self) -> u64 {
        self.head
    }

    /// Messages waiting as of now.
    pub fn pending(&self) -> u64 {
        self.mem.ctrl().tail.0.load(Ordering::Acquire) - self.head
    }

    /// Discards everything waiting; returns how many messages were skipped. Used by a server
    /// that re-attaches: requests queued while no server ran are stale (the loop long since
    /// rendered those steps with its fallback).
    pub fn skip_pending(&mut self) -> u64 {
        let tail = self.mem.ctrl().tail.0.load(Ordering::Acquire);
        let skipped = tail - self.head;
        self.head = tail;
        self.cached_tail = tail;
        self.mem.ctrl().head.0.store(tail, Ordering::Release);
        notify(&self.mem.ctrl().space.0);
        skipped
    }
}

#[cfg(not(loom))]
impl<M: Message> Consumer<M> {
    /// How [`Consumer::recv`] waits for data.
    pub fn set_wait_strategy(&mut self, wait: WaitStrategy) {
        self.wait = wait;
    }

    /// Waits for the next message; returns `PeerGone` if the producer's process dies while
    /// the ring is empty (messages it left are still delivered first).
    pub fn recv(&mut self) -> Result<M, RecvError> {
        self.recv_until(None)
    }

    /// As [`Consumer::recv`], giving up after `timeout`.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Result<M, RecvError> {
        self.recv_until(Some(Instant::now() + timeout))
    }

    /// As [`Consumer::recv`], giving up at `deadline`. The wait is bounded by the deadline
    /// whatever the strategy, which is how the loop waits for a force without ever blocking
    /// on the server.
    pub fn recv_deadline(&mut self, deadline: Instant) -> Result<M, RecvError> {
        self.recv_until(Some(deadline))
    }

    fn recv_until(&mut self, deadline: Option<Instant>) -> Result<M, RecvError> {
        if !self.has_data()? {
            let mem = &self.mem;
            let head = self.head;
            let mut tail = self.cached_tail;
            let waited = wait_for(
                &mem.ctrl().data.0,
                self.wait,
                deadline,
                self.peer.as_deref(),
                || {
                    tail = mem.ctrl().tail.0.load(Ordering::Acquire);
                    (tail != head).then_some(())
                },
            );
            self.cached_tail = tail;
            match waited {
                Ok(()) => {}
                Err(WaitEnd::Timeout) => return Err(RecvError::Timeout),
                Err(WaitEnd::PeerGone) => return Err(RecvError::PeerGone),
            }
            self.has_data()?;
        }
        self.read()
    }
}
