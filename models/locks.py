"""Locks and exclusions: which (arm, IK branch) may observe a target, and which targets no arm may.

A :class:`TargetLock` says that a target, whenever it is observed, is observed by one arm
(and, when ``branch`` is given, through one IK branch: the index 0..3 of
:func:`models.kinematics.inverse_fov`'s solutions, as in
:attr:`models.incompatibility.Assignments.branch`). An excluded target is observed by no arm.

Both act on the incompatibility structure (:func:`models.incompatibility.build_assignments`
drops every other column of a locked target and every column of an excluded one), so every
allocation engine and every post-pass that reads the structure honours them. What is here
is the up-front check that a lock can be honoured at all (:func:`check_locks`): a lock that
cannot is an :class:`~models.errors.InputError` naming ``locked[i]`` and why, never a target
silently left out.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from models.collision import arm_pair_clearance_mm
from models.errors import InputError
from models.instrument import Instrument
from models.kinematics import inverse_fov, positive_turn_move_time_s
from models.types import PlaneTargets

__all__ = ["N_BRANCHES", "LockColumns", "TargetLock", "allowed_columns", "branch_of", "check_exclusions", "check_lock_targets",
           "check_locks", "lock_columns",
           "lock_reason", "locked_ids"]

N_BRANCHES = 4  # IK solutions per (arm, point), thesis eqs. 3.17-3.27

#: target index -> (arm, branch or None): the only columns a locked target keeps
LockColumns = Mapping[int, tuple[int, int | None]]


@dataclass(frozen=True)
class TargetLock:
    """Target ``target_id`` observed only by ``arm`` (and IK ``branch`` 0..3, None: any)."""

    target_id: str
    arm: int
    branch: int | None = None

    def describe(self) -> str:
        """The lock in words, for reasons and messages."""
        return f"arm {self.arm}" + ("" if self.branch is None else f" branch {self.branch}")


def locked_ids(locks: Sequence[TargetLock] | None) -> dict[str, TargetLock]:
    """The locks by target id."""
    return {lk.target_id: lk for lk in locks or ()}


def lock_reason(reason: str) -> str:
    """The reason of a locked target left unobserved: the plain reason, prefixed ``locked_``
    (``locked_no_time``, ``locked_conflict``, ...), so that the answer says its lock kept it
    from any other arm."""
    return reason if reason.startswith("locked_") else f"locked_{reason}"


def check_exclusions(ids: Sequence[str], excluded: Sequence[str] | None, field: str = "excluded_targets") -> None:
    """Every excluded id names a target, once (``InputError`` naming ``field[i]``)."""
    known = set(ids)
    seen: set[str] = set()
    for i, t in enumerate(excluded or ()):
        if not isinstance(t, str) or t not in known:
            raise InputError(f"{field}[{i}]", f"unknown target id {t!r}")
        if t in seen:
            raise InputError(f"{field}[{i}]", f"target {t!r} is excluded twice")
        seen.add(t)


def _check_shape(instrument: Instrument, i: int, lk: TargetLock, field: str) -> None:
    """The lock's own fields: a TargetLock, an arm index in range, a branch 0..3 or None."""
    if not isinstance(lk, TargetLock):
        raise InputError(f"{field}[{i}]", f"must be a TargetLock, got {type(lk).__name__}")
    if isinstance(lk.arm, bool) or not isinstance(lk.arm, int | np.integer) or not 0 <= lk.arm < instrument.n_arms:
        raise InputError(f"{field}[{i}].arm", f"arm index must be in 0..{instrument.n_arms - 1}, got {lk.arm!r}")
    b = lk.branch
    if b is not None and (isinstance(b, bool) or not isinstance(b, int | np.integer) or not 0 <= b < N_BRANCHES):
        raise InputError(f"{field}[{i}].branch", f"IK branch must be in 0..{N_BRANCHES - 1} or null, got {b!r}")


def _reach_problem(instrument: Instrument, lk: TargetLock, x_mm: float, y_mm: float,
                   fixed: Mapping[int, tuple[float, float]], park_move_limit_s: float | None,
                   buffer_mm: float) -> str | None:
    """Why arm ``lk.arm`` (branch ``lk.branch``) cannot observe the point (x, y), or None."""
    k = int(lk.arm)
    if not instrument.arms[k].enabled or k in fixed:
        return f"arm {k} is disabled"
    ik = inverse_fov(instrument, k, np.array([x_mm]), np.array([y_mm]))
    valid = np.asarray(ik.valid[0], bool)
    where = f"target {lk.target_id!r} at ({x_mm:.2f}, {y_mm:.2f}) mm"
    if not valid.any():
        return f"arm {k} cannot reach {where}"
    if lk.branch is not None and not valid[lk.branch]:
        return (f"arm {k} reaches {where} only through IK branch(es) "
                f"{', '.join(map(str, np.flatnonzero(valid)))}, not branch {lk.branch}")
    if lk.branch is not None:
        valid = valid & (np.arange(N_BRANCHES) == lk.branch)
    q = np.column_stack([ik.theta1_rad[0], ik.theta2_rad[0]])[valid]
    if park_move_limit_s is not None:
        park = instrument.park_configuration[k]
        t_s = positive_turn_move_time_s(park, q, instrument.arms[k].joint1_speed_rad_s,
                                        instrument.arms[k].joint2_speed_rad_s)
        q = q[t_s <= park_move_limit_s]
        if not len(q):
            return (f"{lk.describe()} reaches {where} only by a move from park longer than the park "
                    f"move limit of {park_move_limit_s:g} s (fastest {float(np.min(t_s)):.1f} s)")
    for j, qj in fixed.items():
        q = q[arm_pair_clearance_mm(instrument, k, q, int(j), np.asarray(qj, float)) >= buffer_mm]
        if not len(q):
            return f"{lk.describe()} on {where} collides with disabled arm {j}"
    return None


def check_lock_targets(instrument: Instrument, ids: Sequence[str], locks: Sequence[TargetLock] | None,
                       excluded: Sequence[str] | None = None, field: str = "locked") -> None:
    """The checks that need no geometry: each lock well formed, its target one of ``ids``, not
    excluded, and locked once (``InputError`` naming ``field[i]``)."""
    known, out = set(ids), set(excluded or ())
    first: dict[str, int] = {}
    for i, lk in enumerate(locks or ()):
        _check_shape(instrument, i, lk, field)
        if lk.target_id not in known:
            raise InputError(f"{field}[{i}].target_id", f"unknown target id {lk.target_id!r}")
        if lk.target_id in first:
            raise InputError(f"{field}[{i}]", f"target {lk.target_id!r} is locked twice "
                             f"({field}[{first[lk.target_id]}] locks it already)")
        first[lk.target_id] = i
        if lk.target_id in out:
            raise InputError(f"{field}[{i}]", f"target {lk.target_id!r} is both locked and excluded")


def check_locks(instrument: Instrument, targets: PlaneTargets, locks: Sequence[TargetLock] | None,
                excluded: Sequence[str] | None = None, *,
                fixed: Mapping[int, tuple[float, float]] | None = None,
                park_move_limit_s: float | None = None, buffer_mm: float | None = None,
                field: str = "locked", index: Sequence[int] | None = None) -> None:
    """Every lock can be honoured: :func:`check_lock_targets`, and its arm is enabled (not in
    ``fixed``) and reaches the target (on its branch) within the park move limit without
    touching a disabled arm. Otherwise an ``InputError`` naming ``field[i]`` (``i`` from
    ``index``, the locks' positions in the request, default their positions here) says why."""
    locks = tuple(locks or ())
    names = list(range(len(locks))) if index is None else [int(i) for i in index]
    try:
        check_lock_targets(instrument, targets.ids, locks, excluded, field)
    except InputError as exc:
        raise InputError(_renamed(str(exc.field), field, names), exc.message) from None
    fixed = dict(fixed or {})
    buffer = instrument.collision_buffer_mm if buffer_mm is None else float(buffer_mm)
    pos = {t: j for j, t in enumerate(targets.ids)}
    for n, lk in enumerate(locks):
        j = pos[lk.target_id]
        why = _reach_problem(instrument, lk, float(targets.x_mm[j]), float(targets.y_mm[j]), fixed,
                             park_move_limit_s, buffer)
        if why is not None:
            raise InputError(f"{field}[{names[n]}]", f"cannot be honoured: {why}")


def _renamed(name: str, field: str, names: Sequence[int]) -> str:
    """``field[n]...`` as ``field[names[n]]...``."""
    head = f"{field}["
    if not name.startswith(head):
        return name
    n, rest = name[len(head):].split("]", 1)
    return f"{field}[{names[int(n)]}]{rest}"


def allowed_columns(n_arms: int, n_targets: int, locks: LockColumns | None,
                    excluded: Sequence[int] | np.ndarray | None) -> np.ndarray:
    """(n_arms, n_targets, 4) bool: the (arm, target, branch) columns the locks and exclusions
    leave (all, without either)."""
    ok = np.ones((n_arms, n_targets, N_BRANCHES), bool)
    for t, (arm, branch) in (locks or {}).items():
        ok[:, t, :] = False
        if branch is None:
            ok[arm, t, :] = True
        else:
            ok[arm, t, branch] = True
    if excluded is not None and len(excluded):
        ok[:, np.asarray(excluded, int), :] = False
    return ok


def branch_of(instrument: Instrument, arm: int, x_mm: float, y_mm: float, theta1_rad: float,
              theta2_rad: float, tol_rad: float = 1e-6) -> int | None:
    """The IK branch (0..3) through which ``arm`` at (theta1, theta2) reaches (x, y), or None
    when none of its solutions has those angles."""
    ik = inverse_fov(instrument, int(arm), np.array([x_mm]), np.array([y_mm]))
    d1 = np.abs(ik.theta1_rad[0] - theta1_rad)
    d2 = np.abs((ik.theta2_rad[0] - theta2_rad + np.pi) % (2 * np.pi) - np.pi)
    hit = np.flatnonzero(ik.valid[0] & (d1 < tol_rad) & (d2 < tol_rad))
    return int(hit[0]) if len(hit) else None


def lock_columns(ids: Sequence[str], locks: Sequence[TargetLock] | None) -> dict[int, tuple[int, int | None]]:
    """The locks as target index -> (arm, branch or None); locks of targets not in ``ids``
    are left out (another pointing's)."""
    pos = {t: j for j, t in enumerate(ids)}
    return {pos[lk.target_id]: (int(lk.arm), None if lk.branch is None else int(lk.branch))
            for lk in locks or () if lk.target_id in pos}


def arm_limits(ids: Sequence[str], locks: Sequence[TargetLock] | None, n_arms: int) -> tuple[int, ...] | None:
    """Per target of ``ids``, the bit mask of the arms it may use: its locked arm's bit, or
    every arm's (None without locks). The programme optimiser and the angle search read it,
    so that a locked target's pointing and angle are ones where its own arm reaches it."""
    cols = lock_columns(ids, locks)
    if not cols:
        return None
    every = (1 << int(n_arms)) - 1
    return tuple((1 << cols[j][0]) if j in cols else every for j in range(len(ids)))
