//! A model, from its file to the engine that steps it: the contract it must meet, the ONNX
//! Runtime it runs on, the memory it may take, and the allocation-free per-step runner.
//!
//! - this file: loading a model file and checking it against the contract, before anything runs
//!   it. Everything here runs off the hot path (it allocates freely).
//!   [`engine::StepEngine`] builds on it: it adds the preallocated buffers and the warm-up run.
//! - [`contract`]: the model contract (metadata keys, input/output names, the nine features).
//! - [`contract_check`]: the contract's checks on plain data (no ONNX Runtime: the fuzz target
//!   compiles it as it is).
//! - [`runtime`]: finds and loads ONNX Runtime (the PyPI wheel's library, `load-dynamic`).
//! - [`memory_limit`]: the arena that bounds what a model may allocate while it runs.
//! - [`engine`]: [`engine::StepEngine`], the allocation-free per-step runner.

pub mod contract;
pub mod contract_check;
pub mod engine;
pub mod memory_limit;
pub mod runtime;

use std::path::{Path, PathBuf};

use ort::session::Session;
use ort::value::{TensorElementType, ValueType};

use crate::model::contract::ModelKind;
pub use crate::model::contract_check::{
    check_declared, map_features, parse_metadata, parse_reference, Declared, Metadata, ModelError,
    Reference, Signature,
};
use crate::model::runtime::Runtime;

/// How ONNX Runtime runs a session. The defaults are what the inference thread wants: the
/// caller's thread does all the work (one intra-op thread means ONNX Runtime starts no pool
/// thread of its own), and nothing spins.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionConfig {
    /// Intra-op threads; 1 keeps all work on the calling (inference) thread.
    pub intra_threads: usize,
    /// Let ONNX Runtime's pool threads spin while waiting for work. Off by default: on a
    /// two-core machine a spinning pool steals the loop's core. Only matters with
    /// `intra_threads > 1`.
    pub spinning: bool,
    /// Warm-up runs before a model is accepted (at least 1: the finite-output check).
    pub warmup_runs: usize,
    /// Bind inputs and outputs once (`OrtIoBinding`, one binding per state phase) and step with
    /// `RunWithBinding` instead of `Run` with preallocated outputs. Both write into the same
    /// preallocated buffers; the binding makes ONNX Runtime allocate 1-4 fewer times per call
    /// at the same speed (`scripts/bench-models.sh`), so it is the default.
    pub io_binding: bool,
    /// How long the server's registry lets a load (session, checks, warm-up) take before it
    /// stops it ([`crate::model::engine::load_bounded`]); 10 s by default.
    pub load_timeout: std::time::Duration,
    /// Most bytes the models' working memory may take, in one CPU arena all sessions share
    /// ([`crate::model::memory_limit`]); a model whose run needs more fails its warm-up and is refused.
    /// `None`: ONNX Runtime's own arena per session, unbounded (the one-shot subcommands).
    pub memory_limit: Option<usize>,
}

impl Default for SessionConfig {
    fn default() -> Self {
        Self {
            intra_threads: 1,
            spinning: false,
            warmup_runs: 32,
            io_binding: true,
            load_timeout: std::time::Duration::from_secs(10),
            memory_limit: None,
        }
    }
}

/// What the contract and the model's signature say, once checked.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ModelInfo {
    pub path: PathBuf,
    pub kind: ModelKind,
    /// `haptics.previous_force`, if the model declares it.
    pub previous_force: Option<String>,
    /// `haptics.step_s`: the period its state steps at, s, if the model declares it.
    pub step_s: Option<f64>,
    /// `haptics.feature_gains`: (g_v, g_a) of its training features, rad/s, if declared.
    pub feature_gains: Option<(f64, f64)>,
    /// The model's input features, in its input order.
    pub features: Vec<String>,
    pub units: String,
    pub provenance: serde_json::Value,
    /// For each model input feature, its index in the schema it was validated against.
    pub input_map: Vec<usize>,
    /// The schema the model was validated against (the segment's, or the standard nine).
    pub schema: Vec<String>,
    /// Concrete shape of the `features` input as fed: `[1, n]` or `[1, 1, n]`.
    pub features_shape: Vec<i64>,
    /// Concrete shape of `h_in`/`c_in` (stateful models only).
    pub state_shape: Option<Vec<i64>>,
    /// Shape of the `force` output as the model produces it for one sample.
    pub force_shape: Vec<i64>,
    /// What one call costs: `{"export": the `haptics.cost` metadata (null without it),
    /// "warmup": this load's warm-up on this machine}` (docs/model-contract.md, "Cost").
    /// Boxed: the info travels inside enums whose variants should stay small.
    pub cost: Box<serde_json::Value>,
    /// How many reference steps (`haptics.reference`) this engine checked itself against when
    /// it loaded the model, all within their tolerance; `None`: the model carries none (a
    /// model exported before them, or written by hand).
    pub reference_steps: Option<usize>,
}

/// rt-loop's default per-step deadline for the server's answer (`--deadline-us`), us: a model
/// whose warm-up steps take longer cannot answer in time on this machine.
pub const LOOP_DEADLINE_US: f64 = 50.0;

/// The model's `haptics.cost` metadata (what its export measured), parsed; null without it
/// (older models) or when it is not JSON.
pub fn read_cost(session: &Session) -> serde_json::Value {
    session
        .metadata()
        .ok()
        .and_then(|m| m.custom("haptics.cost"))
        .and_then(|s| serde_json::from_str(&s).ok())
        .unwrap_or(serde_json::Value::Null)
}

/// Opens `path` as a single-threaded session configured by `cfg`. The file is read first so a
/// missing or unreadable file and a corrupt one get different errors.
pub fn open_session(rt: &Runtime, path: &Path, cfg: &SessionConfig) -> Result<Session, ModelError> {
    let bytes = std::fs::read(path).map_err(|e| ModelError::Unreadable {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    open_session_from_bytes(rt, &bytes, path, cfg)
}

/// Opens a model held in memory (e.g. uploaded over gRPC). `label` names it in errors.
pub fn open_session_from_bytes(
    rt: &Runtime,
    bytes: &[u8],
    label: &Path,
    cfg: &SessionConfig,
) -> Result<Session, ModelError> {
    let session_err = |e: haptics_ort_host::SessionError| ModelError::Session {
        reason: e.to_string(),
    };
    // The product's one way to build a session (ort-host/src/session.rs: the caller's thread,
    // nothing spinning, every optimisation, memory patterns, the fused operators registered).
    let settings = haptics_ort_host::SessionSettings {
        intra_threads: cfg.intra_threads,
        spinning: cfg.spinning,
    };
    let builder =
        haptics_ort_host::session::builder(rt.environment(), settings).map_err(session_err)?;
    let builder = with_memory_limit(rt, builder, cfg)?;
    // one session created at a time in the process (ort-host says why)
    haptics_ort_host::session::commit(builder, bytes).map_err(|e| match e {
        haptics_ort_host::SessionError::Graph(reason) => ModelError::Corrupt {
            path: label.to_path_buf(),
            reason,
        },
        other => session_err(other),
    })
}

/// Makes the session allocate from the bounded arena when `cfg.memory_limit` is set.
fn with_memory_limit(
    rt: &Runtime,
    builder: ort::session::builder::SessionBuilder,
    cfg: &SessionConfig,
) -> Result<ort::session::builder::SessionBuilder, ModelError> {
    let Some(limit) = cfg.memory_limit else {
        return Ok(builder);
    };
    crate::model::memory_limit::register(rt, limit)
        .map_err(|reason| ModelError::Session { reason })?;
    builder
        .with_env_allocators()
        .map_err(|e| ModelError::Session {
            reason: e.to_string(),
        })
}

fn float_tensor_shape(name: &str, ty: &ValueType) -> Result<Vec<i64>, ModelError> {
    match ty {
        ValueType::Tensor { ty, shape, .. } => {
            if *ty != TensorElementType::Float32 {
                return Err(ModelError::BadShape {
                    name: name.to_string(),
                    detail: format!("must be a float32 tensor, is {ty:?}"),
                });
            }
            Ok(shape.iter().copied().collect())
        }
        other => Err(ModelError::BadShape {
            name: name.to_string(),
            detail: format!("must be a float32 tensor, is {other:?}"),
        }),
    }
}

/// Most bytes of `haptics.provenance` a model may carry (64 KiB): it is shown by every model
/// list and status (gRPC, `/api/models`, the page), so a model with megabytes of it would make
/// those answers huge (docs/model-contract.md, "Loader limits").
pub const MAX_PROVENANCE_BYTES: usize = 64 << 10;
/// Most bytes of any other `haptics.*` entry (4 KiB): names, a kind, units, a number.
pub const MAX_METADATA_VALUE_BYTES: usize = 4 << 10;
/// Most bytes of `haptics.reference` (16 KiB: the exporter's 32 steps of nine features take
/// about 5 KiB). Read once at load, never listed.
pub use haptics_ort_host::reference::MAX_REFERENCE_BYTES;

/// Reads and checks the `haptics.*` metadata entries, each capped in size first.
pub fn read_metadata(session: &Session) -> Result<Metadata, ModelError> {
    let meta = session.metadata().map_err(|e| ModelError::RunFailed {
        reason: format!("cannot read metadata: {e}"),
    })?;
    check_metadata_sizes(|key| meta.custom(key))?;
    parse_metadata(|key| meta.custom(key))
}

/// Refuses a model whose `haptics.*` metadata is over its cap ([`MAX_PROVENANCE_BYTES`],
/// [`MAX_METADATA_VALUE_BYTES`]); the error names the entry and its size, never its value.
pub fn check_metadata_sizes(custom: impl Fn(&str) -> Option<String>) -> Result<(), ModelError> {
    use crate::model::contract::{
        META_FEATURES, META_KIND, META_PREVIOUS_FORCE, META_PROVENANCE, META_REFERENCE,
        META_STATE_SIZE, META_UNITS,
    };
    for key in [
        META_FEATURES,
        META_KIND,
        META_UNITS,
        META_PROVENANCE,
        META_STATE_SIZE,
        META_PREVIOUS_FORCE,
        META_REFERENCE,
    ] {
        let limit = match key {
            META_PROVENANCE => MAX_PROVENANCE_BYTES,
            META_REFERENCE => MAX_REFERENCE_BYTES,
            _ => MAX_METADATA_VALUE_BYTES,
        };
        if let Some(v) = custom(key).filter(|v| v.len() > limit) {
            return Err(ModelError::BadMetadata {
                key: key.to_string(),
                value: format!("<{} bytes>", v.len()),
                reason: format!("at most {limit} bytes (the loader's metadata limit)"),
            });
        }
    }
    Ok(())
}

/// Checks input/output names, element types and shapes against the contract for `kind` with
/// `n` features.
pub fn check_signature(session: &Session, meta: &Metadata) -> Result<Signature, ModelError> {
    let declared = |name: &str, ty: &ValueType| (name.to_string(), float_tensor_shape(name, ty));
    let inputs: Vec<Declared> = session
        .inputs()
        .iter()
        .map(|o| declared(o.name(), o.dtype()))
        .collect();
    let outputs: Vec<Declared> = session
        .outputs()
        .iter()
        .map(|o| declared(o.name(), o.dtype()))
        .collect();
    check_declared(&inputs, &outputs, meta)
}
