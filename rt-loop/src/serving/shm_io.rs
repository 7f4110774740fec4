//! The loop's shared-memory segment (crate `shm-ring`): creation with the feature schema, and
//! [`LoopIo`], the per-step side channel to infer-server: telemetry rows, the loop heartbeat
//! and the command mailbox.
//!
//! REAL-TIME PATH: [`LoopIo::on_step`] allocates nothing, takes no lock and does no I/O: one
//! overwrite-ring push (never blocks, never fails), one atomic heartbeat store, and every
//! [`COMMAND_POLL_EVERY`] steps one non-blocking mailbox poll.

/// What the recorder's state starts with at a run's start after a failed recording: it begins
/// with "failed" (what the control plane's `recorder_failed` looks for) until one succeeds.
const FAILED_BEFORE: &str = "failed in the last run; now writing ";

use crate::config::RunConfig;
use crate::features::SCHEMA_NAMES;
use crate::percentiles::quantiles;
use crate::record::row::Row;
use crate::record::RecorderReport;
use crate::serving::shm_model::ShmClient;
use crate::serving::sink::{RunFigures, SinkTotals, StepAction, StepSink};
use anyhow::{anyhow, bail, Result};
use haptics_proto::experiment_args::ExperimentArgs;
use haptics_proto::{
    Command, LoopClock, LoopStatus, LoopStatusLink, Quantiles, Segment, StatusText, TelemetryRow,
    RECORDER_BYTES,
};
use shm_ring::{
    Config, Consumer, DecodeError, Link, OverwriteProducer, RecvError, SegmentName, WaitStrategy,
};
use std::fmt::Write as _;
use std::time::{Duration, Instant};

/// Steps between two polls of the command mailbox (1.6 ms at 10 kHz).
pub const COMMAND_POLL_EVERY: u64 = 16;
/// The loop-status block is published about this often (never per step).
pub const STATUS_EVERY: Duration = Duration::from_millis(100);
/// Steps between two looks at the clock for [`STATUS_EVERY`] (6.4 ms at 10 kHz).
const STATUS_CHECK_EVERY: u32 = 64;

fn unix_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The segment of one rt-loop instance, split into the model client and the side channel.
pub struct LoopSegment {
    pub client: ShmClient,
    pub io: LoopIo,
    pub name: SegmentName,
}

/// Creates `/haptics-<instance>` with the loop's feature schema (the names of
/// [`SCHEMA_NAMES`], in the order `Features::as_schema_array` gives them).
pub fn create_segment(instance: &str, answer_wait: WaitStrategy) -> Result<LoopSegment> {
    let name =
        SegmentName::for_instance(instance).map_err(|e| anyhow!("--instance {instance:?}: {e}"))?;
    let config = Config {
        feature_names: SCHEMA_NAMES.iter().map(|s| s.to_string()).collect(),
        ..haptics_proto::layout::config()
    };
    let segment = Segment::create(&name, &config).map_err(|e| anyhow!("segment {name}: {e}"))?;
    if let Some(pid) = segment.replaced_stale() {
        eprintln!("rt-loop: replaced the segment {name} left by a dead loop ({pid:?})");
    }
    let side = segment
        .loop_side()
        .map_err(|e| anyhow!("segment {name}: {e}"))?;
    let names = side.link.feature_names();
    if names
        .iter()
        .map(String::as_str)
        .ne(SCHEMA_NAMES.iter().copied())
    {
        bail!("segment {name}: schema {names:?} is not the loop's {SCHEMA_NAMES:?}");
    }
    let mut client = ShmClient::new(
        side.features_tx,
        side.forces_rx,
        side.link.clone(),
        answer_wait,
    );
    let mut io = LoopIo::new(side.telemetry_tx, side.commands_rx, side.link);
    // The keeper: audits the segment and re-creates it when it is found corrupt.
    let (c, i) = crate::serving::shm_renew::Renewal::start(io.link.clone(), answer_wait)?;
    (client.renewal, io.renewal) = (Some(c), Some(i));
    Ok(LoopSegment { client, io, name })
}

/// A validated experiment request from the mailbox.
#[derive(Clone, Debug, PartialEq)]
pub struct StartRequest {
    pub id: u64,
    pub experiment: crate::config::ExperimentKind,
    /// What the start sets over the loop's defaults.
    pub params: ExperimentArgs,
}

/// A command, checked like any outside input.
#[derive(Clone, Debug, PartialEq)]
pub enum LoopCommand {
    Start(StartRequest),
    Stop {
        id: u64,
    },
    /// Refused with the reason (logged off the real-time path).
    Refused {
        id: u64,
        reason: &'static str,
    },
}

pub fn parse_command(c: &Command) -> LoopCommand {
    use crate::config::ExperimentKind as E;
    match *c {
        Command::Stop { id } => LoopCommand::Stop { id },
        Command::SetParameter { id, .. } => LoopCommand::Refused {
            id,
            reason: "set-parameter is not supported by rt-loop",
        },
        // The values were checked when the command was decoded (haptics_proto::command).
        Command::Start {
            id,
            experiment,
            args,
        } => {
            let experiment = match experiment.as_str() {
                "abstraction" => E::Abstraction,
                "reproduction" => E::Reproduction,
                "shadow" => E::Shadow,
                "position-replay" => {
                    return LoopCommand::Refused {
                        id,
                        reason: "position-replay needs a trajectory file: use rt-loop run",
                    }
                }
                _ => {
                    return LoopCommand::Refused {
                        id,
                        reason: "unknown experiment name",
                    }
                }
            };
            LoopCommand::Start(StartRequest {
                id,
                experiment,
                params: args,
            })
        }
    }
}

/// Telemetry, heartbeat and mailbox of the loop.
pub struct LoopIo {
    telemetry_tx: OverwriteProducer<TelemetryRow>,
    commands_rx: Consumer<Command>,
    link: Link,
    run_id: u32,
    /// Commands that arrived during a run and could not be acted on there (a start while one
    /// runs is refused): counted, the last one kept for the log after the run.
    pub refused_during_run: u64,
    pub last_refused: Option<(u64, &'static str)>,
    pub rows_sent: u64,
    /// What goes into the segment's loop-status block (kept here, updated in place).
    status: LoopStatus,
    /// "writing PATH" of the current recording (the row count is appended at each publication).
    recorder_prefix: StatusText<RECORDER_BYTES>,
    /// The last run's recording failed (a full disk, an I/O error): the next run's recorder
    /// state says so until a recording succeeds, so a failure is never hidden by the next run's
    /// "writing ..." (control plane: `recorder_failed`, `haptics_recorder_failed`).
    last_recording_failed: bool,
    status_countdown: u32,
    last_status: Instant,
    /// Fresh endpoints when the segment is re-created after corruption (`shm_renew`).
    pub renewal: Option<crate::serving::shm_renew::Renewal>,
    /// The keeper's corruption count when the current run began.
    corrupt_at_run_start: u64,
}

impl LoopIo {
    pub fn new(
        telemetry_tx: OverwriteProducer<TelemetryRow>,
        commands_rx: Consumer<Command>,
        link: Link,
    ) -> Self {
        LoopIo {
            telemetry_tx,
            commands_rx,
            link,
            run_id: 0,
            refused_during_run: 0,
            last_refused: None,
            rows_sent: 0,
            status: LoopStatus {
                scheduling: StatusText::new("idle (no experiment yet)"),
                recorder: StatusText::new("off"),
                ..LoopStatus::default()
            },
            recorder_prefix: StatusText::default(),
            last_recording_failed: false,
            status_countdown: STATUS_CHECK_EVERY,
            last_status: Instant::now(),
            renewal: None,
            corrupt_at_run_start: 0,
        }
    }

    /// Sets what does not change between runs (off the real-time path).
    pub fn set_identity(&mut self, cfg: &RunConfig) {
        self.status.clock = match cfg.clock {
            crate::config::ClockKind::Lockstep => LoopClock::Lockstep,
            crate::config::ClockKind::Realtime => LoopClock::Realtime,
        };
        self.status.board.set(&cfg.board.to_string());
        self.status.rate_hz = cfg.rate_hz;
        self.status.velocity_gain_rad_s = cfg.params.g_v;
        self.status.acceleration_gain_rad_s = cfg.params.g_a;
    }

    /// A run begins (off the real-time path): its counters start at 0, the scheduling it
    /// obtained and its recording (`None`: "off") are set, and the block is published.
    pub fn begin_run_status(
        &mut self,
        cfg: &RunConfig,
        scheduling: &str,
        recording: Option<&std::path::Path>,
    ) {
        self.set_identity(cfg);
        let s = &mut self.status;
        s.running = true;
        s.run_id = u64::from(self.run_id);
        s.steps = 0;
        s.fallbacks = 0;
        s.experiment.set(match cfg.experiment {
            crate::config::ExperimentKind::Abstraction => "abstraction",
            crate::config::ExperimentKind::PositionReplay => "position-replay",
            crate::config::ExperimentKind::Reproduction => "reproduction",
            crate::config::ExperimentKind::Shadow => "shadow",
        });
        s.on_time = 0;
        s.late_one = 0;
        s.held = 0;
        s.fallback_steps = 0;
        s.saturated = 0;
        s.corrupt = 0;
        self.corrupt_at_run_start = self.renewal.as_ref().map_or(0, |r| r.corrupt());
        s.max_transition_step_n = 0.0;
        s.passivity_on = cfg.passivity.enabled_on(cfg.board);
        s.passivity_energy_j = 0.0;
        s.passivity_received_j = 0.0;
        s.passivity_returned_j = 0.0;
        s.passivity_damping_ns_per_m = 0.0;
        s.passivity_active_steps = 0;
        s.deadline_misses = 0;
        s.overruns = 0;
        s.round_trip = Quantiles::default();
        s.period_jitter = Quantiles::default();
        s.scheduling.set(scheduling);
        self.recorder_prefix = match recording {
            Some(p) => {
                // Keep room for " rows N"; a long path loses its beginning, not its name.
                let path = p.display().to_string();
                let lead = if self.last_recording_failed {
                    FAILED_BEFORE
                } else {
                    "writing "
                };
                let room = RECORDER_BYTES - lead.len() - 28;
                let mut cut = path.len().saturating_sub(room);
                while !path.is_char_boundary(cut) {
                    cut += 1;
                }
                let shown = if cut > 0 {
                    format!("...{}", &path[cut..])
                } else {
                    path
                };
                StatusText::new(&format!("{lead}{shown}"))
            }
            None => StatusText::default(),
        };
        self.set_recorder_rows(0);
        self.publish_status();
    }

    /// The recorder's state with `rows` rows handed to it so far ("off" without a recording).
    /// No allocation.
    pub fn set_recorder_rows(&mut self, rows: u64) {
        if self.recorder_prefix.is_empty() {
            self.status.recorder.set("off");
        } else {
            self.status.recorder = self.recorder_prefix;
            let _ = write!(self.status.recorder, " rows {rows}");
        }
    }

    /// Sets the recorder's state text (e.g. "failed: ...") as is.
    pub fn set_recorder_text(&mut self, text: &str) {
        self.status.recorder.set(text);
    }

    /// The run ended (off the real-time path): `running` false, the final figures stay.
    pub fn end_run_status(&mut self) {
        self.status.running = false;
        self.publish_status();
    }

    /// The run's figures into the status block (no allocation, no lock): steps, fallbacks, the
    /// ladder's counts, the model's misses and round trip, the clock's overruns and jitter,
    /// the recorder's rows.
    pub fn fill_status(&mut self, f: &RunFigures<'_>) {
        match f.recorder {
            Some((_, true)) => {
                self.set_recorder_text("failed (the run ends at 0 A; see its summary)")
            }
            Some((n, false)) => self.set_recorder_rows(n),
            None => self.set_recorder_rows(0),
        }
        let s = &mut self.status;
        s.steps = f.steps;
        s.fallbacks = f.experiment.model_stats().map_or(0, |m| m.fallbacks);
        if let Some(l) = f.experiment.ladder_report() {
            s.on_time = l.counts.on_time;
            s.late_one = l.counts.late_one;
            s.held = l.counts.held;
            s.fallback_steps = l.counts.fallback;
            s.saturated = l.counts.saturated;
            s.max_transition_step_n = l.max_transition_step_n;
        }
        if let Some(p) = f.passivity {
            s.passivity_on = p.enabled;
            s.passivity_energy_j = p.energy_j;
            s.passivity_received_j = p.received_j;
            s.passivity_returned_j = p.returned_j;
            s.passivity_damping_ns_per_m = p.max_damping_ns_per_m;
            s.passivity_active_steps = p.active_steps;
        }
        f.experiment.report_status(s);
        s.board_fifo_overflows = f.board.fifo_overflows;
        s.board_quadrature_errors = f.board.quadrature_errors;
        if let Some(c) = f.clock {
            s.overruns = c.overruns();
            s.period_jitter = quantiles(c.jitter());
        }
    }

    /// The status being built; [`LoopIo::publish_status`] writes it.
    pub fn status_mut(&mut self) -> &mut LoopStatus {
        &mut self.status
    }

    pub fn status(&self) -> &LoopStatus {
        &self.status
    }

    /// Whether the status block is due (about every [`STATUS_EVERY`]). Per step: one
    /// decrement, and every [`STATUS_CHECK_EVERY`] steps one monotonic clock read (vDSO).
    #[inline]
    pub fn status_due(&mut self) -> bool {
        self.status_countdown -= 1;
        if self.status_countdown > 0 {
            return false;
        }
        self.status_countdown = STATUS_CHECK_EVERY;
        self.last_status.elapsed() >= STATUS_EVERY
    }

    /// Writes the status into the segment (seqlock, no allocation, no lock, no syscall but
    /// the vDSO clock reads).
    pub fn publish_status(&mut self) {
        self.renew_if_pending();
        self.last_status = Instant::now();
        self.status.updated_unix_ns = unix_ns();
        self.link.publish_loop_status(&self.status);
    }

    /// Moves telemetry and mailbox to a re-created segment's endpoints (`shm_renew`; at each
    /// status publication, about every 100 ms: telemetry sent to the old segment meanwhile is
    /// simply not read) and updates the run's corruption count.
    fn renew_if_pending(&mut self) {
        let Some(renewal) = self.renewal.as_mut() else {
            return;
        };
        let (tx, rx, link) = (
            &mut self.telemetry_tx,
            &mut self.commands_rx,
            &mut self.link,
        );
        renewal.swap_io(|new| crate::serving::shm_renew::IoEnds {
            telemetry_tx: std::mem::replace(tx, new.telemetry_tx),
            commands_rx: std::mem::replace(rx, new.commands_rx),
            link: std::mem::replace(link, new.link),
        });
        self.status.corrupt = renewal.corrupt().saturating_sub(self.corrupt_at_run_start);
    }

    /// While idle (called every few ms): publishes about every [`STATUS_EVERY`].
    pub fn idle_status(&mut self) {
        if self.last_status.elapsed() >= STATUS_EVERY {
            self.publish_status();
        }
    }

    pub fn link(&self) -> &Link {
        &self.link
    }

    pub fn set_run_id(&mut self, run_id: u32) {
        self.run_id = run_id;
    }

    pub fn run_id(&self) -> u32 {
        self.run_id
    }

    pub fn heartbeat(&self) {
        self.link.heartbeat();
    }

    /// Non-blocking poll of the mailbox (one command at a time).
    pub fn poll_command(&mut self) -> Option<LoopCommand> {
        match self.commands_rx.try_recv() {
            Ok(Some(c)) => Some(parse_command(&c)),
            Ok(None) => None,
            // A command the decoder refused (its id unread: the error names the field, e.g. a
            // start value out of range) is skipped, not acted on.
            Err(RecvError::Decode(DecodeError::InvalidField { field, .. })) => {
                Some(LoopCommand::Refused {
                    id: 0,
                    reason: field,
                })
            }
            // A corrupt mailbox entry is skipped, not acted on.
            Err(_) => Some(LoopCommand::Refused {
                id: 0,
                reason: "unreadable command in the mailbox",
            }),
        }
    }

    /// Publishes one telemetry row with the run id.
    #[inline]
    pub fn publish(&mut self, row: &Row) {
        self.telemetry_tx.send(&telemetry_row(row, self.run_id));
        self.rows_sent += 1;
    }

    /// Per step during a run: telemetry, heartbeat, mailbox. REAL-TIME PATH.
    #[inline]
    pub fn on_step(&mut self, row: &Row) -> StepAction {
        self.publish(row);
        self.link.heartbeat();
        if row.step.is_multiple_of(COMMAND_POLL_EVERY) {
            match self.poll_command() {
                Some(LoopCommand::Stop { .. }) => return StepAction::Stop,
                Some(LoopCommand::Start(r)) => {
                    self.refused_during_run += 1;
                    self.last_refused = Some((r.id, "an experiment is already running"));
                }
                Some(LoopCommand::Refused { id, reason }) => {
                    self.refused_during_run += 1;
                    self.last_refused = Some((id, reason));
                }
                None => {}
            }
        }
        StepAction::Continue
    }
}

/// A recording row as the telemetry ring sends it: the same row, with the run's id.
#[inline]
pub fn telemetry_row(r: &Row, run_id: u32) -> TelemetryRow {
    TelemetryRow { run_id, ..*r }
}

/// The loop's side channel as the run's sink: telemetry and heartbeat every step, the mailbox
/// every [`COMMAND_POLL_EVERY`] steps, the status block about every [`STATUS_EVERY`].
impl StepSink for LoopIo {
    fn begin_run(&mut self, cfg: &RunConfig, scheduling: &str) {
        self.begin_run_status(cfg, scheduling, cfg.record.as_deref());
    }

    #[inline]
    fn on_step(&mut self, row: &Row) -> StepAction {
        LoopIo::on_step(self, row)
    }

    #[inline]
    fn report_due(&mut self) -> bool {
        self.status_due()
    }

    fn report(&mut self, figures: &RunFigures<'_>) {
        self.fill_status(figures);
        self.publish_status();
    }

    fn last_row(&mut self, row: &Row) {
        self.publish(row);
        self.heartbeat();
    }

    fn end_run(
        &mut self,
        figures: &RunFigures<'_>,
        recorder: Option<&RecorderReport>,
    ) -> SinkTotals {
        self.fill_status(figures);
        if let Some(why) = figures.board_fault {
            // counted across runs: the loop's life, like the page's fault indicator
            self.status.board_faults += 1;
            self.status.board_fault.set(why);
        }
        if let Some(r) = recorder {
            self.last_recording_failed = r.error.is_some();
            match (&r.error, &r.path) {
                (Some(e), _) => self.set_recorder_text(&format!("failed: {e}")),
                (None, Some(p)) => self.set_recorder_text(&format!(
                    "wrote {} rows {}",
                    p.display(),
                    r.rows_written
                )),
                (None, None) => {}
            }
        }
        self.end_run_status();
        SinkTotals {
            rows_sent: self.rows_sent,
            corrupt: self.status.corrupt,
        }
    }
}
