#!/usr/bin/env bash
# Runs every test of the project: Rust (unit, integration, cross-process), Python, browser.
# Installs what it needs from the package registries first (idempotent), so it works on a
# fresh clone. `.ci/run` calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
export CARGO_TERM_COLOR=never

step() { printf '\n==> %s\n' "$*"; }

step "set-up (Python env, ONNX Runtime library, browser) if missing"
bash scripts/setup.sh
# shellcheck disable=SC1091
source scripts/env.sh

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy --all-targets -D warnings"
cargo clippy --workspace --all-targets -- -D warnings

step "cargo test (workspace, release: real-time tests need optimised code)"
cargo test --workspace --release

step "loom models of the shm-ring protocol (separate target dir: --cfg loom changes every crate)"
RUSTFLAGS="--cfg loom" CARGO_TARGET_DIR=target/loom cargo test -p shm-ring --release --test loom

if [ -f train/pyproject.toml ]; then
  step "ruff + pytest (train/)"
  (cd train && "$root/.venv/bin/ruff" check . && "$root/.venv/bin/python" -m pytest -q)
fi

if [ -f web-ui/package.json ] && [ -d web-ui/tests ]; then
  step "browser tests (headless Chromium)"
  (cd web-ui && npm test)
fi

step "all tests passed"
