//! The degradation ladder of reproduction (issue 14; docs/physics.md, "The loop step": it
//! never jumps): what the loop renders when the served model's answer to this step is not there in time.
//!
//! Before, every late answer switched the rendered force from the model to the spring-damper
//! fallback (about 1 N away) and back at the next step: force steps a hand feels as buzzing.
//! Now each step takes the first rung that is available:
//!
//! 1. `on_time`: the model's answer to this step, within the deadline;
//! 2. `late_one`: the answer to the previous step, arriving one period late (during this step's
//!    wait, or between the steps);
//! 3. `held`: the last served force, extrapolated with the local stiffness dF/dx estimated from
//!    the recent served forces and positions (bounded), for at most `hold_max_s`;
//! 4. `fallback`: the fallback law, cross-faded in over `crossfade_s` (and cross-faded out over
//!    the same time when the model answers again), its output clamped to the force limit.
//!
//! Any change of rung is slew-limited: while a transition is under way the rendered force moves
//! by at most `slew_n_per_step` per step, and the largest step it took is measured
//! (`max_transition_step_n`). Every step that is not rendered by the on-time answer has one
//! counted reason ([`Reasons`]), so `late_one + held + fallback == sum of the reasons`.
//!
//! Unilateral rendering (issue 11 item 7): the rendered object only pushes. Every rung's force
//! is clamped to `[0, max_force_n]`, and it is 0 out of contact (x <= 0). With F_cmd = -F_pred
//! (docs/physics.md, "The experiments") a non-negative F_pred can only push the probe back out of the object.
//!
//! Saturation (issue 23 item 5): a finite answer above `max_force_n` is rendered AT the limit
//! and counted as `saturated` (a count beside the rungs: such a step is still rendered by its
//! rung, on time or late one). A device saturates, it does not switch objects: before, such an
//! answer was refused and the fallback law (another object, about 1 N away) took over, so a
//! stiff object's oracle lost every deep press to the fallback and stopped being the floor.
//! Only NaN/Inf answers are still refused (`rejected`).
//!
//! REAL-TIME PATH: [`Ladder::render`] allocates nothing, takes no lock and makes no syscall:
//! fixed-size arrays and plain f64 arithmetic; the model hook it calls has the same contract.

use crate::features::Features;
use crate::invalid::{require_within, InvalidSetting};
use crate::serving::model::{Answer, ForceModel, Miss, SpringDamper};
use serde::{Deserialize, Serialize};

/// `[ladder]` of the run configuration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LadderConfig {
    /// Longest time the last served force is held (extrapolated) before the fallback comes, s.
    pub hold_max_s: f64,
    /// Time over which the fallback is faded in (and out again when the model answers), s.
    pub crossfade_s: f64,
    /// Largest change of the rendered force in one step while a transition is under way, N.
    pub slew_n_per_step: f64,
    /// Bound on the local stiffness used to extrapolate a held force, N/m.
    pub stiffness_max_n_per_m: f64,
}

impl Default for LadderConfig {
    fn default() -> Self {
        LadderConfig {
            hold_max_s: 0.003,
            crossfade_s: 0.005,
            slew_n_per_step: 0.04,
            stiffness_max_n_per_m: 5000.0,
        }
    }
}

/// The goal for the change of rendered force any transition causes in one step.
pub const MAX_SLEW_N_PER_STEP: f64 = 0.05;

impl LadderConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        require_within("ladder.hold_max_s", self.hold_max_s, 0.0..=0.1, "0..0.1 s")?;
        require_within("ladder.crossfade_s", self.crossfade_s, 0.0..=1.0, "0..1 s")?;
        let slew = self.slew_n_per_step;
        if !(slew.is_finite() && slew > 0.0 && slew <= MAX_SLEW_N_PER_STEP) {
            return Err(format!(
                "ladder.slew_n_per_step must be within (0, {MAX_SLEW_N_PER_STEP}] N (got {slew})"
            )
            .into());
        }
        require_within(
            "ladder.stiffness_max_n_per_m",
            self.stiffness_max_n_per_m,
            0.0..=1e6,
            "0..1e6 N/m",
        )?;
        Ok(())
    }
}

/// The rung that rendered a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Level {
    OnTime,
    LateOne,
    Held,
    Fallback,
}

/// Steps per rung (`"ladder"` in the run summary). Every step of a reproduction run is counted
/// in exactly one of them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LadderCounts {
    pub on_time: u64,
    pub late_one: u64,
    pub held: u64,
    pub fallback: u64,
    /// Of the steps rendered by a model's answer (on_time + late_one), those whose answer was
    /// above `max_force_n` and were rendered at the limit. Not a rung: not part of
    /// [`LadderCounts::total`].
    pub saturated: u64,
}

impl LadderCounts {
    pub fn total(&self) -> u64 {
        self.on_time + self.late_one + self.held + self.fallback
    }
}

/// Why a step was not rendered by its on-time answer (one reason per such step).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Reasons {
    /// This step's answer missed its deadline (the deadline misses of the run).
    pub late: u64,
    /// No server attached (or it is settling after attaching): nothing was sent.
    pub no_server: u64,
    /// The features ring was full: the server is far behind.
    pub ring_full: u64,
    /// The server flagged its answer (no model, schema mismatch, NaN output, bad features).
    pub flagged: u64,
    /// The server went away during the step.
    pub server_lost: u64,
    /// Lockstep: the server missed several answers in a row and its heartbeat has not moved
    /// since; it is treated as gone (nothing sent) until the heartbeat moves.
    pub hung: u64,
    /// An answer came but was NaN/Inf (an answer beyond `max_force_n` saturates instead).
    pub rejected: u64,
}

impl Reasons {
    pub fn total(&self) -> u64 {
        self.late
            + self.no_server
            + self.ring_full
            + self.flagged
            + self.server_lost
            + self.hung
            + self.rejected
    }

    #[inline]
    fn count(&mut self, m: Miss) {
        let c = match m {
            Miss::Late => &mut self.late,
            Miss::NoServer => &mut self.no_server,
            Miss::RingFull => &mut self.ring_full,
            Miss::Flagged => &mut self.flagged,
            Miss::ServerLost => &mut self.server_lost,
            Miss::Hung => &mut self.hung,
            Miss::Rejected => &mut self.rejected,
        };
        *c += 1;
    }
}

/// Everything the ladder measured in one run (the summary's `ladder`, `degraded_reasons`,
/// `max_transition_step_n` and `transition_steps`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct LadderReport {
    pub counts: LadderCounts,
    pub reasons: Reasons,
    /// Largest change of the rendered force in one step while a transition was under way, N.
    pub max_transition_step_n: f64,
    /// Steps during which a transition (slew catch-up or cross-fade) was under way.
    pub transition_steps: u64,
}

/// Served positions and forces kept for the local-stiffness estimate.
const HISTORY: usize = 16;
/// Below this spread of the recent positions the stiffness is not re-estimated, m (4 counts).
const MIN_X_SPREAD: f64 = 2e-5;

/// One rendered step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rendered {
    /// The force rendered (F_pred, N, >= 0; the loop commands -force).
    pub force: f64,
    pub level: Level,
}

/// The ladder's state for one run. Built before the run; [`Ladder::render`] is the per-step
/// part.
#[derive(Clone, Debug)]
pub struct Ladder {
    cfg: LadderConfig,
    max_force_n: f64,
    fallback: SpringDamper,
    /// Fallback weight change per step (1 / cross-fade steps; 1 for no cross-fade).
    fade_per_step: f64,
    /// Weight of the fallback in the rendered force, 0..1.
    w: f64,
    /// The model side of the blend: the served force, or the held extrapolation.
    model_side: f64,
    last_served_f: f64,
    last_served_x: f64,
    last_served_time: f64,
    stiffness: f64,
    hist_x: [f64; HISTORY],
    hist_f: [f64; HISTORY],
    hist_len: usize,
    hist_next: usize,
    prev_level: Level,
    prev_rendered: f64,
    slewing: bool,
    report: LadderReport,
}

impl Ladder {
    /// `period_s`: the loop's nominal period (the cross-fade is counted in steps of it).
    pub fn new(
        cfg: &LadderConfig,
        max_force_n: f64,
        fallback: SpringDamper,
        period_s: f64,
    ) -> Self {
        let fade_steps = (cfg.crossfade_s / period_s).round();
        Ladder {
            cfg: cfg.clone(),
            max_force_n,
            fallback,
            fade_per_step: if fade_steps >= 1.0 {
                1.0 / fade_steps
            } else {
                1.0
            },
            w: 0.0,
            model_side: 0.0,
            last_served_f: 0.0,
            last_served_x: 0.0,
            last_served_time: 0.0,
            stiffness: 0.0,
            hist_x: [0.0; HISTORY],
            hist_f: [0.0; HISTORY],
            hist_len: 0,
            hist_next: 0,
            prev_level: Level::OnTime,
            prev_rendered: 0.0,
            slewing: false,
            report: LadderReport::default(),
        }
    }

    pub fn report(&self) -> LadderReport {
        self.report
    }

    /// The fallback law's force, unilateral and within the force limit.
    #[inline]
    fn fallback_force(&self, x: f64, v: f64) -> f64 {
        let f = self.fallback.eval(x, v);
        if f.is_finite() {
            f.clamp(0.0, self.max_force_n)
        } else {
            0.0
        }
    }

    /// A served force accepted: the rung's force within `[0, max_force_n]` and whether it was
    /// above the limit (saturated); NaN/Inf refused. A finite answer beyond the limit is the
    /// limit, as a real device saturates (see the module doc); a negative one is 0 (unilateral).
    #[inline]
    fn accept(&self, f: f64) -> Option<(f64, bool)> {
        f.is_finite()
            .then(|| (f.clamp(0.0, self.max_force_n), f > self.max_force_n))
    }

    #[inline]
    fn remember(&mut self, x: f64, f: f64, time: f64) {
        self.last_served_f = f;
        self.last_served_x = x;
        self.last_served_time = time;
        self.hist_x[self.hist_next] = x;
        self.hist_f[self.hist_next] = f;
        self.hist_next = (self.hist_next + 1) % HISTORY;
        self.hist_len = (self.hist_len + 1).min(HISTORY);
    }

    /// Least-squares slope dF/dx of the recent served samples, bounded to
    /// `[0, stiffness_max]`; the previous estimate when the positions hardly moved.
    fn estimate_stiffness(&mut self) {
        let n = self.hist_len;
        if n < 3 {
            return;
        }
        let (mut sx, mut sf) = (0.0, 0.0);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for i in 0..n {
            sx += self.hist_x[i];
            sf += self.hist_f[i];
            lo = lo.min(self.hist_x[i]);
            hi = hi.max(self.hist_x[i]);
        }
        if hi - lo < MIN_X_SPREAD {
            return;
        }
        let (mx, mf) = (sx / n as f64, sf / n as f64);
        let (mut sxx, mut sxf) = (0.0, 0.0);
        for i in 0..n {
            let dx = self.hist_x[i] - mx;
            sxx += dx * dx;
            sxf += dx * (self.hist_f[i] - mf);
        }
        let k = sxf / sxx;
        if k.is_finite() {
            self.stiffness = k.clamp(0.0, self.cfg.stiffness_max_n_per_m);
        }
    }

    #[inline]
    fn held_force(&self, x: f64) -> f64 {
        let f = self.last_served_f + self.stiffness * (x - self.last_served_x);
        f.clamp(0.0, self.max_force_n)
    }

    /// Renders one step: asks the model, walks down the ladder as far as needed, blends,
    /// slew-limits a transition, counts. `time`: loop time of the step, s.
    /// REAL-TIME PATH (see the module doc).
    #[inline]
    pub fn render(
        &mut self,
        model: &mut dyn ForceModel,
        step: u64,
        time: f64,
        feats: &Features,
    ) -> Rendered {
        let (x, v) = (feats.position_x, feats.velocity);
        let mut saturated = false;
        let answer = match model.answer(step, feats) {
            Answer::OnTime(f) => match self.accept(f) {
                Some((f, sat)) => {
                    saturated = sat;
                    Answer::OnTime(f)
                }
                None => Answer::Missing(Miss::Rejected),
            },
            Answer::LateOne(f) => match self.accept(f) {
                Some((f, sat)) => {
                    saturated = sat;
                    Answer::LateOne(f)
                }
                None => Answer::Missing(Miss::Rejected),
            },
            m => m,
        };
        if saturated {
            self.report.counts.saturated += 1;
        }
        let level = match answer {
            Answer::OnTime(f) | Answer::LateOne(f) => {
                self.model_side = f;
                self.remember(x, f, time);
                self.w = (self.w - self.fade_per_step).max(0.0);
                if let Answer::OnTime(_) = answer {
                    self.report.counts.on_time += 1;
                    Level::OnTime
                } else {
                    // the step's own answer was late: that is its reason
                    self.report.reasons.count(Miss::Late);
                    self.report.counts.late_one += 1;
                    Level::LateOne
                }
            }
            Answer::Missing(why) => {
                self.report.reasons.count(why);
                if matches!(self.prev_level, Level::OnTime | Level::LateOne) {
                    self.estimate_stiffness();
                }
                self.model_side = self.held_force(x);
                if time - self.last_served_time <= self.cfg.hold_max_s {
                    self.report.counts.held += 1;
                    Level::Held
                } else {
                    self.w = (self.w + self.fade_per_step).min(1.0);
                    self.report.counts.fallback += 1;
                    Level::Fallback
                }
            }
        };
        let target = if self.w > 0.0 {
            (1.0 - self.w) * self.model_side + self.w * self.fallback_force(x, v)
        } else {
            self.model_side
        };
        let fading = self.w > 0.0 && self.w < 1.0;
        if level != self.prev_level {
            self.slewing = true;
        }
        let mut force = target;
        let in_transition = self.slewing || fading;
        if in_transition {
            let d = target - self.prev_rendered;
            let s = self.cfg.slew_n_per_step;
            if d.abs() <= s {
                self.slewing = false;
            } else {
                force = self.prev_rendered + s.copysign(d);
            }
        }
        let left_contact = x <= 0.0;
        if left_contact {
            // out of contact the rendered object does not exist: no force, no transition left
            force = 0.0;
            self.slewing = false;
        }
        // The step a transition took, not the probe leaving the object: that zeroes the force
        // whatever the rung (a model whose answer at the surface is not 0 drops there, on time
        // or not), and was counted here as a transition's step of up to several newtons.
        if in_transition && !left_contact {
            self.report.transition_steps += 1;
            let dstep = (force - self.prev_rendered).abs();
            if dstep > self.report.max_transition_step_n {
                self.report.max_transition_step_n = dstep;
            }
        }
        self.prev_level = level;
        self.prev_rendered = force;
        Rendered { force, level }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scripted model: one answer per step from a list.
    struct Script(Vec<Answer>);
    impl ForceModel for Script {
        fn name(&self) -> &str {
            "script"
        }
        fn predict(&mut self, _: u64, _: &Features) -> Option<f64> {
            None
        }
        fn answer(&mut self, step: u64, _: &Features) -> Answer {
            self.0[step as usize]
        }
    }

    fn feats(x: f64) -> Features {
        Features {
            position_x: x,
            ..Features::default()
        }
    }

    const T: f64 = 1e-4;

    fn ladder() -> Ladder {
        Ladder::new(
            &LadderConfig::default(),
            20.0,
            SpringDamper {
                k1: 400.0,
                k2: 0.0,
                b: 0.0,
            },
            T,
        )
    }

    /// The model renders F = 300 x, the fallback 400 x: a 1 N gap at x = 10 mm. A single late
    /// answer is covered by the previous step's answer; a run of misses holds, then fades the
    /// fallback in, then back out: no step moves the force by more than the slew limit, and
    /// every rung is counted with its reason.
    #[test]
    fn walks_the_ladder_without_jumps() {
        let x = |k: usize| 0.01 + 1e-6 * k as f64; // slowly pressing in
        let mut script = Vec::new();
        for k in 0..200 {
            script.push(Answer::OnTime(300.0 * x(k)));
        }
        script.push(Answer::LateOne(300.0 * x(199))); // 200: previous answer, late
        for _ in 201..400 {
            script.push(Answer::Missing(Miss::Late)); // 201..399: nothing
        }
        for k in 400..800 {
            script.push(Answer::OnTime(300.0 * x(k)));
        }
        let mut m = Script(script);
        let mut l = ladder();
        let mut prev = 0.0;
        let mut levels = Vec::new();
        let mut worst_after_start: f64 = 0.0;
        for k in 0..800 {
            let r = l.render(&mut m, k as u64, k as f64 * T, &feats(x(k)));
            if k > 0 {
                worst_after_start = worst_after_start.max((r.force - prev).abs());
            }
            prev = r.force;
            levels.push(r.level);
        }
        let rep = l.report();
        assert_eq!(levels[200], Level::LateOne);
        assert_eq!(levels[201], Level::Held);
        // hold 3 ms = 30 steps after the last served step (200)
        assert_eq!(levels[230], Level::Held);
        assert_eq!(levels[231], Level::Fallback);
        assert_eq!(levels[400], Level::OnTime);
        assert_eq!(rep.counts.total(), 800);
        assert_eq!(rep.counts.late_one, 1);
        assert_eq!(rep.counts.held, 30);
        assert_eq!(rep.counts.fallback, 169);
        assert_eq!(rep.counts.on_time, 600);
        assert_eq!(rep.reasons.total(), 200);
        assert_eq!(rep.reasons.late, 200);
        assert!(rep.max_transition_step_n <= 0.04 + 1e-12, "{rep:?}");
        // the model moves 0.0003 N per step on its own; nothing else moves it faster
        assert!(worst_after_start <= 0.04 + 1e-12, "{worst_after_start}");
        // the fallback is fully in by the end of the gap, fully out at the end
        assert!((prev - 300.0 * x(799)).abs() < 1e-9, "faded out: {prev}");
        assert!(rep.transition_steps >= 100, "{rep:?}");
    }

    /// Leaving the object during a transition zeroes the force at once (the object is gone),
    /// and that drop is not a transition's step: `max_transition_step_n` stays within the slew
    /// limit, while the steps of the transition in contact are still measured.
    #[test]
    fn leaving_contact_mid_transition_is_not_a_transition_step() {
        // a model answering 6 N at the surface; a late run makes the ladder hold, then the
        // answers return while the probe is still in: a slewed transition back to 6 N, and
        // the probe leaves the object in the middle of it
        let mut script = Vec::new();
        for _ in 0..100 {
            script.push(Answer::OnTime(6.0));
        }
        for _ in 100..140 {
            script.push(Answer::Missing(Miss::Late));
        }
        for _ in 140..200 {
            script.push(Answer::OnTime(6.0));
        }
        let mut m = Script(script);
        let mut l = ladder();
        let mut forces = Vec::new();
        for k in 0..200 {
            let x = if k < 143 { 0.001 } else { -0.001 };
            forces.push(l.render(&mut m, k as u64, k as f64 * T, &feats(x)).force);
        }
        let rep = l.report();
        assert_eq!(forces[143], 0.0, "out of contact nothing is rendered");
        assert!(
            forces[142] > 0.5,
            "still in transition at the exit: {}",
            forces[142]
        );
        assert!(rep.transition_steps > 0, "{rep:?}");
        assert!(rep.max_transition_step_n <= 0.04 + 1e-12, "{rep:?}");
    }

    /// Unilateral: negative answers render 0 N, and nothing is rendered out of contact;
    /// NaN/Inf answers are refused with a reason.
    #[test]
    fn only_pushes_and_refuses_bad_answers() {
        let mut m = Script(vec![
            Answer::OnTime(-3.0),
            Answer::OnTime(2.0),
            Answer::OnTime(f64::NAN),
            Answer::OnTime(f64::INFINITY),
            Answer::OnTime(0.5),
        ]);
        let mut l = ladder();
        let r0 = l.render(&mut m, 0, 0.0, &feats(0.01));
        assert_eq!(r0.force, 0.0);
        let r1 = l.render(&mut m, 1, T, &feats(-0.001));
        assert_eq!(r1.force, 0.0, "out of contact");
        let r2 = l.render(&mut m, 2, 2.0 * T, &feats(0.01));
        assert_eq!(r2.level, Level::Held);
        let r3 = l.render(&mut m, 3, 3.0 * T, &feats(0.01));
        assert_eq!(r3.level, Level::Held);
        assert_eq!(l.report().reasons.rejected, 2);
        assert_eq!(l.report().counts.saturated, 0);
        assert!(r2.force >= 0.0 && r3.force >= 0.0);
    }

    /// A finite answer above the force limit is rendered at the limit by its own rung and
    /// counted as saturated; the fallback law (here 400 x = 4 N, far below) never takes over.
    /// A large negative answer is 0 (the object only pushes), not a refusal.
    #[test]
    fn answers_beyond_the_limit_saturate_instead_of_falling_back() {
        let mut script = vec![Answer::OnTime(19.9); 50];
        script.extend([Answer::OnTime(1e6); 400]); // 40 ms deep press, far beyond 20 N
        script.push(Answer::LateOne(25.0));
        script.push(Answer::OnTime(-1e6));
        script.push(Answer::OnTime(19.0));
        let n = script.len();
        let mut m = Script(script);
        let mut l = ladder();
        let mut levels = Vec::new();
        let mut forces = Vec::new();
        for k in 0..n {
            let r = l.render(&mut m, k as u64, k as f64 * T, &feats(0.01));
            levels.push(r.level);
            forces.push(r.force);
        }
        // after the first step's slew from 0 the answer is rendered as given, then at 20 N
        for k in 50..450 {
            assert_eq!(levels[k], Level::OnTime, "step {k}");
            assert_eq!(forces[k], 20.0, "step {k}: at the limit, not the fallback");
        }
        assert_eq!(levels[450], Level::LateOne);
        assert_eq!(forces[450], 20.0);
        assert_eq!(levels[451], Level::OnTime);
        let rep = l.report();
        assert_eq!(rep.counts.saturated, 401);
        assert_eq!(rep.counts.fallback + rep.counts.held, 0);
        assert_eq!(rep.reasons.rejected, 0);
        assert_eq!(rep.counts.total(), n as u64, "saturated is not a rung");
    }

    /// The fallback's own output is clamped to the force limit (a fitted law can go far
    /// beyond it deep in the object).
    #[test]
    fn fallback_is_clamped() {
        let mut m = Script(vec![Answer::Missing(Miss::NoServer); 2000]);
        let mut l = Ladder::new(
            &LadderConfig::default(),
            5.0,
            SpringDamper {
                k1: 1e5,
                k2: 0.0,
                b: 0.0,
            },
            T,
        );
        let mut last = 0.0;
        for k in 0..2000 {
            last = l.render(&mut m, k, k as f64 * T, &feats(0.02)).force;
            assert!(last <= 5.0);
        }
        assert_eq!(last, 5.0);
        assert_eq!(l.report().reasons.no_server, 2000);
    }

    #[test]
    fn config_is_range_checked() {
        let bad = [
            LadderConfig {
                slew_n_per_step: 0.2,
                ..LadderConfig::default()
            },
            LadderConfig {
                hold_max_s: f64::NAN,
                ..LadderConfig::default()
            },
            LadderConfig {
                crossfade_s: -1.0,
                ..LadderConfig::default()
            },
        ];
        for c in bad {
            assert!(c.validate().is_err(), "{c:?}");
        }
        assert!(LadderConfig::default().validate().is_ok());
    }
}
