//! The force model hook of reproduction (docs/physics.md, "The experiments"): each step the loop asks a
//! [`ForceModel`] for F_pred from the step's features and renders `F_cmd = -F_pred`.
//!
//! The built-in model is a fitted second-order spring-damper law ([`SpringDamper`]), which is
//! also the fallback the loop uses whenever a served prediction is missing, late, NaN/Inf or
//! out of range (docs/physics.md, "The loop step": the loop never trusts the server).
//!
//! Plugging in the inference server (issue 4): implement `ForceModel` for a shared-memory
//! client that, in `predict`, writes `features.as_array()` with the step number into the
//! features ring and waits (spin or spin-then-park, bounded by its own deadline) for the slot
//! tagged with the same step in the force ring; it returns `None` on timeout or a stale tag.
//! Nothing else in the loop changes. `predict` runs on the loop thread, so an implementation
//! must not allocate, lock or do I/O, and must bound its wait.

use crate::features::Features;
use crate::lstsq::{FitError, NormalEquations3};
use serde::{Deserialize, Serialize};

/// Why a step has no usable answer of its own (the ladder counts one reason per such step).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Miss {
    /// The answer did not come before the step's deadline.
    Late,
    /// No server attached, or one settling after attaching: nothing was sent.
    NoServer,
    /// The features ring was full.
    RingFull,
    /// The server answered with a flag (no model, schema mismatch, NaN, bad features...).
    Flagged,
    /// The server went away.
    ServerLost,
    /// Lockstep: the server missed several answers in a row and its heartbeat stands still.
    Hung,
    /// The answer was NaN/Inf or beyond the force limit (decided by the ladder).
    Rejected,
}

/// What a model has for one step (see [`crate::serving::ladder`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Answer {
    /// The answer to this step, in time: F_pred, N.
    OnTime(f64),
    /// This step's answer is late, but the previous step's answer arrived one period late
    /// and is there now: its F_pred, N.
    LateOne(f64),
    /// Nothing usable, and why.
    Missing(Miss),
}

/// `Any`: a run gives its model back as `Box<dyn ForceModel>`, and the caller that lent a
/// concrete model recognises it there (`ShmModel::from_model`).
pub trait ForceModel: Send + std::any::Any {
    /// Short name for the run metadata and the summary.
    fn name(&self) -> &str;
    /// Called once before the run's first step, off the real-time path: a shared-memory client
    /// can wait for its server here and mark the next message as a run start (the step
    /// counter passed to `predict` restarts at 0 with every run).
    fn begin_run(&mut self) {}
    /// Why the run cannot start (e.g. no server came during `begin_run`): the run is refused
    /// with this message before its first step, the motor still at 0 A.
    fn start_error(&self) -> Option<&str> {
        None
    }
    /// Predicted reaction force (N, positive = the virtual object pushes back) for step
    /// `step` from its features; `None` when no prediction is available in time.
    fn predict(&mut self, step: u64, features: &Features) -> Option<f64>;
    /// The step's answer for the degradation ladder. The default maps `predict`: a value is
    /// on time, `None` a late answer. A served model overrides it to pass on the previous
    /// step's late answer and the precise reason of a miss. Same real-time contract as
    /// `predict`.
    #[inline]
    fn answer(&mut self, step: u64, features: &Features) -> Answer {
        match self.predict(step, features) {
            Some(f) => Answer::OnTime(f),
            None => Answer::Missing(Miss::Late),
        }
    }
    /// Which served model gave the answer last used: the server's registry id
    /// (`ForceMsg.model_id`), so telemetry says which model drew each step. 0: none (a
    /// built-in model, or no answer yet). Same real-time contract as `predict`.
    #[inline]
    fn model_id(&self) -> u32 {
        0
    }
    /// Fills what the model knows for the loop-status block (deadline misses, round-trip
    /// percentiles). Called about every 100 ms on the loop thread: no allocation, no lock.
    fn report_status(&self, _status: &mut haptics_proto::LoopStatus) {}
}

/// `F = k1 x + k2 x^2 + b v` while in contact (x > 0), never pulling (F >= 0).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpringDamper {
    pub k1: f64,
    pub k2: f64,
    pub b: f64,
}

impl Default for SpringDamper {
    /// Fitted (least squares on rtob_force) to the 1.8 N/s training recording of
    /// `materials/sponge.toml` made by scripts/record-dataset.sh, with `rt-loop fit`.
    fn default() -> Self {
        SpringDamper {
            k1: 191.0,
            k2: 5200.0,
            b: 192.0,
        }
    }
}

impl SpringDamper {
    #[inline]
    pub fn eval(&self, x: f64, v: f64) -> f64 {
        if x <= 0.0 {
            return 0.0;
        }
        (self.k1 * x + self.k2 * x * x + self.b * v).max(0.0)
    }

    /// Least-squares fit of (k1, k2, b) on the samples in contact (x > 0, finite force).
    pub fn fit(x: &[f64], v: &[f64], f: &[f64]) -> Result<SpringDamper, FitError> {
        let mut eq = NormalEquations3::default();
        for i in 0..x.len().min(v.len()).min(f.len()) {
            if !(x[i] > 0.0 && f[i].is_finite() && v[i].is_finite()) {
                continue;
            }
            eq.add([x[i], x[i] * x[i], v[i]], f[i]);
        }
        if eq.rows() < 10 {
            return Err(FitError::TooFew {
                found: eq.rows(),
                needed: 10,
                what: "samples in contact",
            });
        }
        let sol = eq
            .solve()
            .ok_or(FitError::Singular("no motion in the data?"))?;
        Ok(SpringDamper {
            k1: sol[0],
            k2: sol[1],
            b: sol[2],
        })
    }
}

impl SpringDamper {
    /// [`SpringDamper::fit`] on a recording's `position_x`, `velocity` and `force_col`.
    pub fn fit_recording(path: &std::path::Path, force_col: &str) -> anyhow::Result<SpringDamper> {
        let cols = crate::record::read::read_columns(path, &["position_x", "velocity", force_col])?;
        SpringDamper::fit(&cols[0], &cols[1], &cols[2])
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }
}

/// The built-in model as a served model: the spring-damper law on the features.
#[derive(Clone, Debug)]
pub struct SpringDamperModel(pub SpringDamper);

impl ForceModel for SpringDamperModel {
    fn name(&self) -> &str {
        "spring-damper"
    }
    #[inline]
    fn predict(&mut self, _step: u64, f: &Features) -> Option<f64> {
        Some(self.0.eval(f.position_x, f.velocity))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_recovers_known_coefficients() {
        let truth = SpringDamper {
            k1: 150.0,
            k2: 9000.0,
            b: 12.0,
        };
        let mut x = vec![];
        let mut v = vec![];
        let mut f = vec![];
        for i in 0..2000 {
            let t = i as f64 * 0.01;
            let xi = 0.015 + 0.012 * (t * 0.7).sin();
            let vi = 0.012 * 0.7 * (t * 0.7).cos();
            x.push(xi);
            v.push(vi);
            f.push(truth.eval(xi, vi));
        }
        let fit = SpringDamper::fit(&x, &v, &f).unwrap();
        assert!((fit.k1 - truth.k1).abs() < 1e-6 * truth.k1.abs() + 1e-6);
        assert!((fit.k2 - truth.k2).abs() < 1e-6 * truth.k2);
        assert!((fit.b - truth.b).abs() < 1e-6 * truth.b);
        assert!(SpringDamper::fit(&[0.0; 5], &[0.0; 5], &[0.0; 5]).is_err());
        assert_eq!(truth.eval(-0.01, 1.0), 0.0);
    }
}
