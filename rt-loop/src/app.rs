//! What rt-loop's subcommands do, given their parsed arguments ([`crate::cli`]) and the
//! process's shutdown signal: [`run`] dispatches; `main` only parses and calls it. Each command
//! turns its arguments into the library's configuration and calls the library (the run, the
//! daemon, the import, the friction identification), then reports.

use crate::cli::{seconds_flag, Cmd, FitArgs, IdentifyArgs, ModelArg, RunArgs, ServeArgs};
use crate::config::{BoardKind, ClockKind, ExperimentKind, RunConfig};
use crate::serving::model::SpringDamper;
use crate::serving::shm_model::ShmModel;
use crate::stop::Shutdown;
use anyhow::Result;
use std::process::ExitCode;

/// Runs the subcommand until it ends or `shutdown` is requested (SIGINT/SIGTERM: a run ends at
/// 0 A with its recording complete).
pub fn run(cmd: &Cmd, shutdown: &Shutdown) -> Result<ExitCode> {
    match cmd {
        Cmd::Run(a) => run_experiment(a, shutdown),
        Cmd::Features(a) => import_features(a),
        Cmd::Serve(a) => serve(a, shutdown),
        Cmd::IdentifyFriction(a) => identify_friction(a),
        Cmd::Fit(a) => fit(a),
        Cmd::Board(b) => board(b),
        Cmd::ObjectForce(a) => crate::object_force::run(a).map(|()| ExitCode::SUCCESS),
    }
}

struct Bar(indicatif::ProgressBar);

impl crate::run::Progress for Bar {
    fn update(&mut self, t: f64) {
        self.0.set_position((t * 1000.0) as u64);
    }
    fn finish(&mut self) {
        self.0.finish_and_clear();
    }
}

/// `rt-loop run`: one experiment, its summary on stderr (and as JSON with --summary-json).
/// Exit status 1 when the run did not end as planned or lost rows.
pub fn run_experiment(a: &RunArgs, shutdown: &Shutdown) -> Result<ExitCode> {
    let cfg = a.resolve()?;
    cfg.validate().map_err(|e| anyhow::anyhow!(e))?;
    let show = !a.no_progress && cfg.clock == ClockKind::Lockstep;
    let mut bar = None;
    if show {
        let total = match crate::run::build_experiment(&cfg, None) {
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
    let mut model: Option<Box<dyn crate::serving::model::ForceModel>> = None;
    if a.model == ModelArg::Oracle {
        let (material, _) = crate::object::material::Material::load(&cfg.material)?;
        // in the loop's force units: K_fn / K_f of the simulated bench (crate::object::oracle)
        let scale = match cfg.board {
            BoardKind::Sim => cfg.params.k_fn / cfg.sim.force_constant,
            BoardKind::Replay | BoardKind::S826 { .. } => 1.0,
        };
        model = Some(Box::new(crate::object::oracle::OracleModel::new(
            &material,
            cfg.rate_hz,
            scale,
        )));
    }
    if a.model == ModelArg::Shm || a.telemetry {
        // every flag checked before anything is created
        let answer_wait = a.shm.answer_wait(cfg.clock, cfg.rate_hz)?;
        let server_wait = seconds_flag("--server-wait-s", a.server_wait_s, true)?;
        let seg = crate::serving::shm_io::create_segment(
            &a.shm.instance,
            a.shm.wait_strategy(cfg.clock),
        )?;
        let mut client = seg.client;
        client.stop_on(shutdown.clone());
        if a.model == ModelArg::Shm && uses_model {
            // The wait for the server (and its model) happens in the model's begin_run, after
            // the loop wrote 0 A and armed the watchdog; the run is refused if none comes.
            counters = Some(client.counters.clone());
            model = Some(Box::new(
                ShmModel::new(client, answer_wait, server_wait).require_server(&a.shm.instance),
            ));
        }
        // Who we are (clock, board, rate, feature filters) before the server attaches: it checks a model's
        // `haptics.step_s` against this rate when it activates the start model, which it does
        // as soon as it attaches, before the run begins (and publishes the rest).
        let mut io = seg.io;
        io.set_identity(&cfg);
        io.publish_status();
        segment = Some(io);
    }
    let outcome = crate::run::run_with(
        &cfg,
        model,
        shutdown,
        bar.as_mut().map(|b| b as &mut dyn crate::run::Progress),
        segment
            .as_mut()
            .map(|s| s as &mut dyn crate::serving::sink::StepSink),
    );
    let mut summary = outcome.result?;
    summary.shm = counters.map(|c| c.snapshot());
    // the served model came back with the result: its round-trip histogram
    if let Some(m) = outcome.model.and_then(ShmModel::from_model) {
        summary.round_trip_us = crate::percentiles::Percentiles::of(&m.client().round_trip_ns);
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

/// The run's summary, one line per part, on stderr.
pub fn print_summary(s: &crate::run::RunSummary) {
    eprintln!(
        "rt-loop: {} ({} clock): {} steps, {:.3} s loop time in {:.2} s wall ({:.0} steps/s), stop: {}",
        s.experiment, s.clock, s.steps, s.loop_time_s, s.wall_s, s.steps_per_s, s.stop
    );
    if let Some(t) = s.ramp_turns.filter(|t| t.cycles_turned > 0) {
        eprintln!(
            "rt-loop: ramps: {} cycle(s) turned round at the depth bound {:.1} mm before their F_max (the object is too soft for it within the travel); later cycles capped at {:.2} N",
            t.cycles_turned,
            t.turn_depth_m * 1e3,
            t.f_cap_n
        );
    }
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
            "rt-loop: ladder: {} on time, {} late one, {} held, {} fallback, {} saturated at the force limit; max transition step {:.4} N over {} transition steps",
            l.on_time, l.late_one, l.held, l.fallback, l.saturated, s.max_transition_step_n, s.transition_steps
        );
        eprintln!(
            "rt-loop: not on time because: {} late, {} no server, {} flagged, {} ring full, {} server lost, {} hung, {} rejected",
            r.late, r.no_server, r.flagged, r.ring_full, r.server_lost, r.hung, r.rejected
        );
    }
    if let Some(p) = &s.passivity {
        eprintln!("rt-loop: {p}");
    }
    if s.long_steps > 0 {
        eprintln!(
            "rt-loop: {} long steps (over {} periods; filters took bounded updates), longest {:.2} ms",
            s.long_steps,
            crate::control::rig::LONG_STEP_FACTOR,
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

/// `rt-loop features`: a measured series into the recording format.
pub fn import_features(a: &crate::cli::FeaturesArgs) -> Result<ExitCode> {
    let opts = a.options();
    let r = crate::import::import(&opts)?;
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

/// `rt-loop serve`: the daemon until shutdown.
pub fn serve(a: &ServeArgs, shutdown: &Shutdown) -> Result<ExitCode> {
    crate::daemon::run(&a.resolve()?, shutdown)?;
    Ok(ExitCode::SUCCESS)
}

/// `rt-loop fit`: the spring-damper fallback fitted to a recording, as TOML on stdout.
pub fn fit(a: &FitArgs) -> Result<ExitCode> {
    let sd = SpringDamper::fit_recording(&a.input, &a.force_col)?;
    println!(
        "[reproduction.fallback]\nk1 = {}\nk2 = {}\nb = {}",
        sd.k1, sd.k2, sd.b
    );
    Ok(ExitCode::SUCCESS)
}

/// `rt-loop identify-friction`: the sweeps, the fit, the bench file.
pub fn identify_friction(a: &IdentifyArgs) -> Result<ExitCode> {
    let mut cfg = match &a.config {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::default(),
    };
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    a.board.apply(&mut cfg)?;
    let mut plan = crate::control::friction_id::SweepPlan::default();
    if let Some(v) = &a.speeds_mm_s {
        plan.speeds_mps = v.iter().map(|s| s * 1e-3).collect();
    }
    let args: Vec<String> = std::env::args().skip(1).collect();
    let command = format!("rt-loop {}", args.join(" "));
    let id = crate::control::friction_id::identify(&cfg, &plan)?;
    crate::control::friction_id::report(&id, &command, &a.out, a.json.as_deref())?;
    Ok(ExitCode::SUCCESS)
}

/// `rt-loop board check | calibrate | clear-safe-mode`.
pub fn board(cmd: &crate::cli::BoardCmd) -> Result<ExitCode> {
    use crate::cli::BoardCmd;
    match cmd {
        BoardCmd::Check(a) => {
            let cfg = a.resolve()?;
            let lines = crate::bringup::check::check(&cfg)?;
            for l in &lines {
                println!("{l}");
            }
            if let Some(p) = &a.json {
                std::fs::write(p, serde_json::to_string_pretty(&lines)?)
                    .map_err(|e| anyhow::anyhow!("--json {}: {e}", p.display()))?;
            }
            let failed = lines.iter().filter(|l| !l.pass).count();
            println!(
                "{}",
                if failed == 0 {
                    "board check: every line passed".to_string()
                } else {
                    format!("board check: {failed} line(s) failed (see what to change above)")
                }
            );
            Ok(if failed == 0 {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            })
        }
        BoardCmd::Calibrate(a) => {
            let cfg = a.check.resolve()?;
            if a.out.exists() && !a.overwrite {
                anyhow::bail!(
                    "{} already exists: choose another --out or pass --overwrite",
                    a.out.display()
                );
            }
            let given = crate::bringup::calibrate::Given {
                counts_per_metre: a.counts_per_metre,
                force_constant: a.force_constant,
                amps_per_volt: a.amps_per_volt,
                skip_friction: a.skip_friction,
            };
            let (rig, notes) = crate::bringup::calibrate::calibrate(&cfg, &given)?;
            let args: Vec<String> = std::env::args().skip(1).collect();
            let header = format!(
                "The rig file: written by `rt-loop {}`.\n{}\nRead by every command with --rig FILE.",
                args.join(" "),
                notes.join("\n")
            );
            std::fs::write(&a.out, rig.to_toml(&header)?)
                .map_err(|e| anyhow::anyhow!("{}: {e}", a.out.display()))?;
            for n in &notes {
                println!("{n}");
            }
            println!("wrote {}", a.out.display());
            Ok(ExitCode::SUCCESS)
        }
        BoardCmd::ClearSafeMode(a) => {
            let cfg = a.resolve()?;
            let mut b = crate::bringup::check::open_board(&cfg)?;
            b.open()?;
            let was = b.safe_mode().map_err(|e| anyhow::anyhow!("{e}"))?;
            b.clear_safe_mode()?;
            let now = b.safe_mode().map_err(|e| anyhow::anyhow!("{e}"))?;
            crate::board::Board::shutdown(&mut b);
            if now {
                anyhow::bail!("the board is still in safe mode after clearing it");
            }
            println!(
                "{}",
                if was {
                    "safe mode cleared: the board drives the amplifier again when a run starts"
                } else {
                    "the board was not in safe mode"
                }
            );
            Ok(ExitCode::SUCCESS)
        }
    }
}
