//! The Sensoray 826 SDK's C interface as `826api.h` declares it (Linux: `lib826_64.so`, the C
//! calling convention; `uint` is a 32-bit `unsigned int`): the function types this driver
//! calls, the constants it uses, and every `S826_ERR_*` code as a typed error that names it.
//! Written from the header's declarations (signatures and values only).

use std::os::raw::{c_int, c_uint};

// ---- functions (one type per signature in 826api.h) ----
/// `int S826_SystemOpen(void)`: a bit mask of the boards found (bit N = board N), or an error.
pub type SystemOpenFn = unsafe extern "C" fn() -> c_int;
/// `int S826_SystemClose(void)`.
pub type SystemCloseFn = unsafe extern "C" fn() -> c_int;
/// `int S826_VersionRead(uint board, uint *api, uint *driver, uint *bdrev, uint *fpgarev)`.
pub type VersionReadFn =
    unsafe extern "C" fn(c_uint, *mut c_uint, *mut c_uint, *mut c_uint, *mut c_uint) -> c_int;
/// `int S826_CounterModeWrite(uint board, uint chan, uint mode)`.
pub type CounterModeWriteFn = unsafe extern "C" fn(c_uint, c_uint, c_uint) -> c_int;
/// `int S826_CounterStateWrite(uint board, uint chan, uint run)`.
pub type CounterStateWriteFn = unsafe extern "C" fn(c_uint, c_uint, c_uint) -> c_int;
/// `int S826_CounterSnapshotConfigWrite(uint board, uint chan, uint ctrl, uint mode)`.
pub type CounterSnapshotConfigWriteFn =
    unsafe extern "C" fn(c_uint, c_uint, c_uint, c_uint) -> c_int;
/// `int S826_CounterSnapshot(uint board, uint chan)`.
pub type CounterSnapshotFn = unsafe extern "C" fn(c_uint, c_uint) -> c_int;
/// `int S826_CounterSnapshotRead(uint board, uint chan, uint *value, uint *tstamp,
/// uint *reason, uint tmax)`.
pub type CounterSnapshotReadFn =
    unsafe extern "C" fn(c_uint, c_uint, *mut c_uint, *mut c_uint, *mut c_uint, c_uint) -> c_int;
/// `int S826_CounterPreloadWrite(uint board, uint chan, uint reg, uint counts)`.
pub type CounterPreloadWriteFn = unsafe extern "C" fn(c_uint, c_uint, c_uint, c_uint) -> c_int;
/// `int S826_CounterPreload(uint board, uint chan, uint level, uint sticky)`.
pub type CounterPreloadFn = unsafe extern "C" fn(c_uint, c_uint, c_uint, c_uint) -> c_int;
/// `int S826_DacRangeWrite(uint board, uint chan, uint range, uint safemode)`.
pub type DacRangeWriteFn = unsafe extern "C" fn(c_uint, c_uint, c_uint, c_uint) -> c_int;
/// `int S826_DacDataWrite(uint board, uint chan, uint setpoint, uint safemode)`.
pub type DacDataWriteFn = unsafe extern "C" fn(c_uint, c_uint, c_uint, c_uint) -> c_int;
/// `int S826_SafeWrenWrite(uint board, uint enable)`.
pub type SafeWrenWriteFn = unsafe extern "C" fn(c_uint, c_uint) -> c_int;
/// `int S826_SafeControlWrite(uint board, uint settings, uint mode)`.
pub type SafeControlWriteFn = unsafe extern "C" fn(c_uint, c_uint, c_uint) -> c_int;
/// `int S826_SafeControlRead(uint board, uint *settings)`.
pub type SafeControlReadFn = unsafe extern "C" fn(c_uint, *mut c_uint) -> c_int;
/// `int S826_WatchdogConfigWrite(uint board, uint config, uint timers[5])`.
pub type WatchdogConfigWriteFn = unsafe extern "C" fn(c_uint, c_uint, *mut c_uint) -> c_int;
/// `int S826_WatchdogEnableWrite(uint board, uint enable)`.
pub type WatchdogEnableWriteFn = unsafe extern "C" fn(c_uint, c_uint) -> c_int;
/// `int S826_WatchdogKick(uint board, uint data)`.
pub type WatchdogKickFn = unsafe extern "C" fn(c_uint, c_uint) -> c_int;
/// `int S826_WatchdogEventWait(uint board, uint tmax)`.
pub type WatchdogEventWaitFn = unsafe extern "C" fn(c_uint, c_uint) -> c_int;

// ---- constants ----
/// Boards one system supports (board numbers 0..15).
pub const MAX_BOARDS: u32 = 16;
/// Counter channels.
pub const NUM_COUNT: u32 = 6;
/// Analog output channels.
pub const NUM_DAC: u32 = 8;
/// DAC range code: -10 V to +10 V.
pub const DAC_SPAN_10_10: u32 = 3;
/// Counter clock mode: quadrature x4 (ClkA and ClkB).
pub const CM_K_QUADX4: u32 = 7 << 4;
/// Snapshot reason bit: quadrature error.
pub const SSRMASK_QUADERR: u32 = 1 << 8;
/// Snapshot reason bit: soft snapshot.
pub const SSRMASK_SOFT: u32 = 1 << 7;
/// Register write mode: all bits; clear the designated bits; set them.
pub const BITWRITE: u32 = 0;
pub const BITCLR: u32 = 1;
pub const BITSET: u32 = 2;
/// Safe-control bit: safe mode active.
pub const CONFIG_SAF: u32 = 1 << 1;
/// Watchdog configuration bit: activate safe mode upon timer0 timeout.
pub const WD_SEN: u32 = 1 << 4;
/// Index of timer0's interval in the watchdog timers array (20 ns resolution).
pub const WD_DELAY0: usize = 0;
/// Watchdog timer ticks per microsecond (50 MHz).
pub const WD_TICKS_PER_US: u32 = 50;
/// Safe-mode register write enable: set / clear.
pub const SAFEN_SWE: u32 = 1 << 1;
pub const SAFEN_SWD: u32 = 1 << 0;
/// The value `S826_WatchdogKick` must be given for a kick to count.
pub const WATCHDOG_KICK: u32 = 0x5A55_AA5A;
/// `tmax` for "do not wait".
pub const NO_WAIT: u32 = 0;
/// `tmax` for "wait forever".
pub const WAIT_INFINITE: u32 = 0xFFFF_FFFF;
/// DAC setpoint of 0 V in the +/-10 V range (16-bit, offset binary).
pub const DAC_ZERO: u32 = 0x8000;
/// Largest DAC setpoint.
pub const DAC_MAX: u32 = 0xFFFF;

// ---- error codes ----
pub const ERR_OK: c_int = 0;
pub const ERR_BOARD: c_int = -1;
pub const ERR_VALUE: c_int = -2;
pub const ERR_NOTREADY: c_int = -3;
pub const ERR_CANCELLED: c_int = -4;
pub const ERR_DRIVER: c_int = -5;
pub const ERR_MISSEDTRIG: c_int = -6;
pub const ERR_DUPADDR: c_int = -9;
pub const ERR_BOARDCLOSED: c_int = -10;
pub const ERR_CREATEMUTEX: c_int = -11;
pub const ERR_MEMORYMAP: c_int = -12;
pub const ERR_MALLOC: c_int = -13;
pub const ERR_FIFOOVERFLOW: c_int = -15;
pub const ERR_LOCALBUS: c_int = -16;
/// Port-specific errors are this base minus the OS's code.
pub const ERR_OSSPECIFIC: c_int = -100;

/// Every error an 826 call returns, by its name in `826api.h`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum S826Code {
    #[error("S826_ERR_BOARD (illegal board number)")]
    Board,
    #[error("S826_ERR_VALUE (illegal argument value)")]
    Value,
    #[error("S826_ERR_NOTREADY (device not ready, or timeout waiting for it)")]
    NotReady,
    #[error("S826_ERR_CANCELLED (wait cancelled)")]
    Cancelled,
    #[error("S826_ERR_DRIVER (driver call failed)")]
    Driver,
    #[error("S826_ERR_MISSEDTRIG (missed ADC trigger)")]
    MissedTrig,
    #[error("S826_ERR_DUPADDR (two boards set to the same board number)")]
    DupAddr,
    #[error("S826_ERR_BOARDCLOSED (board is not open)")]
    BoardClosed,
    #[error("S826_ERR_CREATEMUTEX (cannot create a mutex)")]
    CreateMutex,
    #[error("S826_ERR_MEMORYMAP (cannot map the board to memory)")]
    MemoryMap,
    #[error("S826_ERR_MALLOC (cannot allocate memory)")]
    Malloc,
    #[error("S826_ERR_FIFOOVERFLOW (the counter's snapshot FIFO overflowed)")]
    FifoOverflow,
    #[error("S826_ERR_LOCALBUS (cannot read the local bus: register holds an illegal value)")]
    LocalBus,
    #[error("S826_ERR_OSSPECIFIC - {0} (operating-system error {0})")]
    OsSpecific(i32),
    #[error("unknown 826 error code {0}")]
    Unknown(i32),
}

impl S826Code {
    /// The code's error, `None` for `S826_ERR_OK` (and, for `S826_SystemOpen`, any
    /// non-negative value, which is its board mask).
    pub fn of(rc: c_int) -> Option<S826Code> {
        Some(match rc {
            ERR_OK => return None,
            ERR_BOARD => S826Code::Board,
            ERR_VALUE => S826Code::Value,
            ERR_NOTREADY => S826Code::NotReady,
            ERR_CANCELLED => S826Code::Cancelled,
            ERR_DRIVER => S826Code::Driver,
            ERR_MISSEDTRIG => S826Code::MissedTrig,
            ERR_DUPADDR => S826Code::DupAddr,
            ERR_BOARDCLOSED => S826Code::BoardClosed,
            ERR_CREATEMUTEX => S826Code::CreateMutex,
            ERR_MEMORYMAP => S826Code::MemoryMap,
            ERR_MALLOC => S826Code::Malloc,
            ERR_FIFOOVERFLOW => S826Code::FifoOverflow,
            ERR_LOCALBUS => S826Code::LocalBus,
            rc if rc <= ERR_OSSPECIFIC => S826Code::OsSpecific(ERR_OSSPECIFIC - rc),
            rc => S826Code::Unknown(rc),
        })
    }

    /// Whether the code means the board is gone (closed, unreachable, its driver failing)
    /// rather than one refused operation.
    pub fn board_gone(self) -> bool {
        matches!(
            self,
            S826Code::Board
                | S826Code::Driver
                | S826Code::BoardClosed
                | S826Code::LocalBus
                | S826Code::MemoryMap
                | S826Code::OsSpecific(_)
        )
    }
}

/// An 826 call that failed: which call, and the code it returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{call} returned {code}")]
pub struct S826Error {
    pub call: &'static str,
    pub code: S826Code,
}

/// `Ok` for `S826_ERR_OK`, else the call's typed error.
#[inline]
pub fn check(call: &'static str, rc: c_int) -> Result<(), S826Error> {
    match S826Code::of(rc) {
        None => Ok(()),
        Some(code) => Err(S826Error { call, code }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_names_itself() {
        let all = [
            (ERR_BOARD, "S826_ERR_BOARD"),
            (ERR_VALUE, "S826_ERR_VALUE"),
            (ERR_NOTREADY, "S826_ERR_NOTREADY"),
            (ERR_CANCELLED, "S826_ERR_CANCELLED"),
            (ERR_DRIVER, "S826_ERR_DRIVER"),
            (ERR_MISSEDTRIG, "S826_ERR_MISSEDTRIG"),
            (ERR_DUPADDR, "S826_ERR_DUPADDR"),
            (ERR_BOARDCLOSED, "S826_ERR_BOARDCLOSED"),
            (ERR_CREATEMUTEX, "S826_ERR_CREATEMUTEX"),
            (ERR_MEMORYMAP, "S826_ERR_MEMORYMAP"),
            (ERR_MALLOC, "S826_ERR_MALLOC"),
            (ERR_FIFOOVERFLOW, "S826_ERR_FIFOOVERFLOW"),
            (ERR_LOCALBUS, "S826_ERR_LOCALBUS"),
            (ERR_OSSPECIFIC - 2, "S826_ERR_OSSPECIFIC - 2"),
        ];
        for (rc, name) in all {
            let e = check("S826_X", rc).unwrap_err();
            assert!(
                e.to_string()
                    .starts_with(&format!("S826_X returned {name}")),
                "{e}"
            );
        }
        assert!(check("S826_X", ERR_OK).is_ok());
        assert_eq!(S826Code::of(-7), Some(S826Code::Unknown(-7)));
        assert!(S826Code::BoardClosed.board_gone() && !S826Code::NotReady.board_gone());
    }
}
