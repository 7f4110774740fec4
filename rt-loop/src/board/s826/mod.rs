//! A Sensoray 826 PCIe card driving the thesis's rig: a quadrature encoder on one counter
//! channel, a current amplifier on one analog output, the card's hardware watchdog guarding
//! both. The vendor's library is loaded at run time ([`library`]); its C interface, exactly as
//! `826api.h` declares it, and its error codes as typed errors are in [`api`]; the board
//! itself, its lifecycle and its per-step calls are in [`board`].
//!
//! The same code drives the C-ABI double of the SDK (`tests/s826-double`, built as
//! `libs826_double.so`), which simulates the rig behind the same symbols: what could only be
//! checked against the double, not a real card, is listed in docs/lab.md.

pub mod api;
pub mod board;
pub mod library;

pub use board::{S826Board, Versions};

use crate::invalid::{require_positive, InvalidSetting};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// How the 826 is wired to the rig (`[s826]` in the config; the rig file's calibration
/// overrides `amps_per_volt` and `direction`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct S826Config {
    /// The vendor library (`--s826-lib`; else HAPTICS_S826_LIB, else the library paths).
    pub lib: Option<PathBuf>,
    /// Counter channel (0..5) the encoder's A/B lines are wired to.
    pub encoder_channel: u32,
    /// Analog output (0..7) wired to the amplifier's command input.
    pub dac_channel: u32,
    /// The amplifier's gain: amperes per volt of command.
    pub amps_per_volt: f64,
    /// +1 when positive current moves the encoder's count up, -1 when it moves it down (the
    /// counts are multiplied by this, so the loop always sees positive = into the object).
    pub direction: i32,
    /// Hardware watchdog timeout, microseconds; `None`: five periods of the loop's rate.
    pub watchdog_us: Option<u32>,
    /// Reads of an empty snapshot FIFO retried within one step before it is a fault.
    pub snapshot_retries: u32,
}

impl Default for S826Config {
    fn default() -> Self {
        S826Config {
            lib: None,
            encoder_channel: 0,
            dac_channel: 0,
            amps_per_volt: 0.1,
            direction: 1,
            watchdog_us: None,
            snapshot_retries: 3,
        }
    }
}

/// Periods of the loop the hardware watchdog waits by default.
pub const WATCHDOG_PERIODS: f64 = 5.0;

impl S826Config {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        require_positive(&[("s826.amps_per_volt", self.amps_per_volt)])?;
        if self.encoder_channel >= api::NUM_COUNT {
            return Err("s826.encoder_channel must be 0..5 (the 826's counters)".into());
        }
        if self.dac_channel >= api::NUM_DAC {
            return Err("s826.dac_channel must be 0..7 (the 826's analog outputs)".into());
        }
        if self.direction != 1 && self.direction != -1 {
            return Err("s826.direction must be 1 or -1".into());
        }
        if self.watchdog_us == Some(0) {
            return Err("s826.watchdog_us must be > 0".into());
        }
        Ok(())
    }

    /// The watchdog timeout at `rate_hz`: the configured one, else [`WATCHDOG_PERIODS`]
    /// periods.
    pub fn watchdog_at(&self, rate_hz: f64) -> u32 {
        self.watchdog_us
            .unwrap_or((WATCHDOG_PERIODS * 1e6 / rate_hz).round() as u32)
            .max(1)
    }
}
