#!/usr/bin/env bash
# Records the training and test dataset on the simulated sponge bench (SPEC section 4):
# ramp rates 0.8, 1.8, 3.9, 6.2 N/s (train) and 2.1 N/s (test), 14 cycles each, F_max from
# 1 N in 1 N steps up to 14 N, lockstep clock at 10 kHz, seed 1 (test: seed 2); and a
# validation recording at 5.0 N/s (seed 3).
#
# Usage: scripts/record-dataset.sh [--material FILE] [--bench FILE] [OUTDIR=data/dataset]
#        --material: the simulated object (default materials/sponge.toml; e.g. materials/foam-b.toml)
#        --bench: bench file of `rt-loop identify-friction` (the RFOB subtracts its friction model;
#        default none, as the thesis code); both are written into each recording's metadata.
# Env:   DECIMATE (default 1: every step, lossless, ~460 MB for the five files; 2 halves that:
#        5 kHz rows, ~240 MB; the loop and its online features always run at 10 kHz),
#        SEED (default 1; the test recording uses SEED + 1).
# Existing files are kept (delete one to record it again).
set -euo pipefail
cd "$(dirname "$0")/.."
material=materials/sponge.toml
bench_args=()
while [ $# -gt 0 ]; do
  case "$1" in
    --material) material=${2:?--material needs a file}; shift 2 ;;
    --bench) bench_args=(--bench "${2:?--bench needs a file}"); shift 2 ;;
    -h|--help) sed -n 2,15p "$0"; exit 0 ;;
    -*) echo "record-dataset: unknown option $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
[ -f "$material" ] || { echo "record-dataset: no material file $material" >&2; exit 2; }
out=${1:-data/dataset}
decimate=${DECIMATE:-1}
seed=${SEED:-1}
mkdir -p "$out"
# shellcheck disable=SC1091
source scripts/env.sh
haptics_build
bin=target/release/rt-loop

record() { # name ramp_rate seed
  local file="$out/$1.parquet"
  if [ -f "$file" ]; then
    echo "record-dataset: $file exists, skipped"
    return
  fi
  local t0=$SECONDS
  "$bin" run --experiment abstraction --clock lockstep --rate-hz 10000 --seed "$3" \
    --material "$material" "${bench_args[@]}" --ramp-rate "$2" --cycles 14 --f-max-start 1 \
    --f-max-step 1 --decimate "$decimate" --record "$file" --no-progress
  echo "record-dataset: $file: $(du -h "$file" | cut -f1), $((SECONDS - t0)) s"
}

record train_0.8 0.8 "$seed"
record train_1.8 1.8 "$seed"
record train_3.9 3.9 "$seed"
record train_6.2 6.2 "$seed"
record test_2.1 2.1 $((seed + 1))
# validation: a ramp rate neither trained nor tested on; haptics-train makes every choice
# (feedback noise, the recommended model) on it, so the test is scored once
record validation_5.0 5.0 $((seed + 2))
du -ch "$out"/*.parquet | tail -1
