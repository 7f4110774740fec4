"""Which recorded truth a comparison uses (docs/recording-format.md, "Which truth to compare
with").

A simulated recording holds two truths. `F_true` is the felt force, what pushes the probe from
outside: with the simulated hand (shadow, reproduction) the hand's force, which carries, besides
the object's force, the bench's friction (up to its 1 N breakaway force while the probe rests)
and the motor's mass. `F_object` is the simulated object's own force. A model of the object
(every model train/ fits) is compared with `F_object`; a felt force (the study's reproduction
against its reference) with `F_true`.

Recordings made before rt-loop wrote `F_object` lack it. Without a hand the two truths are the
same quantity, so `F_true` stands in exactly; on a hand run it does not, and every caller says
so in its report (the `note`), never silently.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

#: the simulated object's own force on the probe (NaN where the bench has no object of its own)
OBJECT_FORCE = "F_object"
#: the felt force: the simulated hand's, or the object's where there is no hand
FELT_FORCE = "F_true"


@dataclass(frozen=True)
class Truth:
    """The column an object-only model is compared with, and why when it is not F_object."""

    column: str | None
    note: str = ""

    @property
    def is_object(self) -> bool:
        return self.column == OBJECT_FORCE


def object_truth(columns: Mapping[str, np.ndarray], name: str, hand: bool) -> Truth:
    """The object's own force in a recording's `columns` (`name` for the note): `F_object` when
    it holds a value; else `F_true` with a note saying what it stands for (exactly the object's
    force without a hand, the felt force on a hand run); None when neither is there (a real
    or imported recording)."""
    f = columns.get(OBJECT_FORCE)
    if f is not None and np.isfinite(np.asarray(f, dtype=np.float64)).any():
        return Truth(OBJECT_FORCE)
    if FELT_FORCE not in columns:
        return Truth(None, f"{name}: no simulated truth (neither {OBJECT_FORCE} nor {FELT_FORCE})")
    why = "no F_object column (recorded before it existed)" if f is None else "F_object is NaN"
    if hand:
        what = "the felt force F_true, which on a hand run also carries the friction and mass"
    else:
        what = "F_true, the same force without a hand"
    return Truth(FELT_FORCE, f"{name}: {why}; compared with {what}")


#: rt-loop experiments in which the simulated hand presses the probe
HAND_EXPERIMENTS = ("shadow", "reproduction")


def is_hand_run(meta: Mapping, name: str = "") -> bool:
    """Whether a recording's run metadata (`haptics.run`) says the simulated hand pressed (or,
    without metadata, its name is one of the OOD suite's hand presses, hand_*)."""
    run = meta.get("haptics.run")
    if isinstance(run, Mapping) and "experiment" in run:
        return run["experiment"] in HAND_EXPERIMENTS
    return name.startswith("hand_")
