//! A C-ABI double of Sensoray's 826 library: the same symbols with the same signatures as
//! `826api.h` declares them, the same error codes, and behind them a simulated rig (rt-loop's
//! simulated bench: motor, amplifier, encoder counts, the sponge and the hand). Built by the
//! workspace as `target/<profile>/libs826_double.so`; `rt-loop --board s826 --s826-lib` that
//! file runs the whole product as on the real card. Test support, never shipped.
//!
//! Behaviour kept from the card: `S826_ERR_BOARDCLOSED` before `S826_SystemOpen`,
//! `S826_ERR_BOARD` for another board number, `S826_ERR_VALUE` for an out-of-range channel or a
//! DAC setpoint above 0xFFFF, `S826_ERR_NOTREADY` from `S826_CounterSnapshotRead` on an empty
//! FIFO (no wait), `S826_ERR_FIFOOVERFLOW` once after the 16-deep FIFO lost a snapshot, the
//! safe-mode registers (safe DAC values, safe control, watchdog) writable only while
//! `S826_SafeWrenWrite` enabled them, a kick counted only with its value 0x5A55AA5A, and the
//! watchdog putting the card in safe mode (the safe DAC value on the output) by itself, from
//! its own timer thread, when not kicked in time; safe mode left only by clearing it.
//! Fault injection: [`faults`].

pub mod faults;
pub mod hw;

use hw::{card, start_watchdog_thread, watchdog_bell, Card, KICK, SAF, WD_SEN};
use std::os::raw::{c_int, c_uint};
use std::time::{Duration, Instant};

const ERR_OK: c_int = 0;
const ERR_BOARD: c_int = -1;
const ERR_VALUE: c_int = -2;
const ERR_NOTREADY: c_int = -3;
const ERR_DRIVER: c_int = -5;
const ERR_BOARDCLOSED: c_int = -10;
const ERR_FIFOOVERFLOW: c_int = -15;
const NUM_COUNT: c_uint = 6;
const NUM_DAC: c_uint = 8;

/// Runs `f` on the open card `board`, or returns the card's error for it.
fn with_card(board: c_uint, f: impl FnOnce(&mut Card) -> c_int) -> c_int {
    let mut g = card();
    let Some(c) = g.as_mut() else {
        return ERR_BOARDCLOSED;
    };
    if !c.open {
        return ERR_BOARDCLOSED;
    }
    if board != c.env.board {
        return ERR_BOARD;
    }
    if let Some(at) = c.faults.vanish_at {
        if c.snapshots >= at && !c.vanished {
            c.vanished = true;
            let amps = c.amps;
            c.log(
                "fault-board-vanished",
                format_args!("snapshot={at} amps={amps:.4}"),
            );
        }
    }
    if c.vanished {
        return ERR_DRIVER;
    }
    f(c)
}

/// # Safety
/// No pointers.
#[no_mangle]
pub extern "C" fn S826_SystemOpen() -> c_int {
    let env = faults::RigEnv::from_env();
    let faults = faults::Faults::from_env();
    let mut g = card();
    let c = g.get_or_insert_with(|| Card::new(env.clone()));
    c.faults = faults;
    if c.faults.no_board || c.vanished {
        c.log("open", format_args!("no board (injected)"));
        return 0;
    }
    c.build_sim();
    c.open = true;
    c.snapshots = 0;
    c.dac_writes = 0;
    let b = c.env.board;
    c.log("open", format_args!("board={b}"));
    drop(g);
    start_watchdog_thread();
    1 << b
}

#[no_mangle]
pub extern "C" fn S826_SystemClose() -> c_int {
    let mut g = card();
    if let Some(c) = g.as_mut() {
        if c.open {
            c.open = false;
            let (amps, saf, n) = (c.amps, c.saf, c.snapshots);
            c.log(
                "close",
                format_args!("amps={amps:.4} safe_mode={saf} snapshots={n}"),
            );
        }
    }
    ERR_OK
}

/// # Safety
/// Each pointer is null or valid for one write.
#[no_mangle]
pub unsafe extern "C" fn S826_VersionRead(
    board: c_uint,
    api: *mut c_uint,
    driver: *mut c_uint,
    bdrev: *mut c_uint,
    fpgarev: *mut c_uint,
) -> c_int {
    with_card(board, |_| {
        for (p, v) in [
            (api, 0x0303_0005u32),
            (driver, 0x0303_0005),
            (bdrev, 0),
            (fpgarev, 0x0001_0004),
        ] {
            if !p.is_null() {
                // SAFETY: the caller's pointer, checked non-null.
                unsafe { *p = v };
            }
        }
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_CounterModeWrite(board: c_uint, chan: c_uint, mode: c_uint) -> c_int {
    with_card(board, |c| {
        if chan >= NUM_COUNT {
            return ERR_VALUE;
        }
        c.counters[chan as usize].mode = mode;
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_CounterStateWrite(board: c_uint, chan: c_uint, run: c_uint) -> c_int {
    with_card(board, |c| {
        if chan >= NUM_COUNT {
            return ERR_VALUE;
        }
        c.counters[chan as usize].running = run != 0;
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_CounterSnapshotConfigWrite(
    board: c_uint,
    chan: c_uint,
    ctrl: c_uint,
    mode: c_uint,
) -> c_int {
    with_card(board, |c| {
        if chan >= NUM_COUNT || mode > 2 {
            return ERR_VALUE;
        }
        let r = &mut c.counters[chan as usize].snapshot_ctrl;
        *r = match mode {
            0 => ctrl,
            1 => *r & !ctrl,
            _ => *r | ctrl,
        };
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_CounterSnapshot(board: c_uint, chan: c_uint) -> c_int {
    let stall = with_card(board, |c| {
        if chan >= NUM_COUNT {
            return ERR_VALUE;
        }
        let n = c.snapshots + 1;
        if c.faults.stall_at == Some(n) {
            let ms = c.faults.stall_ms;
            c.log("fault-host-stall", format_args!("snapshot={n} ms={ms}"));
            return ms as c_int;
        }
        0
    });
    if stall < 0 {
        return stall;
    }
    if stall > 0 {
        // The host is stuck in this call (the card's lock is free: its watchdog runs on).
        std::thread::sleep(Duration::from_millis(stall as u64));
    }
    with_card(board, |c| {
        c.soft_snapshot(chan as usize);
        ERR_OK
    })
}

/// # Safety
/// Each pointer is null or valid for one write.
#[no_mangle]
pub unsafe extern "C" fn S826_CounterSnapshotRead(
    board: c_uint,
    chan: c_uint,
    value: *mut c_uint,
    tstamp: *mut c_uint,
    reason: *mut c_uint,
    tmax: c_uint,
) -> c_int {
    let deadline = Instant::now() + Duration::from_micros(tmax.min(1_000_000) as u64);
    loop {
        let rc = with_card(board, |c| {
            if chan >= NUM_COUNT {
                return ERR_VALUE;
            }
            let ctr = &mut c.counters[chan as usize];
            let Some((v, t, r)) = ctr.fifo.pop_front() else {
                return ERR_NOTREADY;
            };
            for (p, x) in [(value, v), (tstamp, t), (reason, r)] {
                if !p.is_null() {
                    // SAFETY: the caller's pointer, checked non-null.
                    unsafe { *p = x };
                }
            }
            if std::mem::take(&mut ctr.overflowed) {
                ERR_FIFOOVERFLOW
            } else {
                ERR_OK
            }
        });
        if rc != ERR_NOTREADY || tmax == 0 || Instant::now() >= deadline {
            return rc;
        }
        std::thread::sleep(Duration::from_micros(50));
    }
}

#[no_mangle]
pub extern "C" fn S826_CounterPreloadWrite(
    board: c_uint,
    chan: c_uint,
    reg: c_uint,
    counts: c_uint,
) -> c_int {
    with_card(board, |c| {
        if chan >= NUM_COUNT || reg > 1 {
            return ERR_VALUE;
        }
        c.counters[chan as usize].preload[reg as usize] = counts;
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_CounterPreload(
    board: c_uint,
    chan: c_uint,
    level: c_uint,
    _sticky: c_uint,
) -> c_int {
    with_card(board, |c| {
        if chan >= NUM_COUNT {
            return ERR_VALUE;
        }
        if level != 0 {
            c.preload(chan as usize);
        }
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_DacRangeWrite(
    board: c_uint,
    chan: c_uint,
    range: c_uint,
    safemode: c_uint,
) -> c_int {
    with_card(board, |c| {
        if chan >= NUM_DAC || range > 3 {
            return ERR_VALUE;
        }
        if safemode != 0 {
            if c.wren {
                c.range_safe[chan as usize] = range;
            }
        } else {
            c.range_run[chan as usize] = range;
        }
        c.apply_output(chan as usize, "range");
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_DacDataWrite(
    board: c_uint,
    chan: c_uint,
    setpoint: c_uint,
    safemode: c_uint,
) -> c_int {
    with_card(board, |c| {
        if chan >= NUM_DAC || setpoint > 0xFFFF {
            return ERR_VALUE;
        }
        if safemode != 0 {
            // write-protected: ignored unless S826_SafeWrenWrite enabled it
            if c.wren {
                c.dac_safe[chan as usize] = setpoint;
            }
        } else {
            c.dac_writes += 1;
            if c.faults.dac_refuse_at == Some(c.dac_writes) {
                let (n, s) = (c.dac_writes, c.snapshots);
                c.log("fault-dac-refused", format_args!("write={n} snapshot={s}"));
                return ERR_NOTREADY;
            }
            c.dac_run[chan as usize] = setpoint;
        }
        c.apply_output(
            chan as usize,
            if safemode != 0 {
                "safe-write"
            } else {
                "run-write"
            },
        );
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_SafeWrenWrite(board: c_uint, enable: c_uint) -> c_int {
    with_card(board, |c| {
        match enable {
            2 => c.wren = true,
            1 => c.wren = false,
            _ => return ERR_VALUE,
        }
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_SafeControlWrite(board: c_uint, settings: c_uint, mode: c_uint) -> c_int {
    with_card(board, |c| {
        if mode > 2 {
            return ERR_VALUE;
        }
        if !c.wren {
            return ERR_OK; // write-protected: ignored
        }
        let now = if c.saf { SAF } else { 0 };
        let next = match mode {
            0 => settings,
            1 => now & !settings,
            _ => now | settings,
        };
        let saf = next & SAF != 0;
        if saf != c.saf {
            c.saf = saf;
            let chan = c.motor_chan;
            c.apply_output(chan, "safe-mode");
            let (amps, n) = (c.amps, c.snapshots);
            c.log(
                "safe-mode",
                format_args!(
                    "{} cause=host snapshot={n} amps={amps:.4}",
                    if saf { "on" } else { "off" }
                ),
            );
        }
        ERR_OK
    })
}

/// # Safety
/// `settings` is null or valid for one write.
#[no_mangle]
pub unsafe extern "C" fn S826_SafeControlRead(board: c_uint, settings: *mut c_uint) -> c_int {
    with_card(board, |c| {
        if settings.is_null() {
            return ERR_VALUE;
        }
        // SAFETY: the caller's pointer, checked non-null.
        unsafe { *settings = if c.saf { SAF } else { 0 } };
        ERR_OK
    })
}

/// # Safety
/// `timers` is null or points to 5 readable values.
#[no_mangle]
pub unsafe extern "C" fn S826_WatchdogConfigWrite(
    board: c_uint,
    config: c_uint,
    timers: *mut c_uint,
) -> c_int {
    let rc = with_card(board, |c| {
        if timers.is_null() {
            return ERR_VALUE;
        }
        if !c.wren {
            return ERR_OK;
        }
        // SAFETY: the caller's 5-element array.
        let t0 = unsafe { *timers };
        c.wd_config = config;
        c.wd_timeout = Duration::from_nanos(t0 as u64 * 20);
        ERR_OK
    });
    watchdog_bell().notify_all();
    rc
}

#[no_mangle]
pub extern "C" fn S826_WatchdogEnableWrite(board: c_uint, enable: c_uint) -> c_int {
    let rc = with_card(board, |c| {
        if !c.wren {
            return ERR_OK;
        }
        c.wd_enabled = enable != 0;
        c.wd_expired = false;
        c.last_kick = Instant::now();
        let (t, sen) = (c.wd_timeout.as_micros(), c.wd_config & WD_SEN != 0);
        c.log(
            "watchdog",
            format_args!(
                "{} timeout_us={t} safe_mode_on_timeout={sen}",
                if enable != 0 { "armed" } else { "off" }
            ),
        );
        ERR_OK
    });
    watchdog_bell().notify_all();
    rc
}

#[no_mangle]
pub extern "C" fn S826_WatchdogKick(board: c_uint, data: c_uint) -> c_int {
    with_card(board, |c| {
        if data != KICK {
            // not the kick value: not a kick (made visible as a value error)
            return ERR_VALUE;
        }
        if c.wd_enabled && !c.wd_expired {
            c.last_kick = Instant::now();
        }
        ERR_OK
    })
}

#[no_mangle]
pub extern "C" fn S826_WatchdogEventWait(board: c_uint, tmax: c_uint) -> c_int {
    let deadline = Instant::now() + Duration::from_micros(tmax.min(60_000_000) as u64);
    loop {
        let rc = with_card(board, |c| {
            c.watchdog_check();
            if c.wd_expired {
                ERR_OK
            } else {
                ERR_NOTREADY
            }
        });
        if rc != ERR_NOTREADY || Instant::now() >= deadline {
            return rc;
        }
        std::thread::sleep(Duration::from_micros(100));
    }
}

/// The amplifier's current now, A (for tests that load the double in-process).
#[no_mangle]
pub extern "C" fn s826_double_amps() -> f64 {
    card().as_ref().map_or(0.0, |c| c.amps)
}
