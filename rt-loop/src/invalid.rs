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
