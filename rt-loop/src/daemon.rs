//! The daemon: the long-running loop of the system behind `rt-loop serve` (scripts, the web
//! page). It owns the instance's shared-memory segment for its whole life, idles at 0 A (or
//! loops a default experiment), and runs the experiments the mailbox asks for, one at a time,
//! with telemetry and the heartbeat flowing. It keeps one served model (the segment's client)
//! for its whole life: each run is given it and gives it back with its result. SIGINT/SIGTERM
//! end the running experiment at 0 A, finish its recording, remove the segment and exit.

use crate::config::{ClockKind, ExperimentKind, RunConfig};
use crate::percentiles::Percentiles;
use crate::serving::model::ForceModel;
use crate::serving::shm_io::{create_segment, LoopCommand, StartRequest};
use crate::serving::shm_model::{AnswerWait, ShmModel};
use crate::stop::{Shutdown, StopReason};
use anyhow::{anyhow, Result};
use shm_ring::WaitStrategy;
use std::path::PathBuf;
use std::time::Duration;

/// What `rt-loop serve` runs with.
#[derive(Clone, Debug)]
pub struct DaemonConfig {
    /// Everything a run needs (clock, rate, board, material, ramp defaults...).
    pub base: RunConfig,
    pub instance: String,
    /// Experiment started at once and again whenever it finishes, until a stop command.
    pub autostart: Option<ExperimentKind>,
    /// Record each experiment to `DIR/<experiment>-<run>-<unix s>.parquet`.
    pub record_dir: Option<PathBuf>,
    /// Realtime: per-step answer deadline.
    pub deadline: Duration,
    /// Lockstep: safety timeout per answer.
    pub answer_timeout: Duration,
    /// How long a reproduction/shadow run waits at its start for a server (0: not at all).
    pub server_wait: Duration,
    /// Lockstep: safety timeouts in a row before the server is treated as hung.
    pub give_up_after: u32,
    pub answer_wait: WaitStrategy,
}

impl DaemonConfig {
    pub fn answer_wait_mode(&self) -> AnswerWait {
        match self.base.clock {
            ClockKind::Realtime => AnswerWait::Deadline(self.deadline),
            ClockKind::Lockstep => AnswerWait::Lockstep {
                safety: self.answer_timeout,
                give_up_after: self.give_up_after,
            },
        }
    }
}

/// The configuration of one requested experiment (the request's values over the defaults).
pub fn experiment_config(base: &RunConfig, req: &StartRequest) -> RunConfig {
    let mut c = base.clone();
    c.experiment = req.experiment;
    c.ramp.override_with(&req.params);
    c.max_duration_s = None;
    c
}

/// What became of the run's recording, for its "ended" line: nothing when it was saved whole
/// (or there was none), else "RECORDER ERROR" with the rows saved and where, so a run never
/// reads "finished" with rows lost unsaid.
fn recording_outcome(s: &crate::run::RunSummary) -> String {
    let Some(r) = &s.recorder else {
        return String::new();
    };
    let path = r
        .path
        .as_ref()
        .map_or("-".to_string(), |p| p.display().to_string());
    match &r.error {
        Some(e) => format!(
            " but RECORDER ERROR: {e}; {} of {} rows saved in {path} \
             (docs/recording-format.md, \"A failed recording\")",
            r.rows_written, r.rows_received
        ),
        None if s.drops > 0 || r.rows_written < r.rows_received => format!(
            " but the recording lost rows: {} written of {} received, {} dropped ({path})",
            r.rows_written, r.rows_received, s.drops
        ),
        None => String::new(),
    }
}

fn unix_s() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// Runs until `shutdown` is requested (SIGINT/SIGTERM). Returns the number of experiments run.
pub fn run(cfg: &DaemonConfig, shutdown: &Shutdown) -> Result<u64> {
    cfg.base.validate().map_err(|e| anyhow!(e))?;
    if let Some(d) = &cfg.record_dir {
        std::fs::create_dir_all(d).map_err(|e| anyhow!("--record-dir {}: {e}", d.display()))?;
    }
    let seg = create_segment(&cfg.instance, cfg.answer_wait)?;
    let name = seg.name.clone();
    let mut io = seg.io;
    io.set_identity(&cfg.base);
    io.publish_status();
    // The served model, given to each reproduction/shadow run and given back by it.
    let mut client = seg.client;
    client.stop_on(shutdown.clone());
    let mut served = Some(ShmModel::new(
        client,
        cfg.answer_wait_mode(),
        cfg.server_wait,
    ));
    eprintln!(
        "rt-loop: serving segment {name} ({:?} clock, {} Hz, board {:?}); autostart {}",
        cfg.base.clock,
        cfg.base.rate_hz,
        cfg.base.board,
        cfg.autostart.map_or(
            "none (idle at 0 A until a start command)".into(),
            |e| format!("{e:?}")
        )
    );
    let mut next: Option<StartRequest> = cfg.autostart.map(|e| StartRequest {
        id: 0,
        experiment: e,
        params: Default::default(),
    });
    let mut runs = 0u64;
    let mut run_id = 0u32;
    loop {
        if shutdown.is_requested() {
            break;
        }
        let Some(req) = next.take() else {
            // Idle: 0 A (no run, the board is not driven), heartbeat, mailbox, status.
            io.heartbeat();
            io.idle_status();
            match io.poll_command() {
                Some(LoopCommand::Start(r)) => next = Some(r),
                Some(LoopCommand::Stop { .. }) => {}
                Some(LoopCommand::Refused { id, reason }) => {
                    eprintln!("rt-loop: command {id} refused: {reason}")
                }
                None => std::thread::sleep(Duration::from_millis(2)),
            }
            continue;
        };
        let mut rc = experiment_config(&cfg.base, &req);
        if let Err(e) = rc.validate() {
            eprintln!(
                "rt-loop: command {} refused: {e} (parameters {:?})",
                req.id, req.params
            );
            continue;
        }
        run_id = run_id.wrapping_add(1);
        io.set_run_id(run_id);
        if let Some(d) = &cfg.record_dir {
            let n = format!(
                "{}-{run_id}-{}.parquet",
                format!("{:?}", rc.experiment).to_lowercase(),
                unix_s()
            );
            rc.record = Some(d.join(n));
        }
        // The client's counters (shared atomics), read before and after the run.
        let counters = served.as_ref().map(|m| m.client().counters.clone());
        let model: Option<Box<dyn ForceModel>> = match rc.experiment {
            ExperimentKind::Reproduction | ExperimentKind::Shadow => match served.take() {
                Some(m) => Some(Box::new(m)),
                None => {
                    eprintln!("rt-loop: the shared-memory client is not available: fallback only");
                    None
                }
            },
            _ => None,
        };
        let before = counters.as_ref().map(|c| c.snapshot());
        // Only abstraction runs the ramp cycles: the other runs are not logged with settings
        // they do not use (a shadow or reproduction run follows the hand's programme).
        let ramp = match rc.experiment {
            ExperimentKind::Abstraction => format!(
                ", ramp {} N/s, {} cycles, F_max {} + {} N",
                rc.ramp.ramp_rate, rc.ramp.cycles, rc.ramp.f_max_start, rc.ramp.f_max_step
            ),
            _ => String::new(),
        };
        eprintln!(
            "rt-loop: run {run_id}: {:?} (command {}){ramp}{}",
            rc.experiment,
            req.id,
            rc.record
                .as_ref()
                .map_or(String::new(), |p| format!(", recording {}", p.display()))
        );
        let outcome = crate::run::run_with(&rc, model, shutdown, None, Some(&mut io));
        if served.is_none() {
            served = outcome.model.and_then(ShmModel::from_model);
        }
        let result = outcome.result;
        runs += 1;
        if io.refused_during_run > 0 {
            if let Some((id, why)) = io.last_refused {
                eprintln!(
                    "rt-loop: {} command(s) refused during the run (last: {id}: {why})",
                    io.refused_during_run
                );
            }
            io.refused_during_run = 0;
        }
        match result {
            Ok(s) => {
                let shm = match (counters.as_ref(), before) {
                    (Some(c), Some(b)) if s.model.is_some() => {
                        let a = c.snapshot();
                        let rtt = served
                            .as_ref()
                            .and_then(|m| Percentiles::of(&m.client().round_trip_ns))
                            .map_or(String::new(), |p| {
                                format!(
                                    ", round trip p50 {:.1} us p99 {:.1} us max {:.1} us",
                                    p.p50, p.p99, p.max
                                )
                            });
                        format!(
                            "; shm: {} sent, {} answered, {} late, {} no server, {} flagged{rtt}",
                            a.sent - b.sent,
                            a.answered - b.answered,
                            a.late - b.late,
                            a.no_server - b.no_server,
                            a.flagged - b.flagged
                        )
                    }
                    _ => String::new(),
                };
                eprintln!(
                    "rt-loop: run {run_id} ended: {}{}, {} steps, {:.2} s{}{}",
                    s.stop,
                    recording_outcome(&s),
                    s.steps,
                    s.loop_time_s,
                    s.model.map_or(String::new(), |m| format!(
                        ", model {} served / {} fallbacks",
                        m.served, m.fallbacks
                    )),
                    shm
                );
                if let (Some(l), Some(r)) = (&s.ladder, &s.degraded_reasons) {
                    eprintln!(
                        "rt-loop: run {run_id} ladder: {} on time, {} late one, {} held, {} fallback, {} saturated (max transition step {:.4} N); not on time because: {} late, {} no server, {} flagged, {} ring full, {} server lost, {} hung, {} rejected",
                        l.on_time, l.late_one, l.held, l.fallback, l.saturated, s.max_transition_step_n,
                        r.late, r.no_server, r.flagged, r.ring_full, r.server_lost, r.hung, r.rejected
                    );
                }
                if let Some(p) = &s.passivity {
                    eprintln!("rt-loop: run {run_id} {p}");
                }
                if s.stop == StopReason::Interrupted {
                    break;
                }
                // A finished autostart experiment starts again; a stopped one leaves the loop idle.
                if s.stop != StopReason::Stopped {
                    next = cfg.autostart.map(|e| StartRequest {
                        id: 0,
                        experiment: e,
                        params: Default::default(),
                    });
                }
            }
            Err(e) => eprintln!("rt-loop: run {run_id} failed: {e:#}"),
        }
    }
    // Dropping the client and the side channel unlinks the segment (clean exit).
    drop(io);
    drop(served);
    eprintln!("rt-loop: serve stopped after {runs} experiment(s); segment {name} removed");
    Ok(runs)
}
