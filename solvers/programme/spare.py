"""Spare arms: whether a target fits into an exposure as it is, on one of its idle arms.

An exposure (a configuration of the arms) takes one more target when an idle arm (at park,
on blank sky or on a sky position, not out of service) reaches it within the park move limit
(every IK branch tried, :func:`models.incompatibility.build_assignments`, which also keeps
the zone of avoidance out) and, there, clears every other arm as it stands by the collision
buffer (the capsule clearance of :mod:`models.collision`, the same test the incompatibility
structure makes). Nothing else of the exposure changes, so the answer is exact for the
exposure as planned.

:func:`spare_arm_for` is the test; :func:`only_here` explains a plan's exposures that observe
few targets (issue 38: such an exposure is wanted only for targets that no other exposure can
observe).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.collision import body_segments_mm, segment_distance_mm
from models.incompatibility import build_assignments
from models.instrument import Instrument
from models.sky import sky_to_focal_mm, tangent_radius_mm

__all__ = ["FEW_TARGETS", "IDLE_KINDS", "NOWHERE_ELSE", "NO_SPARE_ARM", "OUTSIDE_OTHER_FIELDS", "TAKERS_OBSERVE_FEWER",
           "Bodies", "Exposure", "bodies_of", "explained", "only_here", "placements",
           "spare_arm_for", "takers"]

#: An exposure observing at most this many targets is one the plan explains
FEW_TARGETS = 2
#: why a target of such an exposure can be observed in no other exposure of the plan
OUTSIDE_OTHER_FIELDS = "outside_other_fields"
NO_SPARE_ARM = "no_spare_arm"
#: why a target of such an exposure (observing more than one) stays although another exposure
#: could take it: every exposure that can observes fewer than FEW_TARGETS (moving it there
#: leaves as many exposures observing few)
TAKERS_OBSERVE_FEWER = "takers_observe_fewer"
#: the reasons that no other exposure can observe a target at all
NOWHERE_ELSE = frozenset({OUTSIDE_OTHER_FIELDS, NO_SPARE_ARM})
#: the assignment kinds of an idle arm (at park, on blank sky, on a sky position); an arm out of
#: service ("fixed") or observing a target is not idle
IDLE_KINDS = frozenset({"park", "blank", "sky"})


@dataclass(frozen=True)
class Exposure:
    """One exposure of a plan: its pointing (sky centre, position angle, deg), every arm's joint
    angles ``q`` (n_arms, 2), which arms are ``idle`` (free to take a target) and the targets
    it observes (indices into the programme)."""

    ra_deg: float
    dec_deg: float
    position_angle_deg: float
    q: np.ndarray
    idle: np.ndarray
    targets: tuple[int, ...]


def spare_arm_for(inst: Instrument, q: np.ndarray, idle: np.ndarray, x_mm: float, y_mm: float,
                  park_move_limit_s: float | None, allowed_arms: int | None = None,
                  ) -> tuple[int, float, float] | None:
    """An idle arm of the configuration ``q`` that can observe the FOV point (x_mm, y_mm) with
    the other arms as they are: (arm, theta1_rad, theta2_rad), the lowest arm and branch first;
    None when none can. ``allowed_arms``: a bit mask of the arms the target may use (a lock)."""
    for k, pose, ok in _options(inst, np.asarray(q, float)[None], np.asarray(idle, bool)[None], x_mm, y_mm,
                                park_move_limit_s, allowed_arms):
        if ok[0]:
            return k, float(pose[0]), float(pose[1])
    return None


def placements(inst: Instrument, q: np.ndarray, idle: np.ndarray, x_mm: float, y_mm: float,
               park_move_limit_s: float | None, allowed_arms: int | None = None,
               ) -> tuple[np.ndarray, np.ndarray]:
    """For each of E configurations of one pointing (``q`` (E, n_arms, 2), ``idle``
    (E, n_arms)), the idle arm that takes the FOV point as :func:`spare_arm_for` chooses it
    (the lowest arm and branch first) and its pose: ``arm`` (E,), -1 where none can, and
    ``pose`` (E, 2) joint angles (rad)."""
    e = len(q)
    arm, pose = np.full(e, -1, np.int64), np.zeros((e, 2))
    for k, kpose, ok in _options(inst, np.asarray(q, float), np.asarray(idle, bool), x_mm, y_mm,
                                 park_move_limit_s, allowed_arms):
        new = ok & (arm < 0)
        arm[new], pose[new] = k, kpose
        if (arm >= 0).all():
            break
    return arm, pose


def takers(inst: Instrument, q: np.ndarray, idle: np.ndarray, x_mm: float, y_mm: float,
           park_move_limit_s: float | None, bodies: Bodies | None = None) -> np.ndarray:
    """(E,) which of E configurations of one pointing (``q`` (E, n_arms, 2), ``idle``
    (E, n_arms)) can take the FOV point on an idle arm (:func:`spare_arm_for`, all at once);
    ``bodies``: those of ``q`` when the caller has them (:func:`bodies_of`)."""
    out = np.zeros(len(q), bool)
    for _, _, ok in _options(inst, q, idle, x_mm, y_mm, park_move_limit_s, None, bodies):
        out |= ok
    return out


def _options(inst: Instrument, q: np.ndarray, idle: np.ndarray, x_mm: float, y_mm: float,
             park_move_limit_s: float | None, allowed_arms: int | None, bodies: Bodies | None = None):
    """Per (arm, IK branch) reaching the point within the park move limit: the arm, its pose
    and (E,) whether each configuration has that arm idle and clear of its other arms there.
    ``bodies``: those of ``q`` when the caller has them (:func:`bodies_of`)."""
    reach = build_assignments(inst, np.array([x_mm]), np.array([y_mm]), park_move_limit_s=park_move_limit_s,
                              include_park=False).assignments
    options = np.flatnonzero(reach.target == 0)
    if allowed_arms is not None:
        options = options[((allowed_arms >> reach.arm[options].astype(np.int64)) & 1).astype(bool)]
    options = options[idle[:, reach.arm[options]].any(axis=0)] if len(q) else options[:0]
    if options.size == 0:
        return
    poses = np.column_stack([reach.theta1_rad[options], reach.theta2_rad[options]])
    arms = reach.arm[options].astype(np.int64)
    own = Bodies.of_segments(*body_segments_mm(inst, arms, poses[:, 0], poses[:, 1]))
    clear = _clear(inst, arms, own, bodies_of(inst, q) if bodies is None else bodies)
    for o, k in enumerate(arms):
        yield int(k), poses[o], idle[:, k] & clear[o]


@dataclass(frozen=True)
class Bodies:
    """The capsules of every arm of E configurations (:func:`models.collision.body_segments_mm`):
    ``start``, ``end`` (E, n_arms, n_bodies, 2) and ``half_width`` (E, n_arms, n_bodies), with
    each segment's ``mid`` point and its ``reach`` (half its length plus the half width: no
    point of the capsule is farther from ``mid``)."""

    start: np.ndarray
    end: np.ndarray
    half_width: np.ndarray
    mid: np.ndarray
    reach: np.ndarray

    @staticmethod
    def of_segments(start: np.ndarray, end: np.ndarray, half_width: np.ndarray) -> Bodies:
        d = end - start
        return Bodies(start, end, half_width, 0.5 * (start + end), 0.5 * np.hypot(d[..., 0], d[..., 1]) + half_width)

    def rows(self, rows) -> Bodies:
        return Bodies(self.start[rows], self.end[rows], self.half_width[rows], self.mid[rows], self.reach[rows])


def bodies_of(inst: Instrument, q: np.ndarray) -> Bodies:
    """The capsules of every arm of the configurations ``q`` (E, n_arms, 2)."""
    arms = np.broadcast_to(np.arange(q.shape[1]), q.shape[:2])
    return Bodies.of_segments(*body_segments_mm(inst, arms, q[..., 0], q[..., 1]))


def _clear(inst: Instrument, arms: np.ndarray, own: Bodies, b: Bodies) -> np.ndarray:
    """(O, E): whether arm ``arms[o]``, its capsules ``own`` (O, n_bodies, ...), clears every
    other arm of each of E configurations ``b`` by the collision buffer: the capsule clearance
    of :func:`models.collision.arm_pair_clearance_mm`, computed for the body pairs whose lower
    bound (the distance of the segments' midpoints less both capsules' reach, by the triangle
    inequality) is below the buffer; the others clear it."""
    buffer = float(inst.collision_buffer_mm)
    gap = b.mid[None, :, :, None, :, :] - own.mid[:, None, None, :, None, :]  # (O, E, arms, bodies, bodies, 2)
    lower = (np.hypot(gap[..., 0], gap[..., 1]) - own.reach[:, None, None, :, None]
             - b.reach[None, :, :, None, :])
    lower[np.arange(len(arms)), :, arms] = np.inf  # each arm and itself
    o, e, m, ia, ib = np.nonzero(lower < buffer)
    d = (segment_distance_mm(own.start[o, ia], own.end[o, ia], b.start[e, m, ib], b.end[e, m, ib])
         - own.half_width[o, ia] - b.half_width[e, m, ib])
    hit = d < buffer
    ok = np.ones((len(arms), len(b.start)), bool)
    ok[o[hit], e[hit]] = False
    return ok


def only_here(inst: Instrument, ra_deg: np.ndarray, dec_deg: np.ndarray, exposures: list[Exposure],
              park_move_limit_s: float | None, few: int = FEW_TARGETS) -> dict[int, dict[int, str]]:
    """For every exposure observing at most ``few`` targets, its targets that no other exposure
    of the plan can take, with the reason: :data:`OUTSIDE_OTHER_FIELDS` (no other exposure's
    field of view holds it) or :data:`NO_SPARE_ARM` (no other exposure whose field holds it
    has an idle arm that can observe it, :func:`spare_arm_for`); and, of an exposure observing
    more than one, its targets that only exposures observing fewer than ``few`` can take,
    :data:`TAKERS_OBSERVE_FEWER` (moving one there leaves as many exposures observing few, and
    this exposure could take it back; the consolidation's moves,
    :func:`solvers.programme.consolidate.thin_moves`, go only to exposures observing at least
    ``few``). A target with none of these is left out: an exposure observing at least ``few``
    could take it (:func:`explained` names one). Returns {exposure index: {target index: reason}}."""
    return explained(inst, ra_deg, dec_deg, exposures, park_move_limit_s, few)[0]


def explained(inst: Instrument, ra_deg: np.ndarray, dec_deg: np.ndarray, exposures: list[Exposure],
              park_move_limit_s: float | None, few: int = FEW_TARGETS,
              ) -> tuple[dict[int, dict[int, str]], dict[int, dict[int, int]]]:
    """:func:`only_here`'s reasons, and for every other target of an exposure observing at
    most ``few`` the exposure that could take it as the plan stands (one observing at least
    ``few``; of an exposure observing one target, the fullest that can): ({exposure index:
    {target index: reason}}, {exposure index: {target index: taker's exposure index}})."""
    ra, dec = np.asarray(ra_deg, float), np.asarray(dec_deg, float)
    scale = float(inst.plate_scale_arcsec_per_mm)
    groups = _pointings(inst, exposures)
    out: dict[int, dict[int, str]] = {}
    movable: dict[int, dict[int, int]] = {}
    for j, e in enumerate(exposures):
        if not 0 < len(e.targets) <= few:
            continue
        reasons, takes = {}, {}
        for t in e.targets:
            held, most, taker = False, -1, -1  # most: the most targets an exposure that can take it observes
            for g in groups:
                others = g.members != j
                if not others.any() or tangent_radius_mm(ra[t], dec[t], g.ra_deg, g.dec_deg, scale) > inst.fov_radius_mm:
                    continue
                held = True
                x, y = sky_to_focal_mm(ra[[t]], dec[[t]], g.ra_deg, g.dec_deg, scale, g.position_angle_deg)
                ok = takers(inst, g.q[others], g.idle[others], float(x[0]), float(y[0]), park_move_limit_s,
                            g.bodies.rows(others))
                for m in g.members[others][ok]:
                    if len(exposures[m].targets) > most:
                        most, taker = len(exposures[m].targets), int(m)
                if most >= few:
                    break
            if not held:
                reasons[t] = OUTSIDE_OTHER_FIELDS
            elif most < 0:
                reasons[t] = NO_SPARE_ARM
            elif len(e.targets) > 1 and most < few:
                reasons[t] = TAKERS_OBSERVE_FEWER
            else:
                takes[t] = taker
        if reasons:
            out[j] = reasons
        if takes:
            movable[j] = takes
    return out, movable


@dataclass(frozen=True)
class _Pointing:
    """The exposures of one pointing (``members``: their indices), their joint angles and
    idle arms stacked."""

    ra_deg: float
    dec_deg: float
    position_angle_deg: float
    members: np.ndarray
    q: np.ndarray
    idle: np.ndarray
    bodies: Bodies


def _pointings(inst: Instrument, exposures: list[Exposure]) -> list[_Pointing]:
    """The exposures grouped by pointing (centre and angle), in order of first appearance."""
    index: dict[tuple[float, float, float], list[int]] = {}
    for j, e in enumerate(exposures):
        index.setdefault((e.ra_deg, e.dec_deg, e.position_angle_deg), []).append(j)
    out = []
    for key, js in index.items():
        q = np.stack([exposures[k].q for k in js])
        out.append(_Pointing(*key, np.array(js), q, np.stack([exposures[k].idle for k in js]), bodies_of(inst, q)))
    return out
