//! ONNX Runtime custom operators for the haptics models: one fused node per physics-shaped
//! model, in the custom-op domain [`DOMAIN`]: `StructuredStep` (train's `structured`),
//! `LawFreeStep` (`lawfree`), `BlendStep` (`blend`: two of those in one node), `DenseStep`
//! (`dnn`, `dnn_fb`),
//! `PronyStep` (`prony`), `LstmStep` (`lstm`, `lstm_fb`), `SlowLstmStep` (`lstm_slow`),
//! `SvrStep` (`svr`), `SpringDamperStep` (`sd_const`, `sd_poly1`, `sd_poly2`) and `ForestStep`
//! (`rf`).
//!
//! Why: ONNX Runtime 1.32 pays 0.2-0.5 us of dispatch per node whatever its size, and the
//! hand-built graph of `structured` has 50-56 nodes for a few hundred flops (docs/infer-server.md,
//! "Every model family"). One node computing the whole step costs one dispatch.
//!
//! Two consumers run the same kernels:
//! - infer-server links this crate and adds [`domain`] to every session it opens, so models with
//!   and without the operators load alike;
//! - Python onnxruntime (train's parity check and cost measurement) loads the cdylib,
//!   `libhaptics_fused_ops.so`, with `SessionOptions.register_custom_ops_library`, which calls
//!   [`RegisterCustomOps`].
//!
//! A stateful kernel may leave the part of its next step that reads only the state for after
//! the answer: a serving thread opts in ([`serve_ahead_on_this_thread`]) and runs it
//! ([`run_ahead`]) once the answer is out; elsewhere every step does all its work (ahead.rs).
//!
//! Every constant a model needs travels as node attributes, parsed and checked once when ONNX
//! Runtime creates the kernel (a bad attribute fails the session's creation with a one-line
//! error); the kernels' `compute` allocates nothing (tensors read and written through the raw C
//! API: the safe wrappers build shape vectors on every call).

mod ahead;
mod attrs;
mod blend;
mod dense;
mod forest;
mod huge;
mod lawfree;
mod lstm;
mod math;
mod prony;
mod register;
mod scaler;
mod slow_lstm;
mod spring_damper;
mod stateful;
mod stateless;
mod structured;
mod svr;
mod tensors;

pub use ahead::{run_ahead, serve_ahead_on_this_thread};
pub use attrs::{AttrError, Attrs};
pub use blend::{BlendParams, BlendStep};
pub use dense::{DenseParams, DenseStep};
pub use forest::{ForestParams, ForestStep};
pub use lawfree::{LawFreeParams, LawFreeStep};
pub use lstm::{LstmParams, LstmStep};
pub use math::{Fused, Madd, Split};
pub use prony::{PronyParams, PronyStep};
pub use slow_lstm::{SlowLstmParams, SlowLstmStep};
pub use spring_damper::{SpringDamperParams, SpringDamperStep};
pub use stateful::{StatefulStep, StepModel};
pub use stateless::{RowModel, StatelessStep};
pub use structured::{StructuredParams, StructuredStep};
pub use svr::{SvrParams, SvrStep};

use ort::operator::OperatorDomain;

/// The custom-op domain of every operator here (the node's `domain` in the ONNX file).
pub const DOMAIN: &str = "ai.haptics";

/// The domain with every operator, for `SessionBuilder::with_operators`.
pub fn domain() -> ort::Result<OperatorDomain> {
    OperatorDomain::new(DOMAIN)?
        .add(StructuredStep::default())?
        .add(LawFreeStep::default())?
        .add(BlendStep::default())?
        .add(DenseStep::default())?
        .add(PronyStep::default())?
        .add(LstmStep::default())?
        .add(SlowLstmStep::default())?
        .add(SvrStep::default())?
        .add(SpringDamperStep::default())?
        .add(ForestStep::default())
}
