"""Sky positions for the spare arms of a pointing's configurations (thesis 5.3.1.2, padding).

After the science targets of a configuration are allocated, an arm without a target rests
somewhere: the thesis pads it onto "blank sky" (Algorithm 5). In the near infrared that rest
is worth an exposure of its own, the sky spectrum the science spectra are corrected with, if
its probe field holds no target light. So every spare arm of a configuration is placed, in
this order:

1. on one of the astronomer's sky positions (``sky_positions``, projected into the pointing's
   focal plane), nearest the arm's previous position first;
2. else on blank sky this module picks: a point of a grid over the FOV at least
   ``radius_mm`` from every target of the programme (every pointing's targets, projected into
   this pointing, not only its members);
3. else at park (or, when park does not fit either, where the allocator rested it).

A placement keeps the buffer to every other arm of the configuration and the park move limit,
so the configuration stays collision-free; the motion planner moves a sky arm to park when
its leg cannot be planned (``planner.sequence``: sky rests are domain kind ``"blank"``), so a
sky position never costs a failed leg.

Default radius: the thesis' padding asks only that a blank-sky rest take no target. A probe's
field is 3.7 x 1.2 arcsec (thesis table 2.1, half-diagonal 1.94 arcsec) and the slicer is
designed for seeing of 1.2 arcsec or better (thesis 2.1); a target's light is negligible
beyond about twice that FWHM (2.4 arcsec). Their sum, 4.3 arcsec, rounded up gives
:data:`DEFAULT_SKY_RADIUS_ARCSEC` = 6 arcsec = 5 mm at the plate scale of 1.2 arcsec/mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from models import clock
from models.collision import body_segments_mm, clearance_mm
from models.incompatibility import within_park_move_limit
from models.instrument import Instrument
from models.kinematics import direct_move_time_s, inverse_fov, tip_fov
from models.sky import angular_separation_deg, focal_mm_to_sky, sky_to_focal_mm, tangent_radius_mm
from models.types import ArmAssignment, Configuration

__all__ = ["DEFAULT_SKY_RADIUS_ARCSEC", "MAX_SKY_RADIUS_ARCSEC", "SkyArm", "SkyField", "SkyRequest",
           "arm_sky", "place_sky", "sky_field", "sky_request", "usable_sky_positions"]

#: default least distance of a sky position from every target (arcsec); see the module docstring
DEFAULT_SKY_RADIUS_ARCSEC = 6.0
#: the largest radius accepted (arcsec): the FOV's diameter (250 mm at 1.2 arcsec/mm)
MAX_SKY_RADIUS_ARCSEC = 300.0
#: grid step of the blank-sky candidates (mm): finer than a tip body (10 mm radius)
GRID_STEP_MM = 2.5
#: targets and sky positions farther than this from a pointing (deg) play no part in its sky
#: (a FOV of 5 arcmin and a radius of at most 300 arcsec lie well within)
NEAR_DEG = 1.0
#: margin kept inside the FOV edge by a sky tip (mm)
FOV_MARGIN_MM = 0.5
#: candidates checked for collisions at once (in order of move time): the first chunk is
#: small (the nearest rest usually fits), the later ones ``CHUNK`` each
FIRST_CHUNK = 8
CHUNK = 64
#: clearance margin over the buffer (mm): a sky rest never sits exactly at the buffer
CLEAR_MM = 0.01


@dataclass(frozen=True)
class SkyField:
    """One pointing's sky, in its focal plane: the frame (tangent point, PA, plate scale),
    the radius (mm), every programme target near the pointing (``avoid_xy_mm``, (m, 2)) and
    the astronomer's usable sky positions inside its FOV (``sky_xy_mm``, (n, 2))."""

    ra_deg: float
    dec_deg: float
    position_angle_deg: float
    plate_scale_arcsec_per_mm: float
    radius_mm: float
    avoid_xy_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    sky_xy_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)

    def clear(self, xy_mm: np.ndarray) -> np.ndarray:
        """Which points (k, 2) lie at least ``radius_mm`` from every target to avoid."""
        xy = np.asarray(xy_mm, float).reshape(-1, 2)
        if not len(self.avoid_xy_mm) or not len(xy):
            return np.ones(len(xy), bool)
        d, _ = cKDTree(self.avoid_xy_mm).query(xy)
        return d >= self.radius_mm - 1e-9


@dataclass(frozen=True)
class SkyArm:
    """An idle arm's rest as reported: ``kind`` "sky" (its tip at least the radius from every
    target, inside the FOV; ``ra_deg``/``dec_deg`` where it points) or "blank" (a rest that
    is not clear sky)."""

    kind: str
    ra_deg: float | None = None
    dec_deg: float | None = None


def _unit(ra_deg: np.ndarray, dec_deg: np.ndarray) -> np.ndarray:
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    return np.column_stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])


def usable_sky_positions(sky_ra_deg: Sequence[float], sky_dec_deg: Sequence[float],
                         target_ra_deg: Sequence[float], target_dec_deg: Sequence[float],
                         target_ids: Sequence[str], radius_arcsec: float,
                         ) -> tuple[np.ndarray, list[str]]:
    """The indices of the sky positions at least ``radius_arcsec`` from every target (on the
    sphere), and one notice per position dropped, naming its nearest target."""
    n = len(sky_ra_deg)
    if not n:
        return np.zeros(0, int), []
    if not len(target_ra_deg):
        return np.arange(n), []
    tree = cKDTree(_unit(np.asarray(target_ra_deg, float), np.asarray(target_dec_deg, float)))
    chord, nearest = tree.query(_unit(np.asarray(sky_ra_deg, float), np.asarray(sky_dec_deg, float)))
    sep_arcsec = np.degrees(2.0 * np.arcsin(np.clip(chord / 2.0, 0.0, 1.0))) * 3600.0
    keep = sep_arcsec >= radius_arcsec
    notices = [f"sky_positions[{i}] is {sep_arcsec[i]:.2f} arcsec from target {target_ids[nearest[i]]}, "
               f"closer than sky_radius_arcsec ({radius_arcsec:g}): not used"
               for i in np.flatnonzero(~keep)]
    return np.flatnonzero(keep), notices


@dataclass(frozen=True)
class SkyRequest:
    """A plan's sky, before any pointing: the radius (arcsec), the programme's targets
    (RA/Dec, deg) and the astronomer's usable sky positions (RA/Dec, deg), with the notices
    of the positions dropped for lying closer than the radius to a target."""

    radius_arcsec: float = DEFAULT_SKY_RADIUS_ARCSEC
    target_ra_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    target_dec_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    sky_ra_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    sky_dec_deg: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    given: int = 0
    notices: tuple[str, ...] = ()

    def near(self, ra_deg: float, dec_deg: float, within_deg: float = NEAR_DEG) -> SkyRequest:
        """The part of this sky within ``within_deg`` of (``ra_deg``, ``dec_deg``): what one
        pointing needs (small enough to ship to a worker with its task)."""
        t = angular_separation_deg(self.target_ra_deg, self.target_dec_deg, ra_deg, dec_deg) <= within_deg
        k = angular_separation_deg(self.sky_ra_deg, self.sky_dec_deg, ra_deg, dec_deg) <= within_deg
        return replace(self, target_ra_deg=self.target_ra_deg[t], target_dec_deg=self.target_dec_deg[t],
                       sky_ra_deg=self.sky_ra_deg[k], sky_dec_deg=self.sky_dec_deg[k])

    def field(self, inst: Instrument, ra_deg: float, dec_deg: float, position_angle_deg: float) -> SkyField:
        """The :class:`SkyField` of a pointing (:func:`sky_field`)."""
        return sky_field(inst, ra_deg, dec_deg, position_angle_deg, self.target_ra_deg, self.target_dec_deg,
                         self.sky_ra_deg, self.sky_dec_deg, self.radius_arcsec)


def sky_request(target_ids: Sequence[str], target_ra_deg: Sequence[float], target_dec_deg: Sequence[float],
                sky_ra_deg: Sequence[float] = (), sky_dec_deg: Sequence[float] = (),
                radius_arcsec: float = DEFAULT_SKY_RADIUS_ARCSEC) -> SkyRequest:
    """A plan's :class:`SkyRequest`: the sky positions closer than ``radius_arcsec`` to a
    target are dropped, each with a notice (:func:`usable_sky_positions`)."""
    tra, tdec = np.asarray(target_ra_deg, float), np.asarray(target_dec_deg, float)
    sra, sdec = np.asarray(sky_ra_deg, float), np.asarray(sky_dec_deg, float)
    keep, notices = usable_sky_positions(sra, sdec, tra, tdec, target_ids, radius_arcsec)
    return SkyRequest(float(radius_arcsec), tra, tdec, sra[keep], sdec[keep], len(sra), tuple(notices))


def sky_field(inst: Instrument, ra_deg: float, dec_deg: float, position_angle_deg: float,
              target_ra_deg: Sequence[float], target_dec_deg: Sequence[float],
              sky_ra_deg: Sequence[float], sky_dec_deg: Sequence[float],
              radius_arcsec: float = DEFAULT_SKY_RADIUS_ARCSEC) -> SkyField:
    """The :class:`SkyField` of a pointing at (``ra_deg``, ``dec_deg``, ``position_angle_deg``):
    the programme's targets within the FOV radius plus the sky radius of its centre, and the
    (already usable, :func:`usable_sky_positions`) sky positions inside its FOV, projected."""
    scale = inst.plate_scale_arcsec_per_mm
    radius_mm = float(radius_arcsec) / scale
    avoid = _near_projected(ra_deg, dec_deg, position_angle_deg, scale, target_ra_deg, target_dec_deg,
                            inst.fov_radius_mm + radius_mm + 1.0)
    sky = _near_projected(ra_deg, dec_deg, position_angle_deg, scale, sky_ra_deg, sky_dec_deg,
                          inst.fov_radius_mm - FOV_MARGIN_MM)
    return SkyField(float(ra_deg), float(dec_deg), float(position_angle_deg), scale, radius_mm, avoid, sky)


def _near_projected(ra_deg: float, dec_deg: float, pa_deg: float, scale: float,
                    ras: Sequence[float], decs: Sequence[float], within_mm: float) -> np.ndarray:
    """The points (RA/Dec) whose gnomonic image about the pointing lies within ``within_mm``
    of its centre, projected to (k, 2) mm."""
    ra, dec = np.asarray(ras, float), np.asarray(decs, float)
    if not len(ra):
        return np.zeros((0, 2))
    near = tangent_radius_mm(ra, dec, ra_deg, dec_deg, scale) <= within_mm
    if not near.any():
        return np.zeros((0, 2))
    x, y = sky_to_focal_mm(ra[near], dec[near], ra_deg, dec_deg, scale, pa_deg)
    return np.column_stack([np.ravel(x), np.ravel(y)])


def _blank_grid(inst: Instrument, sky: SkyField) -> np.ndarray:
    """The blank-sky points (k, 2): a square grid over the FOV, kept where clear of targets."""
    r = inst.fov_radius_mm - FOV_MARGIN_MM
    g = np.arange(-r, r + 1e-9, GRID_STEP_MM)
    xx, yy = np.meshgrid(g, g)
    pts = np.column_stack([xx.ravel(), yy.ravel()])
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= r]
    return pts[sky.clear(pts)]


@dataclass(frozen=True)
class _Candidates:
    """One arm's sky rests: joint angles (k, 2) and whether each is an astronomer's position."""

    q: np.ndarray
    given: np.ndarray


def _arm_candidates(inst: Instrument, arm: int, points: np.ndarray, given: np.ndarray,
                    park_move_limit_s: float | None) -> _Candidates:
    """Every IK solution of ``arm`` on ``points`` (k, 2) within the park move limit."""
    if not len(points):
        return _Candidates(np.zeros((0, 2)), np.zeros(0, bool))
    ik = inverse_fov(inst, arm, points[:, 0], points[:, 1])
    rows, cols = np.nonzero(ik.valid)
    q = np.column_stack([ik.theta1_rad[rows, cols], ik.theta2_rad[rows, cols]])
    ok = within_park_move_limit(inst, arm, q, park_move_limit_s)
    return _Candidates(q[ok], given[rows][ok])


def _fitting(inst: Instrument, arm: int, cand: np.ndarray, q: np.ndarray, buffer_mm: float) -> int | None:
    """The first candidate (in the given order) of ``arm`` keeping the buffer to every other arm
    (the bodies of the other arms computed once, a chunk of candidates against all of them at
    once)."""
    others = np.array([j for j in range(len(q)) if j != arm], int)
    theirs = tuple(x[None] for x in body_segments_mm(inst, others, q[others, 0], q[others, 1]))
    for start, stop in _chunks(len(cand)):
        c = cand[start:stop]
        mine = tuple(x[:, None] for x in body_segments_mm(inst, arm, c[:, 0], c[:, 1]))
        ok = np.all(clearance_mm(mine, theirs) >= buffer_mm + CLEAR_MM, axis=1)
        hit = np.flatnonzero(ok)
        if len(hit):
            return start + int(hit[0])
    return None


def _chunks(n: int) -> list[tuple[int, int]]:
    """The candidates' chunks: ``FIRST_CHUNK``, then ``CHUNK`` at a time, up to ``n``."""
    edges = [0, *range(min(FIRST_CHUNK, n), n, CHUNK), n]
    return [(a, b) for a, b in zip(edges, edges[1:], strict=False) if b > a]


def place_sky(inst: Instrument, configs: Sequence[Configuration], sky: SkyField,
              park_move_limit_s: float | None = None,
              buffer_mm: float | None = None) -> tuple[Configuration, ...]:
    """``configs`` with every spare arm (kind "park" or "blank", enabled) on sky where one
    fits: the astronomer's positions first, then blank sky, each by the shortest move from
    the arm's place in the previous configuration (park before c1); else at park where park
    fits; else left where the allocator rested it. Targets and disabled arms never move.
    Each configuration's ``stats["sky_arms"]`` counts its arms on sky."""
    buffer_mm = inst.collision_buffer_mm if buffer_mm is None else float(buffer_mm)
    clock.work("sky_arms", sum(a.kind in ("park", "blank") for c in configs for a in c.assignments))
    points = np.vstack([sky.sky_xy_mm.reshape(-1, 2), _blank_grid(inst, sky)])
    given = np.r_[np.ones(len(sky.sky_xy_mm), bool), np.zeros(len(points) - len(sky.sky_xy_mm), bool)]
    cands = {k: _arm_candidates(inst, k, points, given, park_move_limit_s) for k in inst.enabled_arms}
    prev = np.asarray(inst.park_configuration, float)
    out = []
    for c in configs:
        placed = _place_one(inst, c, cands, prev, buffer_mm)
        out.append(placed)
        prev = placed.q
    return tuple(out)


def _place_one(inst: Instrument, c: Configuration, cands: dict[int, _Candidates], prev: np.ndarray,
               buffer_mm: float) -> Configuration:
    """One configuration's spare arms on sky (see :func:`place_sky`)."""
    asg = list(c.assignments)
    q = c.q
    n_sky = 0
    for k, a in enumerate(asg):
        if a.kind not in ("park", "blank") or k not in cands or not len(cands[k].q):
            continue
        cd = cands[k]
        v1 = inst.arm_array("joint1_speed_rad_s")[k]
        v2 = inst.arm_array("joint2_speed_rad_s")[k]
        order = np.lexsort((direct_move_time_s(prev[k], cd.q, v1, v2), ~cd.given))
        i = _fitting(inst, k, cd.q[order], q, buffer_mm)
        if i is not None:
            t1, t2 = (float(v) for v in cd.q[order[i]])
            asg[k] = _rest(inst, k, "blank", t1, t2)
            q[k] = (t1, t2)
            n_sky += 1
        elif a.kind == "blank":
            park = inst.park_configuration[k]
            if _fitting(inst, k, np.asarray(park, float).reshape(1, 2), q, buffer_mm) is not None:
                asg[k] = _rest(inst, k, "park", float(park[0]), float(park[1]))
                q[k] = park
    return replace(c, assignments=tuple(asg), stats={**c.stats, "sky_arms": n_sky})


def _rest(inst: Instrument, arm: int, kind: str, t1: float, t2: float) -> ArmAssignment:
    x, y = tip_fov(inst, arm, t1, t2)
    return ArmAssignment(arm, kind, t1, t2, float(x), float(y))  # type: ignore[arg-type]


def arm_sky(inst: Instrument, a: ArmAssignment, sky: SkyField | None) -> SkyArm | None:
    """How an idle arm's rest is reported: None for an arm on a target, at park or disabled;
    "sky" with the RA/Dec its tip points at when the rest is inside the FOV and clear of every
    target by the radius; "blank" otherwise (and for every rest when ``sky`` is None)."""
    if a.kind != "blank":
        return None
    if sky is None:
        return SkyArm("blank")
    xy = np.array([[a.x_mm, a.y_mm]])
    inside = math.hypot(a.x_mm, a.y_mm) <= inst.fov_radius_mm
    if not (inside and sky.clear(xy)[0]):
        return SkyArm("blank")
    ra, dec = focal_mm_to_sky(xy[:, 0], xy[:, 1], sky.ra_deg, sky.dec_deg,
                              sky.plate_scale_arcsec_per_mm, sky.position_angle_deg)
    return SkyArm("sky", float(ra[0]), float(dec[0]))
