//! Replay board, position-control replay, reproduction against the simulated hand (and its
//! shadow), the realtime clock.

mod common;

use rt_loop::config::{BoardKind, ClockKind, ExperimentKind};
use rt_loop::record::read::read_columns;

/// Replaying a recording's counts and timestamps through the loop with the same parameters
/// reproduces its estimates exactly; other observer settings change them.
#[test]
fn replay_board_reprocesses_a_recording() {
    let dir = common::tmpdir("replay");
    let path = dir.join("orig.parquet");
    let mut cfg = common::short_cfg(2, 6.0, 3.0);
    cfg.record = Some(path.clone());
    assert!(rt_loop::run::run(&cfg, None, None).unwrap().ok());

    let mut rp = cfg.clone();
    rp.board = BoardKind::Replay;
    rp.replay = Some(path.clone());
    rp.record = Some(dir.join("same.parquet"));
    let s = rt_loop::run::run(&rp, None, None).unwrap();
    assert!(s.ok(), "{s:?}");
    let cols = [
        "rtob_force",
        "velocity",
        "f_previous_x",
        "area_fx",
        "F_true",
        "F_object",
    ];
    let a = read_columns(&path, &cols).unwrap();
    let b = read_columns(&dir.join("same.parquet"), &cols).unwrap();
    for k in 0..cols.len() {
        assert_eq!(a[k].len(), b[k].len());
        for i in 0..a[k].len() {
            assert_eq!(a[k][i].to_bits(), b[k][i].to_bits(), "{} row {i}", cols[k]);
        }
    }

    rp.params.g_rec = 20.0;
    rp.record = Some(dir.join("slow.parquet"));
    assert!(rt_loop::run::run(&rp, None, None).unwrap().ok());
    let c = read_columns(&dir.join("slow.parquet"), &["rtob_force"]).unwrap();
    assert!(a[0].iter().zip(&c[0]).any(|(x, y)| (x - y).abs() > 0.05));
}

/// Position replay: the PID follows a recorded trajectory on the sponge, and the force it
/// needs is close to the force of the original force-controlled run.
#[test]
fn position_replay_follows_the_trajectory_and_reproduces_the_force() {
    let dir = common::tmpdir("posreplay");
    let path = dir.join("orig.parquet");
    let mut cfg = common::short_cfg(2, 2.0, 4.0); // 2 N and 6 N
    cfg.record = Some(path.clone());
    assert!(rt_loop::run::run(&cfg, None, None).unwrap().ok());

    let mut pr = cfg.clone();
    pr.experiment = ExperimentKind::PositionReplay;
    pr.trajectory = Some(path.clone());
    pr.seed = 7;
    pr.record = Some(dir.join("replayed.parquet"));
    let s = rt_loop::run::run(&pr, None, None).unwrap();
    assert!(s.ok(), "{s:?}");
    let o = read_columns(&path, &["time", "position_x", "F_true"]).unwrap();
    let r = read_columns(
        &dir.join("replayed.parquet"),
        &["time", "position_x", "F_true", "phase"],
    )
    .unwrap();
    assert!(r[3].iter().all(|&p| p == 4.0), "phase 4: position");
    let n = r[0].len().min(o[0].len());
    let mut se_x = 0.0;
    let mut se_f = 0.0;
    let mut max_f: f64 = 0.0;
    for i in 0..n {
        se_x += (r[1][i] - o[1][i]).powi(2);
        se_f += (r[2][i] - o[2][i]).powi(2);
        max_f = max_f.max(o[2][i]);
    }
    let rms_x = (se_x / n as f64).sqrt();
    let rms_f = (se_f / n as f64).sqrt();
    eprintln!(
        "position replay: rms x error {:.3} mm, rms force difference {rms_f:.3} N",
        rms_x * 1e3
    );
    assert!(rms_x < 0.5e-3, "rms x {rms_x}");
    assert!(rms_f < 0.15 * max_f, "rms force {rms_f} vs peak {max_f}");
}

/// Reproduction renders F_pred against the hand: the hand feels about the predicted force.
/// Shadow: the same hand on the simulated sponge through a transparent motor, the model
/// predicting alongside: the felt forces of both are comparable.
#[test]
fn reproduction_renders_the_model_and_shadow_compares() {
    let mut cfg = common::short_cfg(1, 1.0, 0.0);
    cfg.hand.repeats = 2;
    cfg.experiment = ExperimentKind::Reproduction;
    let (rows, stop) = common::run_rows(&cfg);
    assert_eq!(stop, rt_loop::control::rig::Stop::Finished);
    assert!(rows.iter().all(|r| r.phase == 5 && !r.fallback));
    let pressed: Vec<_> = rows.iter().filter(|r| r.f_pred > 2.0).collect();
    assert!(pressed.len() > 5000, "the hand pressed the virtual sponge");
    let rms = (pressed
        .iter()
        .map(|r| (r.f_true - r.f_pred).powi(2))
        .sum::<f64>()
        / pressed.len() as f64)
        .sqrt();
    let peak = pressed.iter().map(|r| r.f_pred).fold(0.0, f64::max);
    eprintln!("reproduction: felt vs rendered rms {rms:.3} N, peak {peak:.2} N");
    assert!(peak > 5.0);
    assert!(rms < 1.5, "felt force follows the rendered one: rms {rms}");
    // the motor really pushes back (F_cmd = -F_pred)
    assert!(pressed.iter().all(|r| r.f_ref == -r.f_pred));

    let mut sh = cfg.clone();
    sh.experiment = ExperimentKind::Shadow;
    let (srows, _) = common::run_rows(&sh);
    assert!(srows.iter().all(|r| r.f_ref == 0.0 && r.f_pred.is_finite()));
    let felt_shadow = srows.iter().map(|r| r.f_true).fold(0.0, f64::max);
    let felt_repro = rows.iter().map(|r| r.f_true).fold(0.0, f64::max);
    eprintln!(
        "peak felt force: shadow (sponge) {felt_shadow:.2} N, reproduction {felt_repro:.2} N"
    );
    assert!(felt_shadow > 3.0 && felt_repro > 3.0);
    assert!((felt_shadow - felt_repro).abs() < 0.5 * felt_shadow.max(felt_repro));
}

/// A model that misbehaves (NaN, no answer) is replaced by the fallback and counted; an answer
/// beyond the force limit is rendered at the limit (saturated, issue 23), not replaced; the
/// loop keeps rendering.
#[test]
fn bad_predictions_fall_back() {
    struct Flaky(std::sync::Arc<std::sync::atomic::AtomicU32>);
    impl rt_loop::serving::model::ForceModel for Flaky {
        fn name(&self) -> &str {
            "flaky"
        }
        fn begin_run(&mut self) {
            self.0.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        }
        fn predict(&mut self, step: u64, f: &rt_loop::features::Features) -> Option<f64> {
            match step % 4 {
                0 => Some(f64::NAN),
                1 => Some(1e6),
                2 => None,
                _ => Some(100.0 * f.position_x),
            }
        }
    }
    let mut cfg = common::short_cfg(1, 1.0, 0.0);
    cfg.experiment = ExperimentKind::Reproduction;
    cfg.hand.repeats = 1;
    let begun = std::sync::Arc::new(std::sync::atomic::AtomicU32::new(0));
    let mut rig = rt_loop::run::build_rig(&cfg, Some(Box::new(Flaky(begun.clone())))).unwrap();
    assert_eq!(
        begun.load(std::sync::atomic::Ordering::SeqCst),
        1,
        "begin_run before the run"
    );
    let mut n = 0u64;
    let mut fb = 0u64;
    while let Ok(r) = rig.step() {
        n += 1;
        fb += r.fallback as u64;
        assert!(r.f_pred.is_finite() && r.f_pred.abs() <= 20.0);
    }
    let st = rig.experiment.model_stats().unwrap();
    assert_eq!(st.fallbacks, fb);
    assert_eq!(st.served + st.fallbacks, n);
    // NaN and no answer (half the steps) fall back; 1e6 N saturates at the limit instead.
    assert!(
        (fb as f64 / n as f64 - 0.5).abs() < 0.01,
        "{fb} of {n} fell back"
    );
}

/// The realtime clock at 10 kHz for 0.3 s: about 3000 steps, jitter statistics measured,
/// every recorded row accounted for. (Timing itself is measured by the benchmark, not here.)
#[test]
fn realtime_clock_runs_at_its_rate() {
    let dir = common::tmpdir("rt");
    let mut cfg = common::short_cfg(1, 2.0, 0.0);
    cfg.clock = ClockKind::Realtime;
    cfg.max_duration_s = Some(0.3);
    cfg.realtime.priority = 0; // tests leave the scheduler alone
    cfg.realtime.lock_memory = false;
    // a loaded test machine may stall the process for many ms; the watchdog is tested elsewhere
    cfg.params.watchdog_us = 5_000_000;
    cfg.record = Some(dir.join("rt.parquet"));
    let s = rt_loop::run::run(&cfg, None, None).unwrap();
    assert_eq!(s.stop, rt_loop::stop::StopReason::TimeLimit);
    assert!(s.wall_s > 0.28 && s.wall_s < 2.0, "wall {}", s.wall_s);
    assert!(s.steps > 1000 && s.steps <= 3100, "steps {}", s.steps);
    let j = s.jitter.unwrap();
    assert_eq!(j.period_us, 100.0);
    assert!(j.period_jitter.samples + j.overruns >= s.steps - 1);
    let rep = s.recorder.unwrap();
    assert_eq!(rep.rows_received + s.drops, s.steps);
    // the simulated board followed the wall clock: loop time ~ wall time
    assert!(
        (s.loop_time_s - 0.3).abs() < 0.05,
        "loop time {}",
        s.loop_time_s
    );
}
