# Sourced by the recording scripts (record-dataset.sh, record-ood.sh): their shared options and
# the one way a recording is made, so the two cannot drift apart.
#
# Before sourcing, the script sets `who` (its name in messages); --help prints its header
# comment (up to `set -euo pipefail`). It calls `record_setup DEFAULT_OUT "$@"`, then uses:
#   material, bench_args    the simulated object and the bench file (--material, --bench)
#   out                     the output folder (the first remaining argument, else DEFAULT_OUT)
#   record_run NAME SEED ARGS...   records $out/NAME.parquet with `rt-loop run ARGS` on the
#                                  lockstep clock at 10 kHz, unless the file exists; a run
#                                  that stops early leaves $out/.NAME.partial.parquet instead
#                                  and ends the script (exit 1)
# and the environment: DECIMATE (default 1: every step), HAPTICS_RT_LOOP (an rt-loop binary
# to use instead of building one).

# shellcheck disable=SC2034  # material, bench_args, rest and decimate are the caller's
record_options() {
  material=materials/sponge.toml
  bench_args=()
  while [ $# -gt 0 ]; do
    case "$1" in
      --material) material=${2:?--material needs a file}; shift 2 ;;
      --bench) bench_args=(--bench "${2:?--bench needs a file}"); shift 2 ;;
      -h|--help) sed -n "2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}" "$0"; exit 0 ;;
      -*) echo "$who: unknown option $1" >&2; exit 2 ;;
      *) break ;;
    esac
  done
  [ -f "$material" ] || { echo "$who: no material file $material" >&2; exit 2; }
  rest=("$@")
  decimate=${DECIMATE:-1}
}

# The start of every recording script: from the repository root (where relative paths are
# read, whatever folder the script was run from), its options, its output folder `out` (made)
# and the rt-loop binary `bin`.
record_setup() { # default_out script-args...
  local default_out=$1
  shift
  cd "$(dirname "${BASH_SOURCE[0]}")/.."
  record_options "$@"
  out=${rest[0]:-$default_out}
  mkdir -p "$out"
  record_build
}

# Builds rt-loop (the project's one build command) and sets `bin`; with HAPTICS_RT_LOOP set,
# that binary is used as it is (a frozen copy: long recordings while the tree is rebuilt).
record_build() {
  # shellcheck disable=SC1091
  source scripts/env.sh
  if [ -n "${HAPTICS_RT_LOOP:-}" ]; then
    bin=$HAPTICS_RT_LOOP
    [ -x "$bin" ] || { echo "$who: HAPTICS_RT_LOOP=$bin is not an executable" >&2; exit 2; }
    return
  fi
  haptics_build
  bin=target/release/rt-loop
}

record_run() { # name seed rt-loop-run-args...
  local name=$1 seed=$2
  shift 2
  local file="$out/$name.parquet"
  if [ -f "$file" ]; then
    echo "$who: $file exists, skipped"
    return
  fi
  local t0=$SECONDS rc=0
  "$bin" run --clock lockstep --rate-hz 10000 --seed "$seed" --material "$material" \
    "${bench_args[@]}" --decimate "$decimate" --record "$file" --no-progress "$@" || rc=$?
  if [ "$rc" != 0 ]; then
    # A run that stopped early (rt-loop's `stop:` line above says why) must not pass for a
    # recording: the next run would skip it as done. Its rows are kept, out of the dataset's
    # way (the loaders read train_*/validation_*/test_*, not hidden files).
    if [ -f "$file" ]; then
      mv -f "$file" "$out/.$name.partial.parquet"
      echo "$who: $name did not finish (rt-loop exit $rc, stop line above); its rows so far are in $out/.$name.partial.parquet, not used; $file not written" >&2
    else
      echo "$who: $name did not finish (rt-loop exit $rc, above); nothing recorded" >&2
    fi
    exit 1
  fi
  echo "$who: $file: $(du -h "$file" | cut -f1), $((SECONDS - t0)) s"
}
