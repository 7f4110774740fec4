//! The loop's parameters (docs/physics.md, "Bench parameters", thesis Tables 5.1-5.6 and its C code).
//! Every value defaults to the thesis's and can be overridden from the config file.

use crate::invalid::{first_refused, InvalidSetting};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LoopParams {
    /// Nominal moving mass M_n, kg (the thesis code's value).
    pub m_n: f64,
    /// Nominal force constant K_fn, N/A.
    pub k_fn: f64,
    /// DOB cut-off g_dis, rad/s.
    pub g_dis: f64,
    /// RFOB cut-off g_rec, rad/s.
    pub g_rec: f64,
    /// Force controller gain K_p.
    pub k_p: f64,
    /// Velocity pseudo-derivative cut-off g_v, rad/s.
    pub g_v: f64,
    /// Acceleration pseudo-derivative cut-off g_a, rad/s.
    pub g_a: f64,
    /// Clamp on the current command, A.
    pub current_limit: f64,
    /// DAC full scale: the current at DAC word 65535 (and minus it at 0), A.
    pub dac_full_scale: f64,
    /// Encoder resolution, m per count (quadrature x4).
    pub meters_per_count: f64,
    /// Abort when |x| reaches this, m.
    pub position_limit: f64,
    /// Coulomb friction the RFOB subtracts (F_friction_model = this * sign(v)), N. The thesis
    /// code assumes 0.
    pub friction_model: f64,
    /// Coulomb/Stribeck/viscous friction the RFOB subtracts as well (`[params.friction]`, or
    /// the bench file of `rt-loop identify-friction` via `--bench`); zero by default.
    pub friction: crate::control::friction::Friction,
    /// Position PID gains C_p, C_d, C_i (current = PID * M_n / K_fn).
    pub pid_p: f64,
    pub pid_d: f64,
    pub pid_i: f64,
    /// Add the DOB's disturbance estimate to the position controller's current (acceleration-
    /// based position control as the thesis's bench runs it). Without it the PID alone has to
    /// hold the object's force through its integral term.
    pub pid_dob: bool,
    /// Watchdog timeout armed on the board, microseconds. 100 ms by default: shared VMs stall a
    /// process for tens of ms now and then; a dedicated real-time host can go much lower.
    pub watchdog_us: u32,
}

impl Default for LoopParams {
    fn default() -> Self {
        LoopParams {
            m_n: 0.643,
            k_fn: 24.0,
            g_dis: 300.0,
            g_rec: 300.0,
            k_p: 2.0,
            g_v: 30.0,
            g_a: 100.0,
            current_limit: 0.59,
            dac_full_scale: 0.6,
            meters_per_count: 5e-6,
            position_limit: 0.05,
            friction_model: 0.0,
            friction: crate::control::friction::Friction::default(),
            pid_p: 700.0,
            pid_d: 12.0,
            pid_i: 1000.0,
            pid_dob: true,
            watchdog_us: 100_000,
        }
    }
}

impl LoopParams {
    /// Refuses values that would make the loop unsafe or meaningless.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let positive = [
            ("m_n", self.m_n),
            ("k_fn", self.k_fn),
            ("g_dis", self.g_dis),
            ("g_rec", self.g_rec),
            ("g_v", self.g_v),
            ("g_a", self.g_a),
            ("current_limit", self.current_limit),
            ("dac_full_scale", self.dac_full_scale),
            ("meters_per_count", self.meters_per_count),
            ("position_limit", self.position_limit),
        ];
        if let Some((name, v)) = first_refused(&positive, |v| v > 0.0) {
            return Err(format!("parameter {name} must be a positive number, got {v}").into());
        }
        let non_negative = [
            ("k_p", self.k_p),
            ("friction_model", self.friction_model),
            ("pid_p", self.pid_p),
            ("pid_d", self.pid_d),
            ("pid_i", self.pid_i),
        ];
        if let Some((name, v)) = first_refused(&non_negative, |v| v >= 0.0) {
            return Err(format!("parameter {name} must be >= 0, got {v}").into());
        }
        self.friction.validate()?;
        if self.current_limit > self.dac_full_scale {
            return Err(format!(
                "current_limit {} A exceeds the DAC full scale {} A",
                self.current_limit, self.dac_full_scale
            )
            .into());
        }
        if self.current_limit > 0.62 {
            return Err(format!(
                "current_limit {} A exceeds the motor's continuous rating 0.62 A",
                self.current_limit
            )
            .into());
        }
        Ok(())
    }
}
