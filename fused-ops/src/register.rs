//! The cdylib's entry point for Python onnxruntime (and any other host that loads custom-op
//! libraries): `SessionOptions.register_custom_ops_library(path)` dlopens
//! libhaptics_fused_ops.so and calls `RegisterCustomOps(options, api_base)`.

use std::sync::OnceLock;

use ort::operator::OperatorDomain;
use ort::{sys, AsPointer};

/// The domain, created once per loaded library and kept for its lifetime: ONNX Runtime holds
/// pointers into it for as long as any session made with these options lives.
struct Domain(OperatorDomain);
// SAFETY: the domain is immutable once built; ONNX Runtime only reads it (from any thread).
unsafe impl Send for Domain {}
// SAFETY: as above.
unsafe impl Sync for Domain {}

static DOMAIN: OnceLock<Result<Domain, String>> = OnceLock::new();

/// Called by the host's ONNX Runtime with its session options and API base: installs that
/// runtime's API table for ort (so this library never loads a second ONNX Runtime) and adds the
/// `ai.haptics` domain to the options.
///
/// # Safety
/// `options` and `api_base` must be the live pointers ONNX Runtime passes.
#[no_mangle]
pub unsafe extern "C" fn RegisterCustomOps(
    options: *mut sys::OrtSessionOptions,
    api_base: *const sys::OrtApiBase,
) -> sys::OrtStatusPtr {
    if options.is_null() || api_base.is_null() {
        return sys::OrtStatusPtr::default(); // nothing to register into, nothing to report with
    }
    // SAFETY: api_base is ONNX Runtime's own, valid for the process.
    let api = unsafe { ((*api_base).GetApi)(sys::ORT_API_VERSION) };
    if api.is_null() {
        eprintln!(
            "haptics_fused_ops: this ONNX Runtime does not offer API version {}",
            sys::ORT_API_VERSION
        );
        return sys::OrtStatusPtr::default();
    }
    // SAFETY: a valid API table (a struct of function pointers), copied bitwise; a second
    // registration keeps the first copy (the same runtime in one process).
    let _ = ort::set_api(unsafe { std::ptr::read(api) });
    let domain = DOMAIN.get_or_init(|| crate::domain().map(Domain).map_err(|e| e.to_string()));
    let result = match domain {
        Ok(Domain(d)) => {
            // SAFETY: both pointers live; the domain lives as long as this library is loaded.
            return unsafe { (ort::api().AddCustomOpDomain)(options, d.ptr().cast_mut()) };
        }
        Err(e) => e.clone(),
    };
    let message =
        std::ffi::CString::new(format!("haptics_fused_ops: {result}")).unwrap_or_default();
    // SAFETY: the API is set; CreateStatus copies the message.
    unsafe { (ort::api().CreateStatus)(sys::OrtErrorCode::ORT_FAIL, message.as_ptr()) }
}
