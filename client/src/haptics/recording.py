"""Recordings read into a frame with their metadata, by the training code's own reader
(`haptics_train.data.load_recording`: the same checks, the same `f_previous` column)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl
from haptics_train.data import load_recording

if TYPE_CHECKING:
    import pandas


@dataclass
class RecordingFrame:
    """A recording: `frame` (polars, one row per recorded step, every column as float64, as
    haptics-train reads it) and `meta` (the file's `haptics.*` metadata: `meta["haptics.run"]`
    holds the experiment, board, material, seed, clock, ramp rate and loop parameters)."""

    frame: pl.DataFrame
    meta: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None
    name: str = ""

    @property
    def run(self) -> dict[str, Any]:
        """The run's metadata (`haptics.run`), or {} when the file has none."""
        r = self.meta.get("haptics.run")
        return r if isinstance(r, dict) else {}

    def __len__(self) -> int:
        return self.frame.height

    def __getitem__(self, column: str) -> np.ndarray:
        return self.frame[column].to_numpy()

    def to_pandas(self) -> pandas.DataFrame:
        """Needs pandas (not a dependency of this package)."""
        return self.frame.to_pandas()


def read_recording(path: str | Path) -> RecordingFrame:
    """A Parquet or CSV recording (docs/recording-format.md), or an MCAP one written by
    `rt-loop run --format mcap` (converted in memory first). Raises haptics_train's DataError
    with the reason when the file cannot be used."""
    p = Path(path)
    if p.suffix.lower() == ".mcap":
        from .mcap_format import read_mcap_table

        columns, meta = read_mcap_table(p)
        from haptics_train.data import recording_from_columns

        rec = recording_from_columns(p.stem, columns, meta)
    else:
        rec = load_recording(p)
    return RecordingFrame(pl.DataFrame(rec.columns), rec.meta, p, rec.name)
