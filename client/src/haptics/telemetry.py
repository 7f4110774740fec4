"""Live telemetry as columns: NumPy arrays, a polars frame, or a pandas frame.

Each gRPC `TelemetrySample` is one bucket of `steps` loop steps. Its single-valued fields (the
bucket's last step) become columns of the same name; its `min` and `max` lists become
`<series>_min` and `<series>_max` for every series of the web protocol, named by the generated
vocabulary (`haptics_train.vocab.SERIES`, written from the Rust crate), so nothing here repeats
the schema by hand."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl
from haptics_train.vocab import SERIES

from .v1 import haptics_pb2 as pb

if TYPE_CHECKING:
    import pandas

def is_repeated(f: Any) -> bool:
    """A descriptor's repeated field (protobuf >= 6 says `is_repeated`; older ones `label`)."""
    return bool(f.is_repeated) if hasattr(f, "is_repeated") else f.label == f.LABEL_REPEATED


#: The sample's scalar fields, in the .proto's order (read from the generated descriptor).
SCALAR_FIELDS: tuple[str, ...] = tuple(
    f.name for f in pb.TelemetrySample.DESCRIPTOR.fields if not is_repeated(f)
)


def _dtype(name: str) -> type:
    f = pb.TelemetrySample.DESCRIPTOR.fields_by_name[name]
    if f.type == f.TYPE_BOOL:
        return np.bool_
    if f.type in (f.TYPE_UINT64, f.TYPE_UINT32):
        return np.uint64
    return np.float64


@dataclass
class Telemetry:
    """A window of telemetry: `columns` maps each column name to a NumPy array (one entry per
    bucket). `decimation` is the loop steps per bucket the server was asked for."""

    columns: dict[str, np.ndarray]
    decimation: int
    #: the loop's step counter when the window opened and closed (from the status), so
    #: `steps_received / steps_produced` says whether the client kept up
    steps_produced: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.columns["step"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    @property
    def steps_received(self) -> int:
        """Loop steps the buckets cover (the sum of their `steps`)."""
        return int(self.columns["steps"].sum()) if len(self) else 0

    def to_polars(self) -> pl.DataFrame:
        return pl.DataFrame(self.columns)

    def to_pandas(self) -> pandas.DataFrame:
        """Needs pandas (`pip install pandas`; not a dependency of this package)."""
        import pandas

        return pandas.DataFrame(self.columns)


def column_names() -> list[str]:
    return [*SCALAR_FIELDS, *(f"{s}_min" for s in SERIES), *(f"{s}_max" for s in SERIES)]


def to_columns(samples: Iterable[pb.TelemetrySample]) -> dict[str, np.ndarray]:
    """Samples as one NumPy array per column (empty arrays for no samples)."""
    rows = list(samples)
    cols: dict[str, np.ndarray] = {}
    for name in SCALAR_FIELDS:
        cols[name] = np.fromiter((getattr(r, name) for r in rows), _dtype(name), len(rows))
    n = len(SERIES)
    for which in ("min", "max"):
        m = np.full((len(rows), n), np.nan)
        for i, r in enumerate(rows):
            v = getattr(r, which)
            k = min(len(v), n)  # an older server may send fewer series: the rest stay NaN
            m[i, :k] = v[:k]
        for j, s in enumerate(SERIES):
            cols[f"{s}_{which}"] = m[:, j]
    return cols
