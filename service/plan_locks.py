"""A plan request's ``locked`` and ``excluded_targets`` translated for the domain
(:mod:`models.locks`, :mod:`planner.locks`); the checks and the policy are the domain's.
Once the pointings are known, :func:`service.pointing_plans.check_pointing_locks` checks every
lock in its target's pointing.

* :func:`without_excluded`: the checks that need no geometry (422 naming
  ``excluded_targets[i]`` / ``locked[i]``), then the request without its excluded targets, so
  that segmentation and allocation never see them, and the entry of the plan's stats that
  :func:`excluded_out` turns into the answer's top-level ``unallocated``;
* :func:`member_locks`: the locks of one pointing's members (its ``PointingOptions.locked``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from models.errors import InputError
from models.instrument import Instrument
from models.locks import TargetLock, check_exclusions, check_lock_targets, check_locks
from models.types import PlaneTargets
from service import adapters
from service.lock_schemas import target_locks
from service.schemas import AllocationRequest, PlanRequest, SkyTarget

__all__ = ["EXCLUDED_KEY", "check_allocation_locks", "excluded_out", "member_locks",
           "without_excluded"]

EXCLUDED_KEY = "excluded_targets"  # the stats entry plan_out pops (never part of the answer's stats)


def without_excluded(req: PlanRequest, inst: Instrument) -> tuple[PlanRequest, dict[str, Any]]:
    """``req`` without its excluded targets, after the lock and exclusion checks that need no
    geometry; and ``{EXCLUDED_KEY: (SkyTarget, ...)}`` (empty without exclusions)."""
    if not req.locked and not req.excluded_targets:
        return req, {}
    ids = [t.id for t in req.targets]
    check_exclusions(ids, req.excluded_targets)
    check_lock_targets(inst, ids, target_locks(req.locked), req.excluded_targets)
    if not req.excluded_targets:
        return req, {}
    out = set(req.excluded_targets)
    if len(out) == len(ids):
        raise InputError("excluded_targets", "every target of the request is excluded: nothing to plan")
    kept = [t for t in req.targets if t.id not in out]
    return req.model_copy(update={"targets": kept}), {EXCLUDED_KEY: tuple(t for t in req.targets if t.id in out)}


def member_locks(req: PlanRequest, members: Sequence[SkyTarget]) -> tuple[TargetLock, ...]:
    """The request's locks of the targets ``members``."""
    have = {t.id for t in members}
    return tuple(lk for lk in target_locks(req.locked) if lk.target_id in have)


def excluded_out(stats: dict[str, Any]) -> tuple[list[dict[str, Any]], tuple[SkyTarget, ...]]:
    """The answer's top-level ``unallocated`` (reason 'excluded') and the excluded targets,
    popped from a plan's ``stats``."""
    excluded = tuple(stats.pop(EXCLUDED_KEY, ()))
    return [{"target_id": t.id, "reason": "excluded"} for t in excluded], excluded


def check_allocation_locks(req: AllocationRequest, targets: PlaneTargets, inst: Instrument) -> None:
    """An allocation request's locks and exclusions, checked as ``allocate`` checks them, on
    its ``targets`` (projected): at submission, so that a job is refused with the endpoint's 422."""
    if not req.locked and not req.excluded_targets:
        return
    check_exclusions(targets.ids, req.excluded_targets)
    check_locks(inst, targets, target_locks(req.locked), req.excluded_targets,
                fixed=adapters.states_dict(req.disabled_arms), buffer_mm=req.collision_buffer_mm)
