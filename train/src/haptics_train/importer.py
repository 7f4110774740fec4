"""Import of a time/displacement/force series measured elsewhere (another device, a
materials-testing machine, an indenter) into the recording format.

Such files come at any rate and in any unit, laid out as their software writes text, with
holes and glitches. Nothing is assumed silently here:

- a text file's separator, decimal mark, header line, units row and encoding are found from
  the file (csv_layout.py) and said in the output and the metadata;
- units come from the options, else from the column headers (`force [mN]`,
  `displacement (mm)`), else SI, which the output then says (`unit_notes`); a series left in
  SI that way whose magnitudes no bench gives in SI (over 1 kN, over 1 m) is refused, naming the
  unit option; an option that contradicts its header is refused;
- non-finite values, time that does not increase and gaps are refused with the row number
  (data rows counted from 1), or, with `repair=True`, interpolated (or dropped) and counted;
- `resample_hz` puts the series on a uniform grid (a window average when it lowers the rate);
- the series goes to rt-loop's own offline feature code (`rt-loop features`) in SI units, so
  the feature definitions exist once, in the loop; rt-loop derives the filter gains from the
  rate (and refuses gains the rate cannot carry) and the contact thresholds from the force's
  noise floor, unless they are given here;
- the output's metadata (`haptics.run`) records the source, its units and where each came
  from, the rate, the repairs and every setting used.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .csv_layout import CsvLayout, header_unit, read_table
from .data import DataError, Recording, load_recording, sha256_file

#: unit -> factor to SI (s, m, N); the same set as `rt-loop features` (rt-loop/src/import.rs).
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "min": 60.0}
POSITION_UNITS: dict[str, float] = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "in": 0.0254}
FORCE_UNITS: dict[str, float] = {"N": 1.0, "mN": 1e-3, "kN": 1e3, "lbf": 4.4482216152605}
#: spellings seen in headers -> the unit's name above
_ALIASES: dict[str, str] = {
    "sec": "s", "secs": "s", "second": "s", "seconds": "s", "msec": "ms", "µs": "us",
    "μs": "us", "usec": "us", "µm": "um", "μm": "um", "inch": "in",
}  # fmt: skip
DEFAULT_MAX_GAP_FACTOR = 1.5
#: Largest magnitudes a bench measures in SI, for a series whose unit nobody stated: a force
#: over 1 kN or a displacement over 1 m is a series in mN or mm read as N or m (a factor of 1000
#: off), so it is refused, naming the option that says the unit.
PLAUSIBLE_SI: dict[str, tuple[float, str]] = {"force": (1000.0, "N"), "position": (1.0, "m")}

class RtLoopMissing(RuntimeError):
    pass


def resolve_unit(
    what: str, header: str, option: str | None, table: dict[str, float]
) -> tuple[str, str]:
    """(unit, where it came from: option | header | default)."""
    if option is not None and option not in table:
        raise DataError(f"--{what}-unit must be one of {tuple(table)}, not {option!r}")
    hu = header_unit(header)
    parsed = None
    if hu is not None:
        parsed = _ALIASES.get(hu[1], hu[1])
        if parsed not in table:
            if option is None:
                raise DataError(
                    f"column {header!r}: unknown unit {hu[1]!r}; give --{what}-unit explicitly "
                    f"(one of {tuple(table)})"
                )
            parsed = None
    if option is not None:
        if parsed is not None and parsed != option:
            raise DataError(
                f"column {header!r} says its unit is {parsed}, but --{what}-unit {option} was given"
            )
        return option, "option"
    if parsed is not None:
        return parsed, "header"
    return next(iter(table)), "default"


def check_plausible_si(
    series: dict[str, np.ndarray], units: dict[str, tuple[str, str]], cols: dict[str, str]
) -> None:
    """Refuses a series taken as SI by default (no header unit, no option) whose magnitude no
    bench gives in SI: it is in a smaller unit, and reading it as SI would be 1000x off."""
    for what, (limit, si) in PLAUSIBLE_SI.items():
        if units[what][1] != "default":
            continue
        v = series[what]
        finite = v[np.isfinite(v)]
        peak = float(np.max(np.abs(finite))) if finite.size else 0.0
        if peak > limit:
            table = FORCE_UNITS if what == "force" else POSITION_UNITS
            raise DataError(
                f"column {cols[what]!r} names no unit (neither its header nor --{what}-unit) and "
                f"reaches {peak:.4g}: over {limit:g} {si}, implausible for a bench in {si}; give "
                f"--{what}-unit (one of {tuple(table)}) or a header like '{what} [unit]'"
            )


def unit_notes(rec: Recording) -> list[str]:
    """One line per series whose unit neither a header nor an option gave (taken as SI)."""
    units = (rec.meta.get("haptics.run") or {}).get("units") or {}
    return [
        f"no unit for {k} (column {v.get('column')!r}) in its header or --{k}-unit: taken as "
        f"{v.get('unit')}"
        for k, v in units.items()
        if v.get("from") == "default"
    ]


def find_column(headers: list[str], name: str) -> str:
    """The exact header, else the one header `name [unit]`."""
    if headers.count(name) > 1:
        raise DataError(f"column name {name!r} is ambiguous: the file has {headers.count(name)}")
    if name in headers:
        return name
    hits = [h for h in headers if (hu := header_unit(h)) is not None and hu[0] == name]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        raise DataError(f"no column {name!r}; the file has {headers}")
    raise DataError(f"column name {name!r} is ambiguous: {hits}")


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


#: inputs read as delimited text (csv_layout.py finds the separator, decimal mark, header line,
#: units row and encoding); anything else must be Parquet
TEXT_SUFFIXES = (".csv", ".tsv", ".txt")


def _read_table(path: Path, wanted: list[str]) -> tuple[pa.Table, CsvLayout | None]:
    """The input as a table (text columns as text: a cell that is not a number is then
    reported with its row instead of turning the whole column into strings), and the text
    file's layout (None for Parquet)."""
    if path.suffix.lower() in TEXT_SUFFIXES:
        layout, table = read_table(path, wanted)
        return table, layout
    try:
        return pq.read_table(path), None
    except (OSError, pa.ArrowException) as e:
        raise DataError(f"cannot read {path}: {e}") from e


_MISSING = {"", "nan", "NaN", "NAN", "na", "NA", "n/a", "N/A", "null", "NULL", "-"}


def _as_float(table: pa.Table, col: str) -> np.ndarray:
    """A column as float64; empty / missing cells are NaN, other text is an error with its row."""
    c = table.column(col)
    if pa.types.is_string(c.type) or pa.types.is_large_string(c.type):
        vals = c.to_pylist()
        out = np.empty(len(vals))
        for i, v in enumerate(vals):
            s = "" if v is None else v.strip()
            if s in _MISSING:
                out[i] = np.nan
                continue
            try:
                out[i] = float(s)
            except ValueError:
                raise DataError(f"row {i + 1}: column {col!r}: {s!r} is not a number") from None
        return out
    if not (pa.types.is_integer(c.type) or pa.types.is_floating(c.type)):
        raise DataError(f"column {col!r} has type {c.type}, not a number")
    return np.asarray(c.to_numpy(zero_copy_only=False), dtype=np.float64)


@dataclass
class Repairs:
    """What `repair=True` changed, counted (recorded in the metadata)."""

    dropped_nonfinite_time: int = 0
    dropped_non_increasing_time: int = 0
    interpolated_position: int = 0
    interpolated_force: int = 0
    dropped_edge_holes: int = 0
    filled_gap_rows: int = 0
    rows: list[str] = field(default_factory=list)  # the first few, for the message

    def total(self) -> int:
        return (self.dropped_nonfinite_time + self.dropped_non_increasing_time
                + self.interpolated_position + self.interpolated_force
                + self.dropped_edge_holes + self.filled_gap_rows)  # fmt: skip


def _median_dt(t: np.ndarray) -> float:
    return float(np.median(np.diff(t)))


def check_or_repair(
    t: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    repair: bool = False,
    max_gap_factor: float = DEFAULT_MAX_GAP_FACTOR,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, Repairs]:
    """Refuses (DataError naming the row, data rows from 1) or repairs and counts:
    non-finite time (dropped), time that does not increase (the row dropped), non-finite
    position/force (linear interpolation in time; holes at either end dropped), gaps longer
    than `max_gap_factor` median periods (filled with rows interpolated at the median period).
    """
    rep = Repairs()
    row = np.arange(1, len(t) + 1)
    bad_t = ~np.isfinite(t)
    if bad_t.any():
        i = int(np.argmax(bad_t))
        if not repair:
            raise DataError(f"row {row[i]}: time is missing or not finite")
        rep.dropped_nonfinite_time = int(bad_t.sum())
        t, x, f, row = t[~bad_t], x[~bad_t], f[~bad_t], row[~bad_t]
    # time must increase: find the first row that does not
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0)) + 1
        if not repair:
            raise DataError(
                f"row {row[i]}: time does not increase ({t[i]:g} s after {t[i - 1]:g} s)"
            )
        # a row is kept when its time is above every earlier kept time (rows after a jump
        # back are dropped until time passes the last good one)
        run_max = -np.inf
        keep = np.zeros(len(t), dtype=bool)
        for k, tv in enumerate(t):
            if tv > run_max:
                keep[k] = True
                run_max = tv
        rep.dropped_non_increasing_time = int((~keep).sum())
        t, x, f, row = t[keep], x[keep], f[keep], row[keep]
    for what, v in (("position", x), ("force", f)):
        bad = ~np.isfinite(v)
        if not bad.any():
            continue
        i = int(np.argmax(bad))
        if not repair:
            raise DataError(
                f"row {row[i]}: {what} is missing or not finite ({int(bad.sum())} such rows); "
                "pass --repair to interpolate them"
            )
        good = np.flatnonzero(~bad)
        if len(good) < 2:
            raise DataError(f"{what}: fewer than two finite values")
        inner = bad.copy()
        inner[: good[0]] = False
        inner[good[-1] + 1 :] = False
        v[inner] = np.interp(t[inner], t[good], v[good])
        setattr(rep, f"interpolated_{what}", int(inner.sum()))
        rep.rows.extend(f"{what}@{r}" for r in row[inner][:5])
    edge = ~(np.isfinite(x) & np.isfinite(f))
    if edge.any():
        rep.dropped_edge_holes = int(edge.sum())
        t, x, f, row = t[~edge], x[~edge], f[~edge], row[~edge]
    if len(t) < 3:
        raise DataError(f"only {len(t)} usable rows")
    med = _median_dt(t)
    dt = np.diff(t)
    gap = dt > max_gap_factor * med
    if gap.any():
        i = int(np.argmax(gap))
        if not repair:
            raise DataError(
                f"row {row[i + 1]}: a gap of {dt[i]:g} s after t = {t[i]:g} s (the median "
                f"period is {med:g} s, the limit {max_gap_factor}x); pass --repair to fill it "
                "by interpolation, --resample-hz, or raise --max-gap-factor"
            )
        new_t = [t[:1]]
        for k in range(len(dt)):
            if gap[k]:
                n = int(np.ceil(dt[k] / med))
                new_t.append(t[k] + dt[k] * np.arange(1, n) / n)
            new_t.append(t[k + 1 : k + 2])
        tt = np.concatenate(new_t)
        rep.filled_gap_rows = len(tt) - len(t)
        x, f, t = np.interp(tt, t, x), np.interp(tt, t, f), tt
    return t, x, f, rep


def resample(t: np.ndarray, v: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """`v` on the uniform grid t0, t0 + 1/rate, ... <= t_end. Lowering the rate averages over
    each new period (the exact mean of the piecewise-linear signal over the window, from its
    cumulative integral), so nothing aliases; raising it interpolates linearly."""
    period = 1.0 / rate_hz
    grid = t[0] + period * np.arange(int(np.floor((t[-1] - t[0]) / period + 1e-9)) + 1)
    if period <= _median_dt(t):
        return grid, np.interp(grid, t, v)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])

    def integral(a: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(t, a, side="right") - 1, 0, len(t) - 2)
        va = np.interp(a, t, v)
        return cum[k] + 0.5 * (v[k] + va) * (a - t[k])

    lo = np.clip(grid - period / 2, t[0], t[-1])
    hi = np.clip(grid + period / 2, t[0], t[-1])
    return grid, (integral(hi) - integral(lo)) / (hi - lo)


def import_series(
    input_path: str | Path,
    out: str | Path,
    time_col: str | None,
    position_col: str,
    force_col: str,
    *,
    sample_rate_hz: float | None = None,
    time_unit: str | None = None,
    position_unit: str | None = None,
    force_unit: str | None = None,
    rt_loop: str | None = None,
    g_v: float | None = None,
    g_a: float | None = None,
    contact_on_n: float | None = None,
    contact_off_n: float | None = None,
    resample_hz: float | None = None,
    repair: bool = False,
    max_gap_factor: float = DEFAULT_MAX_GAP_FACTOR,
    compression_negative: bool = False,
    overwrite: bool = False,
    timeout_s: float = 600.0,
) -> Recording:
    """Every option is keyword-only: a positional call cannot shift a unit into another slot.
    A unit left None is taken from the column header, else SI (s, m, N). An existing `out` is
    refused unless `overwrite` (as `rt-loop run --overwrite`). `compression_negative`: the
    machine's compression is negative displacement and force (a common sign convention of
    testing machines); both are negated, so compression is positive as in the product's
    recordings (into the object, pushing back), and the metadata says so. `sample_rate_hz`
    instead of `time_col`: a file without a time column (a DAQ's samples at a known rate);
    the time is then the row's index over the rate, so a lost sample cannot be seen."""
    src = Path(input_path)
    dst = Path(out)
    if not src.is_file():
        raise DataError(f"no such input file: {src}")
    if src.suffix.lower() not in (*TEXT_SUFFIXES, ".parquet"):
        raise DataError(
            f"{src}: only delimited text ({', '.join(TEXT_SUFFIXES)}) and .parquet inputs are "
            "supported"
        )
    if dst.suffix.lower() != ".parquet":
        raise DataError(f"output {dst} must end in .parquet")
    if dst.exists() and dst.resolve() == src.resolve():
        raise DataError("refusing to overwrite the input with the output")
    if dst.exists() and not overwrite:
        raise DataError(f"{dst} exists: give --overwrite to replace it")
    if resample_hz is not None and not (np.isfinite(resample_hz) and resample_hz > 0):
        raise DataError(f"--resample-hz must be a positive rate, not {resample_hz}")
    if not max_gap_factor > 1:
        raise DataError(f"--max-gap-factor must be above 1, not {max_gap_factor}")
    if (time_col is None) == (sample_rate_hz is None):
        raise DataError(
            "give the time column (--time-col) or, for a file without one, its sampling rate "
            "(--sample-rate-hz): one of the two"
        )
    if sample_rate_hz is not None:
        if not (np.isfinite(sample_rate_hz) and sample_rate_hz > 0):
            raise DataError(f"--sample-rate-hz must be a positive rate, not {sample_rate_hz}")
        if time_unit is not None:
            raise DataError("--time-unit is the unit of a time column; --sample-rate-hz has none")
    named = [("time", time_col), ("position", position_col), ("force", force_col)]
    try:
        table, layout = _read_table(src, [n for _, n in named if n is not None])
    except DataError as e:
        raise DataError(f"{src}: {e}") from None
    headers = list(table.column_names)
    cols = {k: find_column(headers, n) for k, n in named if n is not None}
    units = {
        k: resolve_unit(k, cols[k], opt, table)
        for k, opt, table in (
            ("time", time_unit, TIME_UNITS),
            ("position", position_unit, POSITION_UNITS),
            ("force", force_unit, FORCE_UNITS),
        )
        if k in cols
    }
    if sample_rate_hz is not None:
        units = {"time": ("s", "sample rate"), **units}
    binary = find_rt_loop(rt_loop)
    try:
        x = _as_float(table, cols["position"]) * POSITION_UNITS[units["position"][0]]
        f = _as_float(table, cols["force"]) * FORCE_UNITS[units["force"][0]]
        t = (np.arange(len(x)) / sample_rate_hz if sample_rate_hz is not None
             else _as_float(table, cols["time"]) * TIME_UNITS[units["time"][0]])  # fmt: skip
        if compression_negative:
            x, f = -x, -f
        check_plausible_si({"position": x, "force": f}, units, cols)
        rows_in = len(t)
        t, x, f, rep = check_or_repair(t, x, f, repair, max_gap_factor)
    except DataError as e:
        raise DataError(f"{src}: {e}") from None
    rate_in = 1.0 / _median_dt(t)
    if resample_hz is not None:
        grid, x = resample(t, x, resample_hz)
        _, f = resample(t, f, resample_hz)
        t = grid
    pre = {
        "source": str(src.resolve()),
        "source_sha256": sha256_file(src),
        "units": {k: {"unit": u, "from": how, "column": cols.get(k)}
                  for k, (u, how) in units.items()},  # fmt: skip
        # the rate the time was made from (None: from the time column)
        "sample_rate_given_hz": sample_rate_hz,
        "rows_in": rows_in,
        "rows_out": len(t),
        "sample_rate_in_hz": rate_in,
        "resample_hz": resample_hz,
        "repair": repair,
        "repairs": {k: v for k, v in asdict(rep).items() if k != "rows"},
        "max_gap_factor": max_gap_factor,
        "compression_negative": compression_negative,
        # how a text file was read (None: Parquet)
        "text_layout": layout.as_meta() if layout is not None else None,
        "tool": "haptics-train import",
    }
    dst.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="haptics-import-") as tmp:
        mid = Path(tmp) / "series.parquet"
        # SI units in the headers: rt-loop reads them from there
        pq.write_table(pa.table({"time [s]": t, "position [m]": x, "force [N]": f}), mid)
        cmd = [
            str(binary), "features", "--input", str(mid), "--out", str(dst),
            "--time-col", "time [s]", "--position-col", "position [m]", "--force-col", "force [N]",
            "--max-gap-factor", repr(max_gap_factor), "--meta-json", json.dumps(pre),
        ]  # fmt: skip
        for flag, v in (("--g-v", g_v), ("--g-a", g_a), ("--contact-on-n", contact_on_n),
                        ("--contact-off-n", contact_off_n)):  # fmt: skip
            if v is not None:
                cmd += [flag, repr(float(v))]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired as e:
            raise RuntimeError(f"rt-loop features did not finish within {timeout_s} s") from e
    if proc.returncode != 0:
        err = proc.stderr.strip().replace(str(mid), str(src))
        raise RuntimeError(f"rt-loop features failed (exit {proc.returncode}):\n{err}")
    rec = load_recording(dst)
    rec.meta.setdefault("haptics.import.summary", proc.stderr.strip())
    return rec


def describe_import(rec: Recording) -> str:
    """One line saying what the import did, from the recording's own metadata."""
    run = rec.meta.get("haptics.run") or {}
    pre = run.get("preprocessing") or {}
    units = run.get("units") or {}
    filt = run.get("filters") or {}
    feat = run.get("features") or {}
    contact = run.get("contact") or {}
    timing = run.get("timing") or {}
    u = ", ".join(f"{k} {v.get('unit')} ({v.get('from')})" for k, v in units.items())
    nan = float("nan")
    on, off = feat.get("contact_on_n", nan), feat.get("contact_off_n", nan)
    fixes = {k: v for k, v in (pre.get("repairs") or {}).items() if v}
    rs = pre.get("resample_hz")
    return (
        f"{len(rec)} rows at {timing.get('sample_rate_hz', float('nan')):.4g} Hz"
        + (f" (resampled from {pre.get('sample_rate_in_hz', float('nan')):.4g} Hz)" if rs else "")
        + f"; units {u}; g_v {filt.get('g_v', float('nan')):.4g} ({filt.get('g_v_from')}), "
        f"g_a {filt.get('g_a', float('nan')):.4g} rad/s ({filt.get('g_a_from')}); contact "
        f"{on:.4g}/{off:.4g} N ({contact.get('from')}, noise floor "
        f"{contact.get('force_noise_floor_n', 0):.2g} N), "
        f"{contact.get('cycles')} cycle(s) ({contact.get('loading')}"
        + ("; contact counts compression only: a machine that records compression as "
           "negative needs --compression-negative" if contact.get("loading") == "tension" else "")
        + ")"
        + ("; signs negated (--compression-negative)" if pre.get("compression_negative") else "")
        + (f"; time from the rows at {pre['sample_rate_given_hz']:g} Hz (--sample-rate-hz: "
           "no time column, a lost sample cannot be seen)" if pre.get("sample_rate_given_hz")
           else "")
        + (f"; read as {how}" if (how := CsvLayout.describe_meta(pre.get("text_layout") or {}))
           else "")
        + (f"; repaired {fixes}" if fixes else "")
    )
