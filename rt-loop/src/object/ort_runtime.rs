//! ONNX Runtime for the bench's ONNX objects ([`super::onnx`]): found and loaded once per
//! process, the way infer-server does it (`infer-server/src/runtime.rs`; rt-loop does not
//! depend on infer-server, so these few lines are its own). `ort` is built with
//! `load-dynamic`: nothing is linked at build time; the library is `ORT_DYLIB_PATH` (which
//! `scripts/env.sh` exports) or `.ort/libonnxruntime.so` above the executable, the working
//! directory or this crate (where `scripts/setup.sh` puts it).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ort::environment::Environment;

/// Where the project's set-up puts the library, relative to the repository root.
pub const REPO_LIB_PATH: &str = ".ort/libonnxruntime.so";

static RUNTIME: OnceLock<Result<Environment, String>> = OnceLock::new();

/// The process-wide ONNX Runtime environment, loading the library on the first call. The
/// error is one line that says what to run; it is the same on every later call (a library can
/// be loaded once per process).
pub fn environment() -> Result<&'static Environment, String> {
    RUNTIME
        .get_or_init(|| {
            let env_path = std::env::var_os("ORT_DYLIB_PATH").map(PathBuf::from);
            let path = locate(env_path.as_deref())?;
            ort::init_from(&path)
                .map_err(|e| {
                    format!(
                        "cannot load the ONNX Runtime library {}: {} (run `bash scripts/setup.sh`)",
                        path.display(),
                        one_line(&e.to_string())
                    )
                })?
                .with_name("rt-loop")
                // the bench must not depend on anybody's network (PyPI builds have it off)
                .with_telemetry(false)
                .build()
                .map_err(|e| format!("ONNX Runtime environment: {}", one_line(&e.to_string())))
        })
        .as_ref()
        .map_err(Clone::clone)
}

/// Finds the library without loading it: `env_path` (the value of `ORT_DYLIB_PATH`) when set,
/// else `.ort/libonnxruntime.so` in the ancestors of the executable, the working directory and
/// this crate's directory.
pub fn locate(env_path: Option<&Path>) -> Result<PathBuf, String> {
    if let Some(p) = env_path.filter(|p| !p.as_os_str().is_empty()) {
        return if p.is_file() {
            Ok(p.to_path_buf())
        } else {
            Err(format!(
                "the ONNX Runtime library was not found: ORT_DYLIB_PATH={} is not a file (run \
                 `bash scripts/setup.sh` and `source scripts/env.sh`)",
                p.display()
            ))
        };
    }
    let mut roots: Vec<PathBuf> = Vec::new();
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        roots.push(dir);
    }
    roots.extend(std::env::current_dir().ok());
    roots.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    roots
        .iter()
        .flat_map(|r| r.ancestors())
        .map(|d| d.join(REPO_LIB_PATH))
        .find(|c| c.is_file())
        .ok_or_else(|| {
            format!(
                "the ONNX Runtime library was not found (ORT_DYLIB_PATH unset, no {REPO_LIB_PATH} \
                 above the executable or the working directory): run `bash scripts/setup.sh`"
            )
        })
}

/// ONNX Runtime's messages may span lines; errors here are one line.
pub fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An ORT_DYLIB_PATH that names nothing is a one-line error naming it and what to run.
    #[test]
    fn a_missing_library_is_a_one_line_error() {
        let err = locate(Some(Path::new("/nonexistent/libonnxruntime.so"))).unwrap_err();
        assert!(err.contains("/nonexistent/libonnxruntime.so"), "{err}");
        assert!(err.contains("scripts/setup.sh"), "{err}");
        assert!(!err.contains('\n'));
        assert_eq!(one_line("a\n  b\tc"), "a b c");
    }
}
