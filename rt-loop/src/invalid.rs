//! Why the loop refuses what it was given before anything moves: a setting (config file,
//! flag, material, bench file) out of range or inconsistent with another, or an input series
//! (a trajectory to follow, a recording to replay) that cannot be played. A leaf module: every
//! part that checks its own settings returns these without importing the configuration that
//! gathers them (which imports every part).

/// A setting out of its range or inconsistent with another; the message names it and says
/// what is accepted.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct InvalidSetting(pub String);

/// An input series that cannot be played; the message names the row where it can.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct InvalidSeries(pub String);

macro_rules! from_text {
    ($t:ident) => {
        impl From<String> for $t {
            fn from(s: String) -> Self {
                $t(s)
            }
        }
        impl From<&str> for $t {
            fn from(s: &str) -> Self {
                $t(s.to_string())
            }
        }
        impl $t {
            /// Whether the message contains `s` (tests name the setting they expect).
            pub fn contains(&self, s: &str) -> bool {
                self.0.contains(s)
            }
        }
    };
}

from_text!(InvalidSetting);
from_text!(InvalidSeries);

/// The first of `settings` (name, value) that is not finite or that `ok` refuses: every part
/// checks its ranges through this one loop, so NaN and infinities are refused everywhere.
pub fn first_refused<'a>(
    settings: &[(&'a str, f64)],
    ok: impl Fn(f64) -> bool,
) -> Option<(&'a str, f64)> {
    settings
        .iter()
        .copied()
        .find(|&(_, v)| !(v.is_finite() && ok(v)))
}

/// Refuses the first of `settings` that is not a finite number > 0, naming it.
pub fn require_positive(settings: &[(&str, f64)]) -> Result<(), InvalidSetting> {
    match first_refused(settings, |v| v > 0.0) {
        Some((n, v)) => Err(format!("{n} must be > 0 (got {v})").into()),
        None => Ok(()),
    }
}

/// Refuses the first of `settings` that is not a finite number >= 0, naming it.
pub fn require_non_negative(settings: &[(&str, f64)]) -> Result<(), InvalidSetting> {
    match first_refused(settings, |v| v >= 0.0) {
        Some((n, v)) => Err(format!("{n} must be >= 0 (got {v})").into()),
        None => Ok(()),
    }
}

/// Refuses `v` unless it is finite and within `range`; `shown` is the range as the message
/// gives it, with its unit (`"0..1 s"`).
pub fn require_within(
    name: &str,
    v: f64,
    range: std::ops::RangeInclusive<f64>,
    shown: &str,
) -> Result<(), InvalidSetting> {
    if v.is_finite() && range.contains(&v) {
        Ok(())
    } else {
        Err(format!("{name} must be within {shown} (got {v})").into())
    }
}
