//! The simulated card and the rig behind it: counters, DACs, safe mode and the watchdog as
//! the 826 has them, driving rt-loop's simulated bench (motor, amplifier, friction, the sponge
//! and the hand) in wall-clock time. One card per process; its state outlives
//! `S826_SystemClose` like a real card's (safe mode included), and a thread stands in for the
//! card's own watchdog timer, so the output goes to 0 A even while the host is stalled.

use crate::faults::{Faults, RigEnv};
use rt_loop::board::sim::{SimBoard, SimConfig, SimTime, SimWorld};
use rt_loop::board::Board;
use std::collections::VecDeque;
use std::io::Write;
use std::sync::{Condvar, Mutex, MutexGuard, OnceLock};
use std::time::{Duration, Instant};

pub const FIFO_DEPTH: usize = 16;
/// The kick value the card accepts.
pub const KICK: u32 = 0x5A55_AA5A;
pub const QUADERR: u32 = 1 << 8;
pub const SOFT: u32 = 1 << 7;
pub const SAF: u32 = 1 << 1;
pub const WD_SEN: u32 = 1 << 4;

#[derive(Default)]
pub struct Counter {
    pub mode: u32,
    pub running: bool,
    pub preload: [u32; 2],
    /// Count offset so that the reported count is the preloaded value at the preload instant.
    pub offset: i64,
    pub fifo: VecDeque<(u32, u32, u32)>,
    pub overflowed: bool,
    pub snapshot_ctrl: u32,
}

pub struct Card {
    pub env: RigEnv,
    pub faults: Faults,
    pub open: bool,
    pub sim: Option<SimBoard>,
    pub epoch: Instant,
    pub counters: [Counter; 6],
    pub dac_run: [u32; 8],
    pub dac_safe: [u32; 8],
    pub range_run: [u32; 8],
    pub range_safe: [u32; 8],
    pub wren: bool,
    pub saf: bool,
    pub wd_config: u32,
    pub wd_timeout: Duration,
    pub wd_enabled: bool,
    pub wd_expired: bool,
    pub last_kick: Instant,
    /// Soft snapshots since the last open (the loop's steps).
    pub snapshots: u64,
    /// Run-mode DAC writes since the last open.
    pub dac_writes: u64,
    /// The amplifier's current now, A.
    pub amps: f64,
    /// The DAC channel the amplifier is wired to (the one the driver writes).
    pub motor_chan: usize,
    /// The card vanished (injected): from then on, for the life of the process, every call
    /// fails and `S826_SystemOpen` finds no board; its watchdog still runs.
    pub vanished: bool,
    log: Option<std::fs::File>,
}

/// The card, made at the first open.
pub fn card() -> MutexGuard<'static, Option<Card>> {
    static CARD: OnceLock<Mutex<Option<Card>>> = OnceLock::new();
    CARD.get_or_init(|| Mutex::new(None))
        .lock()
        .unwrap_or_else(|p| p.into_inner())
}

/// Wakes the watchdog thread when the watchdog is (re)configured.
pub fn watchdog_bell() -> &'static Condvar {
    static BELL: Condvar = Condvar::new();
    &BELL
}

fn volts(range: u32, code: u32) -> f64 {
    let (lo, hi) = match range {
        0 => (0.0, 5.0),
        1 => (0.0, 10.0),
        2 => (-5.0, 5.0),
        _ => (-10.0, 10.0),
    };
    lo + (hi - lo) * code as f64 / 65536.0
}

impl Card {
    pub fn new(env: RigEnv) -> Card {
        let log = env.log.as_ref().and_then(|p| {
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(p)
                .ok()
        });
        Card {
            env,
            faults: Faults::default(),
            open: false,
            sim: None,
            epoch: Instant::now(),
            counters: Default::default(),
            dac_run: [0x8000; 8],
            dac_safe: [0x8000; 8],
            range_run: [3; 8],
            range_safe: [3; 8],
            wren: false,
            saf: false,
            wd_config: 0,
            wd_timeout: Duration::from_millis(100),
            wd_enabled: false,
            wd_expired: false,
            last_kick: Instant::now(),
            snapshots: 0,
            dac_writes: 0,
            amps: 0.0,
            motor_chan: 0,
            vanished: false,
            log,
        }
    }

    /// Appends an event line: milliseconds since the card was made, the event, details.
    pub fn log(&mut self, event: &str, details: std::fmt::Arguments<'_>) {
        let ms = self.epoch.elapsed().as_secs_f64() * 1e3;
        if let Some(f) = self.log.as_mut() {
            let _ = writeln!(f, "{ms:.3} {event} {details}");
        }
    }

    /// Builds the simulated rig (at the first open).
    pub fn build_sim(&mut self) {
        if self.sim.is_some() {
            return;
        }
        let material = match rt_loop::object::material::Material::load(std::path::Path::new(
            &self.env.material,
        )) {
            Ok((m, _)) => Some(m),
            Err(e) => {
                let why = format!("{e:#}");
                self.log("material-missing", format_args!("{why} (free air)"));
                None
            }
        };
        let hand = Some(rt_loop::experiment::hand::HandConfig::default());
        let world = match self.env.world.as_str() {
            "hand" => SimWorld { sponge: None, hand },
            "both" => SimWorld {
                sponge: material,
                hand,
            },
            "free" => SimWorld {
                sponge: None,
                hand: None,
            },
            _ => SimWorld {
                sponge: material,
                hand: None,
            },
        };
        let mut sim = SimBoard::new(SimConfig::default(), world, SimTime::Wall, 1);
        let _ = sim.configure();
        self.sim = Some(sim);
    }

    /// The card's timestamp now, microseconds (32 bits, wrapping).
    pub fn timestamp(&self) -> u32 {
        let us = self.epoch.elapsed().as_micros() as u64;
        (self.env.timestamp_start as u64).wrapping_add(us) as u32
    }

    /// Recomputes the amplifier's current from DAC channel `chan` (the one it is wired to
    /// from now on: the driver's) in run or safe mode, and hands it to the simulated motor.
    pub fn apply_output(&mut self, chan: usize, cause: &str) {
        self.motor_chan = chan;
        let code = if self.saf {
            self.dac_safe[chan]
        } else {
            self.dac_run[chan]
        };
        let range = if self.saf {
            self.range_safe[chan]
        } else {
            self.range_run[chan]
        };
        let amps = volts(range, code) * self.env.amps_per_volt;
        let before = self.amps;
        self.amps = amps;
        if let Some(sim) = self.sim.as_mut() {
            let fs = SimConfig::default().dac_full_scale;
            let _ = sim.write(rt_loop::control::dac::current_to_word(amps, fs));
        }
        if before != 0.0 && amps == 0.0 {
            let n = self.snapshots;
            self.log(
                "output-zero",
                format_args!("snapshot={n} cause={cause} amps_before={before:.4}"),
            );
        }
    }

    /// Latches one soft snapshot of counter `chan`.
    pub fn soft_snapshot(&mut self, chan: usize) {
        self.snapshots += 1;
        let n = self.snapshots;
        let counts = match self.sim.as_mut() {
            Some(sim) => sim.read().map(|s| s.counts as i64).unwrap_or(0),
            None => 0,
        };
        let ts = self.timestamp();
        let mut reason = SOFT;
        if self.faults.quaderr_at == Some(n) {
            reason |= QUADERR;
            self.log("fault-quadrature-error", format_args!("snapshot={n}"));
        }
        if self.faults.withholds(n) {
            if self.faults.notready_at == Some(n) {
                self.log("fault-fifo-not-ready", format_args!("snapshot={n}"));
            }
            return;
        }
        let c = &mut self.counters[chan];
        let value = (self.env.direction * counts + c.offset) as u32;
        if c.fifo.len() == FIFO_DEPTH {
            c.fifo.pop_front();
            c.overflowed = true;
        }
        c.fifo.push_back((value, ts, reason));
        if self.faults.overflow_at == Some(n) {
            self.counters[chan].overflowed = true;
            self.log("fault-fifo-overflow", format_args!("snapshot={n}"));
        }
    }

    /// Loads preload register 0 into counter `chan` now.
    pub fn preload(&mut self, chan: usize) {
        let counts = match self.sim.as_mut() {
            Some(sim) => sim.read().map(|s| s.counts as i64).unwrap_or(0),
            None => 0,
        };
        let c = &mut self.counters[chan];
        c.offset = c.preload[0] as i64 - self.env.direction * counts;
    }

    /// The watchdog's check: fires when enabled, not kicked within its timeout.
    pub fn watchdog_check(&mut self) -> Option<Duration> {
        if !self.wd_enabled || self.wd_expired {
            return None;
        }
        let since = self.last_kick.elapsed();
        if since < self.wd_timeout {
            return Some(self.wd_timeout - since);
        }
        self.wd_expired = true;
        let before = self.amps;
        let us = since.as_micros();
        let timeout = self.wd_timeout.as_micros();
        self.log(
            "watchdog-expired",
            format_args!("since_kick_us={us} timeout_us={timeout} amps_before={before:.4}"),
        );
        if self.wd_config & WD_SEN != 0 {
            self.saf = true;
            self.apply_output(self.motor_chan, "watchdog");
            let after = self.amps;
            self.log(
                "safe-mode",
                format_args!("on cause=watchdog amps={after:.4}"),
            );
        }
        None
    }
}

/// The card's watchdog timer: a thread that fires the watchdog on time whatever the host
/// does (it takes the card's lock only to look).
pub fn start_watchdog_thread() {
    static STARTED: OnceLock<()> = OnceLock::new();
    STARTED.get_or_init(|| {
        std::thread::Builder::new()
            .name("s826-double-watchdog".into())
            .spawn(|| loop {
                let wait = {
                    let mut g = card();
                    match g.as_mut() {
                        Some(c) => c.watchdog_check(),
                        None => None,
                    }
                };
                let wait = wait
                    .unwrap_or(Duration::from_millis(5))
                    .min(Duration::from_millis(5));
                let g = card();
                let _ = watchdog_bell().wait_timeout(g, wait.max(Duration::from_micros(20)));
            })
            .expect("spawn the double's watchdog thread");
    });
}
