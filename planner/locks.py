"""Locks in a pointing's plan (:mod:`models.locks`): what the plan of one pointing checks and
reports about its locked targets.

The allocation honours the locks in its structure (:func:`solvers.allocation.allocate`); the
motion planner's changes keep a locked target on its arm and branch
(:class:`planner.sequence.SequenceOptions.locked`). Here: whether an allocation made
elsewhere (the programme optimiser's) honours them, so that the plan uses it only then; and
the reasons of the locked targets a plan leaves unobserved, prefixed ``locked_``
(:func:`models.locks.lock_reason`), once the exposure rules have read the plain ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from models.instrument import Instrument
from models.locks import TargetLock, branch_of, lock_reason
from models.types import AllocationResult, Unallocated

__all__ = ["honours", "member_locks", "motion_locks", "plain_reasons", "with_lock_reasons"]


def member_locks(locks: Sequence[TargetLock], ids: Sequence[str]) -> tuple[TargetLock, ...]:
    """The locks of the targets ``ids`` (one pointing's, or the part of it being allocated)."""
    have = set(ids)
    return tuple(lk for lk in locks if lk.target_id in have)


def motion_locks(locks: Sequence[TargetLock]) -> tuple[tuple[str, int, int | None], ...]:
    """The locks as the motion planner's option (target id, arm, branch or None)."""
    return tuple((lk.target_id, int(lk.arm), lk.branch) for lk in locks)


def honours(instrument: Instrument, result: AllocationResult, locks: Sequence[TargetLock]) -> bool:
    """Whether every locked target ``result`` observes is on its arm (and branch)."""
    by_id = {lk.target_id: lk for lk in locks}
    for c in result.configurations:
        for a in c.assignments:
            lk = by_id.get(a.target_id or "")
            if lk is None or a.kind != "target":
                continue
            if a.arm != lk.arm:
                return False
            if lk.branch is not None and branch_of(instrument, a.arm, a.x_mm, a.y_mm, a.theta1_rad,
                                                   a.theta2_rad) != lk.branch:
                return False
    return True


def plain_reasons(result: AllocationResult) -> AllocationResult:
    """``result`` with its reasons without the ``locked_`` prefix (what the exposure rules read)."""
    if not any(u.reason.startswith("locked_") for u in result.unallocated):
        return result
    return replace(result, unallocated=tuple(replace(u, reason=u.reason.removeprefix("locked_"))
                                             for u in result.unallocated))


def with_lock_reasons(unallocated: Sequence[Unallocated], locks: Sequence[TargetLock]) -> tuple[Unallocated, ...]:
    """``unallocated`` with each locked target's reason prefixed ``locked_``."""
    ids = {lk.target_id for lk in locks}
    return tuple(replace(u, reason=lock_reason(u.reason)) if u.target_id in ids else u for u in unallocated)
