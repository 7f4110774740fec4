//! One ONNX Runtime operator per model, all with the stateful contract (docs/model-contract.md):
//! inputs `features` [1, n], `h_in`, `c_in` [1, 1, H]; outputs `force` [1, 1], `h_out`, `c_out`
//! [1, 1, H]. A model supplies only its parameters and its step ([`StepModel`]); the operator
//! checks the declared shapes once at kernel creation and runs the step without allocating.

use core::marker::PhantomData;

use ort::operator::{
    ComputeContext, Kernel, KernelContext, Operator, OperatorInput, OperatorOutput,
};
use ort::value::TensorElementType;

use crate::attrs::{AttrError, Attrs};
use crate::math::Madd;
use crate::tensors;

/// A model's parameters (parsed once from the node's attributes) and its one step.
pub trait StepModel: Sized + Send + 'static {
    /// The operator's name in the domain.
    const OP: &'static str;
    /// The fewest features the step reads (x first, then v).
    const MIN_FEATURES: usize;

    /// Reads and checks the attributes.
    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError>;

    /// H: the state's length.
    fn state_size(&self) -> usize;

    /// The exact number of features the parameters were fitted on, where they fix it (a
    /// network's input width); `None`: at least `MIN_FEATURES`, the rest unread.
    fn features(&self) -> Option<usize> {
        None
    }

    /// One step: writes `h_out` and `c_out` (each H long) and returns the force. Must not
    /// allocate (it runs on infer-server's inference thread); `&mut self` for scratch space
    /// the model allocated when it was created. Runs compiled for AVX2 where the CPU has it
    /// and FMA where the CPU has them (math.rs `fast!`, `M` its multiply-add): whatever it
    /// calls should be `#[inline]` to be compiled so.
    fn step<M: Madd>(
        &mut self,
        features: &[f32],
        h_in: &[f32],
        c_in: &[f32],
        h_out: &mut [f32],
        c_out: &mut [f32],
    ) -> f32;
}

/// The operator of model `M` (`ai.haptics:<M::OP>`).
pub struct StatefulStep<M>(PhantomData<fn() -> M>);

impl<M> Default for StatefulStep<M> {
    fn default() -> Self {
        Self(PhantomData)
    }
}

/// One node's kernel: its parameters and the tensors' sizes, fixed at creation.
pub struct StatefulKernel<M> {
    model: M,
    n_features: usize,
    state_dims: [i64; 3],
}

impl<M: StepModel> Operator for StatefulStep<M> {
    type Kernel<'attr> = StatefulKernel<M>;

    fn name(&self) -> &str {
        M::OP
    }

    fn inputs(&self) -> impl IntoIterator<Item = OperatorInput> {
        [0, 1, 2].map(|_| OperatorInput::required(TensorElementType::Float32))
    }

    fn outputs(&self) -> impl IntoIterator<Item = OperatorOutput> {
        [0, 1, 2].map(|_| OperatorOutput::required(TensorElementType::Float32))
    }

    fn create_kernel<'attr>(&self, info: &KernelContext<'attr>) -> ort::Result<StatefulKernel<M>> {
        let err = |e: AttrError| ort::Error::new(e.to_string());
        let model = M::from_attrs(info).map_err(err)?;
        let state_dims = [1, 1, model.state_size() as i64];
        let min = model.features().unwrap_or(M::MIN_FEATURES);
        let n_features = tensors::row_width(M::OP, info, 0, "features", min).map_err(err)?;
        if let Some(n) = model.features().filter(|&n| n != n_features) {
            return Err(err(AttrError::Shape {
                op: M::OP,
                name: "features",
                expected: format!("[1, {n}] (the features the weights take)"),
                got: format!("[1, {n_features}]"),
            }));
        }
        for (idx, name) in [(1, "h_in"), (2, "c_in")] {
            tensors::check_shape(M::OP, info, idx, name, &state_dims).map_err(err)?;
        }
        Ok(StatefulKernel {
            model,
            n_features,
            state_dims,
        })
    }
}

impl<M: StepModel> Kernel for StatefulKernel<M> {
    /// Runs on infer-server's inference thread: no allocation, no lock (only the error path,
    /// which fails the call, allocates its message).
    fn compute(&mut self, ctx: &ComputeContext) -> ort::Result<()> {
        let h = self.model.state_size();
        let features = tensors::input(ctx, 0, self.n_features)?;
        let h_in = tensors::input(ctx, 1, h)?;
        let c_in = tensors::input(ctx, 2, h)?;
        let force = tensors::output(ctx, 0, &[1, 1], 1)?;
        let h_out = tensors::output(ctx, 1, &self.state_dims, h)?;
        let c_out = tensors::output(ctx, 2, &self.state_dims, h)?;
        let model = &mut self.model;
        force[0] = crate::math::fast!(M => model.step::<M>(features, h_in, c_in, h_out, c_out));
        Ok(())
    }
}

/// `v` as float32 (hi) plus the float32 of what that leaves out (lo): hi + lo carries about
/// 48 bits of `v`. The states that integrate small steps over millions of steps keep their low
/// part in the contract's second state tensor `c` (structured.rs, lawfree.rs say which).
pub(crate) fn split(v: f64) -> (f32, f32) {
    let hi = v as f32;
    (hi, (v - f64::from(hi)) as f32)
}
