//! The segment in one process: create/attach, header validation, stale replacement, refusal
//! to steal a live segment, liveness, and every channel end to end through real shm.

use std::os::unix::fs::{FileExt, PermissionsExt};
use std::time::Duration;

use haptics_proto::experiment_args::ExperimentArgs;
use haptics_proto::{Command, LoopStatusLink, Segment, TelemetryRow, THESIS_FEATURES};
use shm_ring::{Config, Error, FixedStr, Message, RecvError, Role, SegmentName};
use shm_ring_testing::pattern;

/// A name no other test (or test run) uses.
fn unique(tag: &str) -> SegmentName {
    SegmentName::for_instance(&format!("t{}-{tag}", std::process::id())).unwrap()
}

fn shm_path(name: &SegmentName) -> String {
    format!("/dev/shm{}", name.as_str())
}

#[test]
fn names_are_validated() {
    assert_eq!(
        SegmentName::for_instance("bench-1").unwrap().as_str(),
        "/haptics-bench-1"
    );
    for bad in [
        "noslash",
        "/",
        "/a/b",
        "/sp ace",
        "/.hidden",
        &format!("/{}", "x".repeat(201)),
    ] {
        assert!(
            matches!(SegmentName::new(bad), Err(Error::InvalidName { .. })),
            "{bad}"
        );
    }
}

#[test]
fn config_is_validated() {
    let name = unique("cfg");
    let bad = |c: Config| matches!(Segment::create(&name, &c), Err(Error::InvalidConfig(_)));
    assert!(bad(Config {
        capacities: [1000, 0, 0, 0],
        ..haptics_proto::layout::config()
    }));
    assert!(bad(Config {
        capacities: [0, 0, 1 << 21, 0],
        ..haptics_proto::layout::config()
    }));
    assert!(bad(Config {
        feature_names: (0..17).map(|i| format!("f{i}")).collect(),
        ..haptics_proto::layout::config()
    }));
    assert!(bad(Config {
        feature_names: vec!["a".into(), "a".into()],
        ..haptics_proto::layout::config()
    }));
    assert!(bad(Config {
        feature_names: vec!["x".repeat(33)],
        ..haptics_proto::layout::config()
    }));
    assert!(
        !std::path::Path::new(&shm_path(&name)).exists(),
        "a refused config creates nothing"
    );
}

/// The segment hands out each channel's ends only as the protocol describes them: the right
/// kind and message type, on the writer's or the reader's side, once.
#[test]
fn channel_ends_follow_the_protocol() {
    use haptics_proto::layout::{COMMANDS, FEATURES, FORCES, TELEMETRY};
    use haptics_proto::{FeatureMsg, ForceMsg};
    use shm_ring::{Lossless, Overwrite};
    let name = unique("ends");
    let refused = |r: Result<(), Error>, why: &str| match r {
        Err(Error::Channel { reason, .. }) => assert!(reason.contains(why), "{reason}"),
        other => panic!("expected a refusal ({why}), got {other:?}"),
    };
    let lp = Segment::create(&name, &haptics_proto::layout::config()).unwrap();
    refused(
        lp.consumer(FEATURES).map(drop),
        "read by the server side only",
    );
    refused(
        lp.producer(FORCES).map(drop),
        "written by the server side only",
    );
    refused(
        lp.producer(Lossless::<ForceMsg>::at(0)).map(drop),
        "message type",
    );
    refused(
        lp.producer(Lossless::<TelemetryRow>::at(2)).map(drop),
        "Overwrite",
    );
    refused(
        lp.overwrite_producer(Overwrite::<FeatureMsg>::at(0))
            .map(drop),
        "Lossless",
    );
    let features_tx = lp.producer(FEATURES).unwrap();
    refused(lp.producer(FEATURES).map(drop), "given out already");
    lp.overwrite_producer(TELEMETRY).unwrap();
    lp.consumer(COMMANDS).unwrap();
    // The bundle needs every end: a handle that gave one out cannot build it again.
    assert!(matches!(lp.loop_side(), Err(Error::Channel { .. })));
    drop(features_tx);

    let lp = Segment::create(&unique("ends2"), &haptics_proto::layout::config()).unwrap();
    let _lp = lp.loop_side().unwrap();
    let sv = Segment::attach(&unique("ends2")).unwrap();
    refused(
        sv.producer(FEATURES).map(drop),
        "written by the loop side only",
    );
    let mut forces_tx = sv.producer(FORCES).unwrap();
    forces_tx.try_send(ForceMsg::default()).unwrap();
}

#[test]
fn create_attach_and_header_contents() {
    let name = unique("info");
    let config = Config {
        capacities: [64, 32, 128, 8],
        ..haptics_proto::layout::config()
    };
    let lp = Segment::create(&name, &config).unwrap();
    assert_eq!(lp.role(), Role::Loop);
    let meta = std::fs::metadata(shm_path(&name)).unwrap();
    assert_eq!(
        meta.permissions().mode() & 0o777,
        0o600,
        "segment is private to its user"
    );
    assert!(!lp.peer_alive(), "no server yet");

    let sv = Segment::attach(&name).unwrap();
    assert_eq!(sv.role(), Role::Server);
    assert!(lp.peer_alive() && sv.peer_alive());
    let info = sv.info();
    assert_eq!(info.feature_names, THESIS_FEATURES);
    assert_eq!(info.capacities, [64, 32, 128, 8]);
    assert_eq!(info.creator_pid, std::process::id());
    assert_eq!(info.server_pid, std::process::id());
    assert_eq!(info.server_attachments, 1);
    assert!(info.creator_process_alive());
    assert_eq!(info.total_size, meta.len());

    assert!(
        matches!(
            Segment::attach(&name),
            Err(Error::ServerAlreadyAttached { .. })
        ),
        "one server at a time"
    );
    assert!(
        matches!(
            Segment::create(&name, &config),
            Err(Error::InstanceInUse { .. })
        ),
        "a live segment is never stolen"
    );
    let seen = Segment::inspect(&name).unwrap();
    assert!(seen.loop_alive && seen.server_alive);
    assert_eq!(seen.server_attachments, 1, "inspecting is not attaching");
    assert_eq!(seen.feature_names, THESIS_FEATURES);
    drop(sv);
    assert!(!Segment::inspect(&name).unwrap().server_alive);
    assert!(!lp.info().server_alive && lp.info().loop_alive);
    // The server's lock went with it; a new server may attach.
    let sv2 = Segment::attach(&name).unwrap();
    assert_eq!(sv2.info().server_attachments, 2);
    assert!(matches!(sv2.loop_side(), Err(Error::WrongRole { .. })));
    assert!(matches!(lp.server_side(), Err(Error::WrongRole { .. })));
}

#[test]
fn all_four_channels_end_to_end() {
    let name = unique("chan");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    assert_eq!(sv.skipped_on_attach, 0);
    assert_eq!(sv.link.feature_names(), THESIS_FEATURES);

    for seq in 0..5000u64 {
        lp.features_tx.try_send(pattern::feature(seq)).unwrap();
        lp.telemetry_tx.send(&TelemetryRow {
            step: seq,
            f_pred: seq as f64,
            ..Default::default()
        });
        let f = sv.features_rx.try_recv().unwrap().unwrap();
        pattern::check_feature(&f, seq).unwrap();
        sv.forces_tx.try_send(pattern::force(f.seq)).unwrap();
        pattern::check_force(&lp.forces_rx.try_recv().unwrap().unwrap(), seq).unwrap();
    }
    let mut rows = 0;
    while let Some(row) = sv.telemetry_rx.try_recv().unwrap() {
        assert_eq!(row.f_pred, row.step as f64);
        rows += 1;
    }
    assert_eq!(rows, 5000, "8192 telemetry slots hold all 5000 rows");
    assert_eq!(sv.telemetry_rx.dropped(), 0);

    let cmd = Command::Start {
        id: 3,
        experiment: FixedStr::new("ramp").unwrap(),
        args: ExperimentArgs {
            ramp_rate: Some(10.0),
            cycles: Some(2),
            f_max_start: None,
            f_max_step: Some(0.0),
        },
    };
    sv.commands_tx.try_send(cmd).unwrap();
    assert_eq!(lp.commands_rx.try_recv().unwrap(), Some(cmd));

    lp.heartbeat();
    lp.heartbeat();
    sv.heartbeat();
    assert_eq!(sv.link.peer_heartbeat(), 2);
    assert_eq!(lp.link.peer_heartbeat(), 1);
}

#[test]
fn reattaching_server_skips_stale_requests() {
    let name = unique("skip");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let sv = Segment::attach(&name).unwrap().server_side().unwrap();
    let attachments = lp.link.server_attachments();
    drop(sv);
    assert!(!lp.peer_alive());
    for seq in 0..10 {
        lp.features_tx.try_send(pattern::feature(seq)).unwrap();
    }
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    assert_eq!(sv.skipped_on_attach, 10);
    assert_eq!(
        lp.link.server_attachments(),
        attachments + 1,
        "the loop can see a new server came"
    );
    lp.features_tx.try_send(pattern::feature(10)).unwrap();
    pattern::check_feature(&sv.features_rx.try_recv().unwrap().unwrap(), 10).unwrap();
}

#[test]
fn loop_exit_unlinks_and_server_sees_it() {
    let name = unique("exit");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let mut sv = Segment::attach(&name).unwrap().server_side().unwrap();
    lp.features_tx.try_send(pattern::feature(0)).unwrap();
    drop(lp);
    assert!(
        !std::path::Path::new(&shm_path(&name)).exists(),
        "clean exit removes the segment"
    );
    assert!(!sv.peer_alive());
    // What the loop left is still delivered, then the server learns the loop is gone.
    pattern::check_feature(
        &sv.features_rx.recv_timeout(Duration::from_secs(1)).unwrap(),
        0,
    )
    .unwrap();
    assert_eq!(
        sv.features_rx.recv_timeout(Duration::from_secs(5)),
        Err(RecvError::PeerGone)
    );
    assert!(matches!(
        Segment::attach(&name),
        Err(Error::NotFound { .. })
    ));
}

#[test]
fn garbage_segment_is_refused_then_replaced() {
    let name = unique("junk");
    let path = shm_path(&name);
    std::fs::write(&path, vec![0xabu8; 8192]).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    assert!(matches!(
        Segment::attach(&name),
        Err(Error::BadMagic {
            found: 0xabab_abab_abab_abab,
            ..
        })
    ));
    assert!(matches!(
        Segment::inspect(&name),
        Err(Error::BadMagic { .. })
    ));
    // Nobody holds its locks: the creator treats it as stale and replaces it.
    let lp = Segment::create(&name, &haptics_proto::layout::config()).unwrap();
    assert!(lp.replaced_stale().is_some());
    Segment::attach(&name).unwrap();
}

#[test]
fn group_readable_segment_is_refused() {
    let name = unique("mode");
    let _lp = Segment::create(&name, &haptics_proto::layout::config()).unwrap();
    std::fs::set_permissions(shm_path(&name), std::fs::Permissions::from_mode(0o644)).unwrap();
    assert!(matches!(
        Segment::attach(&name),
        Err(Error::InsecureMode { mode: 0o644, .. })
    ));
}

/// Header offsets (repr(C), all u64): magic 0, layout_version 8, ...; schema 96..608;
/// channels[0] at 608: capacity 608, payload_words 616, slot_bytes 624, slot_align 632,
/// layout_id 640.
fn poke(name: &SegmentName, offset: u64, value: u64) -> u64 {
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(shm_path(name))
        .unwrap();
    let mut old = [0u8; 8];
    file.read_exact_at(&mut old, offset).unwrap();
    file.write_all_at(&value.to_le_bytes(), offset).unwrap();
    u64::from_le_bytes(old)
}

#[test]
fn mismatched_header_is_refused_with_a_clear_error() {
    let name = unique("hdr");
    let _lp = Segment::create(&name, &haptics_proto::layout::config()).unwrap();

    let old = poke(&name, 0, 0x1234);
    assert_eq!(old, shm_ring::MAGIC);
    let e = Segment::attach(&name).err().unwrap();
    assert!(matches!(e, Error::BadMagic { found: 0x1234, .. }), "{e}");
    poke(&name, 0, old);

    let old = poke(&name, 8, 99);
    assert_eq!(old, shm_ring::LAYOUT_VERSION);
    let e = Segment::attach(&name).err().unwrap();
    assert!(
        matches!(
            e,
            Error::VersionMismatch {
                found: 99,
                expected: shm_ring::LAYOUT_VERSION,
                ..
            }
        ),
        "{e}"
    );
    poke(&name, 8, old);

    let old = poke(&name, 616, 3);
    assert_eq!(
        old,
        haptics_proto::FeatureMsg::WORDS as u64,
        "offset 616 is the features payload_words"
    );
    let e = Segment::attach(&name).err().unwrap();
    assert!(
        matches!(&e, Error::LayoutMismatch { what, found: 3, .. } if what == "features payload words"),
        "{e}"
    );
    poke(&name, 616, old);

    let old = poke(&name, 640, 0xdead);
    let e = Segment::attach(&name).err().unwrap();
    assert!(
        matches!(&e, Error::LayoutMismatch { what, .. } if what == "features message layout id"),
        "{e}"
    );
    assert!(e.to_string().contains("layout differs"), "{e}");
    poke(&name, 640, old);

    let old = poke(&name, 608, 1000);
    assert!(matches!(
        Segment::attach(&name),
        Err(Error::LayoutMismatch { .. })
    ));
    poke(&name, 608, old);

    Segment::attach(&name).expect("restored header attaches");
}

#[test]
fn attach_timeout_waits_for_the_loop() {
    let name = unique("late");
    let n2 = name.clone();
    let creator = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(100));
        let seg = Segment::create(&n2, &haptics_proto::layout::config()).unwrap();
        std::thread::sleep(Duration::from_millis(500));
        drop(seg);
    });
    let t0 = std::time::Instant::now();
    assert!(matches!(
        Segment::attach(&name),
        Err(Error::NotFound { .. })
    ));
    Segment::attach_timeout(&name, Duration::from_secs(5)).unwrap();
    assert!(t0.elapsed() >= Duration::from_millis(90));
    creator.join().unwrap();
    assert!(matches!(
        Segment::attach_timeout(&name, Duration::from_millis(50)),
        Err(Error::NotFound { .. })
    ));
}

#[test]
fn endpoints_can_move_to_their_threads() {
    fn send<T: Send>() {}
    send::<haptics_proto::LoopSide>();
    send::<haptics_proto::ServerSide>();
    send::<shm_ring::Link>();
    fn sync<T: Sync>() {}
    sync::<shm_ring::Link>();
    // And for real: each end used from its own thread.
    let name = unique("threads");
    let lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let sv = Segment::attach(&name).unwrap().server_side().unwrap();
    let haptics_proto::LoopSide {
        mut features_tx,
        link,
        ..
    } = lp;
    let haptics_proto::ServerSide {
        mut features_rx, ..
    } = sv;
    let producer = std::thread::spawn(move || {
        for seq in 0..1000 {
            features_tx
                .send_timeout(pattern::feature(seq), Duration::from_secs(5))
                .unwrap();
        }
    });
    for seq in 0..1000 {
        pattern::check_feature(
            &features_rx.recv_timeout(Duration::from_secs(5)).unwrap(),
            seq,
        )
        .unwrap();
    }
    producer.join().unwrap();
    assert!(
        link.peer_alive(),
        "the destructured ends keep the mapping and the locks alive"
    );
}

/// The loop-status block through a real segment: the loop publishes, the server (another
/// mapping of the same memory) reads exactly that back; a server handle cannot write it; a
/// reader racing a publishing thread only ever sees whole snapshots.
#[test]
fn loop_status_block_round_trips_through_the_segment() {
    use haptics_proto::{LoopClock, LoopStatus, Quantiles, StatusText};
    let name = unique("status");
    let lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    let sv = Segment::attach(&name).unwrap().server_side().unwrap();
    assert_eq!(sv.link.loop_status(), None, "never published");
    let mut s = LoopStatus {
        clock: LoopClock::Realtime,
        board: StatusText::new("sim"),
        rate_hz: 10_000.0,
        scheduling: StatusText::new("SCHED_OTHER (FIFO refused: EPERM)"),
        recorder: StatusText::new(&format!("writing /tmp/{} rows 42", "d/".repeat(80))),
        running: true,
        run_id: 2,
        steps: 12_345,
        fallbacks: 17,
        deadline_misses: 5,
        overruns: 3,
        round_trip: Quantiles {
            p50_ns: 1_700,
            p99_ns: 6_200,
            p999_ns: 32_960,
            max_ns: 118_100,
            count: 19_865,
        },
        period_jitter: Quantiles {
            p50_ns: 900,
            p99_ns: 4_000,
            p999_ns: 20_000,
            max_ns: 80_000,
            count: 12_345,
        },
        updated_unix_ns: 1_700_000_000_000_000_000,
        generation: 0,
        experiment: StatusText::new("shadow"),
        on_time: 12_000,
        late_one: 200,
        held: 100,
        fallback_steps: 45,
        corrupt: 1,
        max_transition_step_n: 0.04,
        saturated: 7,
        board_faults: 1,
        board_fault: StatusText::new("the hardware watchdog tripped"),
        board_fifo_overflows: 2,
        board_quadrature_errors: 3,
        passivity_on: true,
        passivity_energy_j: 0.5,
        passivity_received_j: 2.0,
        passivity_returned_j: 1.5,
        passivity_damping_ns_per_m: 120.0,
        passivity_active_steps: 9,
        velocity_gain_rad_s: 30.0,
        acceleration_gain_rad_s: 100.0,
    };
    assert_eq!(
        s.recorder.as_str().len(),
        haptics_proto::RECORDER_BYTES,
        "truncated"
    );
    assert_eq!(lp.link.publish_loop_status(&s), Some(1));
    assert_eq!(
        sv.link.publish_loop_status(&s),
        None,
        "the server never writes it"
    );
    let got = sv.link.loop_status().expect("published");
    assert_eq!(got, LoopStatus { generation: 1, ..s });
    assert_eq!(got.scheduling.as_str(), "SCHED_OTHER (FIFO refused: EPERM)");

    // A publishing thread (every field derived from one counter) against a reader: each
    // snapshot read is internally consistent and generations never go backwards.
    let writer_link = lp.link.clone();
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let d = done.clone();
    let writer = std::thread::spawn(move || {
        for i in 0..200_000u64 {
            s.steps = i;
            s.fallbacks = i * 3;
            s.round_trip.max_ns = i + 7;
            s.board.set(&format!("b{i}"));
            writer_link.publish_loop_status(&s);
        }
        d.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let (mut last_gen, mut reads) = (0, 0u64);
    while !done.load(std::sync::atomic::Ordering::Relaxed) {
        // generation 1 is the publication above (not derived from one counter)
        if let Some(r) = sv.link.loop_status().filter(|r| r.generation > 1) {
            assert_eq!(r.fallbacks, r.steps * 3, "torn snapshot");
            assert_eq!(r.round_trip.max_ns, r.steps + 7, "torn snapshot");
            assert_eq!(r.board.as_str(), format!("b{}", r.steps), "torn text");
            assert!(r.generation >= last_gen);
            last_gen = r.generation;
            reads += 1;
        }
    }
    writer.join().unwrap();
    assert!(reads > 0);
    assert_eq!(sv.link.loop_status().unwrap().steps, 199_999);
}
