//! rt-loop's command line: the subcommands and their flags (clap), and how flags become the
//! library's configurations ([`RunArgs::resolve`], [`ServeArgs::resolve`]): each flag
//! overrides the `--config` file, in one place for `run` and `serve` ([`CommonArgs`]). The
//! experiment options (`--ramp-rate`, `--cycles`, `--f-max-start`, `--f-max-step`) are
//! [`ExperimentArgs`], shared with hapticctl through haptics-proto. Nothing here runs anything:
//! [`crate::app`] does.

use crate::config::{BoardKind, ClockKind, ExperimentKind, RunConfig};
use crate::daemon::DaemonConfig;
use crate::import::{ForceUnit, ImportOptions, PositionUnit, TimeUnit};
use crate::record::Format;
use crate::serving::model::SpringDamper;
use crate::serving::shm_model::AnswerWait;
use anyhow::{bail, Result};
use clap::{Args, Parser, Subcommand};
use haptics_proto::experiment_args::ExperimentArgs;
use shm_ring::WaitStrategy;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "rt-loop",
    version,
    about = "Haptics real-time loop: DOB/RFOB force control on a (simulated) bench"
)]
pub struct Cli {
    #[command(subcommand)]
    pub cmd: Cmd,
}

// Parsed once at start-up: the size of its largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
pub enum Cmd {
    /// Run an experiment (flags override the --config file).
    Run(RunArgs),
    /// Import a time/position/force series and write it in the recording format with the
    /// loop's velocity/acceleration filters and the nine features.
    Features(FeaturesArgs),
    /// Fit the spring-damper fallback (F = k1 x + k2 x^2 + b v) to a recording; prints TOML.
    Fit(FitArgs),
    /// Long-running loop for the system: owns the shared-memory segment, idles at 0 A (or loops
    /// --autostart), runs the experiments infer-server's mailbox asks for, streams telemetry.
    Serve(ServeArgs),
    /// Identify the bench's friction (Coulomb, Stribeck, viscous) with constant-velocity sweeps
    /// in free air under position control; writes the bench file that --bench reads.
    IdentifyFriction(IdentifyArgs),
    /// A real board's first day: `check` (each line pass or what to change), `calibrate`
    /// (writes the rig file every command takes with --rig), `clear-safe-mode`.
    #[command(subcommand)]
    Board(BoardCmd),
    /// Drive a material's object (any law) along a motion CSV (t_s, x_m) and write its force
    /// (the oracle's path without the loop): what the leave-one-rate-out generators use.
    ObjectForce(crate::object_force::ObjectForceArgs),
}

#[derive(Subcommand)]
pub enum BoardCmd {
    /// Versions, the encoder following a small current pulse, DAC polarity and amplifier gain,
    /// counts per metre, and a watchdog trip without the host. Run it in free air.
    Check(BoardCheckArgs),
    /// Measures direction, moving mass and friction; writes the rig file (--out).
    Calibrate(CalibrateArgs),
    /// Leaves safe mode after a watchdog trip or a fault (the explicit action it needs).
    ClearSafeMode(BoardCheckArgs),
}

#[derive(Args)]
pub struct BoardCheckArgs {
    /// A TOML file of settings (rt-loop/config.example.toml): the loop parameters and the
    /// motor's limits the bring-up commands respect; the flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub board: BoardArgs,
    /// Also write the lines as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

impl BoardCheckArgs {
    /// The configuration with these flags over it.
    pub fn resolve(&self) -> Result<RunConfig> {
        let mut c = match &self.config {
            Some(p) => RunConfig::load(p)?,
            None => RunConfig::default(),
        };
        self.board.apply(&mut c)?;
        c.validate().map_err(|e| anyhow::anyhow!(e))?;
        Ok(c)
    }
}

#[derive(Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub check: BoardCheckArgs,
    /// The rig file to write.
    #[arg(long, default_value = "rig.toml")]
    pub out: PathBuf,
    /// Encoder counts per metre (datasheet, or from `board check` with a gauge).
    #[arg(long)]
    pub counts_per_metre: Option<f64>,
    /// Motor force constant, N/A (datasheet).
    #[arg(long)]
    pub force_constant: Option<f64>,
    /// Amplifier gain, A/V (datasheet or its gain setting).
    #[arg(long)]
    pub amps_per_volt: Option<f64>,
    /// Keep the configured friction instead of running the sweeps.
    #[arg(long)]
    pub skip_friction: bool,
    /// Replace an existing --out file.
    #[arg(long)]
    pub overwrite: bool,
}

/// Which board, and for a real one where its library and its calibration are (`run`,
/// `serve`, `identify-friction`, `board ...`).
#[derive(Args, Clone, Default)]
pub struct BoardArgs {
    /// sim, replay, or s826[:N] (a Sensoray 826, N the board number its switches set).
    #[arg(long)]
    pub board: Option<BoardKind>,
    /// The Sensoray 826 library (default: HAPTICS_S826_LIB, else lib826_64.so on the library
    /// paths).
    #[arg(long)]
    pub s826_lib: Option<PathBuf>,
    /// The 826's hardware watchdog, us (default: five periods of --rate-hz).
    #[arg(long)]
    pub s826_watchdog_us: Option<u32>,
    /// Rig file (`rt-loop board calibrate`): counts per metre, direction, A/V, force
    /// constant, moving mass, friction.
    #[arg(long)]
    pub rig: Option<PathBuf>,
}

impl BoardArgs {
    /// These flags over a configuration.
    pub fn apply(&self, c: &mut RunConfig) -> Result<()> {
        if let Some(v) = self.board {
            c.board = v;
        }
        if let Some(p) = &self.s826_lib {
            c.s826.lib = Some(p.clone());
        }
        if let Some(us) = self.s826_watchdog_us {
            c.s826.watchdog_us = Some(us);
        }
        if let Some(p) = &self.rig {
            crate::board::rig_file::RigFile::load(p)?.apply(c);
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct IdentifyArgs {
    /// A TOML file of settings (rt-loop/config.example.toml): the bench it identifies.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub board: BoardArgs,
    /// Seed of the simulated bench's noise (default 1).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Bench file to write (TOML, `[friction]`).
    #[arg(long, default_value = "bench.toml")]
    pub out: PathBuf,
    /// Sweep speeds, mm/s, comma-separated (default 0.5 to 60 mm/s, 12 speeds).
    #[arg(long, value_delimiter = ',')]
    pub speeds_mm_s: Option<Vec<f64>>,
    /// Write the sweep points, fit and (simulated bench) true values here as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelArg {
    /// The built-in spring-damper (no server).
    Builtin,
    /// The simulated object's own physics (the material file), driven by the measured
    /// motion: the rendering floor (rt-loop's oracle model, no server).
    Oracle,
    /// infer-server over shared memory (segment /haptics-<instance>).
    Shm,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WaitArg {
    Spin,
    Park,
    SpinPark,
}

/// How the loop talks to infer-server (shared by `run --model shm` and `serve`).
#[derive(Args, Clone)]
pub struct ShmArgs {
    /// Segment /haptics-<instance> (infer-server --instance NAME attaches to it).
    #[arg(long, default_value = "default")]
    pub instance: String,
    /// Realtime clock: per-step deadline for the server's answer (late = fallback), us.
    #[arg(long, default_value_t = 50.0)]
    pub deadline_us: f64,
    /// Lockstep clock: safety timeout per answer (the loop waits for every answer), s.
    #[arg(long, default_value_t = 5.0)]
    pub answer_timeout_s: f64,
    /// How the loop waits for an answer: default spin in realtime, park in lockstep.
    #[arg(long, value_enum)]
    pub wait: Option<WaitArg>,
    /// Lockstep clock: after this many safety timeouts in a row the server is treated as gone
    /// (steps fall back without waiting) until its heartbeat moves again.
    #[arg(long, default_value_t = crate::serving::shm_model::DEFAULT_GIVE_UP_AFTER)]
    pub give_up_after: u32,
}

/// Longest wait a flag may ask for, s (a day: beyond it a typo, and `Duration` overflows near
/// 1e19 s).
pub const MAX_WAIT_S: f64 = 86_400.0;

/// `v` seconds as a Duration when `0 <= v <= MAX_WAIT_S` (`> 0` unless `zero_ok`), else the
/// error for `flag`.
pub fn seconds_flag(flag: &str, v: f64, zero_ok: bool) -> Result<Duration> {
    let lo_ok = if zero_ok { v >= 0.0 } else { v > 0.0 };
    if !(v.is_finite() && lo_ok && v <= MAX_WAIT_S) {
        anyhow::bail!(
            "{flag} must be within {}{MAX_WAIT_S} s (got {v})",
            if zero_ok { "0.." } else { "(0, " }
        );
    }
    Ok(Duration::from_secs_f64(v))
}

impl ShmArgs {
    pub fn wait_strategy(&self, clock: ClockKind) -> WaitStrategy {
        match (self.wait, clock) {
            (Some(WaitArg::Spin), _) | (None, ClockKind::Realtime) => WaitStrategy::Spin,
            (Some(WaitArg::Park), _) | (None, ClockKind::Lockstep) => WaitStrategy::Park,
            (Some(WaitArg::SpinPark), _) => WaitStrategy::DEFAULT_SPIN_THEN_PARK,
        }
    }

    /// The per-answer wait; `--deadline-us` must fit in the period (`rate_hz`).
    pub fn answer_wait(&self, clock: ClockKind, rate_hz: f64) -> Result<AnswerWait> {
        let period_us = 1e6 / rate_hz;
        if !(self.deadline_us.is_finite()
            && self.deadline_us > 0.0
            && self.deadline_us <= period_us)
        {
            anyhow::bail!(
                "--deadline-us must be in (0, {period_us}] (the period at {rate_hz} Hz; got {})",
                self.deadline_us
            );
        }
        let safety = seconds_flag("--answer-timeout-s", self.answer_timeout_s, false)?;
        if self.give_up_after == 0 || self.give_up_after > 1000 {
            anyhow::bail!(
                "--give-up-after must be within 1..1000 (got {})",
                self.give_up_after
            );
        }
        Ok(match clock {
            ClockKind::Realtime => {
                AnswerWait::Deadline(Duration::from_nanos((self.deadline_us * 1e3) as u64))
            }
            ClockKind::Lockstep => AnswerWait::Lockstep {
                safety,
                give_up_after: self.give_up_after,
            },
        })
    }
}

/// The settings `run` and `serve` share, each overriding the `--config` file.
#[derive(Args)]
pub struct CommonArgs {
    /// A TOML file of settings (rt-loop/config.example.toml); the flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Loop rate, Hz (default 10000, the thesis's bench).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    #[command(flatten)]
    pub board: BoardArgs,
    /// Seed of the simulated bench's noise (default 1): the same seed gives the same run.
    #[arg(long)]
    pub seed: Option<u64>,
    /// The simulated object (default materials/sponge.toml).
    #[arg(long)]
    pub material: Option<PathBuf>,
    /// Bench file (`rt-loop identify-friction`): the RFOB subtracts its friction model in
    /// every experiment (abstraction and reproduction alike).
    #[arg(long)]
    pub bench: Option<PathBuf>,
    /// The experiment's ramp (for `serve`: the defaults a start command may override).
    #[command(flatten)]
    pub experiment: ExperimentArgs,
    /// The passivity layer (`--passivity auto|on|off` and its guards).
    #[command(flatten)]
    pub passivity: crate::passivity::PassivityArgs,
}

impl CommonArgs {
    /// The `--config` file (or the defaults) with these flags over it.
    pub fn resolve(&self) -> Result<RunConfig> {
        let mut c = match &self.config {
            Some(p) => RunConfig::load(p)?,
            None => RunConfig::default(),
        };
        if let Some(v) = self.rate_hz {
            c.rate_hz = v;
        }
        self.board.apply(&mut c)?;
        if let Some(v) = self.seed {
            c.seed = v;
        }
        if let Some(v) = &self.material {
            c.material = v.clone();
        }
        c.ramp.override_with(&self.experiment);
        self.passivity.apply(&mut c.passivity);
        if let Some(p) = &self.bench {
            c.params.friction = crate::control::friction::Friction::load(p)?;
        }
        Ok(c)
    }
}

#[derive(Args)]
pub struct ServeArgs {
    #[command(flatten)]
    pub common: CommonArgs,
    /// realtime: wall clock, fixed period, a deadline per step; lockstep: virtual time, as fast
    /// as possible, every step waits for its answer (deterministic).
    #[arg(long, value_enum, default_value = "realtime")]
    pub clock: ClockKind,
    /// Start this experiment at once and again whenever it finishes, until a stop command.
    #[arg(long, value_enum)]
    pub autostart: Option<ExperimentKind>,
    /// Record every experiment to DIR/<experiment>-<run>-<unix time>.parquet.
    #[arg(long)]
    pub record_dir: Option<PathBuf>,
    /// Reproduction/shadow: wait this long at the run's start for a server (0: start on the
    /// fallback at once; model rendering begins when a server attaches), s.
    #[arg(long, default_value_t = 0.0)]
    pub server_wait_s: f64,
    #[command(flatten)]
    pub shm: ShmArgs,
}

impl ServeArgs {
    /// The daemon's configuration; every flag checked.
    pub fn resolve(&self) -> Result<DaemonConfig> {
        let mut base = self.common.resolve()?;
        base.clock = self.clock;
        if base.board == BoardKind::Replay {
            bail!("serve runs on the simulated bench (--board sim) or a real board; the replay board ends with its data");
        }
        base.record = None;
        base.validate().map_err(|e| anyhow::anyhow!(e))?;
        let server_wait = seconds_flag("--server-wait-s", self.server_wait_s, true)?;
        let answer_wait = self.shm.answer_wait(self.clock, base.rate_hz)?;
        let (deadline, answer_timeout) = match answer_wait {
            AnswerWait::Deadline(d) => (d, Duration::from_secs_f64(self.shm.answer_timeout_s)),
            AnswerWait::Lockstep { safety, .. } => (
                Duration::from_nanos((self.shm.deadline_us * 1e3) as u64),
                safety,
            ),
        };
        Ok(DaemonConfig {
            base,
            instance: self.shm.instance.clone(),
            autostart: self.autostart,
            record_dir: self.record_dir.clone(),
            deadline,
            answer_timeout,
            server_wait,
            give_up_after: self.shm.give_up_after,
            answer_wait: self.shm.wait_strategy(self.clock),
        })
    }
}

#[derive(Args)]
pub struct RunArgs {
    #[command(flatten)]
    pub common: CommonArgs,
    /// The experiment (default abstraction; docs/physics.md, "The experiments").
    #[arg(long, value_enum)]
    pub experiment: Option<ExperimentKind>,
    /// realtime (wall clock, fixed period) or lockstep (virtual time, as fast as possible,
    /// deterministic; the default).
    #[arg(long, value_enum)]
    pub clock: Option<ClockKind>,
    /// Recording the replay board plays back.
    #[arg(long)]
    pub replay: Option<PathBuf>,
    /// F_max of each cycle, N, comma-separated (replaces --f-max-start/--f-max-step; e.g. a
    /// shuffled order).
    #[arg(long, value_delimiter = ',')]
    pub f_max_list: Option<Vec<f64>>,
    /// Partial unloads per cycle: after F_max, down to (1 - --minor-depth) F_max and up again.
    #[arg(long)]
    pub minor_loops: Option<u32>,
    /// Fraction of F_max a partial unload takes off (0..1).
    #[arg(long)]
    pub minor_depth: Option<f64>,
    /// A ramp turns round when the probe reaches this fraction of the position limit
    /// (default 0.8): an object too soft for F_max is pressed as deep as the travel allows.
    #[arg(long)]
    pub turn_depth_frac: Option<f64>,
    /// F_max never exceeds this, N (default 14; at most 15, the motor's continuous force).
    #[arg(long)]
    pub f_max_limit: Option<f64>,
    /// Hold at 0 N before each ramp, s.
    #[arg(long)]
    pub hold_zero: Option<f64>,
    /// Hold at F_max, s.
    #[arg(long)]
    pub hold_max: Option<f64>,
    /// Record to this file (.parquet, .csv or .mcap).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// The recording's format (default: from the --record file's extension).
    #[arg(long, value_enum)]
    pub format: Option<FormatArg>,
    /// Record every N-th step only.
    #[arg(long)]
    pub decimate: Option<u32>,
    /// Replace an existing recording at --record.
    #[arg(long)]
    pub overwrite: bool,
    /// Recorded trajectory (its time and position_x) for position replay.
    #[arg(long)]
    pub trajectory: Option<PathBuf>,
    /// Replay `identify-friction`'s free-air sweeps (x < 0, 0.5-60 mm/s each way, 67 s) instead
    /// of a trajectory: the bench's friction with no object touched, recorded for training
    /// (implies --experiment position-replay).
    #[arg(long)]
    pub friction_sweep: bool,
    /// Stop after this much loop time, s.
    #[arg(long)]
    pub duration: Option<f64>,
    /// Fit the reproduction fallback/built-in model to this recording first.
    #[arg(long)]
    pub fit_fallback: Option<PathBuf>,
    /// Write the summary as JSON here as well.
    #[arg(long)]
    pub summary_json: Option<PathBuf>,
    /// No progress line on the terminal.
    #[arg(long)]
    pub no_progress: bool,
    /// Reproduction/shadow model: the built-in spring-damper, or infer-server over shared memory.
    #[arg(long, value_enum, default_value = "builtin")]
    pub model: ModelArg,
    /// With --model shm: wait this long for infer-server to attach before the run (error if none), s.
    #[arg(long, default_value_t = 30.0)]
    pub server_wait_s: f64,
    /// With --model shm in lockstep: wait for every answer (default) — this is the safety timeout.
    #[command(flatten)]
    pub shm: ShmArgs,
    /// Create the segment and publish telemetry even without --model shm (live plots of any run).
    #[arg(long)]
    pub telemetry: bool,
}

impl RunArgs {
    /// The run's configuration: the `--config` file (or the defaults) with every flag over it.
    pub fn resolve(&self) -> Result<RunConfig> {
        let mut c = self.common.resolve()?;
        macro_rules! set {
            ($field:expr, $v:expr) => {
                if let Some(v) = $v.clone() {
                    $field = v;
                }
            };
        }
        set!(c.experiment, self.experiment);
        set!(c.clock, self.clock);
        set!(c.ramp.f_max_limit, self.f_max_limit);
        set!(c.ramp.hold_zero_s, self.hold_zero);
        set!(c.ramp.hold_max_s, self.hold_max);
        set!(c.ramp.f_max_list, self.f_max_list);
        set!(c.ramp.minor_loops, self.minor_loops);
        set!(c.ramp.minor_depth, self.minor_depth);
        set!(c.ramp.turn_depth_frac, self.turn_depth_frac);
        set!(c.decimate, self.decimate);
        if self.overwrite {
            c.overwrite = true;
        }
        if self.replay.is_some() {
            c.replay = self.replay.clone();
            if self.common.board.board.is_none() {
                c.board = BoardKind::Replay;
            }
        }
        if self.record.is_some() {
            c.record = self.record.clone();
        }
        if self.trajectory.is_some() {
            c.trajectory = self.trajectory.clone();
        }
        if self.friction_sweep {
            c.friction_sweep = true;
            if self.experiment.is_none() {
                c.experiment = ExperimentKind::PositionReplay;
            }
        }
        if self.duration.is_some() {
            c.max_duration_s = self.duration;
        }
        if let Some(f) = self.format {
            c.format = Some(match f {
                FormatArg::Parquet => Format::Parquet,
                FormatArg::Csv => Format::Csv,
                FormatArg::Mcap => Format::Mcap,
            });
        }
        if let Some(p) = &self.fit_fallback {
            c.reproduction.fallback = SpringDamper::fit_recording(p, "rtob_force")?;
            eprintln!("rt-loop: fallback fitted: {:?}", c.reproduction.fallback);
        }
        Ok(c)
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum FormatArg {
    Parquet,
    Csv,
    /// MCAP (Foxglove, PlotJuggler): docs/recording-format.md
    Mcap,
}

#[derive(Args)]
pub struct FeaturesArgs {
    /// The series to import (.csv or .parquet): time, position and force columns.
    #[arg(long)]
    pub input: PathBuf,
    /// Column name; `t` also finds a header `t [ms]` (and takes its unit).
    #[arg(long)]
    pub time_col: String,
    /// Displacement column (into the object), as --time-col.
    #[arg(long)]
    pub position_col: String,
    /// Force column, as --time-col.
    #[arg(long)]
    pub force_col: String,
    /// Default: the header's unit (`t [ms]`), else s. Refused if it contradicts the header.
    #[arg(long, value_enum)]
    pub time_unit: Option<TimeUnit>,
    /// Default: the header's unit, else m.
    #[arg(long, value_enum)]
    pub position_unit: Option<PositionUnit>,
    /// Default: the header's unit, else N.
    #[arg(long, value_enum)]
    pub force_unit: Option<ForceUnit>,
    /// Output recording (.parquet, or .csv).
    #[arg(long)]
    pub out: PathBuf,
    /// Velocity filter gain, rad/s (default: the loop's 30, capped at g dt = 0.2).
    #[arg(long)]
    pub g_v: Option<f64>,
    /// Acceleration filter gain, rad/s (default: the loop's 100, capped at g dt = 0.2).
    #[arg(long)]
    pub g_a: Option<f64>,
    /// Contact starts above this force, N (default: from the force's noise floor and range).
    #[arg(long)]
    pub contact_on_n: Option<f64>,
    /// Contact ends below this force, N (default: half the derived contact_on_n).
    #[arg(long)]
    pub contact_off_n: Option<f64>,
    /// A period above this multiple of the median period is a gap, refused.
    #[arg(long, default_value_t = crate::import::DEFAULT_MAX_GAP_FACTOR)]
    pub max_gap_factor: f64,
    /// JSON object recorded in the metadata as `preprocessing` (what a caller did before).
    #[arg(long)]
    pub meta_json: Option<String>,
}

#[derive(Args)]
pub struct FitArgs {
    /// The recording to fit (.parquet or .csv).
    #[arg(long)]
    pub input: PathBuf,
    /// The force column the law is fitted to.
    #[arg(long, default_value = "rtob_force")]
    pub force_col: String,
}

impl FeaturesArgs {
    /// The import's options (the encoder resolution of the thesis bench).
    pub fn options(&self) -> ImportOptions {
        ImportOptions {
            input: self.input.clone(),
            out: self.out.clone(),
            time_col: self.time_col.clone(),
            position_col: self.position_col.clone(),
            force_col: self.force_col.clone(),
            time_unit: self.time_unit,
            position_unit: self.position_unit,
            force_unit: self.force_unit,
            g_v: self.g_v,
            g_a: self.g_a,
            contact_on_n: self.contact_on_n,
            contact_off_n: self.contact_off_n,
            max_gap_factor: self.max_gap_factor,
            meters_per_count: 5e-6,
            extra_meta: self.meta_json.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    fn parse(args: &[&str]) -> Cmd {
        Cli::try_parse_from(args).unwrap().cmd
    }

    /// `run` and `serve` read the shared flags (and the experiment options) the same way.
    #[test]
    fn run_and_serve_share_their_settings_and_experiment_options() {
        Cli::command().debug_assert();
        let shared = [
            "--rate-hz",
            "2000",
            "--seed",
            "9",
            "--ramp-rate",
            "3.5",
            "--cycles",
            "2",
            "--f-max-start",
            "1.5",
            "--f-max-step",
            "0.5",
        ];
        let Cmd::Run(run) = parse(&[&["rt-loop", "run"][..], &shared].concat()) else {
            panic!("run")
        };
        let Cmd::Serve(serve) = parse(&[&["rt-loop", "serve"][..], &shared].concat()) else {
            panic!("serve")
        };
        let r = run.resolve().unwrap();
        let d = serve.resolve().unwrap();
        assert_eq!((r.rate_hz, r.seed), (2000.0, 9));
        assert_eq!(r.ramp, d.base.ramp);
        assert_eq!((d.base.rate_hz, d.base.seed), (2000.0, 9));
        assert_eq!(
            (
                r.ramp.ramp_rate,
                r.ramp.cycles,
                r.ramp.f_max_start,
                r.ramp.f_max_step
            ),
            (3.5, 2, 1.5, 0.5)
        );
        // serve's own rules: its clock flag wins, no single recording, no replay board
        assert_eq!(d.base.clock, ClockKind::Realtime);
        assert_eq!(d.base.record, None);
        let Cmd::Serve(replay) = parse(&["rt-loop", "serve", "--board", "replay"]) else {
            panic!("serve")
        };
        assert!(replay.resolve().is_err());
    }
}
