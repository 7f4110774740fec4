//! Issue 20 item 5 end to end: a deliberately ACTIVE model (negative damping: its force leads
//! the motion) exported as ONNX with the model contract's metadata, served by the real
//! infer-server to the real rt-loop over shared memory, against the simulated hand (an
//! impedance: stiffness and damping toward its moving set-point, rt-loop/src/experiment/hand.rs).
//!
//! - passivity layer off: the object gives the hand more energy than it received and the
//!   motion oscillates with a growing amplitude;
//! - layer on: the energy the object returned is at most what it received (at every step, up
//!   to one step's work) and the motion stays bounded.
//!
//! The energies are computed here from the recording (the rendered force F = -F_ref held over
//! each period times the encoder's displacement), independently of the layer's own observer,
//! and compared with what the layer reported in the run's summary.
//!
//! Needs the release binaries and the project's `.venv` (onnx), like the other system tests.

use haptics_system_tests::{
    bin, instance, start_infer_server, temp_dir, write_linear_model, CsvTable, Proc,
};
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// The active model: F = K x - B v over `position_x` and `velocity` (N/m, N s/m). -B v is a
/// negative damper: the force is lower while the hand presses in and higher while it lets go,
/// so each oscillation feeds the hand energy. B exceeds the hand's own damping (15 N s/m).
pub const K: f32 = 300.0;
pub const B: f32 = 100.0;
/// Encoder resolution of the simulated bench, m/count.
const M_PER_COUNT: f64 = 5e-6;

pub fn write_active_model(dir: &Path) -> std::path::PathBuf {
    let p = dir.join("active.onnx");
    write_linear_model(&p, &["position_x", "velocity"], &[K, -B], 0.0);
    p
}

/// What a run's recording says about the object's port and the motion.
#[derive(Debug)]
struct Energy {
    /// Net energy into the object (received - returned) after each step, J.
    net: Vec<f64>,
    received: f64,
    returned: f64,
    /// Peak |v| in each 0.25 s window of the recording, m/s.
    v_peaks: Vec<f64>,
    x_max: f64,
}

fn energy(t: &CsvTable) -> Energy {
    let f: Vec<f64> = t.f64s("F_ref").iter().map(|f| -f).collect();
    let x: Vec<f64> = t.f64s("counts").iter().map(|c| c * M_PER_COUNT).collect();
    let v = t.f64s("velocity");
    let (mut net, mut received, mut returned) = (Vec::with_capacity(x.len()), 0.0, 0.0);
    let mut e = 0.0;
    for k in 0..x.len().saturating_sub(1) {
        let dw = if f[k].is_finite() {
            f[k] * (x[k + 1] - x[k])
        } else {
            0.0
        };
        if dw > 0.0 {
            received += dw;
        } else {
            returned -= dw;
        }
        e += dw;
        net.push(e);
    }
    let v_peaks = v
        .chunks(2500)
        .map(|c| c.iter().fold(0.0f64, |m, v| m.max(v.abs())))
        .collect();
    Energy {
        net,
        received,
        returned,
        v_peaks,
        x_max: x.iter().cloned().fold(f64::MIN, f64::max),
    }
}

fn run(inst: &str, dir: &Path, cfg: &Path, layer: &str) -> (CsvTable, serde_json::Value, String) {
    let rec = dir.join(format!("active-{layer}.csv"));
    let sum = dir.join(format!("active-{layer}.json"));
    let mut lp = Proc::spawn(
        "rt-loop",
        Command::new(bin("rt-loop"))
            .args(["run", "--experiment", "reproduction", "--clock", "lockstep"])
            .arg("--config")
            .arg(cfg)
            .args([
                "--model",
                "shm",
                "--instance",
                inst,
                "--server-wait-s",
                "60",
            ])
            .args(["--passivity", layer, "--no-progress", "--record"])
            .arg(&rec)
            .arg("--summary-json")
            .arg(&sum),
    );
    let st = lp.wait_exit(Duration::from_secs(300));
    let out = lp.output();
    let s: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&sum)
            .unwrap_or_else(|e| panic!("rt-loop ({st}) wrote no summary ({e}):\n{out}")),
    )
    .expect("summary json");
    (CsvTable::read(&rec), s, out)
}

#[test]
fn an_active_model_gains_the_hand_energy_without_the_layer_and_none_with_it() {
    let dir = temp_dir("passivity");
    write_active_model(&dir);
    // one press of the default hand (rest 1 s, press 1.5 s, hold 1 s, release 1.5 s, rest 1 s)
    let cfg = dir.join("one-press.toml");
    std::fs::write(&cfg, "[hand]\nrepeats = 1\n").unwrap();
    let inst = instance("passivity");
    let (_server, _) = start_infer_server(&inst, &dir, Some("active.onnx"));

    let (off_t, off_s, off_out) = run(&inst, &dir, &cfg, "off");
    let off = energy(&off_t);
    let (on_t, on_s, on_out) = run(&inst, &dir, &cfg, "on");
    let on = energy(&on_t);
    let min = |e: &Energy| e.net.iter().cloned().fold(f64::MAX, f64::min);
    let peak_growth = |e: &Energy| {
        // the largest ratio of a window's peak speed to an earlier window's (from the first
        // window with motion), the signature of a growing oscillation
        let first = e.v_peaks.iter().position(|p| *p > 1e-3).unwrap_or(0);
        let mut best: f64 = 0.0;
        for i in first..e.v_peaks.len() {
            for j in i + 1..e.v_peaks.len() {
                best = best.max(e.v_peaks[j] / e.v_peaks[i].max(1e-6));
            }
        }
        best
    };
    eprintln!(
        "layer off: received {:.4} J, returned {:.4} J, lowest net {:.4} J, x max {:.4} m, stop {}, window peak |v| {:?}",
        off.received, off.returned, min(&off), off.x_max, off_s["stop"], off.v_peaks
    );
    eprintln!(
        "layer on:  received {:.4} J, returned {:.4} J, lowest net {:.4} J, x max {:.4} m, stop {}, window peak |v| {:?}",
        on.received, on.returned, min(&on), on.x_max, on_s["stop"], on.v_peaks
    );
    eprintln!(
        "summary off: {}\nsummary on: {}",
        off_s["passivity"], on_s["passivity"]
    );

    // Layer off: the active object gives back more than it took (the hand gains energy), and
    // the oscillation grows.
    assert_eq!(off_s["passivity"]["enabled"], false, "{off_out}");
    assert!(
        off.returned > off.received + 0.05,
        "the active model must return more energy than it receives without the layer: {off:?}"
    );
    assert!(
        min(&off) < -0.05,
        "net energy into the object goes negative: {}",
        min(&off)
    );
    assert!(
        peak_growth(&off) > 3.0,
        "a growing oscillation: {:?}",
        off.v_peaks
    );

    // Layer on: never more out than in (up to one step's work at the largest force), bounded.
    assert_eq!(on_s["passivity"]["enabled"], true, "{on_out}");
    assert_eq!(on_s["stop"], "finished", "{on_out}");
    assert!(on_s["passivity"]["active_steps"].as_u64().unwrap() > 0);
    // Sampled data: the force of step k is chosen before the displacement of period k is
    // known, so the observer can only pay a deficit after it happened: up to one step's work
    // (a few N over a few encoder counts: 1e-4 J is 10 N over 10 um) may stay unpaid. In
    // realtime on a loaded machine a late step spans several periods' displacement (seen:
    // -1.03e-4 J under a parallel build), so the bound is three such steps: still 4000 times
    // less than the -1.3 J the same run loses with the layer off.
    let one_step: f64 = 3e-4;
    assert!(
        on.returned <= on.received + one_step,
        "returned {} J > received {} J with the layer on",
        on.returned,
        on.received
    );
    assert!(min(&on) > -one_step, "lowest net {} J", min(&on));
    assert!(on.x_max < 0.04, "bounded motion: x max {} m", on.x_max);
    let quiet = on.v_peaks[on.v_peaks.len() - 4..]
        .iter()
        .cloned()
        .fold(0.0, f64::max);
    assert!(quiet < 0.02, "at rest at the end: {:?}", on.v_peaks);
    // the layer's own observer agrees with the recording's energies
    let rec_in = on_s["passivity"]["received_j"].as_f64().unwrap();
    assert!(
        (rec_in - on.received).abs() < 0.02 * on.received.max(0.01),
        "observer {rec_in} J vs recording {} J",
        on.received
    );
}
