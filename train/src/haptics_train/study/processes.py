"""The real processes of the study: one `rt-loop run` (and, for a served model,
`infer-server serve` beside it), its summary and its recording read back. Everything that
starts a process or reads its files is here, so the scoring stays pure."""

from __future__ import annotations

import json
import os
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from .protocol import OPTIONAL_SERIES, SERIES, StudyError


@dataclass
class Tools:
    rt_loop: Path
    infer_server: Path
    env: dict[str, str]


@dataclass
class Run:
    """One rt-loop run of the study and what came of it."""

    name: str
    kind: str  # reference | reproduction | shadow | replay
    path: Path
    ok: bool
    stop: str = ""
    wall_s: float = 0.0
    steps: int = 0
    served: int = 0
    fallbacks: int = 0
    # the ladder's count of steps rendered at the force limit (a model answered above it) and
    # of answers refused (NaN/Inf): flagged beside the run's figure (issue 23)
    saturated: int = 0
    rejected: int = 0
    note: str = ""
    series: dict[str, np.ndarray] = field(default_factory=dict)


def find_tools(root: Path, rt_loop: str | None, infer_server: str | None) -> Tools:
    def pick(given: str | None, name: str) -> Path:
        p = Path(given) if given else root / "target" / "release" / name
        if not p.is_file():
            raise StudyError(f"{p} not found: build it with `cargo build --release -p {name}`")
        return p

    env = dict(os.environ)
    ort = root / ".ort" / "libonnxruntime.so"
    if "ORT_DYLIB_PATH" not in env and ort.is_file():
        env["ORT_DYLIB_PATH"] = str(ort)
    return Tools(pick(rt_loop, "rt-loop"), pick(infer_server, "infer-server"), env)


def read_series(path: Path, columns: tuple[str, ...] = SERIES) -> dict[str, np.ndarray]:
    """The columns of a recording as float64; an optional one the file lacks (F_object in an
    older recording) is left out of the answer, for the scorer to say so."""
    have = set(pq.read_schema(path).names)
    wanted = [c for c in columns if c in have or c not in OPTIONAL_SERIES]
    table = pq.read_table(path, columns=wanted)
    return {c: np.asarray(table.column(c), dtype=np.float64) for c in wanted}


def write_config(path: Path, seed: int, hand: dict[str, float], clock: str = "lockstep") -> None:
    lines = [f"seed = {seed}", f'clock = "{clock}"', "", "[hand]"]
    lines += [f"{k} = {v}" for k, v in hand.items()]
    path.write_text("\n".join(lines) + "\n")


def _summary(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def run_loop(
    tools: Tools,
    name: str,
    kind: str,
    args: list[str],
    out: Path,
    server_model: Path | None = None,
    instance: str = "",
    timeout_s: float = 300.0,
) -> Run:
    """rt-loop run ARGS --record OUT (and, for a served model, infer-server beside it)."""
    summary = out.with_suffix(".summary.json")
    for p in (out, summary):
        p.unlink(missing_ok=True)
    cmd = [str(tools.rt_loop), "run", *args, "--record", str(out), "--overwrite"]
    cmd += ["--no-progress", "--summary-json", str(summary)]
    server: subprocess.Popen[str] | None = None
    t0 = time.perf_counter()
    if server_model is not None:
        srv_cmd = [str(tools.infer_server), "serve", "--model", str(server_model)]
        srv_cmd += ["--instance", instance, "--grpc", "127.0.0.1:0", "--http", "127.0.0.1:0"]
        srv_cmd += ["--wait", "park", "--exit-when-loop-gone"]
        server = subprocess.Popen(
            srv_cmd,
            env=tools.env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        cmd += ["--model", "shm", "--instance", instance, "--server-wait-s", "20"]
    loop = subprocess.Popen(
        cmd, env=tools.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    note = ""
    try:
        while loop.poll() is None:
            if server is not None and server.poll() not in (None, 0):
                # The server refused the model (it validates at start): the loop would only
                # wait for a server that never comes.
                loop.terminate()
                note = "infer-server refused the model: " + _last_line(server.stderr)
                break
            if time.perf_counter() - t0 > timeout_s:
                loop.terminate()
                note = f"timed out after {timeout_s:.0f} s"
                break
            time.sleep(0.02)
        loop_err = loop.communicate(timeout=30)[1]
    finally:
        if server is not None:
            try:
                server.wait(timeout=10)
            except subprocess.TimeoutExpired:
                server.terminate()
                server.wait(timeout=10)
    wall = time.perf_counter() - t0
    if not note and loop.returncode != 0 and server is not None and server.returncode:
        # The server refused the model after attaching: the loop saw it go away first.
        note = "infer-server refused the model: " + _last_line(server.stderr)
    s = _summary(summary)
    model = s.get("model") or {}
    run = Run(
        name=name,
        kind=kind,
        path=out,
        ok=loop.returncode == 0 and out.is_file(),
        stop=str(s.get("stop", "")),
        wall_s=wall,
        steps=int(s.get("steps", 0) or 0),
        served=int(model.get("served", 0) or 0),
        fallbacks=int(model.get("fallbacks", 0) or 0),
        saturated=int((s.get("ladder") or {}).get("saturated", 0) or 0),
        rejected=int((s.get("degraded_reasons") or {}).get("rejected", 0) or 0),
        note=note,
    )
    if not run.note and loop.returncode != 0:
        # An aborted run (e.g. position-limit) says why in its summary's stop reason.
        run.note = f"rt-loop exit {loop.returncode}"
        if not run.stop:
            run.note += ": " + _last_line_text(loop_err)
    if out.is_file():
        run.series = read_series(out)
    return run


def _last_line(stream: object) -> str:
    try:
        text = stream.read() if stream is not None else ""  # type: ignore[attr-defined]
    except (OSError, ValueError):
        text = ""
    return _last_line_text(text)


def _last_line_text(text: str) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    return lines[-1][:300] if lines else ""
