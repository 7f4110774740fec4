//! Loom models of the ring protocol: every interleaving (and every weak-memory outcome loom
//! can produce) of a producer and a consumer on tiny rings, so wrap-around, full and empty are
//! all hit within a few messages.
//!
//! Run: `RUSTFLAGS="--cfg loom" cargo test -p shm-ring --release --test loom`
#![cfg(loom)]

use loom::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use loom::sync::Arc;
use loom::thread;

use shm_ring::{heap_channel, heap_overwrite_channel, DecodeError, Message, SendError};

/// A two-word message whose words must agree: a torn read shows up as a mismatch.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pair(u64);

impl Message for Pair {
    const WORDS: usize = 2;
    const LAYOUT_ID: u64 = 1;
    fn encode(&self, out: &mut [u64]) {
        out[0] = self.0;
        out[1] = !self.0;
    }
    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        if w[1] != !w[0] {
            return Err(DecodeError::InvalidField {
                field: "torn",
                value: w[0],
            });
        }
        Ok(Pair(w[0]))
    }
}

fn model(f: impl Fn() + Sync + Send + 'static) {
    let mut b = loom::model::Builder::new();
    b.preemption_bound = Some(3);
    b.check(f);
}

/// Capacity 2, three messages: the producer must see "full" and wrap around; the consumer
/// must see "empty" and receive all three in order, each intact.
#[test]
fn lossless_ring_wraps_in_order_through_full_and_empty() {
    model(|| {
        let (mut tx, mut rx) = heap_channel::<Pair>(2);
        let producer = thread::spawn(move || {
            for i in 1..=3u64 {
                let mut msg = Pair(i);
                loop {
                    match tx.try_send(msg) {
                        Ok(()) => break,
                        Err(SendError::Full(m)) => {
                            msg = m;
                            thread::yield_now();
                        }
                        Err(e) => panic!("{e}"),
                    }
                }
            }
        });
        let mut expected = 1u64;
        while expected <= 3 {
            match rx.try_recv().expect("intact slot") {
                Some(Pair(v)) => {
                    assert_eq!(v, expected, "in order, no loss, no duplicate");
                    expected += 1;
                }
                None => thread::yield_now(),
            }
        }
        producer.join().unwrap();
        assert_eq!(rx.try_recv().unwrap(), None, "nothing beyond what was sent");
    });
}

/// A full ring refuses (and hands back) the message; one pop makes room for exactly one.
#[test]
fn full_ring_refuses_until_a_pop_frees_a_slot() {
    model(|| {
        let (mut tx, mut rx) = heap_channel::<Pair>(2);
        tx.try_send(Pair(1)).unwrap();
        tx.try_send(Pair(2)).unwrap();
        let popped = Arc::new(AtomicBool::new(false));
        let popped2 = popped.clone();
        let consumer = thread::spawn(move || {
            assert_eq!(rx.try_recv().unwrap(), Some(Pair(1)));
            popped2.store(true, Ordering::Release);
            rx
        });
        let was_popped = popped.load(Ordering::Acquire);
        let result = tx.try_send(Pair(3));
        if !was_popped {
            // Either still full, or the pop landed in between: both are legal...
            assert!(matches!(result, Ok(()) | Err(SendError::Full(Pair(3)))));
        } else {
            // ...but once the pop is visible, there must be room.
            assert!(result.is_ok());
        }
        let mut rx = consumer.join().unwrap();
        assert_eq!(rx.try_recv().unwrap(), Some(Pair(2)));
        if result.is_ok() {
            assert_eq!(rx.try_recv().unwrap(), Some(Pair(3)));
        }
        assert_eq!(rx.try_recv().unwrap(), None);
    });
}

/// Empty: a consumer polling while one message is published sees either nothing or the whole
/// message, never a partial one.
#[test]
fn empty_ring_poll_sees_nothing_or_a_whole_message() {
    model(|| {
        let (mut tx, mut rx) = heap_channel::<Pair>(2);
        let producer = thread::spawn(move || tx.try_send(Pair(42)).unwrap());
        let first = rx.try_recv().expect("intact");
        producer.join().unwrap();
        match first {
            Some(p) => assert_eq!(p, Pair(42)),
            None => assert_eq!(rx.try_recv().unwrap(), Some(Pair(42))),
        }
    });
}

/// The overwrite (seqlock) ring: the producer laps a consumer that reads concurrently.
/// Whatever the consumer gets is intact and increasing, and received + dropped + still
/// readable accounts for every message.
#[test]
fn overwrite_ring_never_returns_torn_or_reordered_messages() {
    model(|| {
        let (mut tx, mut rx) = heap_overwrite_channel::<Pair>(2);
        let producer = thread::spawn(move || {
            for i in 1..=3u64 {
                tx.send(&Pair(i));
            }
        });
        let mut got = Vec::new();
        for _ in 0..2 {
            if let Some(Pair(v)) = rx.try_recv().expect("never torn") {
                got.push(v);
            }
        }
        producer.join().unwrap();
        while let Some(Pair(v)) = rx.try_recv().expect("never torn") {
            got.push(v);
        }
        assert!(got.windows(2).all(|w| w[0] < w[1]), "increasing: {got:?}");
        assert_eq!(got.last(), Some(&3), "the newest always survives");
        assert_eq!(
            got.len() as u64 + rx.dropped(),
            3,
            "every message received or counted: {got:?}"
        );
    });
}

/// The park/wake handshake: a waiter that re-checks after registering and finds nothing must
/// find the epoch moved by the time the notifier is done (so its futex wait returns at once):
/// no lost wake-up.
#[test]
fn park_handshake_never_loses_a_wakeup() {
    use shm_ring::loom_hooks::Handshake;
    model(|| {
        let signal = Arc::new(Handshake::default());
        let data = Arc::new(AtomicU64::new(0));
        let (s2, d2) = (signal.clone(), data.clone());
        let notifier = thread::spawn(move || {
            d2.store(1, Ordering::Release); // publish
            s2.notify();
        });
        let epoch = signal.register_waiter();
        let saw_data = data.load(Ordering::Acquire) == 1;
        notifier.join().unwrap();
        if !saw_data {
            assert!(
                signal.epoch_moved(epoch),
                "waiter would sleep with nobody to wake it"
            );
        }
    });
}
