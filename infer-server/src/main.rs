//! `infer-server`: validate models, predict from a feature table, serve a model to rt-loop.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use clap::{Parser, Subcommand};
use infer_server::serve::ServeConfig;
use infer_server::server::{MaintenanceEvent, Server};
use infer_server::{FeatureSchema, ModelError, Runtime, RuntimeError, SessionConfig, StepEngine};
use shm_ring::{SegmentName, WaitStrategy};

/// Exit codes: 0 success, 1 the model (or input) was refused, 2 usage error (clap),
/// 3 ONNX Runtime missing or unloadable.
const EXIT_REFUSED: u8 = 1;
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
    /// Serve a model to rt-loop over its shared-memory segment until interrupted.
    Serve {
        /// The model to serve; validated against the segment's feature schema on attach (and
        /// again whenever a loop with another schema attaches).
        #[arg(long)]
        model: PathBuf,
        /// rt-loop instance name: the segment is /haptics-INSTANCE.
        #[arg(long, default_value = "default", conflicts_with = "segment")]
        instance: String,
        /// Explicit segment name (starting with /), instead of --instance.
        #[arg(long)]
        segment: Option<String>,
        /// How the inference thread waits for features: spin (burns a core), park, or
        /// spin-park (spin --spins times, then park).
        #[arg(long, default_value = "spin-park")]
        wait: WaitArg,
        /// Spin budget of spin-park before parking (2000: a few microseconds); a budget covering the
        /// loop's period keeps the thread awake between steps (best latency, one busy core).
        #[arg(long, default_value_t = 2000)]
        spins: u32,
        /// Pin the inference thread to this CPU (ignored with a warning where not permitted).
        #[arg(long)]
        cpu: Option<usize>,
        /// SCHED_FIFO priority (1-99) for the inference thread (reported and ignored where not
        /// permitted). Use with --wait park or spin-park on a two-core machine.
        #[arg(long)]
        rt_priority: Option<i32>,
        /// Lock the process's memory (mlockall) so no page fault can stall a step later
        /// (reported and ignored where not permitted).
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
            model,
            instance,
            segment,
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
            let wait = match wait {
                WaitArg::Spin => WaitStrategy::Spin,
                WaitArg::Park => WaitStrategy::Park,
                WaitArg::SpinPark => WaitStrategy::SpinThenPark { spins },
            };
            let cfg = ServeConfig {
                segment: name,
                wait,
                cpu,
                rt_priority,
                exit_when_loop_gone,
            };
            let session = SessionConfig {
                intra_threads: ort_threads,
                spinning: ort_spin,
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
            serve(cli.ort_lib.as_deref(), &model, cfg, session, stats_every)
        }
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum WaitArg {
    Spin,
    Park,
    SpinPark,
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    // Async-signal-safe: one atomic store.
    STOP.store(true, Ordering::Relaxed);
}

fn serve(
    ort_lib: Option<&Path>,
    model: &Path,
    cfg: ServeConfig,
    session: SessionConfig,
    stats_every: f64,
) -> ExitCode {
    let rt = match load_runtime(ort_lib, false) {
        Ok(rt) => rt,
        Err(code) => return code,
    };
    // Validate once against the standard schema up front, so a broken model is refused before
    // waiting for a loop (the real check is against the segment's schema, on attach).
    if let Err(e) = StepEngine::load(rt, model, &FeatureSchema::standard(), &session) {
        if !matches!(e, ModelError::MissingFeature { .. }) {
            report_model_error(model, &e, false);
            return ExitCode::from(EXIT_REFUSED);
        }
    }
    // SAFETY: installing an async-signal-safe handler (it only stores to an atomic).
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
    let segment = cfg.segment.clone();
    let server = match Server::start(rt, cfg, session) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("infer-server: {e}");
            return ExitCode::from(EXIT_REFUSED);
        }
    };
    eprintln!(
        "infer-server: serving {} on {segment} (ONNX Runtime {}); waiting for rt-loop",
        model.display(),
        rt.version()
    );
    let mut activated = false;
    let mut last_report = Instant::now();
    let mut exit = ExitCode::SUCCESS;
    while !STOP.load(Ordering::Relaxed) && !server.is_finished() {
        std::thread::sleep(Duration::from_millis(20));
        if !activated {
            // Activate once the segment's schema is known, so the first validation is the
            // real one; later schema changes are handled by `maintain`.
            if let Some(schema) = server_schema_if_attached(&server) {
                match server.activate(model) {
                    Ok(a) => eprintln!(
                        "infer-server: attached to {segment}; schema [{}]; model generation {} active",
                        schema.names().join(", "),
                        a.generation
                    ),
                    Err(e) => {
                        report_model_error(model, &e, false);
                        exit = ExitCode::from(EXIT_REFUSED);
                    }
                }
                activated = true;
            }
        }
        match server.maintain() {
            Some(MaintenanceEvent::Revalidated(a)) => eprintln!(
                "infer-server: new loop schema [{}]; model revalidated, generation {} active",
                a.info.schema.join(", "),
                a.generation
            ),
            Some(MaintenanceEvent::RevalidationFailed { path, error }) => {
                // The loop keeps rendering on its fallback (answers carry SCHEMA_MISMATCH).
                report_model_error(&path, &error, false);
                exit = ExitCode::from(EXIT_REFUSED);
            }
            None => {}
        }
        if stats_every > 0.0 && last_report.elapsed().as_secs_f64() >= stats_every {
            report_stats(&server);
            last_report = Instant::now();
        }
    }
    report_stats(&server);
    if let Err(e) = server.shutdown() {
        eprintln!("infer-server: inference thread: {e}");
        return ExitCode::from(EXIT_REFUSED);
    }
    exit
}

fn server_schema_if_attached(server: &Server) -> Option<FeatureSchema> {
    server.stats().attached.then(|| server.schema())
}

fn report_stats(server: &Server) {
    let s = server.stats();
    let l = server.latency().snapshot();
    eprintln!(
        "infer-server: answered {} (model {}, no model {}, errors {}, schema mismatch {}, non-finite {}, bad features {}), resets {}, attachments {}; ring-to-ring p50 {} ns p99 {} ns p99.9 {} ns max {} ns",
        s.answered,
        s.predicted,
        s.no_model,
        s.step_errors,
        s.schema_mismatch,
        s.non_finite,
        s.bad_features,
        s.resets,
        s.attachments,
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
