//! The simulated operator (docs/physics.md, "The simulated sponge bench"): a hand with its own impedance (stiffness and
//! damping toward a moving set-point) following a press-hold-release trajectory. The hand
//! only pushes (it rests against the shaft, it does not grip it).
//!
//! Not a position source: the probe's motion comes out of the hand's impedance, the motor's
//! force and the probe's mass together (rt-loop/src/board/sim.rs integrates them), so a rendered
//! object that generates energy can make the coupled system oscillate with a growing amplitude,
//! as it would on a real hand (what the passivity layer, crate::passivity, is there to stop;
//! tests/tests/passivity_system.rs shows both).
//!
//! The values: for small motions a hand or a finger holding a haptic handle behaves as a
//! mass-spring-damper whose stiffness and damping grow with the grip force. Hajian and Howe
//! 1997 ("Identification of the mechanical impedance at the human finger tip", J. Biomech.
//! Eng. 119) measured the index finger at a few hundred to over a thousand N/m with a few N s/m
//! of damping and an effective mass of grams; Hasser and Cutkosky 2002 (pinch grasp on a knob)
//! and Kuchenbecker, Park and Niemeyer 2003 ("Characterizing the human wrist for improved
//! haptic interaction") found the same growth with grip. The defaults, 1500 N/m and 15 N s/m,
//! are a firm grasp at the stiff, well-damped end of those ranges (a lighter grip, less damped,
//! is easier to destabilise: set `[hand]` lower to try it). The hand's own mass is not
//! modelled: the probe and motor move 0.67 kg, two orders of magnitude above a finger's
//! effective mass, so the probe's mass stands for both; the existing studies' figures were
//! made with this hand and stay valid.

use crate::invalid::{require_non_negative, require_positive, InvalidSetting};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HandConfig {
    /// Hand stiffness toward its set-point, N/m (literature: see the module doc).
    pub stiffness: f64,
    /// Hand damping, N s/m (literature: see the module doc).
    pub damping: f64,
    /// Set-point depth at full press, m (where the hand would go if nothing resisted).
    pub depth_m: f64,
    /// Seconds to press in, hold, release, and rest before the next press.
    pub press_s: f64,
    pub hold_s: f64,
    pub release_s: f64,
    pub rest_s: f64,
    /// Number of press-hold-release repetitions.
    pub repeats: u32,
    /// Each repetition presses this much deeper than the previous one, m.
    pub depth_step_m: f64,
}

impl Default for HandConfig {
    fn default() -> Self {
        HandConfig {
            stiffness: 1500.0,
            damping: 15.0,
            depth_m: 0.030,
            press_s: 1.5,
            hold_s: 1.0,
            release_s: 1.5,
            rest_s: 1.0,
            repeats: 3,
            depth_step_m: 0.002,
        }
    }
}

impl HandConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        require_positive(&[
            ("hand.stiffness", self.stiffness),
            ("hand.depth_m", self.depth_m),
            ("hand.press_s", self.press_s),
            ("hand.release_s", self.release_s),
        ])?;
        require_non_negative(&[
            ("hand.damping", self.damping),
            ("hand.hold_s", self.hold_s),
            ("hand.rest_s", self.rest_s),
            ("hand.depth_step_m", self.depth_step_m),
        ])?;
        if self.repeats == 0 {
            return Err("hand.repeats must be >= 1".into());
        }
        Ok(())
    }

    fn period(&self) -> f64 {
        self.press_s + self.hold_s + self.release_s + self.rest_s
    }

    /// Total duration of the hand's programme, s (a short rest first).
    pub fn duration(&self) -> f64 {
        self.rest_s + self.period() * self.repeats as f64
    }

    /// Set-point position and velocity at time `t` (smooth cosine ramps).
    pub fn setpoint(&self, t: f64) -> (f64, f64) {
        let t = t - self.rest_s;
        if t < 0.0 || t >= self.period() * self.repeats as f64 {
            return (0.0, 0.0);
        }
        let k = (t / self.period()).floor();
        let depth = self.depth_m + self.depth_step_m * k;
        let tc = t - k * self.period();
        let ramp = |u: f64, len: f64| {
            // 0 -> 1 with zero slope at both ends
            let s = 0.5 - 0.5 * (std::f64::consts::PI * u).cos();
            let ds = 0.5 * std::f64::consts::PI * (std::f64::consts::PI * u).sin() / len;
            (s, ds)
        };
        if tc < self.press_s {
            let (s, ds) = ramp(tc / self.press_s, self.press_s);
            (depth * s, depth * ds)
        } else if tc < self.press_s + self.hold_s {
            (depth, 0.0)
        } else if tc < self.press_s + self.hold_s + self.release_s {
            let (s, ds) = ramp(
                (tc - self.press_s - self.hold_s) / self.release_s,
                self.release_s,
            );
            (depth * (1.0 - s), -depth * ds)
        } else {
            (0.0, 0.0)
        }
    }

    /// Force the hand puts on the shaft (N, >= 0, pushing into +x).
    #[inline]
    pub fn force(&self, t: f64, x: f64, v: f64) -> f64 {
        let (xr, vr) = self.setpoint(t);
        (self.stiffness * (xr - x) + self.damping * (vr - v)).max(0.0)
    }
}
