"""VizieR's tab-separated export (``.tsv``: the ``asu-tsv`` output and the "Tab-separated
values" download) read into an astropy table of text cells.

The layout, as VizieR writes it::

    #   VizieR Astronomical Server vizier.cds.unistra.fr        <- comment lines ("#")
    #Column  _RAJ2000  (A11)  Right ascension ...  [ucd=pos.eq.ra;meta.main]
                                                               <- blank lines
    _RAJ2000   _DEJ2000   Name          Vmag                   <- the header row
    "h:m:s"    "d:m:s"                  mag                    <- the units row
    --------   --------   ------------  -----                  <- a row of dashes
    08 51 18.47  +11 46 50.6  Sanders 1850  15.57              <- data, cells padded with spaces

Cells are separated by tabs (or ``|`` / ``;`` / ``,``, VizieR's other "separated values"
options, when the header row holds no tab). The units row and the dashes row are recognised by
their form (a row of dashes; the row right above it is the units row), so a plain tab-separated
file without them is read too. A column's unit comes from the units row (``h:m:s`` is hours,
``d:m:s`` degrees) and its UCD from its ``#Column`` line, so columns are found the way a VizieR
VOTable's are. Cells are kept as text (an empty cell masked), for :mod:`service.tables` to read
each by its own form.

One pass over the lines, with the bounds of :mod:`service.table_checks`: line length, columns,
cell length and the row limit (applied while reading). Only the columns ``keep`` asks for are
built, so a wide export costs no more than the columns read.
"""

from __future__ import annotations

import io
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.table_checks import (
    RowLimit,
    TargetFileError,
    bounded_lines,
    check_names,
    check_row,
    open_plain,
)

DELIMITERS = ("\t", "|", ";", ",")
#: Units of a VizieR units row that name sexagesimal forms: hours or degrees.
SEXAGESIMAL_UNITS = {"h:m:s": "hourangle", "d:m:s": "deg", "hms": "hourangle", "dms": "deg"}
_DASHES = re.compile(r"^-+$")
#: A ``#Column`` line longer than this is not looked at for its UCD.
MAX_COLUMN_LINE_CHARS = 4096
#: Comment lines that open another table of the same export.
_NEW_TABLE = ("#Table", "#RESOURCE")


@dataclass(frozen=True)
class TsvTable:
    """The table read (astropy ``Table`` of the kept columns' text cells), its number of data
    rows and the file line of each."""

    table: Any
    n_rows: int
    lines: list[int]


@dataclass
class _Layout:
    """What the pass has found so far: the delimiter, names, units, UCDs and the data rows."""

    delimiter: str = "\t"
    names: list[str] = field(default_factory=list)
    units: list[str] = field(default_factory=list)
    ucds: dict[str, str] = field(default_factory=dict)
    kept: list[int] = field(default_factory=list)  # the columns built, by index
    rows: list[list[str]] = field(default_factory=list)  # each data row's kept cells
    lines: list[int] = field(default_factory=list)


def read_tsv(path: Path, label: str, rows: RowLimit | None,
             keep: Callable[[str, str], bool]) -> TsvTable:
    """Read the export at ``path`` (plain or compressed); ``keep(name, ucd)`` says which
    columns to build. Errors name ``label`` and the file's line."""
    with open_plain(path) as raw:
        text = io.TextIOWrapper(raw, encoding="utf-8", newline="")
        try:
            layout = _scan(_numbered(bounded_lines(text, label)), label, rows, keep)
        except UnicodeDecodeError:
            raise TargetFileError(f"{label}: not a table: not UTF-8 text; save the table as "
                                  "UTF-8") from None
    if not layout.names:
        raise TargetFileError(f"{label}: the table has no header row (only comment lines)")
    return TsvTable(_table(layout), len(layout.rows), layout.lines)


def _numbered(lines: Iterator[str]) -> Iterator[tuple[int, str]]:
    for number, line in enumerate(lines, start=1):
        yield number, line.rstrip("\r\n")


def _scan(lines: Iterator[tuple[int, str]], label: str, rows: RowLimit | None,
          keep: Callable[[str, str], bool]) -> _Layout:
    """The pass: comments (and their UCDs), the header, the units and dashes rows, the data."""
    layout = _Layout()
    pending: list[tuple[int, list[str]]] = []  # rows after the header, until the layout is known
    head_done = False
    for number, line in lines:
        if line.startswith("#"):
            if layout.rows and line.startswith(_NEW_TABLE):
                raise TargetFileError(f"{label}: line {number} starts a second table; export "
                                      "one table per file")
            _note_ucd(line, layout)
            continue
        if not line.strip():
            continue
        if not layout.names:
            layout.delimiter = next((d for d in DELIMITERS if d in line), "\t")
            layout.names = [c.strip() for c in line.split(layout.delimiter)]
            check_names(layout.names, label, number)
            layout.kept = [k for k, name in enumerate(layout.names)
                           if keep(name, layout.ucds.get(name, ""))]
            continue
        cells = [c.strip() for c in line.split(layout.delimiter)]
        if not head_done:
            pending.append((number, cells))
            head_done = _settle(pending, layout)
            if not head_done:
                continue
            for n, c in pending:
                _add_row(layout, c, n, label, rows)
            pending.clear()
            continue
        _add_row(layout, cells, number, label, rows)
    for n, c in pending:  # a table of one data row, or none
        _add_row(layout, c, n, label, rows)
    return layout


def _settle(pending: list[tuple[int, list[str]]], layout: _Layout) -> bool:
    """Whether the rows under the header are known to be data: a dashes row is dropped (and the
    row above it, if any, is the units row); two rows without dashes are both data."""
    if _dashes(pending[-1][1]):
        if len(pending) == 2:
            layout.units = [_unquote(u) for u in pending[0][1]]
        pending.clear()
        return True
    return len(pending) == 2


def _dashes(cells: list[str]) -> bool:
    return any(cells) and all(not c or _DASHES.match(c) for c in cells)


def _unquote(unit: str) -> str:
    return unit[1:-1].strip() if len(unit) >= 2 and unit[0] == unit[-1] == '"' else unit


def _note_ucd(line: str, layout: _Layout) -> None:
    """The UCD of a ``#Column<TAB>name<TAB>(format)<TAB>description<TAB>[ucd=...]`` line."""
    if layout.names or not line.startswith("#Column\t") or len(line) > MAX_COLUMN_LINE_CHARS:
        return
    parts = line.split("\t")
    last = parts[-1].strip()
    if len(parts) >= 3 and last.startswith("[ucd=") and last.endswith("]"):
        layout.ucds.setdefault(parts[1].strip(), last[5:-1].strip())


def _add_row(layout: _Layout, cells: list[str], line: int, label: str,
             rows: RowLimit | None) -> None:
    n_row = len(layout.rows) + 1
    while len(cells) > len(layout.names) and not cells[-1]:
        cells.pop()  # a delimiter at the end of the line
    check_row(cells, layout.names, (label, n_row, line), True)
    if rows is not None and n_row > rows.most:
        raise rows.refuse(label, f"more than {rows.most} rows (line {line})")
    layout.rows.append([cells[k] if k < len(cells) else "" for k in layout.kept])
    layout.lines.append(line)


def _table(layout: _Layout) -> Any:
    """The kept columns as text columns, each with its unit (units row) and UCD (``#Column``
    line); a column with an empty or missing cell is masked there (a column without one is
    plain: iterating a masked column costs ten times more)."""
    import numpy as np
    from astropy.table import Column, MaskedColumn, Table

    table = Table()
    for j, k in enumerate(layout.kept):
        name = layout.names[k]
        ucd = layout.ucds.get(name, "")
        cells = [row[j] for row in layout.rows]
        data = np.empty(len(cells), dtype=object)
        data[:] = cells
        unit = _unit(layout.units[k] if k < len(layout.units) else "")
        empty = [not c for c in cells]
        col = (MaskedColumn(data, name=name, mask=empty, unit=unit) if any(empty)
               else Column(data, name=name, unit=unit))
        if ucd:
            col.meta["ucd"] = ucd
        table.add_column(col)
    return table


def _unit(text: str) -> Any:
    """The astropy unit a units-row cell names, or None (none, or one astropy does not know)."""
    from astropy import units as u

    text = text.strip()
    text = SEXAGESIMAL_UNITS.get(text.lower().replace(" ", ""), text)
    if not text or set(text) <= {"-"}:
        return None
    unit = u.Unit(text, parse_strict="silent")
    return None if isinstance(unit, u.UnrecognizedUnit) else unit
