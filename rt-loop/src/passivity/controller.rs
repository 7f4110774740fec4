//! The passivity controller (Hannaford and Ryu 2002, "Time-domain passivity control of haptic
//! interfaces", IEEE Trans. Robotics and Automation 18(1)): an adaptive damper in parallel with
//! the rendered object (impedance causality: the loop measures motion and renders a force).
//! When the observer's energy E is negative, the object has given back more than it received;
//! the damper then adds alpha v to the object's force with alpha = -E / (T v^2), which
//! dissipates the deficit over the next period T. Sign conventions: see [`super::observer`].
//!
//! The practical guards (each with its configuration field, [`super::PassivityConfig`]):
//! - a floor on v^2 (`v_floor_mps`): near rest alpha would grow without bound and turn encoder
//!   noise into force; the deficit is paid off over several steps instead;
//! - a cap on alpha (`damping_max_ns_per_m`) and on the force it adds in one step
//!   (`force_max_n`); the result is clamped to the ladder's range [0, max_force_n] (the
//!   rendered object only pushes) and is 0 out of contact (x <= 0), so the motor's limits and
//!   the current clamp downstream still hold whatever the damper asks;
//! - forgetting only dissipated energy, over a window (`window_s`, see the observer).
//!
//! Where it runs: in `Rig::step`, after the experiment's decision (the degradation ladder's
//! output), before the force controller turns the force into a current. Only steps that render
//! an object (phase `reproduction`) pass through it; the abstraction's force ramps and the
//! position replay are not objects and are left alone.
//!
//! REAL-TIME PATH: no allocation, no lock, no syscall (tests/alloc_free_step.rs).

use super::config::PassivityConfig;
use super::observer::EnergyObserver;
use serde::Serialize;

/// The layer's figures (`"passivity"` in the run summary; the status block, gRPC, hapticctl,
/// `/metrics` and the page show them). Energies in J, damping in N s/m.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct PassivityReport {
    /// Whether the controller acts (the observer runs either way).
    pub enabled: bool,
    /// The observer's energy E (received - returned, less what was forgotten).
    pub energy_j: f64,
    /// Gross energy the object received from the hand.
    pub received_j: f64,
    /// Gross energy the object returned to the hand.
    pub returned_j: f64,
    /// Energy the damper took out (its share of what the object received).
    pub dissipated_j: f64,
    /// Dissipated energy forgotten (older than the window, with the object unloaded).
    pub forgotten_j: f64,
    /// Lowest net energy (received - returned) of the run: below 0, the object gave back more
    /// than it had received at that moment.
    pub min_net_j: f64,
    /// The damping of the last step, and the largest of the run.
    pub damping_ns_per_m: f64,
    pub max_damping_ns_per_m: f64,
    /// Steps on which the damper changed the rendered force.
    pub active_steps: u64,
    /// Steps observed (steps that rendered an object).
    pub steps: u64,
}

impl std::fmt::Display for PassivityReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "passivity {}: energy {:.4} J (received {:.4} J, returned {:.4} J, lowest net {:.4} J, damper took {:.4} J, forgotten {:.4} J); damping max {:.1} N s/m, active on {} of {} steps",
            if self.enabled { "on" } else { "off (observing)" },
            self.energy_j,
            self.received_j,
            self.returned_j,
            self.min_net_j,
            self.dissipated_j,
            self.forgotten_j,
            self.max_damping_ns_per_m,
            self.active_steps,
            self.steps
        )
    }
}

#[derive(Clone, Debug)]
pub struct PassivityController {
    enabled: bool,
    v_floor: f64,
    damping_max: f64,
    force_max: f64,
    max_force: f64,
    period: f64,
    /// Velocity for the damper: the encoder's displacement through a first-order low-pass
    /// at `velocity_hz` (its own, not the loop's 30 rad/s estimate: a damper acting on a
    /// velocity that lags the motion by tens of degrees pushes with the motion part of the
    /// time, i.e. it is partly active itself).
    v: f64,
    v_gain: f64,
    observer: EnergyObserver,
    damping: f64,
    max_damping: f64,
    active_steps: u64,
    steps: u64,
}

impl PassivityController {
    /// `enabled`: whether it acts (the mode resolved for the board); `period`: the nominal
    /// step, s; `max_force`: the rendered force's limit (reproduction.max_force_n), N.
    pub fn new(cfg: &PassivityConfig, enabled: bool, period: f64, max_force: f64) -> Self {
        PassivityController {
            enabled,
            v_floor: cfg.v_floor_mps,
            damping_max: cfg.damping_max_ns_per_m,
            force_max: cfg.force_max_n,
            max_force,
            period,
            v: 0.0,
            v_gain: 2.0 * std::f64::consts::PI * cfg.velocity_hz,
            observer: EnergyObserver::new(cfg.window_s),
            damping: 0.0,
            max_damping: 0.0,
            active_steps: 0,
            steps: 0,
        }
    }

    /// Observing only (what a rig has until a run configures it).
    pub fn off() -> Self {
        Self::new(&PassivityConfig::default(), false, 1e-4, f64::INFINITY)
    }

    /// The force to render this step for the object's force `f_object` (>= 0, pushing the
    /// probe out), the probe at `x` (positive into the object), `dt` since the last step.
    /// REAL-TIME PATH.
    #[inline]
    pub fn render(&mut self, f_object: f64, x: f64, dt: f64) -> f64 {
        self.steps += 1;
        if dt > 0.0 && self.steps > 1 {
            // exact first-order discretisation: stable for any dt (a stalled step included)
            let a = 1.0 - (-self.v_gain * dt).exp();
            self.v += a * ((x - self.observer.last_x()) / dt - self.v);
        }
        let v = self.v;
        let e = self.observer.observe(x, dt);
        if f_object == 0.0 {
            self.observer.forget_dissipated();
        }
        let e = e.min(self.observer.energy());
        let mut f = f_object;
        self.damping = 0.0;
        if self.enabled && e < 0.0 && x > 0.0 && f_object.is_finite() {
            // In deficit. Moving in faster than the floor: the damper of Hannaford and Ryu,
            // alpha = -E / (T v^2), capped, adds force and the hand's press pays the deficit.
            // Otherwise the next period's direction is not known well enough to damp (at rest,
            // in a stick-slip, in a slow release the velocity lags the motion and a damper
            // would push with it part of the time): the object's force is withheld (rendered
            // 0, its share of alpha taken to the cap of its own force), so it cannot give back
            // what it does not have. Out of deficit the object is rendered as it is.
            let alpha = if v > self.v_floor {
                (-e / (self.period * v * v)).min(self.damping_max)
            } else {
                f64::INFINITY
            };
            f = if alpha.is_finite() {
                (f_object + (alpha * v).min(self.force_max)).clamp(0.0, self.max_force)
            } else {
                0.0
            };
            if f != f_object {
                self.active_steps += 1;
                self.damping = if alpha.is_finite() {
                    alpha
                } else {
                    self.damping_max
                };
                self.max_damping = self.max_damping.max(self.damping);
            }
        }
        self.observer.commit(x, f, f_object);
        f
    }

    pub fn enabled(&self) -> bool {
        self.enabled
    }

    pub fn report(&self) -> PassivityReport {
        let o = &self.observer;
        PassivityReport {
            enabled: self.enabled,
            energy_j: o.energy(),
            received_j: o.received(),
            returned_j: o.returned(),
            dissipated_j: o.damper(),
            forgotten_j: o.forgotten(),
            min_net_j: o.min_net(),
            damping_ns_per_m: self.damping,
            max_damping_ns_per_m: self.max_damping,
            active_steps: self.active_steps,
            steps: self.steps,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::passivity::PassivityMode;

    /// A mass on a spring with NEGATIVE damping rendered as the object: the oscillation grows
    /// without the controller; with it, the object never returns more than it received (up to
    /// one step's work) and the motion stays bounded.
    fn oscillate(enabled: bool) -> (f64, PassivityReport) {
        let cfg = PassivityConfig {
            mode: PassivityMode::On,
            ..PassivityConfig::default()
        };
        let dt = 1e-4;
        let mut pc = PassivityController::new(&cfg, enabled, dt, 20.0);
        // the hand: 0.5 kg held at 10 mm by a 1500 N/m, 15 N s/m impedance
        let (m, kh, ch, x0): (f64, f64, f64, f64) = (0.5, 1500.0, 15.0, 0.01);
        // the object: 500 N/m spring with -40 N s/m damping (active), pushing only
        let (k, b): (f64, f64) = (500.0, -40.0);
        let (mut x, mut v): (f64, f64) = (0.002, 0.0);
        let mut peak_late: f64 = 0.0;
        for i in 0..100_000 {
            let f_obj = (k * x + b * v).max(0.0) * f64::from(x > 0.0);
            let f = pc.render(f_obj, x, dt);
            let a = (kh * (x0 - x) - ch * v - f) / m;
            v += a * dt;
            x += v * dt;
            if x.is_nan() || x.abs() >= 1.0 {
                return (f64::INFINITY, pc.report());
            }
            if i > 80_000 {
                peak_late = peak_late.max((x - x0).abs());
            }
        }
        (peak_late, pc.report())
    }

    #[test]
    fn the_damper_makes_an_active_object_passive() {
        let (off_peak, off) = oscillate(false);
        let (on_peak, on) = oscillate(true);
        assert!(
            off.min_net_j < -0.01,
            "the active object gives energy: {off:?}"
        );
        assert!(off_peak > 0.005, "and the motion grows: {off_peak}");
        assert!(on.min_net_j > -1e-3, "with the damper it does not: {on:?}");
        // up to one step's work (a few N over a few um)
        assert!(on.returned_j <= on.received_j + 1e-5, "{on:?}");
        assert!(on_peak < 0.001, "and the motion settles: {on_peak}");
        assert!(on.active_steps > 0 && on.max_damping_ns_per_m <= 200.0);
    }

    /// A passive object is left alone: no step changed, E >= 0 throughout.
    #[test]
    fn a_passive_object_is_not_touched() {
        let cfg = PassivityConfig::default();
        let mut pc = PassivityController::new(&cfg, true, 1e-4, 20.0);
        for i in 0..20_000 {
            let t = i as f64 * 1e-4;
            let x = 0.01 * (3.0 * t).sin().max(0.0);
            let v = 0.03 * (3.0 * t).cos() * f64::from(x > 0.0);
            let f_obj = (800.0 * x + 30.0 * v).max(0.0) * f64::from(x > 0.0);
            assert_eq!(pc.render(f_obj, x, 1e-4), f_obj, "step {i}");
        }
        assert_eq!(pc.report().active_steps, 0);
    }

    /// In deficit: moving in, the damper adds at most `force_max_n` and the force stays within
    /// [0, max_force]; moving out (or too slowly to tell), the object's force is withheld; out
    /// of contact, nothing.
    #[test]
    fn the_caps_hold() {
        let cfg = PassivityConfig::default();
        let dt = 1e-4;
        let mut pc = PassivityController::new(&cfg, true, dt, 20.0);
        // a debt: the object pushed 19 N while the probe went out 10 mm
        pc.render(19.0, 0.02, dt);
        pc.render(19.0, 0.01, dt);
        assert!(pc.report().energy_j < -0.1);
        // moving in at 0.2 m/s (20 um per step): the velocity estimate follows within steps
        let mut x = 0.01;
        let mut f = 0.0;
        for _ in 0..200 {
            x += 2e-5;
            f = pc.render(10.0, x, dt);
            // withheld (0) until the velocity estimate is above the floor, then damped
            assert!(
                f == 0.0 || (10.0..=13.0).contains(&f),
                "10 N + at most 3 N: {f}"
            );
        }
        assert!(f > 10.0, "the damper adds force: {f}");
        let f = pc.render(19.5, x + 2e-5, dt);
        assert_eq!(f, 20.0, "clamped to the force limit");
        // moving out while in deficit: withheld
        let mut pc = PassivityController::new(&cfg, true, dt, 20.0);
        pc.render(19.0, 0.02, dt);
        assert_eq!(pc.render(19.0, 0.01, dt), 0.0);
        assert_eq!(pc.render(0.0, -0.001, dt), 0.0, "out of contact");
        assert!(pc.report().max_damping_ns_per_m <= 200.0);
    }
}
