//! Fault injection, read from the environment at every `S826_SystemOpen` (so a test sets it
//! for the rt-loop process it starts). Counts are of soft snapshots (loop steps) and of
//! run-mode DAC writes since that open.
//!
//! | variable | fault |
//! | --- | --- |
//! | `S826_DOUBLE_NO_BOARD=1` | `S826_SystemOpen` finds no board |
//! | `S826_DOUBLE_VANISH_AT=N` | from snapshot N on, every call returns `S826_ERR_DRIVER` (the card is gone; its watchdog still runs and cuts the output) |
//! | `S826_DOUBLE_NOTREADY_AT=N` | from snapshot N on, soft snapshots never reach the FIFO (`S826_ERR_NOTREADY`); `S826_DOUBLE_NOTREADY_COUNT=K` limits it to K snapshots |
//! | `S826_DOUBLE_OVERFLOW_AT=N` | snapshot N's read returns `S826_ERR_FIFOOVERFLOW` (with good data) |
//! | `S826_DOUBLE_QUADERR_AT=N` | snapshot N carries the quadrature-error reason bit |
//! | `S826_DOUBLE_TIMESTAMP_START=T` | the timestamp counter starts at T (e.g. 4294000000: it wraps 1 s in) |
//! | `S826_DOUBLE_DAC_REFUSE_AT=N` | the N-th run-mode `S826_DacDataWrite` returns `S826_ERR_NOTREADY` |
//! | `S826_DOUBLE_STALL_AT=N`, `S826_DOUBLE_STALL_MS=M` | snapshot N blocks the caller M ms (the host stalls inside a driver call; the watchdog fires meanwhile) |
//!
//! The simulated rig: `S826_DOUBLE_WORLD` (`sponge` default, `hand`, `both`, `free`),
//! `S826_DOUBLE_MATERIAL` (default `materials/sponge.toml`), `S826_DOUBLE_AMPS_PER_VOLT`
//! (the amplifier, default 0.1), `S826_DOUBLE_DIRECTION` (the encoder's wiring, default 1),
//! `S826_DOUBLE_BOARD` (its switches, default 0), `S826_DOUBLE_LOG` (a file the double appends
//! its events to: open, close, watchdog, safe mode, injected faults, the output going to 0 A).

fn var<T: std::str::FromStr>(name: &str) -> Option<T> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

#[derive(Clone, Debug, Default)]
pub struct Faults {
    pub no_board: bool,
    pub vanish_at: Option<u64>,
    pub notready_at: Option<u64>,
    pub notready_count: Option<u64>,
    pub overflow_at: Option<u64>,
    pub quaderr_at: Option<u64>,
    pub dac_refuse_at: Option<u64>,
    pub stall_at: Option<u64>,
    pub stall_ms: u64,
}

impl Faults {
    pub fn from_env() -> Faults {
        Faults {
            no_board: var::<u32>("S826_DOUBLE_NO_BOARD").unwrap_or(0) != 0,
            vanish_at: var("S826_DOUBLE_VANISH_AT"),
            notready_at: var("S826_DOUBLE_NOTREADY_AT"),
            notready_count: var("S826_DOUBLE_NOTREADY_COUNT"),
            overflow_at: var("S826_DOUBLE_OVERFLOW_AT"),
            quaderr_at: var("S826_DOUBLE_QUADERR_AT"),
            dac_refuse_at: var("S826_DOUBLE_DAC_REFUSE_AT"),
            stall_at: var("S826_DOUBLE_STALL_AT"),
            stall_ms: var("S826_DOUBLE_STALL_MS").unwrap_or(0),
        }
    }

    /// Whether snapshot `n`'s soft snapshot is withheld from the FIFO.
    pub fn withholds(&self, n: u64) -> bool {
        match self.notready_at {
            Some(at) if n >= at => self.notready_count.is_none_or(|k| n < at + k),
            _ => false,
        }
    }
}

/// The rig the double simulates.
#[derive(Clone, Debug)]
pub struct RigEnv {
    pub world: String,
    pub material: String,
    pub amps_per_volt: f64,
    pub direction: i64,
    pub board: u32,
    pub timestamp_start: u32,
    pub log: Option<String>,
}

impl RigEnv {
    pub fn from_env() -> RigEnv {
        RigEnv {
            world: std::env::var("S826_DOUBLE_WORLD").unwrap_or_else(|_| "sponge".into()),
            material: std::env::var("S826_DOUBLE_MATERIAL")
                .unwrap_or_else(|_| "materials/sponge.toml".into()),
            amps_per_volt: var("S826_DOUBLE_AMPS_PER_VOLT").unwrap_or(0.1),
            direction: if var::<i64>("S826_DOUBLE_DIRECTION") == Some(-1) {
                -1
            } else {
                1
            },
            board: var("S826_DOUBLE_BOARD").unwrap_or(0),
            timestamp_start: var("S826_DOUBLE_TIMESTAMP_START").unwrap_or(0),
            log: std::env::var("S826_DOUBLE_LOG")
                .ok()
                .filter(|s| !s.is_empty()),
        }
    }
}
