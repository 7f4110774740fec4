//! One ONNX Runtime operator per stateless model (docs/model-contract.md): input `features`
//! [N, n], output `force` [N, 1], any N (the export's parity check runs a whole recording in
//! one call, infer-server one row). A model supplies only its parameters and one row
//! ([`RowModel`]); the operator checks the declared width once at kernel creation and runs the
//! rows without allocating.

use core::marker::PhantomData;

use ort::operator::{
    ComputeContext, Kernel, KernelContext, Operator, OperatorInput, OperatorOutput,
};
use ort::value::TensorElementType;

use crate::attrs::{AttrError, Attrs};
use crate::math::{self, Madd};
use crate::tensors;

/// A stateless model's parameters (parsed once from the node's attributes) and one row.
pub trait RowModel: Sized + Send + 'static {
    /// The operator's name in the domain.
    const OP: &'static str;

    /// Reads and checks the attributes.
    fn from_attrs<A: Attrs + ?Sized>(attrs: &A) -> Result<Self, AttrError>;

    /// The features per row.
    fn inputs(&self) -> usize;

    /// The force of one row. Must not allocate (`&mut self`: scratch made at creation); runs
    /// compiled for AVX2 + FMA where the CPU has them (math.rs `fast!`).
    fn row<M: Madd>(&mut self, x: &[f32]) -> f32;
}

/// The operator of model `R` (`ai.haptics:<R::OP>`).
pub struct StatelessStep<R>(PhantomData<fn() -> R>);

impl<R> Default for StatelessStep<R> {
    fn default() -> Self {
        Self(PhantomData)
    }
}

/// One node's kernel: the model.
pub struct StatelessKernel<R> {
    model: R,
}

impl<R: RowModel> Operator for StatelessStep<R> {
    type Kernel<'attr> = StatelessKernel<R>;

    fn name(&self) -> &str {
        R::OP
    }

    fn inputs(&self) -> impl IntoIterator<Item = OperatorInput> {
        [OperatorInput::required(TensorElementType::Float32)]
    }

    fn outputs(&self) -> impl IntoIterator<Item = OperatorOutput> {
        [OperatorOutput::required(TensorElementType::Float32)]
    }

    fn create_kernel<'attr>(&self, info: &KernelContext<'attr>) -> ort::Result<StatelessKernel<R>> {
        let err = |e: AttrError| ort::Error::new(e.to_string());
        let model = R::from_attrs(info).map_err(err)?;
        tensors::check_rows(R::OP, info, 0, "features", model.inputs()).map_err(err)?;
        Ok(StatelessKernel { model })
    }
}

impl<R: RowModel> Kernel for StatelessKernel<R> {
    /// Runs on infer-server's inference thread: no allocation, no lock (only the error path,
    /// which fails the call, allocates its message).
    fn compute(&mut self, ctx: &ComputeContext) -> ort::Result<()> {
        let n = self.model.inputs();
        let (rows, x) = tensors::input_rows(ctx, 0, n)?;
        let force = tensors::output(ctx, 0, &[rows as i64, 1], rows)?;
        let model = &mut self.model;
        math::fast!(M => {
            for (f, row) in force.iter_mut().zip(x.chunks_exact(n)) {
                *f = model.row::<M>(row);
            }
        });
        Ok(())
    }
}
