"""The study's hand is fitted to the object (study/hand.py): an object within the bench's range
keeps the standard set-points; a stiffer one is pressed less deep, so the reference stays within
the force the bench renders and the study measures models, not the motor's current limit."""

import math
import os
from pathlib import Path

import pytest

from haptics_train.study.hand import (
    FORCE_HEADROOM,
    fit_hand,
    next_factor,
    renderable_force_n,
    scaled_hand,
)
from haptics_train.study.processes import Tools
from haptics_train.study.protocol import STUDY_HAND

ROOT = Path(__file__).resolve().parents[2]


def test_the_renderable_force_is_the_lower_of_the_loops_limit_and_the_motors():
    cfg = {"reproduction": {"max_force_n": 20.0}, "params": {"current_limit": 0.59, "k_fn": 24.0}}
    assert renderable_force_n(cfg) == pytest.approx(0.59 * 24.0)
    cfg["reproduction"]["max_force_n"] = 10.0
    assert renderable_force_n(cfg) == 10.0
    assert renderable_force_n({"params": {"current_limit": 0.5}}) != renderable_force_n({})
    assert math.isnan(renderable_force_n({"params": {"current_limit": 0.5}}))
    assert math.isnan(renderable_force_n({"reproduction": {"max_force_n": float("nan")}}))


def test_scaling_moves_the_set_points_only():
    h = scaled_hand(STUDY_HAND, 0.5)
    assert h["depth_m"] == STUDY_HAND["depth_m"] / 2
    assert h["depth_step_m"] == STUDY_HAND["depth_step_m"] / 2
    assert {k: v for k, v in h.items() if "depth" not in k} == {
        k: v for k, v in STUDY_HAND.items() if "depth" not in k
    }
    assert next_factor(1.0, 16.0, 12.0) == pytest.approx(math.sqrt(0.75) * 0.98)


def _tools(rt_loop: Path, infer_server: Path) -> Tools:
    return Tools(rt_loop=rt_loop, infer_server=infer_server, env=dict(os.environ))


@pytest.mark.parametrize(("material", "scaled"), [("sponge", False), ("bouc-wen", True)])
def test_the_hand_is_fitted_on_references_alone(material, scaled, rt_loop, infer_server,
                                                tmp_path):  # fmt: skip
    said: list[str] = []
    fit = fit_hand(_tools(rt_loop, infer_server), tmp_path, STUDY_HAND, 1,
                   ["--material", str(ROOT / "materials" / f"{material}.toml")], "lockstep",
                   said.append)  # fmt: skip
    assert fit["renderable_n"] == pytest.approx(0.59 * 24.0)  # rt-loop's default bench
    assert fit["peak_scaled_n"] <= FORCE_HEADROOM * fit["renderable_n"]
    if scaled:
        # the Bouc-Wen pad pushes 19 N at the standard set-points
        assert fit["peak_n"] > fit["renderable_n"] and 0.5 < fit["factor"] < 1.0, fit
        assert said and "scaled by" in said[-1]
    else:
        assert fit["factor"] == 1.0 and fit["tries"] == 1 and not said, fit
