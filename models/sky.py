"""Sky <-> focal plane: gnomonic (TAN) projection about a tangent point (thesis sec. 4.1.2).

Conventions (every function here):

* Sky angles in degrees (ICRS RA/Dec), focal-plane coordinates in mm.
* Standard coordinates (xi, eta) of thesis eqs. 4.1-4.2 are the TAN intermediate world
  coordinates: +xi toward East (increasing RA), +eta toward North, both at the tangent point.
* Plate scale p in arcsec/mm (thesis eq. 4.5): ``xi_arcsec = p * x_mm`` before rotation.
* Position angle PA (deg) rotates the instrument East of North: the focal-plane +y axis
  points to PA on the sky (PA = 0: +y North, +x East; PA = 90: +y East, +x South).
  ``xi = s (x cos PA + y sin PA)``, ``eta = s (-x sin PA + y cos PA)`` with s = p/3600 deg/mm.
* The projection is radial: a target at angular separation ``sep`` from the tangent point lies
  at focal radius ``tan(sep) * (180/pi) * 3600 / p`` mm, whatever the PA.

The projection itself is astropy's WCS (wcslib), vectorised over arrays; RA wrap at 0/360 and
tangent points at or near the poles are handled by the spherical rotation inside wcslib.
Targets 90 deg or more from the tangent point have no gnomonic image and raise InputError.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from astropy.coordinates import angular_separation
from astropy.wcs import WCS

from models.errors import InputError
from models.types import MAX_PRIORITY

_ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0


def _tan_wcs(
    tangent_ra_deg: float, tangent_dec_deg: float, plate_scale_arcsec_per_mm: float,
    position_angle_deg: float,
) -> WCS:
    """A 2-D TAN WCS whose 'pixels' are focal-plane mm, reference pixel (0, 0) at the tangent."""
    _check_tangent(tangent_ra_deg, tangent_dec_deg, plate_scale_arcsec_per_mm, position_angle_deg)
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [float(tangent_ra_deg) % 360.0, float(tangent_dec_deg)]
    w.wcs.crpix = [0.0, 0.0]  # used with origin=1, so pixel (0, 0) is the tangent point
    s = plate_scale_arcsec_per_mm / 3600.0
    c, n = math.cos(math.radians(position_angle_deg)), math.sin(math.radians(position_angle_deg))
    w.wcs.cd = [[s * c, s * n], [-s * n, s * c]]
    # LONPOLE 180 is the standard zenithal orientation (+eta north); fixing it explicitly
    # keeps the orientation defined when the tangent point is exactly a pole.
    w.wcs.lonpole = 180.0
    w.wcs.set()
    return w


def _check_tangent(ra: float, dec: float, scale: float, pa: float) -> None:
    for name, v in (("tangent_ra_deg", ra), ("tangent_dec_deg", dec),
                    ("plate_scale_arcsec_per_mm", scale), ("position_angle_deg", pa)):
        if not math.isfinite(float(v)):
            raise InputError(name, f"must be finite, got {v!r}")
    if not -90.0 <= dec <= 90.0:
        raise InputError("tangent_dec_deg", f"must be in [-90, 90], got {dec!r}")
    if scale <= 0:
        raise InputError("plate_scale_arcsec_per_mm", f"must be > 0, got {scale!r}")


def _as_arrays(ra_deg, dec_deg, ra_name: str = "ra_deg", dec_name: str = "dec_deg"):
    ra = np.asarray(ra_deg, dtype=float)
    dec = np.asarray(dec_deg, dtype=float)
    if ra.shape != dec.shape:
        raise InputError(dec_name, f"shape {dec.shape} differs from {ra_name} shape {ra.shape}")
    bad = np.flatnonzero(~np.isfinite(ra.ravel()))
    if bad.size:
        raise InputError(f"{ra_name}[{bad[0]}]", "must be finite")
    bad = np.flatnonzero(~(np.abs(dec.ravel()) <= 90.0))
    if bad.size:
        raise InputError(f"{dec_name}[{bad[0]}]", "must be a finite number in [-90, 90]")
    return ra, dec


def angular_separation_deg(ra1_deg, dec1_deg, ra2_deg, dec2_deg) -> np.ndarray:
    """Great-circle separation in degrees (astropy's Vincenty formula), broadcast over arrays."""
    return np.degrees(angular_separation(
        np.radians(ra1_deg), np.radians(dec1_deg), np.radians(ra2_deg), np.radians(dec2_deg)))


def tangent_radius_mm(
    ra_deg, dec_deg, tangent_ra_deg, tangent_dec_deg, plate_scale_arcsec_per_mm: float,
) -> np.ndarray:
    """Focal radius (mm) of targets on the tangent plane about (tangent_ra, tangent_dec).

    Broadcasts over per-target tangent points, so one call checks every member of every
    pointing on *its own* pointing's plane. TAN is radial: radius = tan(sep) / plate scale.
    Separations >= 90 deg give +inf (no gnomonic image).
    """
    sep = np.radians(angular_separation_deg(ra_deg, dec_deg, tangent_ra_deg, tangent_dec_deg))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(sep < 0.5 * math.pi, np.tan(sep), np.inf)
    return r * _ARCSEC_PER_RAD / plate_scale_arcsec_per_mm


def sky_to_focal_mm(
    ra_deg, dec_deg, tangent_ra_deg: float, tangent_dec_deg: float,
    plate_scale_arcsec_per_mm: float, position_angle_deg: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """RA/Dec (deg) -> focal-plane (x_mm, y_mm) through TAN about the tangent point.

    Vectorised over array inputs (output has their shape). See the module docstring for the
    axis and position-angle conventions. Raises InputError for non-finite or out-of-range
    coordinates and for targets >= 90 deg from the tangent point.
    """
    ra, dec = _as_arrays(ra_deg, dec_deg)
    w = _tan_wcs(tangent_ra_deg, tangent_dec_deg, plate_scale_arcsec_per_mm, position_angle_deg)
    sep = angular_separation_deg(ra, dec, tangent_ra_deg, tangent_dec_deg)
    far = np.flatnonzero(~(sep.ravel() < 90.0))
    if far.size:
        raise InputError(f"dec_deg[{far[0]}]",
                         "target is >= 90 deg from the tangent point (no gnomonic image)")
    x, y = w.wcs_world2pix(ra.ravel(), dec.ravel(), 1)
    return x.reshape(ra.shape), y.reshape(ra.shape)


def focal_mm_to_sky(
    x_mm, y_mm, tangent_ra_deg: float, tangent_dec_deg: float,
    plate_scale_arcsec_per_mm: float, position_angle_deg: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Focal-plane (x_mm, y_mm) -> (ra_deg in [0, 360), dec_deg); inverse of sky_to_focal_mm."""
    x = np.asarray(x_mm, dtype=float)
    y = np.asarray(y_mm, dtype=float)
    if x.shape != y.shape:
        raise InputError("y_mm", f"shape {y.shape} differs from x_mm shape {x.shape}")
    for name, a in (("x_mm", x), ("y_mm", y)):
        bad = np.flatnonzero(~np.isfinite(a.ravel()))
        if bad.size:
            raise InputError(f"{name}[{bad[0]}]", "must be finite")
    w = _tan_wcs(tangent_ra_deg, tangent_dec_deg, plate_scale_arcsec_per_mm, position_angle_deg)
    ra, dec = w.wcs_pix2world(x.ravel(), y.ravel(), 1)
    ra = np.mod(ra, 360.0)
    ra[ra >= 360.0] = 0.0  # mod of a tiny negative number rounds to exactly 360.0
    return ra.reshape(x.shape), dec.reshape(x.shape)


def spherical_centroid_deg(ra_deg, dec_deg) -> tuple[float, float]:
    """Centre of a target cloud: direction of the mean unit vector (thesis sec. 4.1.2.1 takes
    the mean; on the sphere this is well defined across RA = 0/360 and at the poles)."""
    ra, dec = np.radians(np.asarray(ra_deg, float)), np.radians(np.asarray(dec_deg, float))
    v = np.array([np.sum(np.cos(dec) * np.cos(ra)), np.sum(np.cos(dec) * np.sin(ra)),
                  np.sum(np.sin(dec))])
    norm = float(np.linalg.norm(v))
    if norm < 1e-12 * max(ra.size, 1):
        raise InputError("targets", "targets are spread over the whole sphere (no centre)")
    v /= norm
    return float(np.degrees(np.arctan2(v[1], v[0])) % 360.0), float(np.degrees(np.arcsin(
        np.clip(v[2], -1.0, 1.0))))


def validate_sky_targets(
    ids: Sequence, ra_deg: Sequence[float], dec_deg: Sequence[float], priority: Sequence,
) -> None:
    """Check a target list; raise InputError naming the first bad field ("targets[i].dec_deg").

    Rules: at least one target; equal lengths; ids unique; RA finite in [0, 360); Dec finite
    in [-90, 90]; priority an integer (not bool/float) in 1 .. 2**32 - 1.
    """
    n = len(ids)
    if n == 0:
        raise InputError("targets", "the target list is empty")
    for name, seq in (("ra_deg", ra_deg), ("dec_deg", dec_deg), ("priority", priority)):
        if len(seq) != n:
            raise InputError(f"targets.{name}", f"has {len(seq)} entries for {n} ids")
    seen: dict = {}
    for i, tid in enumerate(ids):
        if tid in seen:
            raise InputError(f"targets[{i}].id", f"duplicate id {tid!r} (also targets[{seen[tid]}])")
        seen[tid] = i
    ra = np.asarray(ra_deg, dtype=float)
    dec = np.asarray(dec_deg, dtype=float)
    bad = np.flatnonzero(~((ra >= 0.0) & (ra < 360.0)))  # NaN/inf fail both comparisons
    if bad.size:
        i = int(bad[0])
        raise InputError(f"targets[{i}].ra_deg", f"must be finite in [0, 360), got {ra[i]!r}")
    bad = np.flatnonzero(~((dec >= -90.0) & (dec <= 90.0)))
    if bad.size:
        i = int(bad[0])
        raise InputError(f"targets[{i}].dec_deg", f"must be finite in [-90, 90], got {dec[i]!r}")
    for i, p in enumerate(priority):
        if isinstance(p, bool | np.bool_) or not isinstance(p, int | np.integer):
            raise InputError(f"targets[{i}].priority", f"must be an integer, got {p!r}")
        if not 1 <= int(p) <= MAX_PRIORITY:
            raise InputError(f"targets[{i}].priority", f"must be in 1..{MAX_PRIORITY}, got {p!r}")
