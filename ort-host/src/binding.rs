//! Inputs and outputs bound once, and ONNX Runtime's statuses.
//!
//! A [`Binding`] ties a session's input and output names to values the caller owns and
//! preallocated; each step is then `RunWithBinding`, which reads the inputs in place and writes
//! the outputs into the caller's buffers (no output allocated per call, no name looked up).
//! REAL-TIME PATH: [`Binding::run`] and [`release`] allocate nothing, lock nothing and format
//! nothing; a failed run hands its status back for the caller to read off that path
//! ([`message`]) or release on it.

use std::ffi::{c_char, CStr};
use std::ptr;

use ort::sys::{OrtIoBinding, OrtRunOptions, OrtSession, OrtStatusPtr, OrtValue};

use crate::runtime::one_line;

/// One I/O binding of a session, released when dropped (drop it before the session and the
/// values it binds).
pub struct Binding {
    ptr: *mut OrtIoBinding,
}

// SAFETY: an OrtIoBinding is a plain ONNX Runtime object with no thread affinity; `run` takes
// `&mut self`, so one thread at a time uses it.
unsafe impl Send for Binding {}

impl std::fmt::Debug for Binding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Binding").finish_non_exhaustive()
    }
}

impl Binding {
    /// Binds `inputs` and `outputs` (name, value) to `session`. Off the real-time path.
    ///
    /// # Safety
    /// `session` and every value must stay alive, unmoved in ONNX Runtime's sense (the
    /// `OrtValue`s themselves), for as long as this binding; the names are NUL-terminated and
    /// only read during this call.
    pub unsafe fn new(
        session: *mut OrtSession,
        inputs: impl IntoIterator<Item = (*const c_char, *const OrtValue)>,
        outputs: impl IntoIterator<Item = (*const c_char, *mut OrtValue)>,
    ) -> Result<Binding, String> {
        let api = ort::api();
        let mut b = Binding {
            ptr: ptr::null_mut(),
        };
        // SAFETY: as the caller promises; `b` releases what was created if a bind fails.
        unsafe {
            message((api.CreateIoBinding)(session, &mut b.ptr))
                .map_err(|e| format!("CreateIoBinding: {e}"))?;
            for (name, value) in inputs {
                message((api.BindInput)(b.ptr, name, value))
                    .map_err(|e| format!("BindInput {}: {e}", name_of(name)))?;
            }
            for (name, value) in outputs {
                message((api.BindOutput)(b.ptr, name, value))
                    .map_err(|e| format!("BindOutput {}: {e}", name_of(name)))?;
            }
        }
        Ok(b)
    }

    /// One run of `session` with the bound values: null status on success, else ONNX Runtime's
    /// status (read it with [`message`] or drop it with [`release`]). REAL-TIME PATH.
    ///
    /// # Safety
    /// `session` is the one this binding was made for, alive; `run_options` is null or alive;
    /// no other run uses the bound values meanwhile.
    #[inline]
    pub unsafe fn run(
        &mut self,
        session: *mut OrtSession,
        run_options: *const OrtRunOptions,
    ) -> OrtStatusPtr {
        // SAFETY: as the caller promises.
        unsafe { (ort::api().RunWithBinding)(session, run_options, self.ptr) }
    }
}

impl Drop for Binding {
    fn drop(&mut self) {
        if !self.ptr.is_null() {
            // SAFETY: created by CreateIoBinding in `new`, released exactly once.
            unsafe { (ort::api().ReleaseIoBinding)(self.ptr) };
        }
    }
}

unsafe fn name_of(name: *const c_char) -> String {
    // SAFETY: a NUL-terminated name, as `Binding::new`'s caller promises.
    unsafe { CStr::from_ptr(name) }
        .to_string_lossy()
        .into_owned()
}

/// Releases a status without reading it. REAL-TIME PATH (no formatting, no allocation).
pub fn release(s: OrtStatusPtr) {
    if !s.0.is_null() {
        // SAFETY: a non-null status from ONNX Runtime, released exactly once.
        unsafe { (ort::api().ReleaseStatus)(s.0) };
    }
}

/// Takes a status: `Ok` when null, else its message on one line (the status released).
/// Allocates: off the real-time path.
pub fn message(s: OrtStatusPtr) -> Result<(), String> {
    if s.0.is_null() {
        return Ok(());
    }
    let api = ort::api();
    // SAFETY: a non-null status just returned by ONNX Runtime; its message is copied out before
    // the status is released, exactly once.
    unsafe {
        let msg = CStr::from_ptr((api.GetErrorMessage)(s.0))
            .to_string_lossy()
            .into_owned();
        (api.ReleaseStatus)(s.0);
        Err(one_line(&msg))
    }
}
