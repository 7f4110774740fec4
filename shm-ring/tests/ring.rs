//! The ring protocol on heap memory: ordering, full/empty, wrap-around, overwrite accounting,
//! message encodings, and two threads racing with parking waits. Miri-ready (no shm, no
//! syscalls except futex in the threaded tests, which are skipped under Miri).

use std::time::Duration;

use haptics_proto::{Command, FeatureMsg, ForceMsg, TelemetryRow, MAX_FEATURES};
use shm_ring::{
    heap_channel, heap_overwrite_channel, DecodeError, FixedStr, Message, RecvError, SendError,
    WaitStrategy,
};
use shm_ring_testing::pattern;

fn roundtrip<M: Message + PartialEq + std::fmt::Debug>(msg: M) {
    let mut words = vec![0u64; M::WORDS];
    msg.encode(&mut words);
    assert_eq!(M::decode(&words).unwrap(), msg);
}

#[test]
fn every_message_type_survives_encoding() {
    roundtrip(pattern::feature(12345));
    roundtrip(pattern::force(777));
    roundtrip(TelemetryRow {
        run_id: 7,
        step: u64::MAX - 1,
        timestamp: u32::MAX,
        counts: -123_456,
        analog_out_motor: 65535,
        phase: 6,
        fallback: true,
        cycle_no: u32::MAX,
        time: 1.5,
        f_true: 2.0,
        area_fx: -0.25,
        ..Default::default()
    });
    roundtrip(Command::SetParameter {
        id: 9,
        name: FixedStr::new("f_max_newtons").unwrap(),
        value: f64::MAX,
    });
}

#[test]
fn nan_travels_bit_exact() {
    let row = TelemetryRow {
        f_true: f64::NAN,
        f_pred: f64::from_bits(0x7ff8_dead_beef_0001),
        ..Default::default()
    };
    let mut words = vec![0u64; TelemetryRow::WORDS];
    row.encode(&mut words);
    let back = TelemetryRow::decode(&words).unwrap();
    assert_eq!(back.f_true.to_bits(), f64::NAN.to_bits());
    assert_eq!(back.f_pred.to_bits(), 0x7ff8_dead_beef_0001);
}

#[test]
fn invalid_words_are_refused_not_misread() {
    let mut words = vec![0u64; Command::WORDS];
    Command::Stop { id: 1 }.encode(&mut words);
    words[1] = 99;
    assert_eq!(
        Command::decode(&words),
        Err(DecodeError::InvalidField {
            field: "Command.kind",
            value: 99
        })
    );
    let mut words = vec![0u64; FeatureMsg::WORDS];
    pattern::feature(1).encode(&mut words);
    words[3] = MAX_FEATURES as u64 + 1;
    assert!(FeatureMsg::decode(&words).is_err());
    let mut words = vec![0u64; Command::WORDS];
    Command::Start {
        id: 1,
        experiment: FixedStr::new("ab").unwrap(),
        args: Default::default(),
    }
    .encode(&mut words);
    words[2] |= 0xff << 56; // garbage after the NUL padding
    assert!(Command::decode(&words).is_err());
}

#[test]
fn fixed_str_limits() {
    assert_eq!(FixedStr::new("position_x").unwrap().as_str(), "position_x");
    assert!(FixedStr::new(&"x".repeat(33)).is_err());
    assert!(FixedStr::new("a\0b").is_err());
    assert_eq!(FixedStr::new(&"é".repeat(16)).unwrap().as_str().len(), 32);
}

#[test]
fn fifo_full_empty_and_wraparound() {
    let (mut tx, mut rx) = heap_channel::<ForceMsg>(4);
    assert_eq!(rx.try_recv().unwrap(), None, "new ring is empty");
    let mut next_out = 0u64;
    for lap in 0..50u64 {
        // Fill to the brim: exactly 4 fit, the 5th is handed back and counted.
        for i in 0..4 {
            tx.try_send(pattern::force(lap * 4 + i)).unwrap();
        }
        match tx.try_send(pattern::force(9999)) {
            Err(SendError::Full(m)) => {
                assert_eq!(m, pattern::force(9999), "refused message is handed back")
            }
            other => panic!("expected Full, got {other:?}"),
        }
        assert_eq!(tx.free(), 0);
        for _ in 0..4 {
            let m = rx.try_recv().unwrap().expect("message");
            pattern::check_force(&m, next_out).unwrap();
            next_out += 1;
        }
        assert_eq!(rx.try_recv().unwrap(), None);
    }
    assert_eq!(tx.full_count(), 50);
    assert_eq!(tx.position(), 200);
    assert_eq!(rx.position(), 200);
}

#[test]
fn interleaved_partial_fills() {
    let (mut tx, mut rx) = heap_channel::<FeatureMsg>(8);
    let (mut sent, mut got) = (0u64, 0u64);
    for round in 0..200u64 {
        for _ in 0..(round % 7 + 1) {
            if tx.try_send(pattern::feature(sent)).is_ok() {
                sent += 1;
            }
        }
        for _ in 0..(round % 5 + 1) {
            if let Some(m) = rx.try_recv().unwrap() {
                pattern::check_feature(&m, got).unwrap();
                got += 1;
            }
        }
        assert!(sent - got <= 8);
        assert_eq!(rx.pending(), sent - got);
    }
}

#[test]
fn skip_pending_discards_backlog() {
    let (mut tx, mut rx) = heap_channel::<ForceMsg>(8);
    for i in 0..5 {
        tx.try_send(pattern::force(i)).unwrap();
    }
    assert_eq!(rx.skip_pending(), 5);
    assert_eq!(tx.free(), 8);
    tx.try_send(pattern::force(5)).unwrap();
    pattern::check_force(&rx.try_recv().unwrap().unwrap(), 5).unwrap();
}

#[test]
fn overwrite_ring_keeps_newest_and_counts_drops() {
    let (mut tx, mut rx) = heap_overwrite_channel::<TelemetryRow>(8);
    for step in 0..100 {
        tx.send(&TelemetryRow {
            step,
            ..Default::default()
        });
    }
    let mut got = Vec::new();
    while let Some(row) = rx.try_recv().unwrap() {
        got.push(row.step);
    }
    assert_eq!(
        got,
        (92..100).collect::<Vec<_>>(),
        "the 8 newest survive, in order"
    );
    assert_eq!(rx.dropped(), 92);
    assert_eq!(
        tx.dropped(),
        92,
        "the producer can read the consumer's drop count"
    );
    // Keeping up loses nothing.
    for step in 100..110 {
        tx.send(&TelemetryRow {
            step,
            ..Default::default()
        });
        assert_eq!(rx.try_recv().unwrap().unwrap().step, step);
    }
    assert_eq!(rx.dropped(), 92);
}

#[cfg(not(miri))]
#[test]
fn two_threads_one_million_in_order_with_parking() {
    const N: u64 = 1_000_000;
    let (mut tx, mut rx) = heap_channel::<FeatureMsg>(256);
    tx.set_wait_strategy(WaitStrategy::Park);
    rx.set_wait_strategy(WaitStrategy::SpinThenPark { spins: 100 });
    let producer = std::thread::spawn(move || {
        for seq in 0..N {
            tx.send(pattern::feature(seq)).unwrap();
        }
    });
    for seq in 0..N {
        let m = rx.recv_timeout(Duration::from_secs(10)).unwrap();
        pattern::check_feature(&m, seq).unwrap();
    }
    producer.join().unwrap();
    assert_eq!(rx.try_recv().unwrap(), None);
}

#[cfg(not(miri))]
#[test]
fn recv_times_out_on_an_empty_ring() {
    let (_tx, mut rx) = heap_channel::<ForceMsg>(4);
    for wait in [
        WaitStrategy::Spin,
        WaitStrategy::Park,
        WaitStrategy::DEFAULT_SPIN_THEN_PARK,
    ] {
        rx.set_wait_strategy(wait);
        let t0 = std::time::Instant::now();
        assert_eq!(
            rx.recv_timeout(Duration::from_millis(30)),
            Err(RecvError::Timeout)
        );
        let waited = t0.elapsed();
        assert!(
            waited >= Duration::from_millis(30) && waited < Duration::from_secs(2),
            "{wait:?}: {waited:?}"
        );
    }
}

#[cfg(not(miri))]
#[test]
fn parked_consumer_is_woken_promptly() {
    let (mut tx, mut rx) = heap_channel::<ForceMsg>(4);
    rx.set_wait_strategy(WaitStrategy::Park);
    let waiter = std::thread::spawn(move || {
        let t0 = std::time::Instant::now();
        let m = rx.recv_timeout(Duration::from_secs(5)).unwrap();
        (m, t0.elapsed())
    });
    std::thread::sleep(Duration::from_millis(50));
    tx.try_send(pattern::force(1)).unwrap();
    let (m, waited) = waiter.join().unwrap();
    pattern::check_force(&m, 1).unwrap();
    assert!(waited < Duration::from_secs(1), "wake-up took {waited:?}");
}

/// The seqlock under a real race: a producer overwriting as fast as it can, a consumer
/// reading. Every row received must be intact (its fields agree with its step) and in
/// increasing order, and received + dropped must account for every row.
#[cfg(not(miri))]
#[test]
fn overwrite_ring_never_returns_a_torn_row() {
    const N: u64 = 2_000_000;
    let (mut tx, mut rx) = heap_overwrite_channel::<TelemetryRow>(16);
    let row = |step: u64| {
        let h = pattern::mix(step);
        TelemetryRow {
            step,
            time: f64::from_bits(h >> 12 | 0x3ff0_0000_0000_0000),
            dt: f64::from_bits(pattern::mix(h) >> 12 | 0x3ff0_0000_0000_0000),
            area_fx: step as f64,
            counts: h as i32,
            ..Default::default()
        }
    };
    let producer = std::thread::spawn(move || {
        for step in 0..N {
            tx.send(&row(step));
        }
        tx
    });
    let (mut received, mut last) = (0u64, None::<u64>);
    loop {
        match rx.try_recv().unwrap() {
            Some(r) => {
                assert_eq!(r, row(r.step), "torn row");
                assert!(last.is_none_or(|l| r.step > l), "out of order");
                last = Some(r.step);
                received += 1;
                if r.step == N - 1 {
                    break;
                }
            }
            None => std::hint::spin_loop(),
        }
    }
    producer.join().unwrap();
    assert_eq!(
        received + rx.dropped(),
        N,
        "every row is either received or counted as dropped"
    );
}
