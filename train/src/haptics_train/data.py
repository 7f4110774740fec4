"""Recordings (docs/recording-format.md) as column arrays, and the dataset: which recordings
train, which validate (every choice is made on them) and which test (scored once).

This is also the one place where recordings become the arrays the models take
(`training_arrays`): decimated rows for the stateless models, whole sequences for the stateful
ones (`models.base` describes both layouts); the models never see a `Recording`.

A dataset is either a folder (the bench's own convention: `train_*.parquet`,
`validation_*.parquet`, `test_*.parquet`) or a TOML manifest naming each recording with its
role, source and notes (`load_manifest`), for data that did not come from the bench."""

from __future__ import annotations

import hashlib
import json
import re
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from .features import F_PREVIOUS, NINE, RATIO_DIVISORS, TARGET_DEFAULT

#: Columns a recording must have for training (the rest of the format is optional here).
REQUIRED_COLUMNS: tuple[str, ...] = ("time", TARGET_DEFAULT, *NINE)


class DataError(ValueError):
    """A recording or dataset that cannot be used, with the reason."""


@dataclass
class Recording:
    """One recording: every column as a float64 numpy array, at the loop rate."""

    name: str
    columns: dict[str, np.ndarray]
    meta: dict = field(default_factory=dict)
    source: str = ""
    sha256: str = ""
    #: where the data came from and remarks (a manifest's `source` and `notes`)
    origin: str = ""
    notes: str = ""

    @property
    def sample_rate_hz(self) -> float:
        """Rows per second (the median period of the time column)."""
        t = self.columns["time"]
        d = np.diff(t[: min(len(t), 100_000)])
        d = d[d > 0]
        return float(1.0 / np.median(d)) if len(d) else float("nan")

    @property
    def feature_gains(self) -> tuple[float, float] | None:
        """(g_v, g_a), rad/s: the velocity and acceleration filters its features were computed
        with (an import's `filters`, a bench recording's loop `params`); None where unknown."""
        run = self.meta.get("haptics.run") or {}
        src = run.get("filters") or ((run.get("config") or {}).get("params")) or {}
        g_v, g_a = src.get("g_v"), src.get("g_a")
        if isinstance(g_v, int | float) and isinstance(g_a, int | float):
            return float(g_v), float(g_a)
        return None

    @property
    def row_step(self) -> int:
        """Control steps per row (rt-loop's recorder decimation)."""
        return row_step(self.columns)

    def __len__(self) -> int:
        return len(self.columns["time"])

    def head(self, n: int) -> Recording:
        """The first n control steps (a causal prefix: closed loop on it equals the prefix of
        the closed loop on the whole recording)."""
        cols = {k: v[:n] for k, v in self.columns.items()}
        return Recording(
            self.name, cols, self.meta, self.source, self.sha256, self.origin, self.notes
        )

    def column(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise DataError(f"{self.name}: no column {name!r}") from None

    def matrix(self, features: tuple[str, ...] | list[str], stride: int = 1) -> np.ndarray:
        """Features as an [n, f] float64 matrix, rows 0, stride, 2*stride, ..."""
        return np.column_stack([self.column(f)[::stride] for f in features])

    def target(self, name: str = TARGET_DEFAULT, stride: int = 1) -> np.ndarray:
        return self.column(name)[::stride]

    @property
    def ramp_rate(self) -> float | None:
        run = self.meta.get("haptics.run")
        if isinstance(run, dict) and "ramp_rate" in run:
            try:
                return float(run["ramp_rate"])
            except (TypeError, ValueError):
                return None
        m = re.search(r"_(\d+(?:\.\d+)?)$", self.name)
        return float(m.group(1)) if m else None


def add_previous_force(columns: dict[str, np.ndarray], target: str = TARGET_DEFAULT) -> None:
    """`f_previous`: the force response of the previous *control step*, F(t-1).

    rt-loop may record only every k-th step (`--decimate`), so the previous row is not
    necessarily the previous step. The ratio features hold F(t-1) exactly as the loop saw it:
    F(t-1) = f_previous_x * x (or * v, or * a, whichever divisor is non-zero). Only where all
    three divisors are zero (the loop held every ratio: the probe at rest) does this fall back
    to the previous row's force response (interpolated towards this row's when rows are k > 1
    steps apart). Before the first committed force the ratios are 0, and so is this.
    """
    f = columns[target]
    prev = np.full(len(f), np.nan)
    for ratio, div in RATIO_DIVISORS.items():
        if ratio in columns and div in columns:
            ok = np.isnan(prev) & (columns[div] != 0)
            prev[ok] = columns[ratio][ok] * columns[div][ok]
    miss = np.isnan(prev)
    shifted = np.concatenate([[0.0], f[:-1]])
    k = row_step(columns)
    if k > 1:
        # rows k steps apart: F(t-1) interpolated between the previous row (t-k) and this one
        shifted = shifted + (k - 1) / k * (f - shifted)
    prev[miss] = shifted[miss]
    columns[F_PREVIOUS] = prev


def row_step(columns: dict[str, np.ndarray]) -> int:
    """Control steps between consecutive rows (1 unless rt-loop recorded with --decimate)."""
    st = columns.get("step")
    if st is None or len(st) < 2:
        return 1
    d = np.diff(st[: min(len(st), 10_000)])
    return max(int(np.median(d)), 1)


def loop_rate_hz(rec: Recording) -> float:
    """The rate of the loop that recorded `rec` (its haptics.run metadata's `rate_hz`), Hz;
    NaN for data rt-loop did not record (imported from a testing machine)."""
    run = rec.meta.get("haptics.run")
    cfg = run.get("config") if isinstance(run, dict) else None
    try:
        rate = float(cfg["rate_hz"]) if isinstance(cfg, dict) else float("nan")
    except (KeyError, TypeError, ValueError):
        return float("nan")
    return rate if np.isfinite(rate) and rate > 0 else float("nan")


def contact_thresholds(rec: Recording) -> tuple[float, float]:
    """The recording's feature parameters (haptics.run metadata), else rt-loop's defaults."""
    run = rec.meta.get("haptics.run")
    on, off = 0.5, 0.25
    if isinstance(run, dict):
        cfg = run.get("config") if isinstance(run.get("config"), dict) else {}
        for fp in (run.get("features"), cfg.get("features")):
            if isinstance(fp, dict):
                on = float(fp.get("contact_on_n", on))
                off = float(fp.get("contact_off_n", off))
        params = run.get("params")
        if isinstance(params, dict) and isinstance(params.get("features"), dict):
            on = float(params["features"].get("contact_on_n", on))
            off = float(params["features"].get("contact_off_n", off))
    return on, off


def row_stride(rec: Recording, decimate: int | None, target_rate_hz: float = 500.0) -> int:
    """Rows between kept rows: `decimate` control steps, else the recording's row rate over the
    target rate (at least 1)."""
    if decimate is not None:
        return max(1, round(decimate / rec.row_step))
    rate = rec.sample_rate_hz
    return max(1, round(rate / target_rate_hz)) if np.isfinite(rate) else 1


def to_rows(
    recs: Sequence[Recording],
    columns: Sequence[str],
    target: str = TARGET_DEFAULT,
    decimate: int | None = None,
    target_rate_hz: float = 500.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The rows layout: decimated rows of all recordings, X [n, len(columns)] float64 and
    y [n]; rows with a non-finite value in X or y dropped."""
    strides = [row_stride(r, decimate, target_rate_hz) for r in recs]
    xs = [r.matrix(tuple(columns), k) for r, k in zip(recs, strides, strict=True)]
    ys = [r.target(target, k) for r, k in zip(recs, strides, strict=True)]
    x = np.concatenate(xs)
    y = np.concatenate(ys)
    ok = np.isfinite(x).all(axis=1) & np.isfinite(y)
    return x[ok], y[ok]


@dataclass(frozen=True)
class SequenceInfo:
    """What a stateful model needs to know of one training sequence besides its arrays."""

    #: rows per second: the state steps once per row
    sample_rate_hz: float
    #: time of the last row minus the first, s
    duration_s: float
    #: rows between the rows per-row statistics are taken on (the stateless models' decimation)
    stride: int
    #: control steps per row (1 unless rt-loop recorded with --decimate)
    row_step: int
    #: the contact-off force threshold of the recording's feature parameters, N
    contact_off_n: float
    #: the rate of the loop that recorded it (rt-loop's `rate_hz`), Hz; NaN where unknown
    #: (imported data): a model whose state steps in time is served once per step of this loop
    loop_rate_hz: float = float("nan")
    #: how long the probe must have slid one way before a row counts for the models that fit
    #: the bench's friction (models/contact_rows.py, `settled`), s: three time constants of the
    #: velocity filter of an rt-loop recording (its `g_v`); 0 where unknown (imported data)
    settle_s: float = 0.0


def settle_s(rec: Recording) -> float:
    """Three time constants of the velocity filter `rec`'s kinematics were estimated with
    (rt-loop's `g_v`, rad/s: 0.1 s at the default 30 rad/s), for a recording of rt-loop's; 0
    for an import (its velocity is the testing machine's, and no bench's friction sticks in
    its force). Why three: after a reversal the recorded velocity lags the probe's by about
    1/g_v, so for that long its sign is not the friction's (contact_rows.py)."""
    run = rec.meta.get("haptics.run")
    if not isinstance(run, dict) or run.get("filters"):
        return 0.0
    g = ((run.get("config") or {}).get("params") or {}).get("g_v")
    return 3.0 / float(g) if isinstance(g, int | float) and g > 0 else 0.0


def to_sequences(
    recs: Sequence[Recording],
    columns: Sequence[str],
    target: str = TARGET_DEFAULT,
    decimate: int | None = None,
    target_rate_hz: float = 500.0,
) -> tuple[list[np.ndarray], list[np.ndarray], list[SequenceInfo]]:
    """The sequences layout: every recording whole, every row in time order: X_i [n_i,
    len(columns)], y_i [n_i] and its `SequenceInfo`, one per recording."""
    xs = [r.matrix(tuple(columns)) for r in recs]
    ys = [r.target(target) for r in recs]
    info = [
        SequenceInfo(
            sample_rate_hz=r.sample_rate_hz,
            duration_s=float(r.columns["time"][-1] - r.columns["time"][0]),
            stride=row_stride(r, decimate, target_rate_hz),
            row_step=r.row_step,
            contact_off_n=contact_thresholds(r)[1],
            loop_rate_hz=loop_rate_hz(r),
            settle_s=settle_s(r),
        )
        for r in recs
    ]
    return xs, ys, info


def training_arrays(
    recs: Sequence[Recording],
    features: Sequence[str],
    layout: str,
    aux_columns: Sequence[str] = (),
    target: str = TARGET_DEFAULT,
    decimate: int | None = None,
    target_rate_hz: float = 500.0,
) -> tuple[object, object, dict[str, object]]:
    """(X, y, fit_params) for a model's `fit(X, y, **fit_params)`, in its `layout`:

    - `rows`: `to_rows` of `features` (and `aux_columns`, taken from the same rows and passed
      as `aux` [n, len(aux_columns)]);
    - `sequences`: `to_sequences`, with `info` (one `SequenceInfo` per sequence) and, with
      `aux_columns`, `aux` (one [n_i, len(aux_columns)] array per sequence).
    """
    nf = len(features)
    cols = (*features, *aux_columns)
    if layout == "rows":
        xa, y = to_rows(recs, cols, target, decimate, target_rate_hz)
        params: dict[str, object] = {"aux": xa[:, nf:]} if aux_columns else {}
        return xa[:, :nf], y, params
    if layout == "sequences":
        xas, ys, info = to_sequences(recs, cols, target, decimate, target_rate_hz)
        params = {"info": info}
        if aux_columns:
            params["aux"] = [xa[:, nf:] for xa in xas]
        return [xa[:, :nf] for xa in xas], ys, params
    raise ValueError(f"unknown layout {layout!r} (rows|sequences)")


def same_object(recorded: str, material: str) -> bool:
    """Whether a recording's material text (its `haptics.run` metadata's `material`: the file
    rt-loop read) describes the object of `material`, a material file's text. Compared as
    TOML tables with `law` as rt-loop reads it (`"foam"` where a file names none), so an edited
    comment, or the law written out, is the same object; any value changed is another.
    `scripts/up.sh` refuses a dataset recorded on another object. Raises
    `tomllib.TOMLDecodeError` for a text that is not TOML."""

    def tables(text: str) -> dict:
        doc = tomllib.loads(text)
        doc.setdefault("law", "foam")
        return doc

    return tables(recorded) == tables(material)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _table_to_columns(table: pa.Table) -> dict[str, np.ndarray]:
    cols: dict[str, np.ndarray] = {}
    for name in table.column_names:
        col = table.column(name)
        if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
            continue
        arr = col.to_numpy(zero_copy_only=False)
        cols[name] = np.asarray(arr, dtype=np.float64)
    return cols


def load_recording(path: str | Path, name: str | None = None) -> Recording:
    """Reads a Parquet (or CSV with a `.meta.json` sidecar) recording and checks its columns."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"no such recording: {path}")
    meta: dict = {}
    try:
        if path.suffix.lower() == ".csv":
            table = pacsv.read_csv(path)
            side = path.with_suffix(".meta.json")
            if side.exists():
                meta = json.loads(side.read_text())
        else:
            pf = pq.ParquetFile(path)
            table = pf.read()
            # The Rust writer puts key-value metadata in the file footer; pyarrow writers put
            # it in the Arrow schema. Read both.
            kv = {**(pf.metadata.metadata or {}), **(pf.schema_arrow.metadata or {})}
            for k, v in kv.items():
                key = k.decode(errors="replace")
                if not key.startswith("haptics."):
                    continue
                text = v.decode(errors="replace")
                try:
                    meta[key] = json.loads(text)
                except json.JSONDecodeError:
                    meta[key] = text
    except (OSError, pa.ArrowException) as e:
        raise DataError(f"cannot read recording {path}: {e}") from e
    cols = _table_to_columns(table)
    missing = [c for c in REQUIRED_COLUMNS if c not in cols]
    if missing:
        raise DataError(f"{path}: missing columns {missing} (see docs/recording-format.md)")
    if len(cols["time"]) < 3:
        raise DataError(f"{path}: only {len(cols['time'])} rows")
    check_finite(cols, str(path))
    add_previous_force(cols)
    return Recording(
        name=name or path.stem, columns=cols, meta=meta, source=str(path), sha256=sha256_file(path)
    )


def check_finite(cols: dict[str, np.ndarray], where: str) -> None:
    """Every required column finite on every row: one NaN force would poison the ratio
    features of every later row, so it is refused with its row (data rows from 1)."""
    for c in REQUIRED_COLUMNS:
        bad = ~np.isfinite(cols[c])
        if bad.any():
            i = int(np.argmax(bad))
            raise DataError(
                f"{where}: row {i + 1}: column {c!r} is {cols[c][i]} ({int(bad.sum())} "
                "non-finite rows); re-import it (haptics-train import --repair interpolates)"
            )


def recording_from_columns(
    name: str, columns: dict[str, np.ndarray], meta: dict | None = None
) -> Recording:
    cols = {k: np.asarray(v, dtype=np.float64) for k, v in columns.items()}
    missing = [c for c in REQUIRED_COLUMNS if c not in cols]
    if missing:
        raise DataError(f"{name}: missing columns {missing}")
    check_finite(cols, name)
    add_previous_force(cols)
    return Recording(name=name, columns=cols, meta=meta or {})


ROLES = ("train", "validation", "test")


@dataclass
class Dataset:
    train: list[Recording]
    test: list[Recording]
    root: str = ""
    #: recordings every choice is made on (hyperparameters, feedback noise, the recommended
    #: model); empty when the dataset has none, and then nothing is chosen on data
    validation: list[Recording] = field(default_factory=list)
    #: the manifest file it came from ("" for a folder)
    manifest: str = ""

    def split(self, role: str) -> list[Recording]:
        return {"train": self.train, "validation": self.validation, "test": self.test}[role]

    def describe(self) -> list[dict]:
        out = []
        for split in ROLES:
            for r in self.split(split):
                out.append(
                    {
                        "split": split,
                        "name": r.name,
                        "rows": len(r),
                        "duration_s": float(r.columns["time"][-1] - r.columns["time"][0]),
                        "sample_rate_hz": r.sample_rate_hz,
                        "ramp_rate": r.ramp_rate,
                        "row_step": r.row_step,
                        "sha256": r.sha256[:16],
                        "source": r.origin,
                        "notes": r.notes,
                    }
                )
        return out


def load_dataset(root: str | Path) -> Dataset:
    """The bench's folder convention: `train_*.parquet` train, `validation_*.parquet` (optional)
    validate, `test_*.parquet` are held out."""
    root = Path(root)
    if not root.is_dir():
        raise DataError(
            f"dataset directory {root} does not exist (record it with scripts/record-dataset.sh)"
        )
    train = [load_recording(p) for p in sorted(root.glob("train_*.parquet"))]
    val = [load_recording(p) for p in sorted(root.glob("validation_*.parquet"))]
    test = [load_recording(p) for p in sorted(root.glob("test_*.parquet"))]
    if not train:
        raise DataError(f"{root}: no train_*.parquet recordings")
    if not test:
        raise DataError(f"{root}: no test_*.parquet recording (held-out ramp rate)")
    for r in (*train, *val, *test):
        r.origin = r.origin or "rt-loop recording"
    return Dataset(train=train, test=test, root=str(root), validation=val)


def load_manifest(path: str | Path) -> Dataset:
    """A TOML manifest: one table per recording, named by its key.

    ```toml
    [recordings.slow]
    path = "imported/rate_0.01.parquet"   # relative to the manifest's folder
    role = "train"                        # train | validation | test
    source = "Instron 5944, sample A, 2024-03-02"
    notes = "one cycle, 0.01 /s"
    ```
    """
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(f"no such manifest: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{path}: not valid TOML: {e}") from None
    recs = doc.get("recordings")
    if not isinstance(recs, dict) or not recs:
        raise DataError(f"{path}: no [recordings.<name>] tables")
    unknown = set(doc) - {"recordings", "name", "notes"}
    if unknown:
        raise DataError(f"{path}: unknown keys {sorted(unknown)} (recordings, name, notes)")
    by_role: dict[str, list[Recording]] = {r: [] for r in ROLES}
    for name, e in recs.items():
        if not isinstance(e, dict):
            raise DataError(f"{path}: recordings.{name} must be a table")
        bad = set(e) - {"path", "role", "source", "notes"}
        if bad:
            raise DataError(f"{path}: recordings.{name}: unknown keys {sorted(bad)}")
        role = e.get("role")
        if role not in ROLES:
            raise DataError(f"{path}: recordings.{name}: role must be one of {ROLES}, not {role!r}")
        if not isinstance(e.get("path"), str):
            raise DataError(f"{path}: recordings.{name}: no path")
        p = Path(e["path"])
        rec = load_recording(p if p.is_absolute() else path.parent / p, name=name)
        rec.origin = str(e.get("source", ""))
        rec.notes = str(e.get("notes", ""))
        by_role[role].append(rec)
    if not by_role["train"]:
        raise DataError(f"{path}: no recording with role = \"train\"")
    if not by_role["test"]:
        raise DataError(
            f"{path}: no recording with role = \"test\": every model is scored once on a test "
            "recording no choice has seen; set one aside (haptics-train import ... --manifest "
            f"{path} --role test), e.g. a test at another rate or depth"
        )
    return Dataset(
        train=by_role["train"], test=by_role["test"], validation=by_role["validation"],
        root=str(path.parent), manifest=str(path),
    )  # fmt: skip


def write_manifest_entry(
    path: str | Path, name: str, rec_path: str | Path, role: str, source: str, notes: str = ""
) -> None:
    """Adds (or replaces) one recording in a manifest, keeping the others as they are."""
    if role not in ROLES:
        raise DataError(f"role must be one of {ROLES}, not {role!r}")
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise DataError(f"manifest name {name!r}: use letters, digits, _ . -")
    path = Path(path)
    doc = tomllib.loads(path.read_text()) if path.exists() else {}
    recs = doc.setdefault("recordings", {})
    rp = Path(rec_path).resolve()
    try:
        rel = str(rp.relative_to(path.parent.resolve()))
    except ValueError:
        rel = str(rp)
    recs[name] = {"path": rel, "role": role, "source": source, "notes": notes}
    lines = ["# dataset manifest (haptics-train --manifest); roles: train, validation, test"]
    for k in ("name", "notes"):
        if k in doc:
            lines.append(f"{k} = {json.dumps(str(doc[k]))}")
    for n, e in recs.items():
        lines += ["", f"[recordings.{json.dumps(n)}]"]
        lines += [f"{k} = {json.dumps(str(v))}" for k, v in e.items()]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def load_data(dataset: str | Path, manifest: str | Path | None = None) -> Dataset:
    """A manifest when given, else the folder convention."""
    return load_manifest(manifest) if manifest else load_dataset(dataset)
