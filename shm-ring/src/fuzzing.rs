//! Entry points for the `cargo fuzz` targets in `fuzz/` (hidden from the docs, not a stable
//! API). They drive the crate's real code with arbitrary bytes: the header validation an
//! attacher runs, the rings' index and slot handling with a hostile writer poking the shared
//! words between operations, and the message decoders. Each panics only on a broken
//! invariant (that is what the fuzzer reports); bad input must come back as an error.
//! Generic over the protocol: haptics-proto's `fuzzing` module runs them with its messages.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use crate::header::{Header, MAGIC, MAX_SCHEMA_NAMES};
use crate::message::Message;
use crate::overwrite::{OverwriteConsumer, OverwriteProducer};
use crate::protocol::{shapes, Protocol};
use crate::ring_mem::{slot_words, RingControl, RingMem};
use crate::segment::{validate, SegmentName};
use crate::spsc::{Consumer, Producer, RecvError};
use crate::wait::WaitStrategy;

/// Reads the input as little-endian words (the last partial word zero-padded).
fn words_of(data: &[u8]) -> impl Iterator<Item = u64> + '_ {
    data.chunks(8).map(|c| {
        let mut b = [0u8; 8];
        b[..c.len()].copy_from_slice(c);
        u64::from_le_bytes(b)
    })
}

/// A header-sized, header-aligned block of zeroed atomics (what a fresh mapping holds).
struct HeaderBuf(Box<HeaderWords>);

#[repr(C, align(128))]
struct HeaderWords([AtomicU64; std::mem::size_of::<Header>() / 8]);

impl HeaderBuf {
    fn new() -> Self {
        HeaderBuf(Box::new(HeaderWords(std::array::from_fn(|_| {
            AtomicU64::new(0)
        }))))
    }
    fn header(&self) -> &Header {
        const { assert!(std::mem::size_of::<HeaderWords>() == std::mem::size_of::<Header>()) };
        const { assert!(std::mem::align_of::<HeaderWords>() >= std::mem::align_of::<Header>()) };
        // SAFETY: same size, sufficient alignment, and `Header` is `repr(C)` made only of
        // atomics (any bit pattern is valid, all access is atomic).
        unsafe { &*(self.0.as_ref() as *const HeaderWords).cast::<Header>() }
    }
}

/// What an attacher does with a segment's header: the input's first word is the file size,
/// the rest the header's words (a valid header's words when the input asks, so the checks
/// past the magic are reached too). Whatever validation accepts must place every ring inside
/// the file: that is the property that keeps the rings' accesses inside the mapping.
pub fn header<P: Protocol>(data: &[u8], schema: &[&str]) {
    let shapes = shapes::<P>();
    let mut words = words_of(data);
    let file_size = words.next().unwrap_or(0);
    let buf = HeaderBuf::new();
    let h = buf.header();
    let start_valid = file_size & 1 == 1;
    if start_valid {
        let layout = crate::header::Layout::compute([1024, 1024, 8192, 64], &shapes);
        let names: Vec<_> = schema
            .iter()
            .map(|n| crate::fixed_str::FixedStr::new(n).expect("valid name"))
            .collect();
        h.init([1024, 1024, 8192, 64], &names, &layout, &shapes, 0);
        h.magic.store(MAGIC, Ordering::Relaxed);
    }
    // Overwrite words: (index, value) pairs when starting valid, else the words in order.
    let cells = &buf.0 .0;
    if start_valid {
        while let (Some(i), Some(v)) = (words.next(), words.next()) {
            cells[(i % cells.len() as u64) as usize].store(v, Ordering::Relaxed);
        }
    } else {
        for (cell, w) in cells.iter().zip(words) {
            cell.store(w, Ordering::Relaxed);
        }
    }
    let name = SegmentName::new("/fuzz").expect("valid name");
    // Both outcomes are fine; an accepted layout must lie inside the file.
    if let Ok((layout, schema)) = validate(h, &name, file_size, &shapes) {
        assert!(schema.len() <= MAX_SCHEMA_NAMES);
        assert!(layout.total as u64 <= file_size);
        for (i, shape) in shapes.iter().enumerate() {
            let cap = layout.capacities[i];
            assert!(cap.is_power_of_two() && cap >= 2);
            assert!(layout.control_offsets[i] + RingControl::SIZE <= layout.total);
            assert_eq!(layout.control_offsets[i] % RingControl::ALIGN, 0);
            let slot_bytes = slot_words(shape.words) * 8;
            assert!(layout.slots_offsets[i] + cap * slot_bytes <= layout.total);
        }
    }
    let _ = h.schema();
    let _ = h.capacities();
}

/// Which operation the next input byte asks for.
#[derive(Clone, Copy)]
enum Op {
    Send,
    Recv,
    RecvDeadline,
    Poke,
    SkipPending,
    Counts,
    Reattach,
}

impl Op {
    fn of(b: u8) -> Op {
        match b % 8 {
            0 | 7 => Op::Send,
            1 => Op::Recv,
            2 => Op::RecvDeadline,
            3 => Op::Poke,
            4 => Op::SkipPending,
            5 => Op::Counts,
            _ => Op::Reattach,
        }
    }
}

/// Sets one shared word of the ring (tail, head, a signal, a counter, or any slot word) the
/// way a foreign process would.
fn poke(mem: &RingMem, which: u64, value: u64) {
    let c = mem.ctrl();
    let stride = mem.slot(0).len() as u64;
    match which % 8 {
        0 => c.tail.0.store(value, Ordering::Release),
        1 => c.head.0.store(value, Ordering::Release),
        2 => c.data.0.parked.store(value as u32, Ordering::Relaxed),
        3 => c.space.0.epoch.store(value as u32, Ordering::Relaxed),
        _ => {
            let word = which / 8 % (mem.capacity() * stride);
            mem.slot(word / stride)[(word % stride) as usize].store(value, Ordering::Release);
        }
    }
}

/// A byte cursor over the input.
struct Input<'a>(&'a [u8]);

impl Input<'_> {
    fn byte(&mut self) -> Option<u8> {
        let (&b, rest) = self.0.split_first()?;
        self.0 = rest;
        Some(b)
    }
    fn word(&mut self) -> u64 {
        let n = self.0.len().min(8);
        let mut b = [0u8; 8];
        b[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        u64::from_le_bytes(b)
    }
}

/// A lossless ring with one producer and one consumer driven by the input, with pokes of the
/// shared words between operations. Without a poke, what comes out must be exactly what went
/// in, in order (checked against a queue); with pokes, anything may come out or be refused,
/// but nothing may panic, hang or touch memory outside the ring.
fn lossless<M: Message + Copy + PartialEq + std::fmt::Debug>(
    input: &mut Input,
    make: impl Fn(u64) -> M,
) {
    let capacity = 1usize << (input.byte().unwrap_or(0) % 5);
    let mem = RingMem::heap(capacity, M::WORDS);
    let mut tx = Producer::<M>::new(mem.twin(), None);
    let mut rx = Consumer::<M>::new(mem.twin(), None);
    rx.set_wait_strategy(WaitStrategy::Spin);
    let mut model = VecDeque::new();
    let mut poked = false;
    let mut n = 0;
    while let Some(b) = input.byte() {
        let got = match Op::of(b) {
            Op::Send => {
                n += 1;
                let msg = make(n);
                let sent = tx.try_send(msg).is_ok();
                if sent {
                    model.push_back(msg);
                }
                assert!(
                    sent || poked || model.len() == capacity,
                    "refused with room"
                );
                None
            }
            Op::Recv => Some(rx.try_recv()),
            Op::RecvDeadline => Some(rx.recv_deadline(Instant::now()).map(Some).or_else(|e| {
                if e == RecvError::Timeout {
                    Ok(None)
                } else {
                    Err(e)
                }
            })),
            Op::Poke => {
                poked = true;
                let which = input.word();
                poke(&mem, which, input.word());
                None
            }
            Op::SkipPending => {
                let skipped = rx.skip_pending();
                if !poked {
                    assert_eq!(skipped, model.len() as u64);
                }
                model.clear();
                None
            }
            Op::Counts => {
                assert!(tx.free() <= capacity as u64);
                assert!(rx.pending() <= capacity as u64);
                if !poked {
                    assert_eq!(rx.pending(), model.len() as u64);
                    assert_eq!(tx.free(), (capacity - model.len()) as u64);
                }
                None
            }
            Op::Reattach => {
                // A new process's endpoints on the same memory (a server re-attaching).
                tx = Producer::new(mem.twin(), None);
                if b & 0x80 != 0 {
                    rx = Consumer::new(mem.twin(), None);
                    rx.set_wait_strategy(WaitStrategy::Spin);
                }
                None
            }
        };
        if let Some(got) = got {
            if !poked {
                assert_eq!(got, Ok(model.pop_front()), "FIFO without interference");
            } else if let Ok(Some(_)) = got {
                model.pop_front();
            }
        }
    }
    if !poked {
        assert_eq!(
            tx.corrupt() + rx.corrupt(),
            0,
            "no corruption without a poke"
        );
    }
}

/// The overwrite ring (telemetry): never blocks, counts what it loses, survives pokes.
fn overwrite<P: FuzzProtocol>(input: &mut Input) {
    let capacity = 1usize << (input.byte().unwrap_or(0) % 5);
    let mem = RingMem::heap(capacity, P::Telemetry::WORDS);
    let mut tx = OverwriteProducer::<P::Telemetry>::new(mem.twin());
    let mut rx = OverwriteConsumer::<P::Telemetry>::new(mem.twin(), None);
    let (mut sent, mut received, mut poked) = (0u64, 0u64, false);
    while let Some(b) = input.byte() {
        match b % 4 {
            0 | 1 => {
                tx.send(&P::telemetry(sent));
                sent += 1;
            }
            2 => match rx.try_recv() {
                Ok(Some(row)) => {
                    if !poked {
                        assert_eq!(P::telemetry_step(&row), received + rx.dropped(), "in order");
                    }
                    received += 1;
                }
                Ok(None) => {
                    if !poked {
                        assert_eq!(received + rx.dropped(), sent, "nothing left unread");
                    }
                }
                Err(_) => assert!(poked, "an error without interference"),
            },
            _ => {
                poked = true;
                let which = input.word();
                poke(&mem, which, input.word());
            }
        }
    }
    if !poked {
        assert!(received + rx.dropped() <= sent);
        assert_eq!(rx.corrupt(), 0);
    }
}

/// How a protocol's messages are made from a counter for [`rings`] (each distinct per `n`).
pub trait FuzzProtocol: Protocol {
    fn features(n: u64) -> Self::Features;
    fn forces(n: u64) -> Self::Forces;
    fn commands(n: u64) -> Self::Commands;
    /// A telemetry message carrying step `step`, and the step back out of one.
    fn telemetry(step: u64) -> Self::Telemetry;
    fn telemetry_step(row: &Self::Telemetry) -> u64;
}

/// The four rings' protocols under arbitrary operation sequences and hostile pokes.
pub fn rings<P: FuzzProtocol>(data: &[u8])
where
    P::Features: Copy + PartialEq + std::fmt::Debug,
    P::Forces: Copy + PartialEq + std::fmt::Debug,
    P::Commands: Copy + PartialEq + std::fmt::Debug,
{
    let mut input = Input(data);
    match input.byte().unwrap_or(0) % 4 {
        0 => lossless(&mut input, P::features),
        1 => lossless(&mut input, P::forces),
        2 => lossless(&mut input, P::commands),
        _ => overwrite::<P>(&mut input),
    }
}

/// Decodes arbitrary words as each of the protocol's message types. Decoding either refuses
/// or gives a value that encodes to words that decode to the same value (compared as words,
/// so NaN payloads compare too).
pub fn messages<P: Protocol>(data: &[u8]) {
    let mut words: Vec<u64> = words_of(data).collect();
    words.resize(crate::message::MAX_WORDS, 0);
    round_trip::<P::Features>(&words);
    round_trip::<P::Forces>(&words);
    round_trip::<P::Telemetry>(&words);
    round_trip::<P::Commands>(&words);
}

fn round_trip<M: Message>(words: &[u64]) {
    let Ok(first) = M::decode(&words[..M::WORDS]) else {
        return;
    };
    let mut once = vec![0u64; M::WORDS];
    first.encode(&mut once);
    let second = M::decode(&once).expect("an encoded message decodes");
    let mut twice = vec![0u64; M::WORDS];
    second.encode(&mut twice);
    assert_eq!(once, twice, "decode(encode(m)) == m");
}
