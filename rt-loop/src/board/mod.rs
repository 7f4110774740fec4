//! The board: what the loop talks to. The loop never knows which board it drives: the
//! simulated bench ([`sim`]), a recording played back ([`replay`]) or a Sensoray 826 card
//! ([`s826`], its vendor library loaded at run time). A new board is a new folder beside these
//! implementing [`Board`], plus one arm in [`crate::run::build_board`].
//!
//! # Lifecycle (in the spirit of ros2_control's hardware interface)
//!
//! ```text
//!  configure ──> activate ──> read / write / kick each step ──> deactivate ──> shutdown
//!  (open, versions,  (arm the watchdog,        │ any Err                       (close)
//!   channels, 0 A)    zero the encoder)        v
//!                                           on_error (0 A, safe mode; the reason counted)
//! ```
//!
//! [`Board::configure`] and [`Board::activate`] run before the loop starts and may allocate;
//! their errors are typed ([`BoardError`]). [`Board::read`], [`Board::write`] and
//! [`Board::kick`] are called on the loop thread once per step: REAL-TIME PATH, they must not
//! allocate, lock, block or do file I/O (a real board's register access is the only allowed
//! syscall), and their failures carry static messages ([`BoardStop`]) so that reporting one
//! never allocates. A failure is handled on the step it happens: the loop calls
//! [`Board::on_error`] (0 A, safe mode) at once and ends the run with the reason, which the
//! status block, gRPC, the page and `/metrics` count and show.

pub mod replay;
pub mod rig_file;
pub mod s826;
pub mod sim;

/// What the board latched at the start of a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Snapshot {
    /// Quadrature x4 encoder count (positive into the object).
    pub counts: i32,
    /// Board counter snapshot, microseconds, wrapping at 2^32.
    pub timestamp_us: u32,
}

/// Why a board could not go on (a step's read, write or kick). Static messages: reporting one
/// never allocates on the loop thread.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoardStop {
    /// A replayed recording has no more samples: the run ends normally.
    EndOfData,
    /// The hardware (or its simulation) failed on this step.
    Fault(&'static str),
    /// The board is gone (unplugged, its driver unloaded, its library says it is closed):
    /// nothing more can be written to it; the amplifier is left to the board's safe mode.
    Gone(&'static str),
}

impl BoardStop {
    /// The reason as shown in status and summaries ("" for the end of data).
    pub fn reason(&self) -> &'static str {
        match self {
            BoardStop::EndOfData => "",
            BoardStop::Fault(m) | BoardStop::Gone(m) => m,
        }
    }
}

/// Why a board could not be configured or activated (before the loop runs: these may
/// allocate). The message names what failed and what to do.
#[derive(Debug, thiserror::Error)]
pub enum BoardError {
    /// What the board needs is not on this machine (its vendor library, the card itself).
    #[error("{0}")]
    Missing(String),
    /// The board refused a set-up step.
    #[error("{step}: {why}")]
    Refused { step: &'static str, why: String },
}

/// Counters a board keeps of what went wrong without stopping the loop (a real card's FIFO
/// overflows and quadrature errors), read off the step about every 100 ms.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct BoardHealth {
    /// Snapshots the board's FIFO lost (S826_ERR_FIFOOVERFLOW): counted, not fatal.
    pub fifo_overflows: u64,
    /// Snapshots that came with a quadrature error flag: counted, not fatal.
    pub quadrature_errors: u64,
    /// Reads that found the FIFO empty and were retried within the step.
    pub not_ready: u64,
    /// Board timestamp wraps seen (every 71.6 min on a real card).
    pub timestamp_wraps: u64,
}

pub trait Board {
    /// Opens the board, checks its versions, sets up its channels and commands 0 A. Before
    /// the loop; may allocate.
    fn configure(&mut self) -> Result<(), BoardError>;
    /// Arms the hardware watchdog (`timeout_us`: if not kicked within it, the board forces 0 A
    /// by itself) and zeroes or references the encoder. Before the loop.
    fn activate(&mut self, watchdog_us: u32) -> Result<(), BoardError>;
    /// Latches the encoder count and the timestamp. The simulated board advances its physics
    /// up to this instant first. REAL-TIME PATH.
    fn read(&mut self) -> Result<Snapshot, BoardStop>;
    /// Writes the loop's 16-bit current word (32768 = 0 A; `crate::control::dac`). REAL-TIME PATH.
    fn write(&mut self, word: u16) -> Result<(), BoardStop>;
    /// Kicks the hardware watchdog. REAL-TIME PATH.
    fn kick(&mut self) -> Result<(), BoardStop>;
    /// 0 A, watchdog off: the run is over. Never fails (best effort on a board that is gone).
    fn deactivate(&mut self);
    /// A step failed: 0 A at once and the board into its safe mode (best effort; on the loop
    /// thread: no allocation).
    fn on_error(&mut self, reason: &'static str);
    /// Closes the board. Idempotent.
    fn shutdown(&mut self);
    /// What went wrong without stopping the loop, so far.
    fn health(&self) -> BoardHealth {
        BoardHealth::default()
    }
    /// Ground truth for the recording's `F_true`: the felt force, what pushes the probe from
    /// outside (N, in the RFOB's sign: positive = the contact pushes the probe back). With the
    /// simulated hand it is the hand's force, which also carries the bench's friction and the
    /// motor's mass dynamics; without one, the object's. NaN on a real board.
    fn true_force(&self) -> f64 {
        f64::NAN
    }
    /// Ground truth for the recording's `F_object`: the simulated object's own force on the
    /// probe (N, same sign), whatever its law and whoever presses; what an object-only model
    /// predicts. NaN where there is no object of the bench's own (a real board, reproduction's
    /// virtual object, a recording without the column). REAL-TIME PATH: a field read.
    fn object_force(&self) -> f64 {
        f64::NAN
    }
    /// Whether the watchdog has fired since it was armed.
    fn watchdog_tripped(&self) -> bool {
        false
    }
    fn name(&self) -> &'static str;
}

impl<B: Board + ?Sized> Board for Box<B> {
    fn configure(&mut self) -> Result<(), BoardError> {
        (**self).configure()
    }
    fn activate(&mut self, watchdog_us: u32) -> Result<(), BoardError> {
        (**self).activate(watchdog_us)
    }
    #[inline]
    fn read(&mut self) -> Result<Snapshot, BoardStop> {
        (**self).read()
    }
    #[inline]
    fn write(&mut self, word: u16) -> Result<(), BoardStop> {
        (**self).write(word)
    }
    #[inline]
    fn kick(&mut self) -> Result<(), BoardStop> {
        (**self).kick()
    }
    fn deactivate(&mut self) {
        (**self).deactivate()
    }
    fn on_error(&mut self, reason: &'static str) {
        (**self).on_error(reason)
    }
    fn shutdown(&mut self) {
        (**self).shutdown()
    }
    fn health(&self) -> BoardHealth {
        (**self).health()
    }
    fn true_force(&self) -> f64 {
        (**self).true_force()
    }
    fn object_force(&self) -> f64 {
        (**self).object_force()
    }
    fn watchdog_tripped(&self) -> bool {
        (**self).watchdog_tripped()
    }
    fn name(&self) -> &'static str {
        (**self).name()
    }
}

/// For a board that wraps another (tests' instrumented boards): forwards the lifecycle's
/// non-step methods (`configure`, `activate`, `deactivate`, `on_error`, `shutdown`, `health`,
/// `true_force`, `object_force`, `watchdog_tripped`) to the field named; the wrapper writes `read`, `write`,
/// `kick` and `name` itself.
#[macro_export]
macro_rules! forward_board_lifecycle {
    ($inner:ident) => {
        fn configure(&mut self) -> Result<(), $crate::board::BoardError> {
            self.$inner.configure()
        }
        fn activate(&mut self, watchdog_us: u32) -> Result<(), $crate::board::BoardError> {
            self.$inner.activate(watchdog_us)
        }
        fn deactivate(&mut self) {
            self.$inner.deactivate()
        }
        fn on_error(&mut self, reason: &'static str) {
            self.$inner.on_error(reason)
        }
        fn shutdown(&mut self) {
            self.$inner.shutdown()
        }
        fn health(&self) -> $crate::board::BoardHealth {
            self.$inner.health()
        }
        fn true_force(&self) -> f64 {
            self.$inner.true_force()
        }
        fn object_force(&self) -> f64 {
            self.$inner.object_force()
        }
        fn watchdog_tripped(&self) -> bool {
            self.$inner.watchdog_tripped()
        }
    };
}
