#!/usr/bin/env bash
# Brings the whole system up on the simulated bench, from a fresh clone:
#   1. installs what it needs (scripts/setup.sh: .venv, ONNX Runtime's library, the page's packages)
#   2. builds rt-loop, infer-server and hapticctl in release
#   3. records the default dataset (data/dataset) if missing; trains, evaluates and exports the
#      candidate models (models/) if there is no recommendation yet
#   4. starts rt-loop (realtime, 10 kHz) and infer-server, and prints the page's address
# Ctrl-C stops both cleanly (current to zero, shared-memory segment removed) and says "stopped".
#
# Settings (environment; README.md, "scripts/up.sh's settings", lists them too):
#   HAPTICS_MODEL       the model to serve (default: the one haptics-train recommends,
#                       models/recommendation.json: the best free run on the validation recording,
#                       scored where the probe is pressed and slides)
#   HAPTICS_CANDIDATES  the specs trained when there is no recommendation
#                       (default sd_poly2,rf:memory,structured,lawfree)
#   HAPTICS_AUTOSTART   the experiment started with the loop (default shadow: the simulated hand
#                       presses the simulated sponge while the model predicts alongside; or
#                       abstraction, reproduction, none)
#   HAPTICS_HTTP        the page's address (default 127.0.0.1:8080)
#   HAPTICS_GRPC        the gRPC address hapticctl talks to (default 127.0.0.1:50051)
#   HAPTICS_INSTANCE    the shared-memory segment's instance name (default default)
#   HAPTICS_TOKEN       the control plane's token (default: unset, infer-server creates one and
#                       writes it into its connection file, which hapticctl reads; the page's
#                       address printed below carries it)
#   HAPTICS_PROFILE     infer-server's wait profile (default auto: chosen from the machine and
#                       printed at start; or dedicated, period, shared)
#   HAPTICS_MATERIAL    the simulated bench's object (default materials/sponge.toml; any
#                       material file, an ONNX object's too: docs/laws/onnx.md). Another object
#                       gets its own dataset and models, data/objects/NAME/dataset and
#                       models/objects/NAME (NAME: the file's name without .toml), recorded and
#                       trained on it when missing; the default keeps data/dataset and models/
#   HAPTICS_BOARD       sim (default), or s826[:N], a Sensoray 826 (docs/lab.md)
#   HAPTICS_S826_LIB    the 826 library (unset and none installed: the C-ABI double
#                       target/release/libs826_double.so, which simulates the rig)
#   HAPTICS_S826_WATCHDOG_US  the card's watchdog (default five periods; 100000 on the double:
#                       this is no real-time host)
#   HAPTICS_RIG         the rig file of `rt-loop board calibrate`
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in
  -h|--help) sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$0"; exit 0 ;;
  "") ;;
  *) echo "up: no arguments (the settings are environment variables: scripts/up.sh --help)" >&2; exit 2 ;;
esac

model=${HAPTICS_MODEL:-}
# not structured_path nor structured_hyst: up.sh recommends on validation, and validation
# prefers both on the sponge, where a hand feels them 27 % and more further (docs/laws.md, "The
# bench's velocity", "A hysteresis of the object's own size"); the study, which chooses by felt
# force, has all three (scripts/fidelity-study.sh)
candidates=${HAPTICS_CANDIDATES:-sd_poly2,rf:memory,structured,lawfree}
autostart=${HAPTICS_AUTOSTART:-shadow}
http=${HAPTICS_HTTP:-127.0.0.1:8080}
grpc=${HAPTICS_GRPC:-127.0.0.1:50051}
instance=${HAPTICS_INSTANCE:-default}
profile=${HAPTICS_PROFILE:-auto}
board=${HAPTICS_BOARD:-sim}
material=${HAPTICS_MATERIAL:-materials/sponge.toml}
[ -f "$material" ] || { echo "up: HAPTICS_MATERIAL=$material: no such material file" >&2; exit 2; }
# the default object keeps the paths every document names; another gets folders of its own, so
# its recordings and models never mix with the sponge's (or another object's)
if [ "$(realpath "$material")" = "$(realpath materials/sponge.toml)" ]; then
  dataset=data/dataset models=models
else
  name=$(basename "$material" .toml)
  dataset=data/objects/$name/dataset models=models/objects/$name
fi

say() { printf '\n==> %s\n' "$*"; }

say "set-up: Python environment, ONNX Runtime library, page packages (first run: a few minutes)"
HAPTICS_NO_BROWSER=1 bash scripts/setup.sh
# shellcheck disable=SC1091
source scripts/env.sh

say "build (release): rt-loop, infer-server, hapticctl"
haptics_build

# A dataset recorded on another object (two material files of the same name, or an edited
# one) must not be trained on, nor its models served, as if it were this object's: each
# recording carries the material file's text in its metadata (`haptics.run`). The two are
# compared as tables, not as text (`haptics_train.data.same_object`): a comment edited, or
# `law = "foam"` written out where the file said nothing, is the same object. An ONNX object's
# graph is not in it: a graph replaced under the same material file goes unnoticed.
if [ -f "$dataset/test_2.1.parquet" ]; then
  .venv/bin/python - "$dataset/test_2.1.parquet" "$material" "$models" <<'PY' || exit 2
import json, sys, tomllib
import pyarrow.parquet as pq
from haptics_train.data import same_object
rec, mat, models = sys.argv[1:]
meta = pq.ParquetFile(rec).metadata.metadata or {}
run = json.loads(meta.get(b"haptics.run", b"{}"))
try:
    text = open(mat).read()
    tomllib.loads(text)
except (OSError, tomllib.TOMLDecodeError) as e:
    sys.exit(f"up: {mat}: not a material file ({e})")
if "material" in run and not same_object(run["material"], text):
    sys.exit(f"up: {rec} was recorded on another object than {mat} ({run.get('material_file')}, "
             f"or the file has changed since): move {rec.rsplit('/', 1)[0]} and {models} aside "
             f"to record and train on {mat}")
PY
fi
if [ ! -f "$dataset/test_2.1.parquet" ]; then
  say "record the dataset of $material in $dataset (ramp rates 0.8, 1.8, 3.9, 6.2 N/s, the 2.1 N/s test run, the bench in free air)"
  bash scripts/record-dataset.sh --material "$material" "$dataset"
fi

recommended() { # the recommended model's name, or nothing
  .venv/bin/python - "$models/recommendation.json" <<'PY' 2>/dev/null || true
import json, sys
doc = json.load(open(sys.argv[1]))
print(doc["recommended"])
PY
}
on=(--dataset "$dataset" --models-dir "$models")
if [ -z "$model" ]; then
  model=$(recommended)
  if [ -z "$model" ] || [ ! -f "$models/$model.onnx" ]; then
    say "train, evaluate and export the candidates ($candidates); recommend one on the validation run"
    .venv/bin/haptics-train train "${on[@]}" --models "$candidates" --no-progress
    .venv/bin/haptics-train evaluate "${on[@]}" --no-progress
    .venv/bin/haptics-train export "${on[@]}"
    model=$(recommended)
    [ -n "$model" ] || { echo "up: no model recommended (see $models/results.json)" >&2; exit 1; }
  fi
  say "serving the recommended model $model ($models/recommendation.json; HAPTICS_MODEL overrides)"
elif [ ! -f "$models/$model.onnx" ]; then
  case "$model" in
    sd_*|prony|structured*) spec=$model ;;
    *) spec="${model%_*}:${model##*_}" ;; # rf_six -> rf:six, dnn_fb_six -> dnn_fb:six
  esac
  say "train the default model $model (haptics-train train --models $spec, then export)"
  .venv/bin/haptics-train train "${on[@]}" --models "$spec"
  .venv/bin/haptics-train export "${on[@]}" --names "$model"
fi

pids=()
stop() {
  trap - INT TERM EXIT
  if [ ${#pids[@]} -gt 0 ]; then
    echo
    echo "up: stopping (current to zero, segment removed)"
    kill -INT "${pids[@]}" 2>/dev/null || true
    for pid in "${pids[@]}"; do wait "$pid" 2>/dev/null || true; done
  fi
  if ls /dev/shm/haptics-"$instance"* >/dev/null 2>&1; then
    echo "up: warning: a segment is left in /dev/shm: $(ls /dev/shm/haptics-"$instance"*)" >&2
    return 1
  fi
}
# Ctrl-C (or a TERM) is the normal way to end: both processes stop, and that is said plainly.
interrupted() {
  if stop; then echo "up: stopped"; exit 0; fi
  exit 1
}
trap interrupted INT TERM
trap stop EXIT

loop_args=(serve --clock realtime --instance "$instance" --board "$board" --material "$material")
bench="the simulated bench ($material)"
case "$board" in
  s826*)
    s826_lib=${HAPTICS_S826_LIB:-}
    if [ -z "$s826_lib" ] && ! ldconfig -p 2>/dev/null | grep -q lib826_64.so \
        && [ ! -f /usr/local/lib/lib826_64.so ]; then
      s826_lib=target/release/libs826_double.so
      watchdog=${HAPTICS_S826_WATCHDOG_US:-100000}
      # the double simulates the rig's object: the same one
      export S826_DOUBLE_MATERIAL=${S826_DOUBLE_MATERIAL:-$material}
      bench="the 826's C-ABI double (no lib826_64.so on this machine; the double simulates the rig)"
    else
      watchdog=${HAPTICS_S826_WATCHDOG_US:-}
      num=${board#s826}
      bench="the Sensoray 826 board number ${num#:}"
      [ -n "${num#:}" ] || bench="the Sensoray 826 board number 0"
    fi
    [ -n "$s826_lib" ] && loop_args+=(--s826-lib "$s826_lib")
    [ -n "$watchdog" ] && loop_args+=(--s826-watchdog-us "$watchdog")
    ;;
esac
[ -n "${HAPTICS_RIG:-}" ] && loop_args+=(--rig "$HAPTICS_RIG")
say "start rt-loop ($bench, realtime 10 kHz) and infer-server"
[ "$autostart" != none ] && loop_args+=(--autostart "$autostart")
target/release/rt-loop "${loop_args[@]}" &
pids+=($!)
target/release/infer-server serve --profile "$profile" --instance "$instance" --models "$models" \
  --model "$model.onnx" --grpc "$grpc" --http "$http" &
pids+=($!)

# Wait for the page to answer before printing its address; stop if either process died.
up=0
for _ in $(seq 1 300); do
  if (exec 3<>"/dev/tcp/${http%:*}/${http##*:}") 2>/dev/null; then up=1; break; fi
  for pid in "${pids[@]}"; do
    kill -0 "$pid" 2>/dev/null || { echo "up: a process failed to start (see above)" >&2; exit 1; }
  done
  sleep 0.1
done
if [ "$up" != 1 ]; then
  echo "up: the page did not answer on http://$http/ within 30 s" >&2
  exit 1
fi
# The page's address with the token (`#token=...`), from the connection file infer-server writes
# once it listens (docs/control-plane.md, "The connection file"); only this user can read it.
if [ -n "${XDG_RUNTIME_DIR:-}" ] && [ -d "${XDG_RUNTIME_DIR}" ]; then
  conn="$XDG_RUNTIME_DIR/haptics/$instance.json"
else
  conn="/tmp/haptics-$(id -u)/$instance.json"
fi
page="http://$http/"
for _ in $(seq 1 50); do
  if [ -f "$conn" ]; then
    page=$(.venv/bin/python -c 'import json, sys; print(json.load(open(sys.argv[1]))["page"])' "$conn") && break
  fi
  sleep 0.1
done
# The hapticctl line works as printed: the address is given when it is not hapticctl's default.
ctl=target/release/hapticctl
[ "$grpc" = 127.0.0.1:50051 ] || ctl+=" --addr http://$grpc"
cat <<EOF

  The system is up on $bench.
    page:      $page
    gRPC:      $grpc   ($ctl status --watch)
    model:     $model ($models/), experiment: $autostart
  Ctrl-C stops both.
EOF
wait -n "${pids[@]}" || true
echo "up: a process ended on its own (see its lines above); stopping the other" >&2
exit 1
