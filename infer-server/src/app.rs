//! `infer-server serve` as a library function: [`run`] takes the server's configuration and a
//! shutdown signal, as mini-redis's `server::run(listener, shutdown)` does, so the binary only
//! parses its arguments and tests run the real server in-process ([`App::start`] when they need
//! the bound addresses first, e.g. with port 0).
//!
//! What runs: the inference thread ([`crate::control::inference_control`]), the model registry, the
//! telemetry thread and the control plane (gRPC and HTTP on a runtime and thread of their own),
//! and, on the calling thread, the housekeeping every 20 ms (attach/detach messages, the start
//! model once a loop attaches, engines given back, revalidation, statistics). The order they
//! stop in is fixed here: the control plane first (streams and WebSockets end, connections
//! close), then the telemetry and inference threads.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use control_plane::{ControlError, ModelSource, TelemetryHub};
use shm_ring::os::shutdown::Shutdown;

use crate::control::control_backend::ControlBackend;
use crate::control::inference_control::InferenceControl;
use crate::control::registry::Registry;
use crate::control::telemetry::{LoopObserver, TelemetryThread};
use crate::exit::{EXIT_REFUSED, EXIT_RUNTIME, EXIT_USAGE};
use crate::model::runtime::{Runtime, RuntimeError};
use crate::model::SessionConfig;
use crate::serving::inference_thread::InferenceConfig;

/// How long the start model waits, once a loop is attached, for the loop's status block (its
/// rate) before it is activated without it.
const START_MODEL_STATUS_WAIT: Duration = Duration::from_millis(500);

/// Everything `infer-server serve` needs (built from its flags by
/// [`crate::cli::ServeArgs::into_config`]).
#[derive(Debug, Clone)]
pub struct AppConfig {
    /// The instance: names the connection file (`haptics_proto::connection`).
    pub instance: String,
    /// The ONNX Runtime library; `None`: the usual search (`Runtime::init`).
    pub ort_lib: Option<PathBuf>,
    /// The model directory.
    pub models_dir: PathBuf,
    /// A model (file name in `models_dir`) to activate once a loop attaches.
    pub start_model: Option<String>,
    pub inference: InferenceConfig,
    pub session: SessionConfig,
    pub control: control_plane::Config,
    /// `mlockall` the process before anything starts (reported and ignored where refused).
    pub lock_memory: bool,
    /// Statistics on stderr this often (`None`: only at exit).
    pub stats_every: Option<Duration>,
}

/// Why the server did not start, or ended with a failure.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// ONNX Runtime is missing or cannot be loaded.
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
    /// A flag's value is not allowed.
    #[error("{0}")]
    Usage(String),
    /// Refused at start (a model, a segment name, an address in use, a thread not started) or
    /// ended with a failure (the start model refused once a loop attached, the control plane
    /// or the inference thread failed).
    #[error("{0}")]
    Refused(String),
}

impl AppError {
    /// The process's exit code for this error ([`crate::exit`]).
    pub fn exit_code(&self) -> u8 {
        match self {
            AppError::Runtime(_) => EXIT_RUNTIME,
            AppError::Usage(_) => EXIT_USAGE,
            AppError::Refused(_) => EXIT_REFUSED,
        }
    }
}

/// Starts the server, prints its one line on stdout (addresses, segment, model directory,
/// ONNX Runtime version: scripts that start it on port 0 read it), and serves until `shutdown`
/// is requested (or, with `exit_when_loop_gone`, the loop leaves). Blocks the caller.
pub fn run(config: AppConfig, shutdown: Shutdown) -> Result<(), AppError> {
    let instance = config.instance.clone();
    let token = config.control.token.clone();
    let app = App::start(config)?;
    println!(
        "infer-server: gRPC {} HTTP http://{} segment {} models {} (ONNX Runtime {})",
        app.grpc_addr(),
        app.http_addr(),
        app.segment,
        app.models_dir.display(),
        app.rt.version()
    );
    let _ = std::io::stdout().flush();
    let info = connection_info(&instance, app.grpc_addr(), app.http_addr(), token);
    match haptics_proto::connection::write(&info) {
        Ok(path) => eprintln!(
            "infer-server: every call needs the token; the connection file {} (this user only) \
             holds it for hapticctl; page: {}",
            path.display(),
            info.page
        ),
        Err(e) => eprintln!(
            "infer-server: warning: no connection file ({e}); give clients the token by hand \
             (--token / HAPTICS_TOKEN); page: {}",
            info.page
        ),
    }
    let result = app.run_until(&shutdown);
    haptics_proto::connection::remove_if_owned(&instance, info.pid);
    result
}

/// What the connection file says: the addresses a client of this machine connects to (an
/// unspecified bind address, 0.0.0.0 or ::, is reached over loopback) and the token.
pub fn connection_info(
    instance: &str,
    grpc: SocketAddr,
    http: SocketAddr,
    token: Option<String>,
) -> haptics_proto::connection::ConnectionInfo {
    let reachable = |a: SocketAddr| {
        let mut a = a;
        if a.ip().is_unspecified() {
            a.set_ip(if a.is_ipv4() {
                std::net::Ipv4Addr::LOCALHOST.into()
            } else {
                std::net::Ipv6Addr::LOCALHOST.into()
            });
        }
        format!("http://{a}")
    };
    let http = reachable(http);
    haptics_proto::connection::ConnectionInfo {
        instance: instance.to_string(),
        pid: std::process::id(),
        grpc: reachable(grpc),
        page: haptics_proto::connection::ConnectionInfo::page_for(&http, token.as_deref()),
        http,
        token,
    }
}

/// The server, started: every thread running, both listeners bound.
pub struct App {
    rt: &'static Runtime,
    segment: shm_ring::SegmentName,
    models_dir: PathBuf,
    stats_every: Option<Duration>,
    inference: Arc<InferenceControl>,
    registry: Arc<Registry>,
    telemetry: TelemetryThread,
    control: control_plane::Running,
    control_shutdown: control_plane::Shutdown,
    /// The start model, until a loop attaches and it is activated.
    pending_activation: Option<String>,
}

impl App {
    /// Loads ONNX Runtime, starts the inference thread, loads the start model (so a broken one
    /// is refused before waiting for a loop), starts the telemetry thread and binds the control
    /// plane.
    pub fn start(config: AppConfig) -> Result<App, AppError> {
        if config.lock_memory {
            if let Err(e) = shm_ring::os::rt_thread::lock_memory() {
                eprintln!("infer-server: mlockall not permitted ({e}); memory not locked");
            }
        }
        let rt = Runtime::init(config.ort_lib.as_deref())?;
        if !config.models_dir.is_dir() {
            eprintln!(
                "infer-server: warning: the model directory {} does not exist (no models to list \
                 until it does; uploads still work)",
                config.models_dir.display()
            );
        }
        let segment = config.inference.segment.clone();
        let inference = InferenceControl::start(rt, config.inference, config.session)
            .map(Arc::new)
            .map_err(|e| AppError::Refused(e.to_string()))?;
        let registry = Arc::new(
            Registry::new(Arc::clone(&inference), &config.models_dir)
                .with_max_uploads_held(config.control.max_uploads_in_flight_bytes),
        );
        // Against the standard features: a model for another loop schema is retried on attach.
        if let Some(name) = &config.start_model {
            match registry.load(ModelSource::Directory { name: name.clone() }) {
                Ok(_) => {}
                Err(ControlError::FailedPrecondition(msg)) => {
                    eprintln!("infer-server: {msg}; trying again when the loop attaches")
                }
                Err(e) => return Err(AppError::Refused(e.to_string())),
            }
        }
        let hub = TelemetryHub::new(1024);
        let observer = Arc::new(LoopObserver::default());
        let telemetry = TelemetryThread::spawn(
            Arc::clone(inference.endpoints()),
            hub.clone(),
            Arc::clone(&observer),
            Duration::from_millis(4),
        )
        .map_err(|e| AppError::Refused(format!("cannot start the telemetry thread: {e}")))?;
        let backend = Arc::new(ControlBackend::new(
            Arc::clone(&registry),
            hub,
            observer,
            env!("CARGO_PKG_VERSION"),
        ));
        let control_shutdown = control_plane::Shutdown::new();
        let control = control_plane::start(config.control, backend, control_shutdown.clone())
            .map_err(|e| AppError::Refused(format!("{e:#}")))?;
        Ok(App {
            rt,
            segment,
            models_dir: config.models_dir,
            stats_every: config.stats_every,
            inference,
            registry,
            telemetry,
            control,
            control_shutdown,
            pending_activation: config.start_model,
        })
    }

    /// The gRPC listener's address (the port chosen when the configuration said 0).
    pub fn grpc_addr(&self) -> SocketAddr {
        self.control.grpc_addr()
    }

    /// The HTTP listener's address.
    pub fn http_addr(&self) -> SocketAddr {
        self.control.http_addr()
    }

    /// The inference thread's control side (what the control plane calls too).
    pub fn inference(&self) -> &Arc<InferenceControl> {
        &self.inference
    }

    /// Housekeeping every 20 ms until `shutdown` is requested, the inference thread ends
    /// (`exit_when_loop_gone`) or the control plane stops; then everything stops, in order.
    pub fn run_until(mut self, shutdown: &Shutdown) -> Result<(), AppError> {
        let mut failures = Vec::new();
        let mut last_report = Instant::now();
        let mut attached = false;
        let mut attached_at = Instant::now();
        let mut undecodable_seen = 0u64;
        while !shutdown.wait_timeout(Duration::from_millis(20))
            && !self.inference.is_finished()
            && !self.control.is_finished()
        {
            let now_attached = self.inference.attached();
            if now_attached != attached {
                attached = now_attached;
                attached_at = Instant::now();
                if attached {
                    eprintln!(
                        "infer-server: attached to {}; features [{}]",
                        self.segment,
                        self.inference.schema().names().join(", ")
                    );
                } else {
                    eprintln!(
                        "infer-server: the loop left {}; waiting for the next one",
                        self.segment
                    );
                }
            }
            // The start model waits (briefly) for the loop's status block: its rate is what a
            // model's `haptics.step_s` is checked against. rt-loop publishes it right after
            // creating the segment; an older loop that never does is not waited on for long.
            let rate_known = self.registry.loop_rate_hz() > 0.0
                || attached_at.elapsed() >= START_MODEL_STATUS_WAIT;
            if attached && rate_known {
                if let Some(name) = self.pending_activation.take() {
                    match self.registry.activate(&name, true) {
                        Ok(a) => eprintln!(
                            "infer-server: {name} active (model id {}) from step {}",
                            a.model.model_id, a.effective_step
                        ),
                        Err(e) => {
                            eprintln!("infer-server: {e}");
                            failures.push(format!("the start model {name} was refused: {e}"));
                        }
                    }
                }
            }
            undecodable_seen = self.report_undecodable(undecodable_seen);
            if let Some(line) = self.registry.maintain() {
                eprintln!("infer-server: {line}");
            }
            if self
                .stats_every
                .is_some_and(|every| last_report.elapsed() >= every)
            {
                report_stats(&self.inference);
                last_report = Instant::now();
            }
        }
        self.stop(failures)
    }

    /// Logs the feature messages skipped since `seen` because they did not decode; returns the
    /// new count.
    fn report_undecodable(&self, seen: u64) -> u64 {
        let counters = self.inference.counters();
        let undecodable = counters.undecodable.load(Ordering::Relaxed);
        if undecodable != seen {
            let why = counters
                .last_undecodable
                .lock()
                .ok()
                .and_then(|e| e.map(|e| e.to_string()))
                .unwrap_or_default();
            eprintln!(
                "infer-server: skipped {} feature message(s) that do not decode ({why}); serving on",
                undecodable - seen
            );
        }
        undecodable
    }

    /// The control plane first (streams and WebSockets end, connections close), then the
    /// telemetry and inference threads.
    fn stop(self, mut failures: Vec<String>) -> Result<(), AppError> {
        self.control_shutdown.trigger();
        if let Err(e) = self.control.join() {
            failures.push(format!("control plane: {e:#}"));
        }
        self.telemetry.stop();
        report_stats(&self.inference);
        self.inference.request_stop();
        let deadline = Instant::now() + Duration::from_secs(2);
        while !self.inference.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
        drop(self.registry);
        match Arc::try_unwrap(self.inference) {
            Ok(inference) => {
                if let Err(e) = inference.shutdown() {
                    failures.push(format!("inference thread: {e}"));
                }
            }
            Err(_) => eprintln!("infer-server: shutting down with the inference thread still held"),
        }
        if failures.is_empty() {
            Ok(())
        } else {
            Err(AppError::Refused(failures.join("; ")))
        }
    }
}

/// One line of the inference thread's counters and latency on stderr.
fn report_stats(server: &InferenceControl) {
    let s = server.stats();
    let l = server.latency().snapshot();
    eprintln!(
        "infer-server: answered {} (model {}, no model {}, errors {}, schema mismatch {}, non-finite {}, bad features {}, undecodable {}), resets {}, attachments {}; period-sync period {} ns margin {} ns locks {} relearns {} (quiet {}, faster {}, gap {}, restart {}) missed wake-ups {}; keep-awake {}; ring-to-ring p50 {} ns p99 {} ns p99.9 {} ns max {} ns; work ahead after {} answers, {} ns each",
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
        if s.keep_awake_cpu >= 0 {
            format!(
                "CPU {} spun {:.1} s",
                s.keep_awake_cpu,
                s.keep_awake_spun_us as f64 / 1e6
            )
        } else {
            "off".to_string()
        },
        l.quantile(0.5),
        l.quantile(0.99),
        l.quantile(0.999),
        l.max,
        s.ahead_runs,
        s.ahead_ns.checked_div(s.ahead_runs).unwrap_or(0),
    );
}
