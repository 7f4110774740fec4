#!/usr/bin/env bash
# The fidelity table of issue 11 for one material, from nothing: identify the bench's friction
# (rt-loop identify-friction -> bench.toml), record the dataset without and with friction
# compensation, train, evaluate (the recommendation: validation free run) and export the
# candidate models on each, record the out-of-distribution suite and score the recommended
# model on it, and run the reproduction study (felt force, the oracle's floor, both friction
# settings side by side; it ranks the candidates again with the felt force of runs of their own,
# another hand programme and seed than the headline, and builds `blend`, the mean of the two it
# ranked first, recommended where it felt closer on those runs: models/blend.py). Prints (and
# writes to the report folder as timings.json) the minutes each step took.
#
# Usage: scripts/fidelity-study.sh [--material FILE] [--out DIR] [extra haptics-train study options]
#   --material  default materials/sponge.toml: its report goes to docs/study and its figures
#               into docs/fidelity.json; another material's report goes to docs/study/<name>
#               (unless --out says otherwise) and its figures into <out>/fidelity.json.
# Env:  MODELS  haptics-train specs to train (default "sd_poly2,rf:memory,structured,
#               structured_path,structured_hyst,lawfree,structured+holds,
#               structured_path+holds,structured_hyst+holds,lawfree+holds,lstm_slow": the
#               spring-damper baseline, the learned model the earlier study found best to
#               feel, the structured model with the bench's friction on the recorded and on
#               the path's velocity, and with a hysteresis of the object's own size (the felt
#               force chooses: validation cannot), the law-free model, the same four trained
#               on the press-and-hold recordings too (`+holds`, holds.py: the felt force
#               chooses that as well), the LSTM stepped at 100 Hz over seconds; the full
#               comparison takes about half an hour per setting on the shared 2-core machine).
#       PRESSES  record the press-and-hold recordings (default 1: the +holds models train on
#               them; every other model ignores them; record-dataset.sh).
#       DECIMATE  for the recordings (default 1).
#       HAPTICS_RT_LOOP, HAPTICS_INFER_SERVER  binaries to use instead of building them (frozen
#               copies while others rebuild the tree).
# Work files: data/fidelity/<name>/{off,on}/{dataset,models}, data/fidelity/<name>/{ood,study}.
set -euo pipefail
cd "$(dirname "$0")/.."
material=materials/sponge.toml
out=""
while [ $# -gt 0 ]; do
  case "$1" in
    --material) material=${2:?--material needs a file}; shift 2 ;;
    --out) out=${2:?--out needs a folder}; shift 2 ;;
    -h|--help) sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$0"; exit 0 ;;
    *) break ;;
  esac
done
[ -f "$material" ] || { echo "fidelity-study: no material file $material" >&2; exit 2; }
name=$(basename "$material" .toml)
holds=structured+holds,structured_path+holds,structured_hyst+holds,lawfree+holds
models=${MODELS:-sd_poly2,rf:memory,structured,structured_path,structured_hyst,lawfree,$holds,lstm_slow}
names=${models//:/_} # rf:memory -> rf_memory: the trained models' names
names=${names//+/_}  # structured+holds -> structured_holds
export PRESSES=${PRESSES:-1}
if [ -z "$out" ]; then
  if [ "$name" = sponge ]; then out=docs/study; else out=docs/study/$name; fi
fi
if [ "$out" = docs/study ]; then fidelity=docs/fidelity.json; else fidelity=$out/fidelity.json; fi
work=data/fidelity/$name
mkdir -p "$work" "$out"
rm -rf "$work/off/models" "$work/on/models" # models of an earlier run are not candidates
# shellcheck disable=SC1091
source scripts/env.sh
if [ ! -x .venv/bin/haptics-train ]; then
  echo "fidelity-study: .venv/bin/haptics-train missing: run bash scripts/setup.sh first" >&2
  exit 2
fi
rt_loop=${HAPTICS_RT_LOOP:-target/release/rt-loop}
infer_server=${HAPTICS_INFER_SERVER:-target/release/infer-server}
export HAPTICS_RT_LOOP=$rt_loop # the recording scripts use it as it is
ht=.venv/bin/haptics-train
declare -A took
step() { # key command...
  local key=$1 t0=$SECONDS
  shift
  echo "[fidelity] $key: $*"
  "$@"
  took[$key]=$((SECONDS - t0))
}
build() {
  if [ -n "${HAPTICS_INFER_SERVER:-}" ]; then echo "(frozen binaries: $rt_loop, $infer_server)"
  else haptics_build; fi
}
# the fidelity file starts from nothing: every key in it comes from this run
rm -f "$fidelity"
step build build
step identify_friction "$rt_loop" identify-friction --out bench.toml
for setting in off on; do
  bench_args=()
  fid_args=()
  [ "$setting" = on ] && bench_args=(--bench bench.toml)
  [ "$setting" = off ] && fid_args=(--fidelity "$fidelity") # the headline setting
  ds=$work/$setting/dataset
  md=$work/$setting/models
  step "record_$setting" bash scripts/record-dataset.sh --material "$material" "${bench_args[@]}" "$ds"
  step "train_$setting" "$ht" train --dataset "$ds" --models-dir "$md" --models "$models" --no-progress
  step "evaluate_$setting" "$ht" evaluate --dataset "$ds" --models-dir "$md" --names "$names" \
    --no-progress "${fid_args[@]}"
  step "export_$setting" "$ht" export --dataset "$ds" --models-dir "$md" --names "$names"
done
step record_ood bash scripts/record-ood.sh --material "$material" "$work/ood"
step study "$ht" study --models-dir "$work/off/models" \
  --bench bench.toml --bench-models-dir "$work/on/models" --material "$material" \
  --trajectory "$work/off/dataset/test_2.1.parquet" --out "$out" --work "$work/study" \
  --rt-loop "$rt_loop" --infer-server "$infer_server" --fidelity "$fidelity" \
  --dataset "$work/off/dataset" "$@"
# the study built `blend` (its ranking runs' first, with the partner and weights that felt closest there) where it could
[ -f "$work/off/models/blend.joblib" ] && names+=,blend
# after the study: the suite's keys are the (felt-force ranked) recommended model's
step score_ood "$ht" ood --suite "$work/ood" --models-dir "$work/off/models" --names "$names" \
  --fidelity "$fidelity" --readme "$out/README.md"
cp "$work/off/models/ood.json" "$out/ood.json"
cp "$work/off/models/recommendation.json" "$out/recommendation.json"
{
  echo "{"
  echo "  \"material\": \"$material\", \"models\": \"$models\","
  sep=""
  for k in build identify_friction record_off train_off evaluate_off export_off record_on \
    train_on evaluate_on export_on record_ood study score_ood; do
    printf '%s  "%s_min": %.2f' "$sep" "$k" "$(awk -v s="${took[$k]}" 'BEGIN { print s / 60 }')"
    sep=$',\n'
  done
  printf '\n}\n'
} > "$out/timings.json"
cat "$out/timings.json" "$fidelity"
