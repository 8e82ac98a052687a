"""The plan's answer: the PlanResponse dict of a segmentation and its pointings' plans
(:func:`plan_out`), each pointing's PlanPointing dict (:func:`pointing_plan_out`), the
exposures observing few targets and why (:func:`few_target_exposures`) and the plan's
completeness and exposure bound. Translation of domain results only; the pipeline
(:mod:`service.pipeline`) decides what goes in."""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np

from models.instrument import Instrument
from planner.consolidation import PLAN_FAILED_REASON
from planner.programme import PointingPlan
from planner.sky import SkyField
from planner.telescope_time import total as total_time
from service import adapters, plan_locks
from service.schemas import SkyTarget
from solvers.programme.spare import FEW_TARGETS, IDLE_KINDS, NOWHERE_ELSE, Exposure, explained
from solvers.segmentation import Pointing, Segmentation

__all__ = ["exposure_bound", "few_target_exposures", "left_out_of", "plan_out", "pointing_plan_out"]


def pointing_plan_out(pointing: Pointing, pp: PointingPlan, ids: Sequence[str] | Mapping[int, str],
                      inst: Instrument, sky: SkyField | None = None) -> dict[str, Any]:
    """One pointing's :class:`~planner.programme.PointingPlan` as a PlanPointing dict
    (``ids[k]``: the id of target ``k``; ``sky``: the pointing's sky, which its idle arms'
    kinds are reported against)."""
    seq = adapters.sequence_out(pp.sequence, inst, sky)
    if pp.unplanned_reason is not None:
        legs = len(pp.sequence.configurations) + 1
        seq["motions"] = [adapters.failed_motion_out(inst, pp.unplanned_reason) for _ in range(legs)]
        seq["executable"], seq["reasons"] = False, [pp.unplanned_reason]
    unallocated = [] if pp.allocation is None else [
        adapters.unallocated_out(u) for u in pp.allocation.unallocated]
    motions = seq["motions"]
    stats = adapters.plain(pp.stats)
    stats["motion"].update({"failed_legs": sum(m["status"] != "ok" for m in motions),
                            **{k: seq["stats"][k] for k in adapters.CHANGE_COUNTS}})
    stats["sequence"] = seq["stats"]["sequence"]
    if pp.telescope_time is not None:
        stats["telescope_time"] = adapters.plain(pp.telescope_time)
    if pp.allocation is None:
        unallocated = [{"target_id": t, "reason": "no_time"} for t in pp.targets.ids]
    return {**adapters.pointing_out(pointing, ids), "ra_deg": pointing.ra_deg % 360.0,
            "configurations": seq["configurations"], "motions": motions,
            "unallocated": unallocated + seq["dropped"], "changes": seq["changes"],
            "executable": seq["executable"], "reasons": seq["reasons"], "not_planned": None,
            "stats": stats}


def _completeness(out: Sequence[dict[str, Any]],
                  targets: Sequence[SkyTarget]) -> dict[str, float]:
    """Completeness of the plan as returned (after the motion planner's changes), over every
    target of the request."""
    observed = {a["target_id"] for p in out for c in p["configurations"] for a in c["assignments"]
                if a["target_id"] is not None}
    priority = {t.id: int(t.priority) for t in targets}
    total = sum(priority.values())
    return {"field_completeness": len(observed) / len(targets) if targets else 1.0,
            "priority_completeness": sum(priority.get(t, 0) for t in observed) / total
            if total else 1.0}


def left_out_of(stats: Mapping[str, Any]) -> frozenset[str]:
    """The pointings a plan's consolidation left out because their new plans failed: those
    its passes name in ``failed`` (the plan's ``stats``, with its ``consolidation``)."""
    passes = (stats.get("consolidation") or {}).get("passes", [])
    return frozenset(i for p in passes for i in p.get("failed", []))


def few_target_exposures(out: Sequence[dict[str, Any]], targets: Sequence[SkyTarget], inst: Instrument,
                         park_move_limit_s: float | None, left_out: Collection[str] = ()) -> list[dict[str, Any]]:
    """The FewTargetExposureOut dicts of a plan: each exposure observing at most
    :data:`~solvers.programme.spare.FEW_TARGETS` targets, with those of them no other exposure
    can take, and why, and for each of the others an exposure that could take it as the plan
    stands (:func:`solvers.programme.spare.explained`), with ``kept_because``
    :data:`planner.consolidation.PLAN_FAILED_REASON` when the exposure's pointing or the
    taker's is one of ``left_out`` (pointing ids the plan's consolidation left out because its
    new plan failed, :func:`left_out_of`), else None."""
    index = {t.id: i for i, t in enumerate(targets)}
    ra = np.array([t.ra_deg for t in targets], float)
    dec = np.array([t.dec_deg for t in targets], float)
    exposures, where = [], []
    for p in out:
        for c in p["configurations"]:
            arms = sorted(c["assignments"], key=lambda a: a["arm"])
            q = np.array([[a["theta1_rad"], a["theta2_rad"]] for a in arms], float).reshape(-1, 2)
            idle = np.array([a["kind"] in IDLE_KINDS for a in arms], bool)
            observed = tuple(index[a["target_id"]] for a in arms if a["target_id"] in index)
            exposures.append(Exposure(float(p["ra_deg"]), float(p["dec_deg"]), float(p["position_angle_deg"]),
                                      q, idle, observed))
            where.append((p["id"], int(c["index"])))
    reasons, movable = explained(inst, ra, dec, exposures, park_move_limit_s)
    blocked = set(left_out)
    return [{"pointing_id": where[j][0], "configuration": where[j][1],
             "target_ids": [targets[t].id for t in e.targets],
             "only_here": [{"target_id": targets[t].id, "reason": r} for t, r in sorted(reasons.get(j, {}).items())],
             "could_move_to": [{"target_id": targets[t].id, "pointing_id": where[m][0], "configuration": where[m][1],
                                "kept_because": PLAN_FAILED_REASON if {where[j][0], where[m][0]} & blocked else None}
                               for t, m in sorted(movable.get(j, {}).items())]}
            for j, e in enumerate(exposures) if 0 < len(e.targets) <= FEW_TARGETS]


def plan_out(seg: Segmentation, out: Sequence[dict[str, Any]], targets: Sequence[SkyTarget],
             stats: dict[str, Any], few: Sequence[dict[str, Any]] = ()) -> dict[str, Any]:
    """A PlanResponse dict from the segmentation and its PlanPointing dicts, in pointing
    order (``targets`` of the request; ``stats`` of the whole plan's deadline, its
    ``time_limit_advice`` and its ``epoch`` report (:func:`at_epoch`), which go to the
    answer's fields of those names and its ``notices``; ``few``: its exposures observing few
    targets, :func:`few_target_exposures`)."""
    reasons: dict[str, int] = {}
    for p in out:
        for u in p["unallocated"]:
            reasons[u["reason"]] = reasons.get(u["reason"], 0) + 1
    motions = [m for p in out for m in p["motions"]]
    stats = dict(stats)
    unallocated, excluded = plan_locks.excluded_out(stats)  # targets in no pointing
    if excluded:
        reasons["excluded"] = len(excluded)
        targets = (*targets, *excluded)
    advice = stats.pop("time_limit_advice", None)
    sky_notices = list(dict.fromkeys(n for p in out for n in p["stats"].get("sky", {}).get("notices", [])))
    epoch = stats.pop("epoch", None)
    return {
        "time_limit_advice": advice,
        "epoch": None if epoch is None else adapters.plain(epoch),
        "notices": ([] if epoch is None else epoch.notices())
                   + ([] if advice is None else [advice["message"]]) + sky_notices,
        "tangent_point": {"ra_deg": seg.tangent_ra_deg, "dec_deg": seg.tangent_dec_deg},
        "pointings": list(out),
        "unallocated": unallocated,
        "few_target_exposures": list(few),
        "executable": all(p["executable"] for p in out),
        "reasons": [f"pointing {p['id']}: {r}" for p in out for r in p["reasons"]],
        "stats": adapters.plain({
            "targets": len(targets), "pointings": len(out),
            "configurations": sum(len(p["configurations"]) for p in out),
            "allocated_targets": sum(1 for p in out for c in p["configurations"]
                                     for a in c["assignments"] if a["target_id"] is not None),
            **_completeness(out, targets),
            "unallocated_by_reason": reasons,
            "sky_arms": sum(int(c["stats"].get("sky_arms", 0)) for p in out for c in p["configurations"]),
            "few_target_exposures": len(few),
            "few_target_exposures_only_here": sum(
                {o["target_id"] for o in f["only_here"] if o["reason"] in NOWHERE_ELSE} >= set(f["target_ids"])
                for f in few),
            "few_target_exposures_explained": sum(map(_explained, few)),
            "few_target_exposures_plan_failed": sum(
                _explained(f) and any(m.get("kept_because") for m in f["could_move_to"]) for f in few),
            "motion_plans": len(motions),
            "motion_plans_failed": sum(1 for m in motions if m["status"] != "ok"),
            **{k: sum(p["stats"]["motion"][k] for p in out) for k in adapters.CHANGE_COUNTS},
            "telescope_time": total_time(adapters.telescope_time_in(p["stats"]["telescope_time"])
                                         for p in out),
            **exposure_bound(seg, sum(len(p["configurations"]) for p in out)),
            **stats,
            "segmentation": seg.stats,
        }),
    }


def _explained(few: Mapping[str, Any]) -> bool:
    """Whether every target of a FewTargetExposureOut dict is listed in its ``only_here`` or
    has a ``could_move_to`` entry with a ``kept_because``."""
    listed = {o["target_id"] for o in few["only_here"]}
    listed |= {m["target_id"] for m in few["could_move_to"] if m.get("kept_because")}
    return listed >= set(few["target_ids"])


def exposure_bound(seg: Segmentation, exposures: int) -> dict[str, Any]:
    """The proven lower bound on the programme's exposures (the programme optimiser's) and
    the plan's exposures over it; empty when the segmentation proves none."""
    bound = seg.stats.get("exposures_lower_bound")
    if bound is None:
        return {}
    return {"exposures_lower_bound": int(bound), "exposures_gap": exposures / bound if bound else None}
