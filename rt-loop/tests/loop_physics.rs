//! Tests that fail if the physics or the control were wrong: RFOB vs the simulation's true
//! contact force, loop area and permanent set, the clamp, the position-limit abort, seeds.

mod common;

use common::{run_rows, short_cfg};
use rt_loop::board::{Board, BoardStop, Snapshot};
use rt_loop::config::ExperimentKind;
use rt_loop::control::rig::Stop;

/// On a slow ramp (1 N/s to 6 N and 10 N), with the RFOB's friction model set to the bench's
/// Coulomb friction, the estimate follows the true contact force. Measured: 0.45 N RMS over
/// the ramps in contact, 0.24 N RMS while the probe slides, 1.75 N worst case (static friction
/// during stick-slip, which a Coulomb model cannot cancel, plus the 3 % force-constant error
/// the observer does not know). Asserted: RMS < 0.5 N, sliding RMS < 0.3 N, worst < 2 N.
/// Without the friction model (the thesis code's choice) the estimate is off by about the
/// 0.85 N Coulomb friction itself while sliding in.
#[test]
fn rfob_follows_true_contact_force_on_a_slow_ramp() {
    let mut cfg = short_cfg(2, 1.0, 4.0);
    cfg.ramp.f_max_start = 6.0; // 6 N then 10 N
    cfg.params.friction_model = cfg.sim.coulomb_n;
    let (rows, stop) = run_rows(&cfg);
    assert_eq!(stop, Stop::Finished);
    let on_ramp: Vec<_> = rows
        .iter()
        .filter(|r| (r.phase == 1 || r.phase == 3) && r.f_true > 1.0 && r.time > 1.0)
        .collect();
    assert!(on_ramp.len() > 50_000);
    let sq: f64 = on_ramp
        .iter()
        .map(|r| (r.rtob_force - r.f_true).powi(2))
        .sum::<f64>()
        / on_ramp.len() as f64;
    let rms = sq.sqrt();
    let worst = on_ramp
        .iter()
        .map(|r| (r.rtob_force - r.f_true).abs())
        .fold(0.0, f64::max);
    let sliding: Vec<_> = on_ramp.iter().filter(|r| r.velocity.abs() > 2e-4).collect();
    let rms_sliding = (sliding
        .iter()
        .map(|r| (r.rtob_force - r.f_true).powi(2))
        .sum::<f64>()
        / sliding.len() as f64)
        .sqrt();
    let worst_sliding = sliding
        .iter()
        .map(|r| (r.rtob_force - r.f_true).abs())
        .fold(0.0, f64::max);
    eprintln!("RFOB vs F_true on slow ramps: rms {rms:.3} N, worst {worst:.3} N; sliding ({} of {} steps): rms {rms_sliding:.3} N worst {worst_sliding:.3} N", sliding.len(), on_ramp.len());
    assert!(rms < 0.5, "rms {rms}");
    assert!(rms_sliding < 0.3, "sliding rms {rms_sliding}");
    assert!(worst < 2.0, "worst {worst}");

    // The thesis's setting (no friction model): the estimate is off by about the friction.
    let mut thesis = cfg.clone();
    thesis.params.friction_model = 0.0;
    let (rows, _) = run_rows(&thesis);
    let up: Vec<_> = rows
        .iter()
        .filter(|r| r.phase == 1 && r.f_true > 1.0 && r.velocity > 1e-4)
        .collect();
    let mean_err = up.iter().map(|r| r.rtob_force - r.f_true).sum::<f64>() / up.len().max(1) as f64;
    assert!(
        (mean_err - thesis.sim.coulomb_n).abs() < 0.3,
        "while sliding in, RFOB - F_true = {mean_err} N, expected about the Coulomb friction"
    );
}

/// The force controller tracks the ramp (F_res follows F_ref).
#[test]
fn force_control_tracks_the_command() {
    let cfg = short_cfg(2, 3.0, 4.0);
    let (rows, _) = run_rows(&cfg);
    let rms = common::ramp_tracking_rms(&rows);
    assert!(rms < 0.15, "tracking rms {rms}");
    let peak = rows.iter().map(|r| r.f_true).fold(0.0, f64::max);
    assert!(peak > 4.5, "the sponge really got pressed: {peak}");
}

/// The F-x loop area of each finished cycle is positive and grows with F_max, and the
/// permanent deformation grows cycle by cycle and stays after the last cycle.
#[test]
fn loop_area_grows_with_f_max_and_permanent_set_remains() {
    let cfg = short_cfg(5, 4.0, 3.0); // F_max 2, 5, 8, 11, 14 N
    let (rows, stop) = run_rows(&cfg);
    assert_eq!(stop, Stop::Finished);
    let mut areas = vec![];
    let mut defs = vec![];
    for w in rows.windows(2) {
        if w[1].cycle_no != w[0].cycle_no {
            areas.push(w[1].area_fx);
            defs.push(w[1].deformation);
        }
    }
    eprintln!("areas {areas:?}\ndeformations {defs:?}");
    assert_eq!(areas.len(), 5, "five cycles segmented");
    for a in &areas {
        assert!(*a > 0.0, "area {a} must be positive");
    }
    for k in 1..areas.len() {
        assert!(areas[k] > areas[k - 1], "area grows with F_max: {areas:?}");
    }
    assert!(
        defs[4] > defs[1] && defs[1] > 0.0,
        "deformation grows: {defs:?}"
    );
    // after the last cycle the probe rests (0 N) at a depth well below the start: the set
    let last = rows.last().unwrap();
    assert!(last.position_x > 1e-3, "rest position {}", last.position_x);
    // 14 N is reached within 30 mm
    let x14 = rows
        .iter()
        .filter(|r| r.rtob_force > 13.5)
        .map(|r| r.position_x)
        .fold(0.0, f64::max);
    assert!(x14 > 0.015 && x14 <= 0.031, "depth at 13+ N: {x14}");
}

/// Faster ramps meet a stiffer sponge (viscoelastic rate dependence): less depth at the same
/// peak force.
#[test]
fn ramp_rate_changes_the_force_depth_curve() {
    let depth_at_peak = |rate: f64| {
        let mut cfg = short_cfg(1, rate, 0.0);
        cfg.ramp.f_max_start = 10.0;
        cfg.ramp.hold_max_s = 0.0;
        let (rows, _) = run_rows(&cfg);
        rows.iter()
            .filter(|r| r.phase == 1)
            .map(|r| r.position_x)
            .fold(0.0, f64::max)
    };
    let slow = depth_at_peak(0.8);
    let fast = depth_at_peak(6.2);
    assert!(slow > fast + 0.0005, "slow {slow} vs fast {fast}");
}

/// However hard the controller asks, the current stays within the clamp and the DAC word
/// matches it; the clamp is really reached in this run.
#[test]
fn current_never_beyond_the_clamp() {
    let mut cfg = short_cfg(1, 50.0, 0.0);
    cfg.ramp.f_max_start = 14.0;
    cfg.params.k_p = 40.0;
    let (rows, _) = run_rows(&cfg);
    let lim = cfg.params.current_limit;
    let mut hit = false;
    for r in &rows {
        assert!(
            r.i_motor.abs() <= lim + 1e-12,
            "I {} at step {}",
            r.i_motor,
            r.step
        );
        let word_current = (r.analog_out_motor as f64 - 32768.0) / 32768.0 * 0.6;
        assert_eq!(word_current, r.i_motor);
        hit |= r.i_a_ref.abs() > lim;
    }
    assert!(hit, "the test must drive the controller into the clamp");
}

/// A hand that pushes to 60 mm against a model that renders nothing drives the probe to the
/// position limit: the loop aborts at |x| >= 0.05 m, and the last word written to the DAC is the
/// one for 0 A (the board in the middle records every word the loop writes).
#[test]
fn position_limit_aborts_with_zero_current() {
    struct Nothing;
    impl rt_loop::serving::model::ForceModel for Nothing {
        fn name(&self) -> &str {
            "nothing"
        }
        fn predict(&mut self, _: u64, _: &rt_loop::features::Features) -> Option<f64> {
            Some(0.0)
        }
    }
    /// The simulated board, with the DAC words the loop wrote.
    struct Words<B> {
        board: B,
        written: Vec<u16>,
    }
    impl<B: Board> Board for Words<B> {
        rt_loop::forward_board_lifecycle!(board);
        fn read(&mut self) -> Result<Snapshot, BoardStop> {
            self.board.read()
        }
        fn write(&mut self, word: u16) -> Result<(), BoardStop> {
            self.written.push(word);
            self.board.write(word)
        }
        fn kick(&mut self) -> Result<(), BoardStop> {
            self.board.kick()
        }
        fn name(&self) -> &'static str {
            "words"
        }
    }
    let mut cfg = short_cfg(1, 1.0, 0.0);
    cfg.experiment = ExperimentKind::Reproduction;
    cfg.hand.depth_m = 0.06;
    let template = rt_loop::run::build_rig(&cfg, Some(Box::new(Nothing))).unwrap();
    let board = Words {
        board: template.board,
        written: Vec::with_capacity(1 << 20),
    };
    let experiment = rt_loop::run::build_experiment(&cfg, Some(Box::new(Nothing))).unwrap();
    let mut rig = rt_loop::control::rig::Rig::new(
        board,
        cfg.params.clone(),
        experiment,
        cfg.features.clone(),
    )
    .unwrap();
    rig.set_period(1.0 / cfg.rate_hz);
    let mut last = None;
    let stop = loop {
        match rig.step() {
            Ok(r) => last = Some(r),
            Err(s) => break s,
        }
    };
    assert_eq!(stop, Stop::PositionLimit);
    let last = last.unwrap();
    assert!(last.position_x < 0.05 && last.position_x > 0.045);
    let zero_amps = rt_loop::control::dac::current_to_word(0.0, cfg.params.dac_full_scale);
    assert_eq!(zero_amps, 32768);
    let words = &rig.board.written;
    assert!(
        words.len() > 2,
        "the loop wrote {} DAC words before the abort",
        words.len()
    );
    // Before the abort the loop commanded a current (so the last word below is the abort's).
    assert_ne!(
        words[words.len() - 2],
        zero_amps,
        "the step before the abort commanded 0 A already: the test would prove nothing"
    );
    assert_eq!(
        *words.last().unwrap(),
        zero_amps,
        "the last DAC word (the abort's) must be the one for 0 A"
    );
    assert!(rig.board.true_force() > 0.0, "the hand was still pushing");
}

/// Same seed: identical data. Another seed: different data.
#[test]
fn identical_seeds_give_identical_runs() {
    let cfg = short_cfg(2, 6.0, 2.0);
    let (a, _) = run_rows(&cfg);
    let (b, _) = run_rows(&cfg);
    assert_eq!(a.len(), b.len());
    assert!(
        common::rows_identical(&a, &b),
        "rows differ for the same seed"
    );
    let mut other = cfg.clone();
    other.seed = 2;
    let (c, _) = run_rows(&other);
    assert!(
        !common::rows_identical(&a, &c),
        "another seed must give another run"
    );
}

/// Timestamps wrap during a run (the sim starts 3 s before 2^32) and dt stays right.
#[test]
fn timestamps_wrap_and_dt_stays_correct() {
    let cfg = short_cfg(1, 2.0, 0.0);
    let (rows, _) = run_rows(&cfg);
    let wraps = rows
        .windows(2)
        .filter(|w| w[1].timestamp < w[0].timestamp)
        .count();
    assert_eq!(wraps, 1);
    for r in &rows[1..] {
        assert!(r.dt > 80e-6 && r.dt < 120e-6, "dt {}", r.dt);
    }
    let jitter = rows[1..].iter().any(|r| r.dt != 100e-6);
    assert!(jitter, "the period jitters");
}

/// A loop slower than the board's watchdog (here: a 50 us watchdog at a 100 us period) is
/// stopped: the board cuts the current and the loop reports it.
#[test]
fn watchdog_trip_stops_the_loop() {
    let mut cfg = short_cfg(1, 2.0, 0.0);
    cfg.params.watchdog_us = 50;
    let (rows, stop) = run_rows(&cfg);
    assert_eq!(stop, Stop::Watchdog);
    assert!(rows.len() <= 1);
}
