//! A kernel's inputs and outputs as plain `f32` slices, through ONNX Runtime's C API directly.
//!
//! Why not ort's `ComputeContext::input`/`output`: they read each tensor's type and shape into
//! new vectors on every call, and the kernels' `compute` must allocate nothing (it runs on
//! infer-server's inference thread). The shapes are checked once instead, when the kernel is
//! created (`check_shape`): ONNX Runtime refuses any input whose shape differs from the graph's
//! fixed one before a kernel runs.

use core::ffi::{c_void, CStr};
use core::ptr;

use ort::operator::{ComputeContext, KernelContext};
use ort::value::ValueType;
use ort::{api, sys, AsPointer};

use crate::attrs::AttrError;

/// An ONNX Runtime status as a Result (the status released).
fn check(status: sys::OrtStatusPtr) -> ort::Result<()> {
    if status.0.is_null() {
        return Ok(());
    }
    // SAFETY: a non-null status from ONNX Runtime, read then released once.
    let message = unsafe {
        let text = CStr::from_ptr((api().GetErrorMessage)(status.0))
            .to_string_lossy()
            .into_owned();
        (api().ReleaseStatus)(status.0);
        text
    };
    Err(ort::Error::new(message))
}

/// Input `idx` as `len` floats. The caller checked at kernel creation that the input has
/// exactly `len` elements.
pub(crate) fn input(ctx: &ComputeContext, idx: usize, len: usize) -> ort::Result<&[f32]> {
    let mut value: *const sys::OrtValue = ptr::null();
    // SAFETY: ctx is the live kernel context of this compute call.
    check(unsafe { (api().KernelContext_GetInput)(ctx.ptr(), idx, &mut value) })?;
    if value.is_null() {
        return Err(ort::Error::new(format!("input {idx} is missing")));
    }
    let mut data: *mut c_void = ptr::null_mut();
    // SAFETY: a float tensor input (the operator declares every input float32); ONNX Runtime
    // has no const getter in the API version used, the data is only read.
    check(unsafe { (api().GetTensorMutableData)(value.cast_mut(), &mut data) })?;
    // SAFETY: `len` elements, checked against the fixed shape at kernel creation; the tensor
    // lives for the compute call, which `ctx`'s borrow bounds.
    Ok(unsafe { core::slice::from_raw_parts(data.cast::<f32>(), len) })
}

/// Input `idx` of rows `width` floats wide (a free first dimension): its row count and its
/// floats. The element count comes from ONNX Runtime's shape info (created and released in its
/// own allocator: nothing Rust allocates).
pub(crate) fn input_rows(
    ctx: &ComputeContext,
    idx: usize,
    width: usize,
) -> ort::Result<(usize, &[f32])> {
    let mut value: *const sys::OrtValue = ptr::null();
    // SAFETY: ctx is the live kernel context of this compute call.
    check(unsafe { (api().KernelContext_GetInput)(ctx.ptr(), idx, &mut value) })?;
    if value.is_null() {
        return Err(ort::Error::new(format!("input {idx} is missing")));
    }
    let mut info: *mut sys::OrtTensorTypeAndShapeInfo = ptr::null_mut();
    // SAFETY: a live tensor value; the info is released below on every path.
    check(unsafe { (api().GetTensorTypeAndShape)(value, &mut info) })?;
    let mut count = 0usize;
    // SAFETY: info was just created.
    let counted = check(unsafe { (api().GetTensorShapeElementCount)(info, &mut count) });
    // SAFETY: created above, released once.
    unsafe { (api().ReleaseTensorTypeAndShapeInfo)(info) };
    counted?;
    let mut data: *mut c_void = ptr::null_mut();
    // SAFETY: a float tensor input (declared float32), only read.
    check(unsafe { (api().GetTensorMutableData)(value.cast_mut(), &mut data) })?;
    if count == 0 {
        return Ok((0, &[]));
    }
    // SAFETY: `count` elements, as ONNX Runtime reports; alive for the compute call.
    let all = unsafe { core::slice::from_raw_parts(data.cast::<f32>(), count) };
    Ok((count / width, all))
}

/// Output `idx`, created with the shape `dims`, as its `len` (= product of `dims`) floats.
#[allow(clippy::mut_from_ref)] // each output is a distinct tensor ONNX Runtime owns
pub(crate) fn output<'a>(
    ctx: &'a ComputeContext,
    idx: usize,
    dims: &[i64],
    len: usize,
) -> ort::Result<&'a mut [f32]> {
    let mut value: *mut sys::OrtValue = ptr::null_mut();
    // SAFETY: ctx is the live kernel context; dims outlives the call.
    check(unsafe {
        (api().KernelContext_GetOutput)(
            ctx.ptr().cast_mut(),
            idx,
            dims.as_ptr(),
            dims.len(),
            &mut value,
        )
    })?;
    if value.is_null() {
        return Err(ort::Error::new(format!(
            "output {idx} could not be created"
        )));
    }
    let mut data: *mut c_void = ptr::null_mut();
    // SAFETY: a float output tensor just created with `len` elements.
    check(unsafe { (api().GetTensorMutableData)(value, &mut data) })?;
    if len == 0 {
        return Ok(&mut []); // an empty batch: its data pointer may be null
    }
    // SAFETY: as above; each output index is a distinct tensor.
    Ok(unsafe { core::slice::from_raw_parts_mut(data.cast::<f32>(), len) })
}

/// Input `idx`'s declared shape (-1 for a dimension the graph leaves free), at kernel creation.
fn declared_shape(info: &KernelContext<'_>, idx: usize) -> Option<Vec<i64>> {
    info.inputs()
        .ok()
        .and_then(|ins| ins.into_iter().nth(idx))
        .and_then(|outlet| match outlet.dtype() {
            ValueType::Tensor { shape, .. } => Some(shape.to_vec()),
            _ => None,
        })
}

fn shape_error(
    op: &'static str,
    name: &'static str,
    expected: String,
    got: Option<Vec<i64>>,
) -> AttrError {
    AttrError::Shape {
        op,
        name,
        expected,
        got: got.map_or_else(|| "no tensor".to_string(), |d| format!("{d:?}")),
    }
}

/// Checks, at kernel creation, that input `idx` (contract name `name`) is declared with exactly
/// the fixed shape `expected`.
pub(crate) fn check_shape(
    op: &'static str,
    info: &KernelContext<'_>,
    idx: usize,
    name: &'static str,
    expected: &[i64],
) -> Result<(), AttrError> {
    match declared_shape(info, idx) {
        Some(dims) if dims == expected => Ok(()),
        other => Err(shape_error(op, name, format!("{expected:?}"), other)),
    }
}

/// Checks, at kernel creation, that input `idx` is declared as rows of exactly `width` values
/// ([N, width], N free or fixed).
pub(crate) fn check_rows(
    op: &'static str,
    info: &KernelContext<'_>,
    idx: usize,
    name: &'static str,
    width: usize,
) -> Result<(), AttrError> {
    match declared_shape(info, idx) {
        Some(dims) if dims.len() == 2 && dims[1] == width as i64 => Ok(()),
        other => Err(shape_error(op, name, format!("[N, {width}]"), other)),
    }
}

/// The width n of input `idx`, declared as the fixed shape [1, n] with n >= `min`.
pub(crate) fn row_width(
    op: &'static str,
    info: &KernelContext<'_>,
    idx: usize,
    name: &'static str,
    min: usize,
) -> Result<usize, AttrError> {
    match declared_shape(info, idx) {
        Some(dims) if dims.len() == 2 && dims[0] == 1 && dims[1] >= min as i64 => {
            Ok(dims[1] as usize)
        }
        other => Err(shape_error(op, name, format!("[1, n], n >= {min}"), other)),
    }
}
