"""One pointing of a plan, as every way of planning a programme computes it (the synchronous
plan of :mod:`service.pipeline`, plan jobs of :mod:`service.programme`, Dask workers of
:mod:`service.runners`, the consolidation of :mod:`service.plan_consolidation`): its targets
projected about it, its task in a round (:class:`PointingTask`, small and picklable), its plan
(:func:`planner.programme.plan_pointing`) as a PlanPointing dict, and which of two rounds'
answers to keep. The policy is the domain's (:mod:`planner.programme`); this module translates
the request for it and its result for the answer.

Callers use these functions through this module (``pointing_plans.pointing_result(...)``),
so that a test may replace one for every way of planning at once.
"""

from __future__ import annotations

import dataclasses
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.errors import InputError
from models.instrument import Instrument
from models.locks import check_locks
from models.sky import sky_to_focal_mm
from models.types import PlaneTargets
from planner import keep, programme
from planner.known_legs import KnownLegs
from planner.programme import (
    PointingOptions,
    PointingOutcome,
    PointingPlan,
    RoundTask,
    better,
    estimated_exposures,
    exposure_caps,
    pointing_need,
    pointing_seed,
    rank,
)
from planner.sky import SkyRequest
from planner.telescope_time import ObservingRules
from service import adapters, plan_locks
from service.errors import FieldError
from service.lock_schemas import target_locks
from service.plan_output import pointing_plan_out
from service.plan_sky import plan_sky, sky_stats, task_sky
from service.schemas import PlanRequest, SkyTarget
from solvers.segmentation import Pointing, Segmentation

Progress = Callable[[float], None]


def no_progress(_: float) -> None:
    """A progress callback that ignores its reports."""


def sky_to_focal(
    targets: Sequence[SkyTarget], ra_deg: float, dec_deg: float, inst: Instrument,
    position_angle_deg: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Gnomonic projection of ``targets`` about (``ra_deg``, ``dec_deg``) onto the FOV frame.

    A target the projection cannot take (>= 90 deg from the pointing) is a 422 naming
    ``targets[i]`` (indices of ``targets`` as given)."""
    try:
        x, y = sky_to_focal_mm(
            np.array([t.ra_deg for t in targets], float),
            np.array([t.dec_deg for t in targets], float),
            ra_deg, dec_deg, inst.plate_scale_arcsec_per_mm, position_angle_deg,
        )
    except InputError as exc:
        m = re.fullmatch(r"(ra_deg|dec_deg)\[(\d+)\]", str(exc.field))
        if m is None:
            raise
        raise FieldError(("body", "targets", int(m.group(2)), m.group(1)), exc.message) from exc
    return np.asarray(x, float), np.asarray(y, float)


def sky_plane_targets(targets: Sequence[SkyTarget], ra_deg: float, dec_deg: float,
                      inst: Instrument, position_angle_deg: float = 0.0) -> PlaneTargets:
    """Sky targets projected about a pointing, as the allocator's ``PlaneTargets``."""
    x, y = sky_to_focal(targets, ra_deg, dec_deg, inst, position_angle_deg)
    return adapters.plane_targets([t.id for t in targets], x, y, [t.priority for t in targets])


@dataclass(frozen=True)
class PointingTask:
    """Everything the plan of one pointing in one round needs, small and picklable (it is what
    a Dask worker receives): the pointing, its own targets, the request's options, its seed
    (:func:`planner.programme.pointing_seed`), its round and its wall-clock share ``share_s``
    (:func:`planner.programme.run_rounds`)."""

    index: int
    pointing: Pointing
    members: tuple[SkyTarget, ...]
    position_angle_deg: float
    options: PointingOptions
    share_s: float
    round: int = 1
    #: the plan's sky near this pointing (its spare arms' sky positions, :mod:`planner.sky`)
    sky: SkyRequest | None = None


def plan_mode(req: PlanRequest) -> str:
    """The plan's segmentation mode (:func:`planner.programme.segmentation_mode`)."""
    return programme.segmentation_mode(req.segmentation_mode, len(req.targets))


def observing_rules(req: PlanRequest) -> ObservingRules:
    """The request's times and stop rules as the domain's :class:`ObservingRules`."""
    return ObservingRules(exposure_time_s=req.exposure_time_s, acquisition_s=req.acquisition_s,
                          max_exposures=req.max_exposures,
                          min_priority_per_exposure=req.min_priority_per_exposure,
                          min_targets_per_exposure=req.min_targets_per_exposure)


def pointing_caps(req: PlanRequest, seg: Segmentation) -> list[int | None]:
    """Each pointing's most exposures: the request's ``max_exposures`` split by
    :func:`planner.programme.exposure_caps` over the pointings' estimates
    (:func:`planner.programme.estimated_exposures`); None each without it."""
    if req.max_exposures is None:
        return [None] * len(seg.pointings)
    return list(exposure_caps(int(req.max_exposures), [estimated_exposures(p) for p in seg.pointings]))


def pointing_needs(seg: Segmentation, req: PlanRequest | None = None) -> list[float]:
    """The need of each pointing of ``seg`` (:func:`planner.programme.pointing_need`, with
    its cap of the request's ``max_exposures``)."""
    caps = [None] * len(seg.pointings) if req is None else pointing_caps(req, seg)
    return [pointing_need(len(p.target_indices), max_configurations=cap)
            for p, cap in zip(seg.pointings, caps, strict=True)]


def kept_of(req: PlanRequest, pointing_id: str) -> keep.KeptPointing | None:
    """The kept pointing of the request with id ``pointing_id`` (None: none; the segmentation
    gives the other pointings ids no kept one has)."""
    if req.keep_configurations is None:
        return None
    return next((k for k in adapters.kept_pointings(req.keep_configurations) if k.id == pointing_id), None)


def pointing_task(req: PlanRequest, seg: Segmentation, task: RoundTask,
                  known_legs: KnownLegs | None = None) -> PointingTask:
    """The task of pointing ``task.index`` of ``seg`` in ``task.round``, within ``task.share_s``
    (``known_legs``: an earlier plan's legs its motion planner reuses, :mod:`planner.known_legs`)."""
    p = seg.pointings[task.index]
    options = PointingOptions(req.method, req.solver,
                              pointing_seed(int(req.seed or 0), task.index, task.round),
                              req.park_move_limit_s, pointing_caps(req, seg)[task.index],
                              observing_rules(req), p.allocation, p.allocation_final, kept=kept_of(req, p.id))
    options = dataclasses.replace(options, known_legs=known_legs, locked=plan_locks.member_locks(
        req, [req.targets[int(k)] for k in p.target_indices]))
    pa = adapters.requested_angle_deg(req.position_angle_deg) if p.position_angle_deg is None else p.position_angle_deg
    return PointingTask(task.index, p, tuple(req.targets[int(k)] for k in p.target_indices),
                        pa, options, float(task.share_s), task.round,
                        plan_sky(req).near(p.ra_deg % 360.0, p.dec_deg))


def plan_pointing(task: PointingTask, inst: Instrument, progress: Progress = no_progress, *,
                  wall_limit_s: float | None = None) -> PointingPlan:
    """:func:`planner.programme.plan_pointing` on the task's targets, projected about its
    pointing (``wall_limit_s``: what the plan's deadline has left, when less than the share)."""
    p = task.pointing
    targets = sky_plane_targets(task.members, p.ra_deg % 360.0, p.dec_deg, inst,
                                task.position_angle_deg)
    sky = task_sky(task, inst)
    options = task.options if sky is None else dataclasses.replace(task.options, sky=sky)
    return programme.plan_pointing(inst, targets, options, task.share_s, progress,
                                   wall_limit_s=wall_limit_s)


def pointing_result(task: PointingTask, inst: Instrument,
                    progress: Progress = no_progress, *, wall_limit_s: float | None = None,
                    ) -> dict[str, Any]:
    """:func:`plan_pointing` as a PlanPointing dict: the unit of work a plan job commits, and
    what a Dask worker returns. Its ``stats.rounds`` holds the outcome of this round
    (:func:`outcome_out`)."""
    ids = {int(k): t.id for k, t in zip(task.pointing.target_indices, task.members, strict=True)}
    t0 = time.monotonic()
    pp = plan_pointing(task, inst, progress, wall_limit_s=wall_limit_s)
    out = pointing_plan_out(task.pointing, pp, ids, inst, task_sky(task, inst))
    out.update(adapters.angle_out(task.position_angle_deg, task.pointing.position_angle_search))
    out["targets"] = adapters.plan_targets_out(task.members, pp.targets)
    if task.sky is not None:
        out["stats"]["sky"] = sky_stats(task.sky, out["configurations"])
    failed = out["stats"]["motion"]["failed_legs"]
    observed = sum(1 for c in out["configurations"] for a in c["assignments"]
                   if a["target_id"] is not None)
    o = PointingOutcome(task.index, task.round, task.share_s, pp.effort_s, out["executable"],
                        failed, observed, pp.overran, pp.allocation is not None, pp.allocation_effort_s,
                        len(out["configurations"]), int(out["stats"]["motion"].get("configurations_added", 0)))
    out["stats"].update({"compute_s": time.monotonic() - t0,
                         "effort": {"effort_s": pp.effort_s, "overran": pp.overran},
                         "rounds": [outcome_out(o)]})
    return out


def outcome_out(o: PointingOutcome) -> dict[str, Any]:
    """One round's outcome as an entry of a PlanPointing's ``stats.rounds``."""
    return {"round": o.round, "share_s": o.share_s, "effort_s": o.effort_s,
            "executable": o.executable, "failed_legs": o.failed_legs, "observed": o.observed,
            "overran": o.overran, "attempted": o.attempted, "allocation_effort_s": o.allocation_effort_s,
            "exposures": o.exposures, "exposures_added": o.exposures_added}


def outcomes_of(answer: Mapping[str, Any], index: int) -> list[PointingOutcome]:
    """The outcome of every round a committed PlanPointing dict records (its own and those of
    the rounds whose plans it replaced or kept)."""
    return [PointingOutcome(index, int(r["round"]), float(r["share_s"]), float(r["effort_s"]),
                            bool(r["executable"]), int(r["failed_legs"]), int(r["observed"]),
                            bool(r["overran"]), bool(r.get("attempted", True)),
                            float(r.get("allocation_effort_s", 0.0)), int(r.get("exposures", 0)),
                            int(r.get("exposures_added", 0)))
            for r in answer.get("stats", {}).get("rounds", [])]


def keep_better(old: dict[str, Any] | None, new: dict[str, Any], index: int) -> dict[str, Any]:
    """Of a pointing's answer so far (None: none) and a later round's, the one to keep
    (:func:`planner.programme.better`), recording both rounds' outcomes."""
    if old is None:
        return new
    earlier, latest = outcomes_of(old, index), outcomes_of(new, index)
    kept = new if better(latest[-1], max(earlier, key=rank)) else old
    return {**kept, "stats": {**kept["stats"],
                              "rounds": [outcome_out(o) for o in earlier + latest]}}


def check_pointing_locks(req: PlanRequest, seg: Segmentation, inst: Instrument) -> None:
    """Every lock, in the pointing its target belongs to (projected as that pointing's plan
    projects it): its arm reaches the target (through its branch) within the park move limit;
    else a 422 naming ``locked[i]`` of the request."""
    if not req.locked:
        return
    where = {lk.target_id: i for i, lk in enumerate(req.locked)}
    locks = target_locks(req.locked)
    for index, pointing in enumerate(seg.pointings):
        members = {req.targets[int(k)].id for k in pointing.target_indices}
        mine = [n for n, lk in enumerate(locks) if lk.target_id in members]
        if not mine:
            continue
        task = pointing_task(req, seg, RoundTask(index, 1, 0.0))
        p = task.pointing
        targets = sky_plane_targets(task.members, p.ra_deg % 360.0, p.dec_deg, inst, task.position_angle_deg)
        check_locks(inst, targets, [locks[n] for n in mine], park_move_limit_s=req.park_move_limit_s,
                    index=[where[locks[n].target_id] for n in mine])
