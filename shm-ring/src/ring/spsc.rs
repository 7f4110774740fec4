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
//!
//! Against a corrupt or hostile peer (another process can write any word of the segment):
//! every index read from shared memory is checked before it is used (`head <= tail <= head +
//! capacity`; a private copy is only ever replaced by a checked value), position arithmetic
//! never overflows or underflows (a wrapped position is just a wrong one, caught by the
//! checks), and a slot's index is `position & mask` with the private, validated mask. What
//! fails a check is counted ([`Consumer::corrupt`], [`Producer::corrupt`], and the segment's
//! process-private total that its owner watches) and reported as [`RecvError::Corrupt`]: a
//! slot with a wrong sequence word is skipped (the ring goes on with the next one), impossible
//! indices refuse until the segment's owner re-creates it. Never a panic, a hang or an access
//! outside the ring.

use std::fmt;
use std::marker::PhantomData;

use crate::ring::mem::{CorruptCount, RingMem};
use crate::ring::message::{DecodeError, Message, MAX_WORDS};
use crate::ring::sync::Ordering;
use crate::ring::wait::{notify, notify_if};

#[cfg(not(loom))]
use crate::ring::wait::{wait_for, WaitEnd, WaitStrategy};
#[cfg(not(loom))]
use std::time::{Duration, Instant};

/// A shared check "is the process on the other side still alive?" (None: in-process rings).
#[cfg(not(loom))]
pub(crate) type PeerProbe = Option<std::sync::Arc<dyn Fn() -> bool + Send + Sync>>;

/// The ring's memory does not hold what the protocol says it must: another writer, a
/// corrupted segment, or a bug. Nothing of it is returned as a message: a bad slot is
/// skipped, impossible indices are refused until the segment is re-created.
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
    /// Last checked value of the shared head: `tail - capacity <= cached_head <= tail`.
    cached_head: u64,
    corrupt: CorruptCount,
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
    /// Last checked value of the shared tail: `head <= cached_tail <= head + capacity`.
    cached_tail: u64,
    corrupt: CorruptCount,
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

/// A producer's starting `(tail, cached_head, corrupt)`, from the shared indices (a server's
/// producer resumes where the previous one stopped). Impossible indices are counted, and the
/// cached head starts a full ring behind, so nothing is written until a checked head says
/// there is room.
fn producer_start(mem: &RingMem) -> (u64, u64, CorruptCount) {
    let tail = mem.ctrl().tail.0.load(Ordering::Relaxed);
    let head = mem.ctrl().head.0.load(Ordering::Acquire);
    let mut corrupt = CorruptCount::default();
    if mem.plausible(head, tail) {
        (tail, head, corrupt)
    } else {
        corrupt.note(mem);
        (tail, tail.wrapping_sub(mem.capacity()), corrupt)
    }
}

impl<M: Message> Producer<M> {
    #[cfg(not(loom))]
    pub(crate) fn new(mem: RingMem, peer: PeerProbe) -> Self {
        assert!(M::WORDS <= MAX_WORDS);
        let (tail, cached_head, corrupt) = producer_start(&mem);
        Producer {
            mem,
            tail,
            cached_head,
            corrupt,
            wait: WaitStrategy::default(),
            peer,
            _msg: PhantomData,
        }
    }

    #[cfg(loom)]
    pub(crate) fn new(mem: RingMem) -> Self {
        let (tail, cached_head, corrupt) = producer_start(&mem);
        Producer {
            mem,
            tail,
            cached_head,
            corrupt,
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
        // `tail - cached_head` is in 0..=capacity (the cache only ever holds a checked head).
        if self.tail.wrapping_sub(self.cached_head) < capacity {
            return true;
        }
        let head = self.mem.ctrl().head.0.load(Ordering::Acquire);
        if !self.mem.plausible(head, self.tail) {
            // The consumer cannot have read past what we wrote, nor be more than a ring
            // behind: someone else wrote the head. Refuse (as full) and count it.
            self.corrupt.note(&self.mem);
            return false;
        }
        self.cached_head = head;
        self.tail - head < capacity
    }

    /// Impossible heads seen by this producer (another writer in the segment), over its life.
    pub fn corrupt(&self) -> u64 {
        self.corrupt.get()
    }

    #[inline]
    fn write(&mut self, msg: &M) {
        let mut words = [0u64; MAX_WORDS];
        msg.encode(&mut words[..M::WORDS]);
        let slot = self.mem.slot(self.tail);
        RingMem::store_payload(slot, &words[..M::WORDS]);
        // Wrapping: a position near 2^64 can only come from a corrupt segment, and a wrong
        // position is caught by the consumer's checks; it must not panic here.
        slot[0].store(self.tail.wrapping_add(1), Ordering::Release);
        self.tail = self.tail.wrapping_add(1);
        self.mem.publish_tail(self.tail);
    }

    /// Messages pushed so far (the shared tail position).
    pub fn position(&self) -> u64 {
        self.tail
    }

    /// Pushes refused because the ring was full, over the ring's life.
    pub fn full_count(&self) -> u64 {
        self.mem.ctrl().full.0.load(Ordering::Relaxed)
    }

    /// Free slots as of now (0 if the shared head is impossible).
    pub fn free(&self) -> u64 {
        let head = self.mem.ctrl().head.0.load(Ordering::Acquire);
        if self.mem.plausible(head, self.tail) {
            self.mem.capacity() - (self.tail - head)
        } else {
            0
        }
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
                    let head = mem.ctrl().head.0.load(Ordering::Acquire);
                    // An impossible head never counts as room: wait on (the deadline or the
                    // peer's death ends the wait; the owner re-creates a corrupt segment).
                    if !mem.plausible(head, tail) {
                        return None;
                    }
                    cached_head = head;
                    (capacity - (tail - head) >= wanted).then_some(())
                },
            );
            self.cached_head = cached_head;
            match waited {
                Ok(()) => {}
                Err(end) => {
                    if !self
                        .mem
                        .plausible(self.mem.ctrl().head.0.load(Ordering::Acquire), tail)
                    {
                        self.corrupt.note(&self.mem);
                    }
                    return Err(match end {
                        WaitEnd::Timeout => SendError::Timeout(msg),
                        WaitEnd::PeerGone => SendError::PeerGone(msg),
                    });
                }
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
            corrupt: CorruptCount::default(),
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
            corrupt: CorruptCount::default(),
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
        let tail = self.mem.ctrl().tail.0.load(Ordering::Acquire);
        let (head, capacity) = (self.head, self.mem.capacity());
        if !self.mem.plausible(head, tail) {
            // Refused until the segment is re-created (the private copy keeps its checked
            // value, so nothing downstream ever computes with the impossible one).
            self.corrupt.note(&self.mem);
            return Err(CorruptRing::Indices {
                head,
                tail,
                capacity,
            });
        }
        self.cached_tail = tail;
        Ok(head != tail)
    }

    /// Corrupt slots and impossible indices seen by this consumer, over its life.
    pub fn corrupt(&self) -> u64 {
        self.corrupt.get()
    }

    /// Reads the slot at `head` (the caller checked `head < cached_tail`).
    #[inline]
    fn read(&mut self) -> Result<M, RecvError> {
        let slot = self.mem.slot(self.head);
        let found = slot[0].load(Ordering::Acquire);
        let expected = self.head.wrapping_add(1);
        let mut words = [0u64; MAX_WORDS];
        for (word, cell) in words[..M::WORDS].iter_mut().zip(&slot[1..=M::WORDS]) {
            *word = cell.load(Ordering::Relaxed);
        }
        // Hand the slot back either way: a slot with a wrong sequence word is skipped, so one
        // corrupt slot costs one message, not the ring (it used to stall it for good).
        let position = self.head;
        self.head = expected;
        self.mem.ctrl().head.0.store(self.head, Ordering::Release);
        // A producer parked on a full ring waits for a quarter of the ring to free up
        // (`space_wanted`), so it is not woken (one syscall each side) for every single slot.
        // `cached_tail` may be behind the real tail, which over-estimates the free space:
        // a spurious wake at worst, never a missed one.
        // No underflow: head <= cached_tail <= head + capacity (both checked).
        let free_at_least = self.mem.capacity() - (self.cached_tail - self.head);
        notify_if(
            &self.mem.ctrl().space.0,
            free_at_least >= space_wanted(self.mem.capacity()),
        );
        if found != expected {
            self.corrupt.note(&self.mem);
            return Err(CorruptRing::SlotSequence {
                position,
                expected,
                found,
            }
            .into());
        }
        Ok(M::decode(&words[..M::WORDS])?)
    }

    /// Messages consumed so far (the shared head position).
    pub fn position(&self) -> u64 {
        self.head
    }

    /// Messages waiting as of now (0 if the shared tail is impossible).
    pub fn pending(&self) -> u64 {
        let tail = self.mem.ctrl().tail.0.load(Ordering::Acquire);
        if self.mem.plausible(self.head, tail) {
            tail - self.head
        } else {
            0
        }
    }

    /// Discards everything waiting; returns how many messages were skipped. Used by a server
    /// that re-attaches: requests queued while no server ran are stale (the loop long since
    /// rendered those steps with its fallback). An impossible tail is counted as corrupt and
    /// the consumer re-synchronises on it anyway (0 skipped): the producer's own checks then
    /// see whether the ring is whole again.
    pub fn skip_pending(&mut self) -> u64 {
        let tail = self.mem.ctrl().tail.0.load(Ordering::Acquire);
        let skipped = if self.mem.plausible(self.head, tail) {
            tail - self.head
        } else {
            self.corrupt.note(&self.mem);
            0
        };
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

    /// Impossible indices do not end the wait early: they are waited out like an empty ring
    /// (until they make sense again, the deadline, or the producer's death, which is how a
    /// server notices that the loop re-created a corrupt segment), so a caller that retries
    /// never spins hot on them; at the deadline they are reported as [`RecvError::Corrupt`].
    fn recv_until(&mut self, deadline: Option<Instant>) -> Result<M, RecvError> {
        // `Err` here = impossible indices (counted): wait them out as below.
        if self.has_data() == Ok(true) {
            return self.read();
        }
        let mem = &self.mem;
        let head = self.head;
        let waited = wait_for(
            &mem.ctrl().data.0,
            self.wait,
            deadline,
            self.peer.as_deref(),
            || {
                let tail = mem.ctrl().tail.0.load(Ordering::Acquire);
                (tail != head && mem.plausible(head, tail)).then_some(())
            },
        );
        if waited == Err(WaitEnd::PeerGone) {
            return Err(RecvError::PeerGone);
        }
        // The tail the wait saw is not trusted: `has_data` loads and checks it again
        // (`head == cached_tail` here, so it does), and only a checked value is cached.
        if self.has_data()? {
            self.read()
        } else {
            Err(RecvError::Timeout)
        }
    }
}
