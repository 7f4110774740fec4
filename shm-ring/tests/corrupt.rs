//! A segment rewritten behind the endpoints' backs (issue 13 item 2): the header's capacities
//! and offsets rewritten after attach change nothing, a corrupt slot is skipped and counted,
//! impossible indices are refused and counted (never a panic, a hang or an access outside the
//! ring), `Link::audit` finds header and index damage, and `Link::recreate` gives a fresh
//! segment the server re-attaches to.
//!
//! Damage is done the way another process would: `pwrite` on `/dev/shm/<name>`.

use std::os::unix::fs::FileExt;
use std::time::{Duration, Instant};

use haptics_proto::{FeatureMsg, ForceMsg, Haptics, Segment, TelemetryRow};
use shm_ring::{CorruptRing, Corruption, RecvError, SegmentName, SendError};

fn unique(tag: &str) -> SegmentName {
    SegmentName::for_instance(&format!("t{}-corrupt-{tag}", std::process::id())).unwrap()
}

/// Writes `value` at `offset` of the segment file, as a foreign process would.
fn poke(name: &SegmentName, offset: u64, value: u64) {
    let file = std::fs::OpenOptions::new()
        .write(true)
        .open(format!("/dev/shm{}", name.as_str()))
        .unwrap();
    file.write_all_at(&value.to_le_bytes(), offset).unwrap();
}

/// Offsets in a ring's control block (`RingControl`: tail, head, each on its own 128 bytes).
const TAIL: u64 = 0;
const HEAD: u64 = 128;
/// Header offsets: channels[0] (features) starts at 608: capacity, payload_words, slot_bytes,
/// slot_align, layout_id, control_offset, slots_offset.
const FEATURES_CAPACITY: u64 = 608;
const FEATURES_SLOTS_OFFSET: u64 = 608 + 6 * 8;
/// Bytes per features slot (sequence word + 20 payload words, rounded up to 64-byte lines).
const FEATURES_SLOT: u64 = 192;

fn feature(seq: u64) -> FeatureMsg {
    FeatureMsg {
        seq,
        len: 9,
        ..FeatureMsg::default()
    }
}

#[test]
fn header_rewritten_after_attach_changes_nothing_and_the_audit_sees_it() {
    let name = unique("hdr");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    assert_eq!(lp.link.audit(), Ok(()));

    // Capacity 0 used to become the mask u64::MAX; a huge slots offset, far outside the map.
    poke(&name, FEATURES_CAPACITY, 0);
    poke(&name, FEATURES_SLOTS_OFFSET, 1 << 40);
    for seq in 1..=3000 {
        lp.features_tx.try_send(feature(seq)).unwrap();
        assert_eq!(sv.features_rx.try_recv().unwrap(), Some(feature(seq)));
        sv.forces_tx
            .try_send(ForceMsg {
                seq,
                ..ForceMsg::default()
            })
            .unwrap();
        assert_eq!(lp.forces_rx.try_recv().unwrap().unwrap().seq, seq);
    }
    assert_eq!(sv.link.info().capacities[0], 1024, "the private copy");
    assert_eq!(sv.link.feature_names().len(), 9);

    assert_eq!(lp.link.corrupt(), 0);
    let found = lp.link.audit();
    assert!(
        matches!(
            found,
            Err(Corruption::Header {
                field: "capacity",
                found: 0,
                expected: 1024
            })
        ),
        "{found:?}"
    );
    assert_eq!(lp.link.corrupt(), 1, "a failed audit is counted");
}

#[test]
fn a_corrupt_slot_is_skipped_and_counted_not_a_stall() {
    let name = unique("slot");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    let slots = sv.link.info().slots_offsets[0];
    for seq in 1..=3 {
        lp.features_tx.try_send(feature(seq)).unwrap();
    }
    // Position 1's sequence word (must be 2).
    poke(&name, slots + FEATURES_SLOT, 77);
    assert_eq!(sv.features_rx.try_recv().unwrap(), Some(feature(1)));
    assert_eq!(
        sv.features_rx.try_recv(),
        Err(RecvError::Corrupt(CorruptRing::SlotSequence {
            position: 1,
            expected: 2,
            found: 77
        }))
    );
    assert_eq!(
        sv.features_rx.try_recv().unwrap(),
        Some(feature(3)),
        "the ring goes on past the bad slot"
    );
    assert_eq!(sv.features_rx.corrupt(), 1);
    assert_eq!(sv.link.corrupt(), 1);
    // And keeps working.
    lp.features_tx.try_send(feature(4)).unwrap();
    assert_eq!(sv.features_rx.try_recv().unwrap(), Some(feature(4)));
    assert_eq!(sv.features_rx.corrupt(), 1);
}

#[test]
fn impossible_indices_are_refused_and_counted_without_panic_or_hang() {
    let name = unique("idx");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    let info = sv.link.info();
    let [features, forces, telemetry, _] = info.control_offsets;

    // A tail far ahead of the head: more than a ring of messages cannot be waiting.
    poke(&name, features + TAIL, u64::MAX);
    assert!(matches!(
        sv.features_rx.try_recv(),
        Err(RecvError::Corrupt(CorruptRing::Indices { head: 0, .. }))
    ));
    assert_eq!(sv.features_rx.pending(), 0);
    // A waiting receive waits the impossible indices out like an empty ring (no hot retry
    // loop in the caller) and reports them at its deadline.
    let t0 = Instant::now();
    assert!(matches!(
        sv.features_rx.recv_timeout(Duration::from_millis(100)),
        Err(RecvError::Corrupt(_))
    ));
    assert!(t0.elapsed() < Duration::from_secs(2), "no hang");
    let seen = sv.features_rx.corrupt();
    assert!(seen >= 2, "{seen}");
    assert_eq!(
        sv.features_rx.skip_pending(),
        0,
        "nothing counted as skipped"
    );
    assert_eq!(sv.features_rx.corrupt(), seen + 1);

    // A tail that becomes impossible while the consumer waits: the value the wait saw is not
    // trusted (it used to be cached and then subtracted from).
    std::thread::scope(|s| {
        let waiter = s.spawn(|| lp.forces_rx.recv_timeout(Duration::from_millis(300)));
        std::thread::sleep(Duration::from_millis(50));
        poke(&name, forces + TAIL, 1 << 62);
        let got = waiter.join().unwrap();
        assert!(matches!(got, Err(RecvError::Corrupt(_))), "{got:?}");
    });
    assert_eq!(lp.forces_rx.corrupt(), 1);

    // A head the producer never wrote up to: refused as full, counted, `free` is 0.
    poke(&name, features + HEAD, 5_000);
    for seq in 0..2000 {
        if let Err(e) = lp.features_tx.try_send(feature(seq)) {
            assert!(matches!(e, SendError::Full(_)));
            break;
        }
    }
    assert!(lp.features_tx.corrupt() >= 1);
    assert_eq!(lp.features_tx.free(), 0);

    // The overwrite ring: a tail behind the consumer is counted and followed.
    for step in 0..5 {
        lp.telemetry_tx.send(&TelemetryRow {
            step,
            ..TelemetryRow::default()
        });
    }
    for _ in 0..5 {
        assert!(sv.telemetry_rx.try_recv().unwrap().is_some());
    }
    poke(&name, telemetry + TAIL, 2);
    assert!(matches!(
        sv.telemetry_rx.try_recv(),
        Err(RecvError::Corrupt(CorruptRing::Indices {
            head: 5,
            tail: 2,
            ..
        }))
    ));
    assert_eq!(sv.telemetry_rx.corrupt(), 1);
    assert_eq!(sv.telemetry_rx.try_recv().unwrap(), None);

    assert!(lp.link.audit().is_err());
    assert_eq!(
        lp.link.corrupt(),
        lp.forces_rx.corrupt() + lp.features_tx.corrupt() + 1,
        "the loop's endpoints and its audit feed the segment's count"
    );
}

#[test]
fn a_server_attaching_to_impossible_indices_refuses_to_send() {
    let name = unique("attach");
    let _lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let forces = Segment::inspect(&name).unwrap().control_offsets[1];
    poke(&name, forces + TAIL, 5);
    poke(&name, forces + HEAD, 100);
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    assert_eq!(sv.forces_tx.corrupt(), 1);
    assert!(matches!(
        sv.forces_tx.try_send(ForceMsg::default()),
        Err(SendError::Full(_))
    ));
    assert!(matches!(
        sv.forces_tx
            .send_timeout(ForceMsg::default(), Duration::from_millis(30)),
        Err(SendError::Timeout(_))
    ));
    assert_eq!(sv.forces_tx.free(), 0);
}

#[test]
fn recreate_gives_a_fresh_segment_the_server_reattaches_to() {
    let name = unique("recreate");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    lp.features_tx.try_send(feature(1)).unwrap();
    assert_eq!(sv.features_rx.recv().unwrap(), feature(1));
    let features = sv.link.info().control_offsets[0];
    poke(&name, features + TAIL, u64::MAX);
    assert!(lp.link.audit().is_err());

    let mut fresh = lp.link.recreate::<Haptics>().unwrap().loop_side().unwrap();
    assert_eq!(fresh.link.audit(), Ok(()));
    assert_eq!(fresh.link.corrupt(), 0);
    // The server sees the old loop gone (its lock released), drains, and re-attaches.
    assert!(!sv.peer_alive());
    // The loop can still drop its old endpoints at any time: the name stays the new one's.
    drop(lp);
    let t0 = Instant::now();
    assert_eq!(
        sv.features_rx.recv_timeout(Duration::from_secs(5)),
        Err(RecvError::PeerGone),
        "a wait on the corrupt ring ends when the loop lets go of it"
    );
    assert!(t0.elapsed() < Duration::from_secs(1));
    drop(sv);
    let mut sv = Segment::attach_timeout(&name, Duration::from_secs(5))
        .unwrap()
        .server_side()
        .unwrap();
    assert_eq!(sv.link.info().server_attachments, 1, "a fresh header");
    fresh.features_tx.try_send(feature(7)).unwrap();
    assert_eq!(sv.features_rx.recv().unwrap(), feature(7));
    sv.forces_tx
        .send(ForceMsg {
            seq: 7,
            force: 1.5,
            ..ForceMsg::default()
        })
        .unwrap();
    assert_eq!(fresh.forces_rx.recv().unwrap().force, 1.5);

    // A second recreate works too; the last loop handle unlinks the name.
    let again: Segment = fresh.link.recreate().unwrap();
    drop(fresh);
    drop(sv);
    assert!(std::path::Path::new(&format!("/dev/shm{}", name.as_str())).exists());
    drop(again);
    assert!(!std::path::Path::new(&format!("/dev/shm{}", name.as_str())).exists());
    assert!(!name.lock_path().exists());
}

#[test]
fn random_writes_while_both_sides_run_never_panic() {
    let name = unique("random");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    let total = sv.link.info().total_size;
    let stop = std::sync::atomic::AtomicBool::new(false);
    let mut writes = 0u64;
    let answered = std::thread::scope(|s| {
        let server = s.spawn(|| {
            let mut answered = 0u64;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                match sv.features_rx.recv_timeout(Duration::from_millis(5)) {
                    Ok(f) => {
                        let _ = sv.forces_tx.try_send(ForceMsg {
                            seq: f.seq,
                            ..ForceMsg::default()
                        });
                        answered += 1;
                    }
                    Err(_) => {
                        let _ = sv.telemetry_rx.try_recv();
                    }
                }
            }
            answered
        });
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open(format!("/dev/shm{}", name.as_str()))
            .unwrap();
        // xorshift: reproducible, no dependency
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let end = Instant::now() + Duration::from_millis(700);
        let mut seq = 0;
        while Instant::now() < end {
            for _ in 0..50 {
                seq += 1;
                let _ = lp.features_tx.try_send(feature(seq));
                let _ = lp.forces_rx.try_recv();
                let _ = lp.commands_rx.try_recv();
                lp.telemetry_tx.send(&TelemetryRow::default());
            }
            // Header and control blocks (the first 4 KiB) as often as the slots.
            let span = if next() % 2 == 0 { 4096 } else { total };
            let offset = (next() % span) & !7;
            file.write_all_at(&next().to_le_bytes(), offset).unwrap();
            writes += 1;
            let _ = lp.link.audit();
        }
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        server.join().unwrap()
    });
    println!(
        "{writes} random writes; loop found {} corruptions, server {}; {answered} answered",
        lp.link.corrupt(),
        sv.link.corrupt()
    );
    assert!(writes > 100);
    assert!(lp.link.corrupt() > 0, "the audit saw the damage");
}
