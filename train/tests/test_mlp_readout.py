"""scripts/lawfree-mlp-readout.py (docs/laws.md, "A network readout on `lawfree`'s memory"):
the prototype reads the folds `python -m haptics_train.loro` leaves, scores `lawfree` exactly as
the study did, and chooses its network on validation; without folds it says so."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from conftest import REPO

from haptics_train import loro

SCRIPT = REPO / "scripts" / "lawfree-mlp-readout.py"


def _run(work: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), str(work), *args], capture_output=True,
                          text=True, timeout=600)  # fmt: skip


def test_scores_lawfree_as_the_study_did_and_chooses_on_validation(tmp_path: Path) -> None:
    out = loro.run(tmp_path, ("sd_poly2", "lawfree"), quick=True, generator="qlv")
    run = _run(tmp_path, "--epochs", "20")
    assert run.returncode == 0, run.stderr
    res = json.loads((tmp_path / "mlp-readout.json").read_text())
    assert sorted(res) == ["fold_rate_0.5", "fold_rate_2", "fold_rate_8"]
    for name, r in res.items():
        # the linear readout scored here is the study's figure for the same fold
        study = out["folds"][name.removeprefix("fold_")]["test"]["lawfree"]
        assert abs(r["lawfree_test"] - study) < 1e-9 * max(1.0, study)
        assert np.isfinite(r["mlp_test"]) and r["mlp_test"] > 0
        c = r["choice"]
        assert c["hidden"] in (16, 32) and c["weight_decay"] in (1e-4, 1e-3)
        assert c["epoch"] in (10, 20) and isinstance(c["residual"], bool)
        # the choice is the candidate with the lowest validation score of those printed
        vals = [float(line.split("validation ")[1].split(" ")[0])
                for line in run.stdout.splitlines() if line.startswith(f"  {name} ")]  # fmt: skip
        assert len(vals) == 8
        assert f"{r['mlp_validation']:.4f}" == f"{min(vals):.4f}"


def test_without_folds_it_says_what_to_run(tmp_path: Path) -> None:
    run = _run(tmp_path)
    assert run.returncode != 0
    assert "no fold_rate_* folders" in run.stderr and "haptics_train.loro" in run.stderr
