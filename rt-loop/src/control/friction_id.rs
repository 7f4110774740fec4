//! Friction identification (`rt-loop identify-friction`, issue 11 item 1): slow constant-velocity
//! sweeps in free air under position control, the DOB's force averaged over each segment, the
//! Coulomb/Stribeck/viscous model fitted ([`crate::control::friction::fit`]) and written to the bench
//! file that `rt-loop run --bench` (and `serve --bench`) read into the RFOB's friction model.
//!
//! Why the DOB: at constant velocity the nominal-mass term vanishes and the disturbance the
//! DOB sees is the friction, in the units the RFOB subtracts it in (K_fn times the current,
//! so a force-constant error is part of what is identified, as it should be).
//!
//! The sweeps are a piecewise-linear position trajectory replayed by the thesis's position PID
//! (the same `position-replay` experiment), on the side of the stroke away from the object
//! (x < 0), so nothing but friction and inertia acts on the probe.

use crate::board::sim::SimConfig;
use crate::board::Board;
use crate::clock::RealtimeClock;
use crate::config::{ClockKind, RunConfig};
use crate::control::friction::{fit, BenchFile, FrictionFit, SweepPoint};
use crate::control::rig::{Rig, Stop};
use crate::experiment::{Experiment, PositionPid, Trajectory};
use crate::invalid::InvalidSetting;
use anyhow::{anyhow, bail, Result};
use serde::Serialize;

/// What to sweep.
#[derive(Clone, Debug)]
pub struct SweepPlan {
    /// Speeds, m/s; each is swept in both directions.
    pub speeds_mps: Vec<f64>,
    /// The stroke's ends, m (both < 0: away from the object).
    pub x_near: f64,
    pub x_far: f64,
    /// A segment lasts at least this long (short strokes for slow speeds), s.
    pub segment_s: f64,
    /// Rest between segments, s.
    pub rest_s: f64,
}

impl Default for SweepPlan {
    fn default() -> Self {
        SweepPlan {
            speeds_mps: [
                0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 10.0, 15.0, 25.0, 40.0, 60.0,
            ]
            .iter()
            .map(|v| v * 1e-3)
            .collect(),
            x_near: -0.004,
            x_far: -0.040,
            segment_s: 3.0,
            rest_s: 0.3,
        }
    }
}

/// One constant-velocity segment of the plan: [t0, t1] at `v` m/s.
#[derive(Clone, Copy, Debug)]
struct Segment {
    t0: f64,
    t1: f64,
    v: f64,
}

impl SweepPlan {
    pub fn validate(&self, position_limit: f64) -> Result<(), InvalidSetting> {
        if self.speeds_mps.is_empty()
            || self
                .speeds_mps
                .iter()
                .any(|v| !(v.is_finite() && *v > 0.0 && *v <= 0.2))
        {
            return Err("sweep speeds must be in (0, 200] mm/s".into());
        }
        if !(self.x_far < self.x_near && self.x_near < 0.0 && -self.x_far < position_limit) {
            return Err(format!(
                "the stroke must lie in (-{position_limit}, 0) m, far end first (got {}..{})",
                self.x_far, self.x_near
            )
            .into());
        }
        if !(self.segment_s > 0.0 && self.rest_s >= 0.0) {
            return Err("segment_s must be > 0 and rest_s >= 0".into());
        }
        Ok(())
    }

    /// The sweeps as a position trajectory (what `rt-loop run --friction-sweep` replays).
    pub fn trajectory(&self) -> Result<Trajectory> {
        let (t, x, _) = self.build();
        Trajectory::new(t, x).map_err(|e| anyhow!(e))
    }

    /// The trajectory's breakpoints (t, x) and the constant-velocity segments.
    fn build(&self) -> (Vec<f64>, Vec<f64>, Vec<Segment>) {
        let (mut t, mut x) = (vec![0.0], vec![0.0]);
        let mut segs = Vec::new();
        let mut go = |t: &mut Vec<f64>, x: &mut Vec<f64>, to: f64, v: f64, seg: bool| {
            let (t0, x0) = (*t.last().unwrap(), *x.last().unwrap());
            let t1 = t0 + (to - x0).abs() / v;
            t.push(t1);
            x.push(to);
            if seg {
                segs.push(Segment {
                    t0,
                    t1,
                    v: v * (to - x0).signum(),
                });
            }
            t.push(t1 + self.rest_s);
            x.push(to);
        };
        // to the near end of the stroke at a moderate speed, then each speed out and back
        go(&mut t, &mut x, self.x_near, 0.01, false);
        let span = self.x_near - self.x_far;
        for &v in &self.speeds_mps {
            let stroke = span.min(v * self.segment_s);
            go(&mut t, &mut x, self.x_near - stroke, v, true);
            go(&mut t, &mut x, self.x_near, v, true);
        }
        go(&mut t, &mut x, 0.0, 0.01, false);
        (t, x, segs)
    }
}

/// The identification's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct Identification {
    pub fit: FrictionFit,
    pub steps: u64,
    pub loop_time_s: f64,
    /// On the simulated bench: its true friction, expressed in the loop's units (times
    /// K_fn / K_f,true), to compare the identified values with.
    pub sim_truth_loop_units: Option<crate::control::friction::Friction>,
}

/// The simulated bench's friction as the loop sees it (N of K_fn times current).
pub fn sim_truth(sim: &SimConfig, k_fn: f64) -> crate::control::friction::Friction {
    let s = k_fn / sim.force_constant;
    crate::control::friction::Friction {
        coulomb_n: sim.coulomb_n * s,
        static_n: sim.static_n * s,
        stribeck_mps: sim.stribeck_mps,
        viscous: sim.viscous * s,
        ..Default::default()
    }
}

/// Runs the sweeps on the configured board (no object: free air) and fits the model.
pub fn identify(cfg: &RunConfig, plan: &SweepPlan) -> Result<Identification> {
    cfg.params.validate().map_err(|e| anyhow!(e))?;
    plan.validate(cfg.params.position_limit)
        .map_err(|e| anyhow!(e))?;
    let (_, _, segs) = plan.build();
    let trajectory = plan.trajectory()?;
    let experiment = Experiment::PositionReplay {
        trajectory,
        pid: PositionPid::new(&cfg.params),
    };
    // No material: the bench in free air.
    let board = crate::run::build_board(cfg, None)?;
    let mut rig: Rig<Box<dyn Board>> =
        Rig::new(board, cfg.params.clone(), experiment, cfg.features.clone())
            .map_err(|f| anyhow!("board {}: {}", cfg.board, f.error))?;
    // Per segment: sums over its steady window.
    let mut acc = vec![(0.0f64, 0.0f64, 0.0f64, 0usize); segs.len()];
    let windows: Vec<(f64, f64)> = segs
        .iter()
        .map(|s| {
            let d = s.t1 - s.t0;
            (s.t0 + (0.4 * d).min(0.3), s.t1 - 0.05 * d)
        })
        .collect();
    let mut k = 0usize;
    let mut loop_time = 0.0;
    // On the realtime clock (a real board, which moves in wall time), the sweep is paced at the
    // loop's rate as `run` paces it: unpaced, the loop would spin a core flat out, and on a busy
    // machine a spinning SCHED_OTHER thread is the one the scheduler preempts for tens of ms,
    // past the card's watchdog. Lockstep (the simulated bench) runs as fast as it can.
    let mut pace = (cfg.clock == ClockKind::Realtime).then(|| RealtimeClock::new(cfg.rate_hz));
    if let Some(c) = pace.as_mut() {
        c.start();
    }
    loop {
        if let Some(c) = pace.as_mut() {
            c.wait();
        }
        match rig.step() {
            Ok(row) => {
                loop_time = row.time;
                while k < segs.len() && row.time > windows[k].1 {
                    k += 1;
                }
                if k < segs.len() && row.time >= windows[k].0 {
                    let a = &mut acc[k];
                    a.0 += row.velocity;
                    a.1 += row.dob_force;
                    a.2 += row.dob_force * row.dob_force;
                    a.3 += 1;
                }
            }
            Err(Stop::Finished) => break,
            Err(s) => bail!(
                "the friction sweep stopped: {s:?} (probe at the position limit or board fault)"
            ),
        }
    }
    rig.finish();
    let points: Vec<SweepPoint> = segs
        .iter()
        .zip(&acc)
        .map(|(s, &(sv, sf, sff, n))| {
            let nf = n.max(1) as f64;
            let mean = sf / nf;
            SweepPoint {
                v_cmd: s.v,
                v_mean: sv / nf,
                force_mean: if n > 0 { mean } else { f64::NAN },
                force_sd: (sff / nf - mean * mean).max(0.0).sqrt(),
                samples: n,
            }
        })
        .collect();
    let fit = fit(&points).map_err(|e| anyhow!(e))?;
    let truth =
        (cfg.board == crate::config::BoardKind::Sim).then(|| sim_truth(&cfg.sim, cfg.params.k_fn));
    Ok(Identification {
        fit,
        steps: rig.steps(),
        loop_time_s: loop_time,
        sim_truth_loop_units: truth,
    })
}

/// The bench file's text: the fitted friction and, as comments, how it was obtained.
pub fn bench_toml(id: &Identification, command: &str) -> Result<String> {
    let mut f = id.fit.friction;
    // the smoothing band is a rendering choice, not identified: keep the default
    f.smooth_mps = crate::control::friction::Friction::default().smooth_mps;
    let body = toml::to_string(&BenchFile { friction: f })?;
    Ok(format!(
        "# The bench configuration: friction identified by `{command}`\n\
         # ({} sweep segments, {:.1} s of loop time, fit RMS residual {:.4} N).\n\
         # Units: N as the loop measures force (K_fn times current), m/s, N s/m.\n\
         # Read by `rt-loop run --bench FILE` / `rt-loop serve --bench FILE` into the RFOB's\n\
         # friction model (F_friction_model of docs/physics.md, The loop step).\n{body}",
        id.fit.points.len(),
        id.loop_time_s,
        id.fit.rms_residual_n
    ))
}

/// Prints the sweep table and the fit (beside the simulated bench's true values), writes the
/// bench file and, optionally, the JSON of everything.
pub fn report(
    id: &Identification,
    command: &str,
    out: &std::path::Path,
    json: Option<&std::path::Path>,
) -> Result<()> {
    eprintln!(
        "rt-loop: friction sweeps ({} steps, {:.1} s loop time)",
        id.steps, id.loop_time_s
    );
    eprintln!("  v_cmd mm/s   v_meas mm/s   F_dob N   sd N   samples");
    for p in &id.fit.points {
        eprintln!(
            "  {:>9.2}   {:>11.3}   {:>7.4}   {:.3}   {}",
            1e3 * p.v_cmd,
            1e3 * p.v_mean,
            p.force_mean,
            p.force_sd,
            p.samples
        );
    }
    let f = id.fit.friction;
    let row = |n: &str, v: f64, t: Option<f64>| match t {
        Some(t) => eprintln!(
            "  {n:<14} {v:>9.4}   true {t:>9.4}   ({:+.1} %)",
            100.0 * (v / t - 1.0)
        ),
        None => eprintln!("  {n:<14} {v:>9.4}"),
    };
    let t = id.sim_truth_loop_units;
    eprintln!(
        "rt-loop: identified (fit RMS residual {:.4} N){}",
        id.fit.rms_residual_n,
        if t.is_some() {
            "; true = the simulated bench's, in loop units (x K_fn/K_f)"
        } else {
            ""
        }
    );
    row("coulomb_n", f.coulomb_n, t.map(|t| t.coulomb_n));
    row("static_n", f.static_n, t.map(|t| t.static_n));
    if f.static_n > f.coulomb_n {
        row("stribeck_mps", f.stribeck_mps, t.map(|t| t.stribeck_mps));
    } else {
        // Below the Stribeck velocity the probe sticks and slips under the PID: the averaged
        // friction there is lower than the sliding curve, so no peak shows in the sweeps.
        eprintln!("  stribeck_mps   - (no Stribeck peak in the sweeps: static_n = coulomb_n)");
    }
    row("viscous", f.viscous, t.map(|t| t.viscous));
    std::fs::write(out, bench_toml(id, command)?)
        .map_err(|e| anyhow!("cannot write {}: {e}", out.display()))?;
    eprintln!("rt-loop: bench file -> {}", out.display());
    if let Some(j) = json {
        std::fs::write(j, serde_json::to_string_pretty(id)?)
            .map_err(|e| anyhow!("cannot write {}: {e}", j.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_builds_out_and_back_segments_inside_the_stroke() {
        let p = SweepPlan::default();
        p.validate(0.05).unwrap();
        let (t, x, segs) = p.build();
        assert_eq!(segs.len(), 2 * p.speeds_mps.len());
        assert!(t.windows(2).all(|w| w[1] >= w[0]));
        assert!(x.iter().all(|&v| (p.x_far - 1e-12..=0.0).contains(&v)));
        for pair in segs.chunks(2) {
            assert!(pair[0].v < 0.0 && pair[1].v > 0.0);
            assert!((pair[0].v + pair[1].v).abs() < 1e-15);
        }
        assert!(SweepPlan {
            x_near: 0.01,
            ..SweepPlan::default()
        }
        .validate(0.05)
        .is_err());
    }

    /// On the simulated bench, the identified friction matches the bench's true friction (in
    /// the loop's units) within a few percent; a short plan keeps the test fast.
    #[test]
    fn identifies_the_simulated_bench() {
        let cfg = RunConfig::default();
        let plan = SweepPlan {
            speeds_mps: [1.0, 2.0, 4.0, 8.0, 20.0, 50.0]
                .iter()
                .map(|v| v * 1e-3)
                .collect(),
            segment_s: 1.0,
            rest_s: 0.2,
            ..SweepPlan::default()
        };
        let id = identify(&cfg, &plan).unwrap();
        let f = id.fit.friction;
        let t = id.sim_truth_loop_units.unwrap();
        assert!(
            (f.coulomb_n / t.coulomb_n - 1.0).abs() < 0.1,
            "{f:?} vs {t:?}"
        );
        assert!((f.viscous / t.viscous - 1.0).abs() < 0.25, "{f:?} vs {t:?}");
        assert!(f.static_n >= f.coulomb_n);
        let text = bench_toml(&id, "test").unwrap();
        let back: BenchFile = toml::from_str(&text).unwrap();
        assert_eq!(back.friction.coulomb_n, f.coulomb_n);
    }
}
