//! [`StepSink`]: where a run's per-step output goes besides its recording. The run
//! ([`crate::run::run_with`]) only knows this trait; the shared-memory side channel
//! ([`crate::serving::shm_io::LoopIo`]: telemetry, heartbeat, mailbox, status block) implements it. So
//! the run does not import the shared-memory modules, and they do not import the run.

use crate::clock::RealtimeClock;
use crate::config::RunConfig;
use crate::experiment::Experiment;
use crate::record::row::Row;
use crate::record::RecorderReport;

/// What the step loop should do after a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepAction {
    Continue,
    /// A stop command arrived: end the run safely (0 A).
    Stop,
}

/// The run's figures so far, handed to [`StepSink::report`] off the per-step path (about every
/// 100 ms, and at the end). Borrowed, never copied into anything that allocates.
pub struct RunFigures<'a> {
    /// Steps rendered so far.
    pub steps: u64,
    /// The experiment: its model's figures, the ladder's counts.
    pub experiment: &'a Experiment,
    /// The realtime clock (overruns, period jitter); `None` in lockstep.
    pub clock: Option<&'a RealtimeClock>,
    /// Rows handed to the recorder so far and whether it failed; `None` without a recording.
    pub recorder: Option<(u64, bool)>,
    /// The board's non-fatal counters (FIFO overflows, quadrature errors).
    pub board: crate::board::BoardHealth,
    /// The board failure that ended the run (`None` while it runs, or when none did).
    pub board_fault: Option<&'static str>,
    /// The passivity layer's figures (reproduction and shadow; `None` for the others).
    pub passivity: Option<crate::passivity::PassivityReport>,
}

/// What a sink sent during the run, for the run's summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SinkTotals {
    /// Telemetry rows published.
    pub rows_sent: u64,
    /// Ring slots or indices found corrupt during the run.
    pub corrupt: u64,
}

/// The per-step output of a run, in the order the run calls it: [`begin_run`](Self::begin_run)
/// once, then per step [`on_step`](Self::on_step) and [`report_due`](Self::report_due) (and
/// [`report`](Self::report) when due), then [`last_row`](Self::last_row) as soon as the loop
/// is at 0 A and [`end_run`](Self::end_run) once the recording is closed.
pub trait StepSink {
    /// A run begins (off the real-time path): `scheduling` says what real-time set-up it
    /// obtained.
    fn begin_run(&mut self, cfg: &RunConfig, scheduling: &str);
    /// After each rendered step. REAL-TIME PATH: no allocation, no lock, no I/O; a bounded,
    /// non-blocking amount of work.
    fn on_step(&mut self, row: &Row) -> StepAction;
    /// Whether [`report`](Self::report) is due. REAL-TIME PATH, called every step: a counter,
    /// now and then a clock read.
    fn report_due(&mut self) -> bool;
    /// The run's figures so far. On the loop thread: no allocation, no lock.
    fn report(&mut self, figures: &RunFigures<'_>);
    /// The loop stopped at 0 A; `row` is its final state (phase `done`), for readers that
    /// must learn at once that the run is over.
    fn last_row(&mut self, row: &Row);
    /// The run is over and its recording closed (`recorder`: its report, `None` without one).
    fn end_run(
        &mut self,
        figures: &RunFigures<'_>,
        recorder: Option<&RecorderReport>,
    ) -> SinkTotals;
}
