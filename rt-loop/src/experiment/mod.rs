//! The experiments of docs/physics.md, "The experiments": abstraction ramp cycles, position-control replay of a
//! recorded trajectory, reproduction against a simulated hand (and its shadow variant).
//! Schedules are built before the run; looking them up in the step allocates nothing.

pub mod hand;

use crate::control::filters::{Estimate, PseudoDerivative};
use crate::features::Features;
use crate::invalid::{require_non_negative, InvalidSeries, InvalidSetting};
use crate::params::LoopParams;
use crate::serving::model::{ForceModel, SpringDamper};
use serde::{Deserialize, Serialize};

/// The `phase` column: haptics-proto's.
pub use haptics_proto::Phase;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RampConfig {
    /// N/s, both up and down.
    pub ramp_rate: f64,
    pub cycles: u32,
    pub f_max_start: f64,
    pub f_max_step: f64,
    /// F_max never exceeds this, N.
    pub f_max_limit: f64,
    /// Hold at 0 N before each cycle's ramp, s.
    pub hold_zero_s: f64,
    /// Hold at F_max, s.
    pub hold_max_s: f64,
    /// Hold at 0 N after the last cycle, s.
    pub final_hold_s: f64,
    /// F_max of each cycle in this order, N (empty: from f_max_start/f_max_step; the
    /// out-of-distribution suite shuffles it so the cycle number no longer encodes the peak).
    pub f_max_list: Vec<f64>,
    /// Partial unloads (minor hysteresis loops) per cycle: from F_max down to
    /// (1 - minor_depth) F_max and back up, this many times, before the full unload.
    pub minor_loops: u32,
    pub minor_depth: f64,
    /// A ramp turns round when the probe reaches this fraction of the position limit
    /// ([`RampSchedule`]): an object too soft to carry F_max within the travel is pressed as
    /// deep as the travel allows, and the run goes on instead of stopping at the limit. In
    /// (0, 1].
    pub turn_depth_frac: f64,
}

impl Default for RampConfig {
    fn default() -> Self {
        RampConfig {
            ramp_rate: 0.8,
            cycles: 14,
            f_max_start: 1.0,
            f_max_step: 1.0,
            f_max_limit: 14.0,
            hold_zero_s: 1.5,
            hold_max_s: 1.0,
            final_hold_s: 1.5,
            f_max_list: Vec::new(),
            minor_loops: 0,
            minor_depth: 0.5,
            turn_depth_frac: 0.8,
        }
    }
}

impl RampConfig {
    /// The options a start sets (`--ramp-rate`, `--cycles`, `--f-max-start`, `--f-max-step`,
    /// or a start command's values) over this configuration.
    pub fn override_with(&mut self, a: &haptics_proto::experiment_args::ExperimentArgs) {
        if let Some(v) = a.ramp_rate {
            self.ramp_rate = v;
        }
        if let Some(v) = a.cycles {
            self.cycles = v;
        }
        if let Some(v) = a.f_max_start {
            self.f_max_start = v;
        }
        if let Some(v) = a.f_max_step {
            self.f_max_step = v;
        }
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.ramp_rate.is_finite() && self.ramp_rate > 0.0) {
            return Err(format!("ramp rate must be > 0 N/s (got {})", self.ramp_rate).into());
        }
        if self.cycles == 0 {
            return Err("cycles must be >= 1".into());
        }
        if let Some(v) = self
            .f_max_list
            .iter()
            .find(|v| !(v.is_finite() && **v > 0.0))
        {
            return Err(format!("every F_max in the list must be > 0 N (got {v})").into());
        }
        if !(self.minor_depth.is_finite() && self.minor_depth > 0.0 && self.minor_depth < 1.0) {
            return Err(format!("minor_depth must be in (0, 1) (got {})", self.minor_depth).into());
        }
        if !(self.turn_depth_frac.is_finite()
            && self.turn_depth_frac > 0.0
            && self.turn_depth_frac <= 1.0)
        {
            return Err(format!(
                "turn_depth_frac must be in (0, 1] of the position limit (got {})",
                self.turn_depth_frac
            )
            .into());
        }
        require_non_negative(&[
            ("f_max_start", self.f_max_start),
            ("f_max_step", self.f_max_step),
            ("f_max_limit", self.f_max_limit),
            ("hold_zero_s", self.hold_zero_s),
            ("hold_max_s", self.hold_max_s),
            ("final_hold_s", self.final_hold_s),
        ])?;
        if self.f_max_limit > 15.0 {
            return Err("f_max_limit above 15 N exceeds the motor's continuous force".into());
        }
        Ok(())
    }

    pub fn f_max(&self, cycle: u32) -> f64 {
        let f = match self.f_max_list.get(cycle as usize) {
            Some(&f) => f,
            None => self.f_max_start + self.f_max_step * cycle as f64,
        };
        f.min(self.f_max_limit)
    }

    /// Cycles run: the list's length when one is given.
    pub fn n_cycles(&self) -> u32 {
        if self.f_max_list.is_empty() {
            self.cycles
        } else {
            self.f_max_list.len() as u32
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Segment {
    t0: f64,
    t1: f64,
    f0: f64,
    f1: f64,
    phase: Phase,
    /// The cycle this segment belongs to (`u32::MAX`: the final hold).
    cycle: u32,
}

/// The piecewise-linear force command of the abstraction phase.
///
/// A force ramp presses an object as deep as its F_max takes it. An object too soft to carry
/// F_max within the bench's travel would run the probe into the position limit, and the run
/// would stop there with the rest of the programme unrecorded. So the schedule **turns
/// round at a depth** (`turn_depth_m`, by default 0.8 of the position limit: see
/// [`RampConfig::turn_depth_frac`]): when the probe reaches it while the force is rising or
/// held, that cycle unloads from the force reached, and every later cycle's F_max is capped at
/// that force (the lowest such force, if it happens again). A rig operator does the same by
/// hand. The objects of this repository never reach it (their ramps stay within 30 mm).
#[derive(Clone, Debug)]
pub struct RampSchedule {
    segs: Vec<Segment>,
    cursor: usize,
    shape: RampShape,
    /// Each cycle's F_max as planned, N.
    f_max: Vec<f64>,
    turn_depth_m: f64,
    turns: RampTurns,
}

/// How far ahead a ramp looks for the turn depth, s: the probe goes on after the force
/// command turns (its mass, the force loop's lag), about 10 mm at 80 mm/s on a 100 N/m pad
/// ramped at 8 N/s, the whole margin to the position limit. Looking further ahead turns
/// ramps on objects that would have stopped the probe by themselves: the default sponge
/// ramped at 50 N/s reaches 30 mm at up to 70 mm/s.
pub const TURN_LOOKAHEAD_S: f64 = 0.05;

/// The timing of a cycle (from [`RampConfig`]), kept to rebuild the cycles after a turn.
#[derive(Clone, Copy, Debug)]
struct RampShape {
    ramp_rate: f64,
    hold_zero_s: f64,
    hold_max_s: f64,
    final_hold_s: f64,
    minor_loops: u32,
    minor_depth: f64,
}

/// How often and where the ramps turned round at the depth bound ([`RampSchedule`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct RampTurns {
    /// The depth at which a ramp turns round, m.
    pub turn_depth_m: f64,
    /// Cycles that turned round before their planned F_max.
    pub cycles_turned: u32,
    /// The force every later cycle is capped at (the lowest force reached at a turn), N; 0 when
    /// no cycle turned.
    pub f_cap_n: f64,
}

impl RampSchedule {
    /// The schedule of `c`, turning round at `c.turn_depth_frac` of `position_limit_m`.
    pub fn new(c: &RampConfig, position_limit_m: f64) -> Self {
        let shape = RampShape {
            ramp_rate: c.ramp_rate,
            hold_zero_s: c.hold_zero_s,
            hold_max_s: c.hold_max_s,
            final_hold_s: c.final_hold_s,
            minor_loops: c.minor_loops,
            minor_depth: c.minor_depth,
        };
        let f_max: Vec<f64> = (0..c.n_cycles()).map(|k| c.f_max(k)).collect();
        let turn_depth_m = c.turn_depth_frac * position_limit_m;
        let mut s = RampSchedule {
            segs: Vec::new(),
            cursor: 0,
            shape,
            f_max,
            turn_depth_m,
            turns: RampTurns {
                turn_depth_m,
                ..RampTurns::default()
            },
        };
        s.build_from(0, 0.0, f64::INFINITY);
        s
    }

    /// Appends the cycles from `first` on, starting at `t`, each F_max capped at `cap`, and
    /// the final hold. Allocates only when the segments outgrow their capacity: never after a
    /// turn, which replaces the rest of a cycle by one segment and leaves the later cycles
    /// their number of segments.
    fn build_from(&mut self, first: usize, mut t: f64, cap: f64) {
        let c = self.shape;
        let segs = &mut self.segs;
        let mut push = |len: f64, f0: f64, f1: f64, phase, cycle: u32| {
            segs.push(Segment {
                t0: t,
                t1: t + len,
                f0,
                f1,
                phase,
                cycle,
            });
            t += len;
        };
        for (k, &planned) in self.f_max.iter().enumerate().skip(first) {
            let (fm, k) = (planned.min(cap), k as u32);
            push(c.hold_zero_s, 0.0, 0.0, Phase::HoldZero, k);
            push(fm / c.ramp_rate, 0.0, fm, Phase::RampUp, k);
            push(c.hold_max_s, fm, fm, Phase::HoldMax, k);
            let fl = fm * (1.0 - c.minor_depth);
            for _ in 0..c.minor_loops {
                push((fm - fl) / c.ramp_rate, fm, fl, Phase::RampDown, k);
                push((fm - fl) / c.ramp_rate, fl, fm, Phase::RampUp, k);
                push(c.hold_max_s, fm, fm, Phase::HoldMax, k);
            }
            push(fm / c.ramp_rate, fm, 0.0, Phase::RampDown, k);
        }
        push(c.final_hold_s, 0.0, 0.0, Phase::HoldZero, u32::MAX);
    }

    pub fn duration(&self) -> f64 {
        self.segs.last().map_or(0.0, |s| s.t1)
    }

    /// The turns so far.
    pub fn turns(&self) -> RampTurns {
        self.turns
    }

    /// Command at time `t` (s since the run started); times only move forward, so the lookup
    /// walks a cursor.
    #[inline]
    pub fn at(&mut self, t: f64) -> (Phase, f64) {
        while self.cursor < self.segs.len() && t >= self.segs[self.cursor].t1 {
            self.cursor += 1;
        }
        match self.segs.get(self.cursor) {
            None => (Phase::Done, 0.0),
            Some(s) => {
                let u = if s.t1 > s.t0 {
                    (t - s.t0) / (s.t1 - s.t0)
                } else {
                    1.0
                };
                (s.phase, s.f0 + (s.f1 - s.f0) * u.clamp(0.0, 1.0))
            }
        }
    }

    /// Command at time `t` with the probe at depth `x` (m) moving at `v` (m/s): as
    /// [`Self::at`], turning the cycle round first when the probe will reach the turn depth
    /// within [`TURN_LOOKAHEAD_S`] while the force is rising or held. Runs on the loop thread:
    /// no allocation (the rebuilt segments fit the capacity the schedule was built with), no
    /// lock.
    #[inline]
    pub fn at_depth(&mut self, t: f64, x: f64, v: f64) -> (Phase, f64) {
        let (phase, f) = self.at(t);
        let ahead = x + TURN_LOOKAHEAD_S * v.max(0.0);
        if ahead >= self.turn_depth_m && f > 0.0 && matches!(phase, Phase::RampUp | Phase::HoldMax)
        {
            self.turn(t, f);
            return self.at(t);
        }
        (phase, f)
    }

    /// Unloads the current cycle from `f` (N) at `t`, and caps every later cycle at `f`.
    fn turn(&mut self, t: f64, f: f64) {
        let Some(cycle) = self.segs.get(self.cursor).map(|s| s.cycle) else {
            return;
        };
        let cap = if self.turns.cycles_turned == 0 {
            f
        } else {
            self.turns.f_cap_n.min(f)
        };
        self.turns.f_cap_n = cap;
        self.turns.cycles_turned += 1;
        let capacity = self.segs.capacity();
        self.segs.truncate(self.cursor);
        let len = f / self.shape.ramp_rate;
        self.segs.push(Segment {
            t0: t,
            t1: t + len,
            f0: f,
            f1: 0.0,
            phase: Phase::RampDown,
            cycle,
        });
        self.build_from(cycle as usize + 1, t + len, cap);
        debug_assert_eq!(self.segs.capacity(), capacity, "a turn must not allocate");
    }
}

/// A recorded position trajectory x(t), linearly interpolated.
#[derive(Clone, Debug)]
pub struct Trajectory {
    t: Vec<f64>,
    x: Vec<f64>,
    cursor: usize,
}

impl Trajectory {
    pub fn new(t: Vec<f64>, x: Vec<f64>) -> Result<Self, InvalidSeries> {
        if t.len() != x.len() || t.len() < 2 {
            return Err("a trajectory needs at least two (time, position) samples".into());
        }
        // every value checked, the first one included (a NaN compares false both ways)
        if let Some(i) = t.iter().position(|v| !v.is_finite()) {
            return Err(format!("row {}: time = {} is not finite", i + 1, t[i]).into());
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(format!("row {}: position_x = {} is not finite", i + 1, x[i]).into());
        }
        if let Some(i) = t.windows(2).position(|w| w[1] < w[0]) {
            return Err(format!("row {}: time goes backwards", i + 2).into());
        }
        Ok(Trajectory { t, x, cursor: 0 })
    }

    /// Loads `time` and `position_x` from a recording.
    pub fn from_recording(path: &std::path::Path) -> anyhow::Result<Self> {
        let mut cols = crate::record::read::read_columns(path, &["time", "position_x"])?;
        let x = cols.pop().unwrap_or_default();
        let t = cols.pop().unwrap_or_default();
        Trajectory::new(t, x).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    pub fn duration(&self) -> f64 {
        self.t.last().copied().unwrap_or(0.0) - self.t[0]
    }

    pub fn max_abs(&self) -> f64 {
        self.x.iter().fold(0.0, |m, v| m.max(v.abs()))
    }

    /// Position at `t` seconds after the trajectory's start; `None` past its end.
    #[inline]
    pub fn at(&mut self, t: f64) -> Option<f64> {
        let t = t + self.t[0];
        let last = self.t.len() - 1;
        if t > self.t[last] {
            return None;
        }
        while self.cursor + 1 < last && self.t[self.cursor + 1] <= t {
            self.cursor += 1;
        }
        let (t0, t1) = (self.t[self.cursor], self.t[self.cursor + 1]);
        let (x0, x1) = (self.x[self.cursor], self.x[self.cursor + 1]);
        if t1 > t0 {
            Some(x0 + (x1 - x0) * ((t - t0) / (t1 - t0)).clamp(0.0, 1.0))
        } else {
            Some(x1)
        }
    }
}

/// Position PID of the thesis's validation (current = PID * M_n / K_fn, plus the DOB's
/// disturbance estimate when `pid_dob`).
#[derive(Clone, Debug)]
pub struct PositionPid {
    ref_vel: PseudoDerivative,
    integ: f64,
}

impl PositionPid {
    pub fn new(p: &LoopParams) -> Self {
        PositionPid {
            ref_vel: PseudoDerivative::new(p.g_v),
            integ: 0.0,
        }
    }

    /// Current before the clamp.
    #[inline]
    pub fn current(&mut self, x_ref: f64, dt: f64, est: &Estimate, p: &LoopParams) -> f64 {
        let e = x_ref - est.x;
        // Reference velocity through the same pseudo-derivative as the measured one, so the D
        // term compares like with like.
        let v_ref = self.ref_vel.update(x_ref, dt);
        self.integ += e * dt;
        let acc = p.pid_p * e + p.pid_d * (v_ref - est.v) + p.pid_i * self.integ;
        let dob = if p.pid_dob { est.f_dis / p.k_fn } else { 0.0 };
        acc * p.m_n / p.k_fn + dob
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReproductionConfig {
    /// The force limit, N: an answer above it is rendered at it and counted as saturated
    /// (`ladder.saturated`), never replaced by the fallback.
    pub max_force_n: f64,
    /// The fallback law (and the built-in model).
    pub fallback: SpringDamper,
}

impl Default for ReproductionConfig {
    fn default() -> Self {
        ReproductionConfig {
            max_force_n: 20.0,
            fallback: SpringDamper::default(),
        }
    }
}

/// Counters of the model hook.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ModelStats {
    pub served: u64,
    pub fallbacks: u64,
}

/// What the loop should do this step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    /// Force control toward F_cmd (N).
    Force(f64),
    /// Position control toward x_ref (m).
    Position(f64),
    /// The experiment is over.
    Done,
}

/// The output of an experiment for one step.
#[derive(Clone, Copy, Debug)]
pub struct Decision {
    pub phase: Phase,
    pub command: Command,
    pub f_pred: f64,
    pub fallback: bool,
    /// The force the features take as "the step's force" (F_res, or F_pred in reproduction).
    pub feature_force: f64,
    /// The served model whose answer the step rendered or held (`ForceMsg.model_id`); 0 when
    /// none did (other experiments, the fallback, a built-in model).
    pub model_id: u32,
}

// One Experiment lives in the Rig for the whole run and is never moved in the step: its size
// costs nothing, while boxing the reproduction's state would add an indirection every step.
#[allow(clippy::large_enum_variant)]
pub enum Experiment {
    Abstraction(RampSchedule),
    PositionReplay {
        trajectory: Trajectory,
        pid: PositionPid,
    },
    /// Reproduction (`shadow = false`): no object, the motor renders F_cmd = -F_pred against
    /// the hand. Shadow (`shadow = true`): the hand presses the real (simulated) sponge through
    /// a transparent motor (F_cmd = 0) while the model predicts alongside.
    Reproduction {
        model: Box<dyn ForceModel>,
        cfg: ReproductionConfig,
        duration: f64,
        shadow: bool,
        stats: ModelStats,
        /// What is rendered when the model's answer is not there in time (issue 14).
        ladder: crate::serving::ladder::Ladder,
    },
}

impl Experiment {
    pub fn name(&self) -> &'static str {
        match self {
            Experiment::Abstraction(_) => "abstraction",
            Experiment::PositionReplay { .. } => "position-replay",
            Experiment::Reproduction { shadow: false, .. } => "reproduction",
            Experiment::Reproduction { shadow: true, .. } => "shadow",
        }
    }

    pub fn duration(&self) -> f64 {
        match self {
            Experiment::Abstraction(s) => s.duration(),
            Experiment::PositionReplay { trajectory, .. } => trajectory.duration(),
            Experiment::Reproduction { duration, .. } => *duration,
        }
    }

    /// Prepares the experiment for its first step (off the real-time path).
    pub fn begin(&mut self) {
        if let Experiment::Reproduction { model, .. } = self {
            model.begin_run();
        }
    }

    /// The model, given back when the run is over (`None`: this experiment has none).
    pub fn into_model(self) -> Option<Box<dyn ForceModel>> {
        match self {
            Experiment::Reproduction { model, .. } => Some(model),
            _ => None,
        }
    }

    /// The ladder's figures of a reproduction/shadow run (`None` for other experiments).
    pub fn ladder_report(&self) -> Option<crate::serving::ladder::LadderReport> {
        match self {
            Experiment::Reproduction { ladder, .. } => Some(ladder.report()),
            _ => None,
        }
    }

    /// The abstraction ramps' turns at the depth bound (`None` for other experiments).
    pub fn ramp_turns(&self) -> Option<RampTurns> {
        match self {
            Experiment::Abstraction(s) => Some(s.turns()),
            _ => None,
        }
    }

    pub fn model_stats(&self) -> Option<ModelStats> {
        match self {
            Experiment::Reproduction { stats, .. } => Some(*stats),
            _ => None,
        }
    }

    /// Lets the model fill its part of the loop-status block (no allocation, no lock).
    pub fn report_status(&self, status: &mut haptics_proto::LoopStatus) {
        if let Experiment::Reproduction { model, .. } = self {
            model.report_status(status);
        }
    }

    /// Decides the step. Runs on the loop thread: no allocation (the model hook is required
    /// to allocate nothing either).
    #[inline]
    pub fn decide(&mut self, step: u64, time: f64, est: &Estimate, feats: &Features) -> Decision {
        match self {
            Experiment::Abstraction(s) => {
                let (phase, f) = s.at_depth(time, est.x, est.v);
                Decision {
                    phase,
                    command: if phase == Phase::Done {
                        Command::Done
                    } else {
                        Command::Force(f)
                    },
                    f_pred: f64::NAN,
                    fallback: false,
                    feature_force: est.f_ext,
                    model_id: 0,
                }
            }
            Experiment::PositionReplay { trajectory, .. } => {
                let (phase, command) = match trajectory.at(time) {
                    Some(x) => (Phase::Position, Command::Position(x)),
                    None => (Phase::Done, Command::Done),
                };
                Decision {
                    phase,
                    command,
                    f_pred: f64::NAN,
                    fallback: false,
                    feature_force: est.f_ext,
                    model_id: 0,
                }
            }
            Experiment::Reproduction {
                model,
                duration,
                shadow,
                stats,
                ladder,
                ..
            } => {
                if time >= *duration {
                    return Decision {
                        phase: Phase::Done,
                        command: Command::Done,
                        f_pred: f64::NAN,
                        fallback: false,
                        feature_force: 0.0,
                        model_id: 0,
                    };
                }
                // the ladder asks the model and replaces a missing answer without a jump;
                // `fallback` marks every step not rendered by the model's on-time answer
                let r = ladder.render(model.as_mut(), step, time, feats);
                let (f_pred, fallback) =
                    (r.force, r.level != crate::serving::ladder::Level::OnTime);
                // the held value is the last served answer; the fallback is no served model's
                let model_id = match r.level {
                    crate::serving::ladder::Level::Fallback => 0,
                    _ => model.model_id(),
                };
                if fallback {
                    stats.fallbacks += 1;
                } else {
                    stats.served += 1;
                }
                Decision {
                    phase: Phase::Reproduction,
                    command: Command::Force(if *shadow { 0.0 } else { -f_pred }),
                    f_pred,
                    fallback,
                    feature_force: f_pred,
                    model_id,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_schedule_shape() {
        let c = RampConfig {
            ramp_rate: 2.0,
            cycles: 3,
            f_max_start: 1.0,
            f_max_step: 1.0,
            f_max_limit: 14.0,
            hold_zero_s: 1.0,
            hold_max_s: 0.5,
            final_hold_s: 1.0,
            ..RampConfig::default()
        };
        let mut s = RampSchedule::new(&c, 0.05);
        // 3 cycles: holds 3*1 + 3*0.5 + ramps 2*(1+2+3)/2 = 6 + final 1
        assert!((s.duration() - (3.0 + 1.5 + 6.0 + 1.0)).abs() < 1e-12);
        assert_eq!(s.at(0.5), (Phase::HoldZero, 0.0));
        let (p, f) = s.at(1.25);
        assert_eq!(p, Phase::RampUp);
        assert!((f - 0.5).abs() < 1e-12);
        assert_eq!(s.at(1.6).0, Phase::HoldMax);
        let (p, f) = s.at(2.25);
        assert_eq!(p, Phase::RampDown);
        assert!((f - 0.5).abs() < 1e-12);
        // cycle 2 (F_max 2 N) ramps from t = 3.5 s to 4.5 s
        let (p, f) = s.at(4.0);
        assert_eq!(p, Phase::RampUp);
        assert!((f - 1.0).abs() < 1e-9);
        assert_eq!(s.at(4.75), (Phase::HoldMax, 2.0));
        assert_eq!(s.at(100.0).0, Phase::Done);
    }

    /// A given F_max order replaces the start/step schedule (cycles = the list's length), and
    /// partial unloads go down to (1 - depth) F_max and back before the full unload.
    #[test]
    fn f_max_list_and_minor_loops() {
        let c = RampConfig {
            ramp_rate: 1.0,
            f_max_list: vec![4.0, 2.0],
            minor_loops: 1,
            minor_depth: 0.5,
            hold_zero_s: 1.0,
            hold_max_s: 1.0,
            final_hold_s: 1.0,
            ..RampConfig::default()
        };
        c.validate().unwrap();
        assert_eq!(c.n_cycles(), 2);
        assert_eq!((c.f_max(0), c.f_max(1)), (4.0, 2.0));
        let mut s = RampSchedule::new(&c, 0.05);
        // cycle 1: hold 1, up 4, hold 1, down 2 (to 2 N), up 2, hold 1, down 4 = 15 s;
        // cycle 2: 1 + 2 + 1 + 1 + 1 + 1 + 2 = 9 s; final 1 s
        assert!((s.duration() - 25.0).abs() < 1e-12);
        assert_eq!(s.at(5.5), (Phase::HoldMax, 4.0));
        let (p, f) = s.at(7.0);
        assert_eq!(p, Phase::RampDown);
        assert!((f - 3.0).abs() < 1e-12);
        let (p, f) = s.at(7.99);
        assert_eq!(p, Phase::RampDown);
        assert!((f - 2.0).abs() < 0.02, "the partial unload's bottom: {f}");
        let (p, f) = s.at(9.0);
        assert_eq!(p, Phase::RampUp);
        assert!((f - 3.0).abs() < 1e-12);
        assert_eq!(s.at(10.5), (Phase::HoldMax, 4.0));
        assert_eq!(s.at(18.5), (Phase::HoldMax, 2.0));
        let bad = RampConfig {
            f_max_list: vec![3.0, -1.0],
            ..RampConfig::default()
        };
        assert!(bad.validate().is_err());
    }

    /// An object too soft for F_max: the probe reaches the turn depth on the way up, that cycle
    /// unloads from the force reached, every later cycle is capped at it, and nothing is
    /// allocated by the turn.
    #[test]
    fn a_ramp_turns_round_at_the_depth_bound() {
        let c = RampConfig {
            ramp_rate: 1.0,
            f_max_list: vec![2.0, 6.0, 8.0],
            minor_loops: 1,
            hold_zero_s: 1.0,
            hold_max_s: 1.0,
            final_hold_s: 1.0,
            ..RampConfig::default()
        };
        c.validate().unwrap();
        let mut s = RampSchedule::new(&c, 0.05);
        let capacity = s.segs.capacity();
        let planned = s.duration();
        // cycle 1 (2 N) stays shallow: no turn
        assert_eq!(s.at_depth(2.5, 0.010, 0.0), (Phase::RampUp, 1.5));
        assert_eq!(s.at_depth(3.5, 0.010, 0.0), (Phase::HoldMax, 2.0));
        assert_eq!(s.turns().cycles_turned, 0);
        // cycle 2 starts at t = 1 + 2 + 1 + (1 + 1 + 1) + 2 = 9 s, ramps from 10 s; at 14 s
        // (4 N) the probe passes 40 mm (0.8 of 50 mm): it turns round from 4 N
        assert_eq!(s.at_depth(12.0, 0.030, 0.0), (Phase::RampUp, 2.0));
        let (p, f) = s.at_depth(14.0, 0.041, 0.0);
        assert_eq!((p, f), (Phase::RampDown, 4.0));
        let t = s.turns();
        assert_eq!((t.cycles_turned, t.f_cap_n), (1, 4.0));
        assert!((t.turn_depth_m - 0.040).abs() < 1e-12);
        // the unload takes 4 s; cycle 3 (planned 8 N) is capped at 4 N: hold 18-19, up 19-23
        let (p, f) = s.at_depth(16.0, 0.030, 0.0);
        assert_eq!(p, Phase::RampDown);
        assert!((f - 2.0).abs() < 1e-12);
        assert_eq!(s.at_depth(18.5, 0.0, 0.0), (Phase::HoldZero, 0.0));
        let (p, f) = s.at_depth(22.0, 0.030, 0.0);
        assert_eq!(p, Phase::RampUp);
        assert!((f - 3.0).abs() < 1e-12);
        assert_eq!(s.at_depth(23.5, 0.035, 0.0), (Phase::HoldMax, 4.0));
        // a hold that creeps past the bound turns round too, and the cap only goes down
        let (p, f) = s.at_depth(23.8, 0.045, 0.0);
        assert_eq!((p, f), (Phase::RampDown, 4.0));
        assert_eq!(s.turns().cycles_turned, 2);
        assert_eq!(s.turns().f_cap_n, 4.0);
        // 23.8 + 4 s of unload + the final hold
        assert!((s.duration() - 28.8).abs() < 1e-9, "{}", s.duration());
        assert!(s.duration() < planned);
        assert_eq!(s.at_depth(30.0, 0.0, 0.0).0, Phase::Done);
        assert_eq!(s.segs.capacity(), capacity, "a turn allocates nothing");
        // unloading or at rest, depth alone turns nothing
        let mut s = RampSchedule::new(&c, 0.05);
        // a fast press turns ahead of the depth: 37 mm at 80 mm/s reaches 40 mm within 0.05 s
        assert_eq!(s.at_depth(12.0, 0.037, 0.08), (Phase::RampDown, 2.0));
        let mut s = RampSchedule::new(&c, 0.05);
        assert_eq!(s.at_depth(0.5, 0.045, 0.0), (Phase::HoldZero, 0.0));
        assert_eq!(s.turns().cycles_turned, 0);
        let bad = RampConfig {
            turn_depth_frac: 1.5,
            ..RampConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("turn_depth_frac"));
    }

    #[test]
    fn trajectory_interpolates_and_ends() {
        let mut t = Trajectory::new(vec![10.0, 11.0, 12.0], vec![0.0, 0.01, 0.0]).unwrap();
        assert_eq!(t.at(0.0), Some(0.0));
        assert!((t.at(0.5).unwrap() - 0.005).abs() < 1e-12);
        assert!((t.at(1.5).unwrap() - 0.005).abs() < 1e-12);
        assert_eq!(t.at(2.5), None);
        assert!(Trajectory::new(vec![1.0, 0.0], vec![0.0, 0.0]).is_err());
    }
}
