//! The material file: everything that describes the simulated object, so a second object is a
//! new TOML file, not new code. Format documented in docs/rt-loop.md; `materials/sponge.toml`
//! is the default.

use crate::invalid::InvalidSetting;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Maxwell branches a material may have: the simulated sponge keeps their state inline (fixed
/// arrays, so stepping it allocates nothing), and the file is checked against the same bound.
pub const MAX_BRANCHES: usize = 6;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    pub name: String,
    /// Rate-independent foam law F_eq(e) of the compression e (m):
    /// `plateau_n * tanh(e / yield_m) + densification_n * ((1 - e / densification_m)^-exponent - 1)`.
    pub equilibrium: Equilibrium,
    /// Generalized Maxwell branches (quasi-linear viscoelasticity): each branch force q obeys
    /// dq = gain * dF_eq - q dt / tau_s, so fast ramps meet a stiffer sponge than slow ones.
    #[serde(default)]
    pub maxwell: Vec<MaxwellBranch>,
    /// Rate-independent hysteresis (a Dahl element bounded by a fraction of F_eq).
    pub hysteresis: Hysteresis,
    /// Permanent deformation (compression set) growing with the largest compression seen.
    pub permanent_set: PermanentSet,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Equilibrium {
    pub plateau_n: f64,
    pub yield_m: f64,
    pub densification_n: f64,
    pub densification_m: f64,
    pub exponent: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaxwellBranch {
    pub gain: f64,
    pub tau_s: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hysteresis {
    /// Half-width of the hysteresis band as a fraction of F_eq.
    pub fraction: f64,
    /// Initial slope of the Dahl element relative to the foam's tangent stiffness.
    pub stiffness_ratio: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PermanentSet {
    /// Set reached after a compression to `reference_m` (m).
    pub max_m: f64,
    pub reference_m: f64,
    /// Target set = max_m * (largest compression / reference_m)^exponent.
    pub exponent: f64,
    /// The set grows toward its target with this time constant while heavily loaded
    /// (compression above `loaded_fraction` of the largest compression seen).
    pub tau_grow_s: f64,
    pub loaded_fraction: f64,
    /// It recovers toward `keep_fraction` of the target with this (slow) time constant.
    pub tau_recover_s: f64,
    pub keep_fraction: f64,
}

impl Material {
    /// Reads a material file. A relative path that does not exist from the working directory is
    /// also looked up from the folders above the executable (`target/release/rt-loop` finds the
    /// repository's `materials/`) and under `/usr/share/haptics` (containers, lab installs), so
    /// the default `materials/sponge.toml` works from any directory.
    pub fn load(path: &Path) -> anyhow::Result<(Material, String)> {
        let found = resolve(path);
        let text = std::fs::read_to_string(&found).map_err(|e| {
            anyhow::anyhow!(
                "cannot read material file {}: {e} (also looked above the executable and in /usr/share/haptics)",
                path.display()
            )
        })?;
        let path = found.as_path();
        let m = Material::parse(&text)
            .map_err(|e| anyhow::anyhow!("material file {}: {e}", path.display()))?;
        Ok((m, text))
    }

    /// The repository's `materials/sponge.toml`, which the tests of the parts that render a
    /// material drive.
    #[cfg(test)]
    pub(crate) fn repository_sponge() -> Material {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../materials/sponge.toml"
        ))
        .unwrap();
        Material::parse(&text).unwrap()
    }

    pub fn parse(text: &str) -> anyhow::Result<Material> {
        let m: Material = toml::from_str(text)?;
        m.validate().map_err(|e| anyhow::anyhow!(e))?;
        Ok(m)
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let e = &self.equilibrium;
        let checks = [
            ("equilibrium.plateau_n", e.plateau_n, true),
            ("equilibrium.yield_m", e.yield_m, false),
            ("equilibrium.densification_n", e.densification_n, true),
            ("equilibrium.densification_m", e.densification_m, false),
            ("equilibrium.exponent", e.exponent, false),
            ("hysteresis.fraction", self.hysteresis.fraction, true),
            (
                "hysteresis.stiffness_ratio",
                self.hysteresis.stiffness_ratio,
                true,
            ),
            ("permanent_set.max_m", self.permanent_set.max_m, true),
            (
                "permanent_set.reference_m",
                self.permanent_set.reference_m,
                false,
            ),
            ("permanent_set.exponent", self.permanent_set.exponent, true),
            (
                "permanent_set.tau_grow_s",
                self.permanent_set.tau_grow_s,
                false,
            ),
            (
                "permanent_set.tau_recover_s",
                self.permanent_set.tau_recover_s,
                false,
            ),
        ];
        for (name, v, zero_ok) in checks {
            let ok = v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0));
            if !ok {
                return Err(format!(
                    "{name} must be {} (got {v})",
                    if zero_ok { ">= 0" } else { "> 0" }
                )
                .into());
            }
        }
        if !(0.0..1.0).contains(&self.hysteresis.fraction) {
            return Err("hysteresis.fraction must be in [0, 1)".into());
        }
        for (name, v) in [
            (
                "permanent_set.keep_fraction",
                self.permanent_set.keep_fraction,
            ),
            (
                "permanent_set.loaded_fraction",
                self.permanent_set.loaded_fraction,
            ),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("{name} must be in [0, 1] (got {v})").into());
            }
        }
        for (i, b) in self.maxwell.iter().enumerate() {
            if !(b.gain.is_finite() && b.gain >= 0.0 && b.tau_s.is_finite() && b.tau_s > 0.0) {
                return Err(format!("maxwell[{i}]: gain must be >= 0 and tau_s > 0").into());
            }
        }
        if self.maxwell.len() > MAX_BRANCHES {
            return Err(format!("at most {} maxwell branches are supported", MAX_BRANCHES).into());
        }
        Ok(())
    }
}

fn resolve(path: &Path) -> std::path::PathBuf {
    if path.is_absolute() || path.exists() {
        return path.to_path_buf();
    }
    let exe_dirs = std::env::current_exe().ok().into_iter().flat_map(|exe| {
        exe.ancestors()
            .skip(1)
            .map(Path::to_path_buf)
            .collect::<Vec<_>>()
    });
    exe_dirs
        .chain(std::iter::once(std::path::PathBuf::from(
            "/usr/share/haptics",
        )))
        .map(|dir| dir.join(path))
        .find(|candidate| candidate.is_file())
        .unwrap_or_else(|| path.to_path_buf())
}
