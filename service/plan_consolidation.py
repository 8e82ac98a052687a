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
from models.types import Configuration
from planner.consolidation import (
    NO_TIME_REASON,
    PASS_EFFORT_S,
    PASS_WALL_GUARD,
    PlannedPointing,
    Regrouped,
    accepted,
    affordable,
    another_pass,
    applies,
    consolidation_tasks,
    costs,
    few_observed,
    left_s,
    no_time,
    pass_wall_s,
    replan_costs,
    replan_wall_s,
    retry_tasks,
)
from planner.known_legs import KnownLegs
from planner.programme import PointingOutcome, RoundTask
from service import adapters, pointing_plans
from service.lock_schemas import target_locks
from service.schemas import PlanRequest
from solvers.segmentation import Segmentation

__all__ = ["changed_segmentation", "consolidated"]


def consolidated(req: PlanRequest, inst: Instrument, seg: Segmentation, answers: list[dict[str, Any]],
                 history: Sequence[Sequence[PointingOutcome]], limit_s: float,
                 wall_left_s: Callable[[], float]) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any]]:
    """``seg`` and ``answers`` after the consolidation (module docstring of
    :mod:`planner.consolidation`), with the plan's ``consolidation`` stats; unchanged when the
    plan is not consolidated (:func:`planner.consolidation.applies`), or when
    the pass empties no exposure within what the rounds left or its plans are not accepted.
    A pass keeps the new plans of each group of pointings that exchanged targets when they are
    better, apart from the other groups'. The pass runs again on the plan it left while it kept
    some, or left out pointings whose new plans failed (the later passes leave them out,
    :func:`planner.consolidation.another_pass`), each on what the rounds and the earlier passes
    left.
    ``limit_s``: the rounds' limit; ``wall_left_s``: the wall-clock seconds the plan has left."""
    if not applies(pointing_plans.plan_mode(req), req.keep_configurations is not None):
        return seg, answers, {}
    passes: list[dict[str, Any]] = []
    history, spent_s = list(history), 0.0
    left_out: list[frozenset[int]] = []  # per pass, the pointings whose new plans failed: out of the later passes
    while another_pass([p["accepted"] for p in passes], left_out=left_out):
        frozen = frozenset().union(*left_out)
        seg, answers, stats, tries, failed = _pass(req, inst, seg, answers, history, limit_s, wall_left_s, spent_s,
                                                   frozen)
        passes.append(stats)
        left_out.append(failed - frozen)
        spent_s += pass_wall_s(stats["effort_s"])
        history += tries
    return seg, answers, {"consolidation": _summary(passes)}


def _pass(req: PlanRequest, inst: Instrument, seg: Segmentation, answers: list[dict[str, Any]],
          history: Sequence[Sequence[PointingOutcome]], limit_s: float, wall_left_s: Callable[[], float],
          spent_s: float, frozen: frozenset[int] = frozenset(),
          ) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any], list[list[PointingOutcome]], frozenset[int]]:
    """One pass on the plan ``answers`` (the pointings ``frozen`` left out), after the rounds'
    and earlier passes' outcomes (``history``) and ``spent_s`` wall-clock seconds of earlier
    passes' own work: ``seg`` and ``answers`` as the pass leaves them, its stats, the outcomes
    of its plans and the pointings whose new plans failed (:func:`_failed`)."""
    index = {t.id: i for i, t in enumerate(req.targets)}
    planned = [_planned(p, index) for p in answers]
    limits = arm_limits([t.id for t in req.targets], target_locks(req.locked), inst.n_arms)
    cost = costs(history)
    left = left_s(limit_s, history, spent_s + pass_wall_s())
    with clock.effort(wall_limit_s=max(min(wall_left_s(), PASS_WALL_GUARD * pass_wall_s()), 0.0)) as effort:
        saved, moved, changed = affordable(inst, np.array([t.ra_deg for t in req.targets]),
                                           np.array([t.dec_deg for t in req.targets]),
                                           np.array([int(t.priority) for t in req.targets]), planned,
                                           req.park_move_limit_s, limits, Budget.start(PASS_EFFORT_S), cost,
                                           left, frozen=frozen)
    stats: dict[str, Any] = {"exposures_emptied": saved, "targets_moved_from_few": moved, "effort_s": effort.t_s,
                             "pointings": [answers[r.index]["id"] for r in changed], "accepted": False}
    if frozen:
        stats["left_out"] = [answers[i]["id"] for i in sorted(frozen)]
    if not changed:
        if no_time(left):
            stats["reason"] = NO_TIME_REASON
        return seg, answers, stats, [], frozenset()
    new_seg = changed_segmentation(req, inst, seg, changed)
    spent_s += pass_wall_s(effort.t_s)
    need = replan_costs(cost, planned, changed)
    tasks = consolidation_tasks(need, left_s(limit_s, history, spent_s), len(history) + 1,
                                [r.index for r in changed])
    if not tasks:  # a guard: the pass chose pointings whose costs fit in what was left
        return seg, answers, {**stats, "reason": "no time left to plan the changed pointings"}, [], frozenset()
    known = {r.index: adapters.known_legs_in(inst, answers[r.index]) for r in changed}
    new, tries = _replanned(req, inst, new_seg, tasks, known, wall_left_s,
                            lambda tries: retry_tasks(need, limit_s, history, spent_s, tries))
    kept = _kept_groups(changed, answers, new)
    failed = _failed([r for r in changed if r.group not in kept], new)
    if not kept:
        return seg, answers, {**stats, "reason": "the changed pointings' plans were not better",
                              "failed": [answers[i]["id"] for i in sorted(failed)]}, tries, failed
    out, pointings = list(answers), list(seg.pointings)
    for r in changed:
        if r.group in kept:
            a = new[r.index]
            rounds = answers[r.index]["stats"].get("rounds", []) + a["stats"].get("rounds", [])
            out[r.index] = {**a, "stats": {**a["stats"], "rounds": rounds}}
            pointings[r.index] = new_seg.pointings[r.index]
    saved_exposures = sum(len(answers[i]["configurations"]) - len(out[i]["configurations"]) for i in new)
    stats = {**stats, "accepted": True, "exposures_saved": saved_exposures}
    refused = sorted(r.index for r in changed if r.group not in kept)
    if refused:  # the groups whose plans were not better keep their old plans
        stats.update(refused=[answers[i]["id"] for i in refused], failed=[answers[i]["id"] for i in sorted(failed)])
    return dataclasses.replace(seg, pointings=tuple(pointings)), out, stats, tries, failed


def changed_segmentation(req: PlanRequest, inst: Instrument, seg: Segmentation,
                         changed: Sequence[Regrouped]) -> Segmentation:
    """``seg`` with the pointings a pass ``changed`` given their new members and allocation,
    observed as it is (``allocation_final``)."""
    pointings = list(seg.pointings)
    for r in changed:
        p = pointings[r.index]
        radius = tangent_radius_mm(np.array([req.targets[i].ra_deg for i in r.members]),
                                   np.array([req.targets[i].dec_deg for i in r.members]), p.ra_deg, p.dec_deg,
                                   float(inst.plate_scale_arcsec_per_mm))
        pointings[r.index] = dataclasses.replace(
            p, target_indices=r.members, allocation=r.allocation, allocation_final=True,
            exposures=len(r.allocation.configurations), radius_mm=float(np.max(radius, initial=0.0)))
    return dataclasses.replace(seg, pointings=tuple(pointings))


def _kept_groups(changed: Sequence[Regrouped], answers: Sequence[dict[str, Any]],
                 new: Mapping[int, dict[str, Any]]) -> set[int]:
    """The groups (:attr:`planner.consolidation.Regrouped.group`) whose new plans replace
    their old ones (:func:`planner.consolidation.accepted` on the group's pointings)."""
    kept = set()
    for g in sorted({r.group for r in changed}):
        idx = [r.index for r in changed if r.group == g]
        if accepted([_observed(answers[i]) for i in idx], [_observed(new[i]) for i in idx],
                    sum(len(answers[i]["configurations"]) for i in idx),
                    sum(len(new[i]["configurations"]) for i in idx), [new[i]["executable"] for i in idx],
                    few_observed([n for i in idx for n in _per_exposure(answers[i])]),
                    few_observed([n for i in idx for n in _per_exposure(new[i])])):
            kept.add(g)
    return kept


def _failed(changed: Sequence[Regrouped], new: Mapping[int, dict[str, Any]]) -> frozenset[int]:
    """The changed pointings whose new plan is not executable or does not observe every
    target the pass gave it (the motion planner dropped one)."""
    out = set()
    for r in changed:
        a = new.get(r.index)
        given = sum(x.target_index is not None for c in r.allocation.configurations for x in c.assignments)
        if a is None or not a["executable"] or len(_observed(a)) < given:
            out.add(r.index)
    return frozenset(out)


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
    kept (:func:`service.pointing_plans.keep_better`): {pointing index: PlanPointing dict}, and the
    outcomes of every plan, try by try."""
    new: dict[int, dict[str, Any]] = {}
    tries: list[list[PointingOutcome]] = []
    while tasks:
        for t in tasks:
            answer = pointing_plans.pointing_result(pointing_plans.pointing_task(req, seg, t, known.get(t.index)), inst,
                                              wall_limit_s=replan_wall_s(wall_left_s()))
            new[t.index] = pointing_plans.keep_better(new.get(t.index), answer, t.index)
        tries.append([pointing_plans.outcomes_of(new[t.index], t.index)[-1] for t in tasks])
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
            arms.append(adapters.assignment_in(a, t, str(t)))
        configs.append(Configuration(len(configs), tuple(arms), 0, sum(x.kind == "target" for x in arms), "feasible"))
    unobserved = {index[u["target_id"]]: u["reason"] for u in p["unallocated"] if u["target_id"] in index}
    return PlannedPointing((float(p["ra_deg"]), float(p["dec_deg"])), float(p["position_angle_deg"] or 0.0),
                           tuple(configs), unobserved)


def _per_exposure(p: dict[str, Any]) -> list[int]:
    """The targets each exposure of a PlanPointing dict observes."""
    return [sum(a["target_id"] is not None for a in c["assignments"]) for c in p["configurations"]]


def _observed(p: dict[str, Any]) -> set[str]:
    return {a["target_id"] for c in p["configurations"] for a in c["assignments"] if a["target_id"] is not None}
