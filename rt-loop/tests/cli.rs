//! The command line as other engineers call it: `rt-loop run ...` and `rt-loop features ...`.

mod common;

use rt_loop::record::read::{read_columns, read_metadata};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_rt-loop"))
}

#[test]
fn run_records_with_the_documented_flags_and_a_config_file() {
    let dir = common::tmpdir("cli-run");
    let cfgfile = dir.join("c.toml");
    std::fs::write(
        &cfgfile,
        "[ramp]\nhold_zero_s = 0.2\nhold_max_s = 0.2\nfinal_hold_s = 0.2\n[params]\nk_p = 2.5\n",
    )
    .unwrap();
    let out = dir.join("r.csv");
    let o = bin()
        .args([
            "run",
            "--experiment",
            "abstraction",
            "--clock",
            "lockstep",
            "--rate-hz",
            "10000",
        ])
        .args([
            "--seed",
            "3",
            "--ramp-rate",
            "6",
            "--cycles",
            "2",
            "--f-max-start",
            "1",
        ])
        .args(["--f-max-step", "2", "--format", "csv", "--no-progress"])
        .arg("--material")
        .arg(common::material())
        .arg("--config")
        .arg(&cfgfile)
        .arg("--record")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("stop: finished") && err.contains("0 dropped"),
        "{err}"
    );
    let meta: serde_json::Value =
        serde_json::from_str(&read_metadata(&out).unwrap().unwrap()).unwrap();
    assert_eq!(meta["seed"], 3);
    assert_eq!(meta["config"]["params"]["k_p"], 2.5);
    assert_eq!(meta["f_max_schedule"], serde_json::json!([1.0, 3.0]));
    let c = read_columns(&out, &["F_ref"]).unwrap();
    let peak = c[0].iter().cloned().fold(0.0, f64::max);
    assert!((peak - 3.0).abs() < 1e-9);
}

#[test]
fn bad_input_gets_a_clear_error() {
    let o = bin()
        .args(["run", "--ramp-rate=-1", "--no-progress"])
        .arg("--material")
        .arg(common::material())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("ramp rate must be > 0"));
    let o = bin()
        .args(["run", "--material", "/nonexistent.toml", "--no-progress"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot read material file"));
}

/// `--friction-sweep` records the bench's friction alone: the probe stays out of contact
/// (x < 0 but for the approach's few encoder counts), the object's force is zero there, and
/// what the RFOB reads while sliding is the friction, opposing the motion. Mixed with a
/// trajectory or another experiment it is a clear error.
#[test]
fn friction_sweep_records_the_bench_out_of_contact() {
    // `rt-loop run ARGS --no-progress` on the test material
    let run = |args: &[&str]| {
        bin()
            .arg("run")
            .args(args)
            .arg("--no-progress")
            .arg("--material")
            .arg(common::material())
            .output()
            .unwrap()
    };
    let dir = common::tmpdir("cli-friction-sweep");
    let out = dir.join("air.parquet");
    let o = run(&[
        "--friction-sweep",
        "--decimate",
        "10",
        "--record",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("position-replay") && err.contains("stop: finished"),
        "{err}"
    );
    let meta: serde_json::Value =
        serde_json::from_str(&read_metadata(&out).unwrap().unwrap()).unwrap();
    assert_eq!(meta["config"]["friction_sweep"], true);
    let c = read_columns(&out, &["position_x", "velocity", "rtob_force", "F_object"]).unwrap();
    let (x, v, f, obj) = (&c[0], &c[1], &c[2], &c[3]);
    let t_end = x.len() as f64 * 10.0 / 10_000.0;
    assert!(t_end > 60.0, "{t_end} s");
    assert!(x.iter().all(|&x| x < 0.001), "the probe pressed the object");
    let deep = x.iter().filter(|&&x| x < -0.004 + 1e-4).count();
    assert!(deep > x.len() / 2, "{deep} of {} rows in free air", x.len());
    // out of contact the object pushes nothing
    let touching: f64 = x
        .iter()
        .zip(obj)
        .filter(|(&x, _)| x < -0.001)
        .map(|(_, &o)| o.abs())
        .fold(0.0, f64::max);
    assert_eq!(touching, 0.0);
    // sliding, the RFOB reads the force that overcomes the friction: along the motion (the
    // motor pushes the probe along v against the friction, the object adds nothing)
    let sliding: Vec<(f64, f64)> = v
        .iter()
        .zip(f)
        .filter(|(&v, _)| v.abs() > 2e-3)
        .map(|(&v, &f)| (v, f))
        .collect();
    assert!(sliding.len() > 1000, "{}", sliding.len());
    let along = sliding.iter().map(|&(v, f)| f * v.signum()).sum::<f64>() / sliding.len() as f64;
    assert!(
        along > 0.3 && along < 3.0,
        "mean friction along v {along} N"
    );

    let o = run(&["--friction-sweep", "--experiment", "abstraction"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--friction-sweep is a position replay"));
    let o = run(&["--friction-sweep", "--trajectory", "x.parquet"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("give it no --trajectory"));
}

/// A series measured elsewhere (ms, mm, N, other column names) becomes a recording whose
/// kinematics and features are those the loop computes for the same series.
#[test]
fn features_imports_a_foreign_series() {
    let dir = common::tmpdir("cli-features");
    let input = dir.join("measured.csv");
    let mut s = String::from("t_ms,depth_mm,force\n");
    let mut t = vec![];
    let mut x = vec![];
    let mut f = vec![];
    for i in 0..20_000 {
        let tm = i as f64 * 0.5; // 2 kHz
        let w = tm / 1000.0 * 0.5 * std::f64::consts::TAU;
        let depth = 10.0 * w.sin().max(0.0); // mm, press-release cycles
                                             // loading above unloading: a hysteretic loop
        let force = if depth > 0.0 {
            0.6 * depth + 0.5 * w.cos()
        } else {
            0.0
        };
        s += &format!("{tm},{depth},{force}\n");
        t.push(tm * 1e-3); // the importer scales by multiplication
        x.push(depth * 1e-3);
        f.push(force);
    }
    std::fs::write(&input, s).unwrap();
    let out = dir.join("imported.parquet");
    let o = bin()
        .args([
            "features",
            "--time-col",
            "t_ms",
            "--position-col",
            "depth_mm",
        ])
        .args([
            "--force-col",
            "force",
            "--time-unit",
            "ms",
            "--position-unit",
            "mm",
        ])
        .args(["--force-unit", "N"])
        .arg("--input")
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let c = read_columns(
        &out,
        &[
            "time",
            "position_x",
            "rtob_force",
            "velocity",
            "cycle_no",
            "area_fx",
            "F_ref",
        ],
    )
    .unwrap();
    assert_eq!(c[0].len(), 20_000);
    assert!((c[0][19_999] - 9.9995).abs() < 1e-9);
    assert!((c[1][400] - x[400]).abs() < 1e-15);
    assert!(
        c[6].iter().all(|v| v.is_nan()),
        "no command in an imported series"
    );
    let spec = rt_loop::import::ImportSpec {
        input: input.clone(),
        time_col: String::new(),
        position_col: String::new(),
        force_col: String::new(),
        time_unit: rt_loop::import::TimeUnit::S,
        position_unit: rt_loop::import::PositionUnit::M,
        force_unit: rt_loop::import::ForceUnit::N,
        out: out.clone(),
        g_v: 30.0,
        g_a: 100.0,
        meters_per_count: 5e-6,
        // the command derives the contact thresholds from the force's noise floor
        features: rt_loop::features::FeatureParams::from_force(&f).0,
    };
    let rows = rt_loop::import::rows_from_series(&t, &x, &f, &spec).unwrap();
    for i in 0..rows.len() {
        assert_eq!(rows[i].velocity.to_bits(), c[3][i].to_bits());
        assert_eq!(rows[i].area_fx.to_bits(), c[5][i].to_bits());
    }
    let cycles = c[4].iter().cloned().fold(0.0, f64::max);
    assert!(cycles >= 5.0, "press-release cycles segmented: {cycles}");
    assert!(c[5].iter().any(|&a| a > 0.0), "a hysteretic loop has area");

    // a missing column is a clear error
    let o = bin()
        .args([
            "features",
            "--time-col",
            "nope",
            "--position-col",
            "depth_mm",
        ])
        .args(["--force-col", "force"])
        .arg("--input")
        .arg(&input)
        .arg("--out")
        .arg(dir.join("x.parquet"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no column \"nope\""));
}

/// SIGINT during a realtime run: the loop stops at its next step with 0 A, the recording is
/// complete (renamed, every step written) and the exit code says success.
#[test]
fn sigint_stops_cleanly_with_a_complete_recording() {
    let dir = common::tmpdir("cli-sigint");
    let out = dir.join("rt.parquet");
    let cfgfile = dir.join("c.toml");
    std::fs::write(
        &cfgfile,
        "[realtime]\npriority = 0\nlock_memory = false\ncpu = -1\n[params]\nwatchdog_us = 5000000\n",
    )
    .unwrap();
    let child = bin()
        .args([
            "run",
            "--clock",
            "realtime",
            "--no-progress",
            "--duration",
            "60",
        ])
        .arg("--material")
        .arg(common::material())
        .arg("--config")
        .arg(&cfgfile)
        .arg("--record")
        .arg(&out)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // the partial file appears once the handlers are installed and the run is starting
    let partial = rt_loop::record::partial_path(&out);
    let t = std::time::Instant::now();
    while !partial.exists() && t.elapsed().as_secs() < 30 {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    // SAFETY: signalling our own child.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) };
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("stop: interrupted"), "{err}");
    let steps = read_columns(&out, &["step"]).unwrap()[0].len();
    assert!(steps > 0, "{steps} rows");
    assert!(!partial.exists(), "renamed to its final name");
    assert!(err.contains(&format!("{steps} written")), "{err}");
}

#[test]
fn default_material_is_found_from_any_working_directory() {
    // The default `materials/sponge.toml` is relative; run from a directory that has none, as
    // train/'s tests and the study do, and it is found from the executable's location.
    let dir = std::env::temp_dir().join(format!("rt-loop-cwd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = bin()
        .current_dir(&dir)
        .args(["run", "--experiment", "shadow", "--clock", "lockstep"])
        .args(["--duration", "0.05", "--no-progress"])
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// An object too soft to carry F_max within the travel (a Bouc-Wen pad at an eighth of the
/// repository's stiffness, no cubic term: about 5 N at 50 mm): the ramps turn round at
/// 0.8 of the position limit instead of running the probe into it, the run finishes, the
/// summary counts the turns, and the probe never reaches the limit.
#[test]
fn ramps_turn_round_on_an_object_too_soft_for_f_max() {
    let dir = common::tmpdir("cli-soft");
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../materials/bouc-wen.toml"
    ))
    .unwrap()
    .replace("stiffness_n_per_m = 800.0", "stiffness_n_per_m = 100.0")
    .replace("cubic_n_per_m3 = 1.0e6", "cubic_n_per_m3 = 0.0");
    let material = dir.join("soft.toml");
    std::fs::write(&material, text).unwrap();
    let out = dir.join("r.csv");
    let run = |extra: &[&str]| {
        bin()
            .args([
                "run",
                "--clock",
                "lockstep",
                "--rate-hz",
                "10000",
                "--seed",
                "1",
            ])
            .args(["--ramp-rate", "8", "--cycles", "3", "--f-max-start", "3"])
            .args([
                "--f-max-step",
                "3",
                "--hold-zero",
                "0.3",
                "--hold-max",
                "0.3",
            ])
            .args(["--format", "csv", "--no-progress", "--overwrite"])
            .args(extra)
            .arg("--material")
            .arg(&material)
            .arg("--record")
            .arg(&out)
            .output()
            .unwrap()
    };
    let o = run(&[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("stop: finished"), "{err}");
    // 3 N stays shallow; 6 and 9 N would pass 40 mm: both turn, the third capped at the
    // force the second reached
    assert!(
        err.contains("rt-loop: ramps: 2 cycle(s) turned round at the depth bound 40.0 mm"),
        "{err}"
    );
    let c = read_columns(&out, &["position_x", "F_ref"]).unwrap();
    let deepest = c[0].iter().cloned().fold(f64::MIN, f64::max);
    // it went on past 40 mm (80 mm/s at the turn) but stopped short of the 50 mm limit
    assert!(deepest > 0.040 && deepest < 0.049, "deepest {deepest} m");
    let peak = c[1].iter().cloned().fold(0.0, f64::max);
    assert!(
        peak > 3.0 && peak < 6.0,
        "turned before 6 N: peak F_ref {peak}"
    );
    // the bound at the limit itself leaves the probe no room to stop: the run ends there
    let o = run(&["--turn-depth-frac", "1.0"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("stop: position-limit"),
        "{err}"
    );
    let o = run(&["--turn-depth-frac", "1.5"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("turn_depth_frac must be in (0, 1]"));
}
