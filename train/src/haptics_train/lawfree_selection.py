"""How `haptics-train train` chooses `lawfree`'s form on validation: the grid of readouts,
ridges and memory spans (`lawfree_candidates`), scored on two validation scores at once
(`choose_on_both`); then two additions tried once on that choice, each kept only where it is
clearly closer on both scores (`keep_at_margin`): the irreversible memory
(`lawfree_damage_candidate`) and the network readout (`try_network_readout`, never on a rig with
a friction: `network_skipped`).

Every number here is a grid of the path's or the fit's own scales, or a margin, never a
material's constant; each says why it is what it is and where it was measured. The pipeline
(`pipeline.train_models`) does the fitting and the scoring; this module says what is tried and
what is kept.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable

import numpy as np

from .data import Dataset, training_arrays
from .metrics import fmt_figure
from .models import ForceModel, TrainConfig
from .models.lawfree import LAWFREE_DEFAULT
from .models.lawfree_net import NET_MAX_STEPS, fit_network_readout

#: How `lawfree`'s candidates are chosen (`choose_on_both`): its memory span decides what the
#: rests and holds between the sliding rows look like, which the sliding score leaves out.
BOTH_SCORES_RULE = (
    "the larger of two multiples of the best candidate's: the free-run RMSE on the sliding rows "
    "(the selection metric) and over every validation row"
)


def choose_on_both(sliding: dict[str, float], every: dict[str, float]) -> str:
    """The candidate whose worse multiple of the best, of its sliding score and its all-row
    score, is the lowest (`BOTH_SCORES_RULE`; the recommendation's rule with the felt force,
    `fidelity.rank`, is the same shape). Why both for `lawfree`: the sliding rows leave out the
    rests and the holds at the turning points, where a slow memory (a foam's compression set,
    recovering over tens of seconds) shows, and every row alone follows the stick friction no
    model can know (`validation_free_run_rmse`); a candidate must be near the best on both. On
    the bench's foams the sliding score alone dropped the 30-100 s filters and the hand felt the
    sponge's and foam-b's `lawfree` 50 % further off (docs/laws.md, "`lawfree`'s memory span");
    on testing-machine data, where the two scores agree, it chose as the sliding score does."""

    def multiple(v: float, best: float) -> float:
        return v / best if np.isfinite(v) and np.isfinite(best) and best > 0 else float("inf")

    finite = [k for k in sliding if np.isfinite(sliding[k]) and np.isfinite(every.get(k, np.nan))]
    if not finite:
        return min(sliding, key=lambda k: sliding[k] if np.isfinite(sliding[k]) else np.inf)
    bs, be = min(sliding[k] for k in finite), min(every[k] for k in finite)
    return min(sliding, key=lambda k: max(multiple(sliding[k], bs),
                                          multiple(every.get(k, np.nan), be)))  # fmt: skip


#: lawfree's readouts, chosen on validation when the dataset has validation recordings:
#: (label, hyper-parameters). The depth functions without a constant memory weight, or the
#: powers with one: on the bench's recordings (the friction inside the RFOB target) a constant
#: memory weight and the friction's Dahl states are the same columns, and the restricted readout
#: renders the objects better; on testing-machine data (no friction) a constant weight is a
#: linear viscoelastic memory and the free one fits better. Which holds is the data's to say
#: (docs/laws.md, "A memory holds no force at the surface"). Not a candidate: depth functions
#: WITH a constant, which fits the RFOB as well as the first (sponge 0.4599 against 0.4643 N)
#: and so wins by noise while it gives the object's hysteresis to the friction again (1.46 N):
#: a free run against the RFOB cannot tell the two apart, so the candidates must differ in
#: what it can see.
LAWFREE_READOUTS: tuple[tuple[str, dict], ...] = (
    ("depth-functions", {"memory_at_surface": False, "readout_depth_scales": [0.1, 0.3]}),
    ("powers+constant", {"memory_at_surface": True, "readout_depth_scales": []}),
)

#: lawfree's ridge (relative to the rows' count, `LawFree.fit`), chosen on validation with the
#: readout: a grid of decades, not a material's number. The readout has 66 weights over
#: filters and plays that overlap; how much shrinkage the data bear depends on how much of the
#: motion the training ramps cover, which only held-out data can say. Measured on the bench's
#: objects (docs/laws.md, "`lawfree`'s ridge chosen on validation"), the sliding validation
#: score's choice moved the felt force with it: Bouc-Wen 0.522 N at 1e-4 against 0.409 at 1e-3.
LAWFREE_RIDGES: tuple[float, ...] = (1e-4, 1e-3, 1e-2)

#: lawfree's memory span: the longest time constant of its fading-memory filters (s), chosen on
#: validation with the readout and the ridge; the filters are LAWFREE_DEFAULT's (0.01-100 s, half
#: a decade apart) up to the span. A grid of decades, not a material's number. Why it is chosen
#: and not fixed: a filter much slower than the training recordings barely moves in them, so it
#: is fitted as a copy of the compression, and a slower motion (or a longer one) then moves it
#: and the readout extrapolates. On testing-machine tests of 4.5-42 s, the slow filters made
#: `lawfree` 0.28 N off on its 0.25 mm/s validation test where a 1 s span was 0.06 N
#: (Hunt-Crossley, 0.5 mm/s held out); on the bench's minute-long recordings, with a set that
#: recovers over tens of seconds, the slow ones may be what the data need: validation says
#: which, on the sliding rows and over every row (`choose_on_both`; docs/laws.md, "`lawfree`'s
#: memory span chosen on validation").
LAWFREE_SPANS_S: tuple[float, ...] = (1.0, 10.0, 100.0)


#: The scales c (fractions of the deepest training compression D) of `lawfree`'s irreversible
#: memory (`damage_frac`: d = u - u_max, the depth below the deepest compression so far, and
#: c (1 - exp(d / c))), a grid of the path's scales as `play_frac` is, not a material's
#: number. Not in the grid of `lawfree_candidates`: it is tried once, on the grid's choice
#: (`lawfree_damage_candidate`), and kept where validation prefers it clearly
#: (`keep_at_margin`). Why an
#: irreversible memory: filled rubbers, foams and tissues soften below the deepest load they
#: have carried and do not recover within a test (the Mullins effect: L. Mullins, Rubber Chem.
#: Technol. 42:339, 1969; R. W. Ogden, D. G. Roxburgh, Proc. R. Soc. A 455:2861, 1999;
#: preconditioning of tissues, Y. C. Fung, Biomechanics, 1993), which neither a fading memory
#: nor a play operator (both forget) can hold. Why once and not in the grid: the grid's 18
#: candidates already take most of `scripts/up.sh`'s training time. Measured in docs/laws.md,
#: "An irreversible memory".
LAWFREE_DAMAGE_FRAC: tuple[float, ...] = (0.02, 0.05, 0.15)


#: How much closer an addition to the grid's choice (the irreversible memory, the network
#: readout) must bring it, on the sliding rows and over every validation row alike, to be kept
#: (`keep_at_margin`): 10 %. Why a margin: each changes how the object feels beyond what a
#: validation recording shows (a memory that never forgets, for the rest of a session; a
#: network, wherever it extrapolates), so it must beat the recordings' noise clearly.
#: Measured (docs/laws.md, "An irreversible memory"): on the six bench laws the irreversible
#: memory came at most 2.4 % closer over every row (0.976-0.994x; 0.87-1.02x on the sliding
#: rows), so it is kept on none; on an object that softens below its deepest press, 0.68x
#: (every row) and 0.22x (sliding).
KEEP_MARGIN = 0.9

#: What `train_info_["selection"]["rule"]` adds to `BOTH_SCORES_RULE` where the irreversible
#: memory was tried.
DAMAGE_RULE = (
    "; then the choice with the irreversible memory, kept where it is at most "
    f"{KEEP_MARGIN:g}x the choice's on both"
)


def keep_at_margin(
    sliding: dict[str, float], every: dict[str, float], base: str, cand: str
) -> bool:
    """Whether candidate `cand` (an addition to `base`, the grid's choice: its irreversible
    memory, its network readout) is at most `KEEP_MARGIN` times `base` on both scores (each a
    dict by label). A candidate without a finite score on both is never kept; one with them
    beside a `base` without them always is."""
    if not all(np.isfinite(d[cand]) for d in (sliding, every)):
        return False
    if not all(np.isfinite(d[base]) and d[base] > 0 for d in (sliding, every)):
        return True
    return max(d[cand] / d[base] for d in (sliding, every)) <= KEEP_MARGIN


#: What `train_info_["selection"]["rule"]` adds where `lawfree`'s network readout was tried
#: (`try_network_readout`): the same margin as the irreversible memory's, for a like reason: a
#: network extrapolates differently from the linear readout (it saturates where the linear
#: readout goes on linearly past the deepest training press), and its training length is
#: itself chosen on the validation recordings, which favours it there.
NETWORK_RULE = (
    "; then the choice read through a network (lawfree_net.py), kept where it is at most "
    f"{KEEP_MARGIN:g}x the choice's on both"
)


#: Why the network readout is not tried on recordings with a friction: it cannot tell the
#: bench's friction from the object, and renders it. Measured on the six bench laws (docs/laws.md,
#: "The network readout in the product"): its rendered object went 1.3-2.3x further from the
#: object's own force, its free run below the floor no model of the object can pass; neither
#: the friction fitted again beside it nor a force vanishing at the surface mended it. A
#: testing machine's recordings hold no friction, and there it is tried.
NETWORK_SKIPPED = (
    "the training recordings show a friction in free air ({air:.3g} N, {pct:.2g} % of the "
    "largest force fitted), which a network readout would render as the object's (docs/laws.md, "
    "'The network readout in the product')"
)

#: The free air's friction, as a fraction of the largest force fitted, from which the network
#: readout is not tried: 1 %. What the free air shows on a testing machine is its force
#: sensor's noise (the leave-one-rate-out tests: 2 mN of noise, 0.05-0.1 % of their force);
#: on the bench the friction is about 0.85 N, 6 % of a 14 N press. Below 1 %, what a network
#: could render of a friction is within what a rig's force sensor resolves.
NETWORK_FRICTION_FRAC = 0.01


def network_skipped(m: ForceModel) -> str | None:
    """Why fitted `lawfree` `m` is not read through a network (`NETWORK_SKIPPED`: its training
    recordings show a friction in free air of at least `NETWORK_FRICTION_FRAC` of the largest
    force fitted), or None."""
    air = float(m.train_info_.get("free_air_friction_n") or 0.0)
    top = float(m.train_info_.get("target_max_n") or 0.0)  # absent: a model pickled before it
    if air <= 0 or (top > 0 and air < NETWORK_FRICTION_FRAC * top):
        return None
    return NETWORK_SKIPPED.format(air=air, pct=100 * air / top if top > 0 else float("nan"))


def try_network_readout(
    m: ForceModel, dataset: Dataset, cfg: TrainConfig, sliding: float, every: float,
    score: Callable[[ForceModel], tuple[float, float]], max_steps: int = NET_MAX_STEPS,
) -> tuple[ForceModel, dict]:
    """`lawfree` `m` (scored `sliding`, `every` on validation) read through each network of
    `lawfree_net.NET_GRID` (each trained for at most `max_steps` mini-batches: the user's
    `network_steps`, `haptics-train train --lawfree-network-steps`), the best on validation
    scored by `score` (the pipeline's two validation scores of a model) and kept where it is
    at most `KEEP_MARGIN` times `m` on both; returns (the model kept, what was tried, for
    `train_info_["selection"]["network_readout"]`)."""
    X, y, params = training_arrays(dataset.train, m.features, m.layout, (), cfg.target,
                                   cfg.decimate, cfg.target_rate_hz)  # fmt: skip
    valid = [(r.matrix(m.features), r.target(cfg.target), 1.0 / r.sample_rate_hz)
             for r in dataset.validation]  # fmt: skip
    t0 = time.perf_counter()
    cand, tried = fit_network_readout(
        m, X, y, params["info"], valid, seed=cfg.seed, max_steps=max_steps,  # type: ignore[arg-type]
        log=lambda line: print(f"[train] lawfree network readout {line}", flush=True),
    )
    s, e = score(cand)
    keep = keep_at_margin({"net": s, "m": sliding}, {"net": e, "m": every}, "m", "net")
    print(f"[train] lawfree network readout: validation free-run RMSE {fmt_figure(s)} N (every row "
          f"{fmt_figure(e)} N) against {fmt_figure(sliding)} N ({fmt_figure(every)} N): "
          f"{'kept' if keep else 'not kept'}", flush=True)  # fmt: skip
    note = {"candidates_every_row": tried, "chosen": cand.network.describe(),  # type: ignore[attr-defined]
            "validation": s, "validation_every_row": e, "kept": keep,
            "seconds": round(time.perf_counter() - t0, 1)}  # fmt: skip
    return (cand if keep else m), note


def lawfree_damage_candidate(label: str, extra: dict, user: dict) -> tuple[str, dict] | None:
    """The grid's choice (`label`, its hyper-parameters `extra`) with the irreversible memory,
    or None where the user set `damage_frac`."""
    if "damage_frac" in user:
        return None
    tag = f"{label}, damage memory" if label else "damage memory"
    return tag, {**extra, "damage_frac": list(LAWFREE_DAMAGE_FRAC)}


def lawfree_candidates(user: dict) -> list[tuple[str, dict]]:
    """The (label, hyper-parameters) `train_models` tries for `lawfree`: every readout of
    `LAWFREE_READOUTS` at every ridge of `LAWFREE_RIDGES` and every memory span of
    `LAWFREE_SPANS_S`, less what the user set (a ridge or filters the user gives are used for
    every candidate; a readout the user gives is not searched)."""
    # each axis: (its part of the label, its hyper-parameters); one unsearched entry where the
    # user set it
    unset: list[tuple[str, dict]] = [("", {})]
    readouts = unset if user.keys() & {"memory_at_surface", "readout_depth_scales"} else list(
        LAWFREE_READOUTS)  # fmt: skip
    ridges = unset if "ridge" in user else [(f"ridge {r:g}", {"ridge": r}) for r in LAWFREE_RIDGES]
    taus = LAWFREE_DEFAULT["taus_s"]
    spans = unset if "taus_s" in user else [
        (f"memory {s:g} s", {"taus_s": [t for t in taus if t <= s]})
        for s in LAWFREE_SPANS_S]  # fmt: skip
    out = [(", ".join(label for label, _ in axes if label),
            {k: v for _, h in axes for k, v in h.items()})
           for axes in itertools.product(readouts, ridges, spans)]  # fmt: skip
    return out if len(out) > 1 else []
