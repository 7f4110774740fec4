//! `rt-loop`: run an experiment on a board (`run`), import a measured series into the
//! recording format (`features`), or fit the spring-damper fallback (`fit`).

use clap::{Args, Parser, Subcommand};
use rt_loop::config::{BoardKind, ClockKind, ExperimentKind, RunConfig};
use rt_loop::import::{ForceUnit, ImportOptions, PositionUnit, TimeUnit};
use rt_loop::record::Format;
use rt_loop::shm_model::{AnswerWait, ShmModel};
use shm_ring::WaitStrategy;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "rt-loop",
    version,
    about = "Haptics real-time loop: DOB/RFOB force control on a (simulated) bench"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

// Parsed once at start-up: the size of its largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Cmd {
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
}

#[derive(Args)]
struct IdentifyArgs {
    #[arg(long)]
    config: Option<PathBuf>,
    #[arg(long)]
    seed: Option<u64>,
    /// Bench file to write (TOML, `[friction]`).
    #[arg(long, default_value = "bench.toml")]
    out: PathBuf,
    /// Sweep speeds, mm/s, comma-separated (default 0.5 to 60 mm/s, 12 speeds).
    #[arg(long, value_delimiter = ',')]
    speeds_mm_s: Option<Vec<f64>>,
    /// Write the sweep points, fit and (simulated bench) true values here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum ModelArg {
    /// The built-in spring-damper (no server).
    Builtin,
    /// The simulated object's own physics (the material file), driven by the measured
    /// motion: the rendering floor (rt-loop's oracle model, no server).
    Oracle,
    /// infer-server over shared memory (segment /haptics-<instance>).
    Shm,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum WaitArg {
    Spin,
    Park,
    SpinPark,
}

/// How the loop talks to infer-server (shared by `run --model shm` and `serve`).
#[derive(Args, Clone)]
struct ShmArgs {
    /// Segment /haptics-<instance> (infer-server --instance NAME attaches to it).
    #[arg(long, default_value = "default")]
    instance: String,
    /// Realtime clock: per-step deadline for the server's answer (late = fallback), us.
    #[arg(long, default_value_t = 50.0)]
    deadline_us: f64,
    /// Lockstep clock: safety timeout per answer (the loop waits for every answer), s.
    #[arg(long, default_value_t = 5.0)]
    answer_timeout_s: f64,
    /// How the loop waits for an answer: default spin in realtime, park in lockstep.
    #[arg(long, value_enum)]
    wait: Option<WaitArg>,
    /// Lockstep clock: after this many safety timeouts in a row the server is treated as gone
    /// (steps fall back without waiting) until its heartbeat moves again.
    #[arg(long, default_value_t = rt_loop::shm_model::DEFAULT_GIVE_UP_AFTER)]
    give_up_after: u32,
}

/// Longest wait a flag may ask for, s (a day: beyond it a typo, and `Duration` overflows near
/// 1e19 s).
const MAX_WAIT_S: f64 = 86_400.0;

/// `v` seconds as a Duration when `0 <= v <= MAX_WAIT_S` (`> 0` unless `zero_ok`), else the
/// error for `flag`.
fn seconds_flag(flag: &str, v: f64, zero_ok: bool) -> anyhow::Result<Duration> {
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
    fn wait_strategy(&self, clock: ClockKind) -> WaitStrategy {
        match (self.wait, clock) {
            (Some(WaitArg::Spin), _) | (None, ClockKind::Realtime) => WaitStrategy::Spin,
            (Some(WaitArg::Park), _) | (None, ClockKind::Lockstep) => WaitStrategy::Park,
            (Some(WaitArg::SpinPark), _) => WaitStrategy::DEFAULT_SPIN_THEN_PARK,
        }
    }

    /// The per-answer wait; `--deadline-us` must fit in the period (`rate_hz`).
    fn answer_wait(&self, clock: ClockKind, rate_hz: f64) -> anyhow::Result<AnswerWait> {
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

#[derive(Args)]
struct ServeArgs {
    #[arg(long)]
    config: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "realtime")]
    clock: ClockKind,
    #[arg(long)]
    rate_hz: Option<f64>,
    #[arg(long, value_enum)]
    board: Option<BoardKind>,
    #[arg(long)]
    seed: Option<u64>,
    #[arg(long)]
    material: Option<PathBuf>,
    /// Bench file (`rt-loop identify-friction`): the RFOB subtracts its friction model.
    #[arg(long)]
    bench: Option<PathBuf>,
    /// Default ramp rate of abstraction runs (a start command may override), N/s.
    #[arg(long)]
    ramp_rate: Option<f64>,
    #[arg(long)]
    cycles: Option<u32>,
    #[arg(long)]
    f_max_start: Option<f64>,
    #[arg(long)]
    f_max_step: Option<f64>,
    /// Start this experiment at once and again whenever it finishes, until a stop command.
    #[arg(long, value_enum)]
    autostart: Option<ExperimentKind>,
    /// Record every experiment to DIR/<experiment>-<run>-<unix time>.parquet.
    #[arg(long)]
    record_dir: Option<PathBuf>,
    /// Reproduction/shadow: wait this long at the run's start for a server (0: start on the
    /// fallback at once; model rendering begins when a server attaches), s.
    #[arg(long, default_value_t = 0.0)]
    server_wait_s: f64,
    #[command(flatten)]
    shm: ShmArgs,
}

#[derive(Args)]
struct RunArgs {
    #[arg(long)]
    config: Option<PathBuf>,
    #[arg(long, value_enum)]
    experiment: Option<ExperimentKind>,
    #[arg(long, value_enum)]
    clock: Option<ClockKind>,
    #[arg(long, value_enum)]
    board: Option<BoardKind>,
    /// Recording the replay board plays back.
    #[arg(long)]
    replay: Option<PathBuf>,
    #[arg(long)]
    rate_hz: Option<f64>,
    #[arg(long)]
    seed: Option<u64>,
    #[arg(long)]
    material: Option<PathBuf>,
    /// Bench file (`rt-loop identify-friction`): the RFOB subtracts its friction model in
    /// every experiment (abstraction and reproduction alike).
    #[arg(long)]
    bench: Option<PathBuf>,
    /// F_max of each cycle, N, comma-separated (replaces --f-max-start/--f-max-step; e.g. a
    /// shuffled order).
    #[arg(long, value_delimiter = ',')]
    f_max_list: Option<Vec<f64>>,
    /// Partial unloads per cycle: after F_max, down to (1 - --minor-depth) F_max and up again.
    #[arg(long)]
    minor_loops: Option<u32>,
    /// Fraction of F_max a partial unload takes off (0..1).
    #[arg(long)]
    minor_depth: Option<f64>,
    /// Force ramp rate, N/s.
    #[arg(long)]
    ramp_rate: Option<f64>,
    #[arg(long)]
    cycles: Option<u32>,
    #[arg(long)]
    f_max_start: Option<f64>,
    #[arg(long)]
    f_max_step: Option<f64>,
    #[arg(long)]
    f_max_limit: Option<f64>,
    /// Hold at 0 N before each ramp, s.
    #[arg(long)]
    hold_zero: Option<f64>,
    /// Hold at F_max, s.
    #[arg(long)]
    hold_max: Option<f64>,
    /// Record to this file (.parquet, or .csv).
    #[arg(long)]
    record: Option<PathBuf>,
    #[arg(long, value_enum)]
    format: Option<FormatArg>,
    /// Record every N-th step only.
    #[arg(long)]
    decimate: Option<u32>,
    /// Replace an existing recording at --record.
    #[arg(long)]
    overwrite: bool,
    /// Recorded trajectory (its time and position_x) for position replay.
    #[arg(long)]
    trajectory: Option<PathBuf>,
    /// Stop after this much loop time, s.
    #[arg(long)]
    duration: Option<f64>,
    /// Fit the reproduction fallback/built-in model to this recording first.
    #[arg(long)]
    fit_fallback: Option<PathBuf>,
    /// Write the summary as JSON here as well.
    #[arg(long)]
    summary_json: Option<PathBuf>,
    #[arg(long)]
    no_progress: bool,
    /// Reproduction/shadow model: the built-in spring-damper, or infer-server over shared memory.
    #[arg(long, value_enum, default_value = "builtin")]
    model: ModelArg,
    /// With --model shm: wait this long for infer-server to attach before the run (error if none), s.
    #[arg(long, default_value_t = 30.0)]
    server_wait_s: f64,
    /// With --model shm in lockstep: wait for every answer (default) — this is the safety timeout.
    #[command(flatten)]
    shm: ShmArgs,
    /// Create the segment and publish telemetry even without --model shm (live plots of any run).
    #[arg(long)]
    telemetry: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum FormatArg {
    Parquet,
    Csv,
}

#[derive(Args)]
struct FeaturesArgs {
    #[arg(long)]
    input: PathBuf,
    /// Column name; `t` also finds a header `t [ms]` (and takes its unit).
    #[arg(long)]
    time_col: String,
    #[arg(long)]
    position_col: String,
    #[arg(long)]
    force_col: String,
    /// Default: the header's unit (`t [ms]`), else s. Refused if it contradicts the header.
    #[arg(long, value_enum)]
    time_unit: Option<TimeUnit>,
    /// Default: the header's unit, else m.
    #[arg(long, value_enum)]
    position_unit: Option<PositionUnit>,
    /// Default: the header's unit, else N.
    #[arg(long, value_enum)]
    force_unit: Option<ForceUnit>,
    /// Output recording (.parquet, or .csv).
    #[arg(long)]
    out: PathBuf,
    /// Velocity filter gain, rad/s (default: the loop's 30, capped at g dt = 0.2).
    #[arg(long)]
    g_v: Option<f64>,
    /// Acceleration filter gain, rad/s (default: the loop's 100, capped at g dt = 0.2).
    #[arg(long)]
    g_a: Option<f64>,
    /// Contact starts above this force, N (default: from the force's noise floor and range).
    #[arg(long)]
    contact_on_n: Option<f64>,
    /// Contact ends below this force, N (default: half the derived contact_on_n).
    #[arg(long)]
    contact_off_n: Option<f64>,
    /// A period above this multiple of the median period is a gap, refused.
    #[arg(long, default_value_t = rt_loop::import::DEFAULT_MAX_GAP_FACTOR)]
    max_gap_factor: f64,
    /// JSON object recorded in the metadata as `preprocessing` (what a caller did before).
    #[arg(long)]
    meta_json: Option<String>,
}

#[derive(Args)]
struct FitArgs {
    #[arg(long)]
    input: PathBuf,
    #[arg(long, default_value = "rtob_force")]
    force_col: String,
}

struct Bar(indicatif::ProgressBar);

impl rt_loop::run::Progress for Bar {
    fn update(&mut self, t: f64) {
        self.0.set_position((t * 1000.0) as u64);
    }
    fn finish(&mut self) {
        self.0.finish_and_clear();
    }
}

fn resolve(a: &RunArgs) -> anyhow::Result<RunConfig> {
    let mut c = match &a.config {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::default(),
    };
    macro_rules! set {
        ($field:expr, $v:expr) => {
            if let Some(v) = $v.clone() {
                $field = v;
            }
        };
    }
    set!(c.experiment, a.experiment);
    set!(c.clock, a.clock);
    set!(c.board, a.board);
    set!(c.rate_hz, a.rate_hz);
    set!(c.seed, a.seed);
    set!(c.material, a.material);
    set!(c.ramp.ramp_rate, a.ramp_rate);
    set!(c.ramp.cycles, a.cycles);
    set!(c.ramp.f_max_start, a.f_max_start);
    set!(c.ramp.f_max_step, a.f_max_step);
    set!(c.ramp.f_max_limit, a.f_max_limit);
    set!(c.ramp.hold_zero_s, a.hold_zero);
    set!(c.ramp.hold_max_s, a.hold_max);
    set!(c.ramp.f_max_list, a.f_max_list);
    set!(c.ramp.minor_loops, a.minor_loops);
    set!(c.ramp.minor_depth, a.minor_depth);
    set!(c.decimate, a.decimate);
    if let Some(p) = &a.bench {
        c.params.friction = rt_loop::friction::Friction::load(p)?;
    }
    if a.overwrite {
        c.overwrite = true;
    }
    if a.replay.is_some() {
        c.replay = a.replay.clone();
        if a.board.is_none() {
            c.board = BoardKind::Replay;
        }
    }
    if a.record.is_some() {
        c.record = a.record.clone();
    }
    if a.trajectory.is_some() {
        c.trajectory = a.trajectory.clone();
    }
    if a.duration.is_some() {
        c.max_duration_s = a.duration;
    }
    if let Some(f) = a.format {
        c.format = Some(match f {
            FormatArg::Parquet => Format::Parquet,
            FormatArg::Csv => Format::Csv,
        });
    }
    if let Some(p) = &a.fit_fallback {
        c.reproduction.fallback = fit(p, "rtob_force")?;
        eprintln!("rt-loop: fallback fitted: {:?}", c.reproduction.fallback);
    }
    Ok(c)
}

fn fit(path: &std::path::Path, force_col: &str) -> anyhow::Result<rt_loop::model::SpringDamper> {
    let cols = rt_loop::record::read::read_columns(path, &["position_x", "velocity", force_col])?;
    rt_loop::model::SpringDamper::fit(&cols[0], &cols[1], &cols[2])
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

fn cmd_run(a: &RunArgs) -> anyhow::Result<ExitCode> {
    let cfg = resolve(a)?;
    cfg.validate().map_err(|e| anyhow::anyhow!(e))?;
    let show = !a.no_progress && cfg.clock == ClockKind::Lockstep;
    let mut bar = None;
    if show {
        let total = match rt_loop::run::build_experiment(&cfg, None) {
            Ok(e) => e.duration(),
            Err(_) => 0.0,
        };
        let pb = indicatif::ProgressBar::with_draw_target(
            Some((total * 1000.0) as u64),
            indicatif::ProgressDrawTarget::stderr(),
        );
        pb.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {elapsed_precise} [{bar:40}] {percent}% loop time {msg}",
            )
            .expect("valid template"),
        );
        bar = Some(Bar(pb));
    }
    let uses_model = matches!(
        cfg.experiment,
        ExperimentKind::Reproduction | ExperimentKind::Shadow
    );
    let mut segment = None;
    let mut counters = None;
    let mut home = None;
    let mut model: Option<Box<dyn rt_loop::model::ForceModel>> = None;
    if a.model == ModelArg::Oracle {
        let (material, _) = rt_loop::material::Material::load(&cfg.material)?;
        // in the loop's force units: K_fn / K_f of the simulated bench (rt_loop::oracle)
        let scale = match cfg.board {
            BoardKind::Sim => cfg.params.k_fn / cfg.sim.force_constant,
            BoardKind::Replay => 1.0,
        };
        model = Some(Box::new(rt_loop::oracle::OracleModel::new(
            &material,
            cfg.rate_hz,
            scale,
        )));
    }
    if a.model == ModelArg::Shm || a.telemetry {
        // every flag checked before anything is created
        let answer_wait = a.shm.answer_wait(cfg.clock, cfg.rate_hz)?;
        let server_wait = seconds_flag("--server-wait-s", a.server_wait_s, true)?;
        let seg = rt_loop::shm_io::create_segment(&a.shm.instance, a.shm.wait_strategy(cfg.clock))?;
        let client = seg.client;
        if a.model == ModelArg::Shm && uses_model {
            // The wait for the server (and its model) happens in the model's begin_run, after
            // the loop wrote 0 A and armed the watchdog; the run is refused if none comes.
            counters = Some(client.counters.clone());
            let h = std::sync::Arc::new(std::sync::Mutex::new(Some(client)));
            model = ShmModel::borrow_from(&h, answer_wait, server_wait).map(|m| {
                Box::new(m.require_server(&a.shm.instance)) as Box<dyn rt_loop::model::ForceModel>
            });
            home = Some(h);
        }
        segment = Some(seg.io);
    }
    let mut summary = rt_loop::run::run_with(
        &cfg,
        model,
        bar.as_mut().map(|b| b as &mut dyn rt_loop::run::Progress),
        segment.as_mut(),
    )?;
    summary.shm = counters.map(|c| c.snapshot());
    // the client is back home once the run's loop is dropped: its round-trip histogram
    if let Some(c) = home.as_ref().and_then(|h| h.lock().ok()?.take()) {
        let h = &c.round_trip_ns;
        if !h.is_empty() {
            let us = |q: f64| h.value_at_quantile(q) as f64 / 1e3;
            summary.round_trip_us = Some(rt_loop::run::Percentiles {
                p50: us(0.5),
                p99: us(0.99),
                p999: us(0.999),
                max: h.max() as f64 / 1e3,
                count: h.len(),
            });
        }
    }
    print_summary(&summary);
    if let Some(p) = &a.summary_json {
        std::fs::write(p, serde_json::to_string_pretty(&summary)?)?;
    }
    Ok(if summary.ok() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn print_summary(s: &rt_loop::run::RunSummary) {
    eprintln!(
        "rt-loop: {} ({} clock): {} steps, {:.3} s loop time in {:.2} s wall ({:.0} steps/s), stop: {}",
        s.experiment, s.clock, s.steps, s.loop_time_s, s.wall_s, s.steps_per_s, s.stop
    );
    if let Some(r) = &s.recorder {
        eprintln!(
            "rt-loop: recorder: {} rows pushed, {} received, {} written, {} dropped, {} bytes -> {}",
            s.rows_pushed,
            r.rows_received,
            r.rows_written,
            s.drops,
            r.bytes,
            r.path.as_ref().map_or("-".into(), |p| p.display().to_string())
        );
        if let Some(e) = &r.error {
            eprintln!("rt-loop: RECORDER ERROR: {e}");
        }
    }
    if let Some(m) = &s.model {
        eprintln!(
            "rt-loop: model: {} served, {} fallbacks",
            m.served, m.fallbacks
        );
    }
    if let Some(c) = &s.shm {
        eprintln!(
            "rt-loop: shm: {} sent, {} answered in time, {} late (deadline misses), {} without a server, {} flagged by the server, {} ring full, {} stale answers discarded, server lost {} time(s), {} attachment(s) seen",
            c.sent, c.answered, c.late, c.no_server, c.flagged, c.ring_full, c.stale_discarded, c.server_lost, c.attachments_seen
        );
    }
    if let (Some(l), Some(r)) = (&s.ladder, &s.degraded_reasons) {
        eprintln!(
            "rt-loop: ladder: {} on time, {} late one, {} held, {} fallback; max transition step {:.4} N over {} transition steps",
            l.on_time, l.late_one, l.held, l.fallback, s.max_transition_step_n, s.transition_steps
        );
        eprintln!(
            "rt-loop: not on time because: {} late, {} no server, {} flagged, {} ring full, {} server lost, {} hung, {} rejected",
            r.late, r.no_server, r.flagged, r.ring_full, r.server_lost, r.hung, r.rejected
        );
    }
    if s.long_steps > 0 {
        eprintln!(
            "rt-loop: {} long steps (over {} periods; filters took bounded updates), longest {:.2} ms",
            s.long_steps,
            rt_loop::rig::LONG_STEP_FACTOR,
            s.max_step_ms
        );
    }
    if let Some(r) = &s.round_trip_us {
        eprintln!(
            "rt-loop: round trip (send to matching answer): p50 {:.2} us, p99 {:.2} us, p99.9 {:.2} us, max {:.1} us over {} answers",
            r.p50, r.p99, r.p999, r.max, r.count
        );
    }
    if let Some(j) = &s.jitter {
        eprintln!(
            "rt-loop: realtime: period {} us, overruns {}, period jitter p50 {:.1} us p99 {:.1} us p99.9 {:.1} us max {:.1} us; wake latency p50 {:.1} p99 {:.1} max {:.1} us",
            j.period_us,
            j.overruns,
            j.period_jitter.p50_us,
            j.period_jitter.p99_us,
            j.period_jitter.p999_us,
            j.period_jitter.max_us,
            j.wake_latency.p50_us,
            j.wake_latency.p99_us,
            j.wake_latency.max_us
        );
    }
}

fn cmd_features(a: &FeaturesArgs) -> anyhow::Result<ExitCode> {
    let opts = ImportOptions {
        input: a.input.clone(),
        out: a.out.clone(),
        time_col: a.time_col.clone(),
        position_col: a.position_col.clone(),
        force_col: a.force_col.clone(),
        time_unit: a.time_unit,
        position_unit: a.position_unit,
        force_unit: a.force_unit,
        g_v: a.g_v,
        g_a: a.g_a,
        contact_on_n: a.contact_on_n,
        contact_off_n: a.contact_off_n,
        max_gap_factor: a.max_gap_factor,
        meters_per_count: 5e-6,
        extra_meta: a.meta_json.clone(),
    };
    let r = rt_loop::import::import(&opts)?;
    eprintln!(
        "rt-loop: wrote {} rows to {} ({:.3} Hz; g_v {:.3}, g_a {:.3} rad/s; contact {:.4}/{:.4} N, \
         force noise floor {:.2e} N; {} cycles)",
        r.rows,
        a.out.display(),
        r.timing.sample_rate_hz,
        r.g_v,
        r.g_a,
        r.features.contact_on_n,
        r.features.contact_off_n,
        r.force_noise_floor_n,
        r.cycles
    );
    Ok(ExitCode::SUCCESS)
}

fn cmd_serve(a: &ServeArgs) -> anyhow::Result<ExitCode> {
    let mut base = match &a.config {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::default(),
    };
    base.clock = a.clock;
    if let Some(v) = a.rate_hz {
        base.rate_hz = v;
    }
    if let Some(v) = a.board {
        base.board = v;
    }
    if base.board != BoardKind::Sim {
        anyhow::bail!("serve runs on the simulated bench (--board sim) or a real board; the replay board ends with its data");
    }
    if let Some(v) = a.seed {
        base.seed = v;
    }
    if let Some(v) = &a.material {
        base.material = v.clone();
    }
    if let Some(v) = a.ramp_rate {
        base.ramp.ramp_rate = v;
    }
    if let Some(v) = a.cycles {
        base.ramp.cycles = v;
    }
    if let Some(v) = a.f_max_start {
        base.ramp.f_max_start = v;
    }
    if let Some(v) = a.f_max_step {
        base.ramp.f_max_step = v;
    }
    if let Some(p) = &a.bench {
        base.params.friction = rt_loop::friction::Friction::load(p)?;
    }
    base.record = None;
    base.validate().map_err(|e| anyhow::anyhow!(e))?;
    let server_wait = seconds_flag("--server-wait-s", a.server_wait_s, true)?;
    let answer_wait = a.shm.answer_wait(a.clock, base.rate_hz)?;
    let (deadline, answer_timeout) = match answer_wait {
        AnswerWait::Deadline(d) => (d, Duration::from_secs_f64(a.shm.answer_timeout_s)),
        AnswerWait::Lockstep { safety, .. } => (
            Duration::from_nanos((a.shm.deadline_us * 1e3) as u64),
            safety,
        ),
    };
    let cfg = rt_loop::serve::ServeConfig {
        base,
        instance: a.shm.instance.clone(),
        autostart: a.autostart,
        record_dir: a.record_dir.clone(),
        deadline,
        answer_timeout,
        server_wait,
        give_up_after: a.shm.give_up_after,
        answer_wait: a.shm.wait_strategy(a.clock),
    };
    rt_loop::serve::serve(&cfg)?;
    Ok(ExitCode::SUCCESS)
}

fn cmd_identify_friction(a: &IdentifyArgs) -> anyhow::Result<ExitCode> {
    let mut cfg = match &a.config {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::default(),
    };
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    let mut plan = rt_loop::friction_id::SweepPlan::default();
    if let Some(v) = &a.speeds_mm_s {
        plan.speeds_mps = v.iter().map(|s| s * 1e-3).collect();
    }
    let args: Vec<String> = std::env::args().skip(1).collect();
    let command = format!("rt-loop {}", args.join(" "));
    let id = rt_loop::friction_id::identify(&cfg, &plan)?;
    rt_loop::friction_id::report(&id, &command, &a.out, a.json.as_deref())?;
    Ok(ExitCode::SUCCESS)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Ctrl-C / SIGTERM: stop at the next step with 0 A and a complete recording.
    rt_loop::run::install_stop_signals();
    let r = match &cli.cmd {
        Cmd::Run(a) => cmd_run(a),
        Cmd::Features(a) => cmd_features(a),
        Cmd::Serve(a) => cmd_serve(a),
        Cmd::IdentifyFriction(a) => cmd_identify_friction(a),
        Cmd::Fit(a) => fit(&a.input, &a.force_col).map(|sd| {
            println!(
                "[reproduction.fallback]\nk1 = {}\nk2 = {}\nb = {}",
                sd.k1, sd.k2, sd.b
            );
            ExitCode::SUCCESS
        }),
    };
    match r {
        Ok(c) => c,
        Err(e) => {
            eprintln!("rt-loop: error: {e:#}");
            ExitCode::from(2)
        }
    }
}
