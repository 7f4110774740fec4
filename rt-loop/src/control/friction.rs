//! The bench's friction: the model the RFOB subtracts (docs/physics.md, "The loop step", `F_friction_model`) and
//! its identification from slow constant-velocity sweeps in free air under position control.
//!
//! Why: the RFOB's estimate is both the recorded target (abstraction) and the rendered force's
//! feedback (reproduction). Without a friction model the bench's ~1 N Coulomb/Stribeck
//! friction is in the target and is felt again on rendering (counted twice). The same model,
//! identified once and written to the bench file, is subtracted in every experiment.
//!
//! The model is `F(v) = s(v) (F_c + (F_s - F_c) exp(-(v/v_s)^2)) + b v`, with `s(v)` the sign
//! of v smoothed linearly below `smooth_mps`: the loop's velocity estimate is noise at rest and
//! the friction of a probe that sticks is unknowable from its motion, so a resting probe gets
//! no compensation instead of a +-F_s jump on the sign of a rounding error.
//!
//! REAL-TIME PATH: [`Friction::force`] is a few flops, no allocation, no lock.

use crate::invalid::{require_non_negative, require_positive, InvalidSetting};
use crate::lstsq::{FitError, NormalEquations3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Friction parameters in the loop's units (N as the DOB measures them, K_fn times current).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Friction {
    /// Coulomb (sliding) friction, N.
    pub coulomb_n: f64,
    /// Static (breakaway) level of the Stribeck curve, N (0 or <= coulomb: no Stribeck peak).
    pub static_n: f64,
    /// Stribeck velocity, m/s.
    pub stribeck_mps: f64,
    /// Viscous friction, N s/m.
    pub viscous: f64,
    /// Below this speed the sign is smoothed linearly to 0 at rest, m/s.
    pub smooth_mps: f64,
}

impl Default for Friction {
    /// No friction model (the thesis code's `friction_model` = 0).
    fn default() -> Self {
        Friction {
            coulomb_n: 0.0,
            static_n: 0.0,
            stribeck_mps: 0.002,
            viscous: 0.0,
            smooth_mps: 5e-4,
        }
    }
}

impl Friction {
    pub fn is_zero(&self) -> bool {
        self.coulomb_n == 0.0 && self.static_n == 0.0 && self.viscous == 0.0
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        require_non_negative(&[
            ("friction.coulomb_n", self.coulomb_n),
            ("friction.static_n", self.static_n),
            ("friction.viscous", self.viscous),
            ("friction.smooth_mps", self.smooth_mps),
        ])?;
        require_positive(&[("friction.stribeck_mps", self.stribeck_mps)])?;
        if self.coulomb_n.max(self.static_n) > 5.0 {
            return Err(
                "friction above 5 N is not a bench's friction: check the bench file".into(),
            );
        }
        Ok(())
    }

    /// Friction force opposing a probe moving at `v` (m/s), N. Allocation-free.
    #[inline]
    pub fn force(&self, v: f64) -> f64 {
        if !v.is_finite() {
            return 0.0;
        }
        let sign = if self.smooth_mps > 0.0 {
            (v / self.smooth_mps).clamp(-1.0, 1.0)
        } else {
            v.signum() * (v != 0.0) as u8 as f64
        };
        let r = v / self.stribeck_mps;
        let peak = (self.static_n - self.coulomb_n).max(0.0);
        sign * (self.coulomb_n + peak * (-r * r).exp()) + self.viscous * v
    }

    /// Reads a bench file (`[friction]` table, as `rt-loop identify-friction` writes it).
    pub fn load(path: &Path) -> anyhow::Result<Friction> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read bench file {}: {e}", path.display()))?;
        let bench: BenchFile = toml::from_str(&text)
            .map_err(|e| anyhow::anyhow!("bench file {}: {e}", path.display()))?;
        bench
            .friction
            .validate()
            .map_err(|e| anyhow::anyhow!("bench file {}: {e}", path.display()))?;
        Ok(bench.friction)
    }
}

/// The bench file: what the identification measured about the bench (friction so far).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchFile {
    pub friction: Friction,
}

/// One constant-velocity segment's measurement: commanded speed, mean measured speed, mean
/// DOB force (the motor force not explained by the nominal mass: friction at constant speed).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SweepPoint {
    pub v_cmd: f64,
    pub v_mean: f64,
    pub force_mean: f64,
    pub force_sd: f64,
    pub samples: usize,
}

/// The fitted model and how well it explains the sweeps.
#[derive(Clone, Debug, Serialize)]
pub struct FrictionFit {
    pub friction: Friction,
    pub rms_residual_n: f64,
    pub points: Vec<SweepPoint>,
}

/// Least-squares fit of (F_c, F_s - F_c, b) for each Stribeck velocity on a log grid from 0.2
/// to 20 mm/s; the grid point with the smallest residual wins (the model is linear in the
/// other three; negative levels are clipped to 0, so data without a Stribeck peak give
/// `static_n` = `coulomb_n`).
/// Uses the commanded velocity (exact) as the abscissa, the measured mean force as ordinate.
pub fn fit(points: &[SweepPoint]) -> Result<FrictionFit, FitError> {
    let pts: Vec<&SweepPoint> = points
        .iter()
        .filter(|p| p.v_cmd != 0.0 && p.force_mean.is_finite() && p.samples > 0)
        .collect();
    if pts.len() < 4 {
        return Err(FitError::TooFew {
            found: pts.len(),
            needed: 4,
            what: "usable sweep segments (speeds)",
        });
    }
    let mut best: Option<(f64, [f64; 3], f64)> = None;
    for k in 0..=80 {
        let vs = 2e-4 * 10f64.powf(2.0 * k as f64 / 80.0);
        let mut eq = NormalEquations3::default();
        for p in &pts {
            let s = p.v_cmd.signum();
            let r = p.v_cmd / vs;
            eq.add([s, s * (-r * r).exp(), p.v_cmd], p.force_mean);
        }
        let Some(sol) = eq.solve() else {
            continue;
        };
        // physical: no negative levels
        let sol = [sol[0].max(0.0), sol[1].max(0.0), sol[2].max(0.0)];
        let ss: f64 = pts
            .iter()
            .map(|p| {
                let s = p.v_cmd.signum();
                let r = p.v_cmd / vs;
                let m = s * (sol[0] + sol[1] * (-r * r).exp()) + sol[2] * p.v_cmd;
                (m - p.force_mean).powi(2)
            })
            .sum();
        if best.as_ref().is_none_or(|b| ss < b.0) {
            best = Some((ss, sol, vs));
        }
    }
    let (ss, sol, vs) = best.ok_or(FitError::Singular("the sweep data admit no fit"))?;
    let friction = Friction {
        coulomb_n: sol[0],
        static_n: sol[0] + sol[1],
        stribeck_mps: vs,
        viscous: sol[2],
        ..Friction::default()
    };
    friction
        .validate()
        .map_err(|e| FitError::Implausible(format!("{e}: check the sweeps")))?;
    Ok(FrictionFit {
        friction,
        rms_residual_n: (ss / pts.len() as f64).sqrt(),
        points: points.to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> Friction {
        Friction {
            coulomb_n: 0.85,
            static_n: 1.0,
            stribeck_mps: 0.002,
            viscous: 5.0,
            smooth_mps: 0.0,
        }
    }

    #[test]
    fn force_is_odd_smoothed_at_rest_and_has_a_stribeck_peak() {
        let f = Friction {
            smooth_mps: 1e-4,
            ..truth()
        };
        assert_eq!(f.force(0.0), 0.0);
        assert!((f.force(0.01) + f.force(-0.01)).abs() < 1e-12);
        // half-way into the smoothing band: half the breakaway level
        assert!((f.force(5e-5) - 0.5 * 1.0).abs() < 0.01);
        // peak near 0, Coulomb + viscous far from it
        assert!(f.force(2e-4) > 0.98);
        assert!((f.force(0.02) - (0.85 + 5.0 * 0.02)).abs() < 1e-6);
        assert!(Friction::default().is_zero());
        assert_eq!(Friction::default().force(0.3), 0.0);
        assert_eq!(f.force(f64::NAN), 0.0);
    }

    #[test]
    fn fit_recovers_the_model_from_exact_points() {
        let t = truth();
        let pts: Vec<SweepPoint> = [0.5e-3, 1e-3, 2e-3, 3e-3, 5e-3, 1e-2, 2e-2, 4e-2, 8e-2]
            .iter()
            .flat_map(|&v| [v, -v])
            .map(|v| SweepPoint {
                v_cmd: v,
                v_mean: v,
                force_mean: t.force(v),
                force_sd: 0.0,
                samples: 100,
            })
            .collect();
        let fit = fit(&pts).unwrap();
        let f = fit.friction;
        assert!((f.coulomb_n - 0.85).abs() < 0.01, "{f:?}");
        assert!((f.static_n - 1.0).abs() < 0.02, "{f:?}");
        assert!((f.viscous - 5.0).abs() < 0.1, "{f:?}");
        assert!((f.stribeck_mps / 0.002 - 1.0).abs() < 0.1, "{f:?}");
        assert!(fit.rms_residual_n < 0.01);
        assert!(super::fit(&pts[..2]).is_err());
    }

    #[test]
    fn bench_file_round_trips_and_bad_values_are_refused() {
        let dir = std::env::temp_dir().join(format!("friction-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("bench.toml");
        let b = BenchFile { friction: truth() };
        std::fs::write(&p, toml::to_string(&b).unwrap()).unwrap();
        assert_eq!(Friction::load(&p).unwrap(), truth());
        std::fs::write(&p, "[friction]\ncoulomb_n = -1.0\n").unwrap();
        let e = Friction::load(&p).unwrap_err().to_string();
        assert!(e.contains("coulomb_n"), "{e}");
        std::fs::write(&p, "[friction]\ncoulmb_n = 1.0\n").unwrap();
        assert!(Friction::load(&p).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
