//! The command line of `infer-server`: its subcommands and flags (clap), and the serve flags
//! turned into an [`AppConfig`] (profile chosen and overridden, numbers checked, the model
//! directory resolved). Kept apart from `main.rs` so the binary only parses and dispatches, and
//! so the conversion is tested without starting a process.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::{Args, Parser, Subcommand};
use shm_ring::{SegmentName, WaitStrategy};

use crate::app::{AppConfig, AppError};
use crate::model::SessionConfig;
use crate::serving::inference_thread::InferenceConfig;
use crate::serving::profile::{self, Machine, Profile};

#[derive(Parser)]
#[command(
    name = "infer-server",
    version,
    about = "Runs ONNX haptics models for rt-loop"
)]
pub struct Cli {
    /// The ONNX Runtime library (libonnxruntime.so). Default: $ORT_DYLIB_PATH, else
    /// .ort/libonnxruntime.so in an ancestor of the executable or working directory.
    #[arg(long, global = true, value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
    #[command(subcommand)]
    pub command: Command,
}

// Parsed once at start: the size of the largest variant (serve's flags) costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
pub enum Command {
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
    Serve(ServeArgs),
    /// Print which ONNX Runtime library would be loaded, and its version.
    Runtime {
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
}

/// `infer-server serve`'s flags.
#[derive(Args, Debug, Clone)]
pub struct ServeArgs {
    /// The model directory (its *.onnx files are listed, loaded and activated by name).
    /// Default: models/, or the directory of --model when that is a path.
    #[arg(long, value_name = "DIR")]
    pub models: Option<PathBuf>,
    /// A model to activate once a loop attaches: a file name in the model directory, or a
    /// path to a file (then the model directory defaults to that file's directory).
    #[arg(long, value_name = "NAME|PATH")]
    pub model: Option<String>,
    /// gRPC address (haptics.v1, health, reflection).
    #[arg(long, default_value = "127.0.0.1:50051")]
    pub grpc: SocketAddr,
    /// HTTP address (the page, /api, /ws/telemetry, /metrics).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub http: SocketAddr,
    /// Bearer token every call needs (changes, status, models, telemetry, /metrics), on
    /// loopback too. Default: $HAPTICS_TOKEN (empty counts as unset), else a random one
    /// created at start and written, with the addresses, into the connection file only this
    /// user can read ($XDG_RUNTIME_DIR/haptics/INSTANCE.json, else
    /// /tmp/haptics-UID/INSTANCE.json), where hapticctl finds it; the page's address with the
    /// token is printed at start. 1-256 visible ASCII characters.
    #[arg(long)]
    pub token: Option<String>,
    /// Serve /metrics without the token (for a Prometheus that cannot send one; anyone who can
    /// reach the port then reads the loop's state and the active model's name).
    #[arg(long)]
    pub open_metrics: bool,
    /// Listen on a non-loopback address without a token (e.g. inside a container whose
    /// ports are published on the host's 127.0.0.1 only). Anyone who can reach the
    /// address can then swap models and start experiments.
    #[arg(long)]
    pub allow_public_without_token: bool,
    /// Largest model upload accepted, MiB.
    #[arg(long, default_value_t = 64)]
    pub max_upload_mib: usize,
    /// Most MiB of model uploads held in memory: those being received at once (gRPC and
    /// HTTP together; each in progress reserves --max-upload-mib), and, counted apart,
    /// the uploaded models kept loaded.
    #[arg(long, default_value_t = 256)]
    pub max_uploads_mib: usize,
    /// Time limit of a model load (session, checks, warm-up), seconds: a slower model is
    /// stopped and refused (docs/model-contract.md, "Loader limits").
    #[arg(long, default_value_t = 10.0)]
    pub load_timeout_s: f64,
    /// Most MiB the models' working memory may take while they run (one ONNX Runtime CPU arena
    /// all models share, capped): a model whose warm-up needs more is refused at load, the
    /// active model untouched (docs/model-contract.md, "Loader limits"). 16 to 65536.
    #[arg(long, default_value_t = crate::model::memory_limit::DEFAULT_MODEL_MEMORY_MIB)]
    pub model_memory_mib: usize,
    /// A host name the page and /api may be reached under, besides localhost and the
    /// listening addresses (repeatable; also $HAPTICS_ALLOWED_HOSTS, comma-separated). Any
    /// other name in a request's Host is refused (DNS rebinding; docs/control-plane.md).
    #[arg(long = "allowed-host", value_name = "NAME")]
    pub allowed_hosts: Vec<String>,
    /// rt-loop instance name: the segment is /haptics-INSTANCE, the connection file
    /// INSTANCE.json.
    #[arg(
        long,
        env = "HAPTICS_INSTANCE",
        default_value = "default",
        conflicts_with = "segment"
    )]
    pub instance: String,
    /// Explicit segment name (starting with /), instead of --instance.
    #[arg(long)]
    pub segment: Option<String>,
    /// Wait profile: auto (chosen from the machine's CPUs, isolated CPUs and permissions,
    /// printed at start), dedicated (spin on a core of its own), period (sleep until
    /// shortly before each step, spin through its arrival), shared (spin briefly, park).
    /// --wait, --cpu, --rt-priority and --mlock override their part of it.
    #[arg(long, value_enum, default_value = "auto")]
    pub profile: Profile,
    /// How the inference thread waits for features (default: the profile's): spin (burns a
    /// core), park, spin-park (spin --spins times, then park), or period (the
    /// period-synchronised wait).
    #[arg(long)]
    pub wait: Option<WaitArg>,
    /// Spin budget of spin-park before parking (2000: a few microseconds); a budget covering the
    /// loop's period keeps the thread awake between steps (best latency, one busy core).
    #[arg(long, default_value_t = 2000)]
    pub spins: u32,
    /// Pin the inference thread to this CPU (default: the profile's; ignored with a warning
    /// where not permitted).
    #[arg(long)]
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority (1-99) for the inference thread (default: the profile's; 0: the
    /// default scheduler; reported and ignored where not permitted).
    #[arg(long)]
    pub rt_priority: Option<i32>,
    /// Lock the process's memory (mlockall) so no page fault can stall a step later
    /// (the profiles do where permitted; reported and ignored where not permitted).
    #[arg(long)]
    pub mlock: bool,
    /// Keep the inference thread's CPU awake between steps with a spinner at SCHED_IDLE, the
    /// scheduler's lowest class (on: the period profile's default on a pinned CPU; off: let
    /// the CPU halt between steps). Needs a pinned CPU (--cpu or the profile's).
    #[arg(long, value_enum)]
    pub keep_awake: Option<OnOff>,
    /// Let ONNX Runtime's threads spin (off by default; only matters with --ort-threads > 1).
    #[arg(long)]
    pub ort_spin: bool,
    /// ONNX Runtime intra-op threads (1: all work on the inference thread).
    #[arg(long, default_value_t = 1)]
    pub ort_threads: usize,
    /// Exit when the loop goes away instead of waiting for the next one.
    #[arg(long)]
    pub exit_when_loop_gone: bool,
    /// Print statistics to stderr every SECS seconds (0: only at exit).
    #[arg(long, default_value_t = 5.0)]
    pub stats_every: f64,
}

/// A switch given as `on` or `off`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    On,
    Off,
}

/// `--wait`: how the inference thread waits for features.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum WaitArg {
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

impl ServeArgs {
    /// The server's configuration from these flags: the wait profile chosen from the machine
    /// (printed on stderr, with the explicit flags that override it), every number checked,
    /// the model directory and the start model resolved, `$HAPTICS_TOKEN` and
    /// `$HAPTICS_ALLOWED_HOSTS` read. A bad value is a usage error ([`AppError::Usage`]).
    pub fn into_config(self, ort_lib: Option<PathBuf>) -> Result<AppConfig, AppError> {
        let segment = match &self.segment {
            Some(s) => SegmentName::new(s),
            None => SegmentName::for_instance(&self.instance),
        }
        // A bad name is a usage error (exit 2), as in rt-loop.
        .map_err(|e| AppError::Usage(e.to_string()))?;
        if self.rt_priority.is_some_and(|p| !(0..=99).contains(&p)) {
            return Err(AppError::Usage(
                "--rt-priority must be 0..=99 (0: default scheduler)".into(),
            ));
        }
        let machine = Machine::detect();
        let mut chosen = profile::settings(self.profile, &machine);
        if let Some(w) = self.wait {
            chosen.wait = match w {
                WaitArg::Spin => WaitStrategy::Spin,
                WaitArg::Park => WaitStrategy::Park,
                WaitArg::SpinPark => WaitStrategy::SpinThenPark { spins: self.spins },
                WaitArg::Period => WaitStrategy::PeriodSync,
            };
        }
        if self.cpu.is_some() {
            chosen.cpu = self.cpu;
        }
        if let Some(p) = self.rt_priority {
            chosen.rt_priority = (p > 0).then_some(p);
        }
        chosen.mlock |= self.mlock;
        if let Some(k) = self.keep_awake {
            if k == OnOff::On && chosen.cpu.is_none() {
                return Err(AppError::Usage(
                    "--keep-awake on needs a pinned CPU (--cpu N, or a profile that pins one)"
                        .into(),
                ));
            }
            chosen.keep_awake = k == OnOff::On;
        }
        let overridden = self.wait.is_some()
            || self.cpu.is_some()
            || self.rt_priority.is_some()
            || self.mlock
            || self.keep_awake.is_some();
        eprintln!(
            "infer-server: profile {}{} on {}: {}",
            profile_name(chosen.profile),
            match (self.profile, overridden) {
                (Profile::Auto, false) => " (auto)",
                (Profile::Auto, true) => " (auto, with explicit flags)",
                (_, true) => " (with explicit flags)",
                _ => "",
            },
            machine.describe(),
            chosen.describe()
        );
        // Every numeric setting checked here, with what is allowed (the control plane's own,
        // like the upload limits, are checked by control_plane::Config::check).
        let numeric = [
            ("--load-timeout-s", self.load_timeout_s, 0.0, 600.0, false),
            ("--stats-every", self.stats_every, 0.0, 86_400.0, true),
            ("--ort-threads", self.ort_threads as f64, 1.0, 64.0, true),
            (
                "--model-memory-mib",
                self.model_memory_mib as f64,
                16.0,
                65_536.0,
                true,
            ),
        ];
        for (flag, v, lo, hi, lo_ok) in numeric {
            let above_lo = if lo_ok { v >= lo } else { v > lo };
            if !(v.is_finite() && above_lo && v <= hi) {
                let lo_word = if lo_ok { ">=" } else { ">" };
                return Err(AppError::Usage(format!(
                    "{flag} is {v}; it must be {lo_word} {lo} and <= {hi}"
                )));
            }
        }
        let session = SessionConfig {
            intra_threads: self.ort_threads,
            spinning: self.ort_spin,
            load_timeout: Duration::from_secs_f64(self.load_timeout_s),
            memory_limit: Some(self.model_memory_mib << 20),
            ..SessionConfig::default()
        };
        let token = match self
            .token
            .or_else(|| std::env::var("HAPTICS_TOKEN").ok())
            .filter(|t| !t.is_empty())
        {
            Some(t) => {
                control_plane::auth::check_token(&t)
                    .map_err(|e| AppError::Usage(format!("--token / HAPTICS_TOKEN: {e}")))?;
                t
            }
            None => new_token().map_err(|e| {
                AppError::Refused(format!("cannot create a token (/dev/urandom): {e}"))
            })?,
        };
        // The connection file's name: the instance, or the explicit segment's name.
        let instance = match &self.segment {
            Some(s) => s.trim_start_matches('/').trim_start_matches("haptics-"),
            None => self.instance.as_str(),
        }
        .to_string();
        let mut allowed_hosts = self.allowed_hosts;
        if let Ok(env) = std::env::var("HAPTICS_ALLOWED_HOSTS") {
            allowed_hosts.extend(
                env.split(',')
                    .map(str::trim)
                    .filter(|h| !h.is_empty())
                    .map(String::from),
            );
        }
        let control = control_plane::Config {
            grpc_addr: self.grpc,
            http_addr: self.http,
            token: Some(token),
            metrics_open: self.open_metrics,
            allow_public_without_token: self.allow_public_without_token,
            max_upload_bytes: self.max_upload_mib.saturating_mul(1 << 20),
            max_uploads_in_flight_bytes: self.max_uploads_mib.saturating_mul(1 << 20),
            allowed_hosts,
            // Streams end at once on shutdown; this is for connections that hang on.
            shutdown_grace: Duration::from_millis(1000),
            version: env!("CARGO_PKG_VERSION").to_string(),
            ..control_plane::Config::default()
        };
        let (models_dir, start_model) =
            resolve_models(self.models, self.model).map_err(AppError::Usage)?;
        Ok(AppConfig {
            instance,
            ort_lib,
            models_dir,
            start_model,
            inference: InferenceConfig {
                segment,
                wait: chosen.wait,
                cpu: chosen.cpu,
                rt_priority: chosen.rt_priority,
                exit_when_loop_gone: self.exit_when_loop_gone,
                keep_awake: chosen.keep_awake,
            },
            session,
            control,
            lock_memory: chosen.mlock,
            stats_every: (self.stats_every > 0.0)
                .then(|| Duration::from_secs_f64(self.stats_every)),
        })
    }
}

/// A token of 16 random bytes in hex (32 characters), from the kernel's generator.
pub fn new_token() -> std::io::Result<String> {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
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
