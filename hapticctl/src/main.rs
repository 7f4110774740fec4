//! hapticctl: the command-line client of infer-server's control plane (gRPC `haptics.v1`).
mod client;
mod output;

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Duration;

use clap::{Parser, Subcommand};
use haptics_proto::experiment_args::ExperimentArgs;
use haptics_proto::grpc as pb;

use client::{connect, explain, CliError, Client, EXIT_USAGE};

#[derive(Parser, Debug)]
#[command(
    name = "hapticctl",
    version,
    about = "Control infer-server: models, hot swap, experiments, status and telemetry",
    after_help = "Examples:\n  hapticctl models\n  hapticctl swap rf_memory            (a model in the server's directory; scripts/up.sh trains it)\n  hapticctl swap ./new/lstm.onnx      (uploads a local file, then swaps)\n  hapticctl swap models/mine/lawfree.onnx --as mine.onnx   (under its own name)\n  hapticctl status --watch\n  hapticctl experiment start abstraction --ramp-rate 2.1 --cycles 10\n  hapticctl telemetry --decimation 1000"
)]
struct Cli {
    /// gRPC address of infer-server. Default: $HAPTICS_ADDR, else the address in the
    /// instance's connection file (written by infer-server), else http://127.0.0.1:50051.
    #[arg(long, global = true, env = "HAPTICS_ADDR")]
    addr: Option<String>,
    /// The server's token. Default: $HAPTICS_TOKEN, else the token in the instance's
    /// connection file when the address is that file's (so the server's owner needs none).
    #[arg(long, global = true, env = "HAPTICS_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// The instance whose connection file is read: $XDG_RUNTIME_DIR/haptics/INSTANCE.json,
    /// else /tmp/haptics-UID/INSTANCE.json.
    #[arg(
        long,
        global = true,
        env = "HAPTICS_INSTANCE",
        default_value = "default"
    )]
    instance: String,
    /// Print JSON instead of text (one object per line for streams).
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// List the models in the model directory and in memory, with their state.
    Models,
    /// Validate, warm and keep a model loaded (not active).
    Load {
        /// A model file name in the server's model directory.
        #[arg(required_unless_present = "file", conflicts_with = "file")]
        name: Option<String>,
        /// Upload this local file instead.
        #[arg(long)]
        file: Option<PathBuf>,
        /// The name to give the upload (default: the file's name).
        #[arg(long, requires = "file")]
        r#as: Option<String>,
    },
    /// Make a model the active one (loading or uploading it first when needed) and print the
    /// step at which the swap took effect.
    Swap {
        /// A name in the server's model directory, or a path to a local .onnx file to upload.
        model: String,
        /// Upload the local file under this name (default: the file's name). For a model
        /// trained elsewhere whose file name the server's directory already has (each
        /// `haptics-train` models folder holds a `lawfree.onnx`): the server refuses a
        /// different file under a name its directory has.
        #[arg(long)]
        r#as: Option<String>,
    },
    /// Drop a loaded model from the server's memory (not the active one).
    Unload { name: String },
    /// Show the active model.
    Active,
    /// Show the loop and server status.
    Status {
        /// Refresh until interrupted.
        #[arg(long)]
        watch: bool,
        /// Seconds between refreshes with --watch.
        #[arg(long, default_value_t = 1.0)]
        interval: f64,
        /// Stop after this many refreshes with --watch.
        #[arg(long, hide = true)]
        count: Option<u64>,
    },
    /// Start or stop an experiment on the loop.
    Experiment {
        #[command(subcommand)]
        action: ExperimentAction,
    },
    /// Stream live telemetry (min/max per bucket of `decimation` steps) until interrupted.
    Telemetry {
        /// Loop steps per printed sample.
        #[arg(long, default_value_t = 1000)]
        decimation: u32,
        /// Stop after this many samples.
        #[arg(long)]
        count: Option<u64>,
    },
}

#[derive(Subcommand, Debug)]
enum ExperimentAction {
    /// Start an experiment: abstraction, reproduction, shadow or position-replay.
    Start {
        /// abstraction | reproduction | shadow | position-replay
        kind: String,
        /// The same options as `rt-loop run`/`serve` (one definition, in haptics-proto).
        #[command(flatten)]
        params: ExperimentArgs,
    },
    /// Stop the running experiment.
    Stop,
}

#[tokio::main(flavor = "current_thread")]
async fn main() {
    let cli: Cli = haptics_proto::cli_parse::parse();
    if let Err(e) = run(cli).await {
        eprintln!("hapticctl: {}", e.message);
        std::process::exit(e.code);
    }
}

fn print_json(v: &serde_json::Value) {
    println!("{v}");
}

/// Reports `done` to `what` (a model unloaded, an experiment started): `{"<done>": "<what>"}`
/// with `--json`, else the line `<done> <what>`.
fn print_done(json: bool, done: &str, what: &str) {
    if json {
        print_json(&serde_json::json!({ done: what }));
    } else {
        println!("{done} {what}");
    }
}

async fn run(cli: Cli) -> Result<(), CliError> {
    let (addr, token) = client::resolve(cli.addr.as_deref(), cli.token.as_deref(), &cli.instance)?;
    let mut c = connect(&addr, token.as_deref()).await?;
    let addr = c.addr.clone();
    // Every failure names the call that failed (`GetStatus failed: ...`).
    let fail = |call: &'static str| {
        let addr = addr.clone();
        move |s: tonic::Status| explain(call, &s, &addr)
    };
    match cli.command {
        Command::Models => {
            let list = c
                .models
                .list_models(pb::ListModelsRequest {})
                .await
                .map_err(fail("ListModels"))?
                .into_inner();
            if cli.json {
                print_json(&serde_json::Value::Array(
                    list.models.iter().map(output::model_json).collect(),
                ));
            } else {
                print!("{}", output::models_table(&list.models));
            }
        }
        Command::Load { name, file, r#as } => {
            let model = match (name, file) {
                (Some(name), _) => load(&mut c, name, None).await?,
                (None, Some(path)) => upload(&mut c, &path, r#as).await?,
                (None, None) => unreachable!("clap requires one"),
            };
            if cli.json {
                print_json(&output::model_json(&model));
            } else {
                println!("loaded {}", output::model_line(&model));
            }
        }
        Command::Swap { model, r#as } => {
            let (model, step, warnings) = swap(&mut c, &model, r#as).await?;
            if cli.json {
                print_json(&serde_json::json!({
                    "model": output::model_json(&model),
                    "effective_step": step,
                    "warnings": warnings,
                }));
            } else {
                println!(
                    "{} is active from feature message {step} (the segment's count since the \
                     loop started serving; status's step counts the current run)",
                    model.name
                );
                // served anyway, but the user should know (e.g. other feature filters)
                for w in &warnings {
                    eprintln!("hapticctl: warning: {}: {w}", model.name);
                }
            }
        }
        Command::Unload { name } => {
            c.models
                .unload_model(pb::UnloadModelRequest { name: name.clone() })
                .await
                .map_err(fail("UnloadModel"))?;
            print_done(cli.json, "unloaded", &name);
        }
        Command::Active => {
            match c
                .models
                .get_active_model(pb::GetActiveModelRequest {})
                .await
            {
                Ok(m) => {
                    let m = m.into_inner();
                    if cli.json {
                        print_json(&output::model_json(&m));
                    } else {
                        println!(
                            "{} (since feature message {})",
                            output::model_line(&m),
                            m.active_since_step
                        );
                    }
                }
                Err(s) if s.code() == tonic::Code::NotFound => {
                    if cli.json {
                        print_json(&serde_json::Value::Null);
                    } else {
                        println!("no active model: the loop renders its fallback");
                    }
                }
                Err(s) => return Err(fail("GetActiveModel")(s)),
            }
        }
        Command::Status {
            watch,
            interval,
            count,
        } => {
            if !(interval.is_finite() && interval > 0.0) {
                return Err(CliError::new("--interval must be > 0 seconds", EXIT_USAGE));
            }
            let mut shown = 0u64;
            loop {
                let s = c
                    .looper
                    .get_status(pb::GetStatusRequest {})
                    .await
                    .map_err(fail("GetStatus"))?
                    .into_inner();
                if cli.json {
                    print_json(&output::status_json(&s));
                } else if watch && std::io::stdout().is_terminal() {
                    // Redraw in place, like `watch`.
                    print!("\x1b[H\x1b[2J{}", output::status_text(&s));
                    println!("\n(refreshing every {interval} s; Ctrl-C to stop)");
                } else {
                    if watch && shown > 0 {
                        println!();
                    }
                    print!("{}", output::status_text(&s));
                }
                shown += 1;
                if !watch || count.is_some_and(|n| shown >= n) {
                    break;
                }
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_secs_f64(interval)) => {}
                    _ = tokio::signal::ctrl_c() => break,
                }
            }
        }
        Command::Experiment { action } => match action {
            ExperimentAction::Start { kind, params } => {
                c.looper
                    .start_experiment(pb::StartExperimentRequest {
                        kind: kind.clone(),
                        ramp_rate: params.ramp_rate,
                        cycles: params.cycles,
                        f_max_start: params.f_max_start,
                        f_max_step: params.f_max_step,
                    })
                    .await
                    .map_err(fail("StartExperiment"))?;
                print_done(cli.json, "started", &kind);
            }
            ExperimentAction::Stop => {
                c.looper
                    .stop_experiment(pb::StopExperimentRequest {})
                    .await
                    .map_err(fail("StopExperiment"))?;
                // The loop reads its mailbox every few steps: wait until the status says it has
                // stopped, so that an `experiment start` right after this one is not refused.
                wait_idle(&mut c).await?;
                if cli.json {
                    print_json(&serde_json::json!({ "stopped": true }));
                } else {
                    println!("stopped");
                }
            }
        },
        Command::Telemetry { decimation, count } => {
            let mut stream = c
                .looper
                .stream_telemetry(pb::StreamTelemetryRequest { decimation })
                .await
                .map_err(fail("StreamTelemetry"))?
                .into_inner();
            if !cli.json {
                println!("{}", output::SAMPLE_HEADER);
            }
            let mut n = 0u64;
            let mut nan_said = false;
            while count.is_none_or(|c| n < c) {
                let next = tokio::select! {
                    next = stream.message() => next,
                    _ = tokio::signal::ctrl_c() => break,
                };
                let Some(x) = next.map_err(fail("StreamTelemetry"))? else {
                    eprintln!("hapticctl: the server ended the stream (shutting down?)");
                    break;
                };
                if cli.json {
                    print_json(&output::sample_json(&x));
                } else {
                    println!("{}", output::sample_line(&x));
                    if x.f_pred.is_nan() && !nan_said {
                        nan_said = true;
                        eprintln!("hapticctl: {}", output::F_PRED_NAN);
                    }
                }
                n += 1;
            }
        }
    }
    Ok(())
}

/// Polls the status until no experiment runs (at most [`STOP_WAIT`]); a loop that does not stop
/// in that time is said so, not waited for.
async fn wait_idle(c: &mut Client) -> Result<(), CliError> {
    let end = tokio::time::Instant::now() + STOP_WAIT;
    loop {
        let s = c
            .looper
            .get_status(pb::GetStatusRequest {})
            .await
            .map_err(|s| explain("GetStatus", &s, &c.addr))?
            .into_inner();
        if !s.experiment.is_some_and(|e| e.running) {
            return Ok(());
        }
        if tokio::time::Instant::now() >= end {
            return Err(CliError::new(
                format!(
                    "asked the loop to stop, but it still runs its experiment after {} s",
                    STOP_WAIT.as_secs()
                ),
                client::EXIT_SERVER,
            ));
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// How long `experiment stop` waits for the loop to say it has stopped.
const STOP_WAIT: Duration = Duration::from_secs(5);

async fn load(
    c: &mut Client,
    name: String,
    bytes: Option<Vec<u8>>,
) -> Result<pb::ModelInfo, CliError> {
    let r = c
        .models
        .load_model(pb::LoadModelRequest {
            name,
            onnx: bytes.unwrap_or_default(),
        })
        .await
        .map_err(|s| explain("LoadModel", &s, &c.addr))?;
    r.into_inner()
        .model
        .ok_or_else(|| CliError::new("the server answered without the model", client::EXIT_SERVER))
}

/// Uploads a local file, after checking it against the server's limit (so a large file is not
/// sent for nothing).
async fn upload(
    c: &mut Client,
    path: &Path,
    name: Option<String>,
) -> Result<pb::ModelInfo, CliError> {
    let bytes = std::fs::read(path)
        .map_err(|e| CliError::new(format!("cannot read {}: {e}", path.display()), EXIT_USAGE))?;
    if bytes.is_empty() {
        return Err(CliError::new(
            format!("{} is empty", path.display()),
            EXIT_USAGE,
        ));
    }
    let name = match name {
        Some(n) => n,
        None => path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .ok_or_else(|| {
                CliError::new(format!("{} has no file name", path.display()), EXIT_USAGE)
            })?,
    };
    let status = c
        .looper
        .get_status(pb::GetStatusRequest {})
        .await
        .map_err(|s| explain("GetStatus", &s, &c.addr))?
        .into_inner();
    let limit = status.max_upload_bytes;
    if limit > 0 && bytes.len() as u64 > limit {
        return Err(CliError::new(
            format!(
                "{} is {} bytes, over the server's upload limit of {limit} bytes: put it in the \
                 server's model directory and load it by name, or raise the limit",
                path.display(),
                bytes.len()
            ),
            client::EXIT_SERVER,
        ));
    }
    load(c, name, Some(bytes)).await
}

/// A refused upload whose name the server's directory has for another file: says how to
/// upload it under another name.
fn same_name_hint(e: CliError, path: &str) -> CliError {
    if !e.message.contains("upload under another name") {
        return e;
    }
    CliError::new(
        format!("{}: swap {path} --as NEW_NAME.onnx", e.message),
        e.code,
    )
}

/// `swap NAME` activates a model of the server's directory (loading it if needed); `swap PATH`
/// (a path with a `/`, or a bare name the server does not have but that exists here) uploads the
/// local file first.
async fn swap(
    c: &mut Client,
    model: &str,
    upload_as: Option<String>,
) -> Result<(pb::ModelInfo, u64, Vec<String>), CliError> {
    let local = Path::new(model);
    if upload_as.is_some() && !local.is_file() {
        return Err(CliError::new(
            format!("--as names an upload, but {model} is not a local file"),
            EXIT_USAGE,
        ));
    }
    let name = if model.contains('/') || upload_as.is_some() {
        upload(c, local, upload_as)
            .await
            .map_err(|e| same_name_hint(e, model))?
            .name
    } else {
        model.to_string()
    };
    let activate = |name: String| pb::ActivateModelRequest {
        name,
        load_if_needed: true,
    };
    let r = match c.models.activate_model(activate(name.clone())).await {
        Err(s) if s.code() == tonic::Code::NotFound && local.is_file() && !model.contains('/') => {
            let name = upload(c, local, None)
                .await
                .map_err(|e| same_name_hint(e, model))?
                .name;
            c.models.activate_model(activate(name)).await
        }
        r => r,
    }
    .map_err(|s| explain("ActivateModel", &s, &c.addr))?
    .into_inner();
    let model = r.model.ok_or_else(|| {
        CliError::new("the server answered without the model", client::EXIT_SERVER)
    })?;
    Ok((model, r.effective_step, r.warnings))
}
