"""Target positions at the observation date: proper motion, parallax and radial velocity
applied with astropy (``SkyCoord.apply_space_motion``, i.e. ERFA's ``pmsafe``: rigorous
space motion in the barycentric ICRS frame), vectorised over every target.

Conventions:

* Positions are ICRS RA/Dec in degrees at each target's catalogue epoch ``ref_epoch_yr``
  (a Julian year, TDB: Gaia DR3's ``ref_epoch`` is 2016.0). A target with proper motions and
  no epoch is at :data:`DEFAULT_REF_EPOCH_YR` (J2000.0), the epoch of VizieR's computed
  ``_RAJ2000`` columns and of most catalogues without one.
* ``pmra_mas_yr`` is mu_alpha* = mu_alpha cos(dec) (Gaia's ``pmra``, VizieR's ``pmRA``).
* A missing value (NaN) is "none": no proper motion (0), no parallax (a star at infinity:
  astropy's default distance), no radial velocity (0). A parallax that is not positive is
  none (Gaia lists negative parallaxes of distant stars).
* The observation date is an ISO date ``YYYY-MM-DD`` at 00:00 UTC, between
  :data:`FIRST_YEAR` and :data:`LAST_YEAR`.

Only targets with a motion (a non-zero proper motion or radial velocity) are moved; every
other target keeps its given position to the bit. The shift of each target is the angular
separation between its given and its propagated position.
"""

from __future__ import annotations

import datetime as dt
import warnings
from dataclasses import dataclass

import numpy as np

from models.errors import InputError

#: The catalogue epoch of a target with proper motions and no epoch (Julian year).
DEFAULT_REF_EPOCH_YR = 2000.0
#: Observation dates accepted: years FIRST_YEAR .. LAST_YEAR.
FIRST_YEAR, LAST_YEAR = 1900, 2100
#: Catalogue epochs accepted (Julian years): Hipparcos is 1991.25, Gaia 2016.0.
MIN_REF_EPOCH_YR, MAX_REF_EPOCH_YR = 1800.0, 2200.0
#: Days of a Julian year.
JULIAN_YEAR_DAYS = 365.25
#: The largest magnitude accepted of each motion field (mas/yr, mas, km/s).
MOTION_LIMITS = {"pmra_mas_yr": 1e6, "pmdec_mas_yr": 1e6, "parallax_mas": 1e4,
                 "radial_velocity_km_s": 1e5}
#: The motion fields of a target, in the order of :class:`Motions`.
MOTION_FIELDS = ("pmra_mas_yr", "pmdec_mas_yr", "parallax_mas", "radial_velocity_km_s",
                 "ref_epoch_yr")


@dataclass(frozen=True)
class Motions:
    """Space motion of n targets (arrays of length n; NaN = none, see the module doc)."""

    pmra_mas_yr: np.ndarray
    pmdec_mas_yr: np.ndarray
    parallax_mas: np.ndarray
    radial_velocity_km_s: np.ndarray
    ref_epoch_yr: np.ndarray

    @classmethod
    def of(cls, n: int, **columns: object) -> Motions:
        """Motions of ``n`` targets from columns given by name (a list with None for a
        missing value, or nothing: all missing)."""
        def column(name: str) -> np.ndarray:
            values = columns.get(name)
            if values is None:
                return np.full(n, np.nan)
            a = np.array([np.nan if v is None else v for v in values], float)  # type: ignore[attr-defined]
            if a.shape != (n,):
                raise InputError(name, f"{a.size} values for {n} targets")
            return a
        return cls(*(column(name) for name in MOTION_FIELDS))

    def moving(self) -> np.ndarray:
        """Targets with a non-zero proper motion or radial velocity."""
        pm = (np.nan_to_num(self.pmra_mas_yr) != 0) | (np.nan_to_num(self.pmdec_mas_yr) != 0)
        return pm | (np.nan_to_num(self.radial_velocity_km_s) != 0)

    def epochs_yr(self) -> np.ndarray:
        """Each target's catalogue epoch, :data:`DEFAULT_REF_EPOCH_YR` where none is given."""
        return np.where(np.isfinite(self.ref_epoch_yr), self.ref_epoch_yr, DEFAULT_REF_EPOCH_YR)


@dataclass(frozen=True)
class Propagated:
    """Positions at ``epoch_yr`` and what moved: ``shift_arcsec`` per target (0 for a target
    that does not move), ``moving`` (targets with a motion), ``default_epoch`` (moving
    targets given no epoch, put at J2000.0)."""

    ra_deg: np.ndarray
    dec_deg: np.ndarray
    epoch_yr: float
    shift_arcsec: np.ndarray
    moving: np.ndarray
    default_epoch: np.ndarray

    @property
    def n_moving(self) -> int:
        return int(self.moving.sum())

    @property
    def max_shift_arcsec(self) -> float:
        return float(self.shift_arcsec.max()) if self.shift_arcsec.size else 0.0


def parse_date(text: str, field: str = "obs_date") -> dt.date:
    """The ISO date ``YYYY-MM-DD`` ``text``; InputError naming ``field`` when it is no such
    date or lies outside years :data:`FIRST_YEAR` .. :data:`LAST_YEAR`."""
    s = str(text)
    try:
        if len(s) != 10:
            raise ValueError
        day = dt.date.fromisoformat(s)
    except ValueError:
        raise InputError(field, f"{s[:40]!r} is not a date YYYY-MM-DD (e.g. 2027-01-01)") from None
    if not FIRST_YEAR <= day.year <= LAST_YEAR:
        raise InputError(field, f"{s} is not between {FIRST_YEAR}-01-01 and {LAST_YEAR}-12-31")
    return day


def julian_year(day: dt.date) -> float:
    """The Julian epoch (TDB) of 00:00 UTC on ``day``."""
    from astropy.time import Time

    return float(Time(day.isoformat(), scale="utc").tdb.jyear)


def date_a_year_after(day: dt.date) -> dt.date:
    """``day`` one year later (28 February for 29 February)."""
    try:
        return day.replace(year=day.year + 1)
    except ValueError:
        return day.replace(year=day.year + 1, day=28)


def propagate(ra_deg: np.ndarray, dec_deg: np.ndarray, motions: Motions,
              epoch_yr: float) -> Propagated:
    """Every target's position at Julian epoch ``epoch_yr`` (module doc), vectorised: one
    astropy call per distinct catalogue epoch."""
    ra0, dec0 = np.asarray(ra_deg, float), np.asarray(dec_deg, float)
    ra, dec = ra0.copy(), dec0.copy()
    moving = motions.moving()
    shift = np.zeros(ra.size)
    epochs = motions.epochs_yr()
    for ref in np.unique(epochs[moving]):
        idx = np.flatnonzero(moving & (epochs == ref))
        ra[idx], dec[idx] = _apply(ra[idx], dec[idx], motions, idx, float(ref), epoch_yr)
        shift[idx] = _separation_arcsec(ra0[idx], dec0[idx], ra[idx], dec[idx])
    default = moving & ~np.isfinite(motions.ref_epoch_yr)
    return Propagated(ra, dec, float(epoch_yr), shift, moving, default)


def _apply(ra: np.ndarray, dec: np.ndarray, m: Motions, idx: np.ndarray, ref_yr: float,
           epoch_yr: float) -> tuple[np.ndarray, np.ndarray]:
    """``SkyCoord.apply_space_motion`` from ``ref_yr`` to ``epoch_yr`` of the targets ``idx``."""
    from astropy import units as u
    from astropy.coordinates import Distance, SkyCoord
    from astropy.time import Time

    plx = m.parallax_mas[idx]
    known = np.isfinite(plx) & (plx > 0)
    kwargs = {}
    if known.any():
        # no parallax: ERFA's own default for a star at infinity (pmsafe overrides the tiny one)
        kwargs["distance"] = Distance(parallax=np.where(known, plx, 1e-9) * u.mas)
    coord = SkyCoord(ra=ra * u.deg, dec=dec * u.deg, frame="icrs",
                     pm_ra_cosdec=np.nan_to_num(m.pmra_mas_yr[idx]) * u.mas / u.yr,
                     pm_dec=np.nan_to_num(m.pmdec_mas_yr[idx]) * u.mas / u.yr,
                     radial_velocity=np.nan_to_num(m.radial_velocity_km_s[idx]) * u.km / u.s,
                     obstime=Time(ref_yr, format="jyear", scale="tdb"), **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ERFA: "distance overridden" for stars at infinity
        moved = coord.apply_space_motion(new_obstime=Time(epoch_yr, format="jyear", scale="tdb"))
    return moved.ra.to_value(u.deg) % 360.0, moved.dec.to_value(u.deg)


def _separation_arcsec(ra1: np.ndarray, dec1: np.ndarray, ra2: np.ndarray,
                       dec2: np.ndarray) -> np.ndarray:
    from astropy.coordinates import angular_separation

    r = angular_separation(np.radians(ra1), np.radians(dec1), np.radians(ra2), np.radians(dec2))
    return np.degrees(np.asarray(r, float)) * 3600.0


@dataclass(frozen=True)
class EpochReport:
    """What the epoch step did, for the plan's answer: ``obs_date`` (None: no date given, the
    positions are as given), ``shift_date`` (the date the shifts are measured at: the
    observation date, or a year after today without one), the targets with a motion, the
    largest shift and the moving targets put at the default epoch."""

    obs_date: str | None
    shift_date: str
    targets_with_motion: int
    max_shift_arcsec: float
    default_epoch_targets: int

    def notices(self) -> list[str]:
        """Sentences for the astronomer."""
        n, shift = self.targets_with_motion, self.max_shift_arcsec
        out = []
        if self.obs_date is not None:
            out.append(f"Positions propagated to the observation date {self.obs_date}: "
                       f"{_targets(n)} moved, the largest by {shift:.3f} arcsec."
                       if n else f"Observation date {self.obs_date}: no target has a proper "
                       "motion; the positions are as given.")
        elif n:
            out.append(f"{_targets(n)} {'has' if n == 1 else 'have'} proper motions; the "
                       f"positions are used as given, at their catalogue epochs. By "
                       f"{self.shift_date} the largest shift is {shift:.3f} arcsec: give the "
                       "observation date (obs_date; --obs-date) to plan at it.")
        if self.default_epoch_targets:
            out.append(f"{_targets(self.default_epoch_targets)} with proper motions "
                       f"{'has' if self.default_epoch_targets == 1 else 'have'} no catalogue "
                       f"epoch; J2000.0 is assumed (give ref_epoch_yr, or a ref_epoch/Epoch "
                       "column).")
        return out


def _targets(n: int) -> str:
    return f"{n} target" if n == 1 else f"{n} targets"


def at_date(ra_deg: np.ndarray, dec_deg: np.ndarray, motions: Motions, obs_date: str | None,
            today: dt.date) -> tuple[np.ndarray, np.ndarray, EpochReport | None]:
    """The epoch policy of a plan: with ``obs_date`` every target is propagated to it; without
    one the positions stay as given and the report gives the shifts a year after ``today``.
    The report is None when there is neither a date nor a moving target."""
    day = None if obs_date is None else parse_date(obs_date)
    shift_day = day if day is not None else date_a_year_after(today)
    moved = propagate(np.asarray(ra_deg, float), np.asarray(dec_deg, float), motions,
                      julian_year(shift_day)) if motions.moving().any() or day else None
    if moved is None:
        return np.asarray(ra_deg, float), np.asarray(dec_deg, float), None
    report = EpochReport(obs_date=None if day is None else day.isoformat(),
                         shift_date=shift_day.isoformat(), targets_with_motion=moved.n_moving,
                         max_shift_arcsec=moved.max_shift_arcsec,
                         default_epoch_targets=int(moved.default_epoch.sum()))
    if day is None:
        return np.asarray(ra_deg, float), np.asarray(dec_deg, float), report
    return moved.ra_deg, moved.dec_deg, report
