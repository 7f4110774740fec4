//! An object whose law is a stateful ONNX graph (`law = "onnx"`, docs/laws/onnx.md): any law
//! someone can export (a model learned on another rig, a law written in PyTorch or with the
//! ONNX helpers) becomes a bench object, stepped through ONNX Runtime.
//!
//! The bench sub-steps its object tens of times per control period for the stiff contact; one
//! ONNX Runtime call costs a few microseconds, so the graph is stepped at the rate the
//! material file declares (`rate_hz`, on the object's own clock: the sub-steps' time adds up
//! and the graph steps at the first sub-step that completes a period), and the sub-steps in
//! between see its force HELD (zero-order hold). Two rules keep the hold honest: the force is
//! 0 while the probe is out of contact (x <= 0: an object cannot push a probe it does not
//! touch, whatever its last answer), and a negative answer is 0 (objects push, never pull).
//! The graph is fed the position x at its step and the velocity (x - x at its last step) /
//! (time since), so the bench and the oracle (which sees only positions) feed it alike.
//!
//! REAL-TIME PATH ([`OnnxObject::substep`]): writes the kinematics into tensors allocated
//! when the object was made, runs the graph with inputs and outputs bound once
//! (`RunWithBinding`, as infer-server's engine does), copies each state output into its
//! input. Nothing on the Rust side allocates, locks or does I/O (tests/onnx_object.rs counts
//! the Rust allocations of 10,000 sub-steps: 0). ONNX Runtime's `Run` itself allocates
//! internally with its own `malloc` (about 15 per call plus about 3 per node, measured by
//! infer-server's benchmarks, docs/infer-server.md: some 90 for the example's 28 nodes): that is
//! ONNX Runtime's own, not removable from here. A failed run or a non-finite force is latched as a fault ([`OnnxObject::fault`]):
//! the object pushes 0 from then on and the simulated board stops the run with the reason.

use std::ptr;
use std::sync::Arc;

use haptics_ort_host::reference::{check, CheckError};
use haptics_ort_host::Binding;
use ort::session::RunOptions;
use ort::value::Tensor;
use ort::AsPointer;
use serde::{Deserialize, Serialize};

use super::onnx_graph::{Feature, OnnxGraph, OnnxObjectError};
use super::Law;
use crate::invalid::InvalidSetting;

/// The `onnx` law's table as the file writes it (`[onnx]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OnnxFile {
    pub onnx: OnnxTable,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OnnxTable {
    /// The graph, relative to the material file.
    pub model: String,
    /// How often the bench steps the graph, Hz (the rate its law was written or learned at).
    pub rate_hz: f64,
}

/// The `onnx` law's parameters: the file's table and the graph it names, opened and checked.
#[derive(Clone, Debug, Serialize)]
pub struct OnnxParams {
    #[serde(flatten)]
    pub file: OnnxFile,
    #[serde(skip)]
    pub graph: Arc<OnnxGraph>,
}

impl PartialEq for OnnxParams {
    fn eq(&self, other: &Self) -> bool {
        self.file == other.file && self.graph.path == other.graph.path
    }
}

/// The highest `rate_hz` accepted: the bench's sub-step is 10 us, and the graph steps at most
/// once per sub-step.
pub const MAX_RATE_HZ: f64 = 100_000.0;

impl OnnxFile {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let r = self.onnx.rate_hz;
        if !(r.is_finite() && r > 0.0 && r <= MAX_RATE_HZ) {
            return Err(format!("onnx.rate_hz must be in (0, {MAX_RATE_HZ}] (got {r})").into());
        }
        if self.onnx.model.trim().is_empty() {
            return Err("onnx.model must name the graph file".into());
        }
        Ok(())
    }

    /// Opens the graph (relative paths from `base`, the material file's folder) and checks it,
    /// including a few steps at rest and pressed that must give a finite force.
    pub fn open(self, base: &std::path::Path) -> Result<OnnxParams, OnnxObjectError> {
        let path = base.join(&self.onnx.model);
        let graph = Arc::new(OnnxGraph::open(&path)?);
        let mut probe = OnnxObject::with_rate(graph.clone(), self.onnx.rate_hz)?;
        for (x, v) in [(0.0, 0.0), (0.005, 0.05), (0.01, 0.0), (0.002, -0.05)] {
            match probe.io.run(&graph, x, v) {
                Ok(f) if f.is_finite() => {}
                Ok(f) => {
                    return Err(OnnxObjectError::Warmup {
                        path,
                        detail: format!("its force is {f} at x = {x} m, v = {v} m/s (not finite)"),
                    })
                }
                Err(s) => {
                    let msg = status(s).err().unwrap_or_default();
                    return Err(OnnxObjectError::Warmup {
                        path,
                        detail: format!("a step at x = {x} m, v = {v} m/s failed: {msg}"),
                    });
                }
            }
        }
        if let Some(r) = &graph.reference {
            // a fresh copy: the reference is stepped from the zero state, as it was exported
            let mut copy = OnnxObject::with_rate(graph.clone(), self.onnx.rate_hz)?;
            let out = check(r, |row| {
                copy.io
                    .run_row(&graph, row)
                    .map_err(|s| status(s).err().unwrap_or_default())
            });
            if let Err(e) = out {
                let detail = match e {
                    CheckError::Mismatch(m) => m.to_string(),
                    CheckError::Step(msg) => format!("a reference step failed: {msg}"),
                };
                return Err(OnnxObjectError::Reference { path, detail });
            }
        }
        Ok(OnnxParams { file: self, graph })
    }
}

/// One copy's tensors: the graph's inputs and outputs, allocated once and bound once.
struct Io {
    /// First: fields drop in declaration order, and the binding refers to the tensors below.
    binding: Binding,
    // The tensors own the memory the raw pointers below point into (their data lives on the
    // heap: moving the object moves nothing the pointers see); never replaced after `new`.
    _inputs: Vec<Tensor<f32>>,
    _outputs: Vec<Tensor<f32>>,
    features: *mut f32,
    force: *const f32,
    /// Per state pair: (input data, output data, elements).
    state: Box<[(*mut f32, *const f32, usize)]>,
    run_options: RunOptions,
}

fn zeros(shape: &[i64], len: usize) -> Result<Tensor<f32>, String> {
    Tensor::from_array((shape.to_vec(), vec![0f32; len].into_boxed_slice()))
        .map_err(|e| format!("cannot allocate a tensor of shape {shape:?}: {e}"))
}

pub(super) use haptics_ort_host::binding::{message as status, release};

impl Io {
    /// Allocates and binds one copy's tensors (off the real-time path).
    fn new(g: &OnnxGraph) -> Result<Io, String> {
        let mut inputs = vec![zeros(&g.features_shape, g.features.len())?];
        let mut outputs = vec![zeros(&g.force_shape, 1)?];
        for p in g.state.iter() {
            inputs.push(zeros(&p.shape, p.len)?);
            outputs.push(zeros(&p.shape, p.len)?);
        }
        let data = |t: &mut Tensor<f32>| t.data_ptr_mut().cast::<f32>();
        let features = data(&mut inputs[0]);
        let force = data(&mut outputs[0]).cast_const();
        let state = g
            .state
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let input = data(&mut inputs[i + 1]);
                (input, data(&mut outputs[i + 1]).cast_const(), p.len)
            })
            .collect();
        let run_options = RunOptions::new().map_err(|e| e.to_string())?;
        let ins: Vec<_> = inputs.iter().map(|t| t.ptr()).collect();
        let outs: Vec<_> = outputs.iter_mut().map(|t| t.ptr_mut()).collect();
        // SAFETY: the session outlives the binding (the object drops its `Io` before its
        // `Arc<OnnxGraph>`), and the values bound are owned by the `Io` built below, which
        // releases the binding before they go.
        let binding = unsafe {
            Binding::new(
                g.session.ptr().cast_mut(),
                g.in_name_ptrs().zip(ins),
                g.out_name_ptrs().zip(outs),
            )
        }?;
        let io = Io {
            binding,
            _inputs: inputs,
            _outputs: outputs,
            features,
            force,
            state,
            run_options,
        };
        Ok(io)
    }

    /// One step of the graph at (x, v): the force as the graph computed it (maybe NaN: the
    /// caller decides), the state outputs copied into the inputs. A failed run returns ONNX
    /// Runtime's status, for the caller to read ([`status`], off the real-time path) or
    /// release ([`release`], on it). REAL-TIME PATH: nothing on this side allocates (ONNX
    /// Runtime's `Run` does, internally).
    #[inline]
    fn run(&mut self, g: &OnnxGraph, x: f64, v: f64) -> Result<f32, ort::sys::OrtStatusPtr> {
        // SAFETY: `features` points at the `features` tensor's `g.features.len()` floats.
        unsafe {
            for (i, f) in g.features.iter().enumerate() {
                *self.features.add(i) = match f {
                    Feature::PositionX => x,
                    Feature::Velocity => v,
                } as f32;
            }
        }
        self.run_bound(g)
    }

    /// One step on a whole `features` row as given (the reference steps' rows, in the graph's
    /// column order); as [`Io::run`] otherwise. Off the real-time path (at load).
    fn run_row(&mut self, g: &OnnxGraph, row: &[f32]) -> Result<f32, ort::sys::OrtStatusPtr> {
        // the reference parser checked every row's width against the graph's
        assert_eq!(
            row.len(),
            g.features.len(),
            "a features row of another width"
        );
        // SAFETY: `features` points at the `features` tensor's `g.features.len()` floats.
        unsafe { ptr::copy_nonoverlapping(row.as_ptr(), self.features, row.len()) };
        self.run_bound(g)
    }

    /// Runs the bound graph on the features already written. REAL-TIME PATH (via `run`).
    #[inline]
    fn run_bound(&mut self, g: &OnnxGraph) -> Result<f32, ort::sys::OrtStatusPtr> {
        // SAFETY: the session is alive (the object holds its Arc); the binding holds this
        // copy's input and output values; `&mut self` means no other Run uses this binding.
        let s = unsafe {
            self.binding
                .run(g.session.ptr().cast_mut(), self.run_options.ptr())
        };
        if !s.0.is_null() {
            return Err(s);
        }
        // SAFETY: `force` points at the force output's one float; each state pair's pointers
        // at two distinct tensors of `len` floats each.
        unsafe {
            for &(input, output, len) in self.state.iter() {
                ptr::copy_nonoverlapping(output, input, len);
            }
            Ok(*self.force)
        }
    }

    /// This copy's state inputs, copied from `other`'s (a clone carries the state).
    fn copy_state_from(&mut self, other: &Io) {
        for (&(to, _, len), &(from, _, _)) in self.state.iter().zip(other.state.iter()) {
            // SAFETY: both copies come from the same graph: the same pairs, the same lengths.
            unsafe { ptr::copy_nonoverlapping(from.cast_const(), to, len) };
        }
    }
}

/// The bench's object of an `onnx` material: the shared graph, this copy's tensors and the
/// hold between the graph's steps.
pub struct OnnxObject {
    // Declared before `graph`: the binding refers to the session, so it is released first.
    io: Io,
    graph: Arc<OnnxGraph>,
    /// The graph's step, s (1 / rate_hz).
    period: f64,
    /// The bench's sub-step, s.
    h: f64,
    /// Sub-step time since the graph's clock last ticked (carries the remainder).
    acc: f64,
    /// Time and position at the graph's last step (NaN before the first sub-step).
    since: f64,
    x_step: f64,
    /// The graph's last answer, clamped at 0: held over the sub-steps.
    held: f64,
    force: f64,
    fault: Option<&'static str>,
}

// SAFETY: the raw pointers point into tensors this object owns (or into the shared session,
// which ONNX Runtime lets any thread call); the object is stepped through `&mut self` by one
// thread at a time. `ort::Session` is Send + Sync.
unsafe impl Send for OnnxObject {}

impl std::fmt::Debug for OnnxObject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxObject")
            .field("graph", &self.graph.path)
            .field("period", &self.period)
            .field("force", &self.force)
            .field("fault", &self.fault)
            .finish_non_exhaustive()
    }
}

/// Why the bench stops when the graph misbehaves (static: the step formats nothing).
pub const FAULT_NON_FINITE: &str =
    "the ONNX object's graph answered a non-finite force (NaN or infinite): run stopped";
pub const FAULT_RUN: &str = "the ONNX object's graph failed to run in ONNX Runtime: run stopped";

impl OnnxObject {
    /// A fresh object (zero state) of the material's graph. Off the real-time path.
    pub fn new(p: &OnnxParams) -> Self {
        Self::with_rate(p.graph.clone(), p.file.onnx.rate_hz)
            // The same allocation succeeded when the material was loaded (its probe).
            .expect("ONNX Runtime could not allocate an ONNX object's tensors")
    }

    fn with_rate(graph: Arc<OnnxGraph>, rate_hz: f64) -> Result<Self, OnnxObjectError> {
        let io = Io::new(&graph).map_err(|detail| OnnxObjectError::Warmup {
            path: graph.path.clone(),
            detail,
        })?;
        Ok(OnnxObject {
            io,
            graph,
            period: 1.0 / rate_hz,
            h: 1e-5,
            acc: 0.0,
            since: 0.0,
            x_step: f64::NAN,
            held: 0.0,
            force: 0.0,
            fault: None,
        })
    }

    /// The graph it steps.
    pub fn graph(&self) -> &OnnxGraph {
        &self.graph
    }

    /// The values of state pair `pair` (its `NAME_in`; tests, diagnostics).
    pub fn state(&self, pair: usize) -> &[f32] {
        match self.io.state.get(pair) {
            // SAFETY: the input tensor of that pair holds `len` floats owned by self.
            Some(&(input, _, len)) => unsafe { std::slice::from_raw_parts(input, len) },
            None => &[],
        }
    }
}

impl Clone for OnnxObject {
    /// Off the real-time path (the oracle's fresh copy for every run): new tensors for the
    /// copy, the same session, the state copied.
    fn clone(&self) -> Self {
        let mut io =
            Io::new(&self.graph).expect("ONNX Runtime could not allocate an ONNX object's tensors");
        io.copy_state_from(&self.io);
        OnnxObject {
            io,
            graph: self.graph.clone(),
            period: self.period,
            h: self.h,
            acc: self.acc,
            since: self.since,
            x_step: self.x_step,
            held: self.held,
            force: self.force,
            fault: self.fault,
        }
    }
}

impl Law for OnnxObject {
    #[inline]
    fn prepare(&mut self, h: f64) {
        self.h = h;
    }

    #[inline]
    fn substep(&mut self, x: f64) -> f64 {
        if self.x_step.is_nan() {
            // the first sub-step: the object meets the probe at rest where it is
            self.x_step = x;
        }
        self.acc += self.h;
        self.since += self.h;
        // the graph steps at the sub-step closest to each tick of its own clock
        if self.acc >= self.period - 0.5 * self.h && self.fault.is_none() {
            let v = if self.since > 0.0 {
                (x - self.x_step) / self.since
            } else {
                0.0
            };
            match self.io.run(&self.graph, x, v) {
                Ok(f) if f.is_finite() => self.held = f64::from(f).max(0.0),
                Ok(_) => self.fault = Some(FAULT_NON_FINITE),
                Err(s) => {
                    release(s);
                    self.fault = Some(FAULT_RUN);
                }
            }
            if self.fault.is_some() {
                self.held = 0.0;
            }
            // at most one step per sub-step: a remainder above one period is not carried
            self.acc = (self.acc - self.period).clamp(0.0, self.period);
            self.since = 0.0;
            self.x_step = x;
        }
        self.force = if x > 0.0 { self.held } else { 0.0 };
        self.force
    }

    #[inline]
    fn force(&self) -> f64 {
        self.force
    }

    fn fault(&self) -> Option<&'static str> {
        self.fault
    }
}
