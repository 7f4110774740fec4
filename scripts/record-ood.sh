#!/usr/bin/env bash
# Records the out-of-distribution suite (issue 11, item 4): what the training recordings
# (force ramps at 0.8-6.2 N/s, F_max 1, 2, ... 14 N in order) never show a model.
#   fmax_shuffled   F_max in a shuffled order (cycle_no no longer encodes the peak), 2.1 N/s
#   minor_loops     partial unloads: from F_max down to half and back, twice per cycle
#   long_holds      20 s holds at F_max (relaxation) and at 0 N (recovery)
#   ramp_0.4        ramp rate 0.4 N/s (below the training range)
#   ramp_12         ramp rate 12 N/s (above it)
#   position_presses  position-controlled presses (cosine presses to 10-24 mm, the PID)
#   hand_*          the simulated hand pressing the object through the transparent motor
#                   (shadow): slow/fast presses, a soft and a stiff hand. Their target is the
#                   felt force F_true (in shadow the RFOB is held near 0 N by the force loop).
# Every recording: lockstep clock at 10 kHz, seed 11.., the material and bench file given.
#
# Usage: scripts/record-ood.sh [--material FILE] [--bench FILE] [OUTDIR=data/ood]
# Env:   DECIMATE (default 1). Existing files are kept (delete one to record it again).
set -euo pipefail
who=record-ood
# shellcheck source=scripts/record-lib.sh
source "$(dirname "$0")/record-lib.sh"
record_setup data/ood "$@"
start=$SECONDS

abstraction=(--experiment abstraction)
record_run fmax_shuffled 11 "${abstraction[@]}" --ramp-rate 2.1 \
  --f-max-list 7,2,12,5,14,1,9,4,11,3,13,6,10,8
record_run minor_loops 12 "${abstraction[@]}" --ramp-rate 2.1 --cycles 7 --f-max-start 2 \
  --f-max-step 2 --minor-loops 2 --minor-depth 0.5
record_run long_holds 13 "${abstraction[@]}" --ramp-rate 2.1 --cycles 4 --f-max-start 3 \
  --f-max-step 3 --hold-max 20 --hold-zero 20
record_run ramp_0.4 14 "${abstraction[@]}" --ramp-rate 0.4 --cycles 5 --f-max-start 2 \
  --f-max-step 3
record_run ramp_12 15 "${abstraction[@]}" --ramp-rate 12 --cycles 14 --f-max-start 1 \
  --f-max-step 1

# Position-controlled presses: a cosine press profile written as a trajectory (time, x).
traj="$out/position_presses.trajectory.csv"
awk 'BEGIN {
  print "time,position_x"; t = 0; dt = 0.01; pi = 3.141592653589793
  printf "%.4f,%.6f\n", t, 0
  n = split("0.010 0.018 0.024 0.014 0.022", depth, " ")
  n2 = split("1.0 2.0 0.6 3.0 1.5", len, " ")
  for (i = 1; i <= n; i++) {
    for (k = 1; k <= len[i] / dt; k++) { t += dt; printf "%.4f,%.6f\n", t, depth[i] * (0.5 - 0.5 * cos(pi * k * dt / len[i])) }
    t += 1.0; printf "%.4f,%.6f\n", t, depth[i]
    for (k = 1; k <= len[i] / dt; k++) { t += dt; printf "%.4f,%.6f\n", t, depth[i] * (0.5 + 0.5 * cos(pi * k * dt / len[i])) }
    t += 1.5; printf "%.4f,%.6f\n", t, 0
  }
}' > "$traj"
record_run position_presses 16 --experiment position-replay --trajectory "$traj"

# Hand presses: [hand] tables (rt-loop's HandConfig) of several speeds and stiffnesses.
hand() { # name seed stiffness damping press_s release_s depth_m
  local cfg="$out/$1.hand.toml"
  printf '[hand]\nstiffness = %s\ndamping = %s\npress_s = %s\nrelease_s = %s\nhold_s = 0.5\nrest_s = 0.5\ndepth_m = %s\ndepth_step_m = 0.003\nrepeats = 3\n' \
    "$3" "$4" "$5" "$6" "$7" > "$cfg"
  record_run "$1" "$2" --config "$cfg" --experiment shadow
}
hand hand_slow 17 1500 15 2.5 2.5 0.028
hand hand_fast 18 1500 15 0.3 0.3 0.028
hand hand_soft 19 600 8 1.0 1.0 0.040
hand hand_stiff 20 4000 30 1.0 1.0 0.026
du -ch "$out"/*.parquet | tail -1
echo "record-ood: suite in $((SECONDS - start)) s ($material${bench_args[*]:+, ${bench_args[*]}})"
