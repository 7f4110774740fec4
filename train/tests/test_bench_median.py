"""scripts/bench-median.py: the medians `scripts/bench-loaded.sh` prints for BENCH_RUNS > 1."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
from conftest import script_module

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "bench-median.py"


def _module() -> ModuleType:
    return script_module("bench-median.py")


def _run_output(obj: dict) -> str:
    # what a run prints: a table, a note, then the JSON as the last line
    return "key  value\nidle  0.1\nno page rows (BENCH_PAGE=0)\n" + json.dumps(obj) + "\n"


RUNS = [
    {"idle_late_fraction": 0.00173, "page_late_fraction": 0.00217, "model": "structured",
     "keep_awake": True, "swap_miss_ratio": None,
     "family_page_late_fraction": {"prony": 0.001, "lawfree": 0.003}},
    {"idle_late_fraction": 0.00292, "page_late_fraction": 0.00084, "model": "structured",
     "keep_awake": True, "swap_miss_ratio": 1.28,
     "family_page_late_fraction": {"prony": 0.002, "lawfree": 0.001}},
    {"idle_late_fraction": 0.00575, "page_late_fraction": 0.00182, "model": "rf_six",
     "keep_awake": False, "swap_miss_ratio": 0.64,
     "family_page_late_fraction": {"prony": 0.004}},
]  # fmt: skip


def test_each_key_is_its_median_and_every_run_is_kept() -> None:
    out = _module().median_of_runs(RUNS)
    assert out["runs"] == 3
    assert out["idle_late_fraction"] == pytest.approx(0.00292)
    assert out["page_late_fraction"] == pytest.approx(0.00182)
    # a run without the figure does not count as a zero
    assert out["swap_miss_ratio"] == pytest.approx((1.28 + 0.64) / 2)
    # per family, over the runs that have it
    assert out["family_page_late_fraction"] == pytest.approx({"prony": 0.002, "lawfree": 0.002})
    # names and flags: kept when all runs agree, listed when they do not
    assert out["model"] == ["structured", "structured", "rf_six"]
    assert out["keep_awake"] == [True, True, False]
    assert out["per_run"]["idle_late_fraction"] == [0.00173, 0.00292, 0.00575]
    same = _module().median_of_runs(RUNS[:2])
    assert same["model"] == "structured" and same["keep_awake"] is True
    # whole-number counts stay whole where their median is one
    counts = _module().median_of_runs([{"steps": 2000, "nodes": 1}, {"steps": 2000, "nodes": 1}])
    assert counts["steps"] == 2000 and isinstance(counts["steps"], int)


def test_the_command_prints_a_table_then_the_medians_as_its_last_line(tmp_path: Path) -> None:
    files = []
    for i, r in enumerate(RUNS):
        f = tmp_path / f"run{i}.out"
        f.write_text(_run_output(r))
        files.append(str(f))
    res = subprocess.run([sys.executable, str(SCRIPT), *files], capture_output=True, text=True,
                         check=True)  # fmt: skip
    lines = res.stdout.strip().splitlines()
    assert lines[0] == "median of 3 runs:"
    assert any(line.startswith("idle_late_fraction") and "0.00292" in line for line in lines)
    # an object's entries get a row each (bench-models.sh's families)
    assert any(line.startswith("family_page_late_fraction.prony") for line in lines)
    last = json.loads(lines[-1])
    assert last["idle_late_fraction"] == pytest.approx(0.00292) and last["runs"] == 3


def test_a_run_without_its_json_is_a_clear_error(tmp_path: Path) -> None:
    good, cut = tmp_path / "good.out", tmp_path / "cut.out"
    good.write_text(_run_output(RUNS[0]))
    cut.write_text("==> machine floor\nin-process call: p50 1.4 us\n")
    res = subprocess.run([sys.executable, str(SCRIPT), str(good), str(cut)], capture_output=True,
                         text=True)  # fmt: skip
    assert res.returncode == 1
    assert "cut.out: no JSON object line" in res.stderr


def test_runs_runs_the_command_each_time_with_bench_runs_1_and_stops_at_a_failure() -> None:
    show = "import json, os; print(json.dumps({'bench_runs': int(os.environ['BENCH_RUNS'])}))"
    ok = subprocess.run([sys.executable, str(SCRIPT), "--runs", "3", "--", sys.executable, "-c",
                         show], capture_output=True, text=True, check=True)  # fmt: skip
    last = json.loads(ok.stdout.strip().splitlines()[-1])
    assert last["runs"] == 3 and last["per_run"]["bench_runs"] == [1, 1, 1]
    bad = subprocess.run([sys.executable, str(SCRIPT), "--runs", "2", "--", sys.executable, "-c",
                          "raise SystemExit(3)"], capture_output=True, text=True)  # fmt: skip
    assert bad.returncode == 3 and "run 1 of 2 failed (exit 3)" in bad.stderr
