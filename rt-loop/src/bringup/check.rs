//! `rt-loop board check --board s826`: each line says pass, or what to change. In order: the
//! library and the card's versions; safe mode; the encoder following a small, slow,
//! current-limited pulse; the DAC's polarity and the amplifier's gain (two pulses); counts per
//! metre against a commanded displacement (the position loop); and a watchdog trip that shows
//! the card going to safe mode (0 A) by itself, without the host.

use super::{pulse, Line, BRINGUP_WATCHDOG_US};
use crate::board::s826::S826Board;
use crate::board::Board;
use crate::config::{BoardKind, RunConfig};
use crate::experiment::{Experiment, PositionPid, Trajectory};
use anyhow::{anyhow, Result};
use std::time::{Duration, Instant};

/// The test pulses: fractions of the current limit (small: a few newtons on the thesis rig).
pub const PULSE_FRACTIONS: [f64; 2] = [0.15, 0.3];
/// How long each pulse drives, and how long the probe coasts after it.
pub const PULSE: Duration = Duration::from_millis(40);
pub const COAST: Duration = Duration::from_millis(300);
/// The displacement the position loop is commanded to, m.
pub const MOVE_M: f64 = 0.005;
/// Gains within this factor of the configured one pass.
pub const GAIN_TOLERANCE: f64 = 1.33;

/// Opens the configured 826 for bring-up (generous watchdog; `board` its number).
pub fn open_board(cfg: &RunConfig) -> Result<S826Board> {
    let BoardKind::S826 { board } = cfg.board else {
        anyhow::bail!("board check and calibrate need a real board: pass --board s826[:N]");
    };
    let mut s = cfg.s826.clone();
    s.watchdog_us = Some(BRINGUP_WATCHDOG_US);
    Ok(S826Board::new(
        board,
        s,
        cfg.params.current_limit,
        cfg.params.dac_full_scale,
        cfg.rate_hz,
    )?)
}

/// The two pulses' accelerations and what they imply.
pub struct PulsePair {
    pub first: super::Pulse,
    pub second: super::Pulse,
}

impl PulsePair {
    /// The current the motor actually got per commanded ampere, from the difference of the two
    /// accelerations with the nominal mass and force constant (friction cancels).
    pub fn gain_ratio(&self, m_n: f64, k_fn: f64) -> f64 {
        let da = self.second.accel_mps2 - self.first.accel_mps2;
        let di = self.second.amps - self.first.amps;
        da * m_n / (k_fn * di)
    }

    /// The moving mass implied by the force constant `k_f`, assuming the amplifier's gain.
    pub fn mass(&self, k_f: f64) -> f64 {
        k_f * (self.second.amps - self.first.amps)
            / (self.second.accel_mps2 - self.first.accel_mps2)
    }
}

/// Drives the two test pulses on an activated board.
pub fn pulses(board: &mut S826Board, cfg: &RunConfig) -> Result<PulsePair> {
    let p = &cfg.params;
    let mut one = |f: f64| {
        pulse(
            board,
            f * p.current_limit,
            PULSE,
            COAST,
            p.meters_per_count,
            p.dac_full_scale,
        )
    };
    Ok(PulsePair {
        first: one(PULSE_FRACTIONS[0])?,
        second: one(PULSE_FRACTIONS[1])?,
    })
}

fn line(what: &'static str, pass: bool, says: String) -> Line {
    Line { what, pass, says }
}

/// Runs the check; the lines so far (a failing step ends it when what follows would be
/// meaningless or unsafe).
pub fn check(cfg: &RunConfig) -> Result<Vec<Line>> {
    let mut out = Vec::new();
    let mut board = match open_board(cfg) {
        Ok(b) => b,
        Err(e) => {
            out.push(line("library", false, format!("{e:#}")));
            return Ok(out);
        }
    };
    out.push(line("library", true, board.lib_path().to_string()));
    if let Err(e) = board.open() {
        out.push(line("board and versions", false, e.to_string()));
        return Ok(out);
    }
    let v = board.versions().unwrap_or_default();
    out.push(line("board and versions", true, v.to_string()));
    match board.safe_mode() {
        Ok(false) => out.push(line("safe mode", true, "not active".into())),
        Ok(true) => {
            out.push(line(
                "safe mode",
                false,
                "the board is in safe mode (0 A): find out why (docs/lab.md, \"When the watchdog \
                 trips\"), then `rt-loop board clear-safe-mode`"
                    .into(),
            ));
            return Ok(out);
        }
        Err(e) => {
            out.push(line("safe mode", false, e.to_string()));
            return Ok(out);
        }
    }
    board.configure()?;
    board.activate(0)?;
    let p = &cfg.params;
    let pair = pulses(&mut board, cfg)?;
    let c = pair.first.counts;
    let mm = |counts: i64| counts as f64 * p.meters_per_count * 1e3;
    let follows = if c > 10 {
        line(
            "encoder follows the current",
            true,
            format!(
                "+{:.3} A for {} ms moved +{c} counts ({:.2} mm)",
                pair.first.amps,
                PULSE.as_millis(),
                mm(c)
            ),
        )
    } else if c < -10 {
        line(
            "encoder follows the current",
            false,
            format!(
                "+{:.3} A moved {c} counts (backwards): set direction = {} in the rig file (or \
                 swap the encoder's A and B lines)",
                pair.first.amps, -cfg.s826.direction
            ),
        )
    } else {
        line(
            "encoder follows the current",
            false,
            format!(
                "+{:.3} A moved {c} counts: no motion. Check the amplifier is enabled, the motor \
                 free (no object, not at an end stop), the encoder on counter channel {} \
                 (s826.encoder_channel), the DAC on channel {} (s826.dac_channel)",
                pair.first.amps, cfg.s826.encoder_channel, cfg.s826.dac_channel
            ),
        )
    };
    let moved = follows.pass;
    out.push(follows);
    if moved {
        let ratio = pair.gain_ratio(p.m_n, p.k_fn);
        let gain = ratio * cfg.s826.amps_per_volt;
        let says = format!(
            "the motor accelerated as with {gain:.4} A/V (configured {:.4} A/V; {:.2} and {:.2} \
             m/s^2 at {:.3} and {:.3} A, nominal mass {} kg, K_f {} N/A)",
            cfg.s826.amps_per_volt,
            pair.first.accel_mps2,
            pair.second.accel_mps2,
            pair.first.amps,
            pair.second.amps,
            p.m_n,
            p.k_fn
        );
        out.push(if !ratio.is_finite() || ratio <= 0.0 {
            line(
                "DAC polarity and amp gain",
                false,
                format!("{says}: more current accelerated less; check the DAC polarity and the amplifier's current mode"),
            )
        } else if !(1.0 / GAIN_TOLERANCE..=GAIN_TOLERANCE).contains(&ratio) {
            line(
                "DAC polarity and amp gain",
                false,
                format!("{says}: set amps_per_volt = {gain:.4} in the rig file (or correct the mass and force constant: `rt-loop board calibrate`)"),
            )
        } else {
            line("DAC polarity and amp gain", true, says)
        });
        let (b, l) = counts_per_metre(board, cfg)?;
        board = b;
        out.push(l);
    }
    out.push(watchdog_trip(&mut board, cfg)?);
    board.deactivate();
    board.shutdown();
    Ok(out)
}

/// Commands the position loop to [`MOVE_M`] and back; reports the counts it reached.
fn counts_per_metre(board: S826Board, cfg: &RunConfig) -> Result<(S826Board, Line)> {
    // a smooth 0.5 s move, a 0.5 s hold, back in 0.5 s
    let n = 1500usize;
    let t: Vec<f64> = (0..=n).map(|i| i as f64 * 1e-3).collect();
    let x: Vec<f64> = t
        .iter()
        .map(|&t| {
            let s = |u: f64| 0.5 - 0.5 * (std::f64::consts::PI * u.clamp(0.0, 1.0)).cos();
            MOVE_M
                * if t < 1.0 {
                    s(t / 0.5)
                } else {
                    1.0 - s((t - 1.0) / 0.5)
                }
        })
        .collect();
    let trajectory = Trajectory::new(t, x).map_err(|e| anyhow!(e))?;
    let experiment = Experiment::PositionReplay {
        trajectory,
        pid: PositionPid::new(&cfg.params),
    };
    let mut rig =
        crate::control::rig::Rig::new(board, cfg.params.clone(), experiment, cfg.features.clone())
            .map_err(|f| anyhow!("{}", f.error))?;
    rig.set_period(1.0 / cfg.rate_hz);
    let mut clock = crate::clock::RealtimeClock::new(cfg.rate_hz);
    clock.start();
    let (mut sum, mut k) = (0.0, 0u64);
    let stop = loop {
        clock.wait();
        match rig.step() {
            Ok(r) => {
                if r.time > 0.7 && r.time < 0.95 {
                    sum += r.counts as f64;
                    k += 1;
                }
            }
            Err(s) => break s,
        }
    };
    let mut board = rig.board;
    board.deactivate();
    if stop != crate::control::rig::Stop::Finished || k == 0 {
        let l = line(
            "counts per metre",
            false,
            format!("the position loop stopped: {stop:?}"),
        );
        return Ok((board, l));
    }
    let counts = sum / k as f64;
    let reached = counts * cfg.params.meters_per_count;
    let says = format!(
        "commanded {:.3} mm, the encoder held {counts:.0} counts = {:.3} mm at {:.0} counts/m; if \
         a dial gauge shows D mm of travel instead, set counts_per_metre = {counts:.0} / (D / 1000)",
        MOVE_M * 1e3,
        reached * 1e3,
        1.0 / cfg.params.meters_per_count
    );
    let pass = (reached - MOVE_M).abs() < 0.05 * MOVE_M;
    Ok((board, line("counts per metre", pass, says)))
}

/// Arms the watchdog at the board's own timeout, stops kicking, and waits for the card to go
/// into safe mode by itself.
fn watchdog_trip(board: &mut S826Board, cfg: &RunConfig) -> Result<Line> {
    let wd = cfg.s826.watchdog_at(cfg.rate_hz);
    board.set_watchdog_us(wd);
    board.activate(0)?;
    let small = crate::control::dac::current_to_word(
        0.5 * PULSE_FRACTIONS[0] * cfg.params.current_limit,
        cfg.params.dac_full_scale,
    );
    board
        .write(small)
        .map_err(|e| anyhow!("DAC write: {}", e.reason()))?;
    let t0 = Instant::now();
    // the host now does nothing: no kick
    let fired = board
        .wait_watchdog(20 * wd + 100_000)
        .map_err(|e| anyhow!("{e}"))?;
    let after = t0.elapsed();
    let safe = board.safe_mode().map_err(|e| anyhow!("{e}"))?;
    let l = if fired && safe {
        board.clear_safe_mode()?;
        line(
            "watchdog trip",
            true,
            format!(
                "without kicks the card went into safe mode (0 A) by itself after {:.2} ms \
                 (watchdog {wd} us); cleared again by this check",
                after.as_secs_f64() * 1e3
            ),
        )
    } else {
        line(
            "watchdog trip",
            false,
            format!(
                "the watchdog {} and safe mode is {}: the card would NOT cut the motor if the \
                 host stopped; check the 826 driver version and that nothing else configures \
                 the watchdog",
                if fired { "fired" } else { "did not fire" },
                if safe { "on" } else { "off" }
            ),
        )
    };
    board.set_watchdog_us(BRINGUP_WATCHDOG_US);
    Ok(l)
}
