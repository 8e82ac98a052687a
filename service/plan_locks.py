"""A plan request's ``locked`` and ``excluded_targets`` translated for the domain
(:mod:`models.locks`, :mod:`planner.locks`); the checks and the policy are the domain's.

* :func:`without_excluded`: the checks that need no geometry (422 naming
  ``excluded_targets[i]`` / ``locked[i]``), then the request without its excluded targets, so
  that segmentation and allocation never see them, and the entry of the plan's stats that
  :func:`excluded_out` turns into the answer's top-level ``unallocated``;
* :func:`check_pointing_locks`: once the pointings are known, every lock checked in its
  target's pointing (reach, branch, park move limit), before any pointing is planned;
* :func:`member_locks`: the locks of one pointing's members (its ``PointingOptions.locked``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from models.errors import InputError
from models.instrument import Instrument
from models.locks import TargetLock, check_exclusions, check_lock_targets, check_locks
from models.types import PlaneTargets
from planner.programme import RoundTask
from service import adapters
from service.lock_schemas import target_locks
from service.schemas import AllocationRequest, PlanRequest, SkyTarget
from solvers.segmentation import Segmentation

__all__ = ["EXCLUDED_KEY", "check_allocation_locks", "check_pointing_locks", "excluded_out", "member_locks",
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


def check_pointing_locks(req: PlanRequest, seg: Segmentation, inst: Instrument) -> None:
    """Every lock, in the pointing its target belongs to (projected as that pointing's plan
    projects it): its arm reaches the target (through its branch) within the park move limit;
    else a 422 naming ``locked[i]`` of the request."""
    if not req.locked:
        return
    from service import pipeline  # the pointing's task and projection, as its plan makes them

    where = {lk.target_id: i for i, lk in enumerate(req.locked)}
    locks = target_locks(req.locked)
    for index, pointing in enumerate(seg.pointings):
        members = {req.targets[int(k)].id for k in pointing.target_indices}
        mine = [n for n, lk in enumerate(locks) if lk.target_id in members]
        if not mine:
            continue
        task = pipeline.pointing_task(req, seg, RoundTask(index, 1, 0.0))
        p = task.pointing
        targets = pipeline.sky_plane_targets(task.members, p.ra_deg % 360.0, p.dec_deg, inst,
                                             task.position_angle_deg)
        check_locks(inst, targets, [locks[n] for n in mine], park_move_limit_s=req.park_move_limit_s,
                    index=[where[locks[n].target_id] for n in mine])


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
