//! The 826 as a [`Board`]: configure opens the card, reads its versions, programs the
//! safe-mode DAC value to 0 A and sets the counter to quadrature x4 with soft snapshots only;
//! activate zeroes the counter and arms the hardware watchdog (it puts the card into safe mode,
//! 0 A, by itself when the loop stops kicking it); each step reads the count and the card's
//! 32-bit microsecond timestamp together from one soft snapshot, writes the DAC, kicks the
//! watchdog. Safe mode, once entered, is left only by an explicit action
//! ([`S826Board::clear_safe_mode`], `rt-loop board clear-safe-mode`).
//!
//! REAL-TIME PATH: `read`, `write` and `kick` call the library through function pointers
//! resolved at load, allocate nothing and report failures with static messages.

use super::api::*;
use super::library::S826Lib;
use super::S826Config;
use crate::board::{Board, BoardError, BoardHealth, BoardStop, Snapshot};
use crate::control::dac;
use std::os::raw::c_uint;

/// The card's versions (`S826_VersionRead`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Versions {
    pub api: u32,
    pub driver: u32,
    pub board: u32,
    pub fpga: u32,
}

impl std::fmt::Display for Versions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // 826api.h packs versions as major.minor.build in the high/low bytes
        let v = |x: u32| format!("{}.{}.{}", x >> 24, (x >> 16) & 0xFF, x & 0xFFFF);
        write!(
            f,
            "api {} driver {} board rev {} fpga {}",
            v(self.api),
            v(self.driver),
            self.board,
            v(self.fpga)
        )
    }
}

/// Static messages for a step's failed call, one per code (nothing is formatted on the loop
/// thread).
macro_rules! code_messages {
    ($name:ident, $call:literal) => {
        fn $name(code: S826Code) -> &'static str {
            match code {
                S826Code::Board => concat!($call, " returned S826_ERR_BOARD"),
                S826Code::Value => concat!($call, " returned S826_ERR_VALUE"),
                S826Code::NotReady => concat!($call, " returned S826_ERR_NOTREADY"),
                S826Code::Cancelled => concat!($call, " returned S826_ERR_CANCELLED"),
                S826Code::Driver => concat!($call, " returned S826_ERR_DRIVER: board gone?"),
                S826Code::MissedTrig => concat!($call, " returned S826_ERR_MISSEDTRIG"),
                S826Code::DupAddr => concat!($call, " returned S826_ERR_DUPADDR"),
                S826Code::BoardClosed => concat!($call, " returned S826_ERR_BOARDCLOSED"),
                S826Code::CreateMutex => concat!($call, " returned S826_ERR_CREATEMUTEX"),
                S826Code::MemoryMap => concat!($call, " returned S826_ERR_MEMORYMAP"),
                S826Code::Malloc => concat!($call, " returned S826_ERR_MALLOC"),
                S826Code::FifoOverflow => concat!($call, " returned S826_ERR_FIFOOVERFLOW"),
                S826Code::LocalBus => concat!($call, " returned S826_ERR_LOCALBUS: board gone?"),
                S826Code::OsSpecific(_) => concat!($call, " returned S826_ERR_OSSPECIFIC"),
                S826Code::Unknown(_) => concat!($call, " returned an unknown 826 error"),
            }
        }
    };
}
code_messages!(snapshot_msg, "S826_CounterSnapshot");
code_messages!(snapshot_read_msg, "S826_CounterSnapshotRead");
code_messages!(dac_msg, "S826_DacDataWrite");
code_messages!(kick_msg, "S826_WatchdogKick");
code_messages!(safe_read_msg, "S826_SafeControlRead");

/// The stop a failed step call means: the board gone, or one refused operation.
#[inline]
fn stop(code: S826Code, msg: fn(S826Code) -> &'static str) -> BoardStop {
    if code.board_gone() {
        BoardStop::Gone(msg(code))
    } else {
        BoardStop::Fault(msg(code))
    }
}

/// The reason the loop stops when the card's watchdog tripped under it.
pub const WATCHDOG_TRIPPED: &str = "the hardware watchdog tripped (the loop stalled past it): \
the board is in safe mode at 0 A; clear it with `rt-loop board clear-safe-mode`";
/// The reason the loop stops when soft snapshots stop arriving.
pub const SNAPSHOT_NOT_READY: &str =
    "the encoder snapshot never arrived: S826_CounterSnapshotRead returned S826_ERR_NOTREADY";

/// The +/-10 V DAC's code for `volts` (offset binary, 0x8000 = 0 V), clamped to the range.
#[inline]
pub fn volts_to_code(volts: f64) -> u32 {
    if volts.is_nan() {
        return DAC_ZERO;
    }
    let code = DAC_ZERO as f64 + (volts.clamp(-10.0, 10.0) / 10.0 * 32768.0).round();
    code.clamp(0.0, DAC_MAX as f64) as u32
}

/// The volts a code makes.
#[inline]
pub fn code_to_volts(code: u32) -> f64 {
    (code as f64 - DAC_ZERO as f64) / 32768.0 * 10.0
}

pub struct S826Board {
    lib: S826Lib,
    board: u32,
    cfg: S826Config,
    /// The motor's current limit, A: the DAC never commands more, whatever the word says.
    current_limit: f64,
    /// Full scale of the loop's current words (`crate::control::dac`), A.
    dac_full_scale: f64,
    watchdog_us: u32,
    open: bool,
    active: bool,
    versions: Option<Versions>,
    started: bool,
    raw_prev: u32,
    counts: i64,
    ts_prev: u32,
    ts_wraps: u64,
    health: BoardHealth,
    last_code: u32,
}

impl S826Board {
    /// Loads the library (nothing is opened until [`Board::configure`]).
    pub fn new(
        board: u32,
        cfg: S826Config,
        current_limit: f64,
        dac_full_scale: f64,
        rate_hz: f64,
    ) -> Result<S826Board, BoardError> {
        cfg.validate().map_err(|e| BoardError::Refused {
            step: "s826 settings",
            why: e.to_string(),
        })?;
        if board >= MAX_BOARDS {
            return Err(BoardError::Refused {
                step: "s826 settings",
                why: format!("board number {board}: the 826's switches set 0..15"),
            });
        }
        let lib = S826Lib::load(cfg.lib.as_deref())?;
        Ok(S826Board {
            lib,
            board,
            watchdog_us: cfg.watchdog_at(rate_hz),
            cfg,
            current_limit,
            dac_full_scale,
            open: false,
            active: false,
            versions: None,
            started: false,
            raw_prev: 0,
            counts: 0,
            ts_prev: 0,
            ts_wraps: 0,
            health: BoardHealth::default(),
            last_code: DAC_ZERO,
        })
    }

    /// The library's path.
    pub fn lib_path(&self) -> &str {
        &self.lib.path
    }

    /// What `S826_VersionRead` said at configure.
    pub fn versions(&self) -> Option<Versions> {
        self.versions
    }

    /// The watchdog timeout armed at activate, microseconds.
    pub fn watchdog_us(&self) -> u32 {
        self.watchdog_us
    }

    /// Sets the watchdog timeout the next [`Board::activate`] arms, microseconds.
    pub fn set_watchdog_us(&mut self, us: u32) {
        self.watchdog_us = us.max(1);
    }

    /// The DAC code last written in run mode.
    pub fn last_code(&self) -> u32 {
        self.last_code
    }

    /// The timestamp of the last snapshot, unwrapped (microseconds since the counter's 0).
    pub fn timestamp_unwrapped_us(&self) -> u64 {
        (self.ts_wraps << 32) | self.ts_prev as u64
    }

    /// The DAC code for a current, clamped to the motor's limit first (volts from the
    /// amplifier's A/V gain).
    #[inline]
    pub fn code_for(&self, amps: f64) -> u32 {
        let amps = if amps.is_nan() {
            0.0
        } else {
            amps.clamp(-self.current_limit, self.current_limit)
        };
        volts_to_code(amps / self.cfg.amps_per_volt)
    }

    fn call(&self, name: &'static str, rc: i32) -> Result<(), BoardError> {
        check(name, rc).map_err(|e| BoardError::Refused {
            step: name,
            why: format!("board {}: {e}", self.board),
        })
    }

    /// Whether the card is in safe mode (`S826_SafeControlRead`).
    pub fn safe_mode(&self) -> Result<bool, S826Error> {
        let mut s: c_uint = 0;
        // SAFETY: a valid out pointer; the signature is 826api.h's.
        check("S826_SafeControlRead", unsafe {
            (self.lib.safe_control_read)(self.board, &mut s)
        })?;
        Ok(s & CONFIG_SAF != 0)
    }

    /// Runs `f` with the safe-mode registers write-enabled (`S826_SafeWrenWrite`), disabling
    /// them again after whatever `f` returned.
    fn with_safe_write<T>(
        &self,
        f: impl FnOnce() -> Result<T, BoardError>,
    ) -> Result<T, BoardError> {
        // SAFETY: plain value arguments; signature from 826api.h.
        self.call("S826_SafeWrenWrite", unsafe {
            (self.lib.safe_wren_write)(self.board, SAFEN_SWE)
        })?;
        let r = f();
        // SAFETY: as above.
        let off = self.call("S826_SafeWrenWrite", unsafe {
            (self.lib.safe_wren_write)(self.board, SAFEN_SWD)
        });
        let v = r?;
        off?;
        Ok(v)
    }

    /// Leaves safe mode: the explicit action after a watchdog trip or a fault (`rt-loop board
    /// clear-safe-mode`). The board must be configured (open).
    pub fn clear_safe_mode(&mut self) -> Result<(), BoardError> {
        self.with_safe_write(|| {
            // SAFETY: plain values; signature from 826api.h.
            self.call("S826_SafeControlWrite", unsafe {
                (self.lib.safe_control_write)(self.board, CONFIG_SAF, BITCLR)
            })
        })
    }

    /// Opens the card without refusing safe mode (for clearing it).
    pub fn open(&mut self) -> Result<(), BoardError> {
        if self.open {
            return Ok(());
        }
        // SAFETY: no arguments; signature from 826api.h.
        let mask = unsafe { (self.lib.system_open)() };
        if mask < 0 {
            let code = S826Code::of(mask).unwrap_or(S826Code::Unknown(mask));
            let hint = if code == S826Code::DupAddr {
                ": two 826 boards are set to the same board number; change one board's switches"
            } else {
                ": is the s826 kernel module loaded and /dev/s826* readable? (docs/lab.md)"
            };
            return Err(BoardError::Missing(format!(
                "S826_SystemOpen returned {code}{hint}"
            )));
        }
        if mask == 0 {
            // SAFETY: as above.
            unsafe { (self.lib.system_close)() };
            return Err(BoardError::Missing(
                "no Sensoray 826 board found (S826_SystemOpen found none): is the card seated, \
                 its kernel driver loaded and /dev/s826* readable by this user? (docs/lab.md)"
                    .into(),
            ));
        }
        if mask & (1 << self.board) == 0 {
            let found: Vec<String> = (0..MAX_BOARDS)
                .filter(|n| mask & (1 << n) != 0)
                .map(|n| n.to_string())
                .collect();
            // SAFETY: as above.
            unsafe { (self.lib.system_close)() };
            return Err(BoardError::Missing(format!(
                "no 826 with board number {} (found: {}): pass --board s826:N with the number \
                 its switches set",
                self.board,
                found.join(", ")
            )));
        }
        self.open = true;
        let mut v = [0 as c_uint; 4];
        // SAFETY: four valid out pointers; signature from 826api.h.
        self.call("S826_VersionRead", unsafe {
            (self.lib.version_read)(self.board, &mut v[0], &mut v[1], &mut v[2], &mut v[3])
        })?;
        self.versions = Some(Versions {
            api: v[0],
            driver: v[1],
            board: v[2],
            fpga: v[3],
        });
        Ok(())
    }

    /// Waits up to `tmax_us` for the watchdog to fire (`S826_WatchdogEventWait`): `true` when
    /// it did.
    pub fn wait_watchdog(&self, tmax_us: u32) -> Result<bool, S826Error> {
        // SAFETY: plain values; signature from 826api.h.
        let rc = unsafe { (self.lib.watchdog_event_wait)(self.board, tmax_us) };
        match S826Code::of(rc) {
            None => Ok(true),
            Some(S826Code::NotReady) => Ok(false),
            Some(code) => Err(S826Error {
                call: "S826_WatchdogEventWait",
                code,
            }),
        }
    }

    /// Reads the FIFO until it is empty (stale snapshots from before activate).
    fn drain(&mut self) {
        let (mut v, mut t, mut r) = (0, 0, 0);
        for _ in 0..64 {
            // SAFETY: valid out pointers; signature from 826api.h.
            let rc = unsafe {
                (self.lib.counter_snapshot_read)(
                    self.board,
                    self.cfg.encoder_channel,
                    &mut v,
                    &mut t,
                    &mut r,
                    NO_WAIT,
                )
            };
            if rc != ERR_OK && rc != ERR_FIFOOVERFLOW {
                break;
            }
        }
    }

    /// Writes a run-mode DAC code; best effort (used on the way down).
    fn dac_zero_best_effort(&mut self) {
        if self.open {
            // SAFETY: plain values; signature from 826api.h.
            unsafe {
                (self.lib.dac_data_write)(self.board, self.cfg.dac_channel, DAC_ZERO, 0);
            }
            self.last_code = DAC_ZERO;
        }
    }
}

impl Board for S826Board {
    fn configure(&mut self) -> Result<(), BoardError> {
        self.open()?;
        let (b, ch, ech) = (self.board, self.cfg.dac_channel, self.cfg.encoder_channel);
        let safe = self.safe_mode().map_err(|e| BoardError::Refused {
            step: "configure",
            why: e.to_string(),
        })?;
        if safe {
            return Err(BoardError::Refused {
                step: "configure",
                why: format!(
                    "board {b} is in safe mode (its watchdog tripped or a fault put it there): \
                     the motor stays at 0 A until it is cleared explicitly with \
                     `rt-loop board clear-safe-mode --board s826:{b}` (docs/lab.md)"
                ),
            });
        }
        let lib = &self.lib;
        // The safe-mode DAC value: 0 A, in the +/-10 V range (write-protected registers).
        self.with_safe_write(|| {
            // SAFETY: plain values; signatures from 826api.h.
            self.call("S826_DacRangeWrite", unsafe {
                (lib.dac_range_write)(b, ch, DAC_SPAN_10_10, 1)
            })?;
            self.call("S826_DacDataWrite", unsafe {
                (lib.dac_data_write)(b, ch, DAC_ZERO, 1)
            })
        })?;
        // SAFETY (this block): plain values; signatures from 826api.h.
        unsafe {
            self.call(
                "S826_DacRangeWrite",
                (lib.dac_range_write)(b, ch, DAC_SPAN_10_10, 0),
            )?;
            self.call(
                "S826_DacDataWrite",
                (lib.dac_data_write)(b, ch, DAC_ZERO, 0),
            )?;
            self.call(
                "S826_CounterStateWrite",
                (lib.counter_state_write)(b, ech, 0),
            )?;
            self.call(
                "S826_CounterModeWrite",
                (lib.counter_mode_write)(b, ech, CM_K_QUADX4),
            )?;
            // no automatic snapshot triggers: only the loop's soft snapshots enter the FIFO
            self.call(
                "S826_CounterSnapshotConfigWrite",
                (lib.counter_snapshot_config_write)(b, ech, 0, BITWRITE),
            )?;
        }
        self.last_code = DAC_ZERO;
        Ok(())
    }

    fn activate(&mut self, _loop_watchdog_us: u32) -> Result<(), BoardError> {
        // The 826 arms its own timeout (s826.watchdog_us, default a few periods): the loop's
        // generic one is the simulated bench's.
        let (b, ech) = (self.board, self.cfg.encoder_channel);
        {
            let lib = &self.lib;
            // SAFETY (this block): plain values; signatures from 826api.h.
            unsafe {
                // zero the encoder: preload register 0 = 0 counts, start, load it now
                self.call(
                    "S826_CounterPreloadWrite",
                    (lib.counter_preload_write)(b, ech, 0, 0),
                )?;
                self.call(
                    "S826_CounterStateWrite",
                    (lib.counter_state_write)(b, ech, 1),
                )?;
                self.call("S826_CounterPreload", (lib.counter_preload)(b, ech, 1, 0))?;
            }
        }
        self.drain();
        let lib = &self.lib;
        let ticks = (self.watchdog_us as u64 * WD_TICKS_PER_US as u64).min(u32::MAX as u64) as u32;
        let mut timers = [0 as c_uint; 5];
        timers[WD_DELAY0] = ticks;
        self.with_safe_write(|| {
            // SAFETY: `timers` is the 5-element array the header declares; plain values.
            self.call("S826_WatchdogConfigWrite", unsafe {
                (lib.watchdog_config_write)(b, WD_SEN, timers.as_mut_ptr())
            })?;
            self.call("S826_WatchdogEnableWrite", unsafe {
                (lib.watchdog_enable_write)(b, 1)
            })
        })?;
        // SAFETY: plain values.
        self.call("S826_WatchdogKick", unsafe {
            (lib.watchdog_kick)(b, WATCHDOG_KICK)
        })?;
        self.active = true;
        self.started = false;
        self.raw_prev = 0;
        self.counts = 0;
        Ok(())
    }

    #[inline]
    fn read(&mut self) -> Result<Snapshot, BoardStop> {
        let (b, ch) = (self.board, self.cfg.encoder_channel);
        // SAFETY: plain values; signature from 826api.h.
        let rc = unsafe { (self.lib.counter_snapshot)(b, ch) };
        if let Some(code) = S826Code::of(rc) {
            return Err(stop(code, snapshot_msg));
        }
        let (mut value, mut ts, mut reason): (c_uint, c_uint, c_uint) = (0, 0, 0);
        let mut tries = 0;
        loop {
            // SAFETY: valid out pointers; signature from 826api.h.
            let rc = unsafe {
                (self.lib.counter_snapshot_read)(b, ch, &mut value, &mut ts, &mut reason, NO_WAIT)
            };
            match S826Code::of(rc) {
                None => break,
                // a snapshot was lost, this one is good: counted, not fatal
                Some(S826Code::FifoOverflow) => {
                    self.health.fifo_overflows += 1;
                    break;
                }
                Some(S826Code::NotReady) if tries < self.cfg.snapshot_retries => {
                    self.health.not_ready += 1;
                    tries += 1;
                }
                Some(S826Code::NotReady) => return Err(BoardStop::Fault(SNAPSHOT_NOT_READY)),
                Some(code) => return Err(stop(code, snapshot_read_msg)),
            }
        }
        if reason & SSRMASK_QUADERR != 0 {
            self.health.quadrature_errors += 1;
        }
        // A gap longer than the watchdog (or the first read: the time since activate is
        // unknown) means it may have fired: the card would be in safe mode, and the loop must
        // not go on as if it were driving the motor.
        if !self.started || ts.wrapping_sub(self.ts_prev) > self.watchdog_us {
            let mut s: c_uint = 0;
            // SAFETY: a valid out pointer.
            let rc = unsafe { (self.lib.safe_control_read)(b, &mut s) };
            if let Some(code) = S826Code::of(rc) {
                return Err(stop(code, safe_read_msg));
            }
            if s & CONFIG_SAF != 0 {
                return Err(BoardStop::Fault(WATCHDOG_TRIPPED));
            }
        }
        if self.started && ts < self.ts_prev {
            self.ts_wraps += 1;
            self.health.timestamp_wraps += 1;
        }
        self.started = true;
        self.ts_prev = ts;
        // the counter is 32 bits: unwrap through its wrapping difference
        self.counts += value.wrapping_sub(self.raw_prev) as i32 as i64;
        self.raw_prev = value;
        let counts =
            (self.counts * self.cfg.direction as i64).clamp(i32::MIN as i64, i32::MAX as i64);
        Ok(Snapshot {
            counts: counts as i32,
            timestamp_us: ts,
        })
    }

    #[inline]
    fn write(&mut self, word: u16) -> Result<(), BoardStop> {
        let code = self.code_for(dac::word_to_current(word, self.dac_full_scale));
        // SAFETY: plain values; signature from 826api.h.
        let rc = unsafe { (self.lib.dac_data_write)(self.board, self.cfg.dac_channel, code, 0) };
        if let Some(c) = S826Code::of(rc) {
            return Err(stop(c, dac_msg));
        }
        self.last_code = code;
        Ok(())
    }

    #[inline]
    fn kick(&mut self) -> Result<(), BoardStop> {
        // SAFETY: plain values; signature from 826api.h.
        let rc = unsafe { (self.lib.watchdog_kick)(self.board, WATCHDOG_KICK) };
        match S826Code::of(rc) {
            None => Ok(()),
            Some(c) => Err(stop(c, kick_msg)),
        }
    }

    fn deactivate(&mut self) {
        if !self.open {
            return;
        }
        self.dac_zero_best_effort();
        if self.active {
            self.active = false;
            let (b, lib) = (self.board, &self.lib);
            let _ = self.with_safe_write(|| {
                // SAFETY: plain values.
                self.call("S826_WatchdogEnableWrite", unsafe {
                    (lib.watchdog_enable_write)(b, 0)
                })
            });
        }
    }

    fn on_error(&mut self, _reason: &'static str) {
        if !self.open {
            return;
        }
        // 0 A in run mode, then safe mode (its DAC value is 0 A): whatever the loop does next,
        // the card holds 0 A until safe mode is cleared explicitly.
        self.dac_zero_best_effort();
        let (b, lib) = (self.board, &self.lib);
        // SAFETY (this block): plain values; signatures from 826api.h. No allocation: the
        // error paths of `call` are not taken on success, and a failure here is ignored.
        unsafe {
            (lib.safe_wren_write)(b, SAFEN_SWE);
            (lib.safe_control_write)(b, CONFIG_SAF, BITSET);
            (lib.safe_wren_write)(b, SAFEN_SWD);
        }
    }

    fn shutdown(&mut self) {
        if self.open {
            self.open = false;
            self.active = false;
            // SAFETY: no arguments.
            unsafe { (self.lib.system_close)() };
        }
    }

    fn health(&self) -> BoardHealth {
        self.health
    }

    fn name(&self) -> &'static str {
        "s826"
    }
}

impl Drop for S826Board {
    fn drop(&mut self) {
        self.deactivate();
        self.shutdown();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dac_codes_for_volts() {
        assert_eq!(volts_to_code(0.0), 0x8000);
        assert_eq!(volts_to_code(f64::NAN), 0x8000);
        assert_eq!(volts_to_code(-10.0), 0);
        assert_eq!(volts_to_code(10.0), 0xFFFF);
        assert_eq!(volts_to_code(50.0), 0xFFFF);
        assert!((code_to_volts(volts_to_code(5.9)) - 5.9).abs() < 10.0 / 32768.0);
    }
}
