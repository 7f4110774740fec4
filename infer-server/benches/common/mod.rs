//! Set-up shared by infer-server's benchmarks: where the repository is, and the benchmark
//! models (random forest 100 x depth 9, dense 9-150-25-1, LSTM 100), generated once into
//! `target/bench-models` by `make_bench_models.py` with the project's venv.

// Each bench uses a part of this module; the rest would warn as dead code in that bench.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .canonicalize()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf()
}

pub fn bench_models() -> PathBuf {
    let dir = repo_root().join("target/bench-models");
    if ["rf", "dense", "lstm"]
        .iter()
        .all(|m| dir.join(format!("{m}.onnx")).exists())
    {
        return dir;
    }
    let py = std::env::var_os("HAPTICS_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(".venv/bin/python"));
    assert!(
        py.exists(),
        "{} missing: run `bash scripts/setup.sh` (the bench models are built with scikit-learn, skl2onnx and torch)",
        py.display()
    );
    eprintln!("generating benchmark models in {} ...", dir.display());
    let status = Command::new(&py)
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/make_bench_models.py"))
        .arg(&dir)
        .status()
        .unwrap();
    assert!(status.success(), "make_bench_models.py failed");
    dir
}

/// Waits like a paced loop until `next`: sleeps until 30 us before it (when `sleep`; a loop
/// that leaves the other core to the server must), then spins the rest.
pub fn pace_until(next: Instant, sleep: bool) {
    if sleep {
        let now = Instant::now();
        if next > now + Duration::from_micros(30) {
            std::thread::sleep(next - now - Duration::from_micros(30));
        }
    }
    while Instant::now() < next {
        std::hint::spin_loop();
    }
}
