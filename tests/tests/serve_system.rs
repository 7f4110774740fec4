//! `rt-loop serve` + `infer-server serve` + `hapticctl`: the system comes up, the status shows
//! the loop alive, an experiment started through hapticctl (the mailbox) changes the mode and
//! streams telemetry, a shadow run with a served model predicts alongside, and SIGINT to both
//! leaves nothing in /dev/shm.

use haptics_system_tests::{
    bin, ctl, ctl_status, http_get, instance, shm_entries, start_infer_server, temp_dir,
    write_linear_model, Proc,
};
use std::process::Command;
use std::time::{Duration, Instant};

fn wait_status(
    addr: &str,
    what: &str,
    f: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        let s = ctl_status(addr);
        if f(&s) {
            return s;
        }
        assert!(Instant::now() < end, "{what}: last status {s}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn serve_hapticctl_experiments_and_clean_sigint() {
    let dir = temp_dir("serve");
    write_linear_model(
        &dir.join("spring.onnx"),
        &["position_x", "velocity"],
        &[400.0, 20.0],
        0.0,
    );
    let inst = instance("serve");
    // realtime at 1 kHz: light on a two-core machine; parking waits for the answers
    let mut lp = Proc::spawn(
        "rt-loop serve",
        Command::new(bin("rt-loop"))
            .args([
                "serve",
                "--instance",
                &inst,
                "--clock",
                "realtime",
                "--rate-hz",
                "1000",
            ])
            .args(["--deadline-us", "900", "--wait", "park", "--record-dir"])
            .arg(dir.join("rec")),
    );
    lp.wait_for("serving segment", Duration::from_secs(30));
    let (mut server, addr) = start_infer_server(&inst, &dir, Some("spring.onnx"));

    let s = wait_status(&addr, "loop alive", |s| s["loop"]["alive"] == true);
    assert_eq!(s["loop"]["mode"], "idle", "serve idles until asked: {s}");
    // published by the idle loop already
    assert_eq!(s["loop"]["clock"], "realtime", "{s}");
    assert_eq!(s["loop"]["recorder"], "off", "{s}");

    let (ok, out) = ctl(
        &addr,
        &[
            "experiment",
            "start",
            "abstraction",
            "--ramp-rate",
            "6",
            "--cycles",
            "2",
        ],
    );
    assert!(ok, "start: {out}");
    let s = wait_status(&addr, "mode abstraction with steps", |s| {
        s["loop"]["mode"] == "abstraction"
            && s["loop"]["step"].as_u64().unwrap_or(0) > 200
            && s["loop"]["rate_hz"].as_f64().unwrap_or(0.0) > 0.0
    });
    let rate = s["loop"]["rate_hz"].as_f64().unwrap();
    assert!(
        rate > 500.0 && rate < 1500.0,
        "loop rate from telemetry: {rate} Hz"
    );
    let (ok, out) = ctl(&addr, &["experiment", "stop"]);
    assert!(ok, "stop: {out}");
    wait_status(&addr, "idle after stop", |s| s["loop"]["mode"] == "idle");
    lp.wait_for("ended: stopped", Duration::from_secs(10));

    // shadow: the sponge is touched, the served model predicts alongside
    let (ok, out) = ctl(&addr, &["experiment", "start", "shadow"]);
    assert!(ok, "start shadow: {out}");
    wait_status(&addr, "model predictions during shadow", |s| {
        s["server"]["predictions"].as_u64().unwrap_or(0) > 500
    });
    // The loop-status block (written by the loop ~10 Hz into the segment header): clock,
    // board, the scheduling actually obtained, the recorder, and the loop-observed round trip.
    let s = wait_status(&addr, "round trips in the loop's status block", |s| {
        s["loop"]["round_trip_latency"]["count"]
            .as_u64()
            .unwrap_or(0)
            > 200
    });
    let l = &s["loop"];
    assert_eq!(l["clock"], "realtime", "{s}");
    assert_eq!(l["board"], "sim", "{s}");
    let sched = l["scheduling"].as_str().unwrap_or("");
    assert!(
        sched.starts_with("SCHED_FIFO ") || sched.starts_with("SCHED_OTHER"),
        "scheduling obtained: {s}"
    );
    let rec = l["recorder"].as_str().unwrap_or("");
    assert!(
        rec.starts_with("writing ") && rec.contains("shadow-") && rec.contains(" rows "),
        "recorder state: {s}"
    );
    let rtt = &l["round_trip_latency"];
    let (p50, p99, max) = (
        rtt["p50_us"].as_f64().unwrap(),
        rtt["p99_us"].as_f64().unwrap(),
        rtt["max_us"].as_f64().unwrap(),
    );
    assert!(p50 > 0.0 && p50 <= p99 && p99 <= max, "round trip: {s}");
    assert!(l["deadline_misses"].is_u64(), "{s}");
    eprintln!("status during shadow: {}", l);
    assert!(
        l["period_jitter"]["count"].as_u64().unwrap_or(0) > 0 && l["overruns"].is_u64(),
        "period jitter of the realtime clock: {s}"
    );
    // The same block through HTTP: the page's status object and the Prometheus metrics.
    let http = server
        .output()
        .lines()
        .find_map(|l| l.split(" HTTP http://").nth(1))
        .and_then(|r| r.split_whitespace().next())
        .expect("HTTP address in infer-server's ready line")
        .to_string();
    let api: serde_json::Value =
        serde_json::from_str(&http_get(&http, "/api/status")).expect("/api/status JSON");
    assert_eq!(api["loop"]["clock"], "realtime", "{api}");
    assert!(
        api["loop"]["latency_us"]["count"].as_u64().unwrap_or(0) > 0,
        "{api}"
    );
    assert!(
        api["loop"]["latency_us"]["p50"].as_f64().unwrap_or(0.0) > 0.0,
        "{api}"
    );
    let metrics = http_get(&http, "/metrics");
    let p50 = metrics
        .lines()
        .find(|l| l.starts_with("haptics_round_trip_latency_us{quantile=\"0.5\"}"))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or_else(|| panic!("round trip p50 in /metrics:\n{metrics}"));
    assert!(p50 > 0.0, "round trip p50 {p50} in /metrics");
    ctl(&addr, &["experiment", "stop"]);
    let out = lp.wait_for("run 2 ended: stopped", Duration::from_secs(10));
    let line = out.lines().find(|l| l.contains("run 2 ended")).unwrap();
    assert!(line.contains("served"), "{line}");

    // SIGINT to both: clean exits, nothing left in /dev/shm
    lp.signal(libc::SIGINT);
    let st = lp.wait_exit(Duration::from_secs(10));
    assert!(st.success(), "rt-loop serve exit {st}:\n{}", lp.output());
    assert!(lp.output().contains("removed"));
    server.signal(libc::SIGINT);
    let st = server.wait_exit(Duration::from_secs(10));
    assert!(st.code().is_some(), "infer-server ended by itself: {st}");
    assert!(
        shm_entries(&inst).is_empty(),
        "left in /dev/shm: {:?}",
        shm_entries(&inst)
    );
    let recs: Vec<_> = std::fs::read_dir(dir.join("rec")).unwrap().collect();
    assert_eq!(recs.len(), 2, "one recording per experiment");
}
