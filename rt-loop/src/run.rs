//! Puts a run together from its configuration: board, experiment, loop, clock, recorder,
//! and reports what happened. The run's per-step output besides the recording goes to a
//! [`StepSink`] (the shared-memory side channel, or nothing); the model it is given comes
//! back with its result ([`RunOutcome`]), so a long-running loop keeps one served model across
//! runs without lending it.

use crate::board::replay::ReplayBoard;
use crate::board::sim::{SimBoard, SimTime, SimWorld};
use crate::board::Board;
use crate::clock::{JitterStats, RealtimeClock};
use crate::config::{BoardKind, ClockKind, ExperimentKind, RunConfig};
use crate::control::rig::{Rig, Stop};
use crate::experiment::{Experiment, ModelStats, PositionPid, RampSchedule, Trajectory};
use crate::object::material::{LawParams, Material};
use crate::percentiles::Percentiles;
use crate::record::row::Row;
use crate::record::{RecorderHandle, RecorderReport, Target};
use crate::serving::model::{ForceModel, SpringDamperModel};
use crate::serving::sink::{RunFigures, StepAction, StepSink};
use crate::stop::{Shutdown, StopReason};
use anyhow::{anyhow, Result};
use serde::Serialize;
use shm_ring::os::keep_awake::{process_cpu_quota, KeepAwake, StepCounter};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    pub experiment: String,
    pub clock: String,
    pub steps: u64,
    /// How the run ended (written as its text: finished, position-limit, board-fault: ...,
    /// watchdog, recorder-failed, time-limit, interrupted, stopped).
    pub stop: StopReason,
    pub loop_time_s: f64,
    pub wall_s: f64,
    pub steps_per_s: f64,
    pub rows_pushed: u64,
    pub drops: u64,
    pub recorder: Option<RecorderReport>,
    pub jitter: Option<JitterStats>,
    pub model: Option<ModelStats>,
    /// The shared-memory client's counters (runs with a served model), filled in by the caller
    /// from the model the run gives back.
    pub shm: Option<crate::serving::shm_model::ShmCountersSnapshot>,
    /// Loop-observed round trip to the server (runs with a served model), filled in by the caller.
    pub round_trip_us: Option<Percentiles>,
    /// Telemetry rows published into the segment (0 without one).
    pub telemetry_rows: u64,
    /// Reproduction/shadow: steps per rung of the degradation ladder (on_time, late_one,
    /// held, fallback); every step is counted in exactly one. `None` for other experiments.
    pub ladder: Option<crate::serving::ladder::LadderCounts>,
    /// Why each step not rendered by its on-time answer was not (one reason per such step:
    /// their sum is late_one + held + fallback).
    pub degraded_reasons: Option<crate::serving::ladder::Reasons>,
    /// Largest change of the rendered force in one step caused by a change of ladder level, N.
    pub max_transition_step_n: f64,
    /// Steps during which a ladder transition (slew catch-up or cross-fade) was under way.
    pub transition_steps: u64,
    /// Ring slots or indices found corrupt by the loop's shared-memory endpoints.
    pub corrupt: u64,
    /// Steps whose measured dt exceeded [`crate::control::rig::LONG_STEP_FACTOR`] periods (stalls);
    /// the filters took a bounded update on them.
    pub long_steps: u64,
    /// The longest step, ms.
    pub max_step_ms: f64,
    /// The board's counters of what went wrong without stopping the loop (FIFO overflows,
    /// quadrature errors, empty-FIFO retries, timestamp wraps).
    pub board: crate::board::BoardHealth,
    /// Reproduction/shadow: the passivity layer's figures (crate::passivity).
    pub passivity: Option<crate::passivity::PassivityReport>,
    /// Abstraction: the ramps that turned round at the depth bound
    /// (crate::experiment::RampSchedule). `None` for other experiments.
    pub ramp_turns: Option<crate::experiment::RampTurns>,
    pub warnings: Vec<String>,
}

impl RunSummary {
    /// True when the run ended as planned and every row reached the file.
    pub fn ok(&self) -> bool {
        let rec_ok = self.recorder.as_ref().is_none_or(|r| {
            r.error.is_none() && r.rows_written == r.rows_received && self.drops == 0
        });
        self.stop.planned() && rec_ok
    }
}

/// The run's metadata JSON (`haptics.run`).
pub fn metadata_json(cfg: &RunConfig, material_text: &str, model_name: &str) -> String {
    serde_json::json!({
        "experiment": cfg.experiment,
        "board": cfg.board,
        "material_file": cfg.material,
        "material": material_text,
        "seed": cfg.seed,
        "clock": cfg.clock,
        "rate_hz": cfg.rate_hz,
        "ramp_rate": cfg.ramp.ramp_rate,
        "f_max_schedule": (0..cfg.ramp.n_cycles()).map(|c| cfg.ramp.f_max(c)).collect::<Vec<_>>(),
        "decimate": cfg.decimate,
        "model": model_name,
        "config": cfg,
        "rt_loop_version": env!("CARGO_PKG_VERSION"),
        "columns": crate::record::COLUMNS,
        "feature_names": crate::features::FEATURE_NAMES,
    })
    .to_string()
}

/// Builds the experiment (loads trajectories; allocation happens here, before the loop).
pub fn build_experiment(cfg: &RunConfig, model: Option<Box<dyn ForceModel>>) -> Result<Experiment> {
    Ok(match cfg.experiment {
        ExperimentKind::Abstraction => {
            Experiment::Abstraction(RampSchedule::new(&cfg.ramp, cfg.params.position_limit))
        }
        ExperimentKind::PositionReplay if cfg.friction_sweep => {
            let plan = crate::control::friction_id::SweepPlan::default();
            plan.validate(cfg.params.position_limit)
                .map_err(|e| anyhow!("--friction-sweep: {e}"))?;
            Experiment::PositionReplay {
                trajectory: plan.trajectory()?,
                pid: PositionPid::new(&cfg.params),
            }
        }
        ExperimentKind::PositionReplay => {
            let path = cfg
                .trajectory
                .as_ref()
                .ok_or_else(|| anyhow!("position replay needs --trajectory"))?;
            let trajectory = Trajectory::from_recording(path)?;
            if trajectory.max_abs() >= cfg.params.position_limit {
                anyhow::bail!(
                    "trajectory {} reaches {:.4} m, beyond the position limit {} m",
                    path.display(),
                    trajectory.max_abs(),
                    cfg.params.position_limit
                );
            }
            Experiment::PositionReplay {
                trajectory,
                pid: PositionPid::new(&cfg.params),
            }
        }
        ExperimentKind::Reproduction | ExperimentKind::Shadow => Experiment::Reproduction {
            model: model.unwrap_or_else(|| Box::new(SpringDamperModel(cfg.reproduction.fallback))),
            cfg: cfg.reproduction.clone(),
            duration: cfg.hand.duration(),
            shadow: cfg.experiment == ExperimentKind::Shadow,
            stats: ModelStats::default(),
            ladder: crate::serving::ladder::Ladder::new(
                &cfg.ladder,
                cfg.reproduction.max_force_n,
                cfg.reproduction.fallback,
                1.0 / cfg.rate_hz,
            ),
        },
    })
}

/// Builds the board for the configuration.
pub fn build_board(cfg: &RunConfig, material: Option<&Material>) -> Result<Box<dyn Board>> {
    Ok(match cfg.board {
        BoardKind::Replay => {
            let p = cfg
                .replay
                .as_ref()
                .ok_or_else(|| anyhow!("--replay PATH missing"))?;
            Box::new(ReplayBoard::from_recording(p)?)
        }
        BoardKind::Sim => {
            let world = match cfg.experiment {
                ExperimentKind::Abstraction | ExperimentKind::PositionReplay => SimWorld {
                    sponge: material.cloned(),
                    hand: None,
                },
                ExperimentKind::Reproduction => SimWorld {
                    sponge: None,
                    hand: Some(cfg.hand.clone()),
                },
                ExperimentKind::Shadow => SimWorld {
                    sponge: material.cloned(),
                    hand: Some(cfg.hand.clone()),
                },
            };
            let time = match cfg.clock {
                ClockKind::Lockstep => SimTime::Virtual {
                    period_s: 1.0 / cfg.rate_hz,
                },
                ClockKind::Realtime => SimTime::Wall,
            };
            Box::new(SimBoard::new(cfg.sim.clone(), world, time, cfg.seed))
        }
        BoardKind::S826 { board } => Box::new(crate::board::s826::S826Board::new(
            board,
            cfg.s826.clone(),
            cfg.params.current_limit,
            cfg.params.dac_full_scale,
            cfg.rate_hz,
        )?),
    })
}

/// Builds the loop for a configuration (board, experiment, observers); everything the step
/// needs is allocated here.
pub fn build_rig(
    cfg: &RunConfig,
    model: Option<Box<dyn ForceModel>>,
) -> Result<Rig<Box<dyn Board>>> {
    cfg.validate().map_err(|e| anyhow!(e))?;
    let (material, _) = Material::load(&cfg.material)?;
    let experiment = build_experiment(cfg, model)?;
    let board = build_board(cfg, Some(&material))?;
    let mut rig = Rig::new(board, cfg.params.clone(), experiment, cfg.features.clone())
        .map_err(|f| anyhow!("board {}: {}", cfg.board, f.error))?;
    rig.set_period(1.0 / cfg.rate_hz);
    rig.passivity = crate::passivity::PassivityController::for_run(cfg);
    Ok(rig)
}

/// Progress reporting for long lockstep runs (called off the step, every few thousand steps).
pub trait Progress {
    fn update(&mut self, loop_time_s: f64);
    fn finish(&mut self) {}
}

/// A finished run: its result, and the model it was given (`None` if it was given none), so
/// the caller can read the model's own figures or hand it to the next run.
pub struct RunOutcome {
    pub result: Result<RunSummary>,
    pub model: Option<Box<dyn ForceModel>>,
}

/// Runs a configured experiment to its end (no side channel, nothing to stop it early; the
/// model is dropped after).
pub fn run(
    cfg: &RunConfig,
    model: Option<Box<dyn ForceModel>>,
    progress: Option<&mut dyn Progress>,
) -> Result<RunSummary> {
    let never = Shutdown::new()?;
    run_with(cfg, model, &never, progress, None).result
}

/// [`run`] with a shutdown signal (a request ends the run at its next step, stop
/// "interrupted") and a [`StepSink`] for its per-step output (the shared-memory side channel:
/// every step's row goes out as telemetry, the heartbeat is bumped, and a stop command from
/// the mailbox ends the run with stop "stopped"). The model comes back in the outcome whatever
/// the result.
pub fn run_with(
    cfg: &RunConfig,
    mut model: Option<Box<dyn ForceModel>>,
    shutdown: &Shutdown,
    progress: Option<&mut dyn Progress>,
    sink: Option<&mut dyn StepSink>,
) -> RunOutcome {
    let result = set_up_and_run(cfg, &mut model, shutdown, progress, sink);
    RunOutcome { result, model }
}

/// Builds the run and drives it; the model goes back into `model` on every path.
fn set_up_and_run(
    cfg: &RunConfig,
    model: &mut Option<Box<dyn ForceModel>>,
    shutdown: &Shutdown,
    progress: Option<&mut dyn Progress>,
    sink: Option<&mut dyn StepSink>,
) -> Result<RunSummary> {
    cfg.validate().map_err(|e| anyhow!(e))?;
    let (material, material_text) = Material::load(&cfg.material)?;
    // Only reproduction and shadow use a model: the others leave it with the caller.
    let uses_model = matches!(
        cfg.experiment,
        ExperimentKind::Reproduction | ExperimentKind::Shadow
    );
    let given = if uses_model { model.take() } else { None };
    // Without a model of its own, reproduction renders its fallback: that one stays here.
    let given_some = given.is_some();
    let give_back = |e: Experiment, model: &mut Option<Box<dyn ForceModel>>| {
        if given_some {
            *model = e.into_model();
        }
    };
    let experiment = build_experiment(cfg, given)?;
    let board = build_board(cfg, Some(&material)).and_then(|b| {
        refuse_existing_recording(cfg)?;
        Ok(b)
    });
    let board = match board {
        Ok(b) => b,
        Err(e) => {
            give_back(experiment, model);
            return Err(e);
        }
    };
    // Rig::new configures the board (0 A), then lets the model wait for its server; the
    // board is activated (watchdog armed) right before the first step.
    let mut rig = match Rig::new(board, cfg.params.clone(), experiment, cfg.features.clone()) {
        Ok(r) => r,
        Err(failed) => {
            give_back(*failed.experiment, model);
            return Err(anyhow!("board {}: {}", cfg.board, failed.error));
        }
    };
    rig.set_period(1.0 / cfg.rate_hz);
    rig.passivity = crate::passivity::PassivityController::for_run(cfg);
    // The ONNX object's own rate, once: `drive` keeps the loop's CPU awake for such an
    // object, and the summary's hint below names that rate.
    let onnx_rate_hz = match &material.law {
        LawParams::Onnx(p) => Some(p.file.onnx.rate_hz),
        _ => None,
    };
    let mut result = drive(
        cfg,
        &mut rig,
        &material_text,
        onnx_rate_hz.is_some(),
        shutdown,
        progress,
        sink,
    );
    // 0 A, watchdog off, board closed, whatever happened.
    rig.finish();
    give_back(rig.experiment, model);
    if let (Ok(s), Some(rate_hz)) = (&mut result, onnx_rate_hz) {
        let overruns = s.jitter.as_ref().map(|j| j.overruns);
        if let Some(w) = overruns.and_then(|o| onnx_overrun_hint(s.steps, o, rate_hz)) {
            eprintln!("rt-loop: warning: {w}");
            s.warnings.push(w);
        }
    }
    result
}

/// The share of overrun periods above which a realtime run on an ONNX object says why.
const ONNX_OVERRUN_HINT: f64 = 0.01;

/// A realtime run whose loop overran more than [`ONNX_OVERRUN_HINT`] of its periods while the
/// bench stepped an ONNX object: the graph runs on the loop's own thread (ONNX Runtime's
/// dispatch per node, several microseconds a run hot and a few times that on a core that
/// slept between periods; docs/laws/onnx.md, "What it costs the realtime loop"), and a
/// lower `onnx.rate_hz` is the user's lever. Measured on the 2-core development machine, the
/// loop's CPU not kept awake: the example at 10 kHz in the 10 kHz loop with the oracle ran
/// 6.4-9.0 kHz, at 2.5 kHz 9.6-9.8 kHz; kept awake (`[realtime] keep_awake`, by default
/// with an ONNX object) 9.95-9.98 kHz at 10 kHz.
fn onnx_overrun_hint(steps: u64, overruns: u64, rate_hz: f64) -> Option<String> {
    let periods = steps + overruns;
    let share = overruns as f64 / periods.max(1) as f64;
    (share > ONNX_OVERRUN_HINT).then(|| {
        format!(
            "{:.1} % of the loop's periods overran ({overruns} of {periods}); the bench steps \
             its ONNX object on the loop's thread at {rate_hz:.0} Hz: a lower onnx.rate_hz in \
             the material file (e.g. {:.0}) runs the graph less often (docs/laws/onnx.md, \
             \"What it costs the realtime loop\")",
            100.0 * share,
            (rate_hz / 4.0).max(1.0)
        )
    })
}

/// A recording is never overwritten unless asked (`--overwrite`).
fn refuse_existing_recording(cfg: &RunConfig) -> Result<()> {
    if let Some(p) = &cfg.record {
        // lstat: a dangling symlink is "something there" too (the recorder refuses it).
        if std::fs::symlink_metadata(p).is_ok() && !cfg.overwrite {
            anyhow::bail!(
                "{} already exists: choose another path or pass --overwrite",
                p.display()
            );
        }
    }
    Ok(())
}

/// Runs the built loop to its end: clock, recorder, sink, stop conditions, summary.
fn drive(
    cfg: &RunConfig,
    rig: &mut Rig<Box<dyn Board>>,
    material_text: &str,
    onnx_object: bool,
    shutdown: &Shutdown,
    mut progress: Option<&mut dyn Progress>,
    mut sink: Option<&mut dyn StepSink>,
) -> Result<RunSummary> {
    let model_name = match &rig.experiment {
        Experiment::Reproduction { model, .. } => model.name().to_string(),
        _ => "none".to_string(),
    };
    let start_error = match &rig.experiment {
        Experiment::Reproduction { model, .. } => model.start_error().map(str::to_string),
        _ => None,
    };
    if let Some(e) = start_error {
        rig.safe_stop();
        anyhow::bail!("{e}");
    }
    let mut recorder = match &cfg.record {
        Some(p) => Some(RecorderHandle::start(
            Target::File(p.clone()),
            cfg.format(),
            metadata_json(cfg, material_text, &model_name),
            cfg.queue_capacity,
        )?),
        None => None,
    };
    let decimate = cfg.decimate as u64;
    let max_time = cfg.max_duration_s.unwrap_or(f64::INFINITY);
    let mut warnings = Vec::new();
    let mut clock: Option<RealtimeClock> = None;
    let mut scheduling = "SCHED_OTHER (lockstep clock: no real-time set-up)".to_string();
    // Restores the thread's scheduling, affinity and memory locking when the run ends.
    let mut _rt_guard = None;
    // The loop's CPU kept awake (clock::KeepAwake): the loop thread moves `awake.steps` once
    // a step (one relaxed store, no syscall); the spinner stops when `_keeper` drops.
    let awake = Arc::new(StepCounter::default());
    let mut _keeper = None;
    if cfg.clock == ClockKind::Realtime {
        let g = cfg.realtime.request().apply();
        scheduling = g.describe();
        warnings = g.obtained().warnings();
        for w in &warnings {
            eprintln!("rt-loop: warning: {w} (continuing without it)");
        }
        let quota = process_cpu_quota();
        if let (true, Some(cpu)) = (
            cfg.realtime
                .keep_awake
                .wanted(onnx_object, quota.as_deref()),
            g.obtained().pinned_cpu,
        ) {
            match KeepAwake::spawn("rt-loop", cpu, Arc::clone(&awake)) {
                Ok(k) => {
                    _keeper = Some(k);
                    // short: the loop-status block holds 64 bytes of it (hapticctl status)
                    scheduling.push_str(", kept awake");
                }
                Err(e) => eprintln!("rt-loop: warning: keep-awake not started ({e})"),
            }
        }
        _rt_guard = Some(g);
        let mut c = RealtimeClock::new(cfg.rate_hz);
        c.start();
        clock = Some(c);
    }
    if let Some(s) = sink.as_deref_mut() {
        s.begin_run(cfg, &scheduling);
    }
    // The watchdog is armed now, right before the first step, after every wait and set-up.
    if let Err(e) = rig.activate() {
        rig.safe_stop();
        anyhow::bail!("board {}: {e}", cfg.board);
    }
    let lockstep = cfg.clock == ClockKind::Lockstep;
    let wall = Instant::now();
    let mut last_time = 0.0;
    let mut last_row: Option<Row> = None;
    let stop = loop {
        if let Some(c) = clock.as_mut() {
            c.wait();
        }
        match rig.step() {
            Ok(row) => {
                awake.steps.store(row.step, Ordering::Relaxed);
                last_time = row.time;
                last_row = Some(row);
                // The step was rendered: it is recorded even when a stop command ends the run here.
                if let Some(r) = recorder.as_mut() {
                    if row.step % decimate == 0 {
                        if lockstep {
                            r.push_wait(row);
                        } else {
                            r.push_or_drop(row);
                        }
                    }
                    if r.failed() {
                        // Nothing more can be recorded: end the run with the motor at 0 A.
                        rig.safe_stop();
                        break StopReason::RecorderFailed;
                    }
                }
                if let Some(s) = sink.as_deref_mut() {
                    if s.on_step(&row) == StepAction::Stop {
                        rig.safe_stop();
                        break StopReason::Stopped;
                    }
                    // about every 100 ms, never per step; allocation-free
                    if s.report_due() {
                        s.report(&figures(rig, clock.as_ref(), recorder.as_ref()));
                    }
                }
                if row.time >= max_time {
                    rig.safe_stop();
                    break StopReason::TimeLimit;
                }
                // one relaxed atomic load per step: the signal handler's request
                if shutdown.is_requested() {
                    rig.safe_stop();
                    break StopReason::Interrupted;
                }
                if lockstep && row.step & 0x3FFF == 0 {
                    if let Some(p) = progress.as_deref_mut() {
                        p.update(row.time);
                    }
                }
            }
            Err(Stop::Finished) => break StopReason::Finished,
            Err(Stop::PositionLimit) => break StopReason::PositionLimit,
            Err(Stop::Watchdog) => break StopReason::Watchdog,
            Err(Stop::BoardFault(m)) => break StopReason::BoardFault(m),
            Err(Stop::BoardGone(m)) => break StopReason::BoardGone(m),
        }
    };
    if let Some(p) = progress {
        p.finish();
    }
    // Tell the telemetry reader (infer-server's status) at once that the run is over: one last
    // row in phase `done`, at 0 A.
    if let (Some(s), Some(mut r)) = (sink.as_deref_mut(), last_row) {
        r.step += 1;
        r.phase = crate::experiment::Phase::Done as u8;
        r.f_ref = 0.0;
        r.i_a_ref = 0.0;
        r.i_motor = 0.0;
        r.analog_out_motor = 32768;
        s.last_row(&r);
    }
    let wall_s = wall.elapsed().as_secs_f64();
    let steps = rig.steps();
    let at_end = figures(rig, clock.as_ref(), recorder.as_ref()).recorder;
    let (rows_pushed, drops, report) = match recorder {
        Some(r) => {
            let (p, d) = (r.pushed(), r.dropped());
            (p, d, Some(r.finish()))
        }
        None => (0, 0, None),
    };
    let totals = sink.map(|s| {
        let f = RunFigures {
            recorder: at_end,
            ..figures(rig, clock.as_ref(), None)
        };
        s.end_run(&f, report.as_ref())
    });
    let ladder = rig.experiment.ladder_report();
    Ok(RunSummary {
        experiment: rig.experiment.name().into(),
        clock: format!("{:?}", cfg.clock).to_lowercase(),
        steps,
        stop,
        loop_time_s: last_time,
        wall_s,
        steps_per_s: steps as f64 / wall_s.max(1e-9),
        rows_pushed,
        drops,
        recorder: report,
        jitter: clock.map(|c| c.stats()),
        model: rig.experiment.model_stats(),
        shm: None,
        round_trip_us: None,
        telemetry_rows: totals.map_or(0, |t| t.rows_sent),
        ladder: ladder.map(|l| l.counts),
        degraded_reasons: ladder.map(|l| l.reasons),
        max_transition_step_n: ladder.map_or(0.0, |l| l.max_transition_step_n),
        transition_steps: ladder.map_or(0, |l| l.transition_steps),
        corrupt: totals.map_or(0, |t| t.corrupt),
        long_steps: rig.long_steps(),
        max_step_ms: rig.max_dt() * 1e3,
        board: rig.board_health(),
        passivity: ladder.map(|_| rig.passivity.report()),
        ramp_turns: rig.experiment.ramp_turns(),
        warnings,
    })
}

/// The run's figures for its sink (no allocation).
fn figures<'a>(
    rig: &'a Rig<Box<dyn Board>>,
    clock: Option<&'a RealtimeClock>,
    recorder: Option<&RecorderHandle>,
) -> RunFigures<'a> {
    RunFigures {
        steps: rig.steps(),
        experiment: &rig.experiment,
        clock,
        recorder: recorder.map(|r| (r.pushed(), r.failed())),
        board: rig.board_health(),
        board_fault: rig.fault(),
        passivity: rig.experiment.model_stats().map(|_| rig.passivity.report()),
    }
}

#[cfg(test)]
mod tests {
    use super::onnx_overrun_hint;

    /// Past 1 % of the periods overrun, a realtime run on an ONNX object names the lever.
    #[test]
    fn an_onnx_object_that_overruns_the_loop_is_named_with_its_lever() {
        assert_eq!(onnx_overrun_hint(22_672, 0, 10_000.0), None);
        assert_eq!(onnx_overrun_hint(9_900, 100, 10_000.0), None);
        let w = onnx_overrun_hint(22_672, 7_234, 10_000.0).unwrap();
        assert!(
            w.starts_with("24.2 % of the loop's periods overran (7234 of 29906)"),
            "{w}"
        );
        assert!(
            w.contains("at 10000 Hz") && w.contains("(e.g. 2500)"),
            "{w}"
        );
    }
}
