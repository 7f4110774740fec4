"""The press-and-hold recordings as a training choice: `+holds` in a model spec.

`PRESSES=1 scripts/record-dataset.sh` adds `train_hold` and `validation_hold` to a dataset:
presses at a hand's speeds (10-80 mm/s) to five depths, each held for seconds, played by the
position controller (presses.py). They show a model what force ramps at a few mm/s cannot: an
object's damping and its fast relaxation at a hand's speeds. They can also mislead a fit: on a
memory foam the compression-set law fitted to the holds grew and recovered in 0.3 and 5.5 s
instead of 2 and 47 s, and every model felt the foam 2-3x further (docs/laws.md, "Presses and
holds in training again").

So whether a model learns from them is a choice among candidates, made where every other
choice between model families is made: by the felt force of the study's ranking runs. A spec
ending in `+holds` (`structured+holds`, `lawfree+holds`) trains on every recording of the
dataset and makes its validation choices on both validation recordings; its name ends in
`_holds`. Any other model never sees a hold recording, in training or in its choices, so it is
the model it would be on the dataset without them. Only the models the study chooses among
take the suffix (`HOLDS_ALGOS`)."""

from __future__ import annotations

from dataclasses import replace

from .data import Dataset, Recording

#: The spec suffix of a model trained on the press-and-hold recordings too.
HOLDS_SPEC = "+holds"
#: What that suffix adds to the model's name (its files, its rows in every table).
HOLDS_NAME = "_holds"
#: The models that take it: the candidates the study's ranking runs choose among.
HOLDS_ALGOS = ("structured", "structured_path", "structured_hyst", "lawfree")
#: The hyperparameter that carries the choice inside a model (saved with it).
HOLDS_KEY = "train_holds"


def split_spec(spec: str) -> tuple[str, bool]:
    """(the spec without `+holds`, whether it had it)."""
    s = spec.strip()
    if s.endswith(HOLDS_SPEC):
        return s[: -len(HOLDS_SPEC)].strip(), True
    return s, False


def spec_algo(spec: str) -> str:
    """The algorithm of a spec, without its feature set or `+holds` (`rf:memory` -> `rf`,
    `lawfree+holds` -> `lawfree`): the key of its hyper-parameters and its choices."""
    return split_spec(spec)[0].partition(":")[0].strip()


def holds_name(hyper: dict) -> str:
    """The name suffix of a model with these hyperparameters (`_holds` or nothing)."""
    return HOLDS_NAME if hyper.get(HOLDS_KEY, False) else ""


def is_hold(rec: Recording) -> bool:
    """A press-and-hold recording (`train_hold`, `validation_hold`; any name ending `_hold`)."""
    return rec.name.endswith("_hold")


def spec_dataset(dataset: Dataset, spec: str) -> Dataset:
    """The recordings the model of `spec` trains and chooses on: all of them for a `+holds`
    spec (which then needs a training hold recording), the others without the hold
    recordings. The test recordings are the same for every model."""
    _, holds = split_spec(spec)
    if holds:
        if not any(is_hold(r) for r in dataset.train):
            raise ValueError(
                f"{spec}: the dataset {dataset.root or dataset.manifest} has no press-and-hold "
                "training recording (train_hold); record it with PRESSES=1 "
                "scripts/record-dataset.sh (existing files are kept)"
            )
        return dataset
    if not any(is_hold(r) for r in (*dataset.train, *dataset.validation)):
        return dataset
    return replace(
        dataset,
        train=[r for r in dataset.train if not is_hold(r)],
        validation=[r for r in dataset.validation if not is_hold(r)],
    )
