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

from models.collision import arm_pair_clearance_mm
from models.incompatibility import build_assignments
from models.instrument import Instrument
from models.sky import sky_to_focal_mm, tangent_radius_mm

__all__ = ["FEW_TARGETS", "IDLE_KINDS", "NOWHERE_ELSE", "NO_SPARE_ARM", "OUTSIDE_OTHER_FIELDS", "TAKERS_OBSERVE_FEWER",
           "Exposure", "explained", "only_here", "placements",
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
           park_move_limit_s: float | None) -> np.ndarray:
    """(E,) which of E configurations of one pointing (``q`` (E, n_arms, 2), ``idle``
    (E, n_arms)) can take the FOV point on an idle arm (:func:`spare_arm_for`, all at once)."""
    out = np.zeros(len(q), bool)
    for _, _, ok in _options(inst, q, idle, x_mm, y_mm, park_move_limit_s, None):
        out |= ok
    return out


def _options(inst: Instrument, q: np.ndarray, idle: np.ndarray, x_mm: float, y_mm: float,
             park_move_limit_s: float | None, allowed_arms: int | None):
    """Per (arm, IK branch) reaching the point within the park move limit: the arm, its pose
    and (E,) whether each configuration has that arm idle and clear of its other arms there."""
    reach = build_assignments(inst, np.array([x_mm]), np.array([y_mm]), park_move_limit_s=park_move_limit_s,
                              include_park=False).assignments
    n = q.shape[1]
    for i in np.flatnonzero(reach.target == 0):
        k = int(reach.arm[i])
        if allowed_arms is not None and not (allowed_arms >> k) & 1:
            continue
        ok = idle[:, k].copy()
        if not ok.any():
            continue
        pose = np.array([reach.theta1_rad[i], reach.theta2_rad[i]])
        others = np.array([j for j in range(n) if j != k])
        qo = q[ok][:, others]  # (E', n - 1, 2)
        clear = arm_pair_clearance_mm(inst, np.full(qo.shape[:2], k), np.broadcast_to(pose, qo.shape),
                                      np.broadcast_to(others, qo.shape[:2]), qo)
        ok[ok] = np.all(clear >= inst.collision_buffer_mm, axis=1)
        yield k, pose, ok


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
    groups = _pointings(exposures)
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
                ok = takers(inst, g.q[others], g.idle[others], float(x[0]), float(y[0]), park_move_limit_s)
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


def _pointings(exposures: list[Exposure]) -> list[_Pointing]:
    """The exposures grouped by pointing (centre and angle), in order of first appearance."""
    index: dict[tuple[float, float, float], list[int]] = {}
    for j, e in enumerate(exposures):
        index.setdefault((e.ra_deg, e.dec_deg, e.position_angle_deg), []).append(j)
    return [_Pointing(*key, np.array(js), np.stack([exposures[k].q for k in js]),
                      np.stack([exposures[k].idle for k in js])) for key, js in index.items()]
