"""A round's task of one pointing, as both plan flows (the synchronous plan and a plan job)
compute it: :func:`service.pointing_plans.pointing_task`, or, when the round plans the pointing
again from its best plan so far (:func:`planner.programme.keeps_plan`), that task with the
plan's configurations as its allocation (observed as they are) and the plan's verified legs
for its motion planner to reuse (:mod:`planner.known_legs`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

from models.instrument import Instrument
from models.types import AllocationResult, Configuration, Unallocated
from planner.programme import RoundTask, keeps_plan, rank
from service import adapters, pointing_plans
from service.schemas import PlanRequest
from solvers.segmentation import Segmentation

__all__ = ["allocation_in", "round_task"]


def round_task(req: PlanRequest, seg: Segmentation, task: RoundTask, inst: Instrument,
               best: Mapping[str, Any] | None) -> pointing_plans.PointingTask:
    """The task of pointing ``task.index`` in ``task.round``; ``best``: the PlanPointing dict
    the rounds keep for it so far (None: none yet)."""
    out = pointing_plans.pointing_task(req, seg, task)
    if best is None or not keeps_plan(max(pointing_plans.outcomes_of(best, task.index), key=rank, default=None),
                                      task.round):
        return out
    members = [req.targets[int(k)].id for k in seg.pointings[task.index].target_indices]
    allocation = allocation_in(best, members)
    if allocation is None:
        return out
    options = dataclasses.replace(out.options, allocation=allocation, allocation_final=True,
                                  known_legs=adapters.known_legs_in(inst, best))
    return dataclasses.replace(out, options=options)


def allocation_in(p: Mapping[str, Any], members: Sequence[str]) -> AllocationResult | None:
    """The configurations of a PlanPointing dict as an allocation of its pointing's
    ``members`` (target ids, in the pointing's order: ``target_index`` is the position
    there), with its unobserved targets and their reasons; an idle arm off park is "blank"
    (the plan places its sky again). None when it names a target that is not a member."""
    pos = {t: i for i, t in enumerate(members)}
    configs = []
    for c in p["configurations"]:
        arms = []
        for a in sorted(c["assignments"], key=lambda a: a["arm"]):
            t = a["target_id"]
            if t is not None and t not in pos:
                return None
            arms.append(adapters.assignment_in(a, None if t is None else pos[t], t))
        yield_ = sum(x.kind == "target" for x in arms)
        configs.append(Configuration(len(configs), tuple(arms), int(c["total_priority"]), yield_, "feasible"))
    seen: set[str] = set()
    unallocated = []
    for u in p["unallocated"]:
        if u["target_id"] in pos and u["target_id"] not in seen:
            seen.add(u["target_id"])
            unallocated.append(Unallocated(pos[u["target_id"]], u["target_id"], u["reason"]))
    return AllocationResult(tuple(configs), tuple(unallocated),
                            {"source": "best plan so far", "n_targets": len(members)})
