"""Allocation edits that make a configuration easier to reach (thesis 2.2.1.1, off-line operations).

When no motion reaches a configuration, its problematic targets are temporarily taken out
(their arms stay at park in that configuration) and placed in another configuration: on an
idle arm (at park or on blank sky) of a configuration still to be observed, with any IK
branch whose bodies keep the collision buffer to every other arm there, or in a new
configuration at the end of the sequence. Every edit is checked against the capsule
collision model (:func:`models.collision.colliding_arm_pairs`), and the edited
configurations keep exactly one entry per arm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from models.collision import arm_pair_clearance_mm
from models.incompatibility import within_park_move_limit
from models.instrument import Instrument
from models.kinematics import inverse_fov, tip_fov
from models.types import ArmAssignment, Configuration

IDLE_KINDS = ("park", "blank")


@dataclass(frozen=True)
class Placed:
    """A target taken out of one configuration, to be observed in another."""

    target_id: str
    target_index: int | None
    x_mm: float
    y_mm: float
    priority: int
    from_arm: int  # the arm that observed it where it was taken out


def park_assignment(instrument: Instrument, arm: int) -> ArmAssignment:
    q = instrument.park_configuration[arm]
    x, y = tip_fov(instrument, arm, q[0], q[1])
    return ArmAssignment(arm, "park", float(q[0]), float(q[1]), float(x), float(y))


def take_out(instrument: Instrument, config: Configuration, arms: Sequence[int],
             priority_of: dict[str, int]) -> tuple[Configuration, list[Placed]]:
    """``config`` with the targets of ``arms`` removed (those arms at park), and the removed targets."""
    out: list[Placed] = []
    asg = list(config.assignments)
    for k in arms:
        a = asg[k]
        if a.kind != "target":
            continue
        p = int(priority_of.get(a.target_id or "", 1))
        out.append(Placed(a.target_id or "", a.target_index, a.x_mm, a.y_mm, p, int(k)))
        asg[k] = park_assignment(instrument, k)
    return _with(config, asg, -sum(p.priority for p in out)), out


def _with(config: Configuration, asg: list[ArmAssignment], d_priority: int) -> Configuration:
    stats = {**config.stats, "changed_for_motion": True}
    return replace(config, assignments=tuple(asg), total_priority=config.total_priority + d_priority,
                   arm_yield=sum(1 for a in asg if a.kind == "target"), stats=stats)


def _fits(instrument: Instrument, q: np.ndarray, arm: int, cand: np.ndarray, buffer_mm: float) -> np.ndarray:
    """Which candidate joint angles (m, 2) of ``arm`` keep the buffer to every other arm of ``q``."""
    ok = np.ones(len(cand), bool)
    for j in range(len(q)):
        if j != arm:
            ok &= arm_pair_clearance_mm(instrument, arm, cand, j, q[j]) >= buffer_mm
    return ok


def try_place(instrument: Instrument, config: Configuration, target: Placed, buffer_mm: float,
              exclude_arms: Sequence[int] = (), park_move_limit_s: float | None = None,
              branch: int | None = None) -> Configuration | None:
    """``config`` with ``target`` on one of its idle arms (any IK branch that fits), or None.

    Arms are tried nearest first (the arm whose base is closest to the target moves least);
    arms in ``exclude_arms`` (e.g. the arm the target was taken from) are not used; only
    branches within ``park_move_limit_s`` of park (None: any), and only IK ``branch`` when given
    (a target locked to it, :mod:`models.locks`).
    """
    q = config.q
    enabled = set(instrument.enabled_arms) - set(exclude_arms)
    idle = [a.arm for a in config.assignments if a.kind in IDLE_KINDS and a.arm in enabled]
    bases = np.array([[instrument.arms[k].base_x_mm, instrument.arms[k].base_y_mm] for k in idle]).reshape(-1, 2)
    dist = np.hypot(bases[:, 0] - target.x_mm, bases[:, 1] - target.y_mm) if idle else np.zeros(0)
    order = sorted(range(len(idle)), key=lambda i: dist[i])
    for i in order:
        k = idle[i]
        ik = inverse_fov(instrument, k, np.array([target.x_mm]), np.array([target.y_mm]))
        ok_b = ik.valid[0] & ((np.arange(ik.valid.shape[-1]) == branch) if branch is not None else True)
        cand = np.column_stack([ik.theta1_rad[0][ok_b], ik.theta2_rad[0][ok_b]])
        cand = cand[within_park_move_limit(instrument, k, cand, park_move_limit_s)]
        if len(cand) == 0:
            continue
        ok = _fits(instrument, q, k, cand, buffer_mm)
        if not ok.any():
            continue
        # the branch closest to park moves least
        park = instrument.park_configuration[k]
        d = np.abs(cand[:, 0] - park[0]) + np.abs((cand[:, 1] - park[1] + np.pi) % (2 * np.pi) - np.pi)
        b = int(np.flatnonzero(ok)[np.argmin(d[ok])])
        asg = list(config.assignments)
        asg[k] = ArmAssignment(k, "target", float(cand[b, 0]), float(cand[b, 1]), target.x_mm, target.y_mm,
                               target.target_index, target.target_id)
        return _with(config, asg, target.priority)
    return None


def other_branches(instrument: Instrument, config: Configuration, arm: int,
                   buffer_mm: float, park_move_limit_s: float | None = None) -> list[Configuration]:
    """``config`` with arm ``arm`` on the same target through each other IK branch that keeps
    the buffer to every other arm (thesis eqs. 3.17-3.27: up to four per point) and is within
    ``park_move_limit_s`` of park (None: any)."""
    a = config.assignments[arm]
    if a.kind != "target":
        return []
    ik = inverse_fov(instrument, arm, np.array([a.x_mm]), np.array([a.y_mm]))
    cand = np.column_stack([ik.theta1_rad[0][ik.valid[0]], ik.theta2_rad[0][ik.valid[0]]])
    same = (np.abs(cand[:, 0] - a.theta1_rad) < 1e-6) & (
        np.abs((cand[:, 1] - a.theta2_rad + np.pi) % (2 * np.pi) - np.pi) < 1e-6)
    cand = cand[~same]
    cand = cand[within_park_move_limit(instrument, arm, cand, park_move_limit_s)]
    if len(cand) == 0:
        return []
    ok = _fits(instrument, config.q, arm, cand, buffer_mm)
    out = []
    for th1, th2 in cand[ok]:
        asg = list(config.assignments)
        asg[arm] = replace(a, theta1_rad=float(th1), theta2_rad=float(th2))
        out.append(_with(config, asg, 0))
    return out


def rest_at_park(instrument: Instrument, config: Configuration, arms: Sequence[int],
                 buffer_mm: float) -> Configuration | None:
    """``config`` with the idle arms among ``arms`` (resting on blank sky) moved to their park
    where park keeps the buffer to every other arm; None if none of them can go there."""
    asg = list(config.assignments)
    moved = False
    for k in arms:
        if asg[k].kind != "blank":
            continue
        park = park_assignment(instrument, k)
        q = np.array([[a.theta1_rad, a.theta2_rad] for a in asg])
        if _fits(instrument, q, k, np.array([[park.theta1_rad, park.theta2_rad]]), buffer_mm)[0]:
            asg[k] = park
            moved = True
    return _with(config, asg, 0) if moved else None


def new_configuration(instrument: Instrument, index: int, status: str = "feasible") -> Configuration:
    """A configuration with every arm at park (to be filled by :func:`try_place`)."""
    asg = tuple(park_assignment(instrument, k) for k in range(instrument.n_arms))
    return Configuration(index, asg, 0, 0, status, {"added_for_motion": True})  # type: ignore[arg-type]
