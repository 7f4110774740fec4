//! `rt-loop features`: imports a time/displacement/force series measured elsewhere and writes
//! it in the recording format, with velocity and acceleration from the loop's pseudo-derivative
//! filters and the nine features from the very same feature code the loop runs.
//!
//! Columns with no source: F_ref, dob_force, I_a_ref, I_motor, F_true, F_pred are NaN;
//! analog_out_motor is 32768 (0 A), phase 0, fallback false. `rtob_force` is the imported
//! force, `counts` the position rounded to encoder counts, `timestamp` the time in
//! microseconds wrapped to 32 bits like a board counter.

use crate::features::{compute_offline, FeatureParams};
use crate::record::{Format, RecorderHandle, Row, Target};
use anyhow::{bail, Result};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum TimeUnit {
    S,
    Ms,
    Us,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum PositionUnit {
    M,
    Mm,
    Um,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum ForceUnit {
    #[value(name = "N")]
    N,
    #[value(name = "mN")]
    MilliN,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ImportSpec {
    pub input: PathBuf,
    pub time_col: String,
    pub position_col: String,
    pub force_col: String,
    pub time_unit: TimeUnit,
    pub position_unit: PositionUnit,
    pub force_unit: ForceUnit,
    pub out: PathBuf,
    pub g_v: f64,
    pub g_a: f64,
    pub meters_per_count: f64,
    pub features: FeatureParams,
}

/// Builds the recording rows of an imported series (exposed for tests).
pub fn rows_from_series(
    t_s: &[f64],
    x_m: &[f64],
    f_n: &[f64],
    spec: &ImportSpec,
) -> Result<Vec<Row>> {
    let n = t_s.len();
    if n == 0 {
        bail!("the input has no rows");
    }
    for i in 0..n {
        if !t_s[i].is_finite() || !x_m[i].is_finite() {
            bail!("row {}: time and position must be finite numbers", i + 1);
        }
        if i > 0 && t_s[i] < t_s[i - 1] {
            bail!(
                "row {}: time goes backwards ({} after {})",
                i + 1,
                t_s[i],
                t_s[i - 1]
            );
        }
    }
    let t0 = t_s[0];
    let dt: Vec<f64> = (0..n)
        .map(|i| if i == 0 { 0.0 } else { t_s[i] - t_s[i - 1] })
        .collect();
    let feats = compute_offline(x_m, &dt, f_n, spec.g_v, spec.g_a, &spec.features);
    Ok((0..n)
        .map(|i| {
            let f = &feats[i].features;
            let time = t_s[i] - t0;
            Row {
                step: i as u64,
                timestamp: ((time * 1e6).round() as u64) as u32,
                time,
                dt: dt[i],
                f_ref: f64::NAN,
                rtob_force: f_n[i],
                dob_force: f64::NAN,
                counts: (x_m[i] / spec.meters_per_count).round() as i32,
                position_x: x_m[i],
                velocity: feats[i].velocity,
                acceleration: feats[i].acceleration,
                i_a_ref: f64::NAN,
                i_motor: f64::NAN,
                analog_out_motor: 32768,
                phase: 0,
                f_true: f64::NAN,
                f_pred: f64::NAN,
                fallback: false,
                cycle_no: f.cycle_no,
                f_previous_x: f.f_previous_x,
                f_previous_v: f.f_previous_v,
                f_previous_a: f.f_previous_a,
                deformation: f.deformation,
                area_fx: f.area_fx,
            }
        })
        .collect())
}

/// Runs the import; returns the number of rows written.
pub fn import(spec: &ImportSpec) -> Result<u64> {
    let cols = crate::record::read::read_columns(
        &spec.input,
        &[&spec.time_col, &spec.position_col, &spec.force_col],
    )?;
    let ts = match spec.time_unit {
        TimeUnit::S => 1.0,
        TimeUnit::Ms => 1e-3,
        TimeUnit::Us => 1e-6,
    };
    let xs = match spec.position_unit {
        PositionUnit::M => 1.0,
        PositionUnit::Mm => 1e-3,
        PositionUnit::Um => 1e-6,
    };
    let fs = match spec.force_unit {
        ForceUnit::N => 1.0,
        ForceUnit::MilliN => 1e-3,
    };
    let t: Vec<f64> = cols[0].iter().map(|v| v * ts).collect();
    let x: Vec<f64> = cols[1].iter().map(|v| v * xs).collect();
    let f: Vec<f64> = cols[2].iter().map(|v| v * fs).collect();
    let rows = rows_from_series(&t, &x, &f, spec)
        .map_err(|e| anyhow::anyhow!("{}: {e}", spec.input.display()))?;
    let meta = serde_json::json!({
        "experiment": "import",
        "board": "none",
        "import": spec,
        "rt_loop_version": env!("CARGO_PKG_VERSION"),
        "columns": crate::record::COLUMNS,
        "feature_names": crate::features::FEATURE_NAMES,
    })
    .to_string();
    let mut rec = RecorderHandle::start(
        Target::File(spec.out.clone()),
        Format::from_path(&spec.out),
        meta,
        1 << 16,
    )?;
    for r in rows {
        rec.push_wait(r);
    }
    let report = rec.finish();
    if let Some(e) = report.error {
        bail!("writing {} failed: {e}", spec.out.display());
    }
    Ok(report.rows_written)
}
