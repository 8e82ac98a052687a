"""A corpus of hostile and accidental target-table uploads, built by code at any size.

:func:`build` writes the files into a directory and returns one :class:`Attack` per file: its
upload name, the statuses a server may answer and a phrase the answer must contain (the
problem, named). ``size_bytes`` is the size of the big files (the upload limit in
``benchmarks/load.py --attack``; a couple of MB in the tests); ``bomb_bytes`` the
decompressed size of the compression bombs (larger than the server's
``MXS_MAX_UPLOAD_DECOMPRESSED_BYTES``). Every file is streamed to disk, so building the corpus
takes memory independent of its size.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

_BLOCK = 2880
_CHUNK = 1 << 20


@dataclass(frozen=True)
class Attack:
    """One hostile file and what a server must answer to it."""

    name: str
    filename: str
    path: Path
    statuses: tuple[int, ...]
    says: str


# ------------------------------------------------------------------ writers


def _card(key: str, value: str | int) -> bytes:
    text = f"{key:<8}= {value!s:>20}" if not isinstance(value, str) else f"{key:<8}= {value:<20}"
    return text.ljust(80).encode()


def fits_header(cards: list[tuple[str, str | int]]) -> bytes:
    """One FITS header: the cards, END, padded to 2880 bytes."""
    raw = b"".join(_card(k, v) for k, v in cards) + b"END".ljust(80)
    return raw + b" " * (-len(raw) % _BLOCK)


def table_fits_header(rows: int) -> bytes:
    """A primary HDU and the header of a binary table of ``rows`` rows of two int16 columns
    ``ra`` and ``dec`` (4 bytes a row)."""
    primary = fits_header([("SIMPLE", "T"), ("BITPIX", 8), ("NAXIS", 0), ("EXTEND", "T")])
    table = fits_header([
        ("XTENSION", "'BINTABLE'"), ("BITPIX", 8), ("NAXIS", 2), ("NAXIS1", 4),
        ("NAXIS2", rows), ("PCOUNT", 0), ("GCOUNT", 1), ("TFIELDS", 2),
        ("TTYPE1", "'ra'"), ("TFORM1", "'I'"), ("TTYPE2", "'dec'"), ("TFORM2", "'I'")])
    return primary + table


def _zeros(f: IO[bytes], n: int) -> None:
    chunk = bytes(_CHUNK)
    while n > 0:
        f.write(chunk[:min(n, _CHUNK)])
        n -= _CHUNK


def _repeat(f: IO[bytes], unit: bytes, n_bytes: int) -> None:
    """Write ``unit`` over and over, about ``n_bytes`` in all."""
    block = unit * max(_CHUNK // len(unit), 1)
    written = 0
    while written + len(block) <= n_bytes:
        f.write(block)
        written += len(block)
    f.write(unit * ((n_bytes - written) // len(unit)))


def _write(path: Path, fill: Callable[[IO[bytes]], None],
           opener: Callable[..., IO[bytes]] = open) -> Path:
    with opener(path, "wb") as f:
        fill(f)
    return path


# ------------------------------------------------------------------ the corpus


def _text_attacks(d: Path, size: int) -> list[Attack]:
    cols = max(size // 2 - 4, 20_000)
    return [
        Attack("duplicate_columns_40kb", "dup40k.csv", _write(
            d / "dup40k.csv", lambda f: f.write(",".join(["10", "20"] + ["0"] * 19_998).encode() + b"\n")),
            (422,), "20000 columns"),
        Attack("duplicate_columns_to_limit", "dup.csv", _write(
            d / "dup.csv", lambda f: (f.write(b"10,20"), _repeat(f, b",0", cols * 2), f.write(b"\n"))),
            (422,), "columns"),
        Attack("repeated_name", "rep.csv", _write(
            d / "rep.csv", lambda f: f.write(b"ra,dec,x,x\n1,2,3,4\n")), (422,), "repeats column 3"),
        Attack("empty_name", "empty.csv", _write(
            d / "empty.csv", lambda f: f.write(b"ra,,dec\n1,2,3\n")), (422,), "column 2 has no name"),
        Attack("long_ra_cell_30kb", "r.csv", _write(
            d / "r.csv", lambda f: f.write(b"ra,dec\n" + b"1" * 30_000 + b"x,20\n")),
            (422,), "30001 characters"),
        Attack("long_cell_to_limit", "long.csv", _write(
            d / "long.csv", lambda f: (f.write(b"ra,dec\n"), _repeat(f, b"1", size - 20),
                                       f.write(b"x,20\n"))), (422,), "longer than"),
        Attack("many_rows", "rows.csv", _write(
            d / "rows.csv", lambda f: (f.write(b"ra,dec\n"), _repeat(f, b"1,2\n", size))),
            (422,), "rows"),
        Attack("many_columns", "wide.csv", _write(d / "wide.csv", lambda f: _wide(f, size)),
               (413, 422), "wide.csv"),
        Attack("ecsv_huge_header", "big.ecsv", _write(
            d / "big.ecsv", lambda f: (f.write(b"# %ECSV 1.0\n# ---\n"),
                                       _repeat(f, b"# x: " + b"a" * 70 + b"\n", size))),
            (422,), "ECSV header"),
        Attack("votable_many_rows", "rows.vot", _write(d / "rows.vot", lambda f: _votable(f, size)),
               (422,), "rows"),
    ]


def _wide(f: IO[bytes], size: int) -> None:
    """1000 columns (``ra``, ``dec`` and 998 more) and rows of zeros to ``size``; the last RA
    is not a number, so that the whole table must be read before the answer."""
    f.write(b"ra,dec," + ",".join(f"c{k}" for k in range(998)).encode() + b"\n")
    row = b"0," * 999 + b"0\n"
    _repeat(f, row, size - 2 * len(row))
    f.write(b"x," + row[2:])


def _votable(f: IO[bytes], size: int) -> None:
    f.write(b'<?xml version="1.0"?>\n<VOTABLE version="1.4"><RESOURCE><TABLE>'
            b'<FIELD name="ra" datatype="double"/><FIELD name="dec" datatype="double"/>'
            b"<DATA><TABLEDATA>\n")
    _repeat(f, b"<TR><TD>1</TD><TD>2</TD></TR>\n", size)
    f.write(b"</TABLEDATA></DATA></TABLE></RESOURCE></VOTABLE>\n")


def _fits_attacks(d: Path, size: int, bomb: int) -> list[Attack]:
    huge = 200_000_000  # declared rows of the bombs (800 MB of data)
    rows_plain = max(size // 4, 200_001)
    return [
        Attack("fits_many_rows", "big.fits", _write(
            d / "big.fits", lambda f: (f.write(table_fits_header(rows_plain)), _zeros(f, rows_plain * 4))),
            (422,), f"declares {rows_plain} rows"),
        Attack("fits_truncated", "cut.fits", _write(
            d / "cut.fits", lambda f: (f.write(table_fits_header(huge)), _zeros(f, _BLOCK)))
            , (422,), "truncated"),
        Attack("gzip_declared_rows", "decl.fits.gz", _write(
            d / "decl.fits.gz", lambda f: (f.write(table_fits_header(6_000_000)),
                                           _zeros(f, min(24_000_000, bomb // 4))), gzip.open),
            (422,), "rows"),
        Attack("gzip_bomb", "bomb.fits.gz", _write(
            d / "bomb.fits.gz", lambda f: (f.write(table_fits_header(huge)), _zeros(f, bomb)),
            gzip.open), (422,), "decompresses to more than"),
        Attack("bzip2_bomb", "bomb.fits.bz2", _write(
            d / "bomb.fits.bz2", lambda f: (f.write(table_fits_header(huge)), _zeros(f, bomb)),
            bz2.open), (422,), "decompresses to more than"),
        Attack("xz_bomb_named_csv", "bomb.csv", _write(
            d / "bomb.csv", lambda f: (f.write(b"ra,dec\n"), _repeat(f, b"1,2\n", bomb)),
            lambda p, m: lzma.open(p, m, preset=0)), (422,), "decompresses to more than"),
        Attack("gzip_twice", "twice.csv.gz", _twice(d / "twice.csv.gz"), (422,), "compressed twice"),
        Attack("zip", "t.fits", _zip(d / "t.zip"), (422,), "zip archive"),
        Attack("many_hdus", "hdus.fits", _write(
            d / "hdus.fits", lambda f: (f.write(table_fits_header(1)), f.write(bytes(_BLOCK)),
                                        _repeat(f, _image_hdu(), 1100 * _BLOCK))),
            (422,), "HDUs"),
    ]


def _image_hdu() -> bytes:
    return fits_header([("XTENSION", "'IMAGE'"), ("BITPIX", 8), ("NAXIS", 0), ("PCOUNT", 0),
                        ("GCOUNT", 1)])


def _twice(path: Path) -> Path:
    path.write_bytes(gzip.compress(gzip.compress(b"ra,dec\n1,2\n")))
    return path


def _zip(path: Path) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("t.fits", table_fits_header(1) + bytes(_BLOCK))
    return path


def build(directory: Path, size_bytes: int, bomb_bytes: int) -> list[Attack]:
    """Write the corpus into ``directory`` (see the module doc)."""
    directory.mkdir(parents=True, exist_ok=True)
    return _text_attacks(directory, size_bytes) + _fits_attacks(directory, size_bytes, bomb_bytes)
