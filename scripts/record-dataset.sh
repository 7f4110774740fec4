#!/usr/bin/env bash
# Records the training and test dataset on the simulated sponge bench (docs/physics.md, "The
# experiments"): ramp rates 0.8, 1.8, 3.9, 6.2 N/s (train) and 2.1 N/s (test), 14 cycles each,
# F_max from 1 N in 1 N steps up to 14 N, lockstep clock at 10 kHz, seed 1 (test: seed 2); and
# a validation recording at 5.0 N/s (seed 3); and `train_air`, the bench alone: the free-air
# sweeps of `rt-loop identify-friction` (x < 0, 0.5-60 mm/s each way, 67 s) replayed by the
# position controller and recorded (`rt-loop run --friction-sweep`). Inside the object the
# bench's friction and the object's damping add up in the RFOB's force and no fit can tell them
# apart; out of contact the force is the bench's alone, so the models that identify the
# friction beside the object (structured, lawfree) are told which is which. Any rig can record
# it (the probe moved away from the object). Spring-dampers fit contact rows only.
# With PRESSES=1, also `train_hold` and `validation_hold`: presses at a hand's speeds (peaks
# of 10, 40 and 80 mm/s) to five depths (0.25-0.95 of the ramps' deepest compression), each
# held 1.5-3.5 s, driven by the position controller (`haptics-train presses`, then `rt-loop run
# --experiment position-replay`; two programmes, seeds 5 and 6). Only the models asked for
# with `+holds` (`structured+holds`, ...: holds.py) train on them; scripts/fidelity-study.sh
# records them and trains its candidates both ways. Off by default: trained on by every model
# they made the recommended model's felt force closer on some objects and further on others
# (docs/laws.md, "Presses and holds at a hand's speeds in training" and "Presses and holds in
# training again"). Needs the project's .venv (setup.sh).
#
# Usage: scripts/record-dataset.sh [--material FILE] [--bench FILE] [OUTDIR=data/dataset]
#        --material: the simulated object (default materials/sponge.toml; e.g. materials/foam-b.toml)
#        --bench: bench file of `rt-loop identify-friction` (the RFOB subtracts its friction model;
#        default none, as the thesis code); both are written into each recording's metadata.
# Env:   DECIMATE (default 1: every step, lossless, ~575 MB for the seven files; 2 halves that:
#        5 kHz rows, ~290 MB; the loop and its online features always run at 10 kHz),
#        SEED (default 1; the test recording uses SEED + 1), PRESSES (default 0; 1 adds the
#        two press-and-hold recordings above, ~145 MB at DECIMATE=1).
# Existing files are kept (delete one to record it again). A run that stops before its end
# (rt-loop's stop line says why) leaves its rows in OUTDIR/.NAME.partial.parquet, not used,
# and ends the script with exit 1; the next run records NAME again.
set -euo pipefail
who=record-dataset
# shellcheck source=scripts/record-lib.sh
source "$(dirname "$0")/record-lib.sh"
record_setup data/dataset "$@"
seed=${SEED:-1}

record() { # name ramp_rate seed
  record_run "$1" "$3" --experiment abstraction --ramp-rate "$2" --cycles 14 --f-max-start 1 \
    --f-max-step 1
}

record train_0.8 0.8 "$seed"
record train_1.8 1.8 "$seed"
record train_3.9 3.9 "$seed"
record train_6.2 6.2 "$seed"
record test_2.1 2.1 $((seed + 1))
# validation: a ramp rate neither trained nor tested on; haptics-train makes every choice
# (feedback noise, the recommended model) on it, so the test is scored once
record validation_5.0 5.0 $((seed + 2))
# the bench alone, out of contact (above): training data of the bench's friction
record_run train_air "$seed" --friction-sweep
# PRESSES=1: presses and holds at a hand's speeds, scaled by the ramps above (presses.py says
# why): one programme to train on, another (its own order and holds) to validate on
presses() { # name programme-seed loop-seed
  if [ ! -f "$out/$1.parquet" ]; then
    [ -x .venv/bin/haptics-train ] || { echo "$who: .venv/bin/haptics-train missing (bash scripts/setup.sh)" >&2; exit 2; }
    .venv/bin/haptics-train presses --dataset "$out" --seed "$2" --out "$out/.presses.parquet"
  fi
  record_run "$1" "$3" --experiment position-replay --trajectory "$out/.presses.parquet"
  rm -f "$out/.presses.parquet"
}
if [ "${PRESSES:-0}" = 1 ]; then
  presses train_hold 5 "$seed"
  presses validation_hold 6 $((seed + 2))
fi
du -ch "$out"/*.parquet | tail -1
