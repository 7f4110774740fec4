"""Import of a time/displacement/force series measured elsewhere (another device, a
materials-testing machine) into the recording format.

The features are computed by rt-loop's own offline feature code (`rt-loop features`), so the
definitions exist once, in the loop, and training never drifts from serving. This module only
finds the binary, checks the input early with clear messages, runs it and checks its output.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from .data import DataError, Recording, load_recording

TIME_UNITS = ("s", "ms", "us")
POSITION_UNITS = ("m", "mm", "um")
FORCE_UNITS = ("N", "mN")


class RtLoopMissing(RuntimeError):
    pass


def _repo_candidates() -> list[Path]:
    here = Path(__file__).resolve()
    starts = [Path.cwd().resolve(), *here.parents]
    out = []
    for s in starts:
        for p in (s, *s.parents):
            c = p / "target" / "release" / "rt-loop"
            if c not in out:
                out.append(c)
    return out


def find_rt_loop(explicit: str | None = None) -> Path:
    """--rt-loop PATH, else $HAPTICS_RT_LOOP, else target/release/rt-loop of this checkout,
    else `rt-loop` on PATH."""
    for label, cand in (
        ("--rt-loop", explicit),
        ("HAPTICS_RT_LOOP", os.environ.get("HAPTICS_RT_LOOP")),
    ):
        if cand:
            p = Path(cand)
            if not (p.is_file() and os.access(p, os.X_OK)):
                raise RtLoopMissing(f"{label} points to {p}, which is not an executable file")
            return p
    for c in _repo_candidates():
        if c.is_file() and os.access(c, os.X_OK):
            return c
    w = shutil.which("rt-loop")
    if w:
        return Path(w)
    raise RtLoopMissing(
        "the rt-loop binary is needed to compute the features (its own offline feature code) "
        "but was not found: build it with `cargo build --release -p rt-loop`, or pass "
        "--rt-loop PATH, or set HAPTICS_RT_LOOP"
    )


def input_columns(path: Path) -> list[str]:
    if path.suffix.lower() == ".csv":
        with pacsv.open_csv(path) as reader:
            return list(reader.schema.names)
    return list(pq.read_schema(path).names)


def import_series(
    input_path: str | Path,
    out: str | Path,
    time_col: str,
    position_col: str,
    force_col: str,
    time_unit: str = "s",
    position_unit: str = "m",
    rt_loop: str | None = None,
    force_unit: str = "N",
    timeout_s: float = 600.0,
) -> Recording:
    src = Path(input_path)
    dst = Path(out)
    if not src.is_file():
        raise DataError(f"no such input file: {src}")
    if src.suffix.lower() not in (".csv", ".parquet"):
        raise DataError(f"{src}: only .csv and .parquet inputs are supported")
    if dst.suffix.lower() != ".parquet":
        raise DataError(f"output {dst} must end in .parquet")
    if time_unit not in TIME_UNITS:
        raise DataError(f"--time-unit must be one of {TIME_UNITS}, not {time_unit!r}")
    if position_unit not in POSITION_UNITS:
        raise DataError(f"--position-unit must be one of {POSITION_UNITS}, not {position_unit!r}")
    if force_unit not in FORCE_UNITS:
        raise DataError(f"--force-unit must be one of {FORCE_UNITS}, not {force_unit!r}")
    cols = input_columns(src)
    missing = [c for c in (time_col, position_col, force_col) if c not in cols]
    if missing:
        raise DataError(f"{src}: no column(s) {missing}; it has {cols}")
    if dst.exists() and dst.resolve() == src.resolve():
        raise DataError("refusing to overwrite the input with the output")
    binary = find_rt_loop(rt_loop)
    dst.parent.mkdir(parents=True, exist_ok=True)
    cmd = [
        str(binary), "features", "--input", str(src),
        "--time-col", time_col, "--position-col", position_col, "--force-col", force_col,
        "--time-unit", time_unit, "--position-unit", position_unit, "--force-unit", force_unit,
        "--out", str(dst),
    ]  # fmt: skip
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as e:
        raise RuntimeError(f"`{' '.join(cmd)}` did not finish within {timeout_s} s") from e
    if proc.returncode != 0:
        raise RuntimeError(
            f"rt-loop features failed (exit {proc.returncode}):\n{proc.stderr.strip()}"
        )
    return load_recording(dst)
