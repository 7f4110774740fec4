"""How a testing machine's text export is laid out, found from the file itself.

Exports of materials-testing software are rarely the plain `time,displacement,force` file a
script writes. What they do, and what is recognised here (each said in the import's output
and recorded in the recording's metadata, so nothing is guessed silently):

- a **separator** other than the comma: `;` (German and French locales, where the comma is the
  decimal mark), a tab (`.txt`, `.tsv`), `|`;
- **decimal commas** (`0,25`), only with a separator that is not itself a comma; a file whose
  cells use both marks is refused with a row of each, since `1.234,5` and `1,234.5` cannot
  both be read;
- a **preamble** (protocol name, sample, date...) above the header: the header is the first
  line that names every requested column;
- a **units row** under the header (`(s)`, `[mm]`, `N`), as some exports write instead of
  units in the header: each unit then reads as if the header had said `name [unit]`;
- the **encoding**: UTF-8 (with or without a byte-order mark), else Windows-1252, the usual
  encoding of exports from Windows software (`Prüfkraft`).

A cell is never altered beyond turning a decimal comma into a point; a cell that is not a
number still reaches the importer's check and is refused with its row.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import re
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa

from .data import DataError

#: separators tried, in this order (a line that names every column with two of them takes the
#: one that gives more cells)
SEPARATORS = (",", ";", "\t", "|")
#: lines searched for the header
HEADER_SEARCH_LINES = 200
_NAMES = {",": "comma", ";": "semicolon", "\t": "tab", "|": "vertical bar"}
# A unit cell: a short token with no digit, bracketed or not ("(s)", "[mm]", "N", "µm").
_UNIT_CELL = re.compile(r"^[\[(]?\s*(?P<u>[^\d\s\[\]()]{1,8})\s*[\])]?$")
# Numbers as written with either decimal mark (and an exponent).
_COMMA_NUMBER = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")
_POINT_NUMBER = re.compile(r"^[+-]?\d*\.\d+(?:[eE][+-]?\d+)?$")
_NOT_UNITS = {"nan", "na", "n/a", "null", "-", "inf", "infinity"}
_HEADER_UNIT = re.compile(r"^(?P<base>.*?)\s*(?:\[(?P<u1>[^\]]+)\]|\((?P<u2>[^)]+)\))\s*$")


def header_unit(header: str) -> tuple[str, str] | None:
    """`"force [mN]"` -> `("force", "mN")`; None when the header names no unit."""
    m = _HEADER_UNIT.match(header)
    if not m:
        return None
    unit = (m.group("u1") or m.group("u2") or "").strip()
    return (m.group("base"), unit) if unit else None


@dataclass(frozen=True)
class CsvLayout:
    """What the file turned out to be. `names`: the header's names, a units row's unit appended
    as `name [unit]`; `header_line`: its line in the file, from 1."""

    separator: str
    decimal_comma: bool
    header_line: int
    units_row: bool
    encoding: str
    names: tuple[str, ...]

    def as_meta(self) -> dict:
        return {"separator": self.separator, "decimal_comma": self.decimal_comma,
                "header_line": self.header_line, "units_row": self.units_row,
                "encoding": self.encoding}  # fmt: skip

    @staticmethod
    def describe_meta(meta: dict) -> str:
        """The non-default parts of a layout's metadata, in words ("" for a plain file)."""
        parts = []
        sep = meta.get("separator", ",")
        if sep != ",":
            parts.append(f"{_NAMES.get(sep, repr(sep))}-separated")
        if meta.get("decimal_comma"):
            parts.append("decimal commas")
        line = meta.get("header_line", 1)
        if line != 1:
            parts.append(f"header on line {line} (the {line - 1} line(s) above skipped)")
        if meta.get("units_row"):
            parts.append("units from the row under the header")
        enc = meta.get("encoding", "utf-8")
        if enc not in ("utf-8", "utf-8-sig"):
            parts.append(f"{enc} text")
        return ", ".join(parts)


def decode(raw: bytes) -> tuple[str, str]:
    """(text, encoding): UTF-8 (a byte-order mark dropped), else Windows-1252, else Latin-1
    (which decodes any byte: the last resort, named in the metadata)."""
    for enc in ("utf-8-sig", "cp1252", "latin-1"):
        try:
            text = raw.decode(enc)
        except UnicodeDecodeError:
            continue
        return text, ("utf-8" if enc == "utf-8-sig" else enc)
    raise AssertionError("latin-1 decodes every byte")


def _cells(line: str, sep: str) -> list[str]:
    row = next(csv.reader([line], delimiter=sep), [])
    return [c.strip() for c in row]


def _names_match(cells: list[str], wanted: list[str]) -> bool:
    bases = set(cells) | {hu[0] for c in cells if (hu := header_unit(c)) is not None}
    return all(w in bases for w in wanted)


def _unit_of(cell: str) -> str | None:
    """The unit a units-row cell gives ('' for an empty cell), None when it is not one."""
    if cell == "":
        return ""
    if cell.lower() in _NOT_UNITS:
        return None
    m = _UNIT_CELL.match(cell)
    return m.group("u") if m else None


def _is_numeric(cell: str) -> bool:
    return bool(cell) and (
        _COMMA_NUMBER.match(cell) is not None
        or _POINT_NUMBER.match(cell) is not None
        or re.match(r"^[+-]?\d+(?:[eE][+-]?\d+)?$", cell) is not None
    )


def _guess_header(lines: list[str]) -> tuple[int, str, list[str]] | None:
    """For messages: (line index, separator, cells) of the line above the first row of
    numbers, with the separator that splits that row into the most cells."""
    for i, line in enumerate(lines):
        best = max(SEPARATORS, key=lambda s: len(_cells(line, s)))
        cells = _cells(line, best)
        if len(cells) > 1 and all(_is_numeric(c) for c in cells if c):
            above = [j for j in range(i - 1, -1, -1) if lines[j].strip()][:2]
            if not above:
                return None
            units = [_unit_of(c) for c in _cells(lines[above[0]], best)]
            if len(above) == 2 and all(u is not None for u in units) and any(units):
                return above[1], best, _cells(lines[above[1]], best)  # above a units row
            return above[0], best, _cells(lines[above[0]], best)
    return None


def find_layout(text: str, wanted: list[str], encoding: str = "utf-8") -> CsvLayout:
    """The layout of `text` whose header names every column in `wanted` (exactly, or as
    `name [unit]` / `name (unit)`); DataError saying what the file has otherwise."""
    lines = text.splitlines()[:HEADER_SEARCH_LINES]
    for i, line in enumerate(lines):
        hits = [(len(c), s, c) for s in SEPARATORS if _names_match(c := _cells(line, s), wanted)]
        if not hits:
            continue
        _, sep, header = max(hits, key=lambda h: h[0])
        nxt = next((k for k in range(i + 1, len(lines)) if lines[k].strip()), None)
        units_row = False
        names = list(header)
        if nxt is not None:
            units = [_unit_of(c) for c in _cells(lines[nxt], sep)]
            if units and all(u is not None for u in units) and any(units):
                units_row = True
                for k, u in enumerate(units[: len(names)]):
                    if u and "[" not in names[k] and "(" not in names[k]:
                        names[k] = f"{names[k]} [{u}]"
        return CsvLayout(sep, False, i + 1, units_row, encoding, tuple(names))
    guess = _guess_header(lines)
    if guess is None:
        raise DataError(
            f"no line of the first {len(lines)} names every column asked for {wanted}, and no "
            "row of numbers was found under a header"
        )
    missing = [w for w in wanted if not _names_match(guess[2], [w])]
    raise DataError(
        f"no column {', '.join(map(repr, missing))}: no line of the first {len(lines)} names "
        f"every column asked for {wanted}; the header looks like line {guess[0] + 1} "
        f"({_NAMES[guess[1]]}-separated): {guess[2]}"
    )


def read_layout(path: Path, wanted: list[str]) -> tuple[CsvLayout, str]:
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise DataError(f"cannot read {path}: {e}") from e
    text, encoding = decode(raw)
    return find_layout(text, wanted, encoding), text


def read_table(path: Path, wanted: list[str]) -> tuple[CsvLayout, pa.Table]:
    """The columns of the text file at `path` as text (the importer parses the numbers, so a
    bad cell is reported with its row), the header's names as in `CsvLayout.names`; data rows
    are the non-blank lines after the header (and its units row). Decimal commas are found
    here and turned into points."""
    layout, text = read_layout(path, wanted)
    lines = text.splitlines()
    start = layout.header_line  # the line after the header, as an index
    if layout.units_row:
        start = next(k for k in range(start, len(lines)) if lines[k].strip()) + 1
    reader = csv.reader(io.StringIO("\n".join(lines[start:])), delimiter=layout.separator)
    rows = [[c.strip() for c in r] for r in reader if any(c.strip() for c in r)]
    width = len(layout.names)
    # a short row's missing cells are missing values (the importer refuses or repairs them
    # with their row); cells past the header's width (a trailing separator) are ignored
    cols = [[r[k] if k < len(r) else "" for r in rows] for k in range(width)]
    asked = [k for k, name in enumerate(layout.names)
             if name in wanted or (header_unit(name) or ("",))[0] in wanted]  # fmt: skip
    decimal_comma = False
    if layout.separator != ",":
        comma = point = None
        for k in asked:
            for n, cell in enumerate(cols[k], start=1):
                if comma is None and _COMMA_NUMBER.match(cell):
                    comma = (n, layout.names[k], cell)
                if point is None and _POINT_NUMBER.match(cell):
                    point = (n, layout.names[k], cell)
            if comma is not None and point is not None:
                break
        if comma is not None and point is not None:
            raise DataError(
                f"row {comma[0]}: column {comma[1]!r} reads {comma[2]!r} with a decimal comma, "
                f"but row {point[0]}: column {point[1]!r} reads {point[2]!r} with a decimal "
                "point; one file, one decimal mark"
            )
        if comma is not None:
            decimal_comma = True
            for k in asked:
                cols[k] = [c.replace(",", ".") for c in cols[k]]
    layout = dataclasses.replace(layout, decimal_comma=decimal_comma)
    arrays = [pa.array(col, type=pa.string()) for col in cols]
    return layout, pa.Table.from_arrays(arrays, names=list(layout.names))
