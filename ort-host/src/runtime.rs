//! Finding and loading the ONNX Runtime shared library, once per process.
//!
//! `ort` is built with `load-dynamic`: nothing is linked or downloaded at build time. The library
//! comes from the `onnxruntime` wheel of the Python registry; `scripts/setup.sh` copies it to
//! `.ort/libonnxruntime.so` at the repository root (and `scripts/env.sh` exports
//! `ORT_DYLIB_PATH`). This module finds it, loads it once per process, and turns every way this
//! can fail into a message that says what to run.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ort::environment::Environment;

/// The command that puts the library in place; printed whenever it is missing.
pub const SETUP_COMMAND: &str = "bash scripts/setup.sh";

/// Where the project's set-up puts the library, relative to the repository root.
pub const REPO_LIB_PATH: &str = ".ort/libonnxruntime.so";

/// The lowest ONNX Runtime minor version this build accepts: `ort`'s own floor
/// ([`ort::MINOR_VERSION`], the C API version it asks for). Tested with 1.31 (the wheel's).
pub const MIN_ORT_MINOR: u32 = ort::MINOR_VERSION;

#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    #[error(
        "the ONNX Runtime library was not found (looked at: {}). Run `{SETUP_COMMAND}` from the \
         repository root: it installs the onnxruntime wheel from PyPI into .venv and copies its \
         library to {REPO_LIB_PATH}. Or point ORT_DYLIB_PATH / --ort-lib at a libonnxruntime.so \
         (version 1.{MIN_ORT_MINOR} or newer).",
        display_paths(searched)
    )]
    Missing { searched: Vec<PathBuf> },
    #[error(
        "could not load the ONNX Runtime library at {path}: {reason}. Run `{SETUP_COMMAND}` to \
         put a compatible library (onnxruntime 1.{MIN_ORT_MINOR} or newer, from the PyPI wheel) at \
         {REPO_LIB_PATH}."
    )]
    Load { path: PathBuf, reason: String },
    #[error("ONNX Runtime loaded from {path} but its environment could not be created: {reason}")]
    Environment { path: PathBuf, reason: String },
}

fn display_paths(paths: &[PathBuf]) -> String {
    paths
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The loaded library and the process-wide ONNX Runtime environment every session is made in.
#[derive(Clone)]
pub struct Runtime {
    env: Environment,
    library: PathBuf,
    version: String,
}

impl std::fmt::Debug for Runtime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Runtime")
            .field("library", &self.library)
            .field("version", &self.version)
            .finish()
    }
}

static RUNTIME: OnceLock<Runtime> = OnceLock::new();

/// The name this process gives ONNX Runtime and prefixes its log lines with: the executable's
/// (`infer-server`, `rt-loop`), read once.
fn program() -> &'static str {
    static NAME: OnceLock<String> = OnceLock::new();
    NAME.get_or_init(|| {
        std::env::current_exe()
            .ok()
            .and_then(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
            .unwrap_or_else(|| "haptics".to_string())
    })
}

/// One ONNX Runtime log line on stderr, plain text: `infer-server: onnxruntime warning: ...`.
fn plain_log_line(
    level: ort::logging::LogLevel,
    _category: &str,
    _id: &str,
    location: &str,
    message: &str,
) {
    use ort::logging::LogLevel;
    let level = match level {
        LogLevel::Verbose | LogLevel::Info => return,
        LogLevel::Warning => "warning",
        LogLevel::Error => "error",
        LogLevel::Fatal => "fatal",
    };
    let message: String = message.chars().filter(|c| *c != '\u{1b}').collect();
    eprintln!("{}: onnxruntime {level}: {message} ({location})", program());
}

impl Runtime {
    /// Loads ONNX Runtime once per process. `explicit` (the `--ort-lib` flag) wins over
    /// `ORT_DYLIB_PATH`, which wins over a search for `.ort/libonnxruntime.so` in the ancestors of
    /// the executable and of the working directory. The library can only be loaded once per
    /// process: a later call returns the runtime already loaded, whatever path it names.
    pub fn init(explicit: Option<&Path>) -> Result<&'static Runtime, RuntimeError> {
        if let Some(rt) = RUNTIME.get() {
            return Ok(rt);
        }
        // One initialisation at a time: ONNX Runtime's environment is a process singleton that
        // keeps the FIRST environment's logger, so a second one built by a racing thread and
        // then dropped would leave it logging through a freed closure (measured: a segfault at
        // the first error logged, with two test threads starting together).
        static INIT: std::sync::Mutex<()> = std::sync::Mutex::new(());
        let _one = INIT.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some(rt) = RUNTIME.get() {
            return Ok(rt);
        }
        let path = locate_library(explicit)?;
        let (version, probe) = probe_version(&path)?;
        let builder = ort::init_from(&path).map_err(|e| RuntimeError::Load {
            path: path.clone(),
            reason: e.to_string(),
        })?;
        // ort holds its own handle now; dropping ours only lowers dlopen's reference count, so
        // the library is never unloaded and reloaded in between.
        drop(probe);
        let env = builder
            .with_name(program())
            // The loop must not depend on anybody's network; ONNX Runtime builds from PyPI have
            // telemetry off on Linux anyway, this says it explicitly.
            .with_telemetry(false)
            // ONNX Runtime's own sink colours its lines with ANSI codes even into a file or a
            // pipe; ours writes plain lines (warnings and errors only, see below).
            .with_logger(std::sync::Arc::new(plain_log_line))
            .build()
            .map_err(|e| RuntimeError::Environment {
                path: path.clone(),
                reason: e.to_string(),
            })?;
        // A custom logger receives every level unless told otherwise: warnings and errors only,
        // as ONNX Runtime's default, so no verbose line is ever formatted during a step.
        env.set_log_level(ort::logging::LogLevel::Warning);
        let rt = Runtime {
            env,
            library: path,
            version,
        };
        Ok(RUNTIME.get_or_init(|| rt))
    }

    pub fn environment(&self) -> &Environment {
        &self.env
    }

    /// The library file that was loaded.
    pub fn library(&self) -> &Path {
        &self.library
    }

    /// ONNX Runtime's own version string, e.g. `1.31.1`.
    pub fn version(&self) -> &str {
        &self.version
    }
}

/// ONNX Runtime's messages may span lines; errors shown to users here are one line.
pub fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Finds the library without loading it. See [`Runtime::init`] for the order.
pub fn locate_library(explicit: Option<&Path>) -> Result<PathBuf, RuntimeError> {
    if let Some(p) = explicit {
        return existing(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH").filter(|p| !p.is_empty()) {
        return existing(PathBuf::from(p));
    }
    let mut searched = Vec::new();
    let mut roots = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        if let Some(dir) = exe.parent() {
            roots.push(dir.to_path_buf());
        }
    }
    if let Ok(cwd) = std::env::current_dir() {
        roots.push(cwd);
    }
    // The crate's own directory at build time: lets `cargo test`/`cargo bench` binaries, which
    // live under target/, find the repository's .ort/ even from another working directory.
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    roots.push(manifest.canonicalize().unwrap_or(manifest));
    for root in roots {
        for dir in root.ancestors() {
            let candidate = dir.join(REPO_LIB_PATH);
            if candidate.is_file() {
                return Ok(candidate);
            }
            if !searched.contains(&candidate) {
                searched.push(candidate);
            }
        }
    }
    Err(RuntimeError::Missing { searched })
}

fn existing(p: PathBuf) -> Result<PathBuf, RuntimeError> {
    if p.is_file() {
        Ok(p)
    } else {
        Err(RuntimeError::Missing { searched: vec![p] })
    }
}

/// Reads the library's version string before handing it to `ort`, so that a too-old library is
/// refused with our message rather than a panic deep inside `ort` at first use.
fn probe_version(path: &Path) -> Result<(String, libloading::Library), RuntimeError> {
    let fail = |reason: String| RuntimeError::Load {
        path: path.to_path_buf(),
        reason,
    };
    // SAFETY: loading ONNX Runtime runs its static initialisers, which have no preconditions.
    let lib = unsafe { libloading::Library::new(path) }.map_err(|e| fail(e.to_string()))?;
    // SAFETY: OrtGetApiBase is the library's documented C entry point with this signature.
    let get_base: libloading::Symbol<unsafe extern "C" fn() -> *const ort::sys::OrtApiBase> =
        unsafe { lib.get(b"OrtGetApiBase") }.map_err(|_| {
            fail("it does not export OrtGetApiBase: not an ONNX Runtime library".into())
        })?;
    // SAFETY: the base struct is static inside the library; GetVersionString returns a static
    // NUL-terminated string.
    let version = unsafe {
        let base = get_base();
        if base.is_null() {
            return Err(fail("OrtGetApiBase returned null".into()));
        }
        std::ffi::CStr::from_ptr(((*base).GetVersionString)())
            .to_string_lossy()
            .into_owned()
    };
    let minor = version
        .split('.')
        .nth(1)
        .and_then(|m| m.parse::<u32>().ok())
        .ok_or_else(|| fail(format!("unreadable version string {version:?}")))?;
    if !version.starts_with("1.") || minor < MIN_ORT_MINOR {
        return Err(fail(format!(
            "its version is {version}, this build needs 1.{MIN_ORT_MINOR} or newer"
        )));
    }
    Ok((version, lib))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path that names nothing is refused with the path and what to run, on one line.
    #[test]
    fn a_missing_library_names_the_path_and_the_set_up() {
        let err = locate_library(Some(Path::new("/nonexistent/libonnxruntime.so"))).unwrap_err();
        let msg = err.to_string();
        assert!(msg.contains("/nonexistent/libonnxruntime.so"), "{msg}");
        assert!(msg.contains(SETUP_COMMAND), "{msg}");
        assert!(!msg.contains('\n'), "{msg}");
        assert_eq!(one_line("a\n  b\tc"), "a b c");
    }

    /// A file that is no ONNX Runtime library is refused before `ort` sees it.
    #[test]
    fn a_file_that_is_not_the_library_is_refused_with_a_reason() {
        let dir = std::env::temp_dir().join(format!("ort-host-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fake = dir.join("libonnxruntime.so");
        std::fs::write(&fake, b"not a library").unwrap();
        let err = probe_version(&fake).unwrap_err();
        assert!(matches!(err, RuntimeError::Load { .. }), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
