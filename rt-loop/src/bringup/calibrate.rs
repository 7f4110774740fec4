//! `rt-loop board calibrate`: measures what the rig file holds and writes it. The direction
//! and the moving mass come from two current pulses (the mass from the difference of their
//! accelerations, so friction cancels; it assumes the force constant and the amplifier's A/V,
//! from their datasheets or the flags); the friction from `rt-loop identify-friction`'s sweeps
//! on the same board; counts per metre from the encoder's datasheet or a gauge (`board
//! check` says how).

use super::check::{open_board, pulses};
use crate::board::rig_file::RigFile;
use crate::board::Board;
use crate::config::{ClockKind, RunConfig};
use anyhow::{anyhow, Result};

/// What calibration takes as given (datasheet values), each defaulting to the configuration.
#[derive(Clone, Debug, Default)]
pub struct Given {
    pub counts_per_metre: Option<f64>,
    pub force_constant: Option<f64>,
    pub amps_per_volt: Option<f64>,
    /// Skip the friction sweeps (keep the configured friction).
    pub skip_friction: bool,
}

/// Measures the rig; the rig file's contents and a few lines on how each value was found.
pub fn calibrate(cfg: &RunConfig, given: &Given) -> Result<(RigFile, Vec<String>)> {
    let mut cfg = cfg.clone();
    if let Some(c) = given.counts_per_metre {
        cfg.params.meters_per_count = 1.0 / c;
    }
    if let Some(k) = given.force_constant {
        cfg.params.k_fn = k;
    }
    if let Some(a) = given.amps_per_volt {
        cfg.s826.amps_per_volt = a;
    }
    // measure the raw direction: counts as the card gives them
    cfg.s826.direction = 1;
    let mut notes = Vec::new();
    let mut board = open_board(&cfg)?;
    board.configure()?;
    board.activate(0)?;
    let pair = pulses(&mut board, &cfg)?;
    board.deactivate();
    board.shutdown();
    drop(board);
    let c = pair.first.counts;
    if c.abs() <= 10 {
        anyhow::bail!(
            "the test pulse moved the encoder {c} counts: no motion (run `rt-loop board check` \
             first)"
        );
    }
    let direction = if c > 0 { 1 } else { -1 };
    notes.push(format!(
        "direction {direction}: +{:.3} A moved {c} counts",
        pair.first.amps
    ));
    // with the direction fixed, the accelerations' signs follow the current
    let sign = direction as f64;
    let signed = |a: f64| a * sign;
    let (a1, a2) = (
        signed(pair.first.accel_mps2),
        signed(pair.second.accel_mps2),
    );
    let mass = cfg.params.k_fn * (pair.second.amps - pair.first.amps) / (a2 - a1);
    if !(mass.is_finite() && mass > 0.0) {
        return Err(anyhow!(
            "the pulses gave no usable acceleration difference ({a1:.3} and {a2:.3} m/s^2): is \
             the probe free?"
        ));
    }
    notes.push(format!(
        "moving mass {mass:.4} kg: {a1:.3} and {a2:.3} m/s^2 at {:.3} and {:.3} A with K_f {} N/A",
        pair.first.amps, pair.second.amps, cfg.params.k_fn
    ));
    cfg.s826.direction = direction;
    cfg.params.m_n = mass;
    let friction = if given.skip_friction {
        notes.push("friction: kept from the configuration (--skip-friction)".into());
        cfg.params.friction
    } else {
        let mut fc = cfg.clone();
        fc.clock = ClockKind::Realtime;
        // the sweeps run paced at the loop's rate (friction_id::identify), on the card's own
        // timestamps; a generous watchdog, as for the pulses
        fc.s826.watchdog_us = Some(super::BRINGUP_WATCHDOG_US);
        let id = crate::control::friction_id::identify(
            &fc,
            &crate::control::friction_id::SweepPlan::default(),
        )?;
        notes.push(format!(
            "friction: {} sweep segments, fit RMS residual {:.4} N",
            id.fit.points.len(),
            id.fit.rms_residual_n
        ));
        id.fit.friction
    };
    let rig = RigFile {
        counts_per_metre: 1.0 / cfg.params.meters_per_count,
        direction,
        amps_per_volt: cfg.s826.amps_per_volt,
        force_constant: cfg.params.k_fn,
        moving_mass_kg: mass,
        friction,
    };
    rig.validate()?;
    Ok((rig, notes))
}
