//! Entry points for the `cargo fuzz` targets in `fuzz/` (hidden from the docs, not a stable
//! API). They drive shm-ring's real code with arbitrary bytes: the header validation an
//! attacher runs, the rings' index and slot handling with a hostile writer poking the shared
//! words between operations (`shm_ring::hostile`), and the haptics messages' decoders. Each
//! panics only on a broken invariant (that is what the fuzzer reports); bad input must come
//! back as an error.

use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::time::Instant;

use haptics_proto::features::{MAX_FEATURES, THESIS_FEATURES};
use haptics_proto::{Command, FeatureMsg, ForceMsg, Haptics, TelemetryRow};
use shm_ring::hostile::{HostileHeader, HostileRing, RING_CONTROL_ALIGN, RING_CONTROL_SIZE};
use shm_ring::{
    slot_words, FixedStr, Message, Protocol, RecvError, WaitStrategy, MAX_SCHEMA_NAMES, MAX_WORDS,
};

/// Reads the input as little-endian words (the last partial word zero-padded).
fn words_of(data: &[u8]) -> impl Iterator<Item = u64> + '_ {
    data.chunks(8).map(|c| {
        let mut b = [0u8; 8];
        b[..c.len()].copy_from_slice(c);
        u64::from_le_bytes(b)
    })
}

/// What an attacher does with a segment's header: the input's first word is the file size,
/// the rest the header's words (a valid header's words when the input asks, so the checks
/// past the magic are reached too). Whatever validation accepts must place every ring inside
/// the file: that is the property that keeps the rings' accesses inside the mapping.
pub fn header(data: &[u8]) {
    header_of::<Haptics>(data, &THESIS_FEATURES)
}

fn header_of<P: Protocol>(data: &[u8], schema: &[&str]) {
    let mut words = words_of(data);
    let file_size = words.next().unwrap_or(0);
    let start_valid = file_size & 1 == 1;
    let h = if start_valid {
        HostileHeader::valid(&P::CHANNELS, schema)
    } else {
        HostileHeader::zeroed()
    };
    // Overwrite words: (index, value) pairs when starting valid, else the words in order.
    let cells = h.words();
    if start_valid {
        while let (Some(i), Some(v)) = (words.next(), words.next()) {
            cells[(i % cells.len() as u64) as usize].store(v, Ordering::Relaxed);
        }
    } else {
        for (cell, w) in cells.iter().zip(words) {
            cell.store(w, Ordering::Relaxed);
        }
    }
    // Both outcomes are fine; an accepted layout must lie inside the file.
    if let Ok(placed) = h.validate(&P::CHANNELS, file_size) {
        assert!(placed.schema.len() <= MAX_SCHEMA_NAMES);
        assert!(placed.total as u64 <= file_size);
        for (i, spec) in P::CHANNELS.iter().enumerate() {
            let cap = placed.capacities[i];
            assert!(cap.is_power_of_two() && cap >= 2);
            assert!(placed.control_offsets[i] + RING_CONTROL_SIZE <= placed.total);
            assert_eq!(placed.control_offsets[i] % RING_CONTROL_ALIGN, 0);
            let slot_bytes = slot_words(spec.shape.words) * 8;
            assert!(placed.slots_offsets[i] + cap * slot_bytes <= placed.total);
        }
    }
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
    let ring = HostileRing::new(capacity, M::WORDS);
    let mut tx = ring.producer::<M>();
    let mut rx = ring.consumer::<M>();
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
                ring.poke(which, input.word());
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
                tx = ring.producer();
                if b & 0x80 != 0 {
                    rx = ring.consumer();
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
fn overwrite(input: &mut Input) {
    let capacity = 1usize << (input.byte().unwrap_or(0) % 5);
    let ring = HostileRing::new(capacity, TelemetryRow::WORDS);
    let mut tx = ring.overwrite_producer::<TelemetryRow>();
    let mut rx = ring.overwrite_consumer::<TelemetryRow>();
    let (mut sent, mut received, mut poked) = (0u64, 0u64, false);
    while let Some(b) = input.byte() {
        match b % 4 {
            0 | 1 => {
                tx.send(&TelemetryRow {
                    step: sent,
                    ..TelemetryRow::default()
                });
                sent += 1;
            }
            2 => match rx.try_recv() {
                Ok(Some(row)) => {
                    if !poked {
                        assert_eq!(row.step, received + rx.dropped(), "in order");
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
                ring.poke(which, input.word());
            }
        }
    }
    if !poked {
        assert!(received + rx.dropped() <= sent);
        assert_eq!(rx.corrupt(), 0);
    }
}

/// A feature message distinct per `n`.
fn features(n: u64) -> FeatureMsg {
    FeatureMsg {
        seq: n,
        len: (n % (MAX_FEATURES as u64 + 1)) as u8,
        values: [n as f64; MAX_FEATURES],
        ..FeatureMsg::default()
    }
}

fn forces(n: u64) -> ForceMsg {
    ForceMsg {
        seq: n,
        force: n as f64 * 0.5,
        ..ForceMsg::default()
    }
}

fn commands(n: u64) -> Command {
    Command::SetParameter {
        id: n,
        name: FixedStr::new("param").expect("valid"),
        value: n as f64,
    }
}

/// The four rings' protocols under arbitrary operation sequences and hostile pokes.
pub fn rings(data: &[u8]) {
    let mut input = Input(data);
    match input.byte().unwrap_or(0) % 4 {
        0 => lossless(&mut input, features),
        1 => lossless(&mut input, forces),
        2 => lossless(&mut input, commands),
        _ => overwrite(&mut input),
    }
}

/// Decodes arbitrary words as each of the haptics message types. Decoding either refuses or
/// gives a value that encodes to words that decode to the same value (compared as words, so
/// NaN payloads compare too).
pub fn messages(data: &[u8]) {
    let mut words: Vec<u64> = words_of(data).collect();
    words.resize(MAX_WORDS, 0);
    round_trip::<FeatureMsg>(&words);
    round_trip::<ForceMsg>(&words);
    round_trip::<TelemetryRow>(&words);
    round_trip::<Command>(&words);
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
