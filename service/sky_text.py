"""How the CLI and its pictures write coordinates, counts and priorities: the same forms as the
page's ``service/static/format.js`` (``raHms``, ``decDms``, ``radecText``, ``plural``,
``priorityText``), so a position reads the same in the terminal, a PNG and the browser.

Astronomers read sexagesimal; every position is written in both forms,
``08h51m18.48s +11°46′50.7″ (132.82698°, +11.78075°)``.
"""

from __future__ import annotations

import math

RA_DECIMALS = 2  # seconds of time: 0.01 s = 0.15 arcsec
DEC_DECIMALS = 1  # seconds of arc


def _parts(value: float, decimals: int) -> tuple[int, int, float]:
    """``|value|`` split into (units, minutes, seconds), rounded once at ``decimals`` of the
    seconds so that 59.999 s carries into the minutes instead of printing as 60.0."""
    scale = 10 ** decimals
    total = round(abs(value) * 3600 * scale)
    total, last = divmod(total, 60 * scale)
    first, mid = divmod(total, 60)
    return int(first), int(mid), last / scale


def _seconds(s: float, decimals: int) -> str:
    return f"{s:0{3 + decimals}.{decimals}f}"


def ra_hms(ra_deg: float) -> str:
    """Right ascension as ``08h51m18.48s`` (hours in [0, 24), seconds to 0.01 s)."""
    h, m, s = _parts((float(ra_deg) % 360.0) / 15.0, RA_DECIMALS)
    return f"{h % 24:02d}h{m:02d}m{_seconds(s, RA_DECIMALS)}s"


def dec_dms(dec_deg: float) -> str:
    """Declination as ``+11°46′50.7″`` (always signed, seconds to 0.1″; a value that rounds to
    zero is ``+00°00′00.0″``)."""
    d, m, s = _parts(float(dec_deg), DEC_DECIMALS)
    sign = "-" if dec_deg < 0 and (d or m or s) else "+"
    return f"{sign}{d:02d}°{m:02d}′{_seconds(s, DEC_DECIMALS)}″"


def radec_text(ra_deg: float, dec_deg: float) -> str:
    """A position in sexagesimal and decimal degrees:
    ``08h51m18.48s +11°46′50.7″ (132.82698°, +11.78075°)``."""
    return f"{ra_hms(ra_deg)} {dec_dms(dec_deg)} ({float(ra_deg) % 360.0:.5f}°, {float(dec_deg):+.5f}°)"


def plural(n: int, noun: str, plural_noun: str | None = None) -> str:
    """``1 pointing``, ``3 pointings`` (``plural_noun`` when it is not ``noun + 's'``)."""
    return f"{n} {noun if n == 1 else (plural_noun or noun + 's')}"


def priority_text(p: float) -> str:
    """A priority as the user wrote it: an integer value without a decimal point (``-5``)."""
    v = float(p)
    return str(int(v)) if math.isfinite(v) and v == int(v) else repr(v)
