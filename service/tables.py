"""Target tables (CSV, VizieR's TSV, ECSV, VOTable, FITS) -> validated targets
``{id, ra_deg, dec_deg, priority}`` and, when the table gives them, their motion fields.

One reader for every entry point (the CLI's ``plan`` and the web page's upload,
``POST /v1/target-lists``), so a file means the same thing wherever it is handed in. The format
is the file name's suffix (:data:`FORMATS`); a name without a known one takes the format its
content shows (XML, ``# %ECSV``, FITS, a tab-separated header), and content that is no table
(an image, a PDF, binary data, text that is not UTF-8) is refused in one line,
``<file>: not a table: <what it is>`` (:func:`service.table_checks.sniff`). VizieR's TSV
export (comment lines, a units row and a row of dashes under the header) is read by
:mod:`service.vizier_tsv`.

Columns are recognised the way the Virtual Observatory names them:

1. by UCD (VOTable ``ucd`` attribute): ``pos.eq.ra;meta.main``, ``pos.eq.dec;meta.main``,
   ``meta.id;meta.main`` (then the same UCDs without ``;meta.main`` when only one column has it);
2. by name, case-insensitively, with common aliases (:data:`ALIASES`: ``ra``, ``RAJ2000``,
   VizieR's ``_RAJ2000`` / ``_DEJ2000``, the Gaia archive's ``source_id`` / ``ra`` / ``dec``, ...).

Values are read by their own form, cell by cell, and never by guessing for a whole column:

* a number (a numeric column, or a string cell such as ``250.4235``) is in degrees, or in the
  column's angular unit when the file gives one (``deg``, ``hourangle``, ``rad``, ...);
* a sexagesimal string (``16:41:41.7``, ``16 41 41.7``, ``16h41m41.7s``, ``+36d27m41s``) is in
  hours for RA and degrees for Dec, unless the string names its unit (``h`` / ``d``) or the
  column's unit is an angle unit other than hours;
* a column whose cells mix the two forms is accepted, and a notice says which rows had which.

A table without RA/Dec columns may give galactic or ecliptic longitude and latitude, converted
to ICRS with a notice; proper motions, parallax, radial velocity and the positions' epoch are
read into each row's ``motion`` (both: :mod:`service.table_motion`, docs/epochs.md).

Every bad cell raises :class:`TargetFileError` naming the file, the row (1 = first data row;
for CSV also the file's line) and the column. A table without an id column gets row-number ids,
a table without a priority column priority 1; both are reported in ``notices``.
"""

from __future__ import annotations

import errno
import math
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from models.epochs import MOTION_FIELDS
from models.types import MAX_PRIORITY
from service.table_checks import (
    TSV,
    RowLimit,
    TargetFileError,
    check_table_file,
    compression,
    sniff,
)
from service.table_motion import frame_columns, read_motions, to_icrs
from service.table_motion import wanted as motion_wanted
from service.vizier_tsv import read_tsv

ALIASES: dict[str, tuple[str, ...]] = {
    "id": ("id", "target_id", "name", "target", "source_id", "objid", "obj_id", "designation",
           "main_id", "source"),
    "ra_deg": ("ra_deg", "ra", "raj2000", "_raj2000", "ra_j2000", "ra_icrs", "_ra_icrs", "radeg",
               "alpha", "_ra", "ra_icrs_deg"),
    "dec_deg": ("dec_deg", "dec", "dej2000", "_dej2000", "decj2000", "dec_j2000", "de_icrs",
                "_de_icrs", "dec_icrs", "decdeg", "delta", "_de", "de", "dec_icrs_deg"),
    "priority": ("priority", "prio", "pri", "weight", "rank_priority"),
}
UCDS: dict[str, tuple[str, ...]] = {
    "id": ("meta.id;meta.main", "meta.id"),
    "ra_deg": ("pos.eq.ra;meta.main", "pos.eq.ra"),
    "dec_deg": ("pos.eq.dec;meta.main", "pos.eq.dec"),
}
FORMATS = {".csv": "ascii.csv", ".ecsv": "ascii.ecsv", ".tsv": TSV, ".vot": "votable",
           ".xml": "votable", ".votable": "votable", ".fits": "fits", ".fit": "fits",
           ".fts": "fits"}
#: How each sky frame's columns are converted (:mod:`service.table_motion`), for notices.
FRAME_DOC = {"galactic": "astropy's Galactic frame", "ecliptic": "astropy's "
             "BarycentricTrueEcliptic, equinox J2000.0"}
#: The formats read, for messages.
KNOWN = "give a .csv, .tsv, .ecsv, .vot or .fits table"
#: Suffixes of a compressed file, after its format's (``.fits.gz``, ``.csv.bz2``).
COMPRESSED = (".gz", ".bz2", ".xz")
MAX_ID_CHARS = 128

# unambiguous (no two ways to match a digit run), so a match takes time linear in the cell
_DECIMAL = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")
#: An RA or Dec cell longer than this is refused before any parsing (the longest sexagesimal
#: form with its separators and many decimals is well under it).
MAX_ANGLE_CELL_CHARS = 64
#: At most this much of an offending cell is echoed in an error message.
ECHO_CHARS = 40
_SEXAGESIMAL = re.compile(r"^[+-]?\d{1,3}\s*[:\shd°]\s*\d[\d\s:.hdms°′″'\"]*$")


@dataclass(frozen=True)
class TargetRow:
    """One target and where it came from (``row`` 1 = first data row; ``line`` of a CSV)."""

    id: str
    ra_deg: float
    dec_deg: float
    priority: int
    row: int
    line: int | None = None
    #: the motion fields given (:data:`models.epochs.MOTION_FIELDS`; none: no motion column)
    motion: dict[str, float] = field(default_factory=dict)

    def request(self) -> dict[str, Any]:
        return {"id": self.id, "ra_deg": self.ra_deg, "dec_deg": self.dec_deg,
                "priority": self.priority, **self.motion}


@dataclass(frozen=True)
class TargetTable:
    """A read table: its targets, the source column of each field and notices for the user."""

    source: str
    targets: tuple[TargetRow, ...]
    columns: dict[str, str | None]
    notices: tuple[str, ...]

    def rows(self) -> list[dict[str, Any]]:
        return [t.request() for t in self.targets]


def motion_lists(targets: Sequence[TargetRow]) -> dict[str, list[float | None]]:
    """The motion fields of ``targets`` as columns (None where a row has none); only the fields
    some row gives (empty: no motion at all)."""
    given = [f for f in MOTION_FIELDS if any(f in t.motion for t in targets)]
    return {f: [t.motion.get(f) for t in targets] for f in given}


def read_targets(path: str | Path) -> list[dict[str, Any]]:
    """Rows ``{id, ra_deg, dec_deg, priority}`` of a target table (see the module doc)."""
    return read_target_table(path).rows()


def read_target_table(path: str | Path, name: str | None = None,
                      rows: RowLimit | None = None) -> TargetTable:
    """Read and validate the table at ``path``; ``name`` is the file name used in messages
    and for the format (default: ``path`` itself). A plain (uncompressed) file is first
    looked at (:func:`service.table_checks.sniff`: content that is no table is refused in one
    line, a name without a known suffix takes the format its content shows), then checked by
    :func:`service.table_checks.check_table_file`: columns, cells, names and, with ``rows``,
    the row limit, all before the table reader sees it."""
    p = Path(path)
    label = name or str(p)
    if not p.is_file():
        raise TargetFileError(f"{label}: no such file")
    fmt = _format(label)
    if compression(p) in (None, "zip"):
        fmt = sniff(p, fmt, label)
        check_table_file(p, fmt, label, rows)
    loaded = _load(p, fmt, label, rows)
    table, n = loaded.table, loaded.n_rows
    if n == 0:
        raise TargetFileError(f"{label}: the table has no rows")
    cols: dict[str, str | None] = {k: _find_column(table, k) for k in ALIASES}
    lines = loaded.lines
    where = _Where(label, lines)
    notices: list[str] = []
    ra, dec = _positions(table, cols, where, notices)
    _check_ranges(ra, dec, cols, where)
    motion, motion_cols, motion_notes = read_motions(table, cols["ra_deg"], where.cell)
    cols.update(motion_cols)
    notices += [f"{label}: {n}" for n in motion_notes]
    if cols["id"]:
        ids = _ids(table[cols["id"]], where)
    else:
        ids = [str(i + 1) for i in range(n)]
        numbers = "1" if n == 1 else f"1..{n}"
        notices.append(f"{label}: no id column; targets are named by their row number ({numbers})")
    if cols["priority"]:
        prio = _priorities(table[cols["priority"]], where)
    else:
        prio = [1] * n
        notices.append(f"{label}: no priority column; every target has priority 1")
    targets = tuple(
        TargetRow(ids[i], float(ra[i]), float(dec[i]), prio[i], i + 1,
                  lines[i] if lines else None,
                  {f: float(v[i]) for f, v in motion.items() if math.isfinite(v[i])})
        for i in range(n)
    )
    return TargetTable(label, targets, cols, tuple(notices))


def _positions(table: Any, cols: dict[str, str | None], where: _Where,
               notices: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """ICRS RA/Dec (deg) of every row: from the RA/Dec columns, else from galactic or
    ecliptic longitude/latitude columns (:func:`service.table_motion.to_icrs`, with a notice
    naming them; ``cols`` then names them for ``ra_deg``/``dec_deg``); neither is an error
    naming the columns looked for."""
    if cols["ra_deg"] is not None and cols["dec_deg"] is not None:
        ra = _angles(table[cols["ra_deg"]], "ra_deg", where, notices)
        return ra, _angles(table[cols["dec_deg"]], "dec_deg", where, notices)
    found = frame_columns(table)
    if found is None:
        k = "ra_deg" if cols["ra_deg"] is None else "dec_deg"
        raise TargetFileError(
            f"{where.label}: no {k} column (looked for UCD {UCDS[k][0]} and the names "
            f"{', '.join(ALIASES[k])}; nor galactic or ecliptic longitude and latitude: "
            "_Glon/_Glat, GLON/GLAT, ELON/ELAT or UCD pos.galactic.lon/lat, "
            "pos.ecliptic.lon/lat)")
    frame, lon_col, lat_col = found
    lon = _angles(table[lon_col], "lon_deg", where, notices)
    lat = _angles(table[lat_col], "lat_deg", where, notices)
    for i in range(len(lon)):
        if not math.isfinite(lon[i]) or not -360.0 <= lon[i] <= 360.0:
            raise TargetFileError(f"{where.cell(i, lon_col)}: longitude {lon[i]:g} deg is not in "
                                  "[-360, 360]")
        if not math.isfinite(lat[i]) or not -90.0 <= lat[i] <= 90.0:
            raise TargetFileError(f"{where.cell(i, lat_col)}: latitude {lat[i]:g} deg is not in "
                                  "[-90, 90]")
    cols["ra_deg"], cols["dec_deg"] = lon_col, lat_col
    notices.append(f"{where.label}: no RA/Dec columns; the {frame.name} longitude and latitude "
                   f"columns {lon_col} and {lat_col} were converted to ICRS RA/Dec "
                   f"({FRAME_DOC[frame.name]})")
    return to_icrs(frame, lon, lat)


# --------------------------------------------------------------------------- reading


def table_suffix(name: str) -> str | None:
    """The format suffix of a file name (``.csv``, ``.fits``, ...), looked up after any
    compression suffix (``x.fits.gz`` -> ``.fits``); None when the name has none known."""
    low = name.lower()
    for z in COMPRESSED:
        if low.endswith(z):
            low = low[:-len(z)]
            break
    suffix = Path(low).suffix
    return suffix if suffix in FORMATS else None


def _format(label: str) -> str | None:
    suffix = table_suffix(label)
    return FORMATS[suffix] if suffix else None


@dataclass(frozen=True)
class _Loaded:
    """A table as its reader gave it, its number of rows and the file line of each (None when
    not known)."""

    table: Any
    n_rows: int
    lines: list[int] | None


def _load(p: Path, fmt: str | None, label: str, rows: RowLimit | None) -> _Loaded:
    if fmt == TSV:
        tsv = read_tsv(p, label, rows, _wanted)
        return _Loaded(tsv.table, tsv.n_rows, tsv.lines)
    table = _read_table(p, fmt, label)
    lines = _csv_lines(p, len(table)) if fmt == "ascii.csv" else None
    return _Loaded(table, len(table), lines)


def _wanted(name: str, ucd: str) -> bool:
    """Whether a column may be read for a field: one of the names or UCDs looked for."""
    return (any(name.lower() in names for names in ALIASES.values())
            or any(ucd.lower() in (x.lower() for x in ucds) for ucds in UCDS.values())
            or motion_wanted(name, ucd))


def _read_table(p: Path, fmt: str | None, label: str) -> Any:
    from astropy.io.registry import IORegistryError
    from astropy.table import Table

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # VOTable unit / schema chatter
            table = Table.read(p, format=fmt) if fmt else Table.read(p)
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 - astropy raises many kinds
        if _out_of_memory(exc):
            raise MemoryError(str(exc)) from exc
        if isinstance(exc, UnicodeDecodeError):
            raise TargetFileError(f"{label}: not a table: not UTF-8 text (byte "
                                  f"0x{exc.object[exc.start]:02x}); save the table as "
                                  "UTF-8") from None
        if isinstance(exc, IORegistryError) and fmt is None:
            raise TargetFileError(f"{label}: not a table: neither its name nor its content "
                                  f"tells a table format ({KNOWN})") from None
        raise TargetFileError(f"{label}: cannot read as a table ({_reason(exc)})") from exc
    return table


def _out_of_memory(exc: BaseException | None) -> bool:
    """Whether ``exc`` or an error it was raised from is the lack of memory (the reader
    wraps some in its own errors)."""
    seen = 0
    while exc is not None and seen < 16:
        if isinstance(exc, MemoryError) or (isinstance(exc, OSError) and exc.errno == errno.ENOMEM):
            return True
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return False


def _csv_lines(p: Path, n: int) -> list[int] | None:
    """File line (1-based) of each data row of a plain CSV, or None when it cannot be told
    (quoted line breaks)."""
    try:
        text = p.read_text(errors="replace")
    except OSError:
        return None
    if '"' in text and re.search(r'"[^"]*\n', text):
        return None
    numbers = [i + 1 for i, ln in enumerate(text.splitlines()) if ln.strip()]
    return numbers[1:n + 1] if len(numbers) == n + 1 else None


def _find_column(table: Any, wanted: str) -> str | None:
    for ucd in UCDS.get(wanted, ()):
        hits = [c for c in table.colnames
                if str(table[c].meta.get("ucd", "")).strip().lower() == ucd.lower()]
        if len(hits) == 1:
            return hits[0]
    lower = {n.lower(): n for n in table.colnames}
    for alias in ALIASES[wanted]:
        if alias in lower:
            return lower[alias]
    return None


@dataclass(frozen=True)
class _Where:
    label: str
    lines: list[int] | None

    def cell(self, i: int, column: str) -> str:
        line = f", line {self.lines[i]}" if self.lines else ""
        return f"{self.label}: row {i + 1}{line}, column {_echo(column)}"


def _masked(col: Any) -> np.ndarray:
    mask = getattr(col, "mask", None)
    if mask is None:
        return np.zeros(len(col), bool)
    return np.asarray(mask, bool).reshape(len(col), -1).any(axis=1)


def _angle_unit(col: Any, field: str) -> Any:
    """The column's angular unit, or None when it has none (or a non-angle one)."""
    from astropy import units as u

    unit = getattr(col, "unit", None)
    try:
        if unit is not None and u.Unit(unit).physical_type == "angle":
            return u.Unit(unit)
    except (ValueError, TypeError):
        pass
    if unit is not None and str(unit).lower().replace(" ", "") in ("h:m:s", "hms"):
        return u.hourangle
    return None


def _angles(col: Any, field: str, where: _Where, notices: list[str]) -> np.ndarray:
    """Degrees of every cell of an RA or Dec column, each read by its own form."""
    from astropy import units as u

    masked = _masked(col)
    if masked.any():
        i = int(np.flatnonzero(masked)[0])
        raise TargetFileError(f"{where.cell(i, col.name)}: empty {field} value")
    unit = _angle_unit(col, field)
    if col.dtype.kind in "iuf":
        values = np.asarray(col, float).reshape(len(col))
        return values * (unit.to(u.deg) if unit is not None else 1.0)
    sexa_unit = unit if unit is not None else (u.hourangle if field == "ra_deg" else u.deg)
    out = np.empty(len(col))
    forms: dict[str, list[int]] = {"decimal": [], "sexagesimal": []}
    for i, raw in enumerate(col):
        text = raw.decode() if isinstance(raw, bytes) else str(raw)
        out[i], form = _angle_cell(text.strip(), field, sexa_unit, unit, where.cell(i, col.name))
        forms[form].append(i + 1)
    if forms["decimal"] and forms["sexagesimal"]:
        hours = field == "ra_deg" and sexa_unit == u.hourangle
        decimal = "decimal degrees" if unit is None else f"decimal values in {unit}"
        notices.append(
            f"{where.label}: column {_echo(col.name)} mixes {decimal} "
            f"({_row_list(forms['decimal'])}) and sexagesimal {'hours' if hours else 'degrees'} "
            f"({_row_list(forms['sexagesimal'])}); each value was read by its own form")
    return out


def _angle_cell(text: str, field: str, sexa_unit: Any, unit: Any, cell: str) -> tuple[float, str]:
    from astropy import units as u
    from astropy.coordinates import Angle

    if not text:
        raise TargetFileError(f"{cell}: empty {field} value")
    if len(text) > MAX_ANGLE_CELL_CHARS:
        raise TargetFileError(f"{cell}: {field} value of {len(text)} characters "
                              f"({_echo(text)}) is longer than {MAX_ANGLE_CELL_CHARS}: not an angle")
    if _DECIMAL.match(text):
        return float(text) * (unit.to(u.deg) if unit is not None else 1.0), "decimal"
    if not _SEXAGESIMAL.match(text):
        raise TargetFileError(f"{cell}: {_echo(text)} is not an angle (decimal degrees, or "
                              f"sexagesimal such as {'16:41:41.7' if field == 'ra_deg' else '+36:27:41'})")
    try:
        named = re.search(r"[hd°]", text) is not None
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # e.g. minutes of 60 are an error, not a carry
            angle = Angle(text) if named else Angle(text, unit=sexa_unit)
        value = float(angle.to_value(u.deg))
    except (ValueError, u.UnitsError, Warning) as exc:
        raise TargetFileError(f"{cell}: {_echo(text)} is not an angle ({_reason(exc)})") from exc
    return value, "sexagesimal"


def _reason(exc: BaseException, most: int = 100) -> str:
    """A reader's error message for the user, cut to ``most`` characters (it may quote the
    file's content)."""
    text = " ".join(str(exc).split())
    return text if len(text) <= most else text[:most] + f"... ({len(text)} characters)"


def _echo(text: str) -> str:
    """``text`` quoted for an error message, cut to :data:`ECHO_CHARS` characters."""
    return repr(text) if len(text) <= ECHO_CHARS else repr(text[:ECHO_CHARS]) + f"... ({len(text)} characters)"


def _row_list(rows: Sequence[int], most: int = 8) -> str:
    """``row 3``, ``rows 1, 4``, ``rows 1, 2, ... and 5 more``: the first ``most`` row numbers."""
    shown = ", ".join(str(r) for r in rows[:most])
    more = f" and {len(rows) - most} more" if len(rows) > most else ""
    return f"{'row' if len(rows) == 1 else 'rows'} {shown}{more}"


def _cell_text(raw: Any) -> str:
    """A cell as the file wrote it, for reading and echoing: text as is; a number of a float
    column that is an integer without its ``.0`` (``-5``, not ``-5.0``)."""
    if isinstance(raw, bytes):
        return raw.decode(errors="replace").strip()
    if isinstance(raw, float | np.floating) and math.isfinite(raw) and float(raw).is_integer():
        return str(int(raw))
    return str(raw).strip()


def _check_ranges(ra: np.ndarray, dec: np.ndarray, cols: dict[str, str | None],
                  where: _Where) -> None:
    for i in range(len(ra)):
        if not math.isfinite(ra[i]) or not 0.0 <= ra[i] < 360.0:
            raise TargetFileError(f"{where.cell(i, str(cols['ra_deg']))}: RA {ra[i]:g} deg is "
                                  "not in [0, 360)")
        if not math.isfinite(dec[i]) or not -90.0 <= dec[i] <= 90.0:
            raise TargetFileError(f"{where.cell(i, str(cols['dec_deg']))}: Dec {dec[i]:g} deg is "
                                  "not in [-90, 90]")


def _ids(col: Any, where: _Where) -> list[str]:
    masked = _masked(col)
    ids: list[str] = []
    seen: dict[str, int] = {}
    for i, raw in enumerate(col):
        text = (raw.decode() if isinstance(raw, bytes) else str(raw)).strip()
        if masked[i] or not text:
            raise TargetFileError(f"{where.cell(i, col.name)}: empty id")
        if len(text) > MAX_ID_CHARS:
            raise TargetFileError(f"{where.cell(i, col.name)}: id longer than {MAX_ID_CHARS} "
                                  "characters")
        if text in seen:
            raise TargetFileError(f"{where.cell(i, col.name)}: duplicate id {_echo(text)} (also row "
                                  f"{seen[text] + 1})")
        seen[text] = i
        ids.append(text)
    return ids


def _priorities(col: Any, where: _Where) -> list[int]:
    masked = _masked(col)
    out: list[int] = []
    for i, raw in enumerate(col):
        cell = where.cell(i, col.name)
        if masked[i]:
            raise TargetFileError(f"{cell}: empty priority")
        text = _cell_text(raw)
        try:
            f = float(text)
        except ValueError:
            raise TargetFileError(f"{cell}: priority {_echo(text)} is not a number (integers "
                                  f"1..{MAX_PRIORITY})") from None
        if not math.isfinite(f) or not f.is_integer() or not 1 <= f <= MAX_PRIORITY:
            raise TargetFileError(f"{cell}: priority {_echo(text)} is not an integer in "
                                  f"1..{MAX_PRIORITY}")
        out.append(int(f))
    return out
