"""The space-motion and sky-frame columns of a target table (:mod:`service.tables` reads the
positions, ids and priorities).

Space motion, found by UCD (a column's UCD equal to, or a refinement of, the one named: Gaia's
``pos.parallax.trig`` is a ``pos.parallax``) and then by name, case-insensitively
(:data:`MOTION_ALIASES`, :data:`MOTION_UCDS`):

* ``pmra_mas_yr`` (mu_alpha* = mu_alpha cos dec): Gaia ``pmra``, VizieR ``pmRA``;
* ``pmdec_mas_yr``: Gaia ``pmdec``, VizieR ``pmDE``;
* ``parallax_mas``: Gaia ``parallax``, VizieR ``Plx``;
* ``radial_velocity_km_s``: Gaia ``radial_velocity``, VizieR ``RV``;
* ``ref_epoch_yr``, the epoch of the positions (Julian year; ``J2016.0`` or ``2016``): Gaia
  ``ref_epoch``, VizieR ``Epoch``; or the table's meta ``ref_epoch`` / ``epoch``.

A column's unit, when the file gives one the field's converts to (``arcsec/yr``, ``deg``,
``m/s``), is applied; otherwise the values are in the field's unit. An empty cell (or NaN)
means "none" for that star (:mod:`models.epochs`). VizieR's computed positions (``_RAJ2000``,
``_RA_icrs``: a name starting with ``_``) are at epoch J2000.0, whatever the catalogue's own
``Epoch`` column says of its original positions.

Sky frame: a table without RA/Dec columns may give galactic (``_Glon``/``_Glat``,
``GLON``/``GLAT``, UCD ``pos.galactic.lon``/``lat``) or ecliptic (``_Elon``/``_Elat``,
``ELON``/``ELAT``, UCD ``pos.ecliptic.lon``/``lat``) longitude and latitude in degrees. They
are converted to ICRS with astropy: galactic is astropy's ``Galactic`` frame (IAU 1958,
defined from FK5 J2000); ecliptic is ``BarycentricTrueEcliptic`` with equinox J2000.0 (the
true ecliptic and equinox of J2000 seen from the barycentre: no aberration, no parallax, as
for catalogue positions).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.epochs import (
    DEFAULT_REF_EPOCH_YR,
    MAX_REF_EPOCH_YR,
    MIN_REF_EPOCH_YR,
    MOTION_FIELDS,
    MOTION_LIMITS,
)
from service.table_checks import TargetFileError, echo

MOTION_ALIASES: dict[str, tuple[str, ...]] = {
    "pmra_mas_yr": ("pmra_mas_yr", "pmra", "pm_ra", "pmra_cosdec", "pm_ra_cosdec", "pmalpha"),
    "pmdec_mas_yr": ("pmdec_mas_yr", "pmdec", "pmde", "pm_dec", "pmdelta"),
    "parallax_mas": ("parallax_mas", "parallax", "plx", "px"),
    "radial_velocity_km_s": ("radial_velocity_km_s", "radial_velocity", "rv", "hrv", "rvel"),
    "ref_epoch_yr": ("ref_epoch_yr", "ref_epoch", "epoch", "epoch_yr"),
}
MOTION_UCDS: dict[str, tuple[str, ...]] = {
    "pmra_mas_yr": ("pos.pm;pos.eq.ra",),
    "pmdec_mas_yr": ("pos.pm;pos.eq.dec",),
    "parallax_mas": ("pos.parallax",),
    "radial_velocity_km_s": ("spect.dopplerVeloc", "phys.veloc;pos.heliocentric"),
    "ref_epoch_yr": ("meta.ref;time.epoch", "time.epoch"),
}
#: The unit of each motion field (astropy's name), for columns that name theirs.
MOTION_UNITS = {"pmra_mas_yr": "mas / yr", "pmdec_mas_yr": "mas / yr", "parallax_mas": "mas",
                "radial_velocity_km_s": "km / s", "ref_epoch_yr": "yr"}
#: Table meta keys of the positions' epoch.
EPOCH_META = ("ref_epoch", "epoch", "ref_epoch_yr")


@dataclass(frozen=True)
class Frame:
    """A sky frame of longitude/latitude columns: its name, the astropy frame, the names and
    UCDs its columns are found by."""

    name: str
    lon_names: tuple[str, ...]
    lat_names: tuple[str, ...]
    lon_ucd: str
    lat_ucd: str


FRAMES = (
    Frame("galactic", ("_glon", "glon", "gal_lon", "l_gal"), ("_glat", "glat", "gal_lat", "b_gal"),
          "pos.galactic.lon", "pos.galactic.lat"),
    Frame("ecliptic", ("_elon", "elon", "ecl_lon", "elon_deg"), ("_elat", "elat", "ecl_lat",
                                                                  "elat_deg"),
          "pos.ecliptic.lon", "pos.ecliptic.lat"),
)


def _ucd(col: Any) -> str:
    return str(col.meta.get("ucd", "")).strip().lower()


def ucd_is(ucd: str, wanted: str) -> bool:
    """Whether ``ucd`` is ``wanted`` or a refinement of it (``pos.parallax.trig``,
    ``spect.dopplerVeloc.opt;em.opt.I``)."""
    u, w = ucd.strip().lower(), wanted.lower()
    return u == w or u.startswith((w + ".", w + ";"))


def wanted(name: str, ucd: str) -> bool:
    """Whether a column may be read for a motion or frame field (by name or UCD)."""
    low = name.lower()
    if any(low in names for names in MOTION_ALIASES.values()):
        return True
    if any(low in f.lon_names or low in f.lat_names for f in FRAMES):
        return True
    ucds = [u for us in MOTION_UCDS.values() for u in us]
    ucds += [u for f in FRAMES for u in (f.lon_ucd, f.lat_ucd)]
    return bool(ucd) and any(ucd_is(ucd, u) for u in ucds)


def find(table: Any, ucds: tuple[str, ...], names: tuple[str, ...]) -> str | None:
    """The one column with one of ``ucds`` (tried in order), else the first of ``names``."""
    for ucd in ucds:
        hits = [c for c in table.colnames if ucd_is(_ucd(table[c]), ucd)]
        if len(hits) == 1:
            return str(hits[0])
    lower = {n.lower(): n for n in table.colnames}
    return next((str(lower[a]) for a in names if a in lower), None)


def motion_columns(table: Any) -> dict[str, str | None]:
    """The column read for each motion field (None: none)."""
    return {f: find(table, MOTION_UCDS[f], MOTION_ALIASES[f]) for f in MOTION_FIELDS}


def frame_columns(table: Any) -> tuple[Frame, str, str] | None:
    """The first frame (galactic, then ecliptic) with both its columns in ``table``."""
    for frame in FRAMES:
        lon = find(table, (frame.lon_ucd,), frame.lon_names)
        lat = find(table, (frame.lat_ucd,), frame.lat_names)
        if lon is not None and lat is not None:
            return frame, lon, lat
    return None


def to_icrs(frame: Frame, lon_deg: np.ndarray, lat_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ICRS RA/Dec (deg) of longitudes/latitudes of ``frame`` (module doc), vectorised."""
    from astropy import units as u
    from astropy.coordinates import BarycentricTrueEcliptic, Galactic, SkyCoord

    lon, lat = np.asarray(lon_deg, float) * u.deg, np.asarray(lat_deg, float) * u.deg
    if frame.name == "galactic":
        c = SkyCoord(Galactic(l=lon, b=lat))
    else:
        c = SkyCoord(BarycentricTrueEcliptic(lon=lon, lat=lat, equinox="J2000"))
    icrs = c.icrs
    return icrs.ra.to_value(u.deg) % 360.0, icrs.dec.to_value(u.deg)


# ------------------------------------------------------------------ values


Cell = Callable[[int, str], str]  # (row index, column) -> "file: row r, line l, column 'c'"


def _factor(col: Any, field: str) -> float:
    """What multiplies the column's values into the field's unit (1 without a usable unit)."""
    from astropy import units as u

    unit = getattr(col, "unit", None)
    if unit is None:
        return 1.0
    try:
        return float(u.Unit(unit).to(u.Unit(MOTION_UNITS[field])))
    except (ValueError, TypeError, u.UnitsError):
        return 1.0


def _cell_value(raw: Any, field: str) -> float:
    """A text cell's number (NaN when blank); an epoch may be written ``J2016.0``."""
    text = (raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)).strip()
    if field == "ref_epoch_yr" and text[:1] in "Jj":
        text = text[1:]
    if not text or text.lower() in ("nan", "--", "null"):
        return math.nan
    return float(text)


def values(col: Any, field: str, cell: Cell) -> np.ndarray:
    """The column's values in the field's unit, NaN where a cell is empty; a cell that is no
    number or out of the field's range is a TargetFileError naming it (``cell``)."""
    n = len(col)
    mask = getattr(col, "mask", None)
    masked = (np.zeros(n, bool) if mask is None
              else np.asarray(mask, bool).reshape(n, -1).any(axis=1))
    if col.dtype.kind in "iuf":
        out = np.asarray(col, float).reshape(n)
    else:
        out = np.empty(n)
        for i, raw in enumerate(col):
            try:
                out[i] = math.nan if masked[i] else _cell_value(raw, field)
            except ValueError:
                text = raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)
                raise TargetFileError(f"{cell(i, col.name)}: {field} {echo(text.strip())} is not "
                                      "a number") from None
    out = np.where(masked, np.nan, out) * _factor(col, field)
    _check_range(out, field, col.name, cell)
    return out


def _check_range(v: np.ndarray, field: str, column: str, cell: Cell) -> None:
    lo, hi = ((MIN_REF_EPOCH_YR, MAX_REF_EPOCH_YR) if field == "ref_epoch_yr"
              else (-MOTION_LIMITS[field], MOTION_LIMITS[field]))
    bad = np.flatnonzero(np.isfinite(v) & ((v < lo) | (v > hi)) | np.isinf(v))
    if bad.size:
        i = int(bad[0])
        raise TargetFileError(f"{cell(i, column)}: {field} {v[i]:g} is not in [{lo:g}, {hi:g}]")


def meta_epoch(table: Any) -> float | None:
    """The positions' epoch a table's meta names (``ref_epoch`` / ``epoch``), or None."""
    meta = {str(k).lower(): v for k, v in getattr(table, "meta", {}).items()}
    for key in EPOCH_META:
        if key in meta:
            try:
                v = _cell_value(meta[key], "ref_epoch_yr")
            except ValueError:
                return None
            return v if MIN_REF_EPOCH_YR <= v <= MAX_REF_EPOCH_YR else None
    return None


def read_motions(table: Any, ra_column: str | None, cell: Cell,
                 ) -> tuple[dict[str, np.ndarray], dict[str, str | None], list[str]]:
    """Every motion field's values (NaN: none), the column read for each and notices. No
    motion column: empty dicts. The epoch of a row comes from VizieR's computed positions
    (J2000.0), the epoch column, the table's meta, in that order; a row with proper motions
    and none of them is left without one (J2000.0 by :mod:`models.epochs`)."""
    cols = motion_columns(table)
    if all(cols[f] is None for f in MOTION_FIELDS[:4]):
        return {}, {}, []
    n = len(table)
    out = {f: (np.full(n, np.nan) if cols[f] is None else values(table[cols[f]], f, cell))
           for f in MOTION_FIELDS}
    notices: list[str] = []
    if ra_column is not None and ra_column.startswith("_"):
        out["ref_epoch_yr"] = np.full(n, DEFAULT_REF_EPOCH_YR)
        cols["ref_epoch_yr"] = None
        notices.append(f"positions of VizieR's computed column {ra_column} are at epoch "
                       f"J{DEFAULT_REF_EPOCH_YR:.1f}")
    else:
        epoch = meta_epoch(table)
        if epoch is not None:
            out["ref_epoch_yr"] = np.where(np.isfinite(out["ref_epoch_yr"]), out["ref_epoch_yr"], epoch)
    return out, cols, notices
