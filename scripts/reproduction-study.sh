#!/usr/bin/env bash
# The reproduction study of the thesis (sections 6.4.3 and 6.4.4): builds rt-loop and
# infer-server in release, then `haptics-train study` runs the simulated hand against the
# simulated sponge and against every served model in models/, runs the position-replay
# validation, and writes docs/study/README.md with its plots.
#   bash scripts/reproduction-study.sh [extra haptics-train study options, e.g. --names rf_memory,sd_poly2]
# Needs: bash scripts/setup.sh (.venv, .ort), data/dataset (scripts/record-dataset.sh) and the
# models (.venv/bin/haptics-train pipeline).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
if [ ! -x .venv/bin/haptics-train ]; then
  echo "reproduction-study: .venv/bin/haptics-train missing: run bash scripts/setup.sh first" >&2
  exit 2
fi
if [ ! -f data/dataset/test_2.1.parquet ]; then
  echo "reproduction-study: data/dataset/test_2.1.parquet missing: run scripts/record-dataset.sh" >&2
  exit 2
fi
if ! ls models/*.onnx >/dev/null 2>&1; then
  echo "reproduction-study: no models/*.onnx: run .venv/bin/haptics-train pipeline" >&2
  exit 2
fi
start=$(date +%s)
echo "[study] build: rt-loop, infer-server, hapticctl (release)"
haptics_build
built=$(date +%s)
.venv/bin/haptics-train study "$@"
echo "[study] build $((built - start)) s, study $(( $(date +%s) - built )) s"
