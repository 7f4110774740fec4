//! The material file: everything that describes the simulated object, so a second object is a
//! new TOML file, not new code. A file names its law (`law = "foam"`, the default for files
//! written before there was a choice; `"bouc_wen"`, `"poroelastic"`, `"onnx"`) and gives that
//! law's tables. An `onnx` file names a graph, opened (relative to the file) when the file is. Format documented in docs/rt-loop.md ("Material file"); `materials/sponge.toml` is
//! the default.

use crate::invalid::InvalidSetting;
use serde::{Deserialize, Serialize};
use std::path::Path;

use super::bouc_wen::BoucWenParams;
use super::onnx::{OnnxFile, OnnxParams};
use super::poroelastic::PoroelasticParams;

/// Maxwell branches a material may have: the simulated sponge keeps their state inline (fixed
/// arrays, so stepping it allocates nothing), and the file is checked against the same bound.
pub const MAX_BRANCHES: usize = 6;

/// The laws a material file may name (`law = "..."`).
pub const LAWS: [&str; 4] = ["foam", "bouc_wen", "poroelastic", "onnx"];

/// A material file: its name and its law's parameters.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Material {
    pub name: String,
    #[serde(flatten)]
    pub law: LawParams,
}

/// The parameters of one law (the file's `law` key says which).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "law", rename_all = "snake_case")]
pub enum LawParams {
    /// The viscoelastic foam of docs/physics.md, "The simulated sponge bench" ([`super::foam`]).
    Foam(Foam),
    /// A Bouc-Wen hysteretic material ([`super::bouc_wen`]).
    BoucWen(BoucWenParams),
    /// A poroelastic gel under a spherical indenter ([`super::poroelastic`]).
    Poroelastic(PoroelasticParams),
    /// A stateful ONNX graph stepped through ONNX Runtime ([`super::onnx`]).
    Onnx(OnnxParams),
}

impl LawParams {
    /// The law's name as the file writes it.
    pub fn name(&self) -> &'static str {
        match self {
            LawParams::Foam(_) => "foam",
            LawParams::BoucWen(_) => "bouc_wen",
            LawParams::Poroelastic(_) => "poroelastic",
            LawParams::Onnx(_) => "onnx",
        }
    }
}

/// The foam law's tables (`law = "foam"`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Foam {
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
        let base = path.parent().unwrap_or(Path::new("."));
        let m = Material::parse_in(&text, base)
            .map_err(|e| anyhow::anyhow!("material file {}: {e}", path.display()))?;
        Ok((m, text))
    }

    /// The repository's `materials/sponge.toml`, which the tests of the parts that render a
    /// material drive.
    #[cfg(test)]
    pub(crate) fn repository_sponge() -> Material {
        Material::repository("sponge")
    }

    /// The repository's `materials/<name>.toml` (tests).
    #[cfg(test)]
    pub(crate) fn repository(name: &str) -> Material {
        let path = format!("{}/../materials/{name}.toml", env!("CARGO_MANIFEST_DIR"));
        Material::parse(&std::fs::read_to_string(path).unwrap()).unwrap()
    }

    /// The foam's tables, when the law is the foam.
    pub fn foam(&self) -> Option<&Foam> {
        match &self.law {
            LawParams::Foam(f) => Some(f),
            _ => None,
        }
    }

    /// Parses a material file: `name`, `law` (default `"foam"`) and that law's tables, every
    /// other key refused. An `onnx` law's graph is opened relative to the working directory
    /// ([`Material::load`] opens it relative to the file).
    pub fn parse(text: &str) -> anyhow::Result<Material> {
        Material::parse_in(text, Path::new("."))
    }

    /// [`Material::parse`], an `onnx` law's graph opened relative to `base`.
    pub fn parse_in(text: &str, base: &Path) -> anyhow::Result<Material> {
        let mut table: toml::Table = toml::from_str(text)?;
        let name = match table.remove("name") {
            Some(toml::Value::String(s)) => s,
            Some(_) => anyhow::bail!("name must be a string"),
            None => anyhow::bail!("missing field `name`"),
        };
        let law = match table.remove("law") {
            None => "foam".to_string(),
            Some(toml::Value::String(s)) => s,
            Some(_) => anyhow::bail!("law must be a string (one of {})", LAWS.join(", ")),
        };
        let rest = toml::Value::Table(table);
        // one line: the law's tables are read without the text, so the error is its message
        let line = |e: toml::de::Error| anyhow::anyhow!("law {law:?}: {}", e.message());
        let law = match law.as_str() {
            "foam" => LawParams::Foam(rest.try_into().map_err(line)?),
            "bouc_wen" => LawParams::BoucWen(rest.try_into().map_err(line)?),
            "poroelastic" => LawParams::Poroelastic(rest.try_into().map_err(line)?),
            "onnx" => {
                // checked before the graph is opened: a bad rate needs no ONNX Runtime
                let file: OnnxFile = rest.try_into().map_err(line)?;
                file.validate().map_err(|e| anyhow::anyhow!(e))?;
                LawParams::Onnx(file.open(base)?)
            }
            other => anyhow::bail!("unknown law {other:?} (known: {})", LAWS.join(", ")),
        };
        let m = Material { name, law };
        m.validate().map_err(|e| anyhow::anyhow!(e))?;
        Ok(m)
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        match &self.law {
            LawParams::Foam(f) => f.validate(),
            LawParams::BoucWen(b) => b.validate(),
            LawParams::Poroelastic(p) => p.validate(),
            LawParams::Onnx(p) => p.file.validate(),
        }
    }
}

impl Foam {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped foams name their law; a file without `law` is a foam (every file written
    /// before there was a choice); a file naming another law reads that law's table; an
    /// unknown law, a table of another law or an unknown key is a one-line error naming it.
    #[test]
    fn a_file_names_its_law_foam_by_default() {
        let sponge = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../materials/sponge.toml"
        ))
        .unwrap();
        let named = Material::parse(&sponge).unwrap();
        assert_eq!(named.law.name(), "foam");
        // the same file as it was written before there was a choice: no `law` line
        let unnamed: String = sponge
            .lines()
            .filter(|l| !l.starts_with("law = "))
            .map(|l| format!("{l}\n"))
            .collect();
        assert_ne!(unnamed, sponge, "materials/sponge.toml names its law");
        assert_eq!(Material::parse(&unnamed).unwrap(), named);
        for foam in ["foam-b", "foam-c"] {
            let path = format!("{}/../materials/{foam}.toml", env!("CARGO_MANIFEST_DIR"));
            let text = std::fs::read_to_string(&path).unwrap();
            assert!(
                text.lines().any(|l| l.starts_with("law = \"foam\"")),
                "{path}"
            );
        }
        let gel = "name = \"g\"\nlaw = \"poroelastic\"\n[poroelastic]\nshear_modulus_pa = 1.0\n\
                   poisson_drained = 0.2\nindenter_radius_m = 0.01\ndiffusivity_m2_per_s = 1e-5\n";
        assert_eq!(Material::parse(gel).unwrap().law.name(), "poroelastic");
        for (text, needle) in [
            ("name = \"x\"\nlaw = \"jelly\"\n", "unknown law \"jelly\""),
            (
                &gel.replace("poroelastic\"\n", "bouc_wen\"\n"),
                "poroelastic",
            ),
            (
                &gel.replace("poisson_drained = 0.2", "poisson_drained = 0.7"),
                "poisson_drained",
            ),
            (&format!("{gel}colour = 1\n"), "colour"),
            ("law = \"foam\"\n", "name"),
        ] {
            let err = Material::parse(text).unwrap_err().to_string();
            assert!(err.contains(needle), "{text:?}: {err}");
            assert!(!err.trim().contains('\n'), "one line: {err}");
        }
    }
}
