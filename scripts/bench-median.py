#!/usr/bin/env python3
"""The median of several runs of a benchmark that prints one JSON object as its last line
(`scripts/bench-loaded.sh` with BENCH_RUNS=N runs itself N times and calls this).

Why: the machines this product is measured on are shared and noisy; one run is one quarter of
an hour of the host's, and the same configuration has moved 3x between runs minutes apart
(docs/infer-server.md). Figures are quoted as medians of several runs, with every run beside
them.

Per key of the first run's object: numbers give their median over the runs that have one (null
where none has); an object (per family) gives a median per inner key; anything else (the
model's name, a flag) is kept when every run agrees and listed per run when they do not.
Prints a table (key, each run, median) and, as its last line, one JSON object: the same keys as
a single run's, holding the medians, plus `runs` (how many) and `per_run` (each key's values,
run by run).

Usage: bench-median.py RUN_OUTPUT... (each a run's standard output; its last line that starts
with `{` is its JSON)
       bench-median.py --runs N [--label NAME] -- COMMAND... (runs COMMAND N times with
       BENCH_RUNS=1 in its environment, its output shown and kept in a temporary folder, then
       as above; a run that fails stops the series with its exit status)
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any


def last_json(text: str, name: str) -> dict[str, Any]:
    """The last line of `text` that is a JSON object."""
    for line in reversed(text.splitlines()):
        if line.startswith("{"):
            try:
                obj = json.loads(line)
            except json.JSONDecodeError as e:
                raise ValueError(f"{name}: its last JSON line does not parse ({e})") from e
            if isinstance(obj, dict):
                return obj
    raise ValueError(f"{name}: no JSON object line (did the run finish?)")


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def combine(values: list[Any]) -> Any:
    """The median of one key's values over the runs (see the module's doc)."""
    present = [v for v in values if v is not None]
    if not present:
        return None
    if all(_is_number(v) for v in present):
        m = statistics.median(present)
        # counts stay whole numbers where the median is one (nodes, steps)
        return int(m) if all(isinstance(v, int) for v in present) and m == int(m) else m
    if all(isinstance(v, dict) for v in present):
        keys = sorted({k for v in present for k in v})
        return {k: combine([v.get(k) for v in present]) for k in keys}
    first = present[0]
    return first if all(v == first for v in present) else values


def median_of_runs(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The medians (the first run's keys, then any key a later run adds), `runs` and
    `per_run`."""
    if not runs:
        raise ValueError("no runs")
    keys = list(runs[0])
    keys += [k for r in runs[1:] for k in r if k not in keys]
    per_run = {k: [r.get(k) for r in runs] for k in keys}
    out = {k: combine(v) for k, v in per_run.items()}
    out["runs"] = len(runs)
    out["per_run"] = per_run
    return out


def _cell(v: Any) -> str:
    if v is None:
        return "-"
    if _is_number(v):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return f"({len(v)} entries)"
    return str(v)


def _flat(key: str, values: list[Any], median: Any) -> list[tuple[str, list[Any], Any]]:
    """(key, per run, median) rows; an object's entries as `key.inner`, one row each."""
    if isinstance(median, dict):
        rows = []
        for k in median:
            inner = [v.get(k) if isinstance(v, dict) else None for v in values]
            rows += _flat(f"{key}.{k}", inner, median[k])
        return rows
    return [(key, values, median)]


def table(result: dict[str, Any]) -> str:
    """One row per key (per inner key of an object): each run's value, then the median."""
    n = result["runs"]
    head = (
        f"{'key':34} "
        + " ".join(f"{'run ' + str(i + 1):>12}" for i in range(n))
        + f" {'median':>12}"
    )
    rows = [head]
    for key, values in result["per_run"].items():
        for k, vals, med in _flat(key, values, result[key]):
            rows.append(
                f"{k:34} " + " ".join(f"{_cell(v):>12}" for v in vals) + f" {_cell(med):>12}"
            )
    return "\n".join(rows)


def run_series(runs: int, label: str, command: list[str]) -> int:
    """Runs `command` `runs` times (BENCH_RUNS=1 in its environment, so a benchmark that calls
    this for itself runs once each time), shows and keeps each run's standard output, then
    prints the medians (`main`). The first run that fails stops the series with its status."""
    outs = Path(tempfile.mkdtemp(prefix=f"{label}-runs.", dir=os.environ.get("TMPDIR")))
    env = {**os.environ, "BENCH_RUNS": "1"}
    files = []
    for i in range(1, runs + 1):
        print(f"==> run {i} of {runs}", file=sys.stderr, flush=True)
        path = outs / f"run{i}.out"
        with (
            path.open("w") as kept,
            subprocess.Popen(command, stdout=subprocess.PIPE, text=True, env=env) as proc,
        ):
            assert proc.stdout is not None
            for line in proc.stdout:
                sys.stdout.write(line)
                sys.stdout.flush()
                kept.write(line)
        if proc.returncode != 0:
            print(f"bench-median: run {i} of {runs} failed (exit {proc.returncode}); the series stops",
                  file=sys.stderr)  # fmt: skip
            return proc.returncode
        files.append(str(path))
    print(f"==> every run's output: {outs}", file=sys.stderr)
    return main(files)


def main(argv: list[str]) -> int:
    if argv[:1] == ["--runs"]:
        try:
            runs = int(argv[1])
            rest = argv[2:]
            label = "bench"
            if rest[:1] == ["--label"]:
                label, rest = rest[1], rest[2:]
            if rest[:1] != ["--"] or len(rest) < 2 or runs < 1:
                raise ValueError
        except (IndexError, ValueError):
            print("bench-median: usage: --runs N [--label NAME] -- COMMAND...", file=sys.stderr)
            return 2
        return run_series(runs, label, rest[1:])
    if not argv:
        print(__doc__.strip().splitlines()[-2], file=sys.stderr)
        return 2
    try:
        runs = [last_json(Path(p).read_text(), p) for p in argv]
        result = median_of_runs(runs)
    except (OSError, ValueError) as e:
        print(f"bench-median: {e}", file=sys.stderr)
        return 1
    print(f"median of {len(runs)} runs:")
    print(table(result))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
