#!/usr/bin/env bash
# What each model family costs as infer-server serves it (issue 25): trains one model of each
# family the product can train (spring-damper, linear, SVR, forests, DNN, LSTM, the feedback
# networks, prony, structured, lstm_slow, lawfree; small and fast: the cost of a call depends on
# the graph, not on how long it trained), exports each with haptics-train (parity with `predict`
# checked, 1e-4 N), adds the one-node `identity` graph (the floor of calling ONNX Runtime at
# all), then serves each through infer-server's own inference thread in process over a real
# shared-memory segment at 10 kHz (benches/model_families.rs) and prints a table (nodes,
# p50/p99/p99.9/max per call in us, allocations per call) and as its LAST line one JSON object:
#   {"families": {NAME: {"p50_us", "p99_us", "p999_us", ...}}, "identity_p50_us": ..}
#
# Usage: scripts/bench-models.sh [--retrain]   (the first run trains: minutes on 2 cores, see
#        docs/infer-server.md; later runs re-export the models already trained)
# Env:   BENCH_DATASET (default data/dataset when it holds a test recording, else a small
#        dataset recorded once into BENCH_DIR/dataset with rt-loop run), BENCH_DIR (default
#        target/bench-models), BENCH_STEPS (measured steps per model, default 20000), BENCH_CPU
#        (the inference thread's CPU instead of the one its profile picks), BENCH_KEEP_AWAKE
#        (1|0: the keep-awake spinner on that CPU or none; default: the profile's, as infer-server),
#        BENCH_RUNS (default 1): serve every family that many times in a row (the models are
#        exported once), then print each key run by run and its median (scripts/bench-median.py);
#        the last line is then the same JSON object holding the medians, plus `runs` and
#        `per_run`. These machines are shared and noisy: quote medians of several runs.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
runs=${BENCH_RUNS:-1}
case "$runs" in
  '' | *[!0-9]* | 0) echo "bench-models: BENCH_RUNS must be a whole number >= 1, got '$runs'" >&2; exit 2 ;;
esac
dir=${BENCH_DIR:-target/bench-models}
case $dir in /*) ;; *) dir=$root/$dir ;; esac
say() { printf '==> %s\n' "$*" >&2; }

# shellcheck disable=SC1091
source scripts/env.sh
[ -x .venv/bin/python ] || { echo "bench-models: no .venv (run bash scripts/setup.sh)" >&2; exit 1; }
export PYTHONPATH="$root/train/src${PYTHONPATH:+:$PYTHONPATH}"
say "build (release): rt-loop, infer-server and the benchmark"
haptics_build >&2
cargo bench -p infer-server --bench model_families --no-run >&2

dataset=${BENCH_DATASET:-}
if [ -z "$dataset" ]; then
  if compgen -G "data/dataset/test_*.parquet" >/dev/null; then
    dataset=data/dataset
  else
    # Short runs of the default bench (the sponge, 10 kHz lockstep): a training, a validation
    # and a test recording of a few presses each.
    dataset=$dir/dataset
    mkdir -p "$dataset"
    record() { # name ramp_rate cycles seed
      [ -f "$dataset/$1.parquet" ] && return
      target/release/rt-loop run --clock lockstep --rate-hz 10000 --seed "$4" \
        --material materials/sponge.toml --experiment abstraction --ramp-rate "$2" \
        --cycles "$3" --f-max-start 2 --f-max-step 2 --record "$dataset/$1.parquet" --no-progress >&2
    }
    say "recording a small dataset into $dataset (rt-loop run, lockstep)"
    record train_3.9 3.9 4 1
    record train_6.2 6.2 4 1
    record validation_5.0 5.0 2 3
    record test_4.0 4.0 3 2
  fi
fi
say "train (once) and export one model per family from $dataset into $dir"
nice -n 10 .venv/bin/python infer-server/benches/bench_models_prep.py "$dataset" "$dir" "$@" >&2

say "serve each through the inference thread (${BENCH_STEPS:-20000} steps each, 10 kHz)"
if [ "$runs" -gt 1 ]; then
  python3 scripts/bench-median.py --runs "$runs" --label bench-models -- \
    cargo bench -q -p infer-server --bench model_families -- "$dir/families"
else
  cargo bench -q -p infer-server --bench model_families -- "$dir/families"
fi
