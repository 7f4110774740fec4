//! The loop step of docs/physics.md, "The loop step", exactly as the thesis code runs it, plus the experiment's
//! command, the online features and the safety checks.
//!
//! REAL-TIME PATH: [`Rig::step`] allocates nothing, takes no lock and does no I/O (beyond the
//! board's own register access). Everything it touches is built in [`Rig::new`]. A test binary
//! with a counting global allocator (tests/alloc_free_step.rs) holds it to that.

use crate::board::{Board, BoardError, BoardHealth, BoardStop};
use crate::control::dac;
use crate::control::filters::Estimator;
use crate::experiment::{Command, Experiment, Phase};
use crate::features::{FeatureExtractor, FeatureParams};
use crate::params::LoopParams;
use crate::record::row::Row;

/// A step whose dt exceeds this many nominal periods is a stall: counted, and its updates
/// bounded (the filters' exact discretisation, see [`crate::control::filters`]; the PID's integral
/// takes at most this many periods).
pub const LONG_STEP_FACTOR: f64 = 3.0;

/// Why the loop stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    /// The experiment (or the replayed data) ended.
    Finished,
    /// |x| reached the position limit: current set to 0, run aborted.
    PositionLimit,
    /// The board reported a fault (a read, a DAC write or a watchdog kick failed): current
    /// set to 0, the board in its safe mode, run aborted.
    BoardFault(&'static str),
    /// The board is gone (unplugged, closed under the loop): its safe mode holds 0 A.
    BoardGone(&'static str),
    /// The watchdog fired (the loop was not kicking it in time).
    Watchdog,
}

/// The board could not be configured or activated; the experiment (and its model) comes
/// back so that a long-running caller keeps its served model.
pub struct StartFailed {
    pub error: BoardError,
    /// Boxed: an experiment is large, and this travels in an `Err`.
    pub experiment: Box<Experiment>,
}

impl std::fmt::Debug for StartFailed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "StartFailed({:?})", self.error)
    }
}

pub struct Rig<B: Board> {
    pub board: B,
    pub params: LoopParams,
    pub experiment: Experiment,
    est: Estimator,
    features: FeatureExtractor,
    step: u64,
    t_prev_us: u32,
    time: f64,
    i_motor: f64,
    started: bool,
    /// Nominal period, s ([`Rig::set_period`]; the bench's 10 kHz until set).
    period: f64,
    long_steps: u64,
    max_dt: f64,
    /// The board's failure that ended the run, if any (the reason shown in status).
    fault: Option<&'static str>,
    /// Whether [`Rig::finish`] has run (deactivate + shutdown happen once).
    finished: bool,
    /// Whether the board was activated (watchdog armed, encoder zeroed).
    activated: bool,
    /// Why activation failed, when it failed on the first step.
    activate_error: Option<BoardError>,
    /// The passivity layer, after the ladder (crate::passivity; observing only until a run
    /// configures it).
    pub passivity: crate::passivity::PassivityController,
}

impl<B: Board> Rig<B> {
    pub fn new(
        mut board: B,
        params: LoopParams,
        mut experiment: Experiment,
        feature_params: FeatureParams,
    ) -> Result<Self, StartFailed> {
        // The board's lifecycle: configure (open, channels, 0 A) before the experiment's
        // start, which may wait for a server (seconds): whatever the DAC held before this
        // process must not stay on the motor meanwhile. Activation (the hardware watchdog
        // armed, the encoder zeroed) waits until the loop is about to step ([`Rig::activate`]):
        // a real card's watchdog of a few periods would trip during any wait before it.
        if let Err(error) = board.configure() {
            board.shutdown();
            return Err(StartFailed {
                error,
                experiment: Box::new(experiment),
            });
        }
        experiment.begin();
        Ok(Rig {
            est: Estimator::new(&params),
            features: FeatureExtractor::new(feature_params),
            board,
            params,
            experiment,
            step: 0,
            t_prev_us: 0,
            time: 0.0,
            i_motor: 0.0,
            started: false,
            period: 1e-4,
            long_steps: 0,
            max_dt: 0.0,
            passivity: crate::passivity::PassivityController::off(),
            fault: None,
            finished: false,
            activated: false,
            activate_error: None,
        })
    }

    /// Activates the board (arms its watchdog, zeroes its encoder) if not done yet: call it
    /// right before the first step, after every wait. The first [`Rig::step`] does it itself
    /// when the caller did not.
    pub fn activate(&mut self) -> Result<(), BoardError> {
        if self.activated {
            return Ok(());
        }
        self.activated = true;
        self.board.activate(self.params.watchdog_us)
    }

    /// Why activating the board on the first step failed (that step stopped the run).
    pub fn activate_error(&self) -> Option<&BoardError> {
        self.activate_error.as_ref()
    }

    /// The board failure that ended the run (`None` when none did).
    pub fn fault(&self) -> Option<&'static str> {
        self.fault
    }

    /// The board's non-fatal counters (FIFO overflows, quadrature errors, ...).
    pub fn board_health(&self) -> BoardHealth {
        self.board.health()
    }

    /// The run is over: 0 A, watchdog off, board closed (once; off the real-time path).
    pub fn finish(&mut self) {
        if !self.finished {
            self.finished = true;
            self.i_motor = 0.0;
            self.board.deactivate();
            self.board.shutdown();
        }
    }

    /// A step's read, write or kick failed: 0 A and safe mode at once, the reason kept.
    /// REAL-TIME PATH: no allocation (static message).
    #[cold]
    fn board_failed(&mut self, stop: BoardStop) -> Stop {
        self.i_motor = 0.0;
        match stop {
            BoardStop::EndOfData => {
                self.safe_stop();
                Stop::Finished
            }
            BoardStop::Fault(m) => {
                self.fault = Some(m);
                self.board.on_error(m);
                Stop::BoardFault(m)
            }
            BoardStop::Gone(m) => {
                self.fault = Some(m);
                self.board.on_error(m);
                Stop::BoardGone(m)
            }
        }
    }

    /// The nominal period (1 / rate), for the stall detection.
    pub fn set_period(&mut self, period_s: f64) {
        self.period = period_s;
    }

    /// Steps longer than [`LONG_STEP_FACTOR`] periods so far.
    pub fn long_steps(&self) -> u64 {
        self.long_steps
    }

    /// The longest step so far, s.
    pub fn max_dt(&self) -> f64 {
        self.max_dt
    }

    pub fn steps(&self) -> u64 {
        self.step
    }

    /// Commands zero current (used on every stop). A board that refuses even this is put
    /// into its safe mode (which holds 0 A by itself).
    pub fn safe_stop(&mut self) {
        self.i_motor = 0.0;
        if let Err(e) = self.board.write(32768) {
            self.fault.get_or_insert(e.reason());
            self.board.on_error(e.reason());
        }
    }

    /// One control step. On `Err` the current has already been set to zero.
    #[inline]
    pub fn step(&mut self) -> Result<Row, Stop> {
        if !self.activated {
            // once, before the first read (the allocation of a failure's message is off the
            // steady state: the run ends here)
            if let Err(e) = self.activate() {
                self.activate_error = Some(e);
                return Err(self.board_failed(BoardStop::Fault("the board could not be activated")));
            }
        }
        let snap = match self.board.read() {
            Ok(s) => s,
            Err(e) => return Err(self.board_failed(e)),
        };
        if self.board.watchdog_tripped() {
            self.safe_stop();
            return Err(Stop::Watchdog);
        }
        let p = &self.params;
        // dt from the wrapping 32-bit microsecond counter: wrapping_sub is right across a wrap.
        let dt = if self.started {
            snap.timestamp_us.wrapping_sub(self.t_prev_us) as f64 * 1e-6
        } else {
            0.0
        };
        self.started = true;
        self.t_prev_us = snap.timestamp_us;
        self.time += dt;
        let long_dt = LONG_STEP_FACTOR * self.period;
        if dt > long_dt {
            // a stall (preemption, page fault, a stuck board read): the filters bound their
            // update by themselves; counted here
            self.long_steps += 1;
        }
        if dt > self.max_dt {
            self.max_dt = dt;
        }
        let x = snap.counts as f64 * p.meters_per_count;
        // Observers use the current applied during the period that just ended.
        let est = self.est.update(x, dt, self.i_motor);
        let feats = self.features.begin(est.x, est.v, est.a);
        if x.abs() >= p.position_limit {
            self.safe_stop();
            return Err(Stop::PositionLimit);
        }
        let d = self.experiment.decide(self.step, self.time, &est, &feats);
        // The identified friction model (params.friction) is subtracted on the object's side of
        // the stroke (x > 0, where the probe can touch it) and under position control. A free
        // probe with its friction compensated and nothing pushing it would coast on without
        // bound (force control toward 0 N holds no position), so on the free side the bench's
        // own friction stops it. Takes effect from the next step's observer update; the same
        // rule in every experiment (abstraction, shadow, reproduction).
        self.est.friction_active = match d.command {
            Command::Force(_) => est.x > 0.0,
            Command::Position(_) => true,
            Command::Done => false,
        };
        let (f_ref, i_ref) = match d.command {
            Command::Force(f_cmd) => {
                // the passivity layer, on the steps that render an object (F_cmd = -F)
                let f_cmd = match d.phase {
                    Phase::Reproduction => -self.passivity.render(-f_cmd, est.x, dt),
                    _ => f_cmd,
                };
                let i_ref = p.k_p * (f_cmd - est.f_ext) * p.m_n / p.k_fn;
                (f_cmd, i_ref + est.f_dis / p.k_fn)
            }
            Command::Position(x_ref) => match &mut self.experiment {
                Experiment::PositionReplay { pid, .. } => {
                    (f64::NAN, pid.current(x_ref, dt.min(long_dt), &est, p))
                }
                _ => (f64::NAN, 0.0),
            },
            Command::Done => {
                self.safe_stop();
                return Err(Stop::Finished);
            }
        };
        // Never beyond the clamp; a NaN command becomes 0 A.
        let i_cmd = if i_ref.is_nan() {
            0.0
        } else {
            i_ref.clamp(-p.current_limit, p.current_limit)
        };
        let mut word = dac::current_to_word(i_cmd, p.dac_full_scale);
        // Rounding to the nearest DAC code may land one code beyond the clamp: step back.
        if dac::word_to_current(word, p.dac_full_scale).abs() > p.current_limit {
            word = if word > 32768 { word - 1 } else { word + 1 };
        }
        self.i_motor = dac::word_to_current(word, p.dac_full_scale);
        // A refused write or kick is handled on this step: 0 A, safe mode, the reason kept.
        if let Err(e) = self.board.write(word) {
            return Err(self.board_failed(e));
        }
        if let Err(e) = self.board.kick() {
            return Err(self.board_failed(e));
        }
        self.features.commit(est.x, d.feature_force);
        let row = Row {
            step: self.step,
            timestamp: snap.timestamp_us,
            time: self.time,
            dt,
            f_ref,
            rtob_force: est.f_ext,
            dob_force: est.f_dis,
            counts: snap.counts,
            position_x: x,
            velocity: est.v,
            acceleration: est.a,
            i_a_ref: i_ref,
            i_motor: self.i_motor,
            analog_out_motor: word,
            phase: d.phase as u8,
            f_true: self.board.true_force(),
            f_pred: d.f_pred,
            fallback: d.fallback,
            cycle_no: feats.cycle_no,
            f_previous_x: feats.f_previous_x,
            f_previous_v: feats.f_previous_v,
            f_previous_a: feats.f_previous_a,
            deformation: feats.deformation,
            area_fx: feats.area_fx,
            f_object: self.board.object_force(),
            run_id: 0,
            model_id: d.model_id,
            f_previous: feats.f_previous,
        };
        debug_assert!(d.phase != Phase::Done);
        self.step += 1;
        Ok(row)
    }
}
