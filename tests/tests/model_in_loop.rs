//! Issue 4 end to end: the real `rt-loop` and `infer-server` processes over real shared memory.
//!
//! - reproduction in lockstep against the simulated hand with a served ONNX model: every step
//!   answered, zero fallbacks, and the forces the loop rendered are exactly what ONNX Runtime
//!   (`infer-server predict`, the same library through another path) computes for the
//!   recorded features;
//! - the server SIGKILLed mid-run: the loop finishes safely on the fallback, the count is
//!   reported; a new server attaches and model rendering resumes.
//!
//! Needs the release binaries (`cargo build --release`; `cargo test --workspace --release`
//! builds them) and the project's `.venv` (`bash scripts/setup.sh`).

use haptics_system_tests::{
    bin, instance, shm_entries, start_infer_server, temp_dir, write_linear_model, CsvTable, Proc,
};
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// The loop's schema: the nine of docs/recording-format.md and `f_previous` = F(t-1).
const SCHEMA: [&str; 10] = haptics_proto::SCHEMA_NAMES;

/// A spring-damper-like linear model over all ten schema features (weights on the ratio
/// features zero: F/x, F/v and F/a explode near zero depth, velocity and acceleration; all ten
/// still go through the model; 0.1 F(t-1) makes the loop's own previous force matter).
fn write_spring_model(dir: &Path) {
    write_linear_model(
        &dir.join("spring.onnx"),
        &SCHEMA,
        &[400.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.05, 10.0, 1.0, 0.1],
        0.02,
    );
}

fn summary(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("summary json")).expect("json")
}

#[test]
fn lockstep_reproduction_renders_exactly_what_onnx_runtime_computes() {
    let dir = temp_dir("e2e-repro");
    write_spring_model(&dir);
    let inst = instance("repro");
    let (mut server, _addr) = start_infer_server(&inst, &dir, Some("spring.onnx"));
    let rec = dir.join("repro.csv");
    let sum = dir.join("summary.json");
    let mut lp = Proc::spawn(
        "rt-loop",
        Command::new(bin("rt-loop"))
            .args(["run", "--experiment", "reproduction", "--clock", "lockstep"])
            .args([
                "--model",
                "shm",
                "--instance",
                &inst,
                "--server-wait-s",
                "60",
            ])
            .args(["--no-progress", "--record"])
            .arg(&rec)
            .arg("--summary-json")
            .arg(&sum),
    );
    let st = lp.wait_exit(Duration::from_secs(300));
    let out = lp.output();
    assert!(st.success(), "rt-loop failed ({st}):\n{out}");
    let s = summary(&sum);
    let steps = s["steps"].as_u64().unwrap();
    assert!(steps > 100_000, "a full reproduction run: {steps} steps");
    assert_eq!(s["stop"], "finished", "{out}");
    assert_eq!(s["model"]["fallbacks"], 0, "zero fallbacks:\n{out}");
    assert_eq!(s["model"]["served"].as_u64(), Some(steps));
    assert_eq!(s["shm"]["answered"].as_u64(), Some(steps), "{out}");
    assert_eq!(s["shm"]["sent"].as_u64(), Some(steps));
    assert_eq!(s["shm"]["late"], 0);
    assert!(out.contains("0 fallbacks"), "the count is reported:\n{out}");

    let t = CsvTable::read(&rec);
    assert_eq!(t.len() as u64, steps);
    assert!(t.bools("fallback").iter().all(|f| !f), "no step fell back");
    let f_pred = t.f64s("F_pred");
    let f_ref = t.f64s("F_ref");
    for (i, (p, r)) in f_pred.iter().zip(&f_ref).enumerate() {
        assert!(p.is_finite(), "step {i}: F_pred {p}");
        assert_eq!(*r, -p, "step {i}: the loop commands -F_pred");
    }
    let max = f_pred.iter().cloned().fold(f64::MIN, f64::max);
    assert!(
        max > 3.0,
        "the hand pressed into the virtual spring: max F_pred {max} N"
    );

    // The recorded features through ONNX Runtime by another path (infer-server predict).
    // f_previous is not a recorded column: in reproduction it is the previous step's F_pred
    // (the force the loop committed), 0 on the first step.
    let feats = dir.join("features.csv");
    let cols: Vec<Vec<&str>> = SCHEMA[..9].iter().map(|n| t.col(n)).collect();
    let pred_text = t.col("F_pred");
    let mut csv = SCHEMA.join(",");
    csv.push('\n');
    for i in 0..t.len() {
        for c in &cols {
            csv.push_str(c[i]);
            csv.push(',');
        }
        csv.push_str(if i == 0 { "0" } else { pred_text[i - 1] });
        csv.push('\n');
    }
    std::fs::write(&feats, csv).unwrap();
    let p = Command::new(bin("infer-server"))
        .arg("predict")
        .arg(dir.join("spring.onnx"))
        .arg("--csv")
        .arg(&feats)
        .current_dir(haptics_system_tests::repo_root())
        .output()
        .expect("infer-server predict");
    assert!(
        p.status.success(),
        "predict: {}",
        String::from_utf8_lossy(&p.stderr)
    );
    let expected: Vec<f32> = String::from_utf8_lossy(&p.stdout)
        .lines()
        .map(|l| l.trim().parse().expect("a force per line"))
        .collect();
    assert_eq!(expected.len(), f_pred.len());
    // Unilateral rendering (issue 11 item 7): the loop renders ONNX Runtime's force clamped
    // to [0, max_force_n], and 0 out of contact (x <= 0).
    let xs = t.f64s("position_x");
    let mut differ = 0;
    let mut clamped = 0;
    for (i, (e, got)) in expected.iter().zip(&f_pred).enumerate() {
        let want = if xs[i] <= 0.0 {
            0.0
        } else {
            (*e as f64).clamp(0.0, 20.0)
        };
        clamped += (want != *e as f64) as usize;
        if want != *got {
            differ += 1;
            assert!(differ > 5, "step {i}: rendered {got}, ONNX Runtime {e}");
        }
    }
    assert_eq!(
        differ, 0,
        "every rendered force equals ONNX Runtime's, clamped"
    );
    eprintln!(
        "{clamped} of {} steps clamped (out of contact or pulling)",
        f_pred.len()
    );

    // lockstep waits for every answer: a second run against the same server is identical
    let rec2 = dir.join("repro2.csv");
    let mut lp2 = Proc::spawn(
        "rt-loop (second run)",
        Command::new(bin("rt-loop"))
            .args(["run", "--experiment", "reproduction", "--clock", "lockstep"])
            .args([
                "--model",
                "shm",
                "--instance",
                &inst,
                "--server-wait-s",
                "60",
            ])
            .args(["--no-progress", "--record"])
            .arg(&rec2),
    );
    let st = lp2.wait_exit(Duration::from_secs(300));
    assert!(st.success(), "second run: {}", lp2.output());
    assert!(
        std::fs::read(&rec).unwrap() == std::fs::read(&rec2).unwrap(),
        "two lockstep runs with the served model gave different recordings"
    );

    // Stopped as a user stops it (Ctrl-C): a clean exit removes its connection file, which a
    // SIGKILL would leave behind in the runtime directory.
    server.signal(libc::SIGINT);
    let _ = server.wait_exit(Duration::from_secs(10));
    assert!(
        shm_entries(&inst).is_empty(),
        "segment removed: {:?}",
        shm_entries(&inst)
    );
}

#[test]
fn server_killed_mid_run_loop_finishes_on_fallback_and_resumes_with_a_new_server() {
    let dir = temp_dir("e2e-kill");
    write_spring_model(&dir);
    // A long lockstep run (10 presses of 5 s) so the kill and the restart land inside it.
    let cfg = dir.join("long.toml");
    std::fs::write(&cfg, "[hand]\nrepeats = 10\ndepth_step_m = 0.0\n").unwrap();
    let inst = instance("kill");
    let (mut server, _) = start_infer_server(&inst, &dir, Some("spring.onnx"));
    let rec = dir.join("kill.csv");
    let sum = dir.join("summary.json");
    let mut lp = Proc::spawn(
        "rt-loop",
        Command::new(bin("rt-loop"))
            .args(["run", "--experiment", "reproduction", "--clock", "lockstep"])
            .arg("--config")
            .arg(&cfg)
            .args([
                "--model",
                "shm",
                "--instance",
                &inst,
                "--server-wait-s",
                "60",
            ])
            .args(["--no-progress", "--record"])
            .arg(&rec)
            .arg("--summary-json")
            .arg(&sum),
    );
    lp.wait_for("infer-server attached", Duration::from_secs(60));
    std::thread::sleep(Duration::from_millis(400));
    server.signal(libc::SIGKILL);
    server.wait_exit(Duration::from_secs(10));
    std::thread::sleep(Duration::from_millis(300));
    let (mut server2, _) = start_infer_server(&inst, &dir, Some("spring.onnx"));
    let st = lp.wait_exit(Duration::from_secs(300));
    let out = lp.output();
    assert!(st.success(), "rt-loop must finish safely ({st}):\n{out}");
    let s = summary(&sum);
    assert_eq!(s["stop"], "finished", "{out}");
    let steps = s["steps"].as_u64().unwrap();
    let fallbacks = s["model"]["fallbacks"].as_u64().unwrap();
    let served = s["model"]["served"].as_u64().unwrap();
    assert_eq!(served + fallbacks, steps);
    assert!(
        fallbacks > 0,
        "the steps without a server fell back:\n{out}"
    );
    assert!(
        out.contains(&format!("{fallbacks} fallbacks")),
        "count reported:\n{out}"
    );
    assert!(
        s["shm"]["server_lost"].as_u64().unwrap() >= 1,
        "{}",
        s["shm"]
    );
    assert!(
        s["shm"]["attachments_seen"].as_u64().unwrap() >= 1,
        "{}",
        s["shm"]
    );

    println!(
        "kill test: {steps} steps, {served} served, {fallbacks} fallbacks, shm {}",
        s["shm"]
    );
    let t = CsvTable::read(&rec);
    let fb = t.bools("fallback");
    let first_fb = fb.iter().position(|&f| f).expect("a fallback step");
    let last_fb = fb.iter().rposition(|&f| f).unwrap();
    assert!(
        first_fb > 1000,
        "served before the kill (first fallback at {first_fb})"
    );
    assert!(
        last_fb + 1000 < fb.len(),
        "model rendering resumed with the new server (last fallback at {last_fb} of {})",
        fb.len()
    );
    assert!(
        fb[first_fb..=last_fb].iter().all(|&f| f),
        "one outage: every step between the kill and the new server fell back"
    );
    // The fallback steps render the spring-damper, finite and within the force limit.
    let f_pred = t.f64s("F_pred");
    assert!(f_pred.iter().all(|f| f.is_finite() && f.abs() <= 20.0));
    let i_motor = t.f64s("I_motor");
    assert!(i_motor.iter().all(|i| i.abs() <= 0.59 + 1e-12));

    server2.signal(libc::SIGINT);
    let _ = server2.wait_exit(Duration::from_secs(10));
    assert!(shm_entries(&inst).is_empty(), "{:?}", shm_entries(&inst));
}
