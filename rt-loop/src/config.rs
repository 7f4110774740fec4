//! The run configuration: a TOML file (`--config`) whose every field has a default; command
//! line flags override it. The whole resolved configuration goes into the run metadata.

use crate::board::sim::SimConfig;
use crate::clock::RealtimeConfig;
use crate::experiment::hand::HandConfig;
use crate::experiment::{RampConfig, ReproductionConfig};
use crate::features::FeatureParams;
use crate::invalid::{require_within, InvalidSetting};
use crate::params::LoopParams;
use crate::record::Format;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ExperimentKind {
    Abstraction,
    PositionReplay,
    Reproduction,
    Shadow,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ClockKind {
    Lockstep,
    Realtime,
}

/// Which board the loop drives: `sim`, `replay`, or `s826[:N]` (a Sensoray 826 card, N the
/// board number its switches set, 0 by default). Written as that text in configs and metadata.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BoardKind {
    #[default]
    Sim,
    Replay,
    S826 {
        board: u32,
    },
}

impl std::str::FromStr for BoardKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "sim" => Ok(BoardKind::Sim),
            "replay" => Ok(BoardKind::Replay),
            "s826" => Ok(BoardKind::S826 { board: 0 }),
            _ => match s.strip_prefix("s826:").map(str::parse::<u32>) {
                Some(Ok(n)) if n < 16 => Ok(BoardKind::S826 { board: n }),
                Some(_) => Err(format!(
                    "board {s:?}: the 826's board number is 0..15 (its switches), e.g. s826:1"
                )),
                None => Err(format!("board {s:?}: expected sim, replay, s826 or s826:N")),
            },
        }
    }
}

impl std::fmt::Display for BoardKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BoardKind::Sim => f.write_str("sim"),
            BoardKind::Replay => f.write_str("replay"),
            BoardKind::S826 { board: 0 } => f.write_str("s826"),
            BoardKind::S826 { board } => write!(f, "s826:{board}"),
        }
    }
}

impl Serialize for BoardKind {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for BoardKind {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    pub experiment: ExperimentKind,
    pub board: BoardKind,
    /// Recording the replay board plays back.
    pub replay: Option<PathBuf>,
    pub clock: ClockKind,
    pub rate_hz: f64,
    pub seed: u64,
    pub material: PathBuf,
    /// Where to record (none: run without recording).
    pub record: Option<PathBuf>,
    /// Parquet unless set (or the record path ends in .csv).
    pub format: Option<Format>,
    /// Record every N-th step (1 = every step, lossless).
    pub decimate: u32,
    /// Replace an existing recording at `record` (refused otherwise: nothing is lost).
    pub overwrite: bool,
    /// Rows the loop-to-recorder ring holds.
    pub queue_capacity: usize,
    /// Stop after this much loop time, s.
    pub max_duration_s: Option<f64>,
    /// Recorded trajectory for position replay.
    pub trajectory: Option<PathBuf>,
    /// Position replay of `identify-friction`'s free-air sweeps instead of a recorded
    /// trajectory (friction_id.rs, `SweepPlan`): a recording of the bench's own friction, out of
    /// contact, for the models that identify it beside the object (record-dataset.sh's
    /// `train_air`).
    pub friction_sweep: bool,
    pub ramp: RampConfig,
    pub params: LoopParams,
    pub sim: SimConfig,
    /// The Sensoray 826's wiring and amplifier (`--board s826`).
    pub s826: crate::board::s826::S826Config,
    pub hand: HandConfig,
    pub features: FeatureParams,
    pub reproduction: ReproductionConfig,
    /// The degradation ladder of reproduction (late answers, held force, fallback fade).
    pub ladder: crate::serving::ladder::LadderConfig,
    /// The time-domain passivity layer of reproduction (after the ladder).
    pub passivity: crate::passivity::PassivityConfig,
    pub realtime: RealtimeConfig,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            experiment: ExperimentKind::Abstraction,
            board: BoardKind::Sim,
            replay: None,
            clock: ClockKind::Lockstep,
            rate_hz: 10_000.0,
            seed: 1,
            material: PathBuf::from("materials/sponge.toml"),
            record: None,
            format: None,
            decimate: 1,
            overwrite: false,
            queue_capacity: 1 << 16,
            max_duration_s: None,
            trajectory: None,
            friction_sweep: false,
            ramp: RampConfig::default(),
            params: LoopParams::default(),
            sim: SimConfig::default(),
            s826: Default::default(),
            hand: HandConfig::default(),
            features: FeatureParams::default(),
            reproduction: ReproductionConfig::default(),
            ladder: crate::serving::ladder::LadderConfig::default(),
            passivity: crate::passivity::PassivityConfig::default(),
            realtime: RealtimeConfig::default(),
        }
    }
}

impl RunConfig {
    pub fn from_toml(text: &str) -> anyhow::Result<RunConfig> {
        Ok(toml::from_str(text)?)
    }

    pub fn load(path: &std::path::Path) -> anyhow::Result<RunConfig> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("cannot read config {}: {e}", path.display()))?;
        RunConfig::from_toml(&text).map_err(|e| anyhow::anyhow!("config {}: {e}", path.display()))
    }

    pub fn format(&self) -> Format {
        self.format.unwrap_or_else(|| {
            self.record
                .as_deref()
                .map_or(Format::Parquet, Format::from_path)
        })
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        require_within("rate", self.rate_hz, 10.0..=100_000.0, "10..100000 Hz")?;
        if self.decimate == 0 {
            return Err("decimate must be >= 1".into());
        }
        if let Some(d) = self.max_duration_s {
            if !(d.is_finite() && d > 0.0) {
                return Err("max_duration_s must be > 0".into());
            }
        }
        if self.board == BoardKind::Replay && self.replay.is_none() {
            return Err("the replay board needs a recording (--replay PATH)".into());
        }
        if self.friction_sweep {
            if self.experiment != ExperimentKind::PositionReplay {
                return Err(
                    "--friction-sweep is a position replay (--experiment position-replay)".into(),
                );
            }
            if self.trajectory.is_some() {
                return Err(
                    "--friction-sweep replays the free-air sweeps: give it no --trajectory".into(),
                );
            }
        } else if self.experiment == ExperimentKind::PositionReplay && self.trajectory.is_none() {
            return Err(
                "position replay needs a trajectory (--trajectory RECORDING, or --friction-sweep)"
                    .into(),
            );
        }
        // The simulated bench measures with the loop's scales; a real board's come from the
        // rig file (`--rig`).
        if self.board == BoardKind::Sim
            && (self.params.meters_per_count != self.sim.meters_per_count
                || self.params.dac_full_scale != self.sim.dac_full_scale)
        {
            return Err("params and sim disagree on the encoder or DAC scale".into());
        }
        self.params.validate()?;
        self.validate_rates()?;
        self.validate_reproduction()?;
        self.ladder.validate()?;
        self.passivity.validate()?;
        self.ramp.validate()?;
        self.sim.validate()?;
        self.s826.validate()?;
        self.hand.validate()?;
        self.features.validate()?;
        Ok(())
    }
}

/// Largest `g T` (filter gain x nominal period) accepted: forward Euler, the thesis's
/// discretisation, alternates in sign beyond 1 and diverges beyond 2.
pub const MAX_GAIN_PERIOD: f64 = 1.0;

impl RunConfig {
    /// Refuses filter gains the loop cannot run at its rate (forward Euler: `g T < 1`).
    fn validate_rates(&self) -> Result<(), InvalidSetting> {
        let t = 1.0 / self.rate_hz;
        let p = &self.params;
        for (name, g) in [
            ("g_v", p.g_v),
            ("g_a", p.g_a),
            ("g_dis", p.g_dis),
            ("g_rec", p.g_rec),
        ] {
            if g * t >= MAX_GAIN_PERIOD {
                return Err(format!(
                    "parameter {name} = {g} rad/s is unstable at {} Hz: g x period = {:.3} must stay below {MAX_GAIN_PERIOD} (forward Euler); lower the gain or raise the rate above {:.0} Hz",
                    self.rate_hz,
                    g * t,
                    g / MAX_GAIN_PERIOD
                ).into());
            }
        }
        Ok(())
    }

    /// `[reproduction]`: the force limit and the fallback law's coefficients.
    fn validate_reproduction(&self) -> Result<(), InvalidSetting> {
        let r = &self.reproduction;
        if !(r.max_force_n.is_finite() && r.max_force_n > 0.0 && r.max_force_n <= 50.0) {
            return Err(format!(
                "reproduction.max_force_n must be within (0, 50] N (got {})",
                r.max_force_n
            )
            .into());
        }
        let fb = &r.fallback;
        for (name, v) in [("k1", fb.k1), ("k2", fb.k2), ("b", fb.b)] {
            if !(v.is_finite() && v.abs() <= 1e7) {
                return Err(format!(
                    "reproduction.fallback.{name} must be a finite number within +-1e7 (got {v})"
                )
                .into());
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The documented example (also in docs/rt-loop.md) parses and states the true defaults.
    #[test]
    fn example_config_states_the_defaults() {
        let text = include_str!("../config.example.toml");
        let c = RunConfig::from_toml(text).unwrap();
        let want = RunConfig {
            record: Some("data/run.parquet".into()),
            format: Some(Format::Parquet),
            ..RunConfig::default()
        };
        assert_eq!(c, want);
        let docs = include_str!("../../docs/rt-loop.md");
        assert!(docs.contains(text.lines().skip(2).collect::<Vec<_>>().join("\n").trim()));
    }

    /// Issue 13 item 4 / issue 14 item 4: every numeric setting is checked with a clear error.
    #[test]
    fn bad_numbers_are_refused_with_their_name() {
        for (text, want) in [
            ("[reproduction]\nmax_force_n = nan\n", "max_force_n"),
            ("[reproduction]\nmax_force_n = -1.0\n", "max_force_n"),
            (
                "[reproduction]\nfallback = { k1 = inf, k2 = 0.0, b = 0.0 }\n",
                "fallback.k1",
            ),
            (
                "[reproduction]\nfallback = { k1 = 1.0, k2 = nan, b = 0.0 }\n",
                "fallback.k2",
            ),
            ("[ladder]\nslew_n_per_step = 1.0\n", "slew_n_per_step"),
            ("[ladder]\nhold_max_s = nan\n", "hold_max_s"),
            ("rate_hz = 1000.0\n[params]\ng_dis = 1500.0\n", "g_dis"),
            ("rate_hz = 100.0\n", "unstable at 100 Hz"),
        ] {
            let c = RunConfig::from_toml(text).unwrap();
            let e = c.validate().unwrap_err();
            assert!(e.contains(want), "{text}: {e}");
        }
        assert!(RunConfig::default().validate().is_ok());
    }

    #[test]
    fn unknown_keys_are_refused() {
        let e = RunConfig::from_toml("[params]\nk_pp = 3.0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("k_pp"), "{e}");
    }
}
