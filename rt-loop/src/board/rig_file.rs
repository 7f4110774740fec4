//! The rig file: what `rt-loop board calibrate` measured on a real rig (counts per metre,
//! direction, the amplifier's A/V, force constant, moving mass, friction), read by every
//! command with `--rig FILE` into the loop's parameters and the 826's settings. TOML.

use crate::config::RunConfig;
use crate::control::friction::Friction;
use anyhow::{anyhow, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    /// Encoder counts per metre of probe travel (quadrature x4).
    pub counts_per_metre: f64,
    /// +1 when positive current moves the count up, -1 when down.
    pub direction: i32,
    /// The amplifier's gain, A per V of command.
    pub amps_per_volt: f64,
    /// Motor force constant, N/A.
    pub force_constant: f64,
    /// Moving mass, kg.
    pub moving_mass_kg: f64,
    /// Friction (`rt-loop identify-friction` on this rig).
    #[serde(default)]
    pub friction: Friction,
}

impl RigFile {
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("counts_per_metre", self.counts_per_metre),
            ("amps_per_volt", self.amps_per_volt),
            ("force_constant", self.force_constant),
            ("moving_mass_kg", self.moving_mass_kg),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(anyhow!("{name} must be a positive number (got {v})"));
            }
        }
        if self.direction != 1 && self.direction != -1 {
            return Err(anyhow!(
                "direction must be 1 or -1 (got {})",
                self.direction
            ));
        }
        Ok(())
    }

    pub fn load(path: &Path) -> Result<RigFile> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow!("cannot read rig file {}: {e}", path.display()))?;
        let r: RigFile =
            toml::from_str(&text).map_err(|e| anyhow!("rig file {}: {e}", path.display()))?;
        r.validate()
            .map_err(|e| anyhow!("rig file {}: {e}", path.display()))?;
        Ok(r)
    }

    /// Puts the calibration into a run's configuration: the loop's scales and nominal plant,
    /// the RFOB's friction, the 826's direction and gain.
    pub fn apply(&self, c: &mut RunConfig) {
        c.params.meters_per_count = 1.0 / self.counts_per_metre;
        c.params.k_fn = self.force_constant;
        c.params.m_n = self.moving_mass_kg;
        c.params.friction = self.friction;
        c.s826.direction = self.direction;
        c.s826.amps_per_volt = self.amps_per_volt;
    }

    /// The file's text, with a header saying what wrote it.
    pub fn to_toml(&self, header: &str) -> Result<String> {
        let body = toml::to_string(self)?;
        let mut out = String::new();
        for line in header.lines() {
            out.push_str("# ");
            out.push_str(line);
            out.push('\n');
        }
        out.push_str(&body);
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_apply() {
        let r = RigFile {
            counts_per_metre: 200_000.0,
            direction: -1,
            amps_per_volt: 0.1,
            force_constant: 23.5,
            moving_mass_kg: 0.66,
            friction: Friction::default(),
        };
        let text = r.to_toml("written by a test").unwrap();
        let back: RigFile = toml::from_str(&text).unwrap();
        assert_eq!(back, r);
        let mut c = RunConfig::default();
        back.apply(&mut c);
        assert_eq!(c.params.meters_per_count, 5e-6);
        assert_eq!(c.s826.direction, -1);
        let bad = RigFile { direction: 2, ..r };
        assert!(bad.validate().is_err());
    }
}
