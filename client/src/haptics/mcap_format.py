"""MCAP recordings: read them, and convert Parquet recordings to MCAP and back, losing nothing.

The layout is rt-loop's (`rt-loop run --format mcap`, rt-loop/src/record/mcap_format.rs;
docs/recording-format.md, "MCAP"): JSON messages with a JSON Schema per channel, `/haptics/row`
(every recorded column), `/haptics/features` (step, time, the nine features),
`/haptics/phase` (an event per change of phase or cycle), `/haptics/run` (the run metadata,
also the file's Metadata record `haptics`). Each schema property names its Arrow type
(`x-arrow-type`), so MCAP -> Parquet restores the columns' exact types and order.

Command line (installed as `haptics-mcap`):

    haptics-mcap to-mcap data/dataset/train_1.8.parquet train_1.8.mcap
    haptics-mcap to-parquet train_1.8.mcap back.parquet
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from haptics_train.vocab import PHASE_NAMES, THESIS_FEATURES
from mcap.exceptions import McapError as McapReadError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

ROW_TOPIC = "/haptics/row"
FEATURES_TOPIC = "/haptics/features"
PHASE_TOPIC = "/haptics/phase"
RUN_TOPIC = "/haptics/run"
RUN_KEY = "haptics.run"
_DRAFT = "https://json-schema.org/draft/2020-12/schema"


class McapError(ValueError):
    """An MCAP file that is not a haptics recording, with the reason."""


def _json_type(t: pa.DataType) -> Any:
    if pa.types.is_boolean(t):
        return "boolean"
    if pa.types.is_integer(t):
        return "integer"
    return ["number", "null"]  # NaN has no JSON spelling: null


def _schema(title: str, description: str, fields: list[pa.Field]) -> bytes:
    return json.dumps({
        "$schema": _DRAFT, "title": title, "description": description, "type": "object",
        "properties": {f.name: {"type": _json_type(f.type), "x-arrow-type": str(f.type)}
                       for f in fields},
        "required": [f.name for f in fields],
    }).encode()  # fmt: skip


def _value(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else v


def parquet_to_mcap(src: str | Path, dst: str | Path) -> int:
    """Writes the Parquet recording `src` as MCAP `dst` (rt-loop's layout); returns the rows."""
    pf = pq.ParquetFile(src)
    table = pf.read()
    kv = {**(pf.metadata.metadata or {}), **(table.schema.metadata or {})}
    run_text = kv.get(RUN_KEY.encode(), b"null").decode()
    for name in table.column_names:
        col = table.column(name)
        if pa.types.is_floating(col.type) and not np.isnan(col.to_numpy()).all():
            vals = col.to_numpy()
            if np.isinf(vals).any():
                raise McapError(f"{src}: column {name} holds an infinity, which JSON cannot carry")
    fields = list(table.schema)
    feature_fields = [table.schema.field(n) for n in ("step", "time", *THESIS_FEATURES)]
    cols = {n: table.column(n).to_pylist() for n in table.column_names}
    n_rows = table.num_rows
    with open(dst, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="haptics-mcap (python)")
        row_ch = w.register_channel(ROW_TOPIC, "json", w.register_schema(
            "haptics.Row", "jsonschema",
            _schema("haptics.Row", "One recorded control step: the columns of "
                    "docs/recording-format.md", fields)))  # fmt: skip
        feat_ch = w.register_channel(FEATURES_TOPIC, "json", w.register_schema(
            "haptics.Features", "jsonschema",
            _schema("haptics.Features", "The nine features of thesis Table 3.1 at one recorded "
                    "step", feature_fields)))  # fmt: skip
        phase_schema = json.dumps({
            "$schema": _DRAFT, "title": "haptics.PhaseEvent",
            "description": "The experiment entered a phase (or a new cycle) at this step",
            "type": "object",
            "properties": {"step": {"type": "integer"}, "time": {"type": "number"},
                           "phase": {"type": "integer"},
                           "name": {"type": "string", "enum": list(PHASE_NAMES)},
                           "cycle_no": {"type": "integer"}},
            "required": ["step", "time", "phase", "name", "cycle_no"],
        }).encode()  # fmt: skip
        phase_ch = w.register_channel(
            PHASE_TOPIC, "json", w.register_schema("haptics.PhaseEvent", "jsonschema", phase_schema)
        )
        run_schema = json.dumps({
            "$schema": _DRAFT, "title": "haptics.Run",
            "description": "The run's metadata (haptics.run): experiment, board, material, seed, "
                           "clock, loop parameters",
            "type": "object", "properties": {"run": {"type": "object"}}, "required": ["run"],
        }).encode()  # fmt: skip
        run_ch = w.register_channel(
            RUN_TOPIC, "json", w.register_schema("haptics.Run", "jsonschema", run_schema)
        )
        w.add_message(run_ch, 0, json.dumps({"run": json.loads(run_text)}).encode(), 0, 0)
        if RUN_KEY.encode() in kv:
            w.add_metadata("haptics", {RUN_KEY: run_text})
        names = table.column_names
        fnames = [f.name for f in feature_fields]
        last: tuple[int, int] | None = None
        seq = 0
        for i in range(n_rows):
            t = int(round(max(cols["time"][i], 0.0) * 1e9))
            step = cols["step"][i]
            row = {n: _value(cols[n][i]) for n in names}
            w.add_message(row_ch, t, json.dumps(row).encode(), t, step & 0xFFFFFFFF)
            feats = {n: row[n] for n in fnames}
            w.add_message(feat_ch, t, json.dumps(feats).encode(), t, step & 0xFFFFFFFF)
            key = (row["phase"], row["cycle_no"])
            if key != last:
                last = key
                ev = {"step": step, "time": row["time"], "phase": key[0],
                      "name": PHASE_NAMES[key[0]] if key[0] < len(PHASE_NAMES) else "unknown",
                      "cycle_no": key[1]}  # fmt: skip
                w.add_message(phase_ch, t, json.dumps(ev).encode(), t, seq)
                seq += 1
        w.finish()
    return n_rows


def read_mcap(path: str | Path) -> tuple[pa.Table, dict[str, str]]:
    """The recording's rows as an Arrow table (columns in file order, their recorded types)
    and its key-value metadata (`haptics.run`), read with the official MCAP reader."""
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        meta: dict[str, str] = {}
        for m in reader.iter_metadata():
            if m.name == "haptics":
                meta.update(m.metadata)
        fields: list[pa.Field] | None = None
        rows: dict[str, list] = {}
        for schema, _channel, message in reader.iter_messages(topics=[ROW_TOPIC]):
            if fields is None:
                s = json.loads(schema.data)
                props = s["properties"]
                fields = [pa.field(n, pa.type_for_alias(props[n]["x-arrow-type"]), False)
                          for n in s["required"]]  # fmt: skip
                rows = {f.name: [] for f in fields}
            d = json.loads(message.data)
            for n, col in rows.items():
                col.append(d[n])
    if fields is None:
        raise McapError(f"{path}: no {ROW_TOPIC} messages: not a haptics recording")
    arrays = []
    for f in fields:
        v = rows[f.name]
        if pa.types.is_floating(f.type):
            arrays.append(pa.array([math.nan if x is None else x for x in v], f.type))
        else:
            arrays.append(pa.array(v, f.type))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields)), meta


def read_mcap_table(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Columns as float64 arrays and the metadata parsed as haptics_train reads it."""
    table, kv = read_mcap(path)
    cols = {n: np.asarray(table.column(n).to_numpy(zero_copy_only=False), dtype=np.float64)
            for n in table.column_names}  # fmt: skip
    meta: dict[str, Any] = {}
    for k, v in kv.items():
        try:
            meta[k] = json.loads(v)
        except json.JSONDecodeError:
            meta[k] = v
    return cols, meta


def mcap_to_parquet(src: str | Path, dst: str | Path) -> int:
    """Writes the MCAP recording `src` as Parquet `dst` with its `haptics.run` metadata;
    returns the rows."""
    table, kv = read_mcap(src)
    table = table.replace_schema_metadata({k.encode(): v.encode() for k, v in kv.items()})
    pq.write_table(table, dst, compression="zstd")
    return table.num_rows


def _atomic(convert: Callable[[Path, Path], int], src: Path, dst: Path) -> int:
    """Writes `<dst>.partial`, renamed to `dst` only once complete: a failed conversion never
    leaves a file that looks finished."""
    tmp = dst.with_name(dst.name + ".partial")
    try:
        n = convert(src, tmp)
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)
    return n


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="haptics-mcap", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    for name, help_ in (("to-mcap", "Parquet recording -> MCAP"),
                        ("to-parquet", "MCAP recording -> Parquet")):  # fmt: skip
        s = sub.add_parser(name, help=help_)
        s.add_argument("src", type=Path)
        s.add_argument("dst", type=Path)
        s.add_argument("--overwrite", action="store_true", help="replace an existing DST")
    a = p.parse_args(argv)
    if a.dst.exists() and not a.overwrite:
        print(f"haptics-mcap: {a.dst} exists (pass --overwrite to replace it)", file=sys.stderr)
        return 1
    try:
        n = _atomic(parquet_to_mcap if a.cmd == "to-mcap" else mcap_to_parquet, a.src, a.dst)
    except (OSError, McapError, McapReadError, pa.ArrowException, ValueError) as e:
        print(f"haptics-mcap: {e}", file=sys.stderr)
        return 1
    print(f"haptics-mcap: {a.src} -> {a.dst}: {n} rows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
