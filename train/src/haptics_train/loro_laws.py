"""The laws the leave-one-rate-out study generates tests from (`loro --generator NAME`), and
which model of train/ shares a class with which law (issue 23, item 6).

Every generator writes loading-unloading CSV at the same rates and validation rates:

- `qlv`: the SYNTHETIC QLV elastomer of `viscoelastic` (Python, this package);
- `bouc-wen`, `gel`, `hunt-crossley`: the bench's own objects (materials/*.toml), driven by
  `rt-loop object-force` (`bench_tests`), so the tests come from the laws the bench renders.

The class notes are declared once per model, as the set of laws inside its class and the set
one element away ("near", with the element), and each report's table is computed from them and
from the study's models; a law that no model of the study shares or is near is flagged.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from . import bench_tests, viscoelastic


@dataclass(frozen=True)
class Law:
    """A law the tests are generated from."""

    title: str
    source: str  # where the law and its implementation come from


LAWS: dict[str, Law] = {
    "qlv": Law("QLV elastomer (Fung): a cubic instantaneous spring, two-term Prony relaxation",
               "`haptics_train.viscoelastic` (Python, this package)"),
    "foam": Law("viscoelastic foam (tanh plateau, densification, Maxwell branches, Dahl, "
                "compression set)", "materials/sponge.toml, foam-b.toml, foam-c.toml "
                "(rt-loop/src/object/foam.rs)"),
    "bouc-wen": Law("Bouc-Wen hysteresis on a stiffening spring (Bouc 1967; Wen 1976)",
                    "materials/bouc-wen.toml (rt-loop/src/object/bouc_wen.rs)"),
    "gel": Law("poroelastic gel, relaxation time growing with the contact size (Hu et al. "
               "2010)", "materials/gel.toml (rt-loop/src/object/poroelastic.rs)"),
    "hunt-crossley": Law("Hunt-Crossley contact with an Eyring (sinh) Maxwell memory, an ONNX "
                         "object", "materials/hunt-crossley.toml (law = \"onnx\"; the graph "
                         "written by haptics_train.objects.hunt_crossley)"),
}  # fmt: skip


@dataclass(frozen=True)
class ModelClass:
    """A model's class: what it is, the laws inside it, and those one element away."""

    what: str
    shares: frozenset[str] = frozenset()
    near: tuple[tuple[str, str], ...] = ()  # (law, the element that differs)


#: keyed by the algorithm (a spec's part before ':'), as `models.parse_spec` reads it
MODEL_CLASSES: dict[str, ModelClass] = {
    "sd_poly2": ModelClass("quadratic spring + linear damper (Kelvin-Voigt)"),
    "prony": ModelClass(
        "cubic spring + Prony (Maxwell) branches on the velocity",
        near=(("qlv", "same cubic spring and Prony kernel; its branches are driven by v, the "
                      "law's by dF_e(x)/dt"),)),
    "structured": ModelClass(
        "foam-shaped: tanh/pole equilibrium, Maxwell branches on dF_eq, Dahl, compression set; "
        "where validation chooses them, indentation powers (e/D)^p and branches whose time "
        "grows with the depth (structured.py, INDENTATION)",
        # the gel: its Hertz force is a power 1.5, its relaxation time a^2 / D grows with the
        # depth, its relaxation function a sum of exponentials in the grid's span
        shares=frozenset({"foam", "gel"}),
        near=(("qlv", "same branches on dF_eq/dt; the cubic spring only approximated by the "
                      "tanh/pole basis"),)),
    "lawfree": ModelClass("assumes no law: fading-memory filters + play operators, a readout "
                          "in functions of the depth (a generic operator class)"),
    "rf": ModelClass("general learner (forest), no law"),
    "dnn": ModelClass("general learner (feed-forward network), no law"),
    "dnn_fb": ModelClass("general learner (network fed back its force), no law"),
    "lstm": ModelClass("general learner (LSTM), no law"),
    "lstm_fb": ModelClass("general learner (LSTM fed back its force), no law"),
    "lstm_slow": ModelClass("general learner (slow LSTM), no law"),
}  # fmt: skip


@dataclass(frozen=True)
class Generator:
    """A `--generator` choice: its law, and how it writes the CSV tests into a folder."""

    law: str
    #: (folder, rates=None) -> the CSV paths: the study's rates, or those given
    write_tests: Callable[..., list[Path]]
    report: str  # the report's stem under docs/report/
    params: Callable[[], dict]


def _bench(material: str) -> Generator:
    path = bench_tests.MATERIALS / f"{material}.toml"
    return Generator(
        material, lambda out, rates=None: bench_tests.write_tests(path, out, rates=rates),
        f"{material}-loro",
        lambda: {"material": f"materials/{material}.toml", "noise_n": bench_tests.NOISE_N},
    )


GENERATORS: dict[str, Generator] = {
    # today's elastomer: its report keeps its name
    "qlv": Generator("qlv", lambda out, rates=None: viscoelastic.write_tests(out, rates=rates),
                     "elastomer-loro",
                     lambda: viscoelastic.Elastomer().__dict__),  # fmt: skip
    "bouc-wen": _bench("bouc-wen"),
    "gel": _bench("gel"),
    "hunt-crossley": _bench("hunt-crossley"),
}


def model_class(name: str) -> ModelClass | None:
    """The class of a model named as in the results (`rf_xva`, `dnn_fb_six`, `lawfree`)."""
    for algo in sorted(MODEL_CLASSES, key=len, reverse=True):
        if name == algo or name.startswith(algo + "_"):
            return MODEL_CLASSES[algo]
    return None


def relation(model: str, law: str) -> str:
    """`shares`, `near: <element>`, or `-` (unknown models: `?`)."""
    c = model_class(model)
    if c is None:
        return "?"
    if law in c.shares:
        return "shares"
    for n, why in c.near:
        if n == law:
            return f"near: {why}"
    return "-"


def class_notes(models: list[str], law: str) -> dict:
    """The computed class notes of a study: per model its class and relation to every law;
    which models share `law`'s class or are near it; `flag` when none is."""
    rows = {m: {"class": (model_class(m) or ModelClass("?")).what,
                **{k: relation(m, k) for k in LAWS}} for m in models}  # fmt: skip
    sharing = [m for m in models if rows[m][law] == "shares"]
    near = [m for m in models if rows[m][law].startswith("near")]
    return {"law": law, "rows": rows, "shares": sharing, "near": near,
            "no_class_shared": not sharing and not near}  # fmt: skip
