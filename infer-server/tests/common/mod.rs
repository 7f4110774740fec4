//! Shared by the integration tests: ONNX Runtime and the fixture models.
//!
//! The fixtures are written by `tests/fixtures/make_models.py` with the project's venv
//! (`bash scripts/setup.sh` creates it). Without the venv the tests fail and say so; set
//! `HAPTICS_SKIP_PY=1` to skip them explicitly instead: each skipped test is recorded
//! ([`skip::skip`]: counted by scripts/test.sh), and under `CI=true` it fails instead.

#![allow(dead_code)]

#[path = "../../../tests/src/skip.rs"]
pub mod skip;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use infer_server::Runtime;

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .canonicalize()
        .expect("manifest dir")
        .parent()
        .expect("crate lives in the workspace")
        .to_path_buf()
}

/// The venv's Python: `$HAPTICS_PYTHON` (scripts/env.sh sets it), else `<repo>/.venv/bin/python`.
pub fn python() -> PathBuf {
    std::env::var_os("HAPTICS_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(".venv/bin/python"))
}

/// True when the caller asked to skip the Python-generated fixtures.
pub fn skip_python() -> bool {
    std::env::var("HAPTICS_SKIP_PY").is_ok_and(|v| v == "1")
}

/// Returns the loaded runtime, or panics with the message that says what to run.
pub fn runtime() -> &'static Runtime {
    match Runtime::init(None) {
        Ok(rt) => rt,
        Err(e) => panic!("{e}"),
    }
}

/// Runs a Python generator script once per test binary into `dir` (under target/).
pub fn generate(script: &Path, dir: &Path, extra: &[&str]) {
    let py = python();
    assert!(
        py.exists(),
        "the tests build their ONNX models with the project's Python venv, and {} does not exist. \
         Run `bash scripts/setup.sh` from the repository root (or set HAPTICS_SKIP_PY=1 to skip \
         these tests explicitly).",
        py.display()
    );
    std::fs::create_dir_all(dir).expect("create fixture dir");
    let out = Command::new(&py)
        .arg(script)
        .arg(dir)
        .args(extra)
        .output()
        .expect("run the fixture generator");
    assert!(
        out.status.success(),
        "{} {} failed:\n{}\n{}",
        py.display(),
        script.display(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The fixture directory, generated on first use. `None` only when HAPTICS_SKIP_PY=1: the
/// calling test is then recorded as skipped (or fails under `CI=true`) and must return.
pub fn fixtures() -> Option<&'static Path> {
    static DIR: OnceLock<Option<PathBuf>> = OnceLock::new();
    let dir = DIR
        .get_or_init(|| {
            if skip_python() {
                return None;
            }
            let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("infer-server-fixtures");
            let script =
                Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/make_models.py");
            generate(&script, &dir, &[]);
            Some(dir)
        })
        .as_deref();
    if dir.is_none() {
        skip::skip("HAPTICS_SKIP_PY=1: the test needs the Python-built fixture models");
    }
    dir
}

/// `fixtures()` joined with `name.onnx`, or return from the test when skipping (recorded).
#[macro_export]
macro_rules! model_or_skip {
    ($name:expr) => {
        match common::fixtures() {
            Some(dir) => dir.join(format!("{}.onnx", $name)),
            None => return,
        }
    };
}

/// A raw HTTP/1.1 GET: (status line, body).
pub fn http_get(addr: &str, path: &str, token: Option<&str>) -> (String, String) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(std::time::Duration::from_secs(5)))
        .unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{}\r\n",
        token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"))
    )
    .unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    (
        head.lines().next().unwrap_or("").to_string(),
        body.to_string(),
    )
}

/// One lockstep step of a loop with the standard nine features: `position_x` and `velocity`
/// set (the linear fixture's inputs), the rest zero; sends it and returns its answer (checked to
/// be this step's).
pub fn lockstep(
    lp: &mut haptics_proto::LoopSide,
    seq: u64,
    position_x: f64,
    velocity: f64,
) -> haptics_proto::ForceMsg {
    let mut values = [0.0; haptics_proto::MAX_FEATURES];
    (values[0], values[1]) = (position_x, velocity);
    let msg = haptics_proto::FeatureMsg {
        seq,
        timestamp_ns: 0,
        run_id: 1,
        flags: 0,
        len: 9,
        values,
    };
    lp.features_tx.try_send(msg).unwrap();
    let a = lp
        .forces_rx
        .recv_timeout(std::time::Duration::from_secs(10))
        .unwrap();
    assert_eq!(a.seq, seq, "answers in order, tagged with their step");
    a
}

/// A fresh segment named `name` (created here, as the loop would), its loop side parking on
/// answers, and the inference thread attached to it with its model hand-off: the set-up every
/// in-process inference-thread test starts from. Parking waits only (never busy-spin in tests:
/// two cores); the thread exits when the loop side is dropped.
pub fn parked_inference_thread(
    name: &shm_ring::SegmentName,
    config: &shm_ring::Config,
) -> (
    haptics_proto::LoopSide,
    infer_server::serving::handoff::Activator,
    infer_server::serving::inference_thread::InferenceThread,
) {
    use shm_ring::WaitStrategy;
    let mut lp = haptics_proto::Segment::create(name, config)
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Park);
    let (activator, taker) = infer_server::serving::handoff::channel();
    let thread = infer_server::serving::inference_thread::InferenceThread::spawn(
        infer_server::serving::inference_thread::InferenceConfig {
            segment: name.clone(),
            wait: WaitStrategy::Park,
            cpu: None,
            rt_priority: None,
            exit_when_loop_gone: true,
            keep_awake: false,
        },
        taker,
    )
    .unwrap();
    (lp, activator, thread)
}
