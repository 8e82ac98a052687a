"""Checks of a target table's file before a table reader sees it: sizes, shapes and names that
cost the reader time or memory out of proportion to the file.

* :func:`decompress` stream-decompresses a gzip, bzip2 or xz file to a plain one, refusing
  at a bound on the decompressed bytes (so a small file declaring a huge size costs at most
  the bound, never the memory of the whole) and refusing nested compression and zip archives.
* :func:`sniff` looks at the plain file's first bytes: content that is no table (an image, a
  PDF, a zip archive, binary data, text that is not UTF-8) is refused in one line, ``not a
  table: <what it is>``, and a name without a known suffix takes the format the content shows.
* :func:`check_table_file` reads only what it needs of the plain file:

  - FITS: the headers of every HDU, card by card (no data). Each HDU's declared data size
    (``|BITPIX|/8 * GCOUNT * (PCOUNT + NAXIS1 * NAXIS2 * ...)``) must fit in the file, and
    the first table's declared rows (``NAXIS2``) must be within the row limit.
  - CSV and ECSV: one pass of the :mod:`csv` module (linear time). At most
    :data:`MAX_COLUMNS` columns, every cell at most :data:`MAX_CELL_CHARS` characters, no
    empty or repeated column name, no row with more cells than the header names (CSV), and
    the rows counted against the row limit as they are read (the pass stops at the first row
    over it). An ECSV header (its ``#`` lines) holds at most :data:`MAX_ECSV_HEADER_CHARS`.
  - VOTable: ``<FIELD`` and ``<TR`` elements counted in the raw bytes against
    :data:`MAX_COLUMNS` and the row limit.
  - VizieR's TSV: checked by its reader (:mod:`service.vizier_tsv`) in its one pass, with
    the CSV bounds.

Every refusal is a :class:`TargetFileError` naming the file, and the line,
row or column where that applies; an echoed value is cut to a few dozen characters.
"""

from __future__ import annotations

import bz2
import codecs
import csv
import gzip
import lzma
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

#: Most columns of a table (a Gaia archive export has about 150).
MAX_COLUMNS = 1000
#: Longest cell of a CSV or ECSV file, in characters (ids are at most 128, angles 64).
MAX_CELL_CHARS = 4096
#: Longest line of a CSV or ECSV file read at once, in characters.
MAX_LINE_CHARS = MAX_COLUMNS * (MAX_CELL_CHARS + 3)
#: Most characters of an ECSV file's YAML header (its ``#`` lines).
MAX_ECSV_HEADER_CHARS = 1_000_000
#: Most HDUs of a FITS file.
MAX_FITS_HDUS = 1000
#: At most this much of a header value or column name is echoed in an error message.
ECHO_CHARS = 40

_BLOCK = 2880
_CARD = 80
_MAGIC: dict[bytes, tuple[str, Any]] = {
    b"\x1f\x8b": ("gzip", gzip.open),
    b"BZh": ("bzip2", bz2.open),
    b"\xfd7zXZ\x00": ("xz", lzma.open),
}
_CHUNK_BYTES = 1 << 20
#: The format name of VizieR's tab-separated export (read by :mod:`service.vizier_tsv`).
TSV = "vizier.tsv"
#: Bytes of a file looked at to tell what it is.
HEAD_BYTES = 1 << 16
#: What a file's first bytes say it is when it is no table (magic numbers).
NOT_TABLES: tuple[tuple[bytes, str], ...] = (
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"%PDF-", "a PDF document"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"GIF87a", "a GIF image"), (b"GIF89a", "a GIF image"),
    (b"II*\x00", "a TIFF image"), (b"MM\x00*", "a TIFF image"),
    (b"\x7fELF", "a program (ELF)"),
    (b"PK\x03\x04", "a zip archive (a .xlsx or .ods sheet is one: save it as CSV); give the "
                    "table itself, plain or compressed with gzip, bzip2 or xz"),
    (b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1", "a Microsoft Office document (save the sheet as CSV)"),
)
#: Bytes that text holds rarely or never (controls other than tab, line feed, form feed and
#: carriage return).
_CONTROL_BYTES = bytes([*range(0, 9), 11, *range(14, 32), 127])


class TargetFileError(ValueError):
    """A target table that cannot be read; the message names file, row (or line) and column."""


@dataclass(frozen=True)
class RowLimit:
    """The most rows a table may hold, and why (the setting that says so)."""

    most: int
    why: str = ""  # appended to "at most N targets", e.g. " in a target list (MXS_...=N)"

    def refuse(self, label: str, what: str) -> TargetFileError:
        return TargetFileError(f"{label}: {what}; at most {count(self.most, 'target')}{self.why}")


def echo(text: str, most: int = ECHO_CHARS) -> str:
    """``text`` quoted for an error message, cut to ``most`` characters."""
    if len(text) <= most:
        return repr(text)
    return repr(text[:most]) + f"... ({len(text)} characters)"


def count(n: int, word: str) -> str:
    """``n`` and ``word`` in the singular or plural (``1 row``, ``2 rows``)."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


# ------------------------------------------------------------------ compression


def compression(path: Path) -> str | None:
    """``gzip``, ``bzip2``, ``xz`` or ``zip`` when the file's first bytes say so, else None."""
    with open(path, "rb") as f:
        head = f.read(6)
    for magic, (name, _) in _MAGIC.items():
        if head.startswith(magic):
            return name
    return "zip" if head.startswith(b"PK\x03\x04") else None


def decompress(path: Path, out: Path, max_bytes: int, label: str, setting: str = "") -> bool:
    """Write the decompressed content of ``path`` to ``out`` and return True when ``path`` is
    compressed (False, and nothing written, when it is plain). More than ``max_bytes``
    decompressed bytes, a zip archive or compressed content inside are refused."""
    kind = compression(path)
    if kind is None:
        return False
    if kind == "zip":
        raise TargetFileError(f"{label}: a zip archive is not read; upload the table itself "
                              "(plain, or compressed with gzip, bzip2 or xz)")
    opener = next(o for name, o in _MAGIC.values() if name == kind)
    written = 0
    try:
        with opener(path, "rb") as src, open(out, "wb") as dst:
            while chunk := src.read(_CHUNK_BYTES):
                written += len(chunk)
                if written > max_bytes:
                    named = f" ({setting}={max_bytes})" if setting else ""
                    raise TargetFileError(
                        f"{label}: decompresses to more than {max_bytes} bytes{named}")
                dst.write(chunk)
    except (OSError, EOFError, lzma.LZMAError, ValueError) as exc:
        if isinstance(exc, TargetFileError):
            raise
        raise TargetFileError(f"{label}: cannot decompress ({kind}): {echo(str(exc), 100)}") from exc
    if compression(out) is not None:
        raise TargetFileError(f"{label}: compressed twice; upload it compressed once at most")
    return True


def open_plain(path: Path) -> IO[bytes]:
    """``path`` opened for reading its content: through its decompressor when it is compressed
    with gzip, bzip2 or xz."""
    kind = compression(path)
    opener = next((o for name, o in _MAGIC.values() if name == kind), None)
    return opener(path, "rb") if opener is not None else open(path, "rb")  # type: ignore[no-any-return]


# ------------------------------------------------------------------ what the content is


def sniff(path: Path, fmt: str | None, label: str) -> str | None:
    """The format to read the plain file ``path`` in, from its first :data:`HEAD_BYTES`:

    * content that is no table (an image, a PDF, a program, binary data, text that is not
      UTF-8) is refused with one line, ``<label>: not a table: <what it is>``;
    * FITS content (a ``SIMPLE`` card first) is read as FITS whatever the name says;
    * otherwise ``fmt`` (from the file's name), or, when the name names no format, the format
      the content shows (:func:`text_format`; None when it shows none)."""
    with open(path, "rb") as f:
        head = f.read(HEAD_BYTES)
    for magic, what in NOT_TABLES:
        if head.startswith(magic):
            raise TargetFileError(f"{label}: not a table: {what}")
    if head.startswith(b"SIMPLE  ="):
        return "fits"
    if fmt == "fits":
        return fmt  # check_fits says what is wrong with it
    why = _not_text(head, complete=len(head) < HEAD_BYTES, xml=fmt == "votable")
    if why:
        raise TargetFileError(f"{label}: not a table: {why}")
    return fmt or text_format(head)


def _not_text(head: bytes, complete: bool, xml: bool) -> str | None:
    """Why ``head`` (a file's first bytes; ``complete`` when they are the whole file) is no
    table text, or None. Control bytes make binary data; other text must be UTF-8 (a VOTable's
    XML may declare another encoding, which its parser reads)."""
    odd = sum(head.count(bytes([b])) for b in _CONTROL_BYTES)
    if b"\x00" in head or odd > 8 + len(head) // 100:  # a stray one is text
        return ("binary data, not text (give a CSV, TSV, ECSV or VOTable file, or a FITS "
                "table)")
    if xml:
        return None
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=complete)
    except UnicodeDecodeError as exc:
        line = head.count(b"\n", 0, exc.start) + 1
        return (f"line {line} is not UTF-8 text (byte 0x{head[exc.start]:02x}); save the "
                "table as UTF-8")
    return None


def text_format(head: bytes) -> str | None:
    """The format a text file's first bytes show: VOTable (XML), ECSV (its ``# %ECSV``
    line), :data:`TSV` (a first line that is no comment and holds a tab); None otherwise."""
    start = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if start.startswith((b"<?xml", b"<VOTABLE")):
        return "votable"
    if start.startswith(b"# %ECSV"):
        return "ascii.ecsv"
    for line in start.splitlines():
        if line.strip() and not line.startswith(b"#"):
            return TSV if b"\t" in line else None
    return None


# ------------------------------------------------------------------ the checks


def check_table_file(path: Path, fmt: str | None, label: str, rows: RowLimit | None) -> None:
    """Refuse ``path`` (a plain, uncompressed file of format ``fmt``, astropy's name) when
    its declared or counted shape is beyond the bounds of this module or ``rows``."""
    if fmt == "fits":
        check_fits(path, label, rows)
    elif fmt in ("ascii.csv", "ascii.ecsv"):
        check_text(path, label, rows, ecsv=fmt == "ascii.ecsv")
    elif fmt == "votable":
        check_votable(path, label, rows)


# ------------------------------------------------------------------ FITS


@dataclass(frozen=True)
class FitsHdu:
    """One HDU as its header declares it."""

    index: int
    table: bool
    rows: int
    data_bytes: int


class _BadFits(ValueError):
    """A FITS header that cannot be read (wrapped into a :class:`TargetFileError`)."""


def _card_value(card: bytes) -> str:
    text = card[10:].decode("ascii", "replace")
    return text.split("/", 1)[0].strip().strip("'").strip()


def _header(f: IO[bytes], index: int) -> dict[str, str] | None:
    """The cards of one header (keyword -> value text), or None at the end of the file."""
    cards: dict[str, str] = {}
    first = True
    while True:
        block = f.read(_BLOCK)
        if not block and first and index > 0:
            return None
        if len(block) < _BLOCK:
            raise _BadFits(f"HDU {index}: the header ends before its END card")
        if first and index == 0 and not block.startswith(b"SIMPLE  ="):
            raise _BadFits("not a FITS file: it does not start with a SIMPLE card")
        first = False
        for k in range(0, _BLOCK, _CARD):
            card = block[k:k + _CARD]
            key = card[:8].decode("ascii", "replace").strip()
            if key == "END":
                return cards
            if card[8:10] == b"= " and key not in cards:
                cards[key] = _card_value(card)


def _int_card(cards: dict[str, str], key: str, index: int, default: int | None = None) -> int:
    if key not in cards:
        if default is not None:
            return default
        raise _BadFits(f"HDU {index}: the header lacks {key}")
    try:
        return int(cards[key])
    except ValueError:
        raise _BadFits(f"HDU {index}: {key} = {echo(cards[key])} is not an integer") from None


def _hdu(cards: dict[str, str], index: int) -> FitsHdu:
    naxis = _int_card(cards, "NAXIS", index)
    if not 0 <= naxis <= 999:
        raise _BadFits(f"HDU {index}: NAXIS = {naxis} is not in 0..999")
    axes = [_int_card(cards, f"NAXIS{i}", index) for i in range(1, naxis + 1)]
    bitpix = abs(_int_card(cards, "BITPIX", index))
    pcount = _int_card(cards, "PCOUNT", index, 0)
    gcount = _int_card(cards, "GCOUNT", index, 1)
    if min(axes, default=0) < 0 or pcount < 0 or gcount < 0:
        raise _BadFits(f"HDU {index}: a negative NAXISn, PCOUNT or GCOUNT")
    if cards.get("GROUPS") == "T" and axes and axes[0] == 0:
        axes = axes[1:]  # random groups: NAXIS1 = 0 is not a dimension
    elements = 0
    if axes:
        elements = 1
        for n in axes:
            elements *= n
    data_bytes = bitpix // 8 * gcount * (pcount + elements)
    table = cards.get("XTENSION", "").upper() in ("BINTABLE", "TABLE")
    rows = axes[1] if table and len(axes) > 1 else 0
    return FitsHdu(index, table, rows, data_bytes)


def fits_hdus(path: Path, label: str) -> list[FitsHdu]:
    """Every HDU of a FITS file as its header declares it; refuses data that the file does
    not hold (a header declaring more rows than were sent)."""
    size = path.stat().st_size
    hdus: list[FitsHdu] = []
    try:
        with open(path, "rb") as f:
            while (cards := _header(f, len(hdus))) is not None:
                hdu = _hdu(cards, len(hdus))
                left = size - f.tell()
                if hdu.data_bytes > left:
                    rows = f" ({hdu.rows} rows)" if hdu.table else ""
                    raise _BadFits(f"HDU {hdu.index} declares {hdu.data_bytes} bytes of "
                                   f"data{rows} but the file holds {left} bytes after its "
                                   "header (truncated, or a header that does not describe "
                                   "its data)")
                hdus.append(hdu)
                if len(hdus) > MAX_FITS_HDUS:
                    raise _BadFits(f"more than {MAX_FITS_HDUS} HDUs")
                f.seek(-(-hdu.data_bytes // _BLOCK) * _BLOCK, 1)
    except _BadFits as exc:
        raise TargetFileError(f"{label}: cannot read as a table (FITS: {exc})") from None
    return hdus


def check_fits(path: Path, label: str, rows: RowLimit | None) -> None:
    """The FITS checks of the module doc."""
    hdus = fits_hdus(path, label)
    tables = [h for h in hdus if h.table]
    if not tables:
        raise TargetFileError(f"{label}: cannot read as a table (FITS: no table HDU, "
                              "BINTABLE or TABLE)")
    first = tables[0]
    if rows is not None and first.rows > rows.most:
        raise rows.refuse(label, f"HDU {first.index} declares {first.rows} rows")


# ------------------------------------------------------------------ CSV, ECSV


def bounded_lines(f: IO[str], label: str) -> Iterator[str]:
    """The lines of ``f``, each read with a bound on its length."""
    number = 0
    while line := f.readline(MAX_LINE_CHARS):
        number += 1
        if len(line) >= MAX_LINE_CHARS and not line.endswith("\n"):
            raise TargetFileError(f"{label}: line {number} is longer than {MAX_LINE_CHARS} "
                                  f"characters (at most {MAX_COLUMNS} columns of "
                                  f"{MAX_CELL_CHARS} characters)")
        yield line


def _ecsv_header(lines: Iterator[str], label: str) -> tuple[str, str]:
    """Consume an ECSV file's ``#`` header; return its delimiter and the first other line."""
    chars = 0
    delimiter = " "
    for line in lines:
        if not line.startswith("#"):
            if line.strip():
                return delimiter, line
            continue
        chars += len(line)
        if chars > MAX_ECSV_HEADER_CHARS:
            raise TargetFileError(f"{label}: the ECSV header is longer than "
                                  f"{MAX_ECSV_HEADER_CHARS} characters")
        m = re.match(r"#\s*delimiter:\s*'(.)'", line)
        if m:
            delimiter = m.group(1)
    return delimiter, ""


def check_names(names: list[str], label: str, line: int) -> None:
    if len(names) > MAX_COLUMNS:
        raise TargetFileError(f"{label}: line {line} names {len(names)} columns; at most "
                              f"{MAX_COLUMNS}")
    seen: dict[str, int] = {}
    for k, raw in enumerate(names, start=1):
        name = raw.strip()
        if not name:
            raise TargetFileError(f"{label}: line {line}, column {k} has no name")
        if len(name) > MAX_CELL_CHARS:
            raise TargetFileError(f"{label}: line {line}, column {k}: the name is longer "
                                  f"than {MAX_CELL_CHARS} characters")
        if name in seen:
            raise TargetFileError(f"{label}: line {line}, column {k}: the name {echo(name)} "
                                  f"repeats column {seen[name]}; column names must differ")
        seen[name] = k


def check_row(row: list[str], names: list[str], where: tuple[str, int, int],
               csv_format: bool) -> None:
    """One data row: its number of cells and each cell's length; ``where`` is (label, row,
    line)."""
    label, n_row, line = where
    if len(row) > MAX_COLUMNS or (csv_format and len(row) > len(names)):
        raise TargetFileError(f"{label}: row {n_row}, line {line} has {count(len(row), 'cell')}; "
                              f"the header names {count(len(names), 'column')}")
    for k, cell in enumerate(row):
        if len(cell) > MAX_CELL_CHARS:
            name = names[k].strip() if k < len(names) else f"#{k + 1}"
            raise TargetFileError(f"{label}: row {n_row}, line {line}, column {echo(name)}: a "
                                  f"cell of {len(cell)} characters ({echo(cell)}) is longer "
                                  f"than {MAX_CELL_CHARS}")


def _blank(row: list[str]) -> bool:
    return not row or (len(row) == 1 and not row[0].strip())


def check_text(path: Path, label: str, rows: RowLimit | None, *, ecsv: bool = False) -> None:
    """The CSV / ECSV checks of the module doc, in one pass of the :mod:`csv` module."""
    with open(path, encoding="utf-8", errors="replace", newline="") as f:
        lines = bounded_lines(f, label)
        delimiter, first = _ecsv_header(lines, label) if ecsv else (",", "")
        source = _chain(first, lines) if ecsv else lines
        reader = csv.reader(source, delimiter=delimiter, skipinitialspace=delimiter == " ")
        names: list[str] | None = None
        n_rows = 0
        try:
            for row in reader:
                if _blank(row):
                    continue
                if names is None:
                    names = row
                    check_names(names, label, reader.line_num)
                    continue
                n_rows += 1
                check_row(row, names, (label, n_rows, reader.line_num), not ecsv)
                if rows is not None and n_rows > rows.most:
                    raise rows.refuse(label, f"more than {rows.most} rows (line "
                                      f"{reader.line_num})")
        except csv.Error as exc:
            why = (f"a cell is longer than {MAX_CELL_CHARS} characters"
                   if "field limit" in str(exc) else echo(str(exc), 100))
            raise TargetFileError(f"{label}: row {n_rows + 1}, line {reader.line_num}: "
                                  f"{why}") from None


def _chain(first: str, rest: Iterator[str]) -> Iterator[str]:
    if first:
        yield first
    yield from rest


# ------------------------------------------------------------------ VOTable


_FIELD = re.compile(rb"<FIELD[\s/>]")
_TR = re.compile(rb"<TR[\s>]")


def check_votable(path: Path, label: str, rows: RowLimit | None) -> None:
    """Count ``<FIELD`` and ``<TR`` elements in the raw file (a VOTable is XML; these counts
    bound what its parser builds)."""
    data = path.read_bytes()
    n_fields = sum(1 for _ in _FIELD.finditer(data))
    if n_fields > MAX_COLUMNS:
        raise TargetFileError(f"{label}: {n_fields} FIELD elements; at most {MAX_COLUMNS} columns")
    if rows is None:
        return
    n_rows = 0
    for _ in _TR.finditer(data):
        n_rows += 1
        if n_rows > rows.most:
            raise rows.refuse(label, f"more than {rows.most} rows (TR elements)")
