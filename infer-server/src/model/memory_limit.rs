//! The memory a model may take while it runs: a CPU arena with a hard limit (ONNX Runtime's
//! `max_mem`), registered once on the process's environment and used by every session the
//! server opens (`session.use_env_allocators`). A model's file says nothing of what it will
//! allocate: a 400-byte model can expand a tensor to a gibibyte at run time. With the limit, the
//! allocation that would pass it fails inside ONNX Runtime (its arena refuses to grow; nothing
//! is allocated), the warm-up run reports the error and the load is refused at once: the active
//! model, which already holds its (small) share of the arena, never notices.
//!
//! The arena is shared: the limit bounds what all models hold at once (the active one's
//! working memory, a candidate's warm-up). Haptics models need kilobytes to a few MiB, so the
//! default (256 MiB, `infer-server serve --model-memory-mib`) leaves room for many while one
//! gibibyte-sized run is refused (docs/model-contract.md, "Loader limits").
use std::ffi::{c_char, CStr, CString};
use std::sync::OnceLock;

use ort::sys::{OrtAllocatorType, OrtArenaCfg, OrtMemType, OrtMemoryInfo, OrtStatusPtr};
use ort::AsPointer;

use crate::model::runtime::Runtime;

/// The limit registered for this process (bytes), once.
static REGISTERED: OnceLock<Result<usize, String>> = OnceLock::new();

/// The default limit of the shared arena, in MiB.
pub const DEFAULT_MODEL_MEMORY_MIB: usize = 256;

/// A status into its message (and the status released); `None` for success.
fn status_message(status: OrtStatusPtr) -> Option<String> {
    if status.0.is_null() {
        return None;
    }
    let api = ort::api();
    // SAFETY: a non-null status from ONNX Runtime; its message is a NUL-terminated string that
    // lives until the status is released, which happens after it is copied.
    unsafe {
        let message = CStr::from_ptr((api.GetErrorMessage)(status.0))
            .to_string_lossy()
            .into_owned();
        (api.ReleaseStatus)(status.0);
        Some(message)
    }
}

/// Registers the bounded arena on `rt`'s environment (once per process; a second call with
/// another limit is refused, the same limit is fine). Sessions use it when opened with
/// `with_env_allocators` (`crate::model::open_session_from_bytes`).
pub fn register(rt: &Runtime, max_bytes: usize) -> Result<(), String> {
    let registered = REGISTERED.get_or_init(|| register_now(rt, max_bytes).map(|()| max_bytes));
    match registered {
        Ok(limit) if *limit == max_bytes => Ok(()),
        Ok(limit) => Err(format!(
            "the model memory limit is {limit} bytes for this process; it cannot change to \
             {max_bytes}"
        )),
        Err(e) => Err(e.clone()),
    }
}

fn register_now(rt: &Runtime, max_bytes: usize) -> Result<(), String> {
    let api = ort::api();
    // kSameAsRequested (1): the arena grows by what is asked, never doubling past the limit.
    let keys: Vec<CString> = ["max_mem", "arena_extend_strategy"]
        .iter()
        .map(|k| CString::new(*k).expect("no NUL"))
        .collect();
    let key_ptrs: Vec<*const c_char> = keys.iter().map(|k| k.as_ptr()).collect();
    let values: [usize; 2] = [max_bytes, 1];
    let mut cfg: *mut OrtArenaCfg = std::ptr::null_mut();
    let mut info: *mut OrtMemoryInfo = std::ptr::null_mut();
    // SAFETY: the key and value arrays have `keys.len()` entries and outlive the call; `cfg`
    // and `info` are out-pointers released below; the environment lives for the process.
    unsafe {
        if let Some(e) = status_message((api.CreateArenaCfgV2)(
            key_ptrs.as_ptr(),
            values.as_ptr(),
            keys.len(),
            &mut cfg,
        )) {
            return Err(format!("CreateArenaCfgV2: {e}"));
        }
        let result = match status_message((api.CreateCpuMemoryInfo)(
            OrtAllocatorType::OrtArenaAllocator,
            OrtMemType::OrtMemTypeDefault,
            &mut info,
        )) {
            Some(e) => Err(format!("CreateCpuMemoryInfo: {e}")),
            None => {
                let env = rt.environment().ptr().cast_mut();
                let r = status_message((api.CreateAndRegisterAllocator)(env, info, cfg))
                    .map_or(Ok(()), |e| Err(format!("CreateAndRegisterAllocator: {e}")));
                (api.ReleaseMemoryInfo)(info);
                r
            }
        };
        (api.ReleaseArenaCfg)(cfg);
        result
    }
}
