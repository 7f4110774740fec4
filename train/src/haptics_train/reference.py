"""Reference steps an exported model carries (`haptics.reference`, docs/model-contract.md), so
that whatever serves it can check, on its own machine and engine, that it computes what the
exporter computed.

Why: an exported model is a graph of operators, some of them the project's own (`ai.haptics`,
`fused-ops/`), whose attributes a kernel reads by name. A server built from older sources
reads the attributes it knows and ignores the rest: `lawfree`'s network readout (`net_w1` ..
`net_b3`) served by such a build renders the linear readout alone, a different object, with no
error anywhere. The parity check at export (`export.parity`) binds the graph to the framework's
`predict` on the exporting machine; these steps carry that result to the serving machine.

What: `REFERENCE_STEPS` rows of the parity recording, evenly spaced over its rows in contact
(every row where it has none), in the model's input order, stepped from the zero state as the
server starts a model, and the force the exporter's ONNX Runtime computed for each.
infer-server steps them when it loads the model and refuses it (`reference_mismatch`) when a
force differs by more than `tolerance_n`. The rows are not consecutive: the check is of the
arithmetic, not of a motion, and spreading them over the recording visits many depths, speeds
and states in a few steps.
"""

from __future__ import annotations

import json

import numpy as np
import onnx

from .closed_loop import OnnxStepper
from .data import Recording
from .export import contact_rows

REFERENCE_KEY = "haptics.reference"

#: Steps carried: enough to visit the recording's range of depths and forces and to move a
#: stateful model's state, few enough for the loader's cap on the entry (16 KiB; 32 rows of
#: nine features print in about 5 KiB).
REFERENCE_STEPS = 32

#: How far the server's force may be from the exporter's, N: the project's parity bound with
#: `predict` (issue 25: "every re-exported model matches its `predict` within 1e-4 N"). Two
#: machines running the same ONNX Runtime on the same graph agree to float32 rounding (about
#: 1e-6 N at 10 N); a server that reads the graph differently is off by far more.
REFERENCE_TOLERANCE_N = 1e-4


def reference_rows(rec: Recording, features: tuple[str, ...], steps: int = REFERENCE_STEPS
                   ) -> np.ndarray:  # fmt: skip
    """`steps` rows of `rec`'s features (float32, the model's input order), evenly spaced over
    the rows where the probe is in the object and the force is at least 0.01 N (every row
    where there are none), finite rows only."""
    x = rec.matrix(features).astype(np.float32)
    finite = np.isfinite(x).all(axis=1)
    pressed = finite & contact_rows(rec, rec.target())  # the parity check's rows of contact
    rows = np.flatnonzero(pressed if pressed.any() else finite)
    if not len(rows):
        raise ValueError(f"{rec.name}: no row with finite features for the reference steps")
    pick = rows[np.linspace(0, len(rows) - 1, min(steps, len(rows))).round().astype(int)]
    return x[pick]


def reference_entry(m: onnx.ModelProto, rows: np.ndarray, source: str) -> dict:
    """The `haptics.reference` object: `rows` stepped through `m` from the zero state by this
    machine's ONNX Runtime (the fused operators registered), as infer-server steps a model."""
    stepper = OnnxStepper(m)
    force = [stepper.step(r) for r in rows]
    if not all(np.isfinite(force)):
        raise ValueError("the exported model answers a non-finite force on its reference rows")
    return entry_of(rows, force, source)


def entry_of(rows: np.ndarray, force: list[float], source: str) -> dict:
    """The `haptics.reference` object for `rows` (the model's inputs, one step each from the
    zero state) and the `force` computed for each: rows and forces as float32."""
    return {
        # float32 values written with 9 significant digits read back bit for bit
        "inputs": [[float(f"{v:.9g}") for v in r] for r in rows.astype(np.float32)],
        "force": [float(f"{np.float32(f):.9g}") for f in force],
        "tolerance_n": REFERENCE_TOLERANCE_N,
        "source": source,
    }


def press_rows(features: tuple[str, ...], depth_m: float = 0.015, speed_m_s: float = 0.02,
               steps: int = REFERENCE_STEPS) -> np.ndarray:  # fmt: skip
    """`steps` rows (float32, in `features`' order) along a press from the surface to `depth_m`
    and back at `speed_m_s`, evenly spaced: reference rows for a graph fed the kinematics
    alone (`position_x`, `velocity`: a bench object's inputs, docs/laws/onnx.md) where no
    recording gives rows."""
    known = {"position_x", "velocity"}
    if not features or not set(features) <= known:
        raise ValueError(f"press rows feed {sorted(known)} only, not {list(features)}")
    half = steps // 2
    x = np.concatenate([np.linspace(0.0, depth_m, steps - half), np.linspace(depth_m, 0.0, half)])
    v = np.where(np.arange(steps) < steps - half, speed_m_s, -speed_m_s)
    cols = {"position_x": x, "velocity": v}
    return np.stack([cols[f] for f in features], axis=1).astype(np.float32)


def add_reference_rows(m: onnx.ModelProto, rows: np.ndarray, source: str) -> dict:
    """Steps `rows` through `m` (`reference_entry`) and writes the entry into its metadata,
    replacing any; returns the entry. For a graph of your own (an ONNX object: `press_rows`)."""
    entry = reference_entry(m, rows, source)
    write_entry(m, entry)
    return entry


def write_entry(m: onnx.ModelProto, entry: dict) -> None:
    """Writes `entry` as `m`'s `haptics.reference`, replacing any (one entry per model)."""
    keep = [p for p in m.metadata_props if p.key != REFERENCE_KEY]
    del m.metadata_props[:]
    m.metadata_props.extend(keep)
    m.metadata_props.add(key=REFERENCE_KEY, value=json.dumps(entry, separators=(",", ":")))


def add_reference(m: onnx.ModelProto, rec: Recording, features: tuple[str, ...]) -> dict:
    """Computes the reference steps of `m` on `rec` and writes them into its metadata
    (replacing any); returns the entry."""
    return add_reference_rows(m, reference_rows(rec, features), f"{rec.name}, rows in contact")


def check_reference(m: onnx.ModelProto) -> str | None:
    """What is wrong with `m`'s reference steps on this machine (malformed, or a force further
    than its tolerance from the recorded one), or None: none carried, or every step agrees.
    The same check as infer-server's at load (docs/model-contract.md)."""
    text = next((p.value for p in m.metadata_props if p.key == REFERENCE_KEY), None)
    if text is None:
        return None
    try:
        doc = json.loads(text)
        rows = np.asarray(doc["inputs"], dtype=np.float32)
        want = np.asarray(doc["force"], dtype=np.float32)
        tol = float(doc["tolerance_n"])
    except (ValueError, KeyError, TypeError) as e:
        return f"{REFERENCE_KEY} is malformed: {e}"
    if rows.ndim != 2 or len(rows) != len(want) or not len(rows) or not np.isfinite(tol):
        return f"{REFERENCE_KEY} is malformed: {rows.shape} inputs for {want.shape} forces"
    stepper = OnnxStepper(m)
    for i, (r, f) in enumerate(zip(rows, want, strict=True)):
        got = stepper.step(r)
        if not abs(got - float(f)) <= tol:
            return (f"{REFERENCE_KEY}: step {i} of {len(rows)} computes {got:.9g} N where the "
                    f"export computed {float(f):.9g} N (tolerance {tol:g} N): this ONNX Runtime "
                    "or fused-operator library reads the graph otherwise, or the graph was "
                    "changed after its export")  # fmt: skip
    return None
