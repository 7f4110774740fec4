#!/usr/bin/env bash
# The conditions users create, measured against this machine's own floor (issue 14):
#   floor     two threads pass a message every 100 us through a shared-memory ring, spinning, on
#             the CPUs the product uses: misses per million at 50 us (tests/benches/machine_floor.rs)
#   in-process  ONNX Runtime's call of the default model, p50 (same bench)
#   the product: infer-server with its automatic profile, rt-loop on the simulated bench, the model
#   users get (the one models/recommendation.json names, as scripts/up.sh serves it; printed)
#   rendering in reproduction with the simulated hand, realtime 10 kHz:
#     idle      nothing else running
#     page      the page open in headless Chromium (web-ui/bench/page-cpu.mjs --hold)
#     hog       stress-ng on a CPU that is not the loop's (nor the inference thread's, when there is a third)
#     swap      100 hot swaps (hapticctl swap, two copies of the model alternately, SWAP_GAP_S apart),
#               each followed SWAP_GAP_S later by a control call that swaps nothing (hapticctl
#               status, the same kind of client): misses near swaps, near the control calls and
#               away from both (scripts/swap-windows.py), so that what a swap adds is told apart
#               from what any call costs on this host
#     idle:TUNED, page:TUNED  idle and page again with infer-server on another wait profile
#               (TUNED_PROFILE, default dedicated: the inference thread spins on a core of its own,
#               the best tuning on a machine with a core to spare; `none` skips them): the
#               product's default set beside the best tuning in one run
#     page:FAMILY  the page open again, one run per model family of scripts/bench-models.sh
#               (target/bench-models/families; FAMILY_SECONDS each, swapped in with hapticctl
#               1 s after the run starts: that second, on the previous model, counts too)
#   per condition: round trip p50/p99/p99.9, misses per million at 50 us, the steps of every
#   degradation level, the largest rendered-force change caused by a level change, and the
#   felt-force RMSE against the same hand programme rendered in lockstep.
# Prints a table, and as its last line one JSON object (the keys of issue 14).
#
# Usage: scripts/bench-loaded.sh            (a few minutes; builds what it needs)
# Env:   BENCH_SECONDS (per condition, default 20), FLOOR_SECONDS (default 20), SWAPS (100),
#        SWAP_GAP_S (the pause after each swap and each control call, default 0.15), BENCH_DIR (default target/bench-loaded), HAPTICS_MODEL (default: the model
#        models/recommendation.json recommends, else rf_six), FAMILIES_DIR (default
#        target/bench-models/families: the page:FAMILY rows; none when it is missing or empty),
#        FAMILY_SECONDS (default 10), TUNED_PROFILE (dedicated|period|shared|none),
#        HAPTICS_BOARD (the realtime runs' board: sim, default; or s826, on HAPTICS_S826_LIB, by
#        default the C-ABI double target/release/libs826_double.so simulating the same hand, its
#        watchdog HAPTICS_S826_WATCHDOG_US, default 100000; the lockstep references stay on sim;
#        a real card has no F_true, so the felt-force columns are NaN there).
#        BENCH_PREBUILT (a folder holding built rt-loop, infer-server, hapticctl and the floor
#        benchmark as machine_floor: nothing is built, installed or trained, for a machine without
#        cargo; the model must be in models/), BENCH_PAGE (1, default; 0 on a machine without
#        Chromium: no page rows, the JSON's page keys are null, and the run says so),
#        BENCH_PYTHON (the Python with numpy and pyarrow for the figures, default .venv/bin/python),
#        SERVER_ARGS (more infer-server flags for every server of the run, e.g. "--keep-awake off":
#        the JSON's `server_args` and `keep_awake` say what the default profile ran with).
#        Without stress-ng, BENCH_PREBUILT runs the hog as a Python busy loop pinned with taskset.
#        BENCH_RUNS (default 1): run the whole benchmark that many times in a row, then print
#        each key's values run by run and their median (scripts/bench-median.py); the last line
#        is then one JSON object with the same keys holding the medians, plus `runs` and
#        `per_run`. These machines are shared and noisy: quote medians of several runs.
# Spins both cores during the floor (a benchmark, never a test). Needs root or sudo only to
# install stress-ng (Debian: apt-get install -y stress-ng rt-tests) when it is missing.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
runs=${BENCH_RUNS:-1}
case "$runs" in
  '' | *[!0-9]* | 0) echo "bench-loaded: BENCH_RUNS must be a whole number >= 1, got '$runs'" >&2; exit 2 ;;
esac
if [ "$runs" -gt 1 ]; then
  # each run is the whole benchmark (BENCH_RUNS=1), in its own work folder under BENCH_DIR; a
  # run that fails stops the series
  exec python3 scripts/bench-median.py --runs "$runs" --label bench-loaded -- bash "$0"
fi
secs=${BENCH_SECONDS:-20}
swaps=${SWAPS:-100}
swap_gap=${SWAP_GAP_S:-0.15}
say() { printf '==> %s\n' "$*" >&2; }
prebuilt=${BENCH_PREBUILT:-}
page_on=${BENCH_PAGE:-1}
py=${BENCH_PYTHON:-.venv/bin/python}
bin=${prebuilt:-target/release}
# The model users get: the recommendation (scripts/up.sh serves the same), else rf_six.
recommended=$("$py" -c 'import json; print(json.load(open("models/recommendation.json"))["recommended"])' 2>/dev/null || true)
model=${HAPTICS_MODEL:-${recommended:-rf_six}}
if [ -n "${HAPTICS_MODEL:-}" ]; then
  say "model: $model (HAPTICS_MODEL)"
elif [ -n "$recommended" ]; then
  say "model: $model (the one models/recommendation.json recommends; HAPTICS_MODEL overrides)"
else
  say "model: $model (no models/recommendation.json; HAPTICS_MODEL overrides)"
fi
families_dir=${FAMILIES_DIR:-target/bench-models/families}
family_secs=${FAMILY_SECONDS:-10}
tuned=${TUNED_PROFILE:-dedicated}
case $tuned in dedicated|period|shared|none) ;; *) echo "bench-loaded: TUNED_PROFILE=$tuned: one of dedicated, period, shared, none" >&2; exit 2 ;; esac

# ---- tools ---------------------------------------------------------------------------------
if [ -z "$prebuilt" ] && { ! command -v stress-ng >/dev/null || ! command -v cyclictest >/dev/null; }; then
  say "installing stress-ng and rt-tests (apt-get)"
  sudo_=""
  [ "$(id -u)" = 0 ] || sudo_=sudo
  $sudo_ apt-get install -y stress-ng rt-tests >&2 || { $sudo_ apt-get update >&2 && $sudo_ apt-get install -y stress-ng rt-tests >&2; }
fi
if ! command -v stress-ng >/dev/null; then
  [ -n "$prebuilt" ] || { echo "bench-loaded: stress-ng is missing and could not be installed" >&2; exit 1; }
  say "no stress-ng: the hog is a Python busy loop pinned with taskset"
fi
if [ "$page_on" = 1 ]; then
  [ -x "${CHROMIUM_PATH:-/usr/bin/chromium}" ] || { echo "bench-loaded: no Chromium at ${CHROMIUM_PATH:-/usr/bin/chromium} (apt-get install -y chromium; BENCH_PAGE=0 skips the page rows)" >&2; exit 1; }
else
  say "BENCH_PAGE=0: no page rows (the page-open goal is not measured by this run)"
fi

# shellcheck disable=SC1091
source scripts/env.sh
if [ -z "$prebuilt" ]; then
  say "build (release): rt-loop, infer-server, hapticctl, the floor benchmark"
  haptics_build >&2
  cargo bench -p haptics-system-tests --bench machine_floor --no-run >&2
  [ "$page_on" != 1 ] || [ -d web-ui/node_modules/playwright-core ] || (cd web-ui && npm ci >&2)
fi
if [ ! -f "models/$model.onnx" ]; then
  [ -z "$prebuilt" ] || { echo "bench-loaded: no models/$model.onnx (BENCH_PREBUILT trains nothing)" >&2; exit 1; }
  say "no models/$model.onnx: recording the dataset and training it (as scripts/up.sh does)"
  [ -f data/dataset/test_2.1.parquet ] || bash scripts/record-dataset.sh data/dataset >&2
  case "$model" in
    sd_*|prony|structured*|lstm_slow) spec=$model ;;
    *) spec="${model%_*}:${model##*_}" ;; # rf_six -> rf:six, dnn_fb_six -> dnn_fb:six
  esac
  .venv/bin/haptics-train train --models "$spec" >&2
  .venv/bin/haptics-train export --names "$model" >&2
fi

work=${BENCH_DIR:-target/bench-loaded}/run-$(date +%Y%m%d-%H%M%S)
mkdir -p "$work/models"
cp "models/$model.onnx" "$work/models/$model.onnx"
cp "models/$model.onnx" "$work/models/${model}_b.onnx" # the same model under a second name: swaps
: >"$work/families.txt"
if [ -d "$families_dir" ] && [ "$page_on" = 1 ]; then
  for f in "$families_dir"/*.onnx; do
    [ -e "$f" ] || continue
    fam=$(basename "$f" .onnx)
    [ "$fam" = identity ] && continue
    cp "$f" "$work/models/family_$fam.onnx"
    echo "$fam" >>"$work/families.txt"
  done
fi
[ -s "$work/families.txt" ] || say "no model families in $families_dir (scripts/bench-models.sh makes them): no page:FAMILY rows"
instance="bench-loaded-$$"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -INT "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
}
trap cleanup EXIT

# ---- floor and in-process call --------------------------------------------------------------
say "machine floor (${FLOOR_SECONDS:-20} s, both cores spinning) and the in-process call"
floor_bench() {
  if [ -n "$prebuilt" ]; then "$bin/machine_floor" --bench; else cargo bench -q -p haptics-system-tests --bench machine_floor; fi
}
FLOOR_SECONDS=${FLOOR_SECONDS:-20} BENCH_MODEL="$root/models/$model.onnx" floor_bench 2>/dev/null | tee "$work/floor.txt" >&2
tail -n 1 "$work/floor.txt" > "$work/floor.json"

# ---- the product ----------------------------------------------------------------------------
read -r -a server_args <<<"${SERVER_ARGS:-}"
start_server() { # profile suffix: infer-server on $instance; sets server, grpc, http
  "$bin/infer-server" serve --instance "$instance" --models "$work/models" --model "$model.onnx" \
    --profile "$1" "${server_args[@]}" --grpc 127.0.0.1:0 --http 127.0.0.1:0 --stats-every 0 \
    >"$work/infer-server$2.out" 2>"$work/infer-server$2.err" &
  server=$!
  pids+=($server)
  for _ in $(seq 1 100); do grep -q "HTTP http" "$work/infer-server$2.out" && break; sleep 0.1; done
  grpc=$(sed -n 's/.*gRPC \([^ ]*\) HTTP.*/\1/p' "$work/infer-server$2.out")
  http=$(sed -n 's/.*HTTP \(http:[^ ]*\) .*/\1/p' "$work/infer-server$2.out")
  [ -n "$grpc" ] && [ -n "$http" ] || { cat "$work/infer-server$2.err" >&2; exit 1; }
  # The page needs the control plane's token: the address infer-server prints with it
  # (`page: http://...#token=...`), as a user opens it from scripts/up.sh's banner.
  page_url=""
  for _ in $(seq 1 50); do
    page_url=$(sed -n 's/.*page: \(http[^ ]*#token=[0-9a-zA-Z]*\).*/\1/p' "$work/infer-server$2.err" | head -1)
    [ -n "$page_url" ] && break
    sleep 0.1
  done
  [ -n "$page_url" ] || page_url=$http
  grep "profile" "$work/infer-server$2.err" >&2 || true
}
say "infer-server, automatic profile"
start_server auto ""
server_cpu=$(sed -n 's/.*wait [^,]*, CPU \([0-9]*\),.*/\1/p' "$work/infer-server.err" | head -1)
last_cpu=$(($(nproc) - 1))
# The hog takes a CPU that is neither the loop's nor the inference thread's when the machine has
# one; on two CPUs there is none, and it shares the inference thread's (the other work a user
# runs lands there).
hog_cpu=""
for c in $(seq 0 "$last_cpu"); do
  if [ "$c" != "${server_cpu:-0}" ] && [ "$c" != "$last_cpu" ]; then hog_cpu=$c; break; fi
done
if [ -z "$hog_cpu" ]; then
  hog_cpu=${server_cpu:-0}
  [ "$hog_cpu" = "$last_cpu" ] && hog_cpu=0
fi

# The simulated hand presses for 5 s per repetition (rt-loop's HandConfig); every run uses the
# same programme, long enough for the longest run (the swaps), and stops at its --duration.
hand_repeats=$(((secs > 60 ? secs : 60) / 5 + 1))
# Every press to the same depth (by default each presses 2 mm deeper: 13 of them would reach the
# position limit).
printf '# bench-loaded: the hand programme of every run\n[hand]\nrepeats = %d\ndepth_step_m = 0.0\n' \
  "$hand_repeats" >"$work/hand.toml"
# The realtime runs' board (HAPTICS_BOARD); the lockstep references always run on sim.
board=${HAPTICS_BOARD:-sim}
board_args=(--board "$board")
case "$board" in
  s826*)
    board_args+=(--s826-lib "${HAPTICS_S826_LIB:-target/release/libs826_double.so}"
      --s826-watchdog-us "${HAPTICS_S826_WATCHDOG_US:-100000}")
    export S826_DOUBLE_WORLD=hand
    ;;
esac
run_loop() { # name clock duration [extra rt-loop args]
  local name=$1 clock=$2 dur=$3
  shift 3
  [ "$clock" = realtime ] && set -- "${board_args[@]}" "$@"
  "$bin/rt-loop" run --config "$work/hand.toml" --experiment reproduction --clock "$clock" \
    --model shm --instance "$instance" --seed 1 --duration "$dur" --record "$work/$name.parquet" --overwrite \
    --summary-json "$work/$name.json" --no-progress "$@" >"$work/$name.out" 2>&1
}

page_condition() { # name page-cpu-output: a realtime run while the page is open in Chromium
  (cd web-ui && exec node bench/page-cpu.mjs --url "$page_url" --hold) >"$work/$2" 2>&1 &
  local page=$!
  pids+=($page)
  run_loop "$1" realtime "$secs" &
  local loop=$!
  wait "$loop"
  kill -USR2 "$page" 2>/dev/null || true # page-cpu.mjs reads Chromium's CPU, then closes it
  wait "$page" || true
}

say "references: the same hand programme rendered in lockstep, and on the simulated real sponge (shadow)"
run_loop lockstep lockstep 1000
"$bin/rt-loop" run --config "$work/hand.toml" --experiment shadow --clock lockstep --seed 1 \
  --record "$work/shadow.parquet" --overwrite --no-progress >"$work/shadow.out" 2>&1

say "idle ($secs s)"
run_loop idle realtime "$secs"

if [ "$page_on" = 1 ]; then
  say "page open in headless Chromium ($secs s)"
  page_condition page page-cpu.out
  cat "$work/page-cpu.out" >&2
fi

say "CPU hog ($(command -v stress-ng >/dev/null && echo stress-ng || echo a Python busy loop)) on CPU $hog_cpu, not the loop's CPU $last_cpu ($secs s)"
if command -v stress-ng >/dev/null; then
  stress-ng --cpu 1 --taskset "$hog_cpu" --timeout $((secs + 10))s >"$work/hog.stress.out" 2>&1 &
else
  taskset -c "$hog_cpu" timeout $((secs + 10)) "$py" -c 'while True: pass' >"$work/hog.stress.out" 2>&1 &
fi
hog=$!
pids+=($hog)
sleep 1
run_loop hog realtime "$secs"
kill -TERM "$hog" 2>/dev/null || true
wait "$hog" 2>/dev/null || true

say "$swaps hot swaps (hapticctl swap) during a realtime run"
run_loop swap realtime 1000 &
loop=$!
sleep 2
: >"$work/swaps.jsonl"
: >"$work/controls.jsonl"
for i in $(seq 1 "$swaps"); do
  if [ $((i % 2)) = 1 ]; then name="${model}_b"; else name="$model"; fi
  if ! "$bin/hapticctl" swap --addr "http://$grpc" --instance "$instance" --json "$name" >>"$work/swaps.jsonl"; then
    echo "bench-loaded: swap $i failed (see above); the loop ran $(tail -n 3 "$work/swap.out")" >&2
    break
  fi
  # Steps away from swaps, too: the figures compare misses within 50 ms of a swap with the
  # misses further away, so swaps must leave gaps longer than 100 ms (with 0.05 s here, as
  # before, swaps 63 ms apart left no step between them further than 50 ms from one, and the
  # only "away" steps were the 0.2 s before the first).
  sleep "$swap_gap"
  # The control: the same kind of client process and a gRPC call, no swap. Its answer carries
  # the loop's step (loop.step), where the figures centre its window.
  "$bin/hapticctl" status --addr "http://$grpc" --instance "$instance" --json >>"$work/controls.jsonl" ||
    echo "bench-loaded: control call $i failed (the swap figures use the others)" >&2
  sleep "$swap_gap"
done
sleep 0.5
# $loop is the subshell running run_loop: stop its rt-loop (SIGINT: the run ends at the next
# step, recording and summary complete).
pkill -INT -P "$loop" 2>/dev/null || true
wait "$loop" || true

if [ -s "$work/families.txt" ]; then
  say "page open, one run per model family ($family_secs s each)"
  (cd web-ui && exec node bench/page-cpu.mjs --url "$page_url" --hold) >"$work/page-cpu-families.out" 2>&1 &
  page=$!
  pids+=($page)
  while read -r fam; do
    # A swap needs an attached loop: the run starts on the previous model and swaps after 1 s
    # (that second is in the row's counts too).
    run_loop "page_$fam" realtime "$((family_secs + 1))" &
    loop=$!
    sleep 1
    "$bin/hapticctl" swap --addr "http://$grpc" --instance "$instance" --json "family_$fam" >/dev/null ||
      echo "bench-loaded: could not swap to the family $fam" >&2
    wait "$loop" || true
  done <"$work/families.txt"
  kill -USR2 "$page" 2>/dev/null || true
  wait "$page" || true
fi

if [ "$tuned" != none ]; then
  say "the best tuning: infer-server --profile $tuned, idle$([ "$page_on" != 1 ] || echo " and page open") ($secs s each)"
  kill -INT "$server" 2>/dev/null || true
  wait "$server" 2>/dev/null || true
  start_server "$tuned" "-$tuned"
  run_loop idle_tuned realtime "$secs"
  [ "$page_on" != 1 ] || page_condition page_tuned page-cpu-tuned.out
fi

# ---- figures ------------------------------------------------------------------------------
"$py" - "$work" "$swaps" "$model" "$tuned" "$page_on" <<'PY'
"""Reads the runs' summaries and recordings; prints the table and the JSON line."""
import json
import math
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

_spec = importlib.util.spec_from_file_location("swap_windows", "scripts/swap-windows.py")
swap_windows = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(swap_windows)

work = Path(sys.argv[1])
n_swaps = int(sys.argv[2])
served = sys.argv[3]
tuned = sys.argv[4]
page_on = sys.argv[5] == "1"
tuned_rows = [n for n in ("idle_tuned", "page_tuned") if (work / f"{n}.json").exists()]
families = [f for f in (work / "families.txt").read_text().split() if (work / f"page_{f}.json").exists()]
floor = json.loads((work / "floor.json").read_text())


def cols(name: str, names: list[str]) -> dict[str, np.ndarray]:
    t = pq.read_table(work / f"{name}.parquet", columns=names)
    return {n: t.column(n).to_numpy(zero_copy_only=False).astype(float) for n in names}


shadow = cols("shadow", ["time", "F_true"])
lock = cols("lockstep", ["time", "F_true"])


def rmse(run: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> float:
    """Felt force of `run` against `ref` at the run's time stamps (the reference interpolated)."""
    t = run["time"]
    keep = t <= ref["time"][-1]
    d = run["F_true"][keep] - np.interp(t[keep], ref["time"], ref["F_true"])
    return float(np.sqrt(np.mean(d * d)))


def within(ref: dict[str, np.ndarray], run: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """`ref`'s rows over `run`'s span of the hand programme (both start at its beginning)."""
    keep = ref["time"] <= run["time"][-1]
    return {k: v[keep] for k, v in ref.items()}


lock_vs_shadow = rmse(lock, shadow)
rows = {}
for name in ["idle", *(["page"] if page_on else []), "hog", "swap", *tuned_rows, *(f"page_{f}" for f in families)]:
    s = json.loads((work / f"{name}.json").read_text())
    rec = cols(name, ["step", "time", "F_true", "fallback"])
    steps = s["steps"]
    shm = s["shm"]
    lad = s.get("ladder") or {}
    rtt = s["round_trip_us"]
    late = shm["late"]
    row = {
        "steps": steps,
        "p50": rtt["p50"], "p99": rtt["p99"], "p999": rtt["p999"],
        "miss_pm": late * 1e6 / max(1, shm["sent"]),
        "on_time": lad.get("on_time"), "late_one": lad.get("late_one"),
        "held": lad.get("held"), "fallback": lad.get("fallback"),
        "max_step_n": s.get("max_transition_step_n"),
        "felt_vs_lockstep": rmse(rec, lock),
        "felt_vs_shadow": rmse(rec, shadow),
        # the lockstep reference's own error over the same span of the programme: a run of
        # BENCH_SECONDS against the whole lockstep programme would weigh other presses
        "lock_vs_shadow_same_span": rmse(within(lock, rec), shadow),
        "overruns": s["jitter"]["overruns"] if s.get("jitter") else None,
    }
    if lad:
        row["late_fraction"] = (lad["held"] + lad["fallback"]) / max(1, steps)
    else:
        row["late_fraction"] = None
    if name == "swap":
        # Lost: steps not in the recording, not sent, or answered without a model's force.
        recorded = rec["step"]
        gaps = int(steps - len(recorded)) + int(np.sum(np.diff(recorded) != 1))
        row["lost"] = gaps + (steps - shm["sent"]) + shm["flagged"] + shm["no_server"] + shm["ring_full"]
        eff = []
        for line in (work / "swaps.jsonl").read_text().splitlines():
            if line.strip():
                eff.append(int(json.loads(line)["effective_step"]))
        ctl = []
        for line in (work / "controls.jsonl").read_text().splitlines():
            if line.strip():
                ctl.append(int((json.loads(line).get("loop") or {}).get("step", 0)))
        # Sequence numbers count from 1 per run, one per sent step (the status's step likewise).
        change = [e - 1 for e in eff if 0 < e - 1 < len(recorded)]
        control = [c - 1 for c in ctl if 0 < c - 1 < len(recorded)]
        # 50 ms at 10 kHz either side; the run's start left out up to 200 ms before the first
        sw_fig = swap_windows.swap_windows(rec["fallback"] != 0, change, control, window=500, lead=2000)
        row.update(sw_fig)
        row["swaps_done"] = len(eff)
        row["swaps_in_run"] = len(change)
        row["controls_in_run"] = len(control)
    rows[name] = row

def page_cpu_of(name: str) -> float | None:
    """Chromium's CPU per second from page-cpu.mjs's JSON line; None when the page never
    loaded (no line: the script failed, e.g. refused without the control plane's token)."""
    f = work / name
    for line in (f.read_text().splitlines() if f.exists() else []):
        if line.startswith("{"):
            return json.loads(line).get("visible_cpu_per_s")
    return None


page_cpu = page_cpu_of("page-cpu.out")
page_cpu_tuned = page_cpu_of("page-cpu-tuned.out") if "page_tuned" in tuned_rows else None


def f(x, d=2):
    return "n/a" if x is None else (f"{x:.{d}f}" if isinstance(x, float) else str(x))


print(f"bench-loaded ({work}); model {served}; load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
print(f"machine floor: {floor['floor_round_trips']} round trips, p50 {floor['floor_p50_us']:.2f} us p99.9 {floor['floor_p999_us']:.2f} us, misses {floor['floor_miss_pm']:.0f} per million")
print(f"in-process ONNX Runtime call: p50 {floor['inprocess_p50_us']:.2f} us")
print(f"lockstep reference vs shadow (the model's own felt-force error): {lock_vs_shadow:.4f} N RMS over its whole programme"
      + (f", {rows['page']['lock_vs_shadow_same_span']:.4f} N over the page run's span" if page_on else ""))
hdr = ["condition", "steps", "rtt p50", "p99", "p99.9 us", "miss/M", "on_time", "late_one", "held", "fallback", "late frac", "max step N", "felt vs lockstep N", "felt vs shadow N"]
print(" | ".join(hdr))
for name, r in rows.items():
    label = name.replace("_tuned", f":{tuned}") if name in tuned_rows else name.replace("page_", "page:", 1)
    print(" | ".join([label, str(r["steps"]), f(r["p50"]), f(r["p99"]), f(r["p999"]), f(r["miss_pm"], 0),
                      f(r["on_time"]), f(r["late_one"]), f(r["held"]), f(r["fallback"]), f(r["late_fraction"], 5),
                      f(r["max_step_n"], 4), f(r["felt_vs_lockstep"], 4), f(r["felt_vs_shadow"], 4)]))
sw = rows["swap"]
print(f"swaps: {sw['swaps_done']} done, {sw['swaps_in_run']} inside the run; lost steps {sw['lost']}; misses per step within 50 ms of a swap {sw['miss_near']:.2e} ({sw['misses_near']} in {sw['steps_near']} steps), of a control call that swaps nothing {sw['miss_control']:.2e} ({sw['misses_control']} in {sw['steps_control']}; {sw['controls_in_run']} calls), away from both {sw['miss_away']:.2e} ({sw['misses_away']} in {sw['steps_away']})")
print(f"swap miss ratio {sw['swap_miss_ratio']:.2f} (near a swap over away); control call's {sw['swap_control_ratio']:.2f}; swap over control {sw['swap_over_control']:.2f} (what the swap adds beyond any call)")
if page_cpu is not None:
    print(f"page: headless Chromium used {page_cpu:.3f} CPU-s per s")
if page_cpu_tuned is not None:
    print(f"page ({tuned}): headless Chromium used {page_cpu_tuned:.3f} CPU-s per s")
# issue 14's key covers the product's conditions (the served model); the family rows (small
# models of every family, swapped in) have their own
maxstep = [r["max_step_n"] for n, r in rows.items() if r["max_step_n"] is not None and n in ("idle", "page", "hog", "swap")]
out = {
    "floor_miss_pm": floor["floor_miss_pm"],
    "inprocess_p50_us": floor["inprocess_p50_us"],
    "idle_p50_us": rows["idle"]["p50"],
    "idle_miss_pm": rows["idle"]["miss_pm"],
    "page_late_fraction": rows["page"]["late_fraction"] if page_on else None,
    "hog_late_fraction": rows["hog"]["late_fraction"],
    "max_transition_step_n": max(maxstep) if maxstep else None,
    # over the same span of the hand programme (before 2026-11-28 04:30 UTC: over lockstep's
    # whole programme, 66 s against the page run's 20 s; docs/infer-server.md)
    "felt_rmse_page_over_lockstep": rows["page"]["felt_vs_shadow"] / rows["page"]["lock_vs_shadow_same_span"]
    if page_on and rows["page"]["lock_vs_shadow_same_span"] > 0 else None,
    "swap_lost_steps": sw["lost"],
    "swap_miss_ratio": sw["swap_miss_ratio"] if math.isfinite(sw["swap_miss_ratio"]) else None,
    # the same near a control call that swaps nothing, and the swap's over the control's
    # (scripts/swap-windows.py): the host's share of swap_miss_ratio told apart from the swap's
    "swap_control_ratio": sw["swap_control_ratio"] if math.isfinite(sw["swap_control_ratio"]) else None,
    "swap_over_control": sw["swap_over_control"] if math.isfinite(sw["swap_over_control"]) else None,
    "model": served,
    "idle_late_fraction": rows["idle"]["late_fraction"],
    "family_page_late_fraction": {f: rows[f"page_{f}"]["late_fraction"] for f in families},
    "family_max_transition_step_n": {f: rows[f"page_{f}"]["max_step_n"] for f in families},
    # the best tuning beside the default (TUNED_PROFILE; absent with none)
    "tuned_profile": tuned if tuned_rows else None,
    "tuned_idle_late_fraction": rows["idle_tuned"]["late_fraction"] if "idle_tuned" in rows else None,
    "tuned_page_late_fraction": rows["page_tuned"]["late_fraction"] if "page_tuned" in rows else None,
    "tuned_idle_p50_us": rows["idle_tuned"]["p50"] if "idle_tuned" in rows else None,
}
out["page_loaded"] = page_cpu is not None
# what the default profile's server ran with (its start-up line: docs/infer-server.md)
out["server_args"] = os.environ.get("SERVER_ARGS", "")
out["keep_awake"] = "kept awake" in (work / "infer-server.err").read_text()
if not page_on:
    print("no page rows (BENCH_PAGE=0): the page-open keys are null; this run does not measure them")
print(json.dumps(out))
if page_on and page_cpu is None:
    # the page condition ran without a page: its figures are an idle run's, not the goal's
    print("bench-loaded: the page never loaded in Chromium (see page-cpu.out): the page row measured no page", file=sys.stderr)
    sys.exit(1)
PY
