"""The plan's consolidation (:mod:`planner.consolidation`) on a plan's PlanPointing dicts:
both plan flows, the synchronous plan and a plan job, call :func:`consolidated` after their
rounds and before the answer is assembled."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from models import clock
from models.budget import Budget
from models.instrument import Instrument
from models.locks import arm_limits
from models.sky import tangent_radius_mm
from models.types import ArmAssignment, Configuration
from planner.consolidation import (
    PASS_EFFORT_S,
    PlannedPointing,
    accepted,
    affordable,
    applies,
    consolidation_tasks,
    costs,
    left_s,
    pass_wall_s,
    retry_tasks,
)
from planner.programme import PointingOutcome, RoundTask
from service import pipeline
from service.lock_schemas import target_locks
from service.schemas import PlanRequest
from solvers.segmentation import Segmentation

__all__ = ["consolidated"]


def consolidated(req: PlanRequest, inst: Instrument, seg: Segmentation, answers: list[dict[str, Any]],
                 history: Sequence[Sequence[PointingOutcome]], limit_s: float,
                 wall_left_s: Callable[[], float]) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any]]:
    """``seg`` and ``answers`` after the consolidation (module docstring of
    :mod:`planner.consolidation`), with the plan's ``consolidation`` stats; unchanged when the
    plan is not consolidated (:func:`planner.consolidation.applies`), or when
    the pass empties no exposure within what the rounds left or its plans are not accepted.
    ``limit_s``: the rounds' limit; ``wall_left_s``: the wall-clock seconds the plan has left."""
    if not applies(pipeline.plan_mode(req), req.keep_configurations is not None):
        return seg, answers, {}
    index = {t.id: i for i, t in enumerate(req.targets)}
    planned = [_planned(p, index) for p in answers]
    limits = arm_limits([t.id for t in req.targets], target_locks(req.locked), inst.n_arms)
    cost = costs(history)
    with clock.effort(wall_limit_s=max(min(wall_left_s(), pass_wall_s()), 0.0)) as effort:
        saved, changed = affordable(inst, np.array([t.ra_deg for t in req.targets]),
                                    np.array([t.dec_deg for t in req.targets]),
                                    np.array([int(t.priority) for t in req.targets]), planned,
                                    req.park_move_limit_s, limits, Budget.start(PASS_EFFORT_S), cost,
                                    left_s(limit_s, history, pass_wall_s()))
    stats: dict[str, Any] = {"exposures_emptied": saved, "effort_s": effort.t_s,
                             "pointings": [answers[r.index]["id"] for r in changed], "accepted": False}
    if not changed:
        return seg, answers, {"consolidation": stats}
    pointings = list(seg.pointings)
    for r in changed:
        p = pointings[r.index]
        radius = tangent_radius_mm(np.array([req.targets[i].ra_deg for i in r.members]),
                                   np.array([req.targets[i].dec_deg for i in r.members]), p.ra_deg, p.dec_deg,
                                   float(inst.plate_scale_arcsec_per_mm))
        pointings[r.index] = dataclasses.replace(
            p, target_indices=r.members, allocation=r.allocation, allocation_final=True,
            exposures=len(r.allocation.configurations), radius_mm=float(np.max(radius, initial=0.0)))
    new_seg = dataclasses.replace(seg, pointings=tuple(pointings))
    tasks = consolidation_tasks(cost, left_s(limit_s, history, pass_wall_s(effort.t_s)), len(history) + 1,
                                [r.index for r in changed])
    if not tasks:  # a guard: the pass chose pointings whose costs fit in what was left
        return seg, answers, {"consolidation": {**stats, "reason": "no time left to plan the changed pointings"}}
    new = _replanned(req, inst, new_seg, tasks, wall_left_s,
                     lambda tries: retry_tasks(cost, limit_s, history, pass_wall_s(effort.t_s), tries))
    ok = accepted([_observed(answers[i]) for i in new], [_observed(a) for a in new.values()],
                  sum(len(answers[i]["configurations"]) for i in new),
                  sum(len(a["configurations"]) for a in new.values()), [a["executable"] for a in new.values()])
    if not ok:
        return seg, answers, {"consolidation": {**stats, "reason": "the changed pointings' plans were not better"}}
    out = list(answers)
    for i, a in new.items():
        rounds = answers[i]["stats"].get("rounds", []) + a["stats"].get("rounds", [])
        out[i] = {**a, "stats": {**a["stats"], "rounds": rounds}}
    saved_exposures = sum(len(answers[i]["configurations"]) - len(out[i]["configurations"]) for i in new)
    return new_seg, out, {"consolidation": {**stats, "accepted": True, "exposures_saved": saved_exposures}}


def _replanned(req: PlanRequest, inst: Instrument, seg: Segmentation, tasks: Sequence[RoundTask],
               wall_left_s: Callable[[], float],
               again: Callable[[list[list[PointingOutcome]]], list[RoundTask]]) -> dict[int, dict[str, Any]]:
    """The changed pointings planned on ``tasks``, then again on the tasks ``again`` gives for
    the outcomes so far (:func:`planner.consolidation.retry_tasks`), each pointing's best plan
    kept (:func:`service.pipeline.keep_better`): {pointing index: PlanPointing dict}."""
    new: dict[int, dict[str, Any]] = {}
    tries: list[list[PointingOutcome]] = []
    while tasks:
        for t in tasks:
            answer = pipeline.pointing_result(pipeline.pointing_task(req, seg, t), inst,
                                              wall_limit_s=max(wall_left_s(), 0.0))
            new[t.index] = pipeline.keep_better(new.get(t.index), answer, t.index)
        tries.append([pipeline.outcomes_of(new[t.index], t.index)[-1] for t in tasks])
        tasks = again(tries)
    return new


def _planned(p: dict[str, Any], index: dict[str, int]) -> PlannedPointing:
    """A PlanPointing dict as :class:`planner.consolidation.PlannedPointing` (targets by their
    index in the request; an idle arm off park is "blank": the plan places its sky again)."""
    configs = []
    for c in p["configurations"]:
        arms = []
        for a in sorted(c["assignments"], key=lambda a: a["arm"]):
            t = index.get(a["target_id"]) if a["target_id"] is not None else None
            kind = "target" if t is not None else a["kind"] if a["kind"] in ("park", "fixed") else "blank"
            arms.append(ArmAssignment(int(a["arm"]), kind, float(a["theta1_rad"]), float(a["theta2_rad"]),
                                      float(a["x_mm"]), float(a["y_mm"]), t, None if t is None else str(t)))
        configs.append(Configuration(len(configs), tuple(arms), 0, sum(x.kind == "target" for x in arms), "feasible"))
    unobserved = {index[u["target_id"]]: u["reason"] for u in p["unallocated"] if u["target_id"] in index}
    return PlannedPointing((float(p["ra_deg"]), float(p["dec_deg"])), float(p["position_angle_deg"] or 0.0),
                           tuple(configs), unobserved)


def _observed(p: dict[str, Any]) -> set[str]:
    return {a["target_id"] for c in p["configurations"] for a in c["assignments"] if a["target_id"] is not None}
