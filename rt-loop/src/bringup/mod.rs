//! Bring-up and calibration, what a lab does on the first day with a real board (`rt-loop
//! board check`, `rt-loop board calibrate`, `rt-loop board clear-safe-mode`), and the pulse
//! measurement both use. Off the real-time path: these run slowly (1 kHz, paced with sleeps)
//! under a generous watchdog, in free air, with small current-limited pulses.

pub mod calibrate;
pub mod check;

use crate::board::Board;
use crate::control::dac;
use crate::lstsq::NormalEquations3;
use anyhow::{anyhow, Result};
use std::time::{Duration, Instant};

/// The pacing of the bring-up steps.
pub const STEP: Duration = Duration::from_millis(1);
/// The watchdog armed during bring-up (sleep-paced steps: generous), microseconds.
pub const BRINGUP_WATCHDOG_US: u32 = 50_000;

/// What one constant-current pulse did to the encoder.
#[derive(Clone, Copy, Debug)]
pub struct Pulse {
    /// Commanded current, A.
    pub amps: f64,
    /// Counts from the start to the end of the pulse (signed as the board reports them).
    pub counts: i64,
    /// Acceleration over the pulse (quadratic fit of position against board time), m/s^2.
    pub accel_mps2: f64,
    /// Board time the pulse lasted, s.
    pub seconds: f64,
}

/// Drives `amps` for `dur`, then 0 A for `coast` (reading, writing and kicking every
/// [`STEP`]), and fits the motion during the pulse.
pub fn pulse(
    board: &mut dyn Board,
    amps: f64,
    dur: Duration,
    coast: Duration,
    meters_per_count: f64,
    dac_full_scale: f64,
) -> Result<Pulse> {
    let word = dac::current_to_word(amps, dac_full_scale);
    let zero = dac::current_to_word(0.0, dac_full_scale);
    let first = board.read().map_err(|e| anyhow!("read: {}", e.reason()))?;
    let (c0, t0) = (first.counts as i64, first.timestamp_us);
    let start = Instant::now();
    let mut fit = NormalEquations3::default();
    let mut last = (c0, 0.0);
    let mut k = 1u32;
    while start.elapsed() < dur + coast {
        let on = start.elapsed() < dur;
        board
            .write(if on { word } else { zero })
            .map_err(|e| anyhow!("DAC write: {}", e.reason()))?;
        board
            .kick()
            .map_err(|e| anyhow!("watchdog kick: {}", e.reason()))?;
        let until = STEP * k;
        k += 1;
        if let Some(d) = until.checked_sub(start.elapsed()) {
            std::thread::sleep(d);
        }
        let s = board.read().map_err(|e| anyhow!("read: {}", e.reason()))?;
        if on {
            let t = s.timestamp_us.wrapping_sub(t0) as f64 * 1e-6;
            let x = (s.counts as i64 - c0) as f64 * meters_per_count;
            fit.add([1.0, t, t * t], x);
            last = (s.counts as i64, t);
        }
    }
    board
        .write(zero)
        .map_err(|e| anyhow!("DAC write: {}", e.reason()))?;
    let accel = fit.solve().map_or(f64::NAN, |c| 2.0 * c[2]);
    Ok(Pulse {
        amps,
        counts: last.0 - c0,
        accel_mps2: accel,
        seconds: last.1,
    })
}

/// One line of a bring-up report: what was checked, whether it passed, and what it found or
/// what to change.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Line {
    pub what: &'static str,
    pub pass: bool,
    pub says: String,
}

impl std::fmt::Display for Line {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:<28} {}  {}",
            self.what,
            if self.pass { "pass" } else { "FAIL" },
            self.says
        )
    }
}
