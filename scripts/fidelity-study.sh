#!/usr/bin/env bash
# The fidelity table of issue 11 for one material, from nothing: identify the bench's friction
# (rt-loop identify-friction -> bench.toml), record the dataset without and with friction
# compensation, train and export the models on each, and run the reproduction study with the
# oracle's floor, both settings side by side. Prints (and writes to the report folder as
# timings.json) the minutes each step took.
#
# Usage: scripts/fidelity-study.sh [--material FILE] [--out DIR] [extra haptics-train study options]
#   --material  default materials/sponge.toml (its report goes to docs/study and its figures
#               into docs/fidelity.json); another material's report goes to docs/study/<name>
#               unless --out says otherwise, and leaves docs/fidelity.json alone.
# Env:  MODELS  haptics-train specs to train (default "sd_poly2,rf:memory": the spring-damper
#               baseline and the model the study found best to feel; the full comparison takes
#               about half an hour per setting on the shared 2-core machine).
#       DECIMATE  for the recordings (default 1).
# Work files: data/fidelity/<name>/{off,on}/{dataset,models}, data/fidelity/<name>/study.
set -euo pipefail
cd "$(dirname "$0")/.."
material=materials/sponge.toml
out=""
while [ $# -gt 0 ]; do
  case "$1" in
    --material) material=${2:?--material needs a file}; shift 2 ;;
    --out) out=${2:?--out needs a folder}; shift 2 ;;
    -h|--help) sed -n 2,17p "$0"; exit 0 ;;
    *) break ;;
  esac
done
[ -f "$material" ] || { echo "fidelity-study: no material file $material" >&2; exit 2; }
name=$(basename "$material" .toml)
models=${MODELS:-sd_poly2,rf:memory}
fidelity=""
if [ -z "$out" ]; then
  if [ "$name" = sponge ]; then out=docs/study; else out=docs/study/$name; fi
fi
if [ "$out" = docs/study ]; then fidelity=docs/fidelity.json; fi
work=data/fidelity/$name
mkdir -p "$work" "$out"
# shellcheck disable=SC1091
source scripts/env.sh
if [ ! -x .venv/bin/haptics-train ]; then
  echo "fidelity-study: .venv/bin/haptics-train missing: run bash scripts/setup.sh first" >&2
  exit 2
fi
declare -A took
step() { # key command...
  local key=$1 t0=$SECONDS
  shift
  echo "[fidelity] $key: $*"
  "$@"
  took[$key]=$((SECONDS - t0))
}
step build haptics_build
step identify_friction target/release/rt-loop identify-friction --out bench.toml
for setting in off on; do
  bench_args=()
  [ "$setting" = on ] && bench_args=(--bench bench.toml)
  ds=$work/$setting/dataset
  md=$work/$setting/models
  step "record_$setting" bash scripts/record-dataset.sh --material "$material" "${bench_args[@]}" "$ds"
  step "train_$setting" .venv/bin/haptics-train train --dataset "$ds" --models-dir "$md" \
    --models "$models" --no-progress
  step "export_$setting" .venv/bin/haptics-train export --dataset "$ds" --models-dir "$md" --no-parity
done
step study .venv/bin/haptics-train study --models-dir "$work/off/models" \
  --bench bench.toml --bench-models-dir "$work/on/models" --material "$material" \
  --trajectory "$work/off/dataset/test_2.1.parquet" --out "$out" --work "$work/study" \
  --fidelity "$fidelity" "$@"
{
  echo "{"
  echo "  \"material\": \"$material\", \"models\": \"$models\","
  sep=""
  for k in build identify_friction record_off train_off export_off record_on train_on export_on study; do
    printf '%s  "%s_min": %.2f' "$sep" "$k" "$(awk -v s="${took[$k]}" 'BEGIN { print s / 60 }')"
    sep=$',\n'
  done
  printf '\n}\n'
} > "$out/timings.json"
cat "$out/timings.json"
