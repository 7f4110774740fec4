//! The `infer-server` binary: `validate` (as train/'s tests call it), `predict`, and the missing
//! library message.

mod common;

use std::path::Path;
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_infer-server"))
}

fn json(out: &Output) -> serde_json::Value {
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"))
}

#[test]
fn validate_json_accepts_a_good_model() {
    let path = model_or_skip!("lstm");
    let out = bin()
        .args(["validate", "--json"])
        .arg(&path)
        .args(["--schema", "position_x,velocity,f_previous_x"])
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = json(&out);
    assert_eq!(v["ok"], true);
    assert_eq!(v["model"]["kind"], "stateful");
    assert_eq!(
        v["model"]["features"],
        serde_json::json!(["f_previous_x", "position_x"])
    );
    assert_eq!(v["model"]["input_map"], serde_json::json!([2, 0]));
    assert_eq!(v["model"]["state_shape"], serde_json::json!([1, 1, 3]));
    assert!(v["runtime"]["version"].as_str().unwrap().starts_with("1."));
    assert_eq!(v["model"]["reference_steps"], serde_json::Value::Null);
    // A model carrying reference steps: how many were checked, in JSON and in words.
    let path = model_or_skip!("lstm_reference");
    let out = bin()
        .args(["validate", "--json"])
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(json(&out)["model"]["reference_steps"], 12);
    let out = bin().arg("validate").arg(&path).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("reference: 12 steps computed as at its export"),
        "{text}"
    );
}

#[test]
fn validate_json_refuses_with_code_and_message() {
    let Some(dir) = common::fixtures() else {
        return;
    };
    for (name, schema, code) in [
        ("corrupt", None, "corrupt"),
        ("wrong_input", None, "wrong_inputs"),
        (
            "needs_deformation",
            Some("position_x,velocity"),
            "missing_feature",
        ),
        ("nan_output", None, "non_finite_output"),
        ("no_kind", None, "missing_metadata"),
        ("linear_reference_wrong", None, "reference_mismatch"),
        ("linear_reference_bad", None, "bad_metadata"),
    ] {
        let mut cmd = bin();
        cmd.args(["validate", "--json"])
            .arg(dir.join(format!("{name}.onnx")));
        if let Some(s) = schema {
            cmd.args(["--schema", s]);
        }
        let out = cmd.output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{name}");
        let v = json(&out);
        assert_eq!(v["ok"], false, "{name}");
        assert_eq!(v["error"]["code"], code, "{name}: {v}");
        assert!(!v["error"]["message"].as_str().unwrap().is_empty());
        // The human-readable reason also goes to stderr.
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("refused"),
            "{name}"
        );
    }
    // A bad schema argument is refused before any model is read.
    let out = bin()
        .args(["validate", "--json"])
        .arg(dir.join("linear.onnx"))
        .args(["--schema", "position_x,position_x"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(json(&out)["error"]["code"], "bad_schema");
}

#[test]
fn missing_library_says_what_to_run_and_exits_non_zero() {
    // Needs no fixture: the library is looked for before any model is opened.
    let out = bin()
        .args(["validate", "--json", "/nonexistent.onnx"])
        .env("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("bash scripts/setup.sh"), "{stderr}");
    assert!(
        stderr.contains("/nonexistent/libonnxruntime.so"),
        "{stderr}"
    );
    assert_eq!(json(&out)["error"]["code"], "runtime_missing");

    // --ort-lib wins over the environment.
    let out = bin()
        .args(["runtime", "--ort-lib", "/also/missing.so"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/also/missing.so"));

    // A file that is not ONNX Runtime is refused as such.
    let out = bin()
        .args(["runtime", "--ort-lib"])
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("could not load"));
}

#[test]
fn predict_steps_a_csv_in_order() {
    let path = model_or_skip!("linear");
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let csv = dir.join("predict-linear.csv");
    std::fs::write(&csv, "position_x,velocity\n0.2,0.7\n-1.5,3.25\n0,0\n").unwrap();
    let out = bin()
        .arg("predict")
        .arg(&path)
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let forces: Vec<f64> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| l.parse().unwrap())
        .collect();
    let want = [2.0 * 0.7 - 3.0 * 0.2 + 0.5, 2.0 * 3.25 + 4.5 + 0.5, 0.5];
    assert_eq!(forces.len(), 3);
    for (g, w) in forces.iter().zip(want) {
        assert!((g - w).abs() < 1e-5, "{g} vs {w}");
    }

    // A malformed row is refused with its line number.
    std::fs::write(&csv, "position_x,velocity\n0.2,0.7\n0.1,abc\n").unwrap();
    let out = bin()
        .arg("predict")
        .arg(&path)
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("line 3"));
}

#[test]
fn serve_answers_a_loop_over_shared_memory_and_exits_when_it_leaves() {
    use haptics_proto::Segment;
    use shm_ring::{SegmentName, WaitStrategy};
    use std::time::{Duration, Instant};

    let path = model_or_skip!("linear");
    let name = SegmentName::new(&format!("/infer-server-cli-{}", std::process::id())).unwrap();
    let mut lp = Segment::create(&name, &haptics_proto::layout::config())
        .unwrap()
        .loop_side()
        .unwrap();
    lp.forces_rx.set_wait_strategy(WaitStrategy::Park);
    let mut child = bin()
        .args([
            "serve",
            "--wait",
            "park",
            "--exit-when-loop-gone",
            "--stats-every",
            "0",
            "--grpc",
            "127.0.0.1:0",
            "--http",
            "127.0.0.1:0",
        ])
        .args(["--segment", name.as_str(), "--model"])
        .arg(&path)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while !lp.peer_alive() {
        assert!(Instant::now() < deadline, "the server did not attach");
        std::thread::sleep(Duration::from_millis(10));
    }
    let mut step = |seq: u64, x: f64, v: f64| common::lockstep(&mut lp, seq, x, v);
    // The model is activated right after the attach; until then answers say NO_MODEL.
    let mut seq = 0;
    loop {
        seq += 1;
        let a = step(seq, 0.0, 0.0);
        if a.flags == 0 {
            assert!((a.force - 0.5).abs() < 1e-6);
            break;
        }
        assert!(a.force.is_nan());
        assert!(Instant::now() < deadline, "no model became active");
        std::thread::sleep(Duration::from_millis(5));
    }
    for i in 0..1000 {
        seq += 1;
        let (x, v) = (i as f64 * 1e-4, (i as f64 * 0.1).cos());
        let a = step(seq, x, v);
        assert_eq!(a.flags, 0);
        let want = 2.0 * v - 3.0 * x + 0.5;
        assert!((a.force - want).abs() < 1e-5, "{} vs {want}", a.force);
    }
    drop(lp);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline + Duration::from_secs(10) {
            child.kill().unwrap();
            panic!("serve did not exit after the loop left");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut stderr = String::new();
    use std::io::Read;
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    assert!(status.success(), "{status}: {stderr}");
    assert!(
        stderr.contains("linear.onnx active (model id 1)"),
        "{stderr}"
    );
    assert!(stderr.contains(&format!("answered {seq}")), "{stderr}");
}

#[test]
fn keep_awake_without_a_pinned_cpu_is_a_usage_error() {
    // The shared profile pins nothing: a spinner kept on "some CPU" would keep none awake.
    let out = bin()
        .args(["serve", "--profile", "shared", "--keep-awake", "on"])
        .args(["--segment", "/infer-server-cli-keep-awake-never-created"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--keep-awake on needs a pinned CPU"), "{err}");
}
