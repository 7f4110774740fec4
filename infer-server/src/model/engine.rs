//! The per-step engine: one validated model, its preallocated input and output tensors, and the
//! recurrent state it carries between steps.
//!
//! Hot path ([`StepEngine::step`]): gather the model's features from the schema-ordered vector
//! into the preallocated input buffer, call ONNX Runtime's C `Run` with the input and output
//! values created at load time, read the force from the preallocated output. A stateful model's
//! state lives in two pairs of tensors that swap roles every step (ping-pong): the step's
//! `h_out`/`c_out` are written straight into the tensors the next step binds as `h_in`/`c_in`,
//! so the state is never copied. The Rust side allocates nothing and takes no lock: the name
//! and value pointer arrays (one set per phase) are built once here, and `ort`'s safe `run`
//! (which builds `SmallVec`s, C strings and a `SessionOutputs` map on every call) is bypassed.
//! What ONNX Runtime does inside `Run` is its own business; `benches/step_latency.rs` counts the
//! `malloc` calls it makes per step (see docs/infer-server.md for the figures).

use std::ffi::{c_char, CStr, CString};
use std::path::{Path, PathBuf};
use std::ptr;
use std::sync::atomic::{AtomicU8, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc};

use haptics_ort_host::Binding;
use ort::session::{RunOptions, Session};
use ort::sys::{OrtRunOptions, OrtStatus, OrtValue};
use ort::value::Tensor;
use ort::AsPointer;

use crate::model::contract::{
    checked_elements, FeatureSchema, ModelKind, INPUT_C, INPUT_FEATURES, INPUT_H, OUTPUT_C,
    OUTPUT_FORCE, OUTPUT_H,
};
use crate::model::runtime::Runtime;
use crate::model::{self, ModelError, ModelInfo, SessionConfig};

/// A feature value as it arrives from a producer (recordings are f64; models take f32).
pub trait FeatureValue: Copy {
    fn to_f32(self) -> f32;
}

impl FeatureValue for f32 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
}

impl FeatureValue for f64 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}

/// A failed step. Small and `Copy` so the hot loop's error path allocates nothing; ONNX
/// Runtime's message for the last failure is kept in the engine
/// ([`StepEngine::last_error_message`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepError {
    /// The vector handed in is shorter than the schema the model was validated against.
    SchemaLength { expected: usize, got: usize },
    /// A feature the model uses is NaN or infinite (or beyond f32's range): the model is not
    /// run. (ONNX Runtime's activations clamp NaN, so a model fed NaN may well answer a
    /// plausible-looking number; refusing here is the only reliable signal.)
    NonFiniteFeature { schema_index: usize },
    /// ONNX Runtime's `Run` failed with this error code.
    Run { code: i32 },
}

impl std::fmt::Display for StepError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            StepError::SchemaLength { expected, got } => write!(
                f,
                "feature vector has {got} values, the schema has {expected}"
            ),
            StepError::NonFiniteFeature { schema_index } => {
                write!(f, "feature #{schema_index} of the schema is not finite")
            }
            StepError::Run { code } => write!(f, "ONNX Runtime Run failed (code {code})"),
        }
    }
}

impl std::error::Error for StepError {}

/// ONNX Runtime's message for the last failed `Run`, copied into a fixed buffer.
struct ErrorText {
    buf: [u8; 256],
    len: usize,
}

impl ErrorText {
    /// Takes ownership of `status` (non-null), copies its message and releases it.
    fn take_status(&mut self, status: *mut OrtStatus) -> StepError {
        let api = ort::api();
        // SAFETY: `status` is a non-null status just returned by ONNX Runtime; its message is a
        // NUL-terminated string owned by the status, copied out before the status is released.
        unsafe {
            let code = (api.GetErrorCode)(status) as i32;
            let text = CStr::from_ptr((api.GetErrorMessage)(status)).to_bytes();
            self.len = text.len().min(self.buf.len());
            self.buf[..self.len].copy_from_slice(&text[..self.len]);
            (api.ReleaseStatus)(status);
            StepError::Run { code }
        }
    }

    fn as_str(&self) -> &str {
        let bytes = &self.buf[..self.len];
        // The buffer may have cut a UTF-8 sequence; show what decodes.
        match std::str::from_utf8(bytes) {
            Ok(s) => s,
            Err(e) => std::str::from_utf8(&bytes[..e.valid_up_to()]).unwrap_or(""),
        }
    }
}

/// Raw pointers into the recurrent-state tensors owned by the engine: two pairs, `h[p]`/`c[p]`
/// holding the current state in phase `p`, the other pair receiving the next.
struct StateBuffers {
    h: [*mut f32; 2],
    c: [*mut f32; 2],
    len: usize,
}

/// One loaded, validated, warmed-up model, ready to be stepped by exactly one thread.
pub struct StepEngine {
    info: ModelInfo,
    session: Session,
    // The tensors below own the memory the raw pointers point into. `Value`s keep their data on
    // the heap, so moving the engine (e.g. handing it to the inference thread) moves nothing the
    // pointers see. They are never replaced after construction.
    _inputs: Vec<Tensor<f32>>,
    _outputs: Vec<Tensor<f32>>,
    _names: Vec<CString>,
    in_names: Box<[*const c_char]>,
    /// Per phase (see [`StateBuffers`]; a stateless model uses phase 0 only).
    in_values: [Box<[*const OrtValue]>; 2],
    out_names: Box<[*const c_char]>,
    out_values: [Box<[*mut OrtValue]>; 2],
    features: *mut f32,
    force: *const f32,
    state: Option<StateBuffers>,
    /// Which pair holds the current state (always 0 for a stateless model).
    phase: usize,
    input_map: Box<[usize]>,
    schema_len: usize,
    last_error: ErrorText,
    /// Created once and passed to every run (a null one makes ONNX Runtime build a default
    /// `RunOptions` per call). Shared with [`load_bounded`], which sets its terminate flag to
    /// stop a load that ran out of time in the middle of a run.
    _run_options_owner: Arc<RunOptions>,
    run_options: *mut OrtRunOptions,
    /// With `SessionConfig::io_binding`: inputs and outputs bound once per phase,
    /// `RunWithBinding` per step.
    binding: [Option<Binding>; 2],
}

impl Drop for StepEngine {
    fn drop(&mut self) {
        // Before the fields (session, tensors) go: the bindings refer to both.
        self.binding = [None, None];
    }
}

impl std::fmt::Debug for StepEngine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StepEngine")
            .field("info", &self.info)
            .finish_non_exhaustive()
    }
}

// SAFETY: every raw pointer points into tensors (or C strings) owned by this struct, and the
// engine is only ever used through `&mut self` by one thread at a time. ONNX Runtime sessions may
// be moved between threads (`ort::Session` is `Send`).
unsafe impl Send for StepEngine {}

/// A zeroed tensor of `shape`, whose size is checked (caps, checked arithmetic) before anything
/// is allocated: a crafted shape gets `BadShape`, never an aborting allocation.
fn zeros(name: &str, shape: &[i64]) -> Result<Tensor<f32>, ModelError> {
    let len = checked_elements(shape).map_err(|detail| ModelError::BadShape {
        name: name.to_string(),
        detail,
    })?;
    Tensor::from_array((shape.to_vec(), vec![0f32; len].into_boxed_slice())).map_err(|e| {
        ModelError::Session {
            reason: format!("cannot allocate a tensor of shape {shape:?}: {e}"),
        }
    })
}

fn data_mut(t: &mut Tensor<f32>) -> *mut f32 {
    t.data_ptr_mut().cast::<f32>()
}

impl StepEngine {
    /// Loads `path`, checks it against the contract and `schema`, preallocates its buffers and
    /// runs the warm-up. Off the hot path: allocates, may take a while for large models.
    pub fn load(
        rt: &Runtime,
        path: &Path,
        schema: &FeatureSchema,
        cfg: &SessionConfig,
    ) -> Result<Self, ModelError> {
        let session = model::open_session(rt, path, cfg)?;
        Self::from_session(session, path, schema, cfg, new_run_options()?)
    }

    /// As [`StepEngine::load`], for a model held in memory (an upload); `label` stands for
    /// its path in [`ModelInfo::path`] and in errors.
    pub fn load_from_bytes(
        rt: &Runtime,
        bytes: &[u8],
        label: &Path,
        schema: &FeatureSchema,
        cfg: &SessionConfig,
    ) -> Result<Self, ModelError> {
        let session = model::open_session_from_bytes(rt, bytes, label, cfg)?;
        Self::from_session(session, label, schema, cfg, new_run_options()?)
    }

    fn from_session(
        mut session: Session,
        path: &Path,
        schema: &FeatureSchema,
        cfg: &SessionConfig,
        run_options: Arc<RunOptions>,
    ) -> Result<Self, ModelError> {
        let mut meta = model::read_metadata(&session)?;
        let reference = meta.reference.take();
        let input_map = model::map_features(&meta.features, schema)?;
        let sig = model::check_signature(&session, &meta)?;

        let mut info = ModelInfo {
            path: path.to_path_buf(),
            kind: meta.kind,
            previous_force: meta.previous_force,
            step_s: meta.step_s,
            feature_gains: meta.feature_gains,
            features: meta.features,
            units: meta.units,
            provenance: meta.provenance,
            input_map,
            schema: schema.names().to_vec(),
            features_shape: sig.features_shape.clone(),
            state_shape: sig.state_shape.clone(),
            force_shape: Vec::new(),
            cost: Box::new(serde_json::json!({ "export": model::read_cost(&session) })),
            reference_steps: None,
        };

        // Inputs, in the contract's order.
        let mut inputs = vec![zeros(INPUT_FEATURES, &sig.features_shape)?];
        let mut in_name_list = vec![INPUT_FEATURES];
        if let Some(s) = &sig.state_shape {
            inputs.push(zeros(INPUT_H, s)?);
            inputs.push(zeros(INPUT_C, s)?);
            in_name_list.extend([INPUT_H, INPUT_C]);
        }

        let mut out_name_list = vec![OUTPUT_FORCE];
        if sig.state_shape.is_some() {
            out_name_list.extend([OUTPUT_H, OUTPUT_C]);
        }

        // One run through ort's safe API with outputs left to ONNX Runtime tells the actual
        // output shapes (declared ones may be dynamic), which the preallocated outputs must match.
        let probe = probe_outputs(
            &mut session,
            &in_name_list,
            &inputs,
            &out_name_list,
            &run_options,
        )?;
        let force_shape = probe[0].0.clone();
        if checked_elements(&force_shape) != Ok(1) {
            return Err(ModelError::BadShape {
                name: OUTPUT_FORCE.to_string(),
                detail: format!(
                    "produced shape {force_shape:?} for one sample; one value expected"
                ),
            });
        }
        info.force_shape = force_shape.clone();
        let mut outputs = vec![zeros(OUTPUT_FORCE, &force_shape)?];
        if let Some(s) = &sig.state_shape {
            for (i, name) in [(1usize, OUTPUT_H), (2, OUTPUT_C)] {
                if probe[i].0 != *s {
                    return Err(ModelError::BadShape {
                        name: name.to_string(),
                        detail: format!("produced shape {:?}, h_in/c_in have {s:?}", probe[i].0),
                    });
                }
                outputs.push(zeros(name, s)?);
            }
        }
        check_finite(&probe, &out_name_list, &vec![0.0; info.features.len()])?;

        let names: Vec<CString> = in_name_list
            .iter()
            .chain(out_name_list.iter())
            .map(|n| CString::new(*n).expect("contract names have no NUL"))
            .collect();
        let in_names: Box<[*const c_char]> = names[..in_name_list.len()]
            .iter()
            .map(|c| c.as_ptr())
            .collect();
        let out_names: Box<[*const c_char]> = names[in_name_list.len()..]
            .iter()
            .map(|c| c.as_ptr())
            .collect();
        // Phase 0: the state pairs as allocated (inputs[1..] in, outputs[1..] out); phase 1:
        // the same tensors with their roles swapped. A stateless model has no state pairs:
        // both phases are the same.
        let phases = [0usize, 1].map(|phase| {
            let (ins, outs): (Vec<*const OrtValue>, Vec<*mut OrtValue>) = if phase == 0 {
                (
                    inputs
                        .iter_mut()
                        .map(|t| t.ptr_mut().cast_const())
                        .collect(),
                    outputs.iter_mut().map(|t| t.ptr_mut()).collect(),
                )
            } else {
                (
                    std::iter::once(inputs[0].ptr_mut().cast_const())
                        .chain(outputs[1..].iter_mut().map(|t| t.ptr_mut().cast_const()))
                        .collect(),
                    std::iter::once(outputs[0].ptr_mut())
                        .chain(inputs[1..].iter_mut().map(|t| t.ptr_mut()))
                        .collect(),
                )
            };
            (ins.into_boxed_slice(), outs.into_boxed_slice())
        });
        let [(in0, out0), (in1, out1)] = phases;
        let features = data_mut(&mut inputs[0]);
        let force = data_mut(&mut outputs[0]).cast_const();
        let state = sig.state_shape.as_ref().map(|s| StateBuffers {
            h: [data_mut(&mut inputs[1]), data_mut(&mut outputs[1])],
            c: [data_mut(&mut inputs[2]), data_mut(&mut outputs[2])],
            // Checked by `zeros` above, which allocated these buffers.
            len: checked_elements(s).unwrap_or(0),
        });

        let mut engine = StepEngine {
            input_map: info.input_map.clone().into_boxed_slice(),
            schema_len: schema.len(),
            info,
            session,
            _inputs: inputs,
            _outputs: outputs,
            _names: names,
            in_names,
            in_values: [in0, in1],
            out_names,
            out_values: [out0, out1],
            features,
            force,
            state,
            phase: 0,
            last_error: ErrorText {
                buf: [0; 256],
                len: 0,
            },
            run_options: run_options.ptr().cast_mut(),
            _run_options_owner: run_options,
            binding: [None, None],
        };
        if cfg.io_binding {
            let phases = if engine.state.is_some() { 2 } else { 1 };
            for p in 0..phases {
                let ins = engine.in_names.iter().copied();
                let outs = engine.out_names.iter().copied();
                // SAFETY: the session, the names and every value bound are owned by `engine`
                // and outlive the binding (dropped first, in Drop).
                let b = unsafe {
                    Binding::new(
                        engine.session.ptr().cast_mut(),
                        ins.zip(engine.in_values[p].iter().copied()),
                        outs.zip(engine.out_values[p].iter().copied()),
                    )
                }
                .map_err(|reason| ModelError::Session { reason })?;
                engine.binding[p] = Some(b);
            }
        }
        let times = engine.warm_up(cfg.warmup_runs.max(1))?;
        engine.info.cost["warmup"] = warmup_cost(&times);
        if let Some(r) = &reference {
            engine.check_reference(r)?;
            engine.info.reference_steps = Some(r.force.len());
        }
        Ok(engine)
    }

    /// Steps the model's reference rows (`haptics.reference`) from the zero state, as the
    /// loop will start it, and refuses the model where a force is further than the reference's
    /// tolerance from what its export computed: this engine would serve another model than
    /// the one trained. Leaves the state reset. At load only, off the hot path.
    fn check_reference(&mut self, r: &model::Reference) -> Result<(), ModelError> {
        use haptics_ort_host::reference::{check, CheckError};
        self.reset();
        let n = self.input_map.len();
        let out = check(r, |row| {
            // SAFETY: `features` points at the feature tensor's `n` floats, and the
            // reference's rows were checked to have exactly that many values when parsed.
            unsafe { ptr::copy_nonoverlapping(row.as_ptr(), self.features, n) };
            self.run_step().map_err(|e| ModelError::RunFailed {
                reason: format!("{e}: {}", self.last_error_message()),
            })
        });
        self.reset();
        out.map_err(|e| match e {
            CheckError::Step(e) => e,
            CheckError::Mismatch(m) => ModelError::ReferenceMismatch {
                step: m.step,
                steps: m.steps,
                input: m.input,
                expected: m.expected,
                got: m.got,
                tolerance: m.tolerance,
            },
        })
    }

    /// Why this model may not answer within the loop's deadline on this machine, from its
    /// warm-up (and its export's measurement); `None` when nothing says so. Printed by the
    /// server when it loads the model.
    pub fn cost_warning(&self) -> Option<String> {
        let us = |v: &serde_json::Value, k: &str| v.get(k).and_then(|x| x.as_f64());
        let warm = us(&self.info.cost["warmup"], "p50_us");
        let export = us(&self.info.cost["export"], "p99_us");
        let deadline = model::LOOP_DEADLINE_US;
        match (warm, export) {
            (Some(p50), _) if p50 > deadline => Some(format!(
                "its warm-up steps took {p50:.1} us (median) on this machine, over the loop's \
                 {deadline:.0} us deadline: it cannot answer in time here (the loop renders \
                 its steps late or held)"
            )),
            (_, Some(p99)) if p99 > deadline => Some(format!(
                "its export measured {p99:.1} us per call at p99, over the loop's {deadline:.0} \
                 us deadline: some steps will be answered late"
            )),
            _ => None,
        }
    }

    pub fn info(&self) -> &ModelInfo {
        &self.info
    }

    pub fn kind(&self) -> ModelKind {
        self.info.kind
    }

    /// Runs one step on a schema-ordered feature vector and returns the model's force, as the
    /// model computed it (possibly NaN: the caller decides what to do with a non-finite value).
    ///
    /// Real-time path: no allocation, no lock, no I/O on the Rust side (see the module comment
    /// for what ONNX Runtime does inside `Run`).
    #[inline]
    pub fn step<T: FeatureValue>(&mut self, schema_values: &[T]) -> Result<f32, StepError> {
        if schema_values.len() < self.schema_len {
            return Err(StepError::SchemaLength {
                expected: self.schema_len,
                got: schema_values.len(),
            });
        }
        // SAFETY: `features` points at the feature tensor's `input_map.len()` floats; every index
        // in `input_map` is < schema_len <= schema_values.len() (checked above and at load).
        unsafe {
            for (i, &src) in self.input_map.iter().enumerate() {
                let v = schema_values.get_unchecked(src).to_f32();
                if !v.is_finite() {
                    return Err(StepError::NonFiniteFeature { schema_index: src });
                }
                *self.features.add(i) = v;
            }
        }
        self.run_step()
    }

    /// Runs one step on the features already in the input tensor, returns the force and makes
    /// the state just written the next step's input. Real-time path: no allocation, no copy.
    #[inline]
    fn run_step(&mut self) -> Result<f32, StepError> {
        self.run_raw()?;
        // SAFETY: `force` points at the one float of the preallocated force output.
        let force = unsafe { *self.force };
        if self.state.is_some() {
            // The state just written is the next step's input: swap roles, copy nothing.
            self.phase ^= 1;
        }
        Ok(force)
    }

    /// ONNX Runtime's message for the last failed step (empty if none failed).
    pub fn last_error_message(&self) -> &str {
        self.last_error.as_str()
    }

    /// Zeroes the recurrent state (a new run starts). No-op for stateless models.
    pub fn reset(&mut self) {
        if let Some(s) = &self.state {
            // SAFETY: each state buffer holds `len` floats owned by self.
            unsafe {
                ptr::write_bytes(s.h[self.phase], 0, s.len);
                ptr::write_bytes(s.c[self.phase], 0, s.len);
            }
        }
    }

    /// The current hidden state `h` (empty for stateless models). For tests and diagnostics.
    pub fn hidden_state(&self) -> &[f32] {
        match &self.state {
            // SAFETY: `h[phase]` holds `len` floats owned by self; the borrow ties them to &self.
            Some(s) => unsafe { std::slice::from_raw_parts(s.h[self.phase], s.len) },
            None => &[],
        }
    }

    #[inline]
    fn run_raw(&mut self) -> Result<(), StepError> {
        if let Some(binding) = self.binding[self.phase].as_mut() {
            // SAFETY: the binding was made for this session, which is alive as long as self;
            // it holds our input and output values, bound at load; `&mut self`: no other run.
            let status = unsafe { binding.run(self.session.ptr().cast_mut(), self.run_options) };
            return if status.0.is_null() {
                Ok(())
            } else {
                Err(self.last_error.take_status(status.0))
            };
        }
        // SAFETY: the session is alive for self's lifetime; the name and value arrays point at
        // C strings and OrtValues owned by self; `&mut self` guarantees no concurrent Run on
        // this session. Passing non-null outputs makes ONNX Runtime write into our buffers.
        let status = unsafe {
            (ort::api().Run)(
                self.session.ptr().cast_mut(),
                self.run_options,
                self.in_names.as_ptr(),
                self.in_values[self.phase].as_ptr(),
                self.in_values[self.phase].len(),
                self.out_names.as_ptr(),
                self.out_names.len(),
                self.out_values[self.phase].as_mut_ptr(),
            )
        };
        if status.0.is_null() {
            Ok(())
        } else {
            Err(self.last_error.take_status(status.0))
        }
    }

    /// Warm-up: primes ONNX Runtime's arena and memory plan and checks the outputs (force and
    /// state) stay finite for a few deterministic inputs. Leaves the state reset.
    /// Runs `runs` warm-up steps again (results ignored) and resets the state. Called on the
    /// control thread just before a swap, so the model's weights are in the shared cache when
    /// the inference thread runs its first step (measured: the first step after a swap took
    /// several times a normal step from cold memory; see benches/hot_swap.rs).
    pub fn rewarm(&mut self, runs: usize) {
        let _ = self.warm_up(runs);
        self.reset();
    }

    /// Returns each step's time (ns; off the hot path: it allocates).
    fn warm_up(&mut self, runs: usize) -> Result<Vec<u64>, ModelError> {
        let n = self.input_map.len();
        let mut input = vec![0f32; self.schema_len];
        let mut times = Vec::with_capacity(runs);
        for r in 0..runs {
            // zeros, ones, then a deterministic spread of small and unit-scale values.
            for (j, v) in input.iter_mut().enumerate() {
                *v = match r {
                    0 => 0.0,
                    1 => 1.0,
                    _ => (((r * 7 + j * 13) % 17) as f32 - 8.0) / 8.0,
                };
            }
            let t0 = std::time::Instant::now();
            let step = self.step(&input);
            times.push(t0.elapsed().as_nanos() as u64);
            let force = step.map_err(|e| ModelError::RunFailed {
                reason: format!("{e}: {}", self.last_error_message()),
            })?;
            let model_input: Vec<f32> = self.input_map.iter().map(|&i| input[i]).collect();
            if !force.is_finite() {
                return Err(ModelError::NonFinite {
                    output: OUTPUT_FORCE.to_string(),
                    value: force,
                    input: model_input,
                });
            }
            if let Some(s) = &self.state {
                // SAFETY: the current pair holds the state the step just wrote, `len` floats each.
                let (h, c) = unsafe {
                    (
                        std::slice::from_raw_parts(s.h[self.phase], s.len),
                        std::slice::from_raw_parts(s.c[self.phase], s.len),
                    )
                };
                for (name, buf) in [(OUTPUT_H, h), (OUTPUT_C, c)] {
                    if let Some(v) = buf.iter().find(|v| !v.is_finite()) {
                        return Err(ModelError::NonFinite {
                            output: name.to_string(),
                            value: *v,
                            input: model_input,
                        });
                    }
                }
            }
            debug_assert_eq!(model_input.len(), n);
        }
        self.reset();
        Ok(times)
    }
}

/// The warm-up's cost, leaving out its first steps (ONNX Runtime's first runs plan memory and
/// fault pages in: not what a served step costs).
fn warmup_cost(times_ns: &[u64]) -> serde_json::Value {
    let skip = (times_ns.len() / 4).min(8);
    let mut t: Vec<u64> = times_ns[skip..].to_vec();
    if t.is_empty() {
        return serde_json::Value::Null;
    }
    t.sort_unstable();
    let us = |ns: u64| (ns as f64 / 10.0).round() / 100.0;
    serde_json::json!({
        "p50_us": us(t[(t.len() - 1) / 2]),
        "max_us": us(*t.last().unwrap_or(&0)),
        "steps": t.len(),
        "deadline_us": model::LOOP_DEADLINE_US,
    })
}

/// An output's shape and values.
type ProbedOutput = (Vec<i64>, Vec<f32>);

/// Runs the model once through `ort`'s safe API (letting ONNX Runtime allocate the outputs) and
/// returns each output's shape and data, in the order of `out_names`.
fn probe_outputs(
    session: &mut Session,
    in_names: &[&str],
    inputs: &[Tensor<f32>],
    out_names: &[&str],
    run_options: &RunOptions,
) -> Result<Vec<ProbedOutput>, ModelError> {
    let feed: Vec<(&str, &Tensor<f32>)> = in_names.iter().copied().zip(inputs.iter()).collect();
    let outputs =
        session
            .run_with_options(feed, run_options)
            .map_err(|e| ModelError::RunFailed {
                reason: e.to_string(),
            })?;
    out_names
        .iter()
        .map(|name| {
            let value = outputs.get(name).ok_or_else(|| ModelError::RunFailed {
                reason: format!("the run returned no `{name}` output"),
            })?;
            let (shape, data) =
                value
                    .try_extract_tensor::<f32>()
                    .map_err(|e| ModelError::BadShape {
                        name: name.to_string(),
                        detail: format!("cannot be read as a float32 tensor: {e}"),
                    })?;
            Ok((shape.to_vec(), data.to_vec()))
        })
        .collect()
}

fn check_finite(outputs: &[ProbedOutput], names: &[&str], input: &[f32]) -> Result<(), ModelError> {
    for ((_, data), name) in outputs.iter().zip(names) {
        if let Some(v) = data.iter().find(|v| !v.is_finite()) {
            return Err(ModelError::NonFinite {
                output: name.to_string(),
                value: *v,
                input: input.to_vec(),
            });
        }
    }
    Ok(())
}

fn new_run_options() -> Result<Arc<RunOptions>, ModelError> {
    RunOptions::new()
        .map(Arc::new)
        .map_err(|e| ModelError::Session {
            reason: format!("CreateRunOptions: {e}"),
        })
}

/// Most loads that ran out of time and whose threads still run (finishing the run in progress,
/// or stuck in session creation, which cannot be interrupted). Beyond it new loads are refused
/// with [`ModelError::Busy`] until one ends, so crafted models cannot pile up threads.
pub const MAX_ABANDONED_LOADS: usize = 2;
static ABANDONED: AtomicUsize = AtomicUsize::new(0);

const RUNNING: u8 = 0;
const DONE: u8 = 1;
const GAVE_UP: u8 = 2;

/// [`StepEngine::load_from_bytes`] with a time limit (`cfg.load_timeout`): the load runs on a
/// thread of its own; when the limit passes first, its run options' terminate flag stops the
/// run in progress (ONNX Runtime checks it between nodes), the caller gets
/// [`ModelError::TimedOut`] at once, and the thread drops what it built when it ends. Session
/// creation (graph optimisation) cannot be interrupted: a load stuck there keeps its thread,
/// and [`MAX_ABANDONED_LOADS`] bounds how many such threads exist ([`ModelError::Busy`] beyond).
pub fn load_bounded(
    rt: &'static Runtime,
    bytes: Arc<[u8]>,
    label: &Path,
    schema: &FeatureSchema,
    cfg: &SessionConfig,
) -> Result<StepEngine, ModelError> {
    let abandoned = ABANDONED.load(Ordering::Acquire);
    if abandoned >= MAX_ABANDONED_LOADS {
        return Err(ModelError::Busy { running: abandoned });
    }
    // RUNNING until the thread ends (DONE) or the caller stops waiting (GAVE_UP); whichever
    // comes second sees the other's mark, so ABANDONED counts exactly the threads given up on
    // and still running.
    let state = Arc::new(AtomicU8::new(RUNNING));
    let run_options = new_run_options()?;
    let (tx, rx) = mpsc::sync_channel(1);
    let (label_owned, schema_owned, cfg_owned): (PathBuf, FeatureSchema, SessionConfig) =
        (label.to_path_buf(), schema.clone(), cfg.clone());
    let options = Arc::clone(&run_options);
    std::thread::Builder::new()
        .name("model-load".into())
        .spawn({
            let state = Arc::clone(&state);
            move || {
                let result = model::open_session_from_bytes(rt, &bytes, &label_owned, &cfg_owned)
                    .and_then(|session| {
                        StepEngine::from_session(
                            session,
                            &label_owned,
                            &schema_owned,
                            &cfg_owned,
                            options,
                        )
                    });
                // The receiver is gone when the load ran out of time: the engine is dropped here.
                let _ = tx.send(result);
                if state.swap(DONE, Ordering::AcqRel) == GAVE_UP {
                    ABANDONED.fetch_sub(1, Ordering::AcqRel);
                }
            }
        })
        .map_err(|e| ModelError::Session {
            reason: format!("cannot start a load thread: {e}"),
        })?;
    match rx.recv_timeout(cfg.load_timeout) {
        Ok(result) => result,
        Err(_) => {
            let _ = run_options.terminate();
            ABANDONED.fetch_add(1, Ordering::AcqRel);
            if state
                .compare_exchange(RUNNING, GAVE_UP, Ordering::AcqRel, Ordering::Acquire)
                .is_err()
            {
                // The thread ended in the meantime: nothing left running.
                ABANDONED.fetch_sub(1, Ordering::AcqRel);
            }
            Err(ModelError::TimedOut {
                limit_s: cfg.load_timeout.as_secs_f64(),
            })
        }
    }
}
