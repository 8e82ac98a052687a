"""The plan's consolidation (:mod:`planner.consolidation`) on a plan's PlanPointing dicts:
both plan flows, the synchronous plan and a plan job, call :func:`consolidated` after their
rounds and before the answer is assembled."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
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
    another_pass,
    applies,
    consolidation_tasks,
    costs,
    few_observed,
    left_s,
    pass_wall_s,
    replan_costs,
    retry_tasks,
)
from planner.known_legs import KnownLegs
from planner.programme import PointingOutcome, RoundTask
from service import adapters, pipeline
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
    The pass runs again on the plan an accepted pass left (:func:`planner.consolidation.another_pass`),
    each on what the rounds and the earlier passes left.
    ``limit_s``: the rounds' limit; ``wall_left_s``: the wall-clock seconds the plan has left."""
    if not applies(pipeline.plan_mode(req), req.keep_configurations is not None):
        return seg, answers, {}
    passes: list[dict[str, Any]] = []
    history, spent_s = list(history), 0.0
    while another_pass([p["accepted"] for p in passes]):
        seg, answers, stats, tries = _pass(req, inst, seg, answers, history, limit_s, wall_left_s, spent_s)
        passes.append(stats)
        spent_s += pass_wall_s(stats["effort_s"])
        history += tries
    return seg, answers, {"consolidation": _summary(passes)}


def _pass(req: PlanRequest, inst: Instrument, seg: Segmentation, answers: list[dict[str, Any]],
          history: Sequence[Sequence[PointingOutcome]], limit_s: float, wall_left_s: Callable[[], float],
          spent_s: float) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any], list[list[PointingOutcome]]]:
    """One pass on the plan ``answers``, after the rounds' and earlier passes' outcomes
    (``history``) and ``spent_s`` wall-clock seconds of earlier passes' own work: ``seg`` and
    ``answers`` as the pass leaves them, its stats and the outcomes of its plans."""
    index = {t.id: i for i, t in enumerate(req.targets)}
    planned = [_planned(p, index) for p in answers]
    limits = arm_limits([t.id for t in req.targets], target_locks(req.locked), inst.n_arms)
    cost = costs(history)
    with clock.effort(wall_limit_s=max(min(wall_left_s(), pass_wall_s()), 0.0)) as effort:
        saved, moved, changed = affordable(inst, np.array([t.ra_deg for t in req.targets]),
                                           np.array([t.dec_deg for t in req.targets]),
                                           np.array([int(t.priority) for t in req.targets]), planned,
                                           req.park_move_limit_s, limits, Budget.start(PASS_EFFORT_S), cost,
                                           left_s(limit_s, history, spent_s + pass_wall_s()))
    stats: dict[str, Any] = {"exposures_emptied": saved, "targets_moved_from_few": moved, "effort_s": effort.t_s,
                             "pointings": [answers[r.index]["id"] for r in changed], "accepted": False}
    if not changed:
        return seg, answers, stats, []
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
    spent_s += pass_wall_s(effort.t_s)
    need = replan_costs(cost, planned, changed)
    tasks = consolidation_tasks(need, left_s(limit_s, history, spent_s), len(history) + 1,
                                [r.index for r in changed])
    if not tasks:  # a guard: the pass chose pointings whose costs fit in what was left
        return seg, answers, {**stats, "reason": "no time left to plan the changed pointings"}, []
    known = {r.index: adapters.known_legs_in(inst, answers[r.index]) for r in changed}
    new, tries = _replanned(req, inst, new_seg, tasks, known, wall_left_s,
                            lambda tries: retry_tasks(need, limit_s, history, spent_s, tries))
    ok = accepted([_observed(answers[i]) for i in new], [_observed(a) for a in new.values()],
                  sum(len(answers[i]["configurations"]) for i in new),
                  sum(len(a["configurations"]) for a in new.values()), [a["executable"] for a in new.values()],
                  few_observed([n for i in new for n in _per_exposure(answers[i])]),
                  few_observed([n for a in new.values() for n in _per_exposure(a)]))
    if not ok:
        return seg, answers, {**stats, "reason": "the changed pointings' plans were not better"}, tries
    out = list(answers)
    for i, a in new.items():
        rounds = answers[i]["stats"].get("rounds", []) + a["stats"].get("rounds", [])
        out[i] = {**a, "stats": {**a["stats"], "rounds": rounds}}
    saved_exposures = sum(len(answers[i]["configurations"]) - len(out[i]["configurations"]) for i in new)
    return new_seg, out, {**stats, "accepted": True, "exposures_saved": saved_exposures}, tries


def _summary(passes: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The plan's ``consolidation`` stats from its passes' (``passes``, in order): what the
    accepted passes emptied, changed and saved (the first pass's when none was accepted), the
    last pass's ``reason`` when it gives one, and every pass's own stats."""
    kept = [p for p in passes if p["accepted"]] or list(passes[:1])
    out: dict[str, Any] = {
        "exposures_emptied": sum(p["exposures_emptied"] for p in kept),
        "targets_moved_from_few": sum(p["targets_moved_from_few"] for p in kept),
        "effort_s": sum(p["effort_s"] for p in passes),
        "pointings": sorted({i for p in kept for i in p["pointings"]}),
        "accepted": any(p["accepted"] for p in passes)}
    if out["accepted"]:
        out["exposures_saved"] = sum(p["exposures_saved"] for p in kept)
    if "reason" in passes[-1] and not out["accepted"]:
        out["reason"] = passes[-1]["reason"]
    return {**out, "passes": list(passes)}


def _replanned(req: PlanRequest, inst: Instrument, seg: Segmentation, tasks: Sequence[RoundTask],
               known: Mapping[int, KnownLegs], wall_left_s: Callable[[], float],
               again: Callable[[list[list[PointingOutcome]]], list[RoundTask]],
               ) -> tuple[dict[int, dict[str, Any]], list[list[PointingOutcome]]]:
    """The changed pointings planned on ``tasks`` (each reusing the legs of its plan before the
    pass where it makes the same moves, ``known``), then again on the tasks ``again`` gives for
    the outcomes so far (:func:`planner.consolidation.retry_tasks`), each pointing's best plan
    kept (:func:`service.pipeline.keep_better`): {pointing index: PlanPointing dict}, and the
    outcomes of every plan, try by try."""
    new: dict[int, dict[str, Any]] = {}
    tries: list[list[PointingOutcome]] = []
    while tasks:
        for t in tasks:
            answer = pipeline.pointing_result(pipeline.pointing_task(req, seg, t, known.get(t.index)), inst,
                                              wall_limit_s=max(wall_left_s(), 0.0))
            new[t.index] = pipeline.keep_better(new.get(t.index), answer, t.index)
        tries.append([pipeline.outcomes_of(new[t.index], t.index)[-1] for t in tasks])
        tasks = again(tries)
    return new, tries


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


def _per_exposure(p: dict[str, Any]) -> list[int]:
    """The targets each exposure of a PlanPointing dict observes."""
    return [sum(a["target_id"] is not None for a in c["assignments"]) for c in p["configurations"]]


def _observed(p: dict[str, Any]) -> set[str]:
    return {a["target_id"] for c in p["configurations"] for a in c["assignments"] if a["target_id"] is not None}
