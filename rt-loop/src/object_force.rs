//! `rt-loop object-force`: a material's object driven along a given motion, its force written
//! out (issue 23, item 6). This is the study's oracle path ([`OracleModel`]: a fresh object of
//! the material, whatever its law, stepped at the loop's rate with the bench's sub-steps along
//! the position) without a loop around it, so that a program outside rt-loop (the
//! leave-one-rate-out generators of train/) gets the force of the bench's OWN law
//! implementations, ONNX objects included, instead of a copy of them.
//!
//! Input: a CSV with columns `t_s` (s, increasing) and `x_m` (m, into the object). Output: the
//! same rows with `force_n` (N) appended. Between two input samples the position is
//! interpolated linearly at every control period; each row's force is the one of the period at
//! its time. Off the real-time path (a command over files). Errors name the file's line (the
//! header is line 1, the first sample line 2), which is what an editor shows.

use crate::features::Features;
use crate::object::material::Material;
use crate::object::oracle::OracleModel;
use crate::serving::model::ForceModel;
use anyhow::{bail, Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct ObjectForceArgs {
    /// Material file (any law: foam, bouc_wen, poroelastic, onnx).
    #[arg(long)]
    pub material: PathBuf,
    /// The motion: CSV with columns `t_s` (s, increasing) and `x_m` (m, into the object).
    #[arg(long)]
    pub input: PathBuf,
    /// Output CSV: `t_s`, `x_m`, `force_n`.
    #[arg(long)]
    pub out: PathBuf,
    /// Control rate the object is stepped at, Hz (the bench's: 10 kHz, 10 sub-steps each).
    #[arg(long, default_value_t = 10_000.0)]
    pub rate_hz: f64,
}

/// The largest |x_m| a motion may hold, m: past it the motion is in another unit.
pub const MAX_PLAUSIBLE_X_M: f64 = 1.0;

/// The force of a fresh object of `material` along the motion (`t_s`, `x_m`), one per sample.
pub fn drive(material: &Material, t_s: &[f64], x_m: &[f64], rate_hz: f64) -> Result<Vec<f64>> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        bail!("--rate-hz must be a positive number (got {rate_hz})");
    }
    if t_s.len() != x_m.len() || t_s.is_empty() {
        bail!("the motion needs as many times as positions, at least one");
    }
    if let Some(i) = (0..t_s.len()).find(|&i| !t_s[i].is_finite() || !x_m[i].is_finite()) {
        bail!("line {}: time and position must be finite numbers", i + 2);
    }
    if let Some(i) = (1..t_s.len()).find(|&i| t_s[i] <= t_s[i - 1]) {
        bail!("line {}: time {} does not increase", i + 2, t_s[i]);
    }
    // A motion in millimetres read as metres would drive the object 1000x too deep and write
    // forces of meganewtons without a word: no bench travels a metre (the importer's limit,
    // `importer.PLAUSIBLE_SI`, is the same).
    if let Some(i) = (0..x_m.len()).find(|&i| x_m[i].abs() > MAX_PLAUSIBLE_X_M) {
        bail!(
            "line {}: position {} m is beyond {MAX_PLAUSIBLE_X_M} m, which no bench travels: \
             `x_m` is in metres (a motion in mm must be divided by 1000)",
            i + 2,
            x_m[i]
        );
    }
    let mut oracle = OracleModel::new(material, rate_hz, 1.0);
    oracle.begin_run();
    let mut feats = Features::default();
    let mut out = Vec::with_capacity(t_s.len());
    let mut seg = 0usize;
    let mut k: u64 = 0;
    let mut force = 0.0;
    for (i, &ti) in t_s.iter().enumerate() {
        // step every control period up to this sample's time (the first sample: its own period)
        let last = ((ti - t_s[0]) * rate_hz).round() as u64;
        while k <= last {
            let tk = t_s[0] + k as f64 / rate_hz;
            while seg + 1 < t_s.len() && t_s[seg + 1] < tk {
                seg += 1;
            }
            let x = if seg + 1 < t_s.len() {
                let w = ((tk - t_s[seg]) / (t_s[seg + 1] - t_s[seg])).clamp(0.0, 1.0);
                x_m[seg] + w * (x_m[seg + 1] - x_m[seg])
            } else {
                x_m[seg]
            };
            feats.position_x = x;
            force = oracle
                .predict(k, &feats)
                .with_context(|| format!("the object failed at t = {tk} s (line {})", i + 2))?;
            k += 1;
        }
        out.push(force);
    }
    Ok(out)
}

fn read_motion(path: &Path) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut r = csv::Reader::from_path(path)
        .with_context(|| format!("cannot read the motion {}", path.display()))?;
    let head = r.headers()?.clone();
    let col = |name: &str| {
        head.iter()
            .position(|h| h.trim() == name)
            .with_context(|| format!("{}: no column `{name}` (need t_s and x_m)", path.display()))
    };
    let (ti, xi) = (col("t_s")?, col("x_m")?);
    let (mut t, mut x) = (Vec::new(), Vec::new());
    for (n, rec) in r.records().enumerate() {
        let rec = rec.with_context(|| format!("{}: line {}", path.display(), n + 2))?;
        let num = |c: usize| -> Result<f64> {
            let s = rec.get(c).unwrap_or("").trim();
            s.parse().with_context(|| {
                format!("{}: line {}: `{s}` is not a number", path.display(), n + 2)
            })
        };
        t.push(num(ti)?);
        x.push(num(xi)?);
    }
    Ok((t, x))
}

/// The command: reads the material and the motion, drives, writes the CSV.
pub fn run(a: &ObjectForceArgs) -> Result<()> {
    let (material, _) = Material::load(&a.material)?;
    let (t, x) = read_motion(&a.input)?;
    let f = drive(&material, &t, &x, a.rate_hz)
        .with_context(|| format!("driving {}", a.input.display()))?;
    let mut w = csv::Writer::from_path(&a.out)
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    w.write_record(["t_s", "x_m", "force_n"])?;
    for i in 0..t.len() {
        w.write_record([t[i].to_string(), x[i].to_string(), f[i].to_string()])?;
    }
    w.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::object::{Law, Object};

    /// A triangular press (in to `depth_m` at `rate` m/s and out again), sampled at 50 Hz.
    fn press(depth_m: f64, rate: f64) -> (Vec<f64>, Vec<f64>) {
        let ramp = depth_m / rate;
        let n = (2.0 * ramp * 50.0).round() as usize;
        let t: Vec<f64> = (0..=n).map(|i| i as f64 / 50.0).collect();
        let x = t
            .iter()
            .map(|&t| depth_m * (1.0 - ((t - ramp) / ramp).abs()) - 0.001)
            .collect();
        (t, x)
    }

    /// A motion in millimetres is refused by name, not driven 1000x too deep.
    #[test]
    fn a_motion_in_millimetres_is_refused() {
        let m = Material::repository("sponge");
        let err = drive(&m, &[0.0, 0.1, 0.2], &[0.0, 5.0, 12.0], 10_000.0).unwrap_err();
        let msg = format!("{err:#}");
        assert!(msg.contains("line 3") && msg.contains("metres"), "{msg}");
        assert!(drive(&m, &[0.0, 0.1], &[0.0, 0.012], 10_000.0).is_ok());
    }

    /// The driven force is the object's own, stepped at the bench's sub-step along the
    /// interpolated motion (checked against an object stepped here), 0 out of contact.
    #[test]
    fn drives_the_material_object_along_the_motion() {
        let m = Material::repository("bouc-wen");
        let (t, x) = press(0.012, 0.01);
        let f = drive(&m, &t, &x, 10_000.0).unwrap();
        assert_eq!(f.len(), t.len());
        let mut o = Object::new(&m);
        let (mut xp, mut k, mut worst): (f64, usize, f64) = (0.0, 0, 0.0);
        for i in 0..t.len() {
            let steps = if i == 0 { 1 } else { 200 };
            for s in 0..steps {
                let xk = if i == 0 {
                    x[0]
                } else {
                    x[i - 1] + (x[i] - x[i - 1]) * (s + 1) as f64 / 200.0
                };
                o.prepare(1e-5);
                for j in 1..=10 {
                    o.substep(xp + (xk - xp) * j as f64 / 10.0);
                }
                o.slow_update(xk, 1e-4);
                xp = xk;
                k += 1;
            }
            worst = worst.max((o.force() - f[i]).abs());
            if x[i] <= 0.0 {
                assert_eq!(f[i], 0.0, "out of contact at row {i}");
            }
        }
        assert_eq!(k, 1 + 200 * (t.len() - 1));
        assert!(worst < 1e-9, "{worst}");
        assert!(f.iter().cloned().fold(0.0, f64::max) > 1.0);
    }

    /// The gel relaxes (Hu et al. 2010): pressed slowly it pushes back less at the same depth
    /// than pressed fast, through the command's files.
    #[test]
    fn the_command_reads_and_writes_csv_and_the_gel_relaxes() {
        let dir = std::env::temp_dir().join(format!("object-force-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut peaks = Vec::new();
        for rate in [0.0005, 0.05] {
            let (t, x) = press(0.015, rate);
            let input = dir.join(format!("in-{rate}.csv"));
            let body: String = t
                .iter()
                .zip(&x)
                .map(|(t, x)| format!("{t},{x}\n"))
                .collect();
            std::fs::write(&input, format!("t_s,x_m\n{body}")).unwrap();
            let args = ObjectForceArgs {
                material: concat!(env!("CARGO_MANIFEST_DIR"), "/../materials/gel.toml").into(),
                input,
                out: dir.join(format!("out-{rate}.csv")),
                rate_hz: 10_000.0,
            };
            run(&args).unwrap();
            let text = std::fs::read_to_string(&args.out).unwrap();
            let mut lines = text.lines();
            assert_eq!(lines.next(), Some("t_s,x_m,force_n"));
            let f: Vec<f64> = lines
                .map(|l| l.split(',').nth(2).unwrap().parse().unwrap())
                .collect();
            assert_eq!(f.len(), t.len());
            peaks.push(f.iter().cloned().fold(0.0, f64::max));
        }
        assert!(
            peaks[0] < 0.9 * peaks[1],
            "slow {} vs fast {}",
            peaks[0],
            peaks[1]
        );
        let bad = dir.join("bad.csv");
        std::fs::write(&bad, "t_s,x_m\n0,0\n0,0.001\n").unwrap();
        let args = ObjectForceArgs {
            material: concat!(env!("CARGO_MANIFEST_DIR"), "/../materials/gel.toml").into(),
            input: bad,
            out: dir.join("never.csv"),
            rate_hz: 10_000.0,
        };
        let e = format!("{:#}", run(&args).unwrap_err());
        assert!(e.contains("does not increase"), "{e}");
        assert!(!args.out.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
