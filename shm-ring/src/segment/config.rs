//! What the creator puts in a new segment: the feature schema and each ring's capacity,
//! checked before anything is mapped.

use super::channel::{ChannelSpec, CHANNELS};
use super::error::Error;
use super::header::MAX_SCHEMA_NAMES;
use crate::fixed_str::FixedStr;

/// Largest ring capacity accepted (slots), to keep a typo from mapping gigabytes.
pub const MAX_CAPACITY: usize = 1 << 20;

/// What the creator puts in a new segment.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Config {
    /// The schema: names of the values the first channel's messages carry, in order (at most
    /// [`MAX_SCHEMA_NAMES`]; haptics-proto's `layout::config()` puts the feature names here).
    pub feature_names: Vec<String>,
    /// Slots per ring, in the protocol's channel order; each a power of two in 2..=2^20, or 0
    /// for the channel's [`ChannelSpec::default_capacity`]. `Default`: all 0.
    pub capacities: [usize; CHANNELS],
}

impl Config {
    /// The capacities to use: 0 replaced by the protocol's default.
    pub(super) fn resolved_capacities(&self, specs: &[ChannelSpec; CHANNELS]) -> [usize; CHANNELS] {
        std::array::from_fn(|i| match self.capacities[i] {
            0 => specs[i].default_capacity,
            n => n,
        })
    }

    pub(super) fn validate(&self, specs: &[ChannelSpec; CHANNELS]) -> Result<Vec<FixedStr>, Error> {
        for (spec, cap) in specs.iter().zip(self.resolved_capacities(specs)) {
            if !cap.is_power_of_two() || !(2..=MAX_CAPACITY).contains(&cap) {
                return Err(Error::InvalidConfig(format!(
                    "{} capacity {cap} must be a power of two in 2..={MAX_CAPACITY}",
                    spec.name
                )));
            }
        }
        if self.feature_names.len() > MAX_SCHEMA_NAMES {
            return Err(Error::InvalidConfig(format!(
                "{} feature names, at most {MAX_SCHEMA_NAMES} fit the schema",
                self.feature_names.len()
            )));
        }
        let mut names = Vec::with_capacity(self.feature_names.len());
        for (i, name) in self.feature_names.iter().enumerate() {
            if name.is_empty() {
                return Err(Error::InvalidConfig(format!("feature name #{i} is empty")));
            }
            if self.feature_names[..i].contains(name) {
                return Err(Error::InvalidConfig(format!(
                    "feature name `{name}` appears twice"
                )));
            }
            names.push(
                FixedStr::new(name)
                    .map_err(|e| Error::InvalidConfig(format!("feature name: {e}")))?,
            );
        }
        Ok(names)
    }
}
