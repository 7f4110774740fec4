"""Feature names and named feature sets (docs/features.md, thesis Table 3.1 and Table 6.10).

"Previous force" everywhere in this package means the force response of the *previous control
step* of the loop (t-1 at the loop rate, 10 kHz on the simulated board), exactly as rt-loop
computes the features. Decimation for training only drops rows; it never changes what
"previous" means, so a model trained on every 20th row is fed the very feature definitions the
loop computes at every step when it is served. (In reproduction the previous force is the
model's own prediction of the previous control step; see `closed_loop`.)
"""

from __future__ import annotations

from dataclasses import dataclass

from .vocab import FEATURE_NAMES, THESIS_FEATURES

#: The nine features of thesis Table 3.1, in its order (docs/recording-format.md): the
#: vocabulary's (vocab.py, generated from proto/), never a copy.
NINE: tuple[str, ...] = THESIS_FEATURES

#: Table 3.1's three groups of three, by position in the vocabulary's order: the kinematics
#: (position, velocity, acceleration), the previous force divided by each of them, and the
#: cycle segmentation (cycle_no, deformation, area_fx).
KINEMATICS: tuple[str, ...] = NINE[0:3]
RATIOS: tuple[str, ...] = NINE[3:6]
CYCLE_FEATURES: tuple[str, ...] = NINE[6:9]

#: Ratio features: name -> the column it divides the previous force by. On a zero divisor the
#: ratio keeps its previous value (thesis code), which the closed loop reproduces.
RATIO_DIVISORS: dict[str, str] = dict(zip(RATIOS, KINEMATICS, strict=True))

#: Better-conditioned alternative to the ratios: the previous force itself, in N, the
#: vocabulary's one feature after the nine. Derived by train/ from the recording (`rtob_force`
#: one control step earlier); it is not a column rt-loop records, so a model using it needs a
#: loop that publishes it.
(F_PREVIOUS,) = FEATURE_NAMES[len(NINE) :]

#: Features built from the previous force (the ratios and f_previous).
PREVIOUS_FORCE_FEATURES: frozenset[str] = frozenset({*RATIO_DIVISORS, F_PREVIOUS})

#: Every feature rt-loop derives from the committed force: the previous-force features and
#: the cycle segmentation. In reproduction the committed force is the model's prediction, so
#: closed-loop evaluation rebuilds all of them.
FEEDBACK_FEATURES: tuple[str, ...] = (*RATIOS, *CYCLE_FEATURES, F_PREVIOUS)

TARGET_DEFAULT = "rtob_force"


@dataclass(frozen=True)
class FeatureSet:
    name: str
    features: tuple[str, ...]
    description: str

    @property
    def uses_feedback(self) -> bool:
        return any(f in FEEDBACK_FEATURES for f in self.features)


FEATURE_SETS: dict[str, FeatureSet] = {
    fs.name: fs
    for fs in (
        FeatureSet("six", NINE[:6], "the six selected features (thesis Tables 6.10, 6.15)"),
        FeatureSet("x", KINEMATICS[:1], "position only (Table 6.10 ablation)"),
        FeatureSet("x_v", KINEMATICS[:2], "position and velocity (Table 6.10)"),
        FeatureSet("nine", NINE, "all nine features of Table 3.1"),
        FeatureSet(
            "xva",
            KINEMATICS,
            "kinematics only: no force feedback (closed loop = one-step)",
        ),
        FeatureSet(
            "xva_f",
            (*KINEMATICS, F_PREVIOUS),
            "x, v, a and the previous force itself (well-conditioned alternative to the ratios)",
        ),
        FeatureSet(
            "memory",
            (*KINEMATICS, *CYCLE_FEATURES),
            "no previous force: kinematics plus the per-cycle memory features",
        ),
    )
}


def feature_set(name: str) -> FeatureSet:
    try:
        return FEATURE_SETS[name]
    except KeyError:
        known = ", ".join(FEATURE_SETS)
        raise ValueError(f"unknown feature set {name!r} (known: {known})") from None
