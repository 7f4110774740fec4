//! The run's contract with its caller: the model it is given comes back with its result (on
//! success, on an error, and untouched when the experiment uses none), and its per-step output
//! goes to a [`StepSink`] in the documented order, which can stop it.

mod common;

use rt_loop::config::ExperimentKind;
use rt_loop::features::Features;
use rt_loop::record::row::Row;
use rt_loop::record::RecorderReport;
use rt_loop::serving::model::ForceModel;
use rt_loop::serving::sink::{RunFigures, SinkTotals, StepAction, StepSink};
use rt_loop::stop::{Shutdown, StopReason};
use std::any::Any;

/// Counts the steps it was asked about.
struct Counting(u64);

impl ForceModel for Counting {
    fn name(&self) -> &str {
        "counting"
    }
    fn predict(&mut self, _step: u64, f: &Features) -> Option<f64> {
        self.0 += 1;
        Some(100.0 * f.position_x.max(0.0))
    }
}

fn counted(model: Option<Box<dyn ForceModel>>) -> u64 {
    let any: Box<dyn Any> = model.expect("the model comes back");
    any.downcast::<Counting>().expect("the same model").0
}

#[test]
fn the_model_comes_back_with_the_result() {
    let never = Shutdown::new().unwrap();
    let mut cfg = common::short_cfg(1, 1.0, 0.0);
    cfg.experiment = ExperimentKind::Reproduction;
    cfg.hand.repeats = 1;
    let out = rt_loop::run::run_with(&cfg, Some(Box::new(Counting(0))), &never, None, None);
    let s = out.result.unwrap();
    assert_eq!(s.stop, StopReason::Finished);
    let m = s.model.unwrap();
    assert_eq!(
        counted(out.model),
        m.served + m.fallbacks,
        "asked once per step"
    );

    // an experiment without a model leaves it untouched
    let abstraction = common::short_cfg(1, 6.0, 0.0);
    let out = rt_loop::run::run_with(
        &abstraction,
        Some(Box::new(Counting(0))),
        &never,
        None,
        None,
    );
    assert!(out.result.unwrap().ok());
    assert_eq!(counted(out.model), 0);

    // a run refused before its first step still gives it back
    let dir = common::tmpdir("outcome");
    let taken = dir.join("taken.csv");
    std::fs::write(&taken, "x").unwrap();
    cfg.record = Some(taken);
    let out = rt_loop::run::run_with(&cfg, Some(Box::new(Counting(7))), &never, None, None);
    assert!(out
        .result
        .unwrap_err()
        .to_string()
        .contains("already exists"));
    assert_eq!(counted(out.model), 7);

    // a run given no model gives none back (its fallback stays with it)
    cfg.record = None;
    let out = rt_loop::run::run_with(&cfg, None, &never, None, None);
    assert!(out.result.unwrap().ok());
    assert!(out.model.is_none());
}

/// Records the calls a run makes and asks it to stop after `stop_after` steps.
#[derive(Default)]
struct Probe {
    calls: Vec<&'static str>,
    steps: u64,
    stop_after: u64,
    last: Option<Row>,
    reported_steps: u64,
}

impl StepSink for Probe {
    fn begin_run(&mut self, _cfg: &rt_loop::config::RunConfig, scheduling: &str) {
        assert!(scheduling.starts_with("SCHED_OTHER"), "{scheduling}");
        self.calls.push("begin");
    }
    fn on_step(&mut self, row: &Row) -> StepAction {
        assert_eq!(row.step, self.steps, "every step, in order");
        self.steps += 1;
        if self.steps == self.stop_after {
            StepAction::Stop
        } else {
            StepAction::Continue
        }
    }
    fn report_due(&mut self) -> bool {
        self.steps.is_multiple_of(1000)
    }
    fn report(&mut self, f: &RunFigures<'_>) {
        self.reported_steps = f.steps;
    }
    fn last_row(&mut self, row: &Row) {
        self.calls.push("last");
        self.last = Some(*row);
    }
    fn end_run(&mut self, f: &RunFigures<'_>, recorder: Option<&RecorderReport>) -> SinkTotals {
        assert!(recorder.is_none());
        self.calls.push("end");
        SinkTotals {
            rows_sent: f.steps,
            corrupt: 3,
        }
    }
}

#[test]
fn the_sink_sees_every_step_in_order_and_can_stop_the_run() {
    let never = Shutdown::new().unwrap();
    let cfg = common::short_cfg(2, 6.0, 0.0);
    let mut probe = Probe {
        stop_after: 2500,
        ..Probe::default()
    };
    let out = rt_loop::run::run_with(&cfg, None, &never, None, Some(&mut probe));
    let s = out.result.unwrap();
    assert_eq!(s.stop, StopReason::Stopped);
    assert!(s.ok(), "a stop command is a planned end");
    assert_eq!(probe.calls, ["begin", "last", "end"]);
    assert_eq!(s.steps, 2500);
    assert_eq!(probe.steps, 2500);
    assert_eq!(
        probe.reported_steps, 2000,
        "reports when due, with the run's figures"
    );
    assert_eq!(
        (s.telemetry_rows, s.corrupt),
        (2500, 3),
        "the sink's totals"
    );
    let last = probe.last.unwrap();
    assert_eq!(last.step, 2500, "one row after the last step");
    assert_eq!(last.phase, rt_loop::experiment::Phase::Done as u8);
    assert_eq!((last.f_ref, last.i_motor), (0.0, 0.0));

    // a requested shutdown ends the run at its next step
    let stop = Shutdown::new().unwrap();
    stop.request();
    let s = rt_loop::run::run_with(&cfg, None, &stop, None, None)
        .result
        .unwrap();
    assert_eq!((s.stop, s.steps), (StopReason::Interrupted, 1));
}
