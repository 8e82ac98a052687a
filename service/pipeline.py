"""The stages behind the HTTP API, composed on domain types; no algorithm lives here.

Each stage function takes a validated request model and an :class:`Instrument`, calls the
domain with typed arguments (static imports, typed option dataclasses: a misspelt option is
an error, never dropped), and converts the domain result to a response dict through
:mod:`service.adapters` at the very end. The whole pipeline (:func:`plan`) passes domain
values between its stages — ``Segmentation`` -> ``PlaneTargets`` per pointing ->
``AllocationResult`` -> ``SequencePlan`` — and splits one wall-clock deadline between them.
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np

from models import clock
from models.errors import InputError
from models.instrument import (
    CONFIGURATION_TIME_GOAL_S,
    Instrument,
    default_instrument,
    load_instrument,
)
from models.sky import sky_to_focal_mm
from models.types import AllocationResult, PlaneTargets
from planner import plan_motion
from planner.clearance import compile_kernels
from planner.options import MotionOptions
from planner.sequence import MIN_LEG_S, SequenceOptions, SequencePlan, plan_sequence
from service import adapters
from service.errors import FieldError
from service.schemas import (
    REQUEST_TYPES,
    AllocationRequest,
    MotionPlanRequest,
    PlanRequest,
    SegmentationRequest,
    SkyTarget,
)
from solvers.allocation import allocate
from solvers.allocation.options import AllocationOptions
from solvers.segmentation import Pointing, Segmentation, segment_field
from solvers.sequencing.options import SequenceOptions as AllocationSequenceOptions

Progress = Callable[[float], None]
log = logging.getLogger("service")

# Shares of one pointing's part of a plan's deadline: the allocation gets ALLOCATION_SHARE of
# it, the motion sequence what the allocation left. A pointing whose part is below
# MIN_POINTING_S is not attempted (its targets are `no_time`). RESERVE_SHARE of the whole
# deadline (at most RESERVE_MAX_S) is kept for building the answer.
ALLOCATION_SHARE = 0.5
#: A pointing's searches get this share of its wall-clock share in effort seconds
#: (:func:`plan_pointing`); the rest is the margin by which a machine may be slower than the
#: effort clock's reference before the wall-clock limit stops the searches instead.
EFFORT_SHARE = 0.5
MIN_POINTING_S = 0.5
RESERVE_SHARE, RESERVE_MAX_S = 0.05, 0.5


def warm_up() -> None:
    """Load (or compile once) the planner's compiled kernels, so that no request pays for it."""
    compile_kernels()


def _noop(_: float) -> None:
    pass


@lru_cache(maxsize=8)
def instrument_from(path: str | None) -> Instrument:
    return default_instrument() if path is None else load_instrument(path)


def instrument_info(inst: Instrument) -> dict[str, Any]:
    return adapters.instrument_out(inst)


# --------------------------------------------------------------------------- sky


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


# ------------------------------------------------------------------- segmentation


def segment(req: SegmentationRequest, inst: Instrument) -> Segmentation:
    """``solvers.segmentation.segment_field`` on the request (thesis ch. 4)."""
    tp = req.tangent_point
    return segment_field(
        np.array([t.ra_deg for t in req.targets], float),
        np.array([t.dec_deg for t in req.targets], float),
        threshold_mm=req.threshold_mm,
        tangent_point=None if tp is None else (tp.ra_deg, tp.dec_deg),
        fov_radius_mm=inst.fov_radius_mm,
        plate_scale_arcsec_per_mm=inst.plate_scale_arcsec_per_mm,
        mode=req.mode,
        seed=int(req.seed or 0),
    )


def segmentation(
    req: SegmentationRequest, inst: Instrument, progress: Progress = _noop
) -> dict[str, Any]:
    seg = segment(req, inst)
    progress(1.0)
    return adapters.segmentation_out(seg, [t.id for t in req.targets])


# --------------------------------------------------------------------- allocation


def _report(progress: Progress, lo: float = 0.0, hi: float = 0.99) -> Callable[[float, str], None]:
    """The allocator's ``progress(fraction, message)`` mapped onto [lo, hi] of ``progress``."""
    def report(p: float, _message: str = "") -> None:
        progress(lo + (hi - lo) * min(max(float(p), 0.0), 1.0))

    return report


def allocate_request(req: AllocationRequest, inst: Instrument, *, time_limit_s: float,
                     progress: Progress = _noop) -> AllocationResult:
    """``solvers.allocation.allocate`` on the request's targets (sky targets are projected
    about ``pointing`` first); ``time_limit_s`` bounds the whole call."""
    adapters.check_arms(req.start, inst, "start")
    adapters.check_arms(req.disabled_arms, inst, "disabled_arms")
    if req.sky:
        p = req.pointing
        assert p is not None  # the schema requires it with sky targets
        targets = sky_plane_targets(req.targets, p.ra_deg, p.dec_deg, inst,  # type: ignore[arg-type]
                                    p.position_angle_deg)
    else:
        targets = adapters.plane_targets_of(req.targets)  # type: ignore[arg-type]
    fixed = adapters.states_dict(req.disabled_arms)
    return allocate(
        inst, targets, method=req.method, solver=req.solver, configurations=req.configurations,
        time_limit_s=float(time_limit_s), seed=int(req.seed or 0),
        collision_buffer_mm=req.collision_buffer_mm,
        start_q=adapters.start_configuration(req.start, inst, fixed), fixed=fixed or None,
        progress=_report(progress),
    )


def allocation(
    req: AllocationRequest, inst: Instrument, progress: Progress = _noop, *, time_limit_s: float
) -> dict[str, Any]:
    result = allocate_request(req, inst, time_limit_s=time_limit_s, progress=progress)
    progress(1.0)
    return adapters.allocation_out(result)


# -------------------------------------------------------------------- motion plans


def motion_options(req: MotionPlanRequest) -> MotionOptions:
    """The request's planning options over the planner's defaults (validated once, there)."""
    d = MotionOptions()
    return MotionOptions(
        dt_s=d.dt_s if req.dt_s is None else req.dt_s,
        dt_col_s=d.dt_col_s if req.dt_col_s is None else req.dt_col_s,
        max_start_stop=d.max_start_stop if req.max_start_stop is None else req.max_start_stop,
        collision_buffer_mm=req.collision_buffer_mm,
        seed=int(req.seed or 0),
    )


def motion_plan(
    req: MotionPlanRequest, inst: Instrument, progress: Progress = _noop, *, time_limit_s: float
) -> dict[str, Any]:
    """``planner.plan_motion`` from ``start`` to ``goal`` within ``time_limit_s``."""
    start = adapters.full_configuration(req.start, inst, "start")
    goal = adapters.full_configuration(req.goal, inst, "goal")
    result = plan_motion(inst, start, goal, options=motion_options(req),
                         time_budget_s=float(time_limit_s))
    progress(1.0)
    return adapters.motion_out(result)


# -------------------------------------------------------------------- whole pipeline


@dataclass(frozen=True)
class PointingPlan:
    """One pointing of a plan on domain types. ``allocation`` is None when the pointing was
    not attempted (its targets ``no_time``); ``unplanned_reason`` says why its legs were not
    planned (a planner failure, or no time left): every leg is then reported failed."""

    pointing: Pointing
    ra_deg: float
    targets: PlaneTargets
    allocation: AllocationResult | None
    sequence: SequencePlan
    unplanned_reason: str | None = None
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True)
class PointingTask:
    """Everything the plan of one pointing needs, small and picklable (it is what a Dask
    worker receives): the pointing, its own targets, the request's options, its seed
    (:func:`pointing_seed`) and its wall-clock share ``share_s``; ``time_limit_s`` caps every
    solver call; ``park_move_limit_s``: the allocation's park move limit (None: none)."""

    index: int
    pointing: Pointing
    members: tuple[SkyTarget, ...]
    method: str
    solver: str
    position_angle_deg: float
    seed: int
    share_s: float
    time_limit_s: float
    park_move_limit_s: float | None = CONFIGURATION_TIME_GOAL_S


class _Deadline:
    """The end of a plan or a pointing on the current clock (:mod:`models.clock`; None: no
    limit), ``reserve_s`` before ``limit_s``."""

    def __init__(self, limit_s: float | None, reserve_s: float = 0.0) -> None:
        self.t0 = clock.now()
        self.end = None if limit_s is None else self.t0 + limit_s - reserve_s

    @classmethod
    def of_plan(cls, limit_s: float | None) -> _Deadline:
        """A whole plan's deadline, keeping back the time to build the answer."""
        return cls(limit_s, 0.0 if limit_s is None else min(RESERVE_SHARE * limit_s, RESERVE_MAX_S))

    def left_s(self) -> float:
        return math.inf if self.end is None else self.end - clock.now()

    def elapsed_s(self) -> float:
        return clock.now() - self.t0


def plan_limit_s(req: PlanRequest, budget_s: float | None) -> float | None:
    """The wall-clock limit of a whole plan: the request's ``time_limit_s`` when it gives one,
    capped by the server's ``budget_s``; None when neither bounds it."""
    limits = [v for v in (req.time_limit_s, budget_s) if v is not None]
    return float(min(limits)) if limits else None


def pointing_shares(limit_s: float | None, n: int) -> list[float]:
    """The wall-clock share of each of ``n`` pointings of a plan limited to ``limit_s`` (a
    plan job or a synchronous plan alike): an even split of the limit (less the answer's
    reserve), fixed in advance, so that a pointing's plan does not depend on how long the
    others took; when that is below
    :data:`MIN_POINTING_S`, the first pointings get that minimum and the others none (their
    targets ``no_time``), as in the synchronous plan."""
    if limit_s is None:
        return [math.inf] * n
    usable = max(limit_s - min(RESERVE_SHARE * limit_s, RESERVE_MAX_S), 0.0)
    even = usable / max(n, 1)
    if even >= MIN_POINTING_S:
        return [even] * n
    fit = int(usable // MIN_POINTING_S)
    return [MIN_POINTING_S if i < fit else 0.0 for i in range(n)]


def pointing_seed(seed: int, index: int) -> int:
    """The seed of pointing ``index`` of a plan seeded ``seed``: a fixed function of the two
    (pointing 0 keeps ``seed``), so a pointing's plan does not depend on which worker computes
    it or in which order the pointings run."""
    return (int(seed) + 2_654_435_761 * int(index)) % 2**31


def sequence_motion(inst: Instrument, allocation: AllocationResult, targets: PlaneTargets, *,
                    seed: int, leg_time_limit_s: float, time_limit_s: float | None,
                    park_move_limit_s: float | None = None,
                    progress: Progress = _noop) -> tuple[SequencePlan, str | None]:
    """``planner.sequence.plan_sequence`` on one pointing's configurations; never raises: a
    planner failure comes back as the unchanged configurations with its reason."""
    options = SequenceOptions(seed=seed, leg_time_limit_s=float(leg_time_limit_s),
                              time_limit_s=None if time_limit_s is None else float(time_limit_s),
                              park_move_limit_s=park_move_limit_s)
    configs = tuple(allocation.configurations)
    try:
        return plan_sequence(inst, configs, options, targets=targets, progress=progress), None
    except Exception as exc:  # noqa: BLE001 - reported as failed legs, never a 5xx
        log.exception("motion sequence planning failed")
        return SequencePlan(configs, ()), f"planner error: {type(exc).__name__}: {exc}"


def segment_plan(req: PlanRequest, inst: Instrument) -> Segmentation:
    """The segmentation stage of a plan (deterministic for the request and its seed)."""
    return segment(SegmentationRequest(targets=req.targets, threshold_mm=req.threshold_mm,
                                       mode=req.segmentation_mode, seed=req.seed), inst)


def pointing_task(req: PlanRequest, seg: Segmentation, index: int, share_s: float,
                  time_limit_s: float) -> PointingTask:
    """The task of pointing ``index`` of ``seg``, planned within ``share_s`` seconds."""
    p = seg.pointings[index]
    return PointingTask(index, p, tuple(req.targets[int(k)] for k in p.target_indices),
                        req.method, req.solver, req.position_angle_deg,
                        pointing_seed(int(req.seed or 0), index), float(share_s),
                        float(time_limit_s), req.park_move_limit_s)


def plan_allocation_options(park_move_limit_s: float | None) -> AllocationOptions:
    """The allocation options of a plan: every location within its park move limit."""
    return AllocationOptions(sequence=AllocationSequenceOptions(park_move_limit_s=park_move_limit_s))


def plan_pointing(task: PointingTask, inst: Instrument, progress: Progress = _noop) -> PointingPlan:
    """Allocation (all configurations) then the executable motion sequence of one pointing,
    within ``task.share_s`` seconds (thesis ch. 5 and 6).

    Every budget inside runs on the effort clock (:func:`models.clock.effort`), and the
    pointing's searches get :data:`EFFORT_SHARE` of its share in effort seconds: the plan
    then depends only on the task (the same on any machine, under any load, whatever the
    number of workers). ``task.share_s`` stays the wall-clock limit: a machine so slow that
    it is reached stops the searches there, and ``stats["effort"]["overran"]`` says so."""
    t0 = time.monotonic()
    with clock.effort(wall_limit_s=task.share_s) as effort:
        plan = _plan_pointing(task, inst, progress)
    return replace(plan, stats={**plan.stats, "compute_s": time.monotonic() - t0, "effort": {
        "effort_s": effort.t_s, "overran": effort.overran}})


def _plan_pointing(task: PointingTask, inst: Instrument, progress: Progress) -> PointingPlan:
    deadline = _Deadline(None if math.isinf(task.share_s) else EFFORT_SHARE * task.share_s)
    p = task.pointing
    ra = p.ra_deg % 360.0
    targets = sky_plane_targets(task.members, ra, p.dec_deg, inst, task.position_angle_deg)
    if task.share_s < MIN_POINTING_S:
        seq = plan_sequence(inst, (), SequenceOptions(seed=task.seed))
        return PointingPlan(p, ra, targets, None, seq, stats={
            "allocation": {"skipped": "request time limit exhausted"},
            "motion": {"legs": len(seq.legs), "leg_budget_s": 0.0, "compute_s": 0.0}})
    result = allocate(inst, targets, method=task.method, solver=task.solver,
                      configurations="all", seed=task.seed,
                      time_limit_s=min(task.time_limit_s, ALLOCATION_SHARE * EFFORT_SHARE * task.share_s),
                      progress=_report(progress, 0.0, 0.5), options=plan_allocation_options(task.park_move_limit_s))
    progress(0.5)
    motion_s = deadline.left_s()
    legs = len(result.configurations) + 1
    tm = time.monotonic()
    if motion_s < MIN_LEG_S:
        seq, err = SequencePlan(tuple(result.configurations), ()), (
            f"no time left for motion planning ({max(motion_s, 0.0):.2f} s of the request's "
            "time limit for its legs)")
        leg_budget = 0.0
    else:
        leg_budget = min(task.time_limit_s, max(motion_s / legs, MIN_LEG_S))
        # a leg the sequence starts gets at least MIN_LEG_S: its limit ends that much early
        seq_limit = None if math.isinf(motion_s) else max(motion_s - MIN_LEG_S, 0.01)
        seq, err = sequence_motion(inst, result, targets, seed=task.seed,
                                   leg_time_limit_s=leg_budget, time_limit_s=seq_limit,
                                   park_move_limit_s=task.park_move_limit_s,
                                   progress=lambda f: progress(0.5 + 0.5 * f))
    stats = {"allocation": result.stats,
             "motion": {"legs": len(seq.legs) if err is None else legs,
                        "leg_budget_s": leg_budget, "compute_s": time.monotonic() - tm}}
    return PointingPlan(p, ra, targets, result, seq, err, stats)


def pointing_result(task: PointingTask, inst: Instrument,
                    progress: Progress = _noop) -> dict[str, Any]:
    """:func:`plan_pointing` as a PlanPointing dict: the unit of work a plan job commits, and
    what a Dask worker returns."""
    ids = {int(k): t.id for k, t in zip(task.pointing.target_indices, task.members, strict=True)}
    return pointing_plan_out(plan_pointing(task, inst, progress), ids, inst)


def plan_pointings(req: PlanRequest, inst: Instrument, progress: Progress = _noop, *,
                   time_limit_s: float, budget_s: float | None = None,
                   ) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any]]:
    """Segmentation -> per pointing, in order: projection onto the pointing's own tangent
    plane (``position_angle_deg``) -> allocation (all configurations) -> executable motion
    sequence park -> c1 -> ... -> park (``planner.sequence.plan_sequence``, which may change
    the configurations so that every leg can be executed).

    The whole plan ends within :func:`plan_limit_s` (the request's time limit, capped by
    ``budget_s``): what is left after the segmentation is split evenly over the pointings in
    advance (:func:`pointing_shares`, as in a plan job), each split between its allocation
    and its motion legs; ``time_limit_s`` also caps every single solver call. A pointing
    whose share is below :data:`MIN_POINTING_S` gets no configurations (its targets
    ``no_time``)."""
    deadline = _Deadline.of_plan(plan_limit_s(req, budget_s))
    seg = segment_plan(req, inst)
    progress(0.05)
    n = max(len(seg.pointings), 1)
    shares = pointing_shares(plan_limit_s(req, budget_s), len(seg.pointings))
    out = []
    for i in range(len(seg.pointings)):
        lo, hi = 0.05 + 0.95 * i / n, 0.05 + 0.95 * (i + 1) / n
        # the fixed share, unless a slow machine left less (then the limit comes first)
        share = min(shares[i], max(deadline.left_s(), 0.0))
        out.append(pointing_result(pointing_task(req, seg, i, share, time_limit_s), inst,
                                   lambda f, lo=lo, hi=hi: progress(lo + (hi - lo) * f)))
        progress(hi)
    return seg, out, {"time_limit_s": time_limit_s, "budget_s": budget_s,
                      "deadline_s": plan_limit_s(req, budget_s),
                      "elapsed_s": deadline.elapsed_s()}


def plan(
    req: PlanRequest, inst: Instrument, progress: Progress = _noop, *, time_limit_s: float,
    budget_s: float | None = None,
) -> dict[str, Any]:
    """:func:`plan_pointings` as a PlanResponse dict. A motion leg that cannot be planned is
    returned with status "failed", never as an exception; the pointing and the plan then say
    ``executable: false`` with the reasons."""
    seg, pointings, stats = plan_pointings(req, inst, progress, time_limit_s=time_limit_s,
                                           budget_s=budget_s)
    out = plan_out(seg, pointings, req.targets, stats)
    progress(1.0)
    return out


def pointing_plan_out(pp: PointingPlan, ids: Sequence[str] | Mapping[int, str],
                      inst: Instrument) -> dict[str, Any]:
    """One :class:`PointingPlan` as a PlanPointing dict (``ids[k]``: the id of target ``k``)."""
    seq = adapters.sequence_out(pp.sequence)
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
    if pp.allocation is None:
        unallocated = [{"target_id": t, "reason": "no_time"} for t in pp.targets.ids]
    return {**adapters.pointing_out(pp.pointing, ids), "ra_deg": pp.ra_deg,
            "configurations": seq["configurations"], "motions": motions,
            "unallocated": unallocated + seq["dropped"], "changes": seq["changes"],
            "executable": seq["executable"], "reasons": seq["reasons"], "stats": stats}


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


def plan_out(seg: Segmentation, out: Sequence[dict[str, Any]], targets: Sequence[SkyTarget],
             stats: dict[str, Any]) -> dict[str, Any]:
    """A PlanResponse dict from the segmentation and its PlanPointing dicts, in pointing
    order (``targets`` of the request; ``stats`` of the whole plan's deadline)."""
    reasons: dict[str, int] = {}
    for p in out:
        for u in p["unallocated"]:
            reasons[u["reason"]] = reasons.get(u["reason"], 0) + 1
    motions = [m for p in out for m in p["motions"]]
    return {
        "tangent_point": {"ra_deg": seg.tangent_ra_deg, "dec_deg": seg.tangent_dec_deg},
        "pointings": list(out),
        "executable": all(p["executable"] for p in out),
        "reasons": [f"pointing {p['id']}: {r}" for p in out for r in p["reasons"]],
        "stats": adapters.plain({
            "targets": len(targets), "pointings": len(out),
            "configurations": sum(len(p["configurations"]) for p in out),
            "allocated_targets": sum(1 for p in out for c in p["configurations"]
                                     for a in c["assignments"] if a["target_id"] is not None),
            **_completeness(out, targets),
            "unallocated_by_reason": reasons,
            "motion_plans": len(motions),
            "motion_plans_failed": sum(1 for m in motions if m["status"] != "ok"),
            **{k: sum(p["stats"]["motion"][k] for p in out) for k in adapters.CHANGE_COUNTS},
            **stats,
            "segmentation": seg.stats,
        }),
    }


def run(kind: str, request: Any, inst: Instrument, progress: Progress = _noop,
        *, time_limit_s: float, budget_s: float | None = None) -> dict[str, Any]:
    """Run one stage by its job kind on an already validated (or raw dict) request."""
    model = REQUEST_TYPES[kind]
    req = request if isinstance(request, model) else model.model_validate(request)
    if isinstance(req, SegmentationRequest):
        return segmentation(req, inst, progress)
    if isinstance(req, AllocationRequest):
        return allocation(req, inst, progress, time_limit_s=time_limit_s)
    if isinstance(req, MotionPlanRequest):
        return motion_plan(req, inst, progress, time_limit_s=time_limit_s)
    assert isinstance(req, PlanRequest)
    return plan(req, inst, progress, time_limit_s=time_limit_s, budget_s=budget_s)
