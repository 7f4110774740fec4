//! `[passivity]` of the run configuration and its flags (`--passivity auto|on|off` and the
//! guards' parameters): every number checked with a one-line error naming it and its range.

use crate::config::BoardKind;
use crate::invalid::{require_within, InvalidSetting};
use serde::{Deserialize, Serialize};

/// Whether the passivity controller acts (the observer always runs and is always reported).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum PassivityMode {
    /// On for a real board, off for the simulated bench and the replay board (see
    /// [`PassivityConfig::enabled_on`]).
    Auto,
    On,
    Off,
}

/// The time-domain passivity layer (Hannaford and Ryu 2002) and its practical guards.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PassivityConfig {
    pub mode: PassivityMode,
    /// Floor on |v| in the damping law alpha = -E / (T v^2), m/s: near rest v^2 -> 0 would ask
    /// for an unbounded damping (and amplify encoder noise); below the floor the deficit is
    /// paid off over the following steps instead of in one.
    pub v_floor_mps: f64,
    /// Cap on the damping alpha, N s/m.
    pub damping_max_ns_per_m: f64,
    /// Cap on the force the damper adds in one step, |alpha v|, N. The rendered force then
    /// stays within [0, reproduction.max_force_n] and the current clamp still holds.
    pub force_max_n: f64,
    /// Window of the forgetting, s: when the object holds no force (nothing is stored in
    /// it), the energy reserve is cut to what the object received during the last window.
    /// Only dissipated energy is forgotten, and only that older than the window.
    pub window_s: f64,
    /// Cut-off of the damper's own velocity estimate (the encoder's displacement, low-passed),
    /// Hz.
    pub velocity_hz: f64,
}

impl Default for PassivityConfig {
    fn default() -> Self {
        PassivityConfig {
            mode: PassivityMode::Auto,
            v_floor_mps: 0.005,
            damping_max_ns_per_m: 200.0,
            force_max_n: 3.0,
            window_s: 2.0,
            velocity_hz: 30.0,
        }
    }
}

impl PassivityConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        require_within(
            "passivity.v_floor_mps",
            self.v_floor_mps,
            1e-5..=1.0,
            "1e-5..1 m/s",
        )?;
        require_within(
            "passivity.damping_max_ns_per_m",
            self.damping_max_ns_per_m,
            0.1..=5000.0,
            "0.1..5000 N s/m",
        )?;
        require_within(
            "passivity.force_max_n",
            self.force_max_n,
            0.01..=50.0,
            "0.01..50 N",
        )?;
        require_within(
            "passivity.window_s",
            self.window_s,
            0.01..=600.0,
            "0.01..600 s",
        )?;
        require_within(
            "passivity.velocity_hz",
            self.velocity_hz,
            1.0..=2000.0,
            "1..2000 Hz",
        )?;
        Ok(())
    }

    /// Whether the controller acts on this board. `auto`: on for a real board (a motor and a
    /// hand that can be hurt); off on the simulated bench, so the studies' figures stay those of
    /// the models as they are (turn it on with `--passivity on` to see what a real board would
    /// render), and off on the replay board, whose recorded motion cannot respond to a damper.
    pub fn enabled_on(&self, board: BoardKind) -> bool {
        match self.mode {
            PassivityMode::On => true,
            PassivityMode::Off => false,
            #[allow(unreachable_patterns)]
            PassivityMode::Auto => !matches!(board, BoardKind::Sim | BoardKind::Replay),
        }
    }
}

/// The flags of `rt-loop run` and `serve` (each overrides `--config`'s `[passivity]`).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct PassivityArgs {
    /// Time-domain passivity layer: auto (on for a real board, off for sim and replay), on, off.
    #[arg(long, value_enum)]
    pub passivity: Option<PassivityMode>,
    /// Floor on |v| in the damping law, m/s (1e-5..1).
    #[arg(long)]
    pub passivity_v_floor_mps: Option<f64>,
    /// Cap on the passivity damping, N s/m (0.1..5000).
    #[arg(long)]
    pub passivity_damping_max: Option<f64>,
    /// Cap on the force the passivity damper adds, N (0.01..50).
    #[arg(long)]
    pub passivity_force_max_n: Option<f64>,
    /// Window of the forgetting of dissipated energy, s (0.01..600).
    #[arg(long)]
    pub passivity_window_s: Option<f64>,
    /// Cut-off of the damper's velocity estimate, Hz (1..2000).
    #[arg(long)]
    pub passivity_velocity_hz: Option<f64>,
}

impl PassivityArgs {
    /// These flags over `c` (checked later with the whole configuration).
    pub fn apply(&self, c: &mut PassivityConfig) {
        if let Some(m) = self.passivity {
            c.mode = m;
        }
        for (flag, field) in [
            (self.passivity_v_floor_mps, &mut c.v_floor_mps),
            (self.passivity_damping_max, &mut c.damping_max_ns_per_m),
            (self.passivity_force_max_n, &mut c.force_max_n),
            (self.passivity_window_s, &mut c.window_s),
            (self.passivity_velocity_hz, &mut c.velocity_hz),
        ] {
            if let Some(v) = flag {
                *field = v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_auto_follows_the_board() {
        let c = PassivityConfig::default();
        c.validate().unwrap();
        assert!(!c.enabled_on(BoardKind::Sim));
        assert!(!c.enabled_on(BoardKind::Replay));
        let on = PassivityConfig {
            mode: PassivityMode::On,
            ..c.clone()
        };
        assert!(on.enabled_on(BoardKind::Sim));
    }

    #[test]
    fn out_of_range_numbers_are_refused_with_their_name_and_range() {
        for (c, want) in [
            (
                PassivityConfig {
                    v_floor_mps: 0.0,
                    ..Default::default()
                },
                "passivity.v_floor_mps must be within 1e-5..1 m/s (got 0)",
            ),
            (
                PassivityConfig {
                    damping_max_ns_per_m: f64::NAN,
                    ..Default::default()
                },
                "passivity.damping_max_ns_per_m",
            ),
            (
                PassivityConfig {
                    force_max_n: 100.0,
                    ..Default::default()
                },
                "passivity.force_max_n must be within 0.01..50 N",
            ),
            (
                PassivityConfig {
                    window_s: -1.0,
                    ..Default::default()
                },
                "passivity.window_s",
            ),
        ] {
            let e = c.validate().unwrap_err();
            assert!(e.contains(want), "{e}");
        }
    }
}
