//! The peer's commands (see `main.rs`).

use std::io::Write;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use haptics_proto::{Segment, TelemetryRow};
use shm_ring::{RecvError, SegmentName, SendError, WaitStrategy};
use shm_ring_testing::pattern;

const USAGE: &str = "usage:
  shm-ring-peer inspect NAME
  shm-ring-peer loop-flood NAME COUNT WAIT    create; push COUNT features; wait until drained
  shm-ring-peer loop-run NAME WAIT            create; stream features + telemetry until killed
  shm-ring-peer server-flood NAME COUNT WAIT  attach; push COUNT forces
  shm-ring-peer server-echo NAME WAIT         attach; answer every feature until the loop dies
WAIT: spin | park | spin-then-park";

pub fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("shm-ring-peer: {e}");
            ExitCode::FAILURE
        }
    }
}

fn parse_wait(s: &str) -> Result<WaitStrategy, String> {
    match s {
        "spin" => Ok(WaitStrategy::Spin),
        "park" => Ok(WaitStrategy::Park),
        "spin-then-park" => Ok(WaitStrategy::DEFAULT_SPIN_THEN_PARK),
        _ => Err(format!("unknown wait strategy `{s}`\n{USAGE}")),
    }
}

fn arg(args: &[String], i: usize) -> Result<&str, String> {
    args.get(i)
        .map(String::as_str)
        .ok_or_else(|| USAGE.to_owned())
}

fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

fn run(args: &[String]) -> Result<(), String> {
    let cmd = arg(args, 0)?;
    let name = SegmentName::new(arg(args, 1)?).map_err(|e| e.to_string())?;
    match cmd {
        "inspect" => {
            // Reads the header without attaching: safe while a server is attached.
            println!("{:#?}", Segment::inspect(&name).map_err(|e| e.to_string())?);
            Ok(())
        }
        "loop-flood" => {
            let count: u64 = arg(args, 2)?.parse().map_err(|e| format!("COUNT: {e}"))?;
            loop_flood(&name, count, parse_wait(arg(args, 3)?)?)
        }
        "loop-run" => loop_run(&name, parse_wait(arg(args, 2)?)?),
        "server-flood" => {
            let count: u64 = arg(args, 2)?.parse().map_err(|e| format!("COUNT: {e}"))?;
            server_flood(&name, count, parse_wait(arg(args, 3)?)?)
        }
        "server-echo" => server_echo(&name, parse_wait(arg(args, 2)?)?),
        _ => Err(USAGE.to_owned()),
    }
}

fn wait_until(timeout: Duration, mut done: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        if done() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    done()
}

fn loop_flood(name: &SegmentName, count: u64, wait: WaitStrategy) -> Result<(), String> {
    let mut lp = Segment::create(name, &haptics_proto::layout::config())
        .and_then(Segment::loop_side)
        .map_err(|e| e.to_string())?;
    lp.features_tx.set_wait_strategy(wait);
    say("ready");
    if !wait_until(Duration::from_secs(30), || lp.peer_alive()) {
        return Err("no server attached within 30 s".into());
    }
    for seq in 0..count {
        lp.features_tx
            .send(pattern::feature(seq))
            .map_err(|e| format!("send {seq}: {e}"))?;
    }
    let capacity = lp.link.info().capacities[haptics_proto::layout::FEATURES.index()] as u64;
    if !wait_until(Duration::from_secs(30), || {
        lp.features_tx.free() == capacity || !lp.peer_alive()
    }) {
        return Err("server did not drain the ring".into());
    }
    say(&format!("done {count}"));
    Ok(())
}

fn loop_run(name: &SegmentName, wait: WaitStrategy) -> Result<(), String> {
    let seg = Segment::create(name, &haptics_proto::layout::config()).map_err(|e| e.to_string())?;
    let replaced = seg
        .replaced_stale()
        .map(|s| s.creator_pid.to_string())
        .unwrap_or_else(|| "-".into());
    let mut lp = seg.loop_side().map_err(|e| e.to_string())?;
    lp.forces_rx.set_wait_strategy(wait);
    say(&format!("ready replaced={replaced}"));
    let mut seq = 0u64;
    loop {
        // Like the real loop: never wait on the server; a full ring is refused and retried.
        match lp.features_tx.try_send(pattern::feature(seq)) {
            Ok(()) => {
                lp.telemetry_tx.send(&TelemetryRow {
                    step: seq,
                    time: seq as f64 * 1e-3,
                    ..Default::default()
                });
                seq += 1;
            }
            Err(SendError::Full(_)) => std::thread::sleep(Duration::from_millis(1)),
            Err(e) => return Err(e.to_string()),
        }
        lp.heartbeat();
        while let Some(force) = lp.forces_rx.try_recv().map_err(|e| e.to_string())? {
            pattern::check_force(&force, force.seq)?;
        }
        if seq & 63 == 0 {
            std::thread::sleep(Duration::from_micros(200));
        }
    }
}

fn server_flood(name: &SegmentName, count: u64, wait: WaitStrategy) -> Result<(), String> {
    let seg = Segment::attach_timeout(name, Duration::from_secs(30)).map_err(|e| e.to_string())?;
    let mut sv = seg.server_side().map_err(|e| e.to_string())?;
    sv.forces_tx.set_wait_strategy(wait);
    say("ready");
    for seq in 0..count {
        sv.forces_tx
            .send(pattern::force(seq))
            .map_err(|e| format!("send {seq}: {e}"))?;
    }
    say(&format!("done {count}"));
    Ok(())
}

fn server_echo(name: &SegmentName, wait: WaitStrategy) -> Result<(), String> {
    let seg = Segment::attach_timeout(name, Duration::from_secs(30)).map_err(|e| e.to_string())?;
    let mut sv = seg.server_side().map_err(|e| e.to_string())?;
    sv.features_rx.set_wait_strategy(wait);
    sv.forces_tx.set_wait_strategy(wait);
    say(&format!("ready skipped={}", sv.skipped_on_attach));
    loop {
        match sv.features_rx.recv() {
            Ok(f) => {
                pattern::check_feature(&f, f.seq)?;
                sv.heartbeat();
                sv.forces_tx
                    .send(pattern::force(f.seq))
                    .map_err(|e| e.to_string())?;
            }
            Err(RecvError::PeerGone) => return Ok(()),
            Err(e) => return Err(e.to_string()),
        }
    }
}
