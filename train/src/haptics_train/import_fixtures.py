"""External-looking input files for the import, generated (not committed): what a testing
machine or another rig exports, with the problems such files have. The tests run every case,
and `python -m haptics_train.import_fixtures` prints the table in docs/train.md (input, what
the import did), computed by running the import on each.

Every series is one SYNTHETIC loading-unloading cycle of `viscoelastic.Elastomer` at 50 Hz
unless the case says otherwise; the last case is a REAL AFM curve (tests/data/SOURCE.md).
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from .data import DataError
from .viscoelastic import loading_unloading


def cycle(rate_mm_s: float = 2.0, sample_hz: float = 50.0) -> dict[str, np.ndarray]:
    return loading_unloading(rate_mm_s, sample_hz=sample_hz, seed=7)


def _write(path: Path, cols: dict[str, np.ndarray | list]) -> Path:
    pacsv.write_csv(pa.table(cols), path)
    return path


def _write_text(path: Path, header: list[str], rows: list[list[str]]) -> Path:
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return path


def _rows(*cols: np.ndarray) -> list[list[str]]:
    return [[repr(float(v)) for v in r] for r in zip(*cols, strict=True)]


@dataclass
class Case:
    name: str
    what: str
    make: Callable[[Path], Path]
    kwargs: dict = field(default_factory=dict)
    #: None: the import must succeed; else a substring of the refusal
    refused: str | None = None


#: the columns of the `time [s]`, `displacement [mm]`, `force [N]` files, named without units
STD = {"time_col": "time", "position_col": "displacement", "force_col": "force"}


def _headers_mm_n(p: Path) -> Path:
    c = cycle()
    return _write(p, {"time [s]": c["time"], "displacement [mm]": c["displacement"],
                      "force [N]": c["force"]})  # fmt: skip


def _plain_mn(p: Path) -> Path:
    c = cycle()
    return _write(p, {"t": c["time"], "x": c["displacement"], "F": 1e3 * c["force"]})


def _header_mn(p: Path) -> Path:
    c = cycle()
    return _write(p, {"time (s)": c["time"], "displacement (mm)": c["displacement"],
                      "force [mN]": 1e3 * c["force"]})  # fmt: skip


def _nan_holes(p: Path) -> Path:
    c = cycle()
    rows = _rows(c["time"], c["displacement"], c["force"])
    for i in (100, 101, 102):
        rows[i][2] = ""  # empty cells, as a logger writes a dropped sample
    rows[200][2] = "NaN"
    return _write_text(p, ["time [s]", "displacement [mm]", "force [N]"], rows)


def _backwards(p: Path) -> Path:
    c = cycle()
    t = c["time"].copy()
    t[300] = t[298]  # a clock that steps back once
    return _write(p, {"time [s]": t, "displacement [mm]": c["displacement"],
                      "force [N]": c["force"]})  # fmt: skip


def _gap(p: Path) -> Path:
    c = cycle()
    keep = np.ones(len(c["time"]), dtype=bool)
    keep[150:200] = False  # one second lost
    return _write(p, {"time [s]": c["time"][keep], "displacement [mm]": c["displacement"][keep],
                      "force [N]": c["force"][keep]})  # fmt: skip


def _tension(p: Path) -> Path:
    c = cycle()
    return _write(p, {"time [s]": c["time"], "displacement [mm]": -c["displacement"],
                      "force [N]": -c["force"]})  # fmt: skip


def _ms_um(p: Path) -> Path:
    c = cycle(sample_hz=1000.0)
    return _write(p, {"t (ms)": 1e3 * c["time"], "depth (µm)": 1e3 * c["displacement"],
                      "load [N]": c["force"]})  # fmt: skip


def _text_cell(p: Path) -> Path:
    c = cycle()
    rows = _rows(c["time"], c["displacement"], c["force"])
    rows[42][1] = "overload"
    return _write_text(p, ["time [s]", "displacement [mm]", "force [N]"], rows)


def _decimal(v: float, digits: int) -> str:
    return f"{v:.{digits}f}".replace(".", ",")


def _zwick(p: Path) -> Path:
    """As a German-language testing machine exports a test: a protocol preamble, `;` between
    cells, decimal commas, units in brackets, Windows-1252 text (`Prüfkraft`)."""
    c = cycle()
    lines = ["Prüfprotokoll;Probe A", "Prüfer;M. Müller", "Datum;20.11.2026", "",
             "Zeit [s];Standardweg [mm];Prüfkraft [N]"]  # fmt: skip
    for t, x, f in zip(c["time"], c["displacement"], c["force"], strict=True):
        lines.append(f"{_decimal(t, 3)};{_decimal(x, 5)};{_decimal(f, 5)}")
    p.write_bytes(("\r\n".join(lines) + "\r\n").encode("cp1252"))
    return p


def _units_row(p: Path) -> Path:
    """Quoted cells and the units in a row of their own under the header, as some testing
    software writes its raw data."""
    c = cycle()
    lines = ['"Time","Extension","Load"', '"(s)","(mm)","(N)"']
    for t, x, f in zip(c["time"], c["displacement"], c["force"], strict=True):
        lines.append(f'"{t:.5f}","{x:.5f}","{f:.5f}"')
    p.write_text("\n".join(lines) + "\n")
    return p


def _tabs(p: Path) -> Path:
    c = cycle()
    lines = ["time [s]\tdisplacement [mm]\tforce [N]"]
    lines += [f"{t:.3f}\t{x:.5f}\t{f:.5f}" for t, x, f in zip(c["time"], c["displacement"],
                                                            c["force"], strict=True)]  # fmt: skip
    p.write_text("\n".join(lines) + "\n")
    return p


def _no_time(p: Path) -> Path:
    """A DAQ's samples: force and displacement, no time column."""
    c = cycle()
    lines = ["force [N];displacement [mm]"]
    lines += [f"{_decimal(f, 5)};{_decimal(x, 5)}" for x, f in zip(c["displacement"], c["force"],
                                                                   strict=True)]  # fmt: skip
    p.write_text("\n".join(lines) + "\n")
    return p


def _mixed_marks(p: Path) -> Path:
    c = cycle()
    lines = ["time [s];displacement [mm];force [N]"]
    for i, (t, x, f) in enumerate(zip(c["time"], c["displacement"], c["force"], strict=True)):
        cell = f"{f:.5f}" if i == 300 else _decimal(f, 5)  # one cell from another locale
        lines.append(f"{_decimal(t, 3)};{_decimal(x, 5)};{cell}")
    p.write_text("\n".join(lines) + "\n")
    return p


#: the one REAL input (tests/data/SOURCE.md: an AFM approach-retract curve, MIT licence)
AFM_SAMPLE = Path(__file__).resolve().parents[2] / "tests" / "data" / "afm-cellhesion-fd.csv"


def _afm(p: Path) -> Path:
    if not AFM_SAMPLE.is_file():
        raise FileNotFoundError(f"{AFM_SAMPLE} (in the source tree only)")
    p.write_bytes(AFM_SAMPLE.read_bytes())
    return p


def _refused_then_repaired(
    name: str, what: str, make: Callable[[Path], Path], refused: str
) -> tuple[Case, Case]:
    """A damaged file twice: refused as it is (`refused`: a substring of the refusal), then
    imported with --repair."""
    return (
        Case(name, what, make, STD, refused=refused),
        Case(f"{name} --repair", "the same, asked to repair", make, {**STD, "repair": True}),
    )


CASES: list[Case] = [
    Case("elastomer_50hz.csv", "50 Hz, one cycle, `time [s]`, `displacement [mm]`, `force [N]`",
         _headers_mm_n, STD),
    Case("plain_mN.csv", "plain headers t, x, F; force in mN, displacement in mm (options)",
         _plain_mn, {"time_col": "t", "position_col": "x", "force_col": "F",
                     "position_unit": "mm", "force_unit": "mN"}),
    Case("header_mN.csv", "`force [mN]`, `displacement (mm)` headers, no unit options",
         _header_mn, STD),
    Case("header_mN.csv + --force-unit N", "an option contradicting the header",
         _header_mn, {**STD, "force_unit": "N"}, refused="says its unit is mN"),
    *_refused_then_repaired("nan_holes.csv", "empty force cells at rows 101-103, `NaN` at row 201",
                            _nan_holes, "row 101: force is missing"),
    *_refused_then_repaired("backwards.csv", "time steps back at row 301",
                            _backwards, "row 301: time does not increase"),
    *_refused_then_repaired("gap.csv", "1 s of samples missing after row 150",
                            _gap, "row 151: a gap of"),
    Case("tension.csv", "tension: negative displacement and force",
         _tension, STD),
    Case("tension.csv --compression-negative",
         "the same from a machine that records compression as negative",
         _tension, {**STD, "compression_negative": True}),
    Case("ms_um_1khz.csv", "1 kHz, `t (ms)`, `depth (µm)`, `load [N]`",
         _ms_um, {"time_col": "t", "position_col": "depth", "force_col": "load"}),
    Case("ms_um_1khz.csv --resample-hz 50", "the same, resampled to 50 Hz (window average)",
         _ms_um, {"time_col": "t", "position_col": "depth", "force_col": "load",
                  "resample_hz": 50.0}),
    Case("elastomer_50hz.csv --g-a 100", "the loop's 10 kHz acceleration gain at 50 Hz",
         _headers_mm_n, {**STD, "g_a": 100.0}, refused="g dt = 2.000"),
    Case("text_cell.csv", "a text cell (`overload`) in the displacement column",
         _text_cell, STD,
         refused="row 43"),
    Case("zwick_export.csv", "a German-language export: four preamble lines, `;`, decimal "
         "commas, `Zeit [s]`, `Standardweg [mm]`, `Prüfkraft [N]`, Windows-1252",
         _zwick, {"time_col": "Zeit", "position_col": "Standardweg", "force_col": "Prüfkraft"}),
    Case("units_row.csv", "quoted `Time`, `Extension`, `Load` with a row `(s)`, `(mm)`, `(N)` "
         "under them", _units_row,
         {"time_col": "Time", "position_col": "Extension", "force_col": "Load"}),
    Case("tabs.txt", "tab-separated text", _tabs, STD),
    Case("no_time.csv --sample-rate-hz 50", "force and displacement only, no time column",
         _no_time, {"time_col": None, "position_col": "displacement", "force_col": "force",
                    "sample_rate_hz": 50.0}),
    Case("mixed_marks.csv", "`;` and decimal commas, but row 301's force with a decimal point",
         _mixed_marks, STD, refused="one file, one decimal mark"),
    Case("afm-cellhesion-fd.csv (REAL)", "AFM approach-retract curve, 1 kHz, N and m (SI "
         "headers), a -0.7 nN baseline (tests/data/SOURCE.md)",
         _afm, {"time_col": "time", "position_col": "height measured", "force_col": "force"}),
]  # fmt: skip


def run_case(case: Case, folder: Path, rt_loop: str | None = None) -> tuple[str, object]:
    """("ok", Recording) or ("refused", message); anything else raises."""
    from .importer import import_series

    src = case.make(folder / case.name.split(" ")[0])
    kw = dict(case.kwargs)
    try:
        rec = import_series(src, folder / "out.parquet", kw.pop("time_col"),
                            kw.pop("position_col"), kw.pop("force_col"), rt_loop=rt_loop,
                            overwrite=True, **kw)
    except (DataError, RuntimeError) as e:  # fmt: skip
        return "refused", str(e)
    return "ok", rec


def table(rt_loop: str | None = None) -> str:
    """The Markdown fixture table of docs/train.md."""
    from .importer import describe_import

    lines = ["| input | what the import did |", "| --- | --- |"]
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            status, res = run_case(case, Path(tmp), rt_loop)
            if status == "ok":
                did = "imported: " + describe_import(res)  # type: ignore[arg-type]
            else:
                msg = str(res).splitlines()[-1].split(": ", 1)[-1]
                did = "**refused**: " + msg.replace(tmp, "...")
            lines.append(f"| `{case.name}`: {case.what} | {did.replace('|', '/')} |")
    return "\n".join(lines)


#: The README's import example (docs/examples/): one SYNTHETIC cycle of the elastomer at two
#: rates, as a testing machine exports it: plain headers, displacement in mm, force in mN.
EXAMPLES: dict[str, float] = {"sample_a_0.5mm_s.csv": 0.5, "sample_a_2mm_s.csv": 2.0}


def write_examples(folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, rate in EXAMPLES.items():
        c = cycle(rate_mm_s=rate)
        series = zip(c["time"], c["displacement"], c["force"], strict=True)
        rows = [[f"{t:.2f}", f"{x:.4f}", f"{1e3 * f:.2f}"] for t, x, f in series]
        out.append(_write_text(folder / name, ["time", "displacement", "force"], rows))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description="prints the import fixture table")
    p.add_argument("--rt-loop")
    p.add_argument("--examples", help="write the README's example CSVs into this folder instead")
    a = p.parse_args()
    if a.examples:
        for path in write_examples(Path(a.examples)):
            print(path)
        return
    print(table(a.rt_loop))


if __name__ == "__main__":
    main()
