//! `rt-loop features`: imports a time/displacement/force series measured elsewhere (a
//! materials-testing machine, an indenter, another motor) and writes it in the recording
//! format, with velocity and acceleration from the loop's pseudo-derivative filters and the
//! nine features from the very same feature code the loop runs.
//!
//! Such series come at any rate and in any unit, so nothing here is assumed silently:
//! - units come from the options, else from the column header (`force [mN]`,
//!   `displacement (mm)`), else SI; an option that contradicts the header is refused;
//! - time must increase on every row, without gaps (a period above `max_gap_factor` times the
//!   median period), and time, position and force must be finite: each refusal names the row
//!   (data rows counted from 1, the header not counted);
//! - the filter gains default to the loop's (30 / 100 rad/s, meant for 10 kHz) capped at
//!   g dt = [`DERIVED_G_DT`] for slower data, and any gain with g dt above [`MAX_G_DT`] is
//!   refused: the forward-Euler pseudo-derivative's error is multiplied by (1 - g dt) each
//!   step, so above 1 it alternates sign (rings) and at 2 it no longer decays (unstable);
//! - contact detection thresholds come from the data's own force noise floor
//!   ([`FeatureParams::from_force`]), unless given;
//! - the metadata records the source, the units (and where each came from), the rate and every
//!   setting used.
//!
//! Columns with no source: F_ref, dob_force, I_a_ref, I_motor, F_true, F_pred, F_object are NaN;
//! analog_out_motor is 32768 (0 A), phase 0, fallback false. `rtob_force` is the imported
//! force, `counts` the position rounded to encoder counts, `timestamp` the time in
//! microseconds wrapped to 32 bits like a board counter.

use crate::features::{compute_offline, FeatureParams};
use crate::params::LoopParams;
use crate::record::{Format, RecorderHandle, Row, Target};
use anyhow::{anyhow, bail, Result};
use std::path::PathBuf;

/// Largest g dt a pseudo-derivative may run at (see the module comment).
pub const MAX_G_DT: f64 = 1.0;
/// g dt of a derived gain when the loop's own gain would exceed it: the discrete pole is then
/// 0.8 against exp(-0.2) = 0.819 for the continuous filter, a 2 % error.
pub const DERIVED_G_DT: f64 = 0.2;
/// Default largest period, as a multiple of the median period, before a gap is refused.
pub const DEFAULT_MAX_GAP_FACTOR: f64 = 1.5;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum TimeUnit {
    S,
    Ms,
    Us,
    Min,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum PositionUnit {
    M,
    Cm,
    Mm,
    Um,
    In,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
pub enum ForceUnit {
    #[value(name = "N")]
    N,
    #[value(name = "mN")]
    MilliN,
    #[value(name = "kN")]
    KiloN,
    #[value(name = "lbf")]
    Lbf,
}

impl TimeUnit {
    /// Seconds per unit.
    pub fn factor(self) -> f64 {
        match self {
            TimeUnit::S => 1.0,
            TimeUnit::Ms => 1e-3,
            TimeUnit::Us => 1e-6,
            TimeUnit::Min => 60.0,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            TimeUnit::S => "s",
            TimeUnit::Ms => "ms",
            TimeUnit::Us => "us",
            TimeUnit::Min => "min",
        }
    }
    /// A header's unit text (`s`, `sec`, `ms`, `µs`, ...).
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "s" | "sec" | "secs" | "second" | "seconds" => Some(TimeUnit::S),
            "ms" | "msec" => Some(TimeUnit::Ms),
            "us" | "µs" | "μs" | "usec" => Some(TimeUnit::Us),
            "min" => Some(TimeUnit::Min),
            _ => None,
        }
    }
}

impl PositionUnit {
    /// Metres per unit.
    pub fn factor(self) -> f64 {
        match self {
            PositionUnit::M => 1.0,
            PositionUnit::Cm => 1e-2,
            PositionUnit::Mm => 1e-3,
            PositionUnit::Um => 1e-6,
            PositionUnit::In => 0.0254,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            PositionUnit::M => "m",
            PositionUnit::Cm => "cm",
            PositionUnit::Mm => "mm",
            PositionUnit::Um => "um",
            PositionUnit::In => "in",
        }
    }
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "m" => Some(PositionUnit::M),
            "cm" => Some(PositionUnit::Cm),
            "mm" => Some(PositionUnit::Mm),
            "um" | "µm" | "μm" => Some(PositionUnit::Um),
            "in" | "inch" => Some(PositionUnit::In),
            _ => None,
        }
    }
}

impl ForceUnit {
    /// Newtons per unit.
    pub fn factor(self) -> f64 {
        match self {
            ForceUnit::N => 1.0,
            ForceUnit::MilliN => 1e-3,
            ForceUnit::KiloN => 1e3,
            ForceUnit::Lbf => 4.448_221_615_260_5,
        }
    }
    pub fn label(self) -> &'static str {
        match self {
            ForceUnit::N => "N",
            ForceUnit::MilliN => "mN",
            ForceUnit::KiloN => "kN",
            ForceUnit::Lbf => "lbf",
        }
    }
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "N" => Some(ForceUnit::N),
            "mN" => Some(ForceUnit::MilliN),
            "kN" => Some(ForceUnit::KiloN),
            "lbf" => Some(ForceUnit::Lbf),
            _ => None,
        }
    }
}

/// The unit text of a header that ends in `[unit]` or `(unit)`, and the name before it:
/// `"force [mN]"` -> `("force", "mN")`.
pub fn header_unit(header: &str) -> Option<(&str, &str)> {
    let h = header.trim_end();
    let open = match h.chars().last()? {
        ']' => '[',
        ')' => '(',
        _ => return None,
    };
    let start = h.rfind(open)?;
    let unit = h[start + 1..h.len() - 1].trim();
    if unit.is_empty() {
        return None;
    }
    Some((h[..start].trim_end(), unit))
}

/// Where a unit came from (recorded in the metadata).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum UnitSource {
    Option,
    Header,
    Default,
}

/// A unit from the option, else the header, else the SI default; an option that contradicts a
/// header it can read (or a header unit it cannot read with no option) is an error.
fn resolve_unit<U: Copy + PartialEq>(
    what: &str,
    header: &str,
    option: Option<U>,
    default: U,
    parse: fn(&str) -> Option<U>,
    label: fn(U) -> &'static str,
) -> Result<(U, UnitSource)> {
    let from_header = header_unit(header).map(|(_, u)| (u, parse(u)));
    match (option, from_header) {
        (Some(o), Some((_, Some(h)))) if o != h => bail!(
            "column {header:?} says its unit is {}, but --{what}-unit {} was given",
            label(h),
            label(o)
        ),
        (Some(o), _) => Ok((o, UnitSource::Option)),
        (None, Some((_, Some(h)))) => Ok((h, UnitSource::Header)),
        (None, Some((u, None))) => {
            bail!("column {header:?}: unknown unit {u:?}; give --{what}-unit explicitly")
        }
        (None, None) => Ok((default, UnitSource::Default)),
    }
}

/// The resolved import: what [`rows_from_series`] runs with.
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

/// What the command line gives: every unit, gain and threshold optional.
#[derive(Clone, Debug)]
pub struct ImportOptions {
    pub input: PathBuf,
    pub out: PathBuf,
    /// Column names; a name without a unit also finds a header `name [unit]`.
    pub time_col: String,
    pub position_col: String,
    pub force_col: String,
    pub time_unit: Option<TimeUnit>,
    pub position_unit: Option<PositionUnit>,
    pub force_unit: Option<ForceUnit>,
    pub g_v: Option<f64>,
    pub g_a: Option<f64>,
    pub contact_on_n: Option<f64>,
    pub contact_off_n: Option<f64>,
    pub max_gap_factor: f64,
    pub meters_per_count: f64,
    /// JSON object merged into the metadata under `"preprocessing"` (what a caller such as
    /// `haptics-train import` did to the series before handing it over).
    pub extra_meta: Option<String>,
}

/// The period statistics of a checked series.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Timing {
    pub median_dt_s: f64,
    pub max_dt_s: f64,
    pub sample_rate_hz: f64,
}

/// Refuses what the features cannot be computed from, naming the first bad row (data rows
/// from 1): non-finite values, time that does not increase, and gaps.
pub fn check_series(t_s: &[f64], x_m: &[f64], f_n: &[f64], max_gap_factor: f64) -> Result<Timing> {
    let n = t_s.len();
    if n < 3 {
        bail!("the input has {n} rows; at least 3 are needed");
    }
    for i in 0..n {
        for (what, v) in [("time", t_s[i]), ("position", x_m[i]), ("force", f_n[i])] {
            if !v.is_finite() {
                bail!(
                    "row {}: {what} is {} (empty cell or not a number); fill or drop it \
                     (haptics-train import --repair interpolates and counts such rows)",
                    i + 1,
                    if v.is_nan() {
                        "missing".to_string()
                    } else {
                        v.to_string()
                    }
                );
            }
        }
        if i > 0 && t_s[i] <= t_s[i - 1] {
            bail!(
                "row {}: time does not increase ({} s after {} s)",
                i + 1,
                t_s[i],
                t_s[i - 1]
            );
        }
    }
    let mut dts: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
    let max_dt = dts.iter().cloned().fold(0.0, f64::max);
    let (i_max, _) = dts
        .iter()
        .enumerate()
        .fold((0, 0.0), |a, (i, &d)| if d > a.1 { (i, d) } else { a });
    dts.sort_by(|a, b| a.total_cmp(b));
    let median = dts[dts.len() / 2];
    if max_dt > max_gap_factor * median {
        bail!(
            "row {}: a gap of {max_dt} s after t = {} s (the median period is {median} s; \
             the limit is {max_gap_factor}x): resample (haptics-train import --repair or \
             --resample-hz) or raise --max-gap-factor",
            i_max + 2,
            t_s[i_max]
        );
    }
    Ok(Timing {
        median_dt_s: median,
        max_dt_s: max_dt,
        sample_rate_hz: 1.0 / median,
    })
}

/// The gain to run a pseudo-derivative at: the given one, else the loop's own capped at
/// g dt = [`DERIVED_G_DT`]; refused above g dt = [`MAX_G_DT`] at the largest period.
pub fn filter_gain(what: &str, given: Option<f64>, loop_gain: f64, timing: &Timing) -> Result<f64> {
    let g = given.unwrap_or_else(|| loop_gain.min(DERIVED_G_DT / timing.median_dt_s));
    if !(g.is_finite() && g > 0.0) {
        bail!("{what} must be a positive number of rad/s, not {g}");
    }
    let gdt = g * timing.max_dt_s;
    if gdt > MAX_G_DT {
        bail!(
            "{what} = {g} rad/s is more than this series' rate can carry: g dt = {gdt:.3} at \
             its largest period {} s ({:.1} Hz); the forward-Euler filter rings above g dt = 1 \
             and is unstable from 2. Use at most {:.3} rad/s, or leave it out to derive it",
            (timing.max_dt_s * 1e6).round() / 1e6,
            timing.sample_rate_hz,
            MAX_G_DT / timing.max_dt_s
        );
    }
    Ok(g)
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
        if !t_s[i].is_finite() || !x_m[i].is_finite() || !f_n[i].is_finite() {
            bail!(
                "row {}: time, position and force must be finite numbers",
                i + 1
            );
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
                f_object: f64::NAN,
                run_id: 0,
                model_id: 0,
                f_previous: f.f_previous,
            }
        })
        .collect())
}

/// The header a column name refers to: the exact name, else the one header `name [unit]`.
fn find_column(headers: &[String], name: &str) -> Result<String> {
    if headers.iter().any(|h| h == name) {
        return Ok(name.to_string());
    }
    let hits: Vec<&String> = headers
        .iter()
        .filter(|h| header_unit(h).is_some_and(|(base, _)| base == name))
        .collect();
    match hits.as_slice() {
        [one] => Ok((*one).clone()),
        [] => bail!("no column {name:?} (columns: {})", headers.join(", ")),
        _ => bail!("column name {name:?} is ambiguous: {hits:?}"),
    }
}

/// What an import did (printed, and in the metadata).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ImportReport {
    pub rows: u64,
    pub timing: Timing,
    pub g_v: f64,
    pub g_a: f64,
    pub features: FeatureParams,
    pub force_noise_floor_n: f64,
    pub cycles: u32,
}

/// Runs the import: resolves units, checks the series, derives gains and thresholds, writes.
pub fn import(o: &ImportOptions) -> Result<ImportReport> {
    let ctx = |e: anyhow::Error| anyhow!("{}: {e}", o.input.display());
    let headers = crate::record::read::column_names(&o.input)?;
    let tc = find_column(&headers, &o.time_col).map_err(ctx)?;
    let xc = find_column(&headers, &o.position_col).map_err(ctx)?;
    let fc = find_column(&headers, &o.force_col).map_err(ctx)?;
    let (tu, tu_src) = resolve_unit(
        "time",
        &tc,
        o.time_unit,
        TimeUnit::S,
        TimeUnit::parse,
        TimeUnit::label,
    )
    .map_err(ctx)?;
    let (xu, xu_src) = resolve_unit(
        "position",
        &xc,
        o.position_unit,
        PositionUnit::M,
        PositionUnit::parse,
        PositionUnit::label,
    )
    .map_err(ctx)?;
    let (fu, fu_src) = resolve_unit(
        "force",
        &fc,
        o.force_unit,
        ForceUnit::N,
        ForceUnit::parse,
        ForceUnit::label,
    )
    .map_err(ctx)?;
    let cols = crate::record::read::read_columns(&o.input, &[&tc, &xc, &fc])?;
    let t: Vec<f64> = cols[0].iter().map(|v| v * tu.factor()).collect();
    let x: Vec<f64> = cols[1].iter().map(|v| v * xu.factor()).collect();
    let f: Vec<f64> = cols[2].iter().map(|v| v * fu.factor()).collect();
    let timing = check_series(&t, &x, &f, o.max_gap_factor).map_err(ctx)?;
    let lp = LoopParams::default();
    let g_v = filter_gain("--g-v", o.g_v, lp.g_v, &timing).map_err(ctx)?;
    let g_a = filter_gain("--g-a", o.g_a, lp.g_a, &timing).map_err(ctx)?;
    let (derived, noise) = FeatureParams::from_force(&f);
    let features = FeatureParams {
        contact_on_n: o.contact_on_n.unwrap_or(derived.contact_on_n),
        contact_off_n: o.contact_off_n.unwrap_or(derived.contact_off_n),
    };
    features
        .validate()
        .map_err(|e| anyhow!("contact thresholds: {e} (--contact-on-n / --contact-off-n)"))?;
    let spec = ImportSpec {
        input: o.input.clone(),
        time_col: tc,
        position_col: xc,
        force_col: fc,
        time_unit: tu,
        position_unit: xu,
        force_unit: fu,
        out: o.out.clone(),
        g_v,
        g_a,
        meters_per_count: o.meters_per_count,
        features: features.clone(),
    };
    let rows = rows_from_series(&t, &x, &f, &spec).map_err(ctx)?;
    let cycles = rows.last().map_or(1, |r| r.cycle_no) - 1;
    let extra: serde_json::Value = match &o.extra_meta {
        Some(s) => serde_json::from_str(s).map_err(|e| anyhow!("--meta-json: {e}"))?,
        None => serde_json::Value::Null,
    };
    let given = |v: Option<f64>| if v.is_some() { "given" } else { "derived" };
    let force_min = f.iter().cloned().fold(f64::INFINITY, f64::min);
    let force_max = f.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let mut meta = serde_json::json!({
        "experiment": "import",
        "board": "none",
        "source": o.input.display().to_string(),
        "import": spec,
        "units": {
            "time": {"unit": tu.label(), "from": tu_src},
            "position": {"unit": xu.label(), "from": xu_src},
            "force": {"unit": fu.label(), "from": fu_src},
        },
        "timing": timing,
        "filters": {
            "g_v": g_v, "g_v_from": given(o.g_v), "g_v_dt": g_v * timing.max_dt_s,
            "g_a": g_a, "g_a_from": given(o.g_a), "g_a_dt": g_a * timing.max_dt_s,
            "max_g_dt": MAX_G_DT,
        },
        "features": features,
        "contact": {
            "from": if o.contact_on_n.is_some() || o.contact_off_n.is_some() { "given" } else { "noise_floor" },
            "force_noise_floor_n": noise,
            "force_min_n": force_min,
            "force_max_n": force_max,
            "cycles": cycles,
            // contact (and so the cycle features) counts compression, positive force: a
            // tension test's cycles are not segmented
            "loading": if -force_min > force_max { "tension" } else { "compression" },
        },
        "max_gap_factor": o.max_gap_factor,
        "preprocessing": extra,
        "rt_loop_version": env!("CARGO_PKG_VERSION"),
        "columns": crate::record::COLUMNS,
        "feature_names": crate::features::FEATURE_NAMES,
    });
    // A caller that converted the series first (haptics-train import) knows the original
    // source and units: those are what the recording must say.
    for key in ["source", "units"] {
        if let Some(v) = extra.get(key) {
            meta[key] = v.clone();
        }
    }
    let meta = meta.to_string();
    let mut rec = RecorderHandle::start(
        Target::File(o.out.clone()),
        Format::from_path(&o.out),
        meta,
        1 << 16,
    )?;
    for r in rows {
        rec.push_wait(r);
    }
    let report = rec.finish();
    if let Some(e) = report.error {
        bail!("writing {} failed: {e}", o.out.display());
    }
    Ok(ImportReport {
        rows: report.rows_written,
        timing,
        g_v,
        g_a,
        features,
        force_noise_floor_n: noise,
        cycles,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn timing(rate: f64) -> Timing {
        Timing {
            median_dt_s: 1.0 / rate,
            max_dt_s: 1.0 / rate,
            sample_rate_hz: rate,
        }
    }

    #[test]
    fn header_units_are_read() {
        assert_eq!(header_unit("force [mN]"), Some(("force", "mN")));
        assert_eq!(
            header_unit("displacement (mm)"),
            Some(("displacement", "mm"))
        );
        assert_eq!(header_unit("force"), None);
        assert_eq!(header_unit("f []"), None);
        let r = |h: &str, o| {
            resolve_unit(
                "force",
                h,
                o,
                ForceUnit::N,
                ForceUnit::parse,
                ForceUnit::label,
            )
        };
        assert_eq!(
            r("force [mN]", None).unwrap(),
            (ForceUnit::MilliN, UnitSource::Header)
        );
        assert_eq!(
            r("force", None).unwrap(),
            (ForceUnit::N, UnitSource::Default)
        );
        assert_eq!(
            r("force [mN]", Some(ForceUnit::MilliN)).unwrap(),
            (ForceUnit::MilliN, UnitSource::Option)
        );
        let e = r("force [mN]", Some(ForceUnit::N)).unwrap_err().to_string();
        assert!(e.contains("says its unit is mN"), "{e}");
        let e = r("force [dyn]", None).unwrap_err().to_string();
        assert!(e.contains("unknown unit \"dyn\""), "{e}");
    }

    #[test]
    fn every_unit_has_its_factor_and_parses_its_label() {
        for u in [TimeUnit::S, TimeUnit::Ms, TimeUnit::Us, TimeUnit::Min] {
            assert_eq!(TimeUnit::parse(u.label()), Some(u));
        }
        for u in [
            PositionUnit::M,
            PositionUnit::Cm,
            PositionUnit::Mm,
            PositionUnit::Um,
            PositionUnit::In,
        ] {
            assert_eq!(PositionUnit::parse(u.label()), Some(u));
        }
        for u in [
            ForceUnit::N,
            ForceUnit::MilliN,
            ForceUnit::KiloN,
            ForceUnit::Lbf,
        ] {
            assert_eq!(ForceUnit::parse(u.label()), Some(u));
        }
        assert_eq!(ForceUnit::MilliN.factor() * 1500.0, 1.5);
        assert_eq!(PositionUnit::In.factor(), 0.0254);
    }

    #[test]
    fn gains_follow_the_rate_and_unstable_ones_are_refused() {
        // 10 kHz: the loop's own gains
        assert_eq!(
            filter_gain("g", None, 100.0, &timing(10_000.0)).unwrap(),
            100.0
        );
        // 50 Hz: capped at g dt = 0.2
        let g = filter_gain("g", None, 100.0, &timing(50.0)).unwrap();
        assert!((g * 0.02 - DERIVED_G_DT).abs() < 1e-12, "{g}");
        // the case: 100 rad/s at 50 Hz sits on the limit g dt = 2
        let e = filter_gain("--g-a", Some(100.0), 100.0, &timing(50.0)).unwrap_err();
        assert!(e.to_string().contains("g dt = 2.000"), "{e}");
        assert!(filter_gain("g", Some(50.0), 100.0, &timing(50.0)).is_ok());
        assert!(filter_gain("g", Some(-1.0), 100.0, &timing(50.0)).is_err());
    }

    #[test]
    fn bad_rows_are_refused_with_their_number() {
        let t: Vec<f64> = (0..10).map(|i| i as f64 * 0.02).collect();
        let x = vec![0.0; 10];
        let mut f = vec![0.0; 10];
        assert!((check_series(&t, &x, &f, 1.5).unwrap().sample_rate_hz - 50.0).abs() < 1e-9);
        f[4] = f64::NAN;
        let e = check_series(&t, &x, &f, 1.5).unwrap_err().to_string();
        assert!(e.starts_with("row 5: force is missing"), "{e}");
        f[4] = 0.0;
        let mut tb = t.clone();
        tb[6] = tb[4];
        let e = check_series(&tb, &x, &f, 1.5).unwrap_err().to_string();
        assert!(e.starts_with("row 7: time does not increase"), "{e}");
        let mut tg = t.clone();
        for v in tg.iter_mut().skip(7) {
            *v += 0.1;
        }
        let e = check_series(&tg, &x, &f, 1.5).unwrap_err().to_string();
        assert!(e.starts_with("row 8: a gap of"), "{e}");
        assert!(check_series(&tg, &x, &f, 10.0).is_ok());
    }
}
