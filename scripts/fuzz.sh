#!/usr/bin/env bash
# Fuzzes the inputs that cross a trust boundary with libFuzzer (the cargo-fuzz targets in
# fuzz/): the shared-memory segment's header, rings and messages, the model contract, the
# recording and CSV readers, the loop's config. Then (unless --no-hostile) the hostile-writer
# system test for a minute.
#
#   scripts/fuzz.sh                      each target for 10 000 000 executions, hostile writer 60 s
#   scripts/fuzz.sh --runs N             each target for N executions
#   scripts/fuzz.sh --seconds S          each target for S seconds (the test command: a few)
#   scripts/fuzz.sh --runs N --seconds S whichever comes first
#   scripts/fuzz.sh ... TARGET...        only these targets
#   options: --no-hostile, --hostile-s S (default 60)
#
# Stable toolchain only (no nightly here): cargo-fuzz passes -Z flags (sanitizer coverage,
# AddressSanitizer), which RUSTC_BOOTSTRAP=1 allows on stable. libFuzzer itself is C++, built by
# the libfuzzer-sys crate: a C++ compiler is needed. What is missing is installed (cargo-fuzz
# from crates.io, g++ from apt when root); if that is impossible the script fails under CI=true
# and otherwise says SKIPPED and exits 0.
#
# Each target starts from its committed corpus (fuzz/corpus/TARGET, read only) and grows a
# working one in fuzz/work/TARGET (git-ignored); a crash leaves its input in
# fuzz/artifacts/TARGET/ and makes the script fail. Prints one line per target: executions,
# executions per second, corpus size, crashes.
set -euo pipefail
cd "$(dirname "$0")/.."

runs=
seconds=0
hostile=1
hostile_s=60
targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --runs) runs=$2; shift 2 ;;
    --seconds) seconds=$2; shift 2 ;;
    --no-hostile) hostile=0; shift ;;
    --hostile-s) hostile_s=$2; shift 2 ;;
    -h|--help) sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$0"; exit 0 ;;
    -*) echo "fuzz.sh: unknown option $1" >&2; exit 2 ;;
    *) targets+=("$1"); shift ;;
  esac
done
# Default 10 million executions, unless only a time budget was given.
if [ -z "$runs" ]; then
  if [ "$seconds" != 0 ]; then runs=0; else runs=10000000; fi
fi

skip_or_fail() {
  if [ "${CI:-}" = "true" ]; then
    echo "fuzz.sh: FAILED: $1 (CI=true: a test that cannot run fails)" >&2
    exit 1
  fi
  echo "fuzz.sh: SKIPPED: $1"
  # In libtest's words, so scripts/test.sh counts the targets as skipped.
  echo "test result: ok. 0 passed; 0 failed; $(grep -c '^\[\[bin\]\]' fuzz/Cargo.toml) ignored (fuzz targets)"
  exit 0
}

if ! command -v c++ >/dev/null && ! command -v g++ >/dev/null && ! command -v clang++ >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get install -y -q g++ >/dev/null || skip_or_fail "no C++ compiler for libFuzzer and apt-get install g++ failed"
  else
    skip_or_fail "no C++ compiler for libFuzzer (install g++ or clang++)"
  fi
fi
if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "fuzz.sh: installing cargo-fuzz (crates.io)"
  cargo install cargo-fuzz --locked --quiet || skip_or_fail "cannot install cargo-fuzz"
fi

export RUSTC_BOOTSTRAP=1
# -O: optimised; -a: with debug assertions and overflow checks (an overflow is a finding).
flags=(-O -a)
cargo fuzz build "${flags[@]}"
bin_dir="fuzz/target/$(rustc -vV | sed -n 's/^host: //p')/release"
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <(cargo fuzz list)
fi

status=0
passed=0
failed=0
printf '%-16s %14s %10s %8s %8s  %s\n' target executions exec/s corpus crashes result
# A time-only run (the test command's) starts from the committed seeds alone, in a fresh
# working corpus: what a long run grew (slow inputs included) does not come into it.
work=fuzz/work
if [ "$runs" = 0 ]; then
  work=fuzz/work/short
  rm -rf "$work"
fi
# The targets' scratch files (fuzz/src/lib.rs) go into one directory of this run, removed
# however the script ends: libFuzzer exits without running destructors, so the targets cannot
# clean up after themselves, and nothing named haptics-fuzz-* may stay in /dev/shm.
scratch_root=/dev/shm
[ -d "$scratch_root" ] && [ -w "$scratch_root" ] || scratch_root=${TMPDIR:-/tmp}
HAPTICS_FUZZ_SCRATCH=$(mktemp -d "$scratch_root/haptics-fuzz-XXXXXX")
export HAPTICS_FUZZ_SCRATCH
trap 'rm -rf "$HAPTICS_FUZZ_SCRATCH"' EXIT
for t in "${targets[@]}"; do
  mkdir -p "$work/$t" "fuzz/corpus/$t" "fuzz/artifacts/$t"
  log="$work/$t.log"
  before=$(find "fuzz/artifacts/$t" -type f | wc -l)
  args=(-print_final_stats=1 -rss_limit_mb=2048 -timeout=10)
  [ "$runs" != 0 ] && args+=("-runs=$runs")
  [ "$seconds" != 0 ] && args+=("-max_total_time=$seconds")
  # The binary cargo fuzz built above, run directly: no rebuild between targets.
  if "$bin_dir/$t" "${args[@]}" -artifact_prefix="fuzz/artifacts/$t/" \
    "$work/$t" "fuzz/corpus/$t" >"$log" 2>&1; then
    result=ok
    passed=$((passed + 1))
  else
    result="FAILED (see $log)"
    status=1
    failed=$((failed + 1))
  fi
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  corpus=$(find "$work/$t" -type f | wc -l)
  crashes=$(( $(find "fuzz/artifacts/$t" -type f | wc -l) - before ))
  printf '%-16s %14s %10s %8s %8s  %s\n' "$t" "${execs:-?}" "${rate:-?}" "$corpus" "$crashes" "$result"
done

# In libtest's words, so scripts/test.sh counts the targets.
echo "test result: $([ $failed = 0 ] && echo ok || echo FAILED). $passed passed; $failed failed; 0 ignored (fuzz targets)"

if [ "$hostile" = 1 ]; then
  echo "fuzz.sh: hostile-writer system test for ${hostile_s} s"
  # the binaries the test starts, built as every script builds them (scripts/env.sh)
  source scripts/env.sh
  haptics_build
  log=fuzz/work/hostile_writer.log
  mkdir -p fuzz/work
  if HAPTICS_HOSTILE_S=$hostile_s cargo test --release -p haptics-system-tests \
    --test hostile_writer -- --nocapture >"$log" 2>&1; then
    grep -E "^hostile writer:" "$log"
  else
    echo "fuzz.sh: hostile-writer test FAILED (see $log)"
    status=1
  fi
fi
exit $status
