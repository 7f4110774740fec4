#!/usr/bin/env bash
# Runs every test of the project: Rust (unit, integration, cross-process), Python, browser.
# Installs what it needs from the package registries first (idempotent), so it works on a
# fresh clone. `.ci/run` calls exactly this.
#
# No test passes by not running: a test whose dependency is missing FAILS under CI=true, and is
# an explicit skip elsewhere. Skips are counted and the last line says how many, as
# "N passed, N failed, N skipped" (each runner's own closing lines stay above it):
#   Rust   libtest's "ignored", plus the tests that recorded a skip in $HAPTICS_SKIP_LOG
#          (tests/src/skip.rs; libtest has no skipped outcome, so they also count as passed
#          there and are moved from passed to skipped here)
#   Python pytest's "skipped"
#   browser node:test's "# skipped"
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
export CARGO_TERM_COLOR=never

# Each step's header says when it started (minutes:seconds since the test command began), so a
# slow run shows where its time went; the total is printed just above the last line.
since_start() { printf '%d:%02d' $((SECONDS / 60)) $((SECONDS % 60)); }
step() { printf '\n==> %s  [%s]\n' "$*" "$(since_start)"; }

mkdir -p target
export HAPTICS_SKIP_LOG="$root/target/test-skips.log"
: >"$HAPTICS_SKIP_LOG"
counts="$root/target/test-counts.log"
: >"$counts"

# Appends "passed failed skipped" of one runner's output (read from stdin) to $counts.
count_rust() {
  awk '/^test result: /{
         for (i = 1; i <= NF; i++) {
           if ($(i+1) ~ /^passed/) p += $i; if ($(i+1) ~ /^failed/) f += $i; if ($(i+1) ~ /^ignored/) s += $i
         }
       } END { print p+0, f+0, s+0 }' >>"$counts"
}
count_pytest() {
  # The closing line, e.g. "12 passed, 2 skipped, 1 failed in 3.4s".
  awk '/ in [0-9.]+s/ && /(passed|failed|skipped|error)/ {
         p = f = s = 0
         for (i = 1; i <= NF; i++) {
           w = $(i+1); sub(/[,=]/, "", w)
           if (w == "passed") p = $i; if (w == "failed" || w == "errors" || w == "error") f += $i; if (w == "skipped") s = $i
         }
       } END { print p+0, f+0, s+0 }' >>"$counts"
}
count_node() {
  awk '/^# pass /{p += $3} /^# fail /{f += $3} /^# cancelled /{f += $3} /^# skipped /{s += $3}
       END { print p+0, f+0, s+0 }' >>"$counts"
}

# A check that is one test: passed when its output ends in "are current", else failed.
count_check() {
  awk '/are current$/ {ok = 1} END { print ok + 0, 1 - ok, 0 }' >>"$counts"
}

summary() {
  local status=$?
  local recorded
  recorded=$(grep -c . "$HAPTICS_SKIP_LOG" 2>/dev/null || true)
  if [ -s "$HAPTICS_SKIP_LOG" ]; then
    echo "skipped (recorded by the tests; under CI=true these fail):"
    sed 's/^/  /' "$HAPTICS_SKIP_LOG"
  fi
  echo "test command: $(since_start) (minutes:seconds)"
  # The last line: read by CI.
  awk -v recorded="${recorded:-0}" -v status="$status" '
    { p += $1; f += $2; s += $3 }
    END {
      p -= recorded; s += recorded
      if (status != 0 && f == 0) f = 1  # a step failed outside a test runner (build, lint)
      printf "%d passed, %d failed, %d skipped\n", p, f, s
    }' "$counts"
}
trap summary EXIT

step "set-up (Python env, ONNX Runtime library, browser) if missing"
bash scripts/setup.sh
# shellcheck disable=SC1091
source scripts/env.sh

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy --all-targets -D warnings"
cargo clippy --workspace --all-targets -- -D warnings

step "crate layers (docs/architecture.md: what each crate may depend on)"
bash scripts/crate-deps.sh --check

# Each test step runs to its end and is counted even when it fails; the script goes on to the
# next step (one failure should not hide the others) and exits non-zero at the end.
failed_steps=()
# run_counted NAME COUNTER CMD...: runs CMD, tees its output to target/test-NAME.log, counts it.
run_counted() {
  local name=$1 counter=$2
  shift 2
  local rc=0
  "$@" 2>&1 | tee "target/test-$name.log" || rc=$?
  "$counter" <"target/test-$name.log"
  if [ "$rc" != 0 ]; then
    failed_steps+=("$name (exit $rc)")
  fi
}

step "generated name lists current (haptics-vocab --check: train/ vocab.py, web-ui/ vocab.ts)"
run_counted vocab count_check cargo run --release -q -p haptics-proto --bin haptics-vocab -- --check

# One build for everything the tests run: the test binaries, the binaries they start, the Sensoray
# 826 double (target/release/libs826_double.so: the system tests' --board s826) and the fused ONNX
# operators (target/release/libhaptics_fused_ops.so: train's parity tests). It selects the same
# targets as `cargo test --workspace`, so cargo unifies dependency features the same way and the
# test step below compiles nothing. Building the two libraries alone (`-p s826-double -p
# haptics-fused-ops`) resolved features without the workspace's dev-dependencies, and the test
# step then compiled Arrow, Parquet, rt-loop and 50 more crates a second time: 4-5 minutes.
step "release build of the workspace's libraries, binaries, tests and examples (the 826 double and the fused operators among them)"
haptics_build --tests # scripts/env.sh: every script's build, with the test targets

step "cargo test (workspace, release: real-time tests need optimised code)"
run_counted rust count_rust cargo test --workspace --release --no-fail-fast

step "loom models of the shm-ring protocol (separate target dir: --cfg loom changes every crate)"
run_counted loom count_rust env RUSTFLAGS="--cfg loom" CARGO_TARGET_DIR=target/loom \
  cargo test -p shm-ring --release --test loom

step "fuzz targets, a few seconds each (fuzz/: libFuzzer; scripts/fuzz.sh runs the long one)"
run_counted fuzz count_rust bash scripts/fuzz.sh --seconds 4 --no-hostile

if [ -f train/pyproject.toml ]; then
  step "ruff + pytest (train/)"
  run_counted python count_pytest bash -c \
    'cd train && "$0/.venv/bin/ruff" check . && "$0/.venv/bin/python" -m pytest -q -rs' "$root"
fi

if [ -f client/pyproject.toml ]; then
  # The Python client against real rt-loop + infer-server processes, rt-loop's MCAP read by the
  # official reader, the example notebook executed (nbclient), the Grafana dashboard's metrics.
  step "ruff + pytest (client/: the haptics Python client, MCAP, docs/notebook.ipynb, ops/grafana)"
  run_counted client count_pytest bash -c \
    'cd client && "$0/.venv/bin/ruff" check --config pyproject.toml . ../ops/grafana && "$0/.venv/bin/python" -m pytest -q -rs' "$root"
fi

if [ -f web-ui/package.json ] && [ -d web-ui/tests ]; then
  step "browser tests (headless Chromium)"
  run_counted browser count_node bash -c 'cd web-ui && npm test'
fi

if [ ${#failed_steps[@]} -gt 0 ]; then
  step "FAILED steps: ${failed_steps[*]}"
  exit 1
fi
step "all tests passed"
