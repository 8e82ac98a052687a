"""The command line's sky files: ``--sky FILE`` (the astronomer's sky positions, a CSV of
RA/Dec in degrees) in, and ``assignments.csv`` (every arm of every configuration with its
``kind``: target, sky, park, fixed or blank) out."""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

ASSIGNMENTS_NAME = "assignments.csv"
ASSIGNMENT_COLUMNS = ("pointing", "configuration", "arm", "kind", "target_id", "x_mm", "y_mm",
                      "theta1_rad", "theta2_rad", "sky_ra_deg", "sky_dec_deg")
RA_NAMES = ("ra", "ra_deg", "raj2000", "ra_icrs", "_raj2000")
DEC_NAMES = ("dec", "dec_deg", "dej2000", "de_icrs", "_dej2000", "decj2000")


class SkyFileError(ValueError):
    """A ``--sky`` file that cannot be read; the message names the file, row and column."""


def _number(text: str, path: str, row: int, column: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise SkyFileError(f"--sky {path}: row {row}: {column} {text!r} is not a number") from None
    if not math.isfinite(v):
        raise SkyFileError(f"--sky {path}: row {row}: {column} must be finite, got {text!r}")
    return v


def _columns(header: list[str], path: str) -> tuple[int, int]:
    """The RA and Dec columns of a header row (names as in RA_NAMES / DEC_NAMES, any case)."""
    names = [h.strip().lower() for h in header]
    ra = next((i for i, n in enumerate(names) if n in RA_NAMES), None)
    dec = next((i for i, n in enumerate(names) if n in DEC_NAMES), None)
    if ra is None or dec is None:
        raise SkyFileError(f"--sky {path}: no {'RA' if ra is None else 'Dec'} column in the header "
                           f"{header}: name them ra,dec (degrees) or give two numeric columns")
    return ra, dec


def read_sky_file(path: str) -> list[dict[str, float]]:
    """The sky positions of a CSV file: two numeric columns RA, Dec (degrees), with or without
    a header row naming them (ra/ra_deg, dec/dec_deg, ...); blank and ``#`` lines are skipped."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise SkyFileError(f"--sky {path}: cannot read it ({exc})") from None
    rows = [(i + 1, r) for i, r in enumerate(csv.reader(text.splitlines()))
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise SkyFileError(f"--sky {path}: no sky positions in the file")
    ra_col, dec_col = 0, 1
    first = rows[0][1]
    try:
        float(first[0])
    except ValueError:
        ra_col, dec_col = _columns(first, path)
        rows = rows[1:]
    out = []
    for n, r in rows:
        if len(r) <= max(ra_col, dec_col):
            raise SkyFileError(f"--sky {path}: row {n}: expected RA and Dec, got {r}")
        out.append({"ra_deg": _number(r[ra_col].strip(), path, n, "RA"),
                    "dec_deg": _number(r[dec_col].strip(), path, n, "Dec")})
    return out


def write_assignments(result: Mapping[str, Any], out: Path) -> Path:
    """``assignments.csv``: one row per arm of every configuration (c1 ... cn as on the page),
    with its kind and, for a sky arm, the RA/Dec its tip points at."""
    path = out / ASSIGNMENTS_NAME
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(ASSIGNMENT_COLUMNS)
        for p in result["pointings"]:
            for c in p["configurations"]:
                for a in c["assignments"]:
                    w.writerow([p["id"], f"c{int(c['index']) + 1}", a["arm"], a.get("kind") or "",
                                a.get("target_id") or "", f"{a['x_mm']:.4f}", f"{a['y_mm']:.4f}",
                                f"{a['theta1_rad']:.6f}", f"{a['theta2_rad']:.6f}",
                                _deg(a.get("sky_ra_deg")), _deg(a.get("sky_dec_deg"))])
    return path


def _deg(v: float | None) -> str:
    return "" if v is None else f"{v:.7f}"
