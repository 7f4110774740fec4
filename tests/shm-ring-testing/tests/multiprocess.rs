//! Two real processes over a real segment: the other process is `shm-ring-peer`, built by
//! cargo for this crate. Ten million messages each way with zero loss, order kept and every
//! slot checked field by field; SIGKILL of either side mid-stream.
//!
//! Parking waits only (the machine may have two cores): the flooding side uses `Park` or
//! spin-then-park, never both sides spinning.

use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use haptics_proto::Segment;
use shm_ring::{Config, Error, RecvError, SegmentName, SendError, WaitStrategy};
use shm_ring_testing::pattern;

const PEER: &str = env!("CARGO_BIN_EXE_shm-ring-peer");
const TEN_MILLION: u64 = 10_000_000;

/// These tests saturate both cores; run them one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

fn unique(tag: &str) -> SegmentName {
    SegmentName::for_instance(&format!("mp{}-{tag}", std::process::id())).unwrap()
}

struct Peer {
    child: Child,
    out: BufReader<ChildStdout>,
}

impl Peer {
    fn spawn(args: &[&str]) -> Peer {
        let mut child = Command::new(PEER)
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn shm-ring-peer");
        let out = BufReader::new(child.stdout.take().unwrap());
        Peer { child, out }
    }

    /// Next line the peer prints (blocking).
    fn line(&mut self) -> String {
        let mut line = String::new();
        self.out.read_line(&mut line).unwrap();
        line.trim().to_owned()
    }

    fn kill9(&mut self) {
        self.child.kill().unwrap(); // SIGKILL
        self.child.wait().unwrap();
    }

    fn expect_success(mut self) {
        let status = self.child.wait().unwrap();
        assert!(status.success(), "peer failed: {status}");
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn eventually(timeout: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        if cond() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    cond()
}

#[test]
fn ten_million_features_from_a_loop_process() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("flood-features");
    let count = TEN_MILLION.to_string();
    let mut peer = Peer::spawn(&["loop-flood", name.as_str(), &count, "park"]);
    assert_eq!(peer.line(), "ready");
    let mut sv = Segment::attach_timeout(&name, Duration::from_secs(10))
        .unwrap()
        .server_side()
        .unwrap();
    sv.features_rx
        .set_wait_strategy(WaitStrategy::DEFAULT_SPIN_THEN_PARK);
    let t0 = Instant::now();
    for seq in 0..TEN_MILLION {
        let msg = sv
            .features_rx
            .recv_timeout(Duration::from_secs(10))
            .unwrap_or_else(|e| panic!("at {seq}: {e}"));
        if let Err(e) = pattern::check_feature(&msg, seq) {
            panic!("{e}");
        }
    }
    let took = t0.elapsed();
    eprintln!(
        "10M features across processes in {took:?} ({:.1} M msg/s)",
        TEN_MILLION as f64 / took.as_secs_f64() / 1e6
    );
    assert_eq!(peer.line(), format!("done {TEN_MILLION}"));
    peer.expect_success();
    assert_eq!(
        sv.features_rx.recv_timeout(Duration::from_secs(5)),
        Err(RecvError::PeerGone),
        "nothing extra arrives"
    );
}

#[test]
fn ten_million_forces_from_a_server_process() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("flood-forces");
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx
        .set_wait_strategy(WaitStrategy::DEFAULT_SPIN_THEN_PARK);
    let count = TEN_MILLION.to_string();
    let mut peer = Peer::spawn(&["server-flood", name.as_str(), &count, "park"]);
    assert_eq!(peer.line(), "ready");
    let t0 = Instant::now();
    for seq in 0..TEN_MILLION {
        let msg = lp
            .forces_rx
            .recv_timeout(Duration::from_secs(10))
            .unwrap_or_else(|e| panic!("at {seq}: {e}"));
        if let Err(e) = pattern::check_force(&msg, seq) {
            panic!("{e}");
        }
    }
    let took = t0.elapsed();
    eprintln!(
        "10M forces across processes in {took:?} ({:.1} M msg/s)",
        TEN_MILLION as f64 / took.as_secs_f64() / 1e6
    );
    assert_eq!(peer.line(), format!("done {TEN_MILLION}"));
    peer.expect_success();
    assert_eq!(lp.forces_rx.try_recv(), Ok(None));
}

/// One request/answer exchange with an echo server; the answer must match the request.
fn exchange(lp: &mut haptics_proto::LoopSide, seq: u64) -> Result<(), RecvError> {
    lp.features_tx
        .try_send(pattern::feature(seq))
        .expect("room for a request");
    loop {
        let force = lp.forces_rx.recv_timeout(Duration::from_secs(5))?;
        if force.seq == seq {
            pattern::check_force(&force, seq).unwrap();
            return Ok(());
        }
        assert!(
            force.seq < seq,
            "answer {} from the future (asked {seq})",
            force.seq
        );
    }
}

#[test]
fn killed_server_is_noticed_and_a_new_one_reattaches() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("kill-server");
    let mut lp = Segment::create(
        &name,
        &Config {
            capacities: [64, 0, 0, 0],
            ..haptics_proto::layout::config()
        },
    )
    .unwrap()
    .loop_side()
    .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Park);

    let mut server = Peer::spawn(&["server-echo", name.as_str(), "park"]);
    assert!(server.line().starts_with("ready"));
    assert!(eventually(Duration::from_secs(5), || lp.peer_alive()));
    let first_attach = lp.link.server_attachments();
    for seq in 0..2000 {
        exchange(&mut lp, seq).unwrap();
    }
    let beats = lp.link.peer_heartbeat();
    assert!(
        beats >= 2000,
        "the echo server beats once per answer ({beats})"
    );

    // Mid-stream: requests in flight, then SIGKILL.
    for seq in 2000..2010 {
        lp.features_tx.try_send(pattern::feature(seq)).unwrap();
    }
    server.kill9();
    assert!(
        eventually(Duration::from_secs(2), || !lp.peer_alive()),
        "the loop notices the dead server"
    );

    // The loop stays safe: no hang, no panic. Waiting for an answer ends (peer gone), and a
    // full request ring refuses new requests instead of blocking or dropping silently.
    let t0 = Instant::now();
    while lp.forces_rx.try_recv().unwrap().is_some() {}
    assert_eq!(
        lp.forces_rx.recv_timeout(Duration::from_secs(5)),
        Err(RecvError::PeerGone)
    );
    assert!(t0.elapsed() < Duration::from_secs(2));
    let mut seq = 2010;
    loop {
        match lp.features_tx.try_send(pattern::feature(seq)) {
            Ok(()) => seq += 1,
            Err(SendError::Full(m)) => {
                assert_eq!(m.seq, seq, "the refused request is handed back");
                break;
            }
            Err(e) => panic!("{e}"),
        }
    }
    assert!(lp.features_tx.full_count() >= 1);
    let heartbeat_after_death = lp.link.peer_heartbeat();

    // A new server comes: it attaches to the same segment, skips the stale requests, and the
    // exchange resumes.
    let mut server2 = Peer::spawn(&["server-echo", name.as_str(), "park"]);
    let ready = server2.line();
    let skipped: u64 = ready
        .strip_prefix("ready skipped=")
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(skipped, 64, "the full ring of stale requests was skipped");
    assert!(eventually(Duration::from_secs(5), || lp.peer_alive()));
    assert_eq!(lp.link.server_attachments(), first_attach + 1);
    for s in seq..seq + 2000 {
        exchange(&mut lp, s).unwrap();
    }
    assert!(lp.link.peer_heartbeat() >= heartbeat_after_death + 2000);
}

#[test]
fn killed_loop_is_noticed_its_segment_replaced_and_the_server_reattaches() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("kill-loop");
    let mut looper = Peer::spawn(&["loop-run", name.as_str(), "park"]);
    assert_eq!(looper.line(), "ready replaced=-");
    let loop_pid = looper.child.id();

    // A live loop's segment is never stolen.
    assert!(
        matches!(Segment::create(&name, &haptics_proto::layout::config()), Err(Error::InstanceInUse { pid, .. }) if pid == loop_pid)
    );

    let mut sv = Segment::attach_timeout(&name, Duration::from_secs(5))
        .unwrap()
        .server_side()
        .unwrap();
    sv.features_rx.set_wait_strategy(WaitStrategy::Park);
    let serve = |sv: &mut haptics_proto::ServerSide, n: u64| -> Result<(), RecvError> {
        let mut last = None;
        for _ in 0..n {
            let f = sv.features_rx.recv_timeout(Duration::from_secs(5))?;
            pattern::check_feature(&f, f.seq).unwrap();
            if let Some(l) = last {
                assert_eq!(f.seq, l + 1, "in order, nothing lost");
            }
            last = Some(f.seq);
            let _ = sv.forces_tx.try_send(pattern::force(f.seq));
        }
        Ok(())
    };
    serve(&mut sv, 3000).unwrap();
    assert!(
        sv.telemetry_rx.try_recv().unwrap().is_some(),
        "telemetry flows too"
    );

    assert!(sv.link.info().creator_process_alive());
    looper.kill9();
    assert!(
        !sv.link.info().creator_process_alive(),
        "pid + start time no longer names a live process"
    );
    assert!(
        eventually(Duration::from_secs(2), || !sv.peer_alive()),
        "the server notices the dead loop"
    );
    // Safe: it drains what the loop left, then learns the loop is gone; nothing hangs.
    let outcome = loop {
        match sv.features_rx.recv_timeout(Duration::from_secs(5)) {
            Ok(f) => pattern::check_feature(&f, f.seq).unwrap(),
            Err(e) => break e,
        }
    };
    assert_eq!(outcome, RecvError::PeerGone);
    assert!(matches!(
        sv.forces_tx.try_send(pattern::force(0)),
        Ok(()) | Err(SendError::Full(_))
    ));
    // The dead loop's segment is still there, and recognised as stale.
    assert!(
        matches!(Segment::attach(&name), Err(Error::CreatorDead { pid, .. }) if pid == loop_pid)
    );

    // A new loop replaces the stale segment; the server re-attaches to the new one.
    let mut looper2 = Peer::spawn(&["loop-run", name.as_str(), "park"]);
    assert_eq!(looper2.line(), format!("ready replaced={loop_pid}"));
    drop(sv);
    let mut sv = Segment::attach_timeout(&name, Duration::from_secs(5))
        .unwrap()
        .server_side()
        .unwrap();
    sv.features_rx.set_wait_strategy(WaitStrategy::Park);
    assert_eq!(sv.link.info().creator_pid, looper2.child.id());
    serve(&mut sv, 3000).unwrap();
    looper2.kill9();
    // Leave nothing behind: replacing the stale segment and exiting cleanly removes it.
    drop(Segment::create(&name, &haptics_proto::layout::config()).unwrap());
    assert!(!std::path::Path::new(&format!("/dev/shm{}", name.as_str())).exists());
}
