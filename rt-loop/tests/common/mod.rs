#![allow(dead_code)]
//! Shared helpers of the integration tests.

use rt_loop::config::{ExperimentKind, RunConfig};
use rt_loop::record::Row;
use std::path::PathBuf;

pub fn material() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../materials/sponge.toml"
    ))
}

/// A short abstraction run: `cycles` cycles at `rate` N/s from 2 N in steps of `step` N.
pub fn short_cfg(cycles: u32, rate: f64, step: f64) -> RunConfig {
    let mut c = RunConfig {
        material: material(),
        ..RunConfig::default()
    };
    c.ramp.ramp_rate = rate;
    c.ramp.cycles = cycles;
    c.ramp.f_max_start = 2.0;
    c.ramp.f_max_step = step;
    c.ramp.hold_zero_s = 0.5;
    c.ramp.hold_max_s = 0.3;
    c.ramp.final_hold_s = 0.5;
    c.experiment = ExperimentKind::Abstraction;
    c
}

/// Runs the loop in memory (lockstep, no recorder) and returns every row and how it stopped.
pub fn run_rows(cfg: &RunConfig) -> (Vec<Row>, rt_loop::control::rig::Stop) {
    let mut rig = rt_loop::run::build_rig(cfg, None).expect("rig");
    let mut rows = Vec::new();
    loop {
        match rig.step() {
            Ok(r) => rows.push(r),
            Err(s) => return (rows, s),
        }
    }
}

/// RMS of the force controller's tracking error (RFOB force against F_ref) over the ramps
/// (phases 1 and 3) of an abstraction run.
pub fn ramp_tracking_rms(rows: &[Row]) -> f64 {
    let ramps: Vec<_> = rows
        .iter()
        .filter(|r| r.phase == 1 || r.phase == 3)
        .collect();
    (ramps
        .iter()
        .map(|r| (r.rtob_force - r.f_ref).powi(2))
        .sum::<f64>()
        / ramps.len() as f64)
        .sqrt()
}

/// A test's own folder under the system's temp dir, removed when the test passes and kept when
/// it fails (a panicking thread), so a failure leaves its recordings to look at while a passing
/// run leaves nothing behind (each run's recordings are tens of MB).
pub struct TestDir(PathBuf);

impl std::ops::Deref for TestDir {
    type Target = PathBuf;
    fn deref(&self) -> &PathBuf {
        &self.0
    }
}

impl AsRef<std::path::Path> for TestDir {
    fn as_ref(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for TestDir {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

pub fn tmpdir(name: &str) -> TestDir {
    let d = std::env::temp_dir().join(format!("rt-loop-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    TestDir(d)
}

/// Bitwise equality of rows (NaN == NaN when the bits match).
pub fn rows_identical(a: &[Row], b: &[Row]) -> bool {
    let bits = |r: &Row| {
        [
            r.time,
            r.dt,
            r.f_ref,
            r.rtob_force,
            r.dob_force,
            r.position_x,
            r.velocity,
            r.acceleration,
            r.i_a_ref,
            r.i_motor,
            r.f_true,
            r.f_pred,
            r.f_previous_x,
            r.f_previous_v,
            r.f_previous_a,
            r.deformation,
            r.area_fx,
            r.f_object,
        ]
        .map(f64::to_bits)
    };
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            bits(x) == bits(y)
                && (
                    x.step,
                    x.timestamp,
                    x.counts,
                    x.analog_out_motor,
                    x.phase,
                    x.fallback,
                    x.cycle_no,
                ) == (
                    y.step,
                    y.timestamp,
                    y.counts,
                    y.analog_out_motor,
                    y.phase,
                    y.fallback,
                    y.cycle_no,
                )
        })
}
