"""The reproduction study of the thesis (sections 6.4.3 and 6.4.4) on the simulated bench.

The same simulated hand (rt-loop's `[hand]`, a press-hold-release programme) presses

- the simulated real sponge through a transparent motor (`shadow`): the reference felt force;
- the virtual sponge rendered by each served ONNX model (`reproduction --model shm` beside
  `infer-server serve`), and by rt-loop's built-in spring-damper.

"Felt force" is the recording's `F_true`: in reproduction and shadow it is the force the
simulated hand pushes with (docs/rt-loop.md), the same quantity on both sides. Both runs use
the lockstep clock and the same seed, so the hand's programme and the loop's time grid are the
same; the felt forces are compared at the reference's time stamps (R2, MAE, MSE, RMSE).

Beside it, the thesis's own 6.4.4 comparison: the model predicting along the real interaction
(`shadow --model shm`: F_pred, built from the model's own previous predictions, against the
simulated object's own force F_object, like with like: the hand's F_true also carries the
bench's friction and mass, which a model of the object does not predict), and the
position-replay validation of 6.4.3: a recorded trajectory replayed with the position PID on
the simulated sponge, its force against the recording's.

The package, one module per concern (each imports only those listed before it):

- `protocol`: the thesis's numbers, the goals, the hands, the model groups;
- `processes`: one rt-loop run (and infer-server beside it), its summary and recording;
- `score`: alignment, metrics, and the picks made from them (best model, floor);
- `plot`: the figures;
- `report`: docs/study/README.md, results.json, the study's docs/fidelity.json keys;
- `run`: the study itself, in order (`run_study`), used by `haptics-train study`.
"""

from __future__ import annotations

from .processes import Run, Tools, find_tools, read_series, run_loop, write_config
from .protocol import (
    BUILTIN,
    DEFAULT_MATERIAL,
    FAST_HAND,
    FIDELITY_KEYS,
    ORACLE,
    SPRING_DAMPERS,
    STUDY_HAND,
    StudyError,
)
from .report import write_fidelity
from .run import clean_work, run_study, study_models
from .score import Row, align, compare, ratio

__all__ = [
    "BUILTIN",
    "DEFAULT_MATERIAL",
    "FAST_HAND",
    "FIDELITY_KEYS",
    "ORACLE",
    "SPRING_DAMPERS",
    "STUDY_HAND",
    "Row",
    "Run",
    "StudyError",
    "Tools",
    "align",
    "clean_work",
    "compare",
    "find_tools",
    "ratio",
    "read_series",
    "run_loop",
    "run_study",
    "study_models",
    "write_config",
    "write_fidelity",
]
