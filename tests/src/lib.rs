//! Helpers for the cross-process tests in `tests/tests/`: the built binaries of the workspace
//! (`target/<profile>/rt-loop`, `infer-server`, `hapticctl`), child processes that are killed
//! when a test fails, the project's Python, and small ONNX models written with the `onnx`
//! package.

pub mod csv_table;
pub mod skip;

pub use csv_table::CsvTable;

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The repository root (this crate lives in `tests/`).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// The profile directory of the running test executable (`target/release` for
/// `cargo test --release`): the test binary lives in `target/<profile>/deps/`.
pub fn bin_dir() -> PathBuf {
    if let Ok(d) = std::env::var("HAPTICS_BIN_DIR") {
        return PathBuf::from(d);
    }
    let exe = std::env::current_exe().expect("current_exe");
    let deps = exe.parent().expect("deps dir");
    deps.parent().expect("profile dir").to_path_buf()
}

/// A workspace binary next to the test's profile, or a panic that says how to build it.
pub fn bin(name: &str) -> PathBuf {
    let p = bin_dir().join(name);
    if !p.is_file() {
        let profile = bin_dir()
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let flag = if profile == "release" {
            " --release"
        } else {
            ""
        };
        panic!(
            "{} is missing: build the workspace's binaries first (cargo build{flag} -p rt-loop -p infer-server -p hapticctl), \
             or point HAPTICS_BIN_DIR at a directory holding them",
            p.display()
        );
    }
    p
}

/// The project's Python (`.venv/bin/python`, made by scripts/setup.sh).
pub fn python() -> PathBuf {
    let p = repo_root().join(".venv/bin/python");
    assert!(
        p.is_file(),
        "{} is missing: run `bash scripts/setup.sh` (it creates .venv with onnx and onnxruntime)",
        p.display()
    );
    p
}

/// Runs a Python snippet with the project's Python; panics with its stderr on failure.
pub fn run_python(code: &str, args: &[&str]) {
    let out = Command::new(python())
        .arg("-c")
        .arg(code)
        .args(args)
        .output()
        .expect("spawn python");
    assert!(
        out.status.success(),
        "python failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Writes a stateless linear ONNX model `force = features @ w + b` over the named features
/// (float32 MatMul + Add, opset 17) with the metadata of docs/model-contract.md.
pub fn write_linear_model(path: &Path, features: &[&str], weights: &[f32], bias: f32) {
    assert_eq!(features.len(), weights.len());
    let code = r#"
import json, sys
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper
path, feats, w, b = sys.argv[1], sys.argv[2].split(","), json.loads(sys.argv[3]), float(sys.argv[4])
n = len(feats)
W = numpy_helper.from_array(np.array(w, dtype=np.float32).reshape(n, 1), "W")
B = numpy_helper.from_array(np.array([b], dtype=np.float32), "B")
nodes = [helper.make_node("MatMul", ["features", "W"], ["xw"]), helper.make_node("Add", ["xw", "B"], ["force"])]
x = helper.make_tensor_value_info("features", TensorProto.FLOAT, ["N", n])
y = helper.make_tensor_value_info("force", TensorProto.FLOAT, ["N", 1])
g = helper.make_graph(nodes, "linear", [x], [y], initializer=[W, B])
m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
m.ir_version = 8
for k, v in {"haptics.features": ",".join(feats), "haptics.kind": "stateless", "haptics.units": "N",
             "haptics.provenance": json.dumps({"source": "haptics-system-tests"})}.items():
    e = m.metadata_props.add(); e.key = k; e.value = v
onnx.checker.check_model(m)
onnx.save(m, path)
"#;
    let w = format!(
        "[{}]",
        weights
            .iter()
            .map(|v| format!("{v:e}"))
            .collect::<Vec<_>>()
            .join(",")
    );
    run_python(
        code,
        &[
            path.to_str().unwrap(),
            &features.join(","),
            &w,
            &format!("{bias:e}"),
        ],
    );
}

/// A child process whose stdout/stderr are collected; killed (SIGKILL) when dropped.
pub struct Proc {
    pub name: String,
    pub child: Child,
    pub out: Arc<Mutex<String>>,
    /// The stdout/stderr readers: joined once the child has exited, so `output()` after
    /// `wait_exit` holds everything the process printed (a fixed sleep raced on a loaded machine).
    readers: Vec<std::thread::JoinHandle<()>>,
}

impl Proc {
    pub fn spawn(name: &str, cmd: &mut Command) -> Proc {
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .current_dir(repo_root());
        let mut child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        let out = Arc::new(Mutex::new(String::new()));
        let mut readers = Vec::new();
        for stream in [
            Box::new(child.stdout.take().unwrap()) as Box<dyn Read + Send>,
            Box::new(child.stderr.take().unwrap()),
        ] {
            let out = out.clone();
            readers.push(std::thread::spawn(move || {
                for line in BufReader::new(stream).lines() {
                    let Ok(line) = line else { break };
                    let mut o = out.lock().unwrap();
                    o.push_str(&line);
                    o.push('\n');
                }
            }));
        }
        Proc {
            name: name.into(),
            child,
            out,
            readers,
        }
    }

    pub fn output(&self) -> String {
        self.out.lock().unwrap().clone()
    }

    pub fn pid(&self) -> i32 {
        self.child.id() as i32
    }

    pub fn signal(&self, sig: i32) {
        // SAFETY: kill(2) on our own child's pid.
        unsafe {
            libc::kill(self.pid(), sig);
        }
    }

    /// Waits until the output contains `needle`; panics with the output after `timeout`.
    pub fn wait_for(&mut self, needle: &str, timeout: Duration) -> String {
        let end = Instant::now() + timeout;
        loop {
            let o = self.output();
            if o.contains(needle) {
                return o;
            }
            if let Ok(Some(st)) = self.child.try_wait() {
                std::thread::sleep(Duration::from_millis(100));
                panic!(
                    "{} exited ({st}) before printing {needle:?}:\n{}",
                    self.name,
                    self.output()
                );
            }
            assert!(
                Instant::now() < end,
                "{} did not print {needle:?} within {timeout:?}:\n{o}",
                self.name
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Waits for the exit; panics with the output after `timeout`.
    pub fn wait_exit(&mut self, timeout: Duration) -> ExitStatus {
        let end = Instant::now() + timeout;
        loop {
            if let Some(st) = self.child.try_wait().expect("try_wait") {
                // The pipes close with the process (no grandchildren hold them), so the readers
                // end once they have read everything.
                for reader in self.readers.drain(..) {
                    let _ = reader.join();
                }
                return st;
            }
            assert!(
                Instant::now() < end,
                "{} did not exit within {timeout:?}:\n{}",
                self.name,
                self.output()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Proc {
    /// A test that fails leaves nothing behind: SIGINT first (rt-loop and infer-server exit
    /// cleanly on it, removing the segment), SIGKILL after 3 s.
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.signal(libc::SIGINT);
            let end = Instant::now() + Duration::from_secs(3);
            while Instant::now() < end {
                if let Ok(Some(_)) = self.child.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// A fresh temporary directory under the system's temp dir, removed when the test is done with
/// it. A test that fails keeps its directory (the loop's logs, recordings and configs are the
/// evidence) and says where it is.
pub struct TempDir(PathBuf);

impl TempDir {
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("test failed: its files are kept in {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// A fresh [`TempDir`]: `haptics-TAG-PID-N` (N counts this process's directories).
pub fn temp_dir(tag: &str) -> TempDir {
    static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let d = std::env::temp_dir().join(format!("haptics-{tag}-{}-{n}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create temp dir");
    TempDir(d)
}

/// A unique instance name for a test (segment `/haptics-<name>`).
pub fn instance(tag: &str) -> String {
    format!("systest-{tag}-{}", std::process::id())
}

/// The token [`start_infer_server`] gives infer-server (`HAPTICS_TOKEN`).
pub const TEST_TOKEN: &str = "systest-token-4f1c2a9e7b3d";

/// Starts `infer-server serve` on free ports and returns it with its gRPC address (read from
/// the line it prints once both listeners are bound).
pub fn start_infer_server(instance: &str, models: &Path, model: Option<&str>) -> (Proc, String) {
    let mut cmd = Command::new(bin("infer-server"));
    // A known token (infer-server requires one on every call, on loopback too): the tests'
    // clients send it; tests/tests/trust.rs covers the token infer-server creates itself.
    cmd.env("HAPTICS_TOKEN", TEST_TOKEN);
    cmd.args(["serve", "--instance", instance, "--grpc", "127.0.0.1:0"])
        .args(["--http", "127.0.0.1:0", "--models"])
        .arg(models);
    if let Some(m) = model {
        cmd.args(["--model", m]);
    }
    let mut p = Proc::spawn("infer-server", &mut cmd);
    let out = p.wait_for("infer-server: gRPC ", Duration::from_secs(60));
    let addr = out
        .lines()
        .find_map(|l| l.strip_prefix("infer-server: gRPC "))
        .and_then(|l| l.split_whitespace().next())
        .expect("gRPC address in the ready line")
        .to_string();
    (p, addr)
}

/// `/dev/shm` entries that belong to an instance (segment and its lock file).
pub fn shm_entries(instance: &str) -> Vec<String> {
    let seg = format!("haptics-{instance}");
    std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.contains(&seg))
                .collect()
        })
        .unwrap_or_default()
}

/// `hapticctl --addr http://ADDR ARGS...`: whether it succeeded, and its stdout and stderr.
pub fn ctl(addr: &str, args: &[&str]) -> (bool, String) {
    let o = Command::new(bin("hapticctl"))
        .env("HAPTICS_TOKEN", TEST_TOKEN)
        .arg("--addr")
        .arg(format!("http://{addr}"))
        .args(args)
        .output()
        .expect("hapticctl");
    (
        o.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        ),
    )
}

/// `hapticctl --json status` at ADDR, parsed; panics (with its output) when the call fails.
pub fn ctl_status(addr: &str) -> serde_json::Value {
    let (ok, out) = ctl(addr, &["--json", "status"]);
    assert!(ok, "hapticctl status: {out}");
    serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("{e}: {out}"))
}

/// GET over a plain TCP connection (HTTP/1.0, the body after the headers); panics unless 200.
pub fn http_get(addr: &str, path: &str) -> String {
    use std::io::{Read, Write};
    let mut c = std::net::TcpStream::connect(addr).expect("connect HTTP");
    c.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(
        c,
        "GET {path} HTTP/1.0\r\nHost: {addr}\r\nAuthorization: Bearer {TEST_TOKEN}\r\n\r\n"
    )
    .unwrap();
    let mut out = String::new();
    c.read_to_string(&mut out).expect("HTTP response");
    assert!(
        out.starts_with("HTTP/1.") && out.contains(" 200 "),
        "{path}: {out}"
    );
    out.split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default()
}

#[cfg(test)]
mod temp_dir_tests {
    use super::temp_dir;

    #[test]
    fn a_passing_test_leaves_no_directory_behind() {
        let dir = temp_dir("unit-pass");
        std::fs::write(dir.join("f"), b"x").unwrap();
        let path = dir.to_path_buf();
        drop(dir);
        assert!(!path.exists(), "{} still exists", path.display());
    }

    #[test]
    fn a_failing_test_keeps_its_files() {
        let (tx, rx) = std::sync::mpsc::channel();
        let failed = std::thread::spawn(move || {
            let dir = temp_dir("unit-fail");
            std::fs::write(dir.join("evidence.log"), b"x").unwrap();
            tx.send(dir.to_path_buf()).unwrap();
            panic!("the test fails");
        })
        .join();
        assert!(failed.is_err());
        let path = rx.recv().unwrap();
        let kept = path.join("evidence.log").exists();
        let _ = std::fs::remove_dir_all(&path);
        assert!(kept, "{} was removed", path.display());
    }
}
