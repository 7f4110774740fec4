//! Opening an ONNX object's graph and checking it against the object contract
//! (docs/laws/onnx.md), off the real-time path: everything here may allocate.
//!
//! The contract is the product's stateful model contract (docs/model-contract.md) read for an
//! object: input `features` (float32, one row: `[1, n]`) whose columns the metadata
//! `haptics.features` names, each `position_x` (m, into the object) or `velocity` (m/s);
//! output `force` (float32, one element, N, >= 0 pushes the probe back); any number of state
//! pairs, an input `NAME_in` and an output `NAME_out` of the same static float32 shape (the
//! model contract's `h_in`/`h_out`, `c_in`/`c_out` are two such pairs). So a stateful model
//! served by infer-server on position and velocity is an object as it is.

use std::ffi::{c_char, CString};
use std::path::{Path, PathBuf};

use haptics_ort_host::reference::{self, Reference, META_REFERENCE};
use ort::session::Session;
use ort::value::{TensorElementType, ValueType};

use super::ort_runtime::{environment, one_line};

/// The input carrying the kinematics.
pub const INPUT_FEATURES: &str = "features";
/// The output carrying the force.
pub const OUTPUT_FORCE: &str = "force";
/// The metadata naming the input's columns.
pub const META_FEATURES: &str = "haptics.features";
/// The metadata naming the force's unit (optional; `N` when present).
pub const META_UNITS: &str = "haptics.units";
/// The columns the bench can feed.
pub const KNOWN_FEATURES: [&str; 2] = ["position_x", "velocity"];
/// Most elements of one state tensor (the model contract's loader limit, 4 MiB of float32).
pub const MAX_STATE_ELEMENTS: usize = 1 << 20;

/// What the bench feeds into one column of `features`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Feature {
    /// The probe's position x, m (positive into the object, 0 at its surface).
    PositionX,
    /// Its velocity, m/s: the position's change since the graph's last step over the time
    /// since then.
    Velocity,
}

/// Why a graph cannot be an object. Each is one line naming the file.
#[derive(Debug, thiserror::Error)]
pub enum OnnxObjectError {
    #[error("{0}")]
    Runtime(String),
    #[error("cannot read the ONNX graph {path}: {reason}")]
    Unreadable { path: PathBuf, reason: String },
    #[error("{path} is not a graph ONNX Runtime can load: {reason}")]
    Corrupt { path: PathBuf, reason: String },
    #[error("{path} does not meet the object contract (docs/laws/onnx.md): {detail}")]
    Contract { path: PathBuf, detail: String },
    #[error("{path}: {detail}")]
    Warmup { path: PathBuf, detail: String },
    /// The graph's reference steps (`haptics.reference`) give other forces here than at its
    /// export: this rt-loop would press another object than the one exported.
    #[error("{path}: {detail}: this rt-loop's ONNX Runtime or fused operators read the graph otherwise than its exporter's did (a build older than the exporter's ignores the attributes it does not know; rebuild: `source scripts/env.sh && haptics_build`), or the graph was changed after its export (export it again)")]
    Reference { path: PathBuf, detail: String },
}

/// One state pair: the tensor fed as `name_in` and read back from `name_out`.
#[derive(Debug)]
pub struct StatePair {
    pub input: String,
    pub output: String,
    pub shape: Vec<i64>,
    pub len: usize,
}

/// A loaded, checked graph: one ONNX Runtime session, shared (`Arc`) by every copy of the
/// object; each copy has its own tensors. The copies (the bench's object, the oracle's) are
/// stepped by the loop's one thread: ONNX Runtime's own operators allow concurrent `Run`s on
/// one session, but the fused network and SVR kernels keep scratch space per session
/// (docs/model-contract.md), so copies must not be stepped from two threads at once.
pub struct OnnxGraph {
    pub path: PathBuf,
    pub(super) session: Session,
    pub features: Box<[Feature]>,
    pub features_shape: Vec<i64>,
    pub force_shape: Vec<i64>,
    pub state: Box<[StatePair]>,
    /// Its reference steps (`haptics.reference`, which `haptics-train export` writes), checked
    /// when the material file opens it (`OnnxFile::open`); `None` when it carries none.
    pub reference: Option<Reference>,
    /// Input names (features, then the state inputs) and output names (force, then the state
    /// outputs), NUL-terminated for the C API, in the order the object binds them.
    pub(super) in_names: Box<[CString]>,
    pub(super) out_names: Box<[CString]>,
}

impl std::fmt::Debug for OnnxGraph {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxGraph")
            .field("path", &self.path)
            .field("features", &self.features)
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

impl OnnxGraph {
    /// Opens `path` and checks it against the contract. A missing library, an unreadable or
    /// corrupt file and a graph of the wrong shape get different one-line errors.
    pub fn open(path: &Path) -> Result<OnnxGraph, OnnxObjectError> {
        let env = environment().map_err(OnnxObjectError::Runtime)?;
        let bytes = std::fs::read(path).map_err(|e| OnnxObjectError::Unreadable {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        let corrupt = |e: String| OnnxObjectError::Corrupt {
            path: path.to_path_buf(),
            reason: one_line(&e),
        };
        // As infer-server opens its sessions (ort-host/src/session.rs): all the work on the
        // caller's thread, every graph optimisation, memory patterns, and the fused operators
        // registered, so an exported `structured` or `lawfree` model (one `ai.haptics` node) is
        // an object as it is.
        let builder = haptics_ort_host::session::builder(env, Default::default())
            .map_err(|e| OnnxObjectError::Runtime(e.to_string()))?;
        let session = haptics_ort_host::session::commit(builder, &bytes)
            .map_err(|e| corrupt(e.to_string()))?;
        let contract = |detail: String| OnnxObjectError::Contract {
            path: path.to_path_buf(),
            detail,
        };
        let features = read_features(&session).map_err(contract)?;
        let (features_shape, force_shape, state) =
            check_signature(&session, features.len()).map_err(contract)?;
        let reference = read_reference(&session, features.len()).map_err(contract)?;
        let in_names = std::iter::once(INPUT_FEATURES)
            .chain(state.iter().map(|p| p.input.as_str()))
            .map(c_name)
            .collect();
        let out_names = std::iter::once(OUTPUT_FORCE)
            .chain(state.iter().map(|p| p.output.as_str()))
            .map(c_name)
            .collect();
        Ok(OnnxGraph {
            path: path.to_path_buf(),
            session,
            features,
            features_shape,
            force_shape,
            state,
            reference,
            in_names,
            out_names,
        })
    }

    pub(super) fn in_name_ptrs(&self) -> impl Iterator<Item = *const c_char> + '_ {
        self.in_names.iter().map(|c| c.as_ptr())
    }

    pub(super) fn out_name_ptrs(&self) -> impl Iterator<Item = *const c_char> + '_ {
        self.out_names.iter().map(|c| c.as_ptr())
    }
}

fn c_name(s: &str) -> CString {
    // ONNX names come from the graph's protobuf strings, which the checks matched against the
    // contract's names; a NUL inside one would have failed those checks.
    CString::new(s).unwrap_or_default()
}

/// `haptics.features`: the input's columns, each one the bench can feed; `haptics.units`, when
/// present, must be `N`.
fn read_features(session: &Session) -> Result<Box<[Feature]>, String> {
    let meta = session
        .metadata()
        .map_err(|e| format!("cannot read its metadata: {}", one_line(&e.to_string())))?;
    if let Some(u) = meta.custom(META_UNITS).filter(|u| u != "N") {
        return Err(format!("{META_UNITS} is {u:?}; the force must be in N"));
    }
    let names = meta.custom(META_FEATURES).ok_or_else(|| {
        format!(
            "no {META_FEATURES} metadata: name the columns of `{INPUT_FEATURES}` (from {})",
            KNOWN_FEATURES.join(", ")
        )
    })?;
    names
        .split(',')
        .map(|n| match n.trim() {
            "position_x" => Ok(Feature::PositionX),
            "velocity" => Ok(Feature::Velocity),
            other => Err(format!(
                "{META_FEATURES} names {other:?}; an object's graph may use {}",
                KNOWN_FEATURES.join(", ")
            )),
        })
        .collect()
}

/// `haptics.reference`, when present: parsed for `n` features (ort-host's format, the one
/// infer-server reads).
fn read_reference(session: &Session, n: usize) -> Result<Option<Reference>, String> {
    let meta = session
        .metadata()
        .map_err(|e| format!("cannot read its metadata: {}", one_line(&e.to_string())))?;
    meta.custom(META_REFERENCE)
        .map(|raw| reference::parse(&raw, n).map_err(|why| format!("{META_REFERENCE}: {why}")))
        .transpose()
}

/// A float32 tensor's declared shape, a dynamic dimension (-1) read as 1 (the bench feeds one
/// row), with at most [`MAX_STATE_ELEMENTS`] elements.
fn shape_of(name: &str, ty: &ValueType) -> Result<(Vec<i64>, usize), String> {
    let ValueType::Tensor { ty, shape, .. } = ty else {
        return Err(format!("{name} must be a float32 tensor, is {ty:?}"));
    };
    if *ty != TensorElementType::Float32 {
        return Err(format!("{name} must be float32, is {ty:?}"));
    }
    let dims: Vec<i64> = shape.iter().map(|&d| if d < 0 { 1 } else { d }).collect();
    if dims.len() > 8 {
        return Err(format!("{name} has rank {}, at most 8", dims.len()));
    }
    let len = dims
        .iter()
        .try_fold(1usize, |n, &d| n.checked_mul(d as usize))
        .filter(|&n| n <= MAX_STATE_ELEMENTS)
        .ok_or_else(|| {
            format!("{name} of shape {dims:?} has over {MAX_STATE_ELEMENTS} elements")
        })?;
    Ok((dims, len))
}

type Signature = (Vec<i64>, Vec<i64>, Box<[StatePair]>);

/// Inputs: `features` with `n` elements and state inputs `NAME_in`; outputs: `force` (one
/// element) and, for each state input, `NAME_out` of its shape; nothing else.
fn check_signature(session: &Session, n: usize) -> Result<Signature, String> {
    let mut features_shape = None;
    let mut state = Vec::new();
    for i in session.inputs() {
        let (shape, len) = shape_of(i.name(), i.dtype())?;
        if i.name() == INPUT_FEATURES {
            if len != n {
                return Err(format!(
                    "input `{INPUT_FEATURES}` has shape {shape:?} ({len} values) but \
                     {META_FEATURES} names {n} columns"
                ));
            }
            features_shape = Some(shape);
        } else if let Some(stem) = i.name().strip_suffix("_in") {
            state.push(StatePair {
                input: i.name().to_string(),
                output: format!("{stem}_out"),
                shape,
                len,
            });
        } else {
            return Err(format!(
                "input `{}` is neither `{INPUT_FEATURES}` nor a state input `NAME_in`",
                i.name()
            ));
        }
    }
    let features_shape = features_shape.ok_or_else(|| format!("no input `{INPUT_FEATURES}`"))?;
    let mut force_shape = None;
    let mut outputs_seen = 0;
    for o in session.outputs() {
        let (shape, len) = shape_of(o.name(), o.dtype())?;
        if o.name() == OUTPUT_FORCE {
            if len != 1 {
                return Err(format!(
                    "output `{OUTPUT_FORCE}` has shape {shape:?}; one value expected"
                ));
            }
            force_shape = Some(shape);
        } else if let Some(p) = state.iter().find(|p| p.output == o.name()) {
            if p.shape != shape {
                return Err(format!(
                    "state output `{}` has shape {shape:?}, its input `{}` {:?}",
                    p.output, p.input, p.shape
                ));
            }
            outputs_seen += 1;
        } else {
            return Err(format!(
                "output `{}` is neither `{OUTPUT_FORCE}` nor the `_out` of a state input",
                o.name()
            ));
        }
    }
    if outputs_seen != state.len() {
        let missing: Vec<&str> = state
            .iter()
            .filter(|p| !session.outputs().iter().any(|o| o.name() == p.output))
            .map(|p| p.output.as_str())
            .collect();
        return Err(format!("no state output {missing:?} for its input"));
    }
    let force_shape = force_shape.ok_or_else(|| format!("no output `{OUTPUT_FORCE}`"))?;
    Ok((features_shape, force_shape, state.into_boxed_slice()))
}
