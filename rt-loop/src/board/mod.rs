//! The board: what the loop talks to. A real data-acquisition card (the thesis used a
//! Sensoray 826) implements the same trait; the loop never knows which board it drives.
//!
//! Every method is called on the loop thread once per step and must not allocate, lock,
//! block or do file I/O (a real board's register reads/writes are the only allowed syscalls).

pub mod replay;
pub mod sim;

/// What the board latched at the start of a step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Snapshot {
    /// Quadrature x4 encoder count (positive into the object).
    pub counts: i32,
    /// Board counter snapshot, microseconds, wrapping at 2^32.
    pub timestamp_us: u32,
}

/// Why a board could not give a snapshot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BoardStop {
    /// A replayed recording has no more samples: the run ends normally.
    EndOfData,
    /// The hardware (or its simulation) failed; the message is static so reporting it never
    /// allocates on the loop thread.
    Fault(&'static str),
}

pub trait Board {
    /// Latches the encoder count and the timestamp. The simulated board advances its physics
    /// up to this instant first.
    fn snapshot(&mut self) -> Result<Snapshot, BoardStop>;
    /// Writes the 16-bit DAC word of the current amplifier (32768 = 0 A).
    fn write_dac(&mut self, word: u16);
    /// Arms the hardware watchdog: if it is not kicked within `timeout_us`, the board forces
    /// the DAC to 0 A by itself.
    fn arm_watchdog(&mut self, timeout_us: u32);
    fn kick_watchdog(&mut self);
    /// Ground truth for the recording: the true contact force on the probe (N, in the RFOB's
    /// sign: positive = the contact pushes the probe back). NaN on a real board.
    fn true_force(&self) -> f64 {
        f64::NAN
    }
    /// Whether the watchdog has fired since it was armed.
    fn watchdog_tripped(&self) -> bool {
        false
    }
    fn name(&self) -> &'static str;
}

impl<B: Board + ?Sized> Board for Box<B> {
    fn snapshot(&mut self) -> Result<Snapshot, BoardStop> {
        (**self).snapshot()
    }
    fn write_dac(&mut self, word: u16) {
        (**self).write_dac(word)
    }
    fn arm_watchdog(&mut self, timeout_us: u32) {
        (**self).arm_watchdog(timeout_us)
    }
    fn kick_watchdog(&mut self) {
        (**self).kick_watchdog()
    }
    fn true_force(&self) -> f64 {
        (**self).true_force()
    }
    fn watchdog_tripped(&self) -> bool {
        (**self).watchdog_tripped()
    }
    fn name(&self) -> &'static str {
        (**self).name()
    }
}
