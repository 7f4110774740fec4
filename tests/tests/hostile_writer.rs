//! Issue 13 item 6: a hostile process writes random words into a live segment's header, ring
//! control blocks and slots while `rt-loop` runs in realtime with a served model.
//!
//! The writer (this test process: neither the loop nor the server) works in bursts: it maps
//! whatever segment the name holds now (the loop re-creates it when it finds it corrupt), writes
//! `BURST` random words at random offsets (half in the header and control blocks, half
//! anywhere), then stays quiet for `QUIET`, for `HAPTICS_HOSTILE_S` seconds in all (default 15;
//! scripts/fuzz.sh runs it for 60). Then the loop runs on undisturbed for `RECOVER_S`.
//!
//! Checked: the loop never panics and ends its run normally (no crash: no access outside its
//! mapping; no hang: it ends on its time limit, on time); the current stays within its limit on
//! every recorded step; the loop counted corruption and re-created the segment; it renders with
//! the model again after the last burst; the server is still up and re-attached. The counts are
//! printed (run with `--nocapture` to see them).
//!
//! Needs the release binaries and the project's `.venv` (like the other system tests).

use haptics_system_tests::{
    bin, instance, start_infer_server, temp_dir, write_linear_model, CsvTable, Proc,
};
use std::os::fd::AsRawFd;
use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Random words per burst.
const BURST: u32 = 40;
/// Quiet time after each burst (the loop re-creates the segment and the server re-attaches).
const QUIET: Duration = Duration::from_millis(1500);
/// Undisturbed time at the end: the loop must be back on the model.
const RECOVER_S: f64 = 4.0;
/// The loop's rate: realtime at 1 kHz with parking waits, light on a two-core machine.
const RATE_HZ: f64 = 1000.0;
/// Largest motor current the loop may command (the rig's limit, A).
const I_MAX: f64 = 0.59;

/// The loop's schema (docs/recording-format.md plus F(t-1)): rt-loop's one list.
const SCHEMA: [&str; 10] = rt_loop::features::SCHEMA_NAMES;

/// xorshift64: reproducible from the printed seed, no dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// The segment the name holds right now, mapped shared (as any process of the user can).
struct Mapped {
    ptr: *mut u8,
    len: usize,
}

impl Mapped {
    fn open(path: &Path) -> Option<Mapped> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)
            .ok()?;
        let len = file.metadata().ok()?.len() as usize;
        if len < 4096 {
            return None;
        }
        // SAFETY: a fresh shared mapping of a file we opened; unmapped in Drop.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                file.as_raw_fd(),
                0,
            )
        };
        (ptr != libc::MAP_FAILED).then(|| Mapped {
            ptr: ptr.cast(),
            len,
        })
    }

    /// Writes `value` at the 8-aligned `offset` (an atomic store: the segment's words are
    /// atomics in both other processes too).
    fn write(&self, offset: usize, value: u64) {
        let offset = (offset % self.len) & !7;
        // SAFETY: inside the mapping, 8-aligned (the mapping is page-aligned).
        let cell = unsafe { &*self.ptr.add(offset).cast::<AtomicU64>() };
        cell.store(value, Ordering::Relaxed);
    }
}

impl Drop for Mapped {
    fn drop(&mut self) {
        // SAFETY: our own mapping.
        unsafe {
            libc::munmap(self.ptr.cast(), self.len);
        }
    }
}

#[test]
fn random_writes_into_a_live_segment_never_crash_the_loop_or_the_server() {
    let hostile_s: f64 = std::env::var("HAPTICS_HOSTILE_S")
        .ok()
        .map(|v| v.parse().expect("HAPTICS_HOSTILE_S: seconds"))
        .unwrap_or(15.0);
    let seed: u64 = std::env::var("HAPTICS_HOSTILE_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x5eed_1e55_0bad_cafe);
    let dir = temp_dir("hostile");
    write_linear_model(
        &dir.join("spring.onnx"),
        &SCHEMA,
        &[400.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.05, 10.0, 1.0, 0.1],
        0.02,
    );
    // Presses for longer than the test: the run ends on its time limit.
    let cfg = dir.join("long.toml");
    std::fs::write(&cfg, "[hand]\nrepeats = 1000\ndepth_step_m = 0.0\n").unwrap();
    let inst = instance("hostile");
    let (mut server, _) = start_infer_server(&inst, &dir, Some("spring.onnx"));
    let rec = dir.join("hostile.csv");
    let sum = dir.join("summary.json");
    let run_s = 1.0 + hostile_s + RECOVER_S;
    let mut lp = Proc::spawn(
        "rt-loop",
        Command::new(bin("rt-loop"))
            .args(["run", "--experiment", "reproduction", "--clock", "realtime"])
            .arg("--config")
            .arg(&cfg)
            .args(["--rate-hz", &RATE_HZ.to_string()])
            .args(["--deadline-us", "900", "--wait", "park"])
            .args(["--model", "shm", "--instance", &inst])
            .args(["--server-wait-s", "60", "--duration", &run_s.to_string()])
            .args(["--no-progress", "--record"])
            .arg(&rec)
            .arg("--summary-json")
            .arg(&sum),
    );
    lp.wait_for("infer-server attached", Duration::from_secs(60));
    let started = Instant::now();
    std::thread::sleep(Duration::from_secs(1));

    let path = Path::new("/dev/shm").join(format!("haptics-{inst}"));
    let mut rng = Rng(seed);
    let (mut writes, mut bursts) = (0u64, 0u64);
    let end = Instant::now() + Duration::from_secs_f64(hostile_s);
    while Instant::now() < end {
        if let Some(m) = Mapped::open(&path) {
            for _ in 0..BURST {
                // Half of the writes into the header and control blocks (first 8 KiB).
                let span = if rng.next().is_multiple_of(2) {
                    8192
                } else {
                    m.len
                };
                let offset = (rng.next() % span as u64) as usize;
                m.write(offset, rng.next());
                writes += 1;
            }
            bursts += 1;
        }
        std::thread::sleep(QUIET);
        assert!(
            lp.child.try_wait().unwrap().is_none(),
            "rt-loop died during the attack:\n{}",
            lp.output()
        );
    }
    let hostile_end_s = started.elapsed().as_secs_f64() + 1.0;

    let st = lp.wait_exit(Duration::from_secs_f64(run_s + 60.0));
    let out = lp.output();
    assert!(st.success(), "rt-loop must end normally ({st}):\n{out}");
    assert!(!out.contains("panicked"), "{out}");
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&sum).expect("summary")).expect("json");
    assert_eq!(
        s["stop"], "time-limit",
        "no hang: the run ended on its limit\n{out}"
    );
    let wall = s["wall_s"].as_f64().unwrap();
    assert!(
        wall < run_s + 10.0,
        "no hang: {wall} s of wall time for a {run_s} s run"
    );
    let corrupt = s["corrupt"].as_u64().expect("corrupt in the summary");
    let recoveries = out.matches("re-created it (recovery").count();
    assert!(corrupt > 0, "the loop found the damage:\n{out}");
    assert!(recoveries > 0, "the loop re-created the segment:\n{out}");

    // Every recorded step's current within the limit (the fallback renders the damaged time).
    let table = CsvTable::read(&rec);
    let mut over = 0;
    let mut max_i = 0.0f64;
    for v in table.col("I_motor") {
        let i: f64 = v.parse().unwrap_or(f64::NAN);
        max_i = max_i.max(i.abs());
        // NaN counts as over the limit too
        if i.is_nan() || i.abs() > I_MAX + 1e-12 {
            over += 1;
        }
    }
    assert_eq!(over, 0, "steps over the current limit (max |I| {max_i} A)");
    // Back on the model after the last burst: the last second is mostly served.
    let (times, fallback) = (table.col("time"), table.col("fallback"));
    let last: Vec<usize> = (0..times.len())
        .filter(|&k| times[k].parse::<f64>().unwrap_or(0.0) > run_s - 1.0)
        .collect();
    let served = last
        .iter()
        .filter(|&&k| matches!(fallback[k], "false" | "0"))
        .count();
    assert!(!last.is_empty(), "the recording covers the last second");
    let served_frac = served as f64 / last.len() as f64;
    assert!(
        served_frac > 0.5,
        "back on the model after the attack: {served} of the last {} steps served\n{out}",
        last.len()
    );
    // The server is still up and attached again.
    assert!(
        server.child.try_wait().unwrap().is_none(),
        "infer-server must stay up:\n{}",
        server.output()
    );
    println!(
        "hostile writer: {hostile_s} s, seed {seed:#x}, {bursts} bursts, {writes} random writes; \
         loop: {corrupt} corrupt detections, {recoveries} recoveries, steps {}, fallback steps {}, \
         server attachments seen {}, max |I_motor| {max_i:.3} A (limit {I_MAX}), {:.0} % of the \
         last second served, run ended on its limit after {wall:.1} s wall (attack ended at \
         {hostile_end_s:.1} s); panics 0, crashes (out-of-bounds) 0, hangs 0; server up",
        s["steps"],
        s["model"]["fallbacks"],
        s["shm"]["attachments_seen"],
        served_frac * 100.0
    );
    server.signal(libc::SIGINT);
    let _ = server.wait_exit(Duration::from_secs(10));
}
