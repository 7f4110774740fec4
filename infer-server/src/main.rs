//! `infer-server`: validate models, predict from a feature table, serve a model to rt-loop.

use std::io::{BufRead, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use control_plane::{ControlError, ModelSource, Shutdown, TelemetryHub};
use infer_server::control_backend::ControlBackend;
use infer_server::inference_control::InferenceControl;
use infer_server::inference_thread::InferenceConfig;
use infer_server::profile::{self, Machine, Profile};
use infer_server::registry::Registry;
use infer_server::telemetry::{LoopObserver, TelemetryThread};
use infer_server::{FeatureSchema, ModelError, Runtime, RuntimeError, SessionConfig, StepEngine};
use shm_ring::{SegmentName, WaitStrategy};

/// Exit codes: 0 success, 1 the model (or input) was refused, 2 usage error (clap),
/// 3 ONNX Runtime missing or unloadable.
const EXIT_REFUSED: u8 = 1;
const EXIT_USAGE: u8 = 2;
const EXIT_RUNTIME: u8 = 3;

#[derive(Parser)]
#[command(
    name = "infer-server",
    version,
    about = "Runs ONNX haptics models for rt-loop"
)]
struct Cli {
    /// The ONNX Runtime library (libonnxruntime.so). Default: $ORT_DYLIB_PATH, else
    /// .ort/libonnxruntime.so in an ancestor of the executable or working directory.
    #[arg(long, global = true, value_name = "PATH")]
    ort_lib: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

// Parsed once at start: the size of the largest variant (serve's flags) costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Command {
    /// Check a model against the contract (docs/model-contract.md) and a feature schema.
    Validate {
        model: PathBuf,
        /// The producer's feature names in slot order (comma-separated). Default: the nine
        /// features of docs/recording-format.md.
        #[arg(long)]
        schema: Option<String>,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Run a model over a CSV table of features (header = feature names, one row per step, in
    /// order) and print one force per line. Stateful models are stepped through the rows in
    /// order from a zero state, as the server steps them.
    Predict {
        model: PathBuf,
        /// CSV file; `-` reads standard input.
        #[arg(long, default_value = "-")]
        csv: String,
    },
    /// Serve rt-loop over its shared-memory segment, with the gRPC control plane and the web
    /// page, until SIGINT/SIGTERM.
    Serve {
        /// The model directory (its *.onnx files are listed, loaded and activated by name).
        /// Default: models/, or the directory of --model when that is a path.
        #[arg(long, value_name = "DIR")]
        models: Option<PathBuf>,
        /// A model to activate once a loop attaches: a file name in the model directory, or a
        /// path to a file (then the model directory defaults to that file's directory).
        #[arg(long, value_name = "NAME|PATH")]
        model: Option<String>,
        /// gRPC address (haptics.v1, health, reflection).
        #[arg(long, default_value = "127.0.0.1:50051")]
        grpc: SocketAddr,
        /// HTTP address (the page, /api, /ws/telemetry, /metrics).
        #[arg(long, default_value = "127.0.0.1:8080")]
        http: SocketAddr,
        /// Bearer token required by mutating calls (load, activate, unload, experiments).
        /// Default: $HAPTICS_TOKEN (empty counts as unset). Required before listening on a
        /// non-loopback address.
        #[arg(long)]
        token: Option<String>,
        /// Listen on a non-loopback address without a token (e.g. inside a container whose
        /// ports are published on the host's 127.0.0.1 only). Anyone who can reach the
        /// address can then swap models and start experiments.
        #[arg(long)]
        allow_public_without_token: bool,
        /// Largest model upload accepted, MiB.
        #[arg(long, default_value_t = 64)]
        max_upload_mib: usize,
        /// Most MiB of model uploads held in memory: those being received at once (gRPC and
        /// HTTP together; each in progress reserves --max-upload-mib), and, counted apart,
        /// the uploaded models kept loaded.
        #[arg(long, default_value_t = 256)]
        max_uploads_mib: usize,
        /// Time limit of a model load (session, checks, warm-up), seconds: a slower model is
        /// stopped and refused (docs/model-contract.md, "Loader limits").
        #[arg(long, default_value_t = 10.0)]
        load_timeout_s: f64,
        /// A host name the page and /api may be reached under, besides localhost and the
        /// listening addresses (repeatable; also $HAPTICS_ALLOWED_HOSTS, comma-separated). Any
        /// other name in a request's Host is refused (DNS rebinding; docs/control-plane.md).
        #[arg(long = "allowed-host", value_name = "NAME")]
        allowed_hosts: Vec<String>,
        /// rt-loop instance name: the segment is /haptics-INSTANCE.
        #[arg(long, default_value = "default", conflicts_with = "segment")]
        instance: String,
        /// Explicit segment name (starting with /), instead of --instance.
        #[arg(long)]
        segment: Option<String>,
        /// Wait profile: auto (chosen from the machine's CPUs, isolated CPUs and permissions,
        /// printed at start), dedicated (spin on a core of its own), period (sleep until
        /// shortly before each step, spin through its arrival), shared (spin briefly, park).
        /// --wait, --cpu, --rt-priority and --mlock override their part of it.
        #[arg(long, value_enum, default_value = "auto")]
        profile: Profile,
        /// How the inference thread waits for features (default: the profile's): spin (burns a
        /// core), park, spin-park (spin --spins times, then park), or period (the
        /// period-synchronised wait).
        #[arg(long)]
        wait: Option<WaitArg>,
        /// Spin budget of spin-park before parking (2000: a few microseconds); a budget covering the
        /// loop's period keeps the thread awake between steps (best latency, one busy core).
        #[arg(long, default_value_t = 2000)]
        spins: u32,
        /// Pin the inference thread to this CPU (default: the profile's; ignored with a warning
        /// where not permitted).
        #[arg(long)]
        cpu: Option<usize>,
        /// SCHED_FIFO priority (1-99) for the inference thread (default: the profile's; 0: the
        /// default scheduler; reported and ignored where not permitted).
        #[arg(long)]
        rt_priority: Option<i32>,
        /// Lock the process's memory (mlockall) so no page fault can stall a step later
        /// (the profiles do where permitted; reported and ignored where not permitted).
        #[arg(long)]
        mlock: bool,
        /// Let ONNX Runtime's threads spin (off by default; only matters with --ort-threads > 1).
        #[arg(long)]
        ort_spin: bool,
        /// ONNX Runtime intra-op threads (1: all work on the inference thread).
        #[arg(long, default_value_t = 1)]
        ort_threads: usize,
        /// Exit when the loop goes away instead of waiting for the next one.
        #[arg(long)]
        exit_when_loop_gone: bool,
        /// Print statistics to stderr every SECS seconds (0: only at exit).
        #[arg(long, default_value_t = 5.0)]
        stats_every: f64,
    },
    /// Print which ONNX Runtime library would be loaded, and its version.
    Runtime {
        #[arg(long)]
        json: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Validate {
            model,
            schema,
            json,
        } => validate(cli.ort_lib.as_deref(), &model, schema.as_deref(), json),
        Command::Predict { model, csv } => predict(cli.ort_lib.as_deref(), &model, &csv),
        Command::Runtime { json } => runtime_info(cli.ort_lib.as_deref(), json),
        Command::Serve {
            models,
            model,
            grpc,
            http,
            token,
            allow_public_without_token,
            max_upload_mib,
            max_uploads_mib,
            load_timeout_s,
            mut allowed_hosts,
            instance,
            segment,
            profile,
            wait,
            spins,
            cpu,
            rt_priority,
            mlock,
            ort_spin,
            ort_threads,
            exit_when_loop_gone,
            stats_every,
        } => {
            let name = match segment {
                Some(s) => SegmentName::new(&s),
                None => SegmentName::for_instance(&instance),
            };
            let name = match name {
                Ok(n) => n,
                Err(e) => {
                    eprintln!("infer-server: {e}");
                    return ExitCode::from(EXIT_REFUSED);
                }
            };
            if rt_priority.is_some_and(|p| !(0..=99).contains(&p)) {
                eprintln!("infer-server: --rt-priority must be 0..=99 (0: default scheduler)");
                return ExitCode::from(EXIT_USAGE);
            }
            let machine = Machine::detect();
            let mut chosen = profile::settings(profile, &machine);
            if let Some(w) = wait {
                chosen.wait = match w {
                    WaitArg::Spin => WaitStrategy::Spin,
                    WaitArg::Park => WaitStrategy::Park,
                    WaitArg::SpinPark => WaitStrategy::SpinThenPark { spins },
                    WaitArg::Period => WaitStrategy::PeriodSync,
                };
            }
            if cpu.is_some() {
                chosen.cpu = cpu;
            }
            if let Some(p) = rt_priority {
                chosen.rt_priority = (p > 0).then_some(p);
            }
            chosen.mlock |= mlock;
            let overridden = wait.is_some() || cpu.is_some() || rt_priority.is_some() || mlock;
            eprintln!(
                "infer-server: profile {}{} on {}: {}",
                profile_name(chosen.profile),
                match (profile, overridden) {
                    (Profile::Auto, false) => " (auto)",
                    (Profile::Auto, true) => " (auto, with explicit flags)",
                    (_, true) => " (with explicit flags)",
                    _ => "",
                },
                machine.describe(),
                chosen.describe()
            );
            let mlock = chosen.mlock;
            let cfg = InferenceConfig {
                segment: name,
                wait: chosen.wait,
                cpu: chosen.cpu,
                rt_priority: chosen.rt_priority,
                exit_when_loop_gone,
            };
            // Every numeric setting checked here, with what is allowed (the control plane's
            // own, like the upload limits, are checked by control_plane::Config::check).
            let numeric = [
                ("--load-timeout-s", load_timeout_s, 0.0, 600.0, false),
                ("--stats-every", stats_every, 0.0, 86_400.0, true),
                ("--ort-threads", ort_threads as f64, 1.0, 64.0, true),
            ];
            for (flag, v, lo, hi, lo_ok) in numeric {
                let above_lo = if lo_ok { v >= lo } else { v > lo };
                if !(v.is_finite() && above_lo && v <= hi) {
                    let lo_word = if lo_ok { ">=" } else { ">" };
                    eprintln!("infer-server: {flag} is {v}; it must be {lo_word} {lo} and <= {hi}");
                    return ExitCode::from(EXIT_USAGE);
                }
            }
            let session = SessionConfig {
                intra_threads: ort_threads,
                spinning: ort_spin,
                load_timeout: Duration::from_secs_f64(load_timeout_s),
                ..SessionConfig::default()
            };
            if mlock {
                // SAFETY: plain syscall on this process.
                if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
                    eprintln!(
                        "infer-server: mlockall not permitted ({}); memory not locked",
                        std::io::Error::last_os_error()
                    );
                }
            }
            let token = token
                .or_else(|| std::env::var("HAPTICS_TOKEN").ok())
                .filter(|t| !t.is_empty());
            let control = control_plane::Config {
                grpc_addr: grpc,
                http_addr: http,
                token,
                allow_public_without_token,
                max_upload_bytes: max_upload_mib.saturating_mul(1 << 20),
                max_uploads_in_flight_bytes: max_uploads_mib.saturating_mul(1 << 20),
                allowed_hosts: {
                    if let Ok(env) = std::env::var("HAPTICS_ALLOWED_HOSTS") {
                        allowed_hosts.extend(
                            env.split(',')
                                .map(str::trim)
                                .filter(|h| !h.is_empty())
                                .map(String::from),
                        );
                    }
                    allowed_hosts
                },
                // Streams end at once on shutdown; this is for connections that hang on.
                shutdown_grace: Duration::from_millis(1000),
                version: env!("CARGO_PKG_VERSION").to_string(),
                ..control_plane::Config::default()
            };
            let (dir, start_model) = match resolve_models(models, model) {
                Ok(v) => v,
                Err(msg) => {
                    eprintln!("infer-server: {msg}");
                    return ExitCode::from(EXIT_USAGE);
                }
            };
            serve(
                cli.ort_lib.as_deref(),
                ServeArgs {
                    dir,
                    start_model,
                    cfg,
                    session,
                    control,
                    stats_every,
                },
            )
        }
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum WaitArg {
    Spin,
    Park,
    SpinPark,
    Period,
}

fn profile_name(p: Profile) -> &'static str {
    match p {
        Profile::Auto => "auto",
        Profile::Dedicated => "dedicated",
        Profile::Period => "period",
        Profile::Shared => "shared",
    }
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    // Async-signal-safe: one atomic store.
    STOP.store(true, Ordering::Relaxed);
}

/// `--models` / `--model` to (model directory, name to activate).
fn resolve_models(
    models: Option<PathBuf>,
    model: Option<String>,
) -> Result<(PathBuf, Option<String>), String> {
    let Some(model) = model else {
        return Ok((models.unwrap_or_else(|| PathBuf::from("models")), None));
    };
    if !model.contains('/') {
        return Ok((
            models.unwrap_or_else(|| PathBuf::from("models")),
            Some(model),
        ));
    }
    let path = Path::new(&model);
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| format!("--model {model}: not a file path"))?
        .to_string();
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    match models {
        None => Ok((parent, Some(name))),
        Some(dir) => {
            let same = match (dir.canonicalize(), parent.canonicalize()) {
                (Ok(a), Ok(b)) => a == b,
                _ => false,
            };
            if same {
                Ok((dir, Some(name)))
            } else {
                Err(format!(
                    "--model {model} is not in the model directory {}: give its file name \
                     inside --models, or leave --models out",
                    dir.display()
                ))
            }
        }
    }
}

struct ServeArgs {
    dir: PathBuf,
    start_model: Option<String>,
    cfg: InferenceConfig,
    session: SessionConfig,
    control: control_plane::Config,
    stats_every: f64,
}

/// The control plane's threads must never compete with the loop: if this process was started
/// with a real-time policy, its threads would inherit it.
fn normal_scheduling() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: sched_setscheduler on the calling thread (pid 0) with an initialised param.
    unsafe {
        libc::sched_setscheduler(0, libc::SCHED_OTHER, &param);
    }
}

fn serve(ort_lib: Option<&Path>, args: ServeArgs) -> ExitCode {
    let rt = match load_runtime(ort_lib, false) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    if !args.dir.is_dir() {
        eprintln!(
            "infer-server: warning: the model directory {} does not exist (no models to list \
             until it does; uploads still work)",
            args.dir.display()
        );
    }
    // SAFETY: installing an async-signal-safe handler (it only stores to an atomic).
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    let segment = args.cfg.segment.clone();
    let server = match InferenceControl::start(rt, args.cfg, args.session) {
        Ok(s) => Arc::new(s),
        Err(e) => {
            eprintln!("infer-server: {e}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let registry = Arc::new(
        Registry::new(Arc::clone(&server), &args.dir)
            .with_max_uploads_held(args.control.max_uploads_in_flight_bytes),
    );
    let mut exit = ExitCode::SUCCESS;
    // Load the start model up front, so a broken one is refused before waiting for a loop.
    // Against the standard features: a model for another loop schema is retried on attach.
    let mut pending_activation = args.start_model.clone();
    if let Some(name) = &args.start_model {
        match registry.load(ModelSource::Directory { name: name.clone() }) {
            Ok(_) => {}
            Err(ControlError::FailedPrecondition(msg)) => {
                eprintln!("infer-server: {msg}; trying again when the loop attaches")
            }
            Err(e) => {
                eprintln!("infer-server: {e}");
                return ExitCode::from(EXIT_REFUSED);
            }
        }
    }

    let hub = TelemetryHub::new(1024);
    let observer = Arc::new(LoopObserver::default());
    let telemetry = match TelemetryThread::spawn(
        Arc::clone(server.endpoints()),
        hub.clone(),
        Arc::clone(&observer),
        Duration::from_millis(4),
    ) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("infer-server: cannot start the telemetry thread: {e}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let backend = Arc::new(ControlBackend::new(
        Arc::clone(&registry),
        hub,
        observer,
        env!("CARGO_PKG_VERSION"),
    ));

    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(args.control.worker_threads.max(1))
        .max_blocking_threads(16)
        .thread_name("control-plane")
        .on_thread_start(normal_scheduling)
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            eprintln!("infer-server: cannot start the control plane's runtime: {e}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let shutdown = Shutdown::new();
    let bound = match runtime.block_on(control_plane::bind(
        args.control.clone(),
        backend,
        shutdown.clone(),
    )) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("infer-server: {e:#}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    // On stdout, one line, for people and for scripts that start it on port 0.
    println!(
        "infer-server: gRPC {} HTTP http://{} segment {segment} models {} (ONNX Runtime {})",
        bound.grpc_addr(),
        bound.http_addr(),
        args.dir.display(),
        rt.version()
    );
    let _ = std::io::stdout().flush();
    if args.control.token.is_some() {
        eprintln!("infer-server: mutating calls need the bearer token");
    }
    let control_thread = std::thread::Builder::new()
        .name("control-plane".into())
        .spawn(move || {
            let r = runtime.block_on(bound.run());
            // Connection tasks still alive after the grace period are dropped here.
            runtime.shutdown_timeout(Duration::from_millis(200));
            r
        });
    let control_thread = match control_thread {
        Ok(t) => t,
        Err(e) => {
            eprintln!("infer-server: cannot start the control plane's thread: {e}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };

    let mut last_report = Instant::now();
    let mut attached = false;
    let mut undecodable_seen = 0u64;
    while !STOP.load(Ordering::Relaxed) && !server.is_finished() && !control_thread.is_finished() {
        std::thread::sleep(Duration::from_millis(20));
        let now_attached = server.attached();
        if now_attached != attached {
            attached = now_attached;
            if attached {
                eprintln!(
                    "infer-server: attached to {segment}; features [{}]",
                    server.schema().names().join(", ")
                );
            } else {
                eprintln!("infer-server: the loop left {segment}; waiting for the next one");
            }
        }
        if attached {
            if let Some(name) = pending_activation.take() {
                match registry.activate(&name, true) {
                    Ok(a) => eprintln!(
                        "infer-server: {name} active (model id {}) from step {}",
                        a.model.model_id, a.effective_step
                    ),
                    Err(e) => {
                        eprintln!("infer-server: {e}");
                        exit = ExitCode::from(EXIT_REFUSED);
                    }
                }
            }
        }
        let undecodable = server.counters().undecodable.load(Ordering::Relaxed);
        if undecodable != undecodable_seen {
            let why = server
                .counters()
                .last_undecodable
                .lock()
                .ok()
                .and_then(|e| e.map(|e| e.to_string()))
                .unwrap_or_default();
            eprintln!(
                "infer-server: skipped {} feature message(s) that do not decode ({why}); serving on",
                undecodable - undecodable_seen
            );
            undecodable_seen = undecodable;
        }
        if let Some(line) = registry.maintain() {
            eprintln!("infer-server: {line}");
        }
        if args.stats_every > 0.0 && last_report.elapsed().as_secs_f64() >= args.stats_every {
            report_stats(&server);
            last_report = Instant::now();
        }
    }

    // Shut down: the control plane first (streams and WebSockets end, connections close),
    // then the telemetry and inference threads.
    shutdown.trigger();
    match control_thread.join() {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            eprintln!("infer-server: control plane: {e:#}");
            exit = ExitCode::from(EXIT_REFUSED);
        }
        Err(_) => {
            eprintln!("infer-server: the control plane panicked");
            exit = ExitCode::from(EXIT_REFUSED);
        }
    }
    telemetry.stop();
    report_stats(&server);
    server.request_stop();
    let deadline = Instant::now() + Duration::from_secs(2);
    while !server.is_finished() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    drop(registry);
    match Arc::try_unwrap(server) {
        Ok(server) => {
            if let Err(e) = server.shutdown() {
                eprintln!("infer-server: inference thread: {e}");
                return ExitCode::from(EXIT_REFUSED);
            }
        }
        Err(_) => eprintln!("infer-server: shutting down with the inference thread still held"),
    }
    exit
}

fn report_stats(server: &InferenceControl) {
    let s = server.stats();
    let l = server.latency().snapshot();
    eprintln!(
        "infer-server: answered {} (model {}, no model {}, errors {}, schema mismatch {}, non-finite {}, bad features {}, undecodable {}), resets {}, attachments {}; period-sync period {} ns margin {} ns locks {} relearns {} (quiet {}, faster {}, gap {}, restart {}) missed wake-ups {}; ring-to-ring p50 {} ns p99 {} ns p99.9 {} ns max {} ns",
        s.answered,
        s.predicted,
        s.no_model,
        s.step_errors,
        s.schema_mismatch,
        s.non_finite,
        s.bad_features,
        s.undecodable,
        s.resets,
        s.attachments,
        s.sync_period_ns,
        s.sync_margin_ns,
        s.sync_locks,
        s.sync_relearns,
        s.sync_let_go[0],
        s.sync_let_go[1],
        s.sync_let_go[2],
        s.sync_let_go[3],
        s.sync_missed_wakes,
        l.quantile(0.5),
        l.quantile(0.99),
        l.quantile(0.999),
        l.max
    );
}

fn load_runtime(ort_lib: Option<&Path>, json: bool) -> Result<&'static Runtime, ExitCode> {
    Runtime::init(ort_lib).map_err(|e| {
        report_runtime_error(&e, json);
        ExitCode::from(EXIT_RUNTIME)
    })
}

fn report_runtime_error(e: &RuntimeError, json: bool) {
    if json {
        let v = serde_json::json!({
            "ok": false,
            "error": { "code": "runtime_missing", "message": e.to_string() },
        });
        println!("{v}");
    }
    eprintln!("infer-server: {e}");
}

fn runtime_info(ort_lib: Option<&Path>, json: bool) -> ExitCode {
    let rt = match load_runtime(ort_lib, json) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    if json {
        let v = serde_json::json!({
            "ok": true,
            "library": rt.library(),
            "version": rt.version(),
        });
        println!("{v}");
    } else {
        println!(
            "ONNX Runtime {} from {}",
            rt.version(),
            rt.library().display()
        );
    }
    ExitCode::SUCCESS
}

fn parse_schema(schema: Option<&str>) -> Result<FeatureSchema, String> {
    match schema {
        None => Ok(FeatureSchema::standard()),
        Some(s) => FeatureSchema::parse(s).map_err(|e| format!("bad --schema: {e}")),
    }
}

fn validate(ort_lib: Option<&Path>, model: &Path, schema: Option<&str>, json: bool) -> ExitCode {
    let schema = match parse_schema(schema) {
        Ok(s) => s,
        Err(msg) => {
            if json {
                let v = serde_json::json!({
                    "ok": false,
                    "model": model,
                    "error": { "code": "bad_schema", "message": msg },
                });
                println!("{v}");
            }
            eprintln!("infer-server: {msg}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let rt = match load_runtime(ort_lib, json) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    match StepEngine::load(rt, model, &schema, &SessionConfig::default()) {
        Ok(engine) => {
            let info = engine.info();
            if json {
                let v = serde_json::json!({
                    "ok": true,
                    "model": info,
                    "runtime": { "library": rt.library(), "version": rt.version() },
                });
                println!("{v}");
            } else {
                println!("{}: valid {} model", model.display(), info.kind);
                println!("  features: {}", info.features.join(", "));
                println!(
                    "  schema indices: {:?} (schema: {})",
                    info.input_map,
                    info.schema.join(", ")
                );
                println!("  units: {}", info.units);
                if let Some(s) = &info.state_shape {
                    println!("  state shape: {s:?}");
                }
                println!("  provenance: {}", info.provenance);
                println!(
                    "  ONNX Runtime {} ({})",
                    rt.version(),
                    rt.library().display()
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            report_model_error(model, &e, json);
            ExitCode::from(EXIT_REFUSED)
        }
    }
}

fn report_model_error(model: &Path, e: &ModelError, json: bool) {
    if json {
        let v = serde_json::json!({
            "ok": false,
            "model": model,
            "error": { "code": e.code(), "message": e.to_string() },
        });
        println!("{v}");
    }
    eprintln!("infer-server: {} refused: {e}", model.display());
}

fn predict(ort_lib: Option<&Path>, model: &Path, csv: &str) -> ExitCode {
    let reader: Box<dyn BufRead> = if csv == "-" {
        Box::new(std::io::stdin().lock())
    } else {
        match std::fs::File::open(csv) {
            Ok(f) => Box::new(std::io::BufReader::new(f)),
            Err(e) => {
                eprintln!("infer-server: cannot open {csv}: {e}");
                return ExitCode::from(EXIT_REFUSED);
            }
        }
    };
    let mut lines = reader.lines();
    let header = match lines.next() {
        Some(Ok(h)) => h,
        _ => {
            eprintln!("infer-server: {csv}: empty table (expected a header of feature names)");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let schema = match FeatureSchema::parse(&header) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("infer-server: {csv}: bad header: {e}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let rt = match load_runtime(ort_lib, false) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    let mut engine = match StepEngine::load(rt, model, &schema, &SessionConfig::default()) {
        Ok(e) => e,
        Err(e) => {
            report_model_error(model, &e, false);
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    let mut row = vec![0f64; schema.len()];
    for (i, line) in lines.enumerate() {
        let line_no = i + 2;
        let line = match line {
            Ok(l) => l,
            Err(e) => {
                eprintln!("infer-server: {csv}: line {line_no}: {e}");
                return ExitCode::from(EXIT_REFUSED);
            }
        };
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != schema.len() {
            eprintln!(
                "infer-server: {csv}: line {line_no} has {} fields, the header has {}",
                fields.len(),
                schema.len()
            );
            return ExitCode::from(EXIT_REFUSED);
        }
        for (slot, f) in row.iter_mut().zip(&fields) {
            match f.trim().parse::<f64>() {
                Ok(v) => *slot = v,
                Err(_) => {
                    eprintln!("infer-server: {csv}: line {line_no}: {f:?} is not a number");
                    return ExitCode::from(EXIT_REFUSED);
                }
            }
        }
        match engine.step(&row) {
            // Full f32 precision, round-trippable.
            Ok(force) => {
                let _ = writeln!(out, "{force:?}");
            }
            Err(e) => {
                eprintln!(
                    "infer-server: line {line_no}: {e}: {}",
                    engine.last_error_message()
                );
                return ExitCode::from(EXIT_REFUSED);
            }
        }
    }
    let _ = out.flush();
    ExitCode::SUCCESS
}
