"""The stages behind the HTTP API, composed on domain types; no algorithm lives here.

Each stage function takes a validated request model and an :class:`Instrument`, calls the
domain with typed arguments (static imports, typed option dataclasses: a misspelt option is
an error, never dropped), and converts the domain result to a response dict through
:mod:`service.adapters` at the very end. The whole pipeline (:func:`plan`) passes domain
values between its stages — ``Segmentation`` -> ``PlaneTargets`` per pointing ->
``AllocationResult`` -> ``SequencePlan`` — and splits one wall-clock deadline between them.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, date, datetime
from functools import lru_cache
from typing import Any

import numpy as np

from models import clock
from models.budget import Budget
from models.errors import InputError
from models.instrument import Instrument, default_instrument, load_instrument
from models.locks import arm_limits
from models.types import AllocationResult
from planner import consolidation, keep, plan_motion, programme, stages
from planner.kernels import compile_kernels
from planner.options import MotionOptions
from planner.programme import (
    DEFAULT_LIMIT_S,
    PointingOutcome,
    RoundTask,
    plan_progress,
    run_rounds,
    wall_reserve_s,
)
from planner.time_advice import time_advice
from service import adapters, plan_locks, pointing_plans
from service.lock_schemas import target_locks
from service.plan_consolidation import consolidated
from service.plan_output import few_target_exposures, left_out_of, plan_out
from service.pointing_plans import (
    Progress,
    keep_better,
    no_progress,
    outcomes_of,
    pointing_needs,
    sky_plane_targets,
)
from service.round_tasks import round_task
from service.schemas import (
    REQUEST_TYPES,
    AllocationRequest,
    MotionPlanRequest,
    PlanRequest,
    SegmentationRequest,
)
from solvers.allocation import allocate
from solvers.allocation.backends import load_engine_libraries
from solvers.programme import FillOptions, segment_programme
from solvers.programme.segment import searched_angles
from solvers.segmentation import Segmentation, segment_field

log = logging.getLogger("service")

def warm_up() -> None:
    """Load (or compile once) the planner's compiled kernels and the default engines'
    libraries, so that no request pays for them."""
    compile_kernels()
    load_engine_libraries()


Stage = Callable[[str], None]


def _no_stage(_: str) -> None:
    pass


class Stages:
    """``on_stage`` called only when the stage changes (progress reports come many times a
    second; the stage's words change a few times a pointing)."""

    def __init__(self, on_stage: Stage):
        self.on_stage, self.last = on_stage, ""

    def __call__(self, stage: str) -> None:
        if stage != self.last:
            self.last = stage
            self.on_stage(stage)


@lru_cache(maxsize=8)
def instrument_from(path: str | None) -> Instrument:
    return default_instrument() if path is None else load_instrument(path)


def instrument_info(inst: Instrument) -> dict[str, Any]:
    return adapters.instrument_out(inst)


# ------------------------------------------------------------------- segmentation


def field_args(req: SegmentationRequest, inst: Instrument) -> dict[str, Any]:
    """The request as the field arguments of ``segment_field`` and of ``field_plane`` (its
    checks, without the clustering)."""
    tp = req.tangent_point
    return {"ra_deg": np.array([t.ra_deg for t in req.targets], float),
            "dec_deg": np.array([t.dec_deg for t in req.targets], float),
            "threshold_mm": req.threshold_mm,
            "tangent_point": None if tp is None else (tp.ra_deg, tp.dec_deg),
            "fov_radius_mm": inst.fov_radius_mm,
            "plate_scale_arcsec_per_mm": inst.plate_scale_arcsec_per_mm,
            "mode": req.mode}


def segment(req: SegmentationRequest, inst: Instrument, fill: FillOptions | None = None,
            optimiser_s: float | None = None, mode_field: str = "mode", variants_s: float = 0.0) -> Segmentation:
    """``solvers.programme.segment_programme`` on the request (thesis ch. 4; mode
    "fewest-exposures": the programme optimiser, allocating as ``fill`` says within
    ``optimiser_s`` wall-clock seconds, on the effort clock as a pointing's plan, the last
    ``variants_s`` of them for its model's other variants)."""
    args = field_args(req, inst)
    if req.mode != "fewest-exposures":
        seg = segment_field(**args, seed=int(req.seed or 0))
        if fill is None or fill.angle_search is None:
            return seg
        return searched_angles(inst, seg, args["ra_deg"], args["dec_deg"], [t.priority for t in req.targets],
                               fill.angle_search, fill.park_move_limit_s)
    wall_s = programme.optimiser_s(None) if optimiser_s is None else float(optimiser_s)
    with clock.effort(wall_limit_s=programme.optimiser_guard_s(wall_s)) as effort:
        seg = segment_programme(inst, args["ra_deg"], args["dec_deg"], [t.priority for t in req.targets],
                                mode=req.mode, threshold_mm=req.threshold_mm,
                                tangent_point=args["tangent_point"], seed=int(req.seed or 0), fill=fill,
                                budget=Budget.start(programme.SHARES.effort_share * wall_s),
                                mode_field=mode_field, variants_s=programme.SHARES.effort_share * variants_s)
    # the optimiser's effort seconds, and whether its wall-clock guard (not its budget) ended
    # it: then, and only then, its pointings depend on the machine's speed
    optimiser = {**seg.stats.get("optimiser", {}), "effort_s": effort.t_s if not effort.overran else None,
                 "overran": effort.overran}
    return dataclasses.replace(seg, stats={**seg.stats, "optimiser": optimiser})


def segmentation(
    req: SegmentationRequest, inst: Instrument, progress: Progress = no_progress
) -> dict[str, Any]:
    """The segmentation stage on the targets at the request's ``obs_date`` (:func:`at_epoch`;
    its report in ``stats.epoch``)."""
    req, epoch = at_epoch(req)
    seg = segment(req, inst)
    progress(1.0)
    out = adapters.segmentation_out(seg, [t.id for t in req.targets])
    if epoch:
        out["stats"]["epoch"] = {**adapters.plain(epoch["epoch"]), "notices": epoch["epoch"].notices()}
    return out


# --------------------------------------------------------------------- allocation


def _report(progress: Progress, lo: float = 0.0, hi: float = 0.99) -> Callable[[float, str], None]:
    """The allocator's ``progress(fraction, message)`` mapped onto [lo, hi] of ``progress``."""
    def report(p: float, _message: str = "") -> None:
        progress(lo + (hi - lo) * min(max(float(p), 0.0), 1.0))

    return report


def allocate_request(req: AllocationRequest, inst: Instrument, *, time_limit_s: float,
                     progress: Progress = no_progress) -> AllocationResult:
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
        locked=target_locks(req.locked), excluded_targets=req.excluded_targets,
        progress=_report(progress),
    )


def allocation(
    req: AllocationRequest, inst: Instrument, progress: Progress = no_progress, *, time_limit_s: float
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
    req: MotionPlanRequest, inst: Instrument, progress: Progress = no_progress, *, time_limit_s: float
) -> dict[str, Any]:
    """``planner.plan_motion`` from ``start`` to ``goal`` within ``time_limit_s``."""
    start = adapters.full_configuration(req.start, inst, "start")
    goal = adapters.full_configuration(req.goal, inst, "goal")
    result = plan_motion(inst, start, goal, options=motion_options(req),
                         time_budget_s=float(time_limit_s))
    progress(1.0)
    return adapters.motion_out(result)


# -------------------------------------------------------------------- whole pipeline


def plan_limit_s(req: PlanRequest, budget_s: float | None) -> float:
    """The wall-clock limit of a whole plan, its one meaning: the request's ``time_limit_s``
    when it gives one, capped by the server's ``budget_s``; the library default
    (:data:`planner.programme.DEFAULT_LIMIT_S`) when neither bounds it."""
    limits = [float(v) for v in (req.time_limit_s, budget_s) if v is not None]
    return min(limits) if limits else DEFAULT_LIMIT_S


def plan_segmentation(req: PlanRequest) -> SegmentationRequest:
    """The segmentation request of a plan."""
    return SegmentationRequest(targets=req.targets, threshold_mm=req.threshold_mm,
                               mode=pointing_plans.plan_mode(req), seed=req.seed)


def segment_plan(req: PlanRequest, inst: Instrument, limit_s: float | None = None) -> Segmentation:
    """The segmentation stage of a plan limited to ``limit_s`` (deterministic for the
    request and its seed); the programme optimiser allocates as the plan will."""
    if req.keep_configurations is not None:
        return segment_kept(req, inst, limit_s)
    fill = FillOptions(method=req.method, solver=req.solver, seed=int(req.seed or 0),
                       park_move_limit_s=req.park_move_limit_s,
                       position_angle_deg=adapters.requested_angle_deg(req.position_angle_deg),
                       angle_search=adapters.angle_search_in(req.position_angle_deg, req.position_angle_range_deg,
                                                             req.position_angle_step_deg),
                       arm_limits=arm_limits([t.id for t in req.targets], target_locks(req.locked), inst.n_arms))
    n = len(req.targets)
    return segment(plan_segmentation(req), inst, fill, programme.optimiser_s(limit_s, n_targets=n),
                   "segmentation_mode", programme.variants_s(limit_s, n_targets=n))


def segment_kept(req: PlanRequest, inst: Instrument, limit_s: float | None) -> Segmentation:
    """The segmentation stage of a plan with ``keep_configurations``: the kept pointings as
    they are (less the request's excluded targets), checked first (members, field of view,
    exclusions, locks, and every kept configuration, by
    :func:`planner.keep.kept_configurations`: a bad one is a 422 before anything is planned),
    then the request's other targets segmented as usual (:func:`segment_plan`), after them
    (:func:`planner.keep.kept_segmentation`)."""
    ids = [t.id for t in req.targets]
    excluded = set(req.excluded_targets or ())
    kept = adapters.kept_pointings(req.keep_configurations)
    groups = keep.member_groups(kept, ids, excluded)
    ra = np.array([t.ra_deg for t in req.targets], float)
    dec = np.array([t.dec_deg for t in req.targets], float)
    for i, (p, g) in enumerate(zip(kept, groups, strict=True)):
        kept[i] = p = p.at_angle(kept_angle_deg(req, p))
        keep.check_excluded(p, excluded)
        keep.kept_pointing(p, g, ra, dec, (p.ra_deg, p.dec_deg), inst)  # its field of view
        members = [req.targets[int(k)] for k in g if k >= 0]
        configs = keep.kept_configurations(inst, sky_plane_targets(members, p.ra_deg, p.dec_deg, inst,
                                                                    float(p.position_angle_deg)), p)
        keep.check_locks(inst, configs, p, target_locks(req.locked))
    taken = {int(k) for g in groups for k in g if k >= 0}
    rest_index = np.array([k for k in range(len(ids)) if k not in taken], dtype=np.int64)
    rest = None if not len(rest_index) else segment_plan(req.model_copy(update={
        "targets": [req.targets[int(k)] for k in rest_index], "keep_configurations": None}), inst, limit_s)
    return keep.kept_segmentation(inst, kept, groups, rest, rest_index, ra, dec)


def kept_angle_deg(req: PlanRequest, p: keep.KeptPointing) -> float:
    """The position angle of kept pointing ``p``: its own, else the request's number (a
    request searching its angle has none to give: 422 naming the pointing's field)."""
    if p.position_angle_deg is not None:
        return float(p.position_angle_deg)
    if isinstance(req.position_angle_deg, int | float):
        return float(req.position_angle_deg)
    raise InputError(f"{p.field}.position_angle_deg", "give the angle the previous plan used: the "
                     f"request's position_angle_deg is {req.position_angle_deg!r}")


def rounds_limit_s(req: PlanRequest, limit_s: float, seg: Segmentation) -> float:
    """What a plan limited to ``limit_s`` leaves its pointings after its segmentation ``seg``
    (:func:`planner.programme.rounds_limit_s`)."""
    if pointing_plans.plan_mode(req) != "fewest-exposures":
        return limit_s
    used_s = (seg.stats.get("optimiser") or {}).get("variants_effort_s", 0.0)
    return programme.rounds_limit_s(limit_s, len(req.targets), used_s)


@dataclass(frozen=True)
class PlanRounds:
    """How a plan computes its pointings in the rounds of :func:`planner.programme.run_rounds`:
    ``compute`` plans a round's tasks and returns their outcomes; ``answers`` holds each
    pointing's answer kept so far (:func:`service.pointing_plans.keep_better`), by index. A
    synchronous plan computes them here (:func:`plan_pointings`), a plan job on its runner,
    committing each (:func:`service.programme.run_plan`)."""

    compute: Callable[[Sequence[RoundTask]], list[PointingOutcome]]
    answers: Mapping[int, dict[str, Any]]


def plan_programme(req: PlanRequest, inst: Instrument, limit_s: float, stage: Stages,
                   rounds_for: Callable[[Segmentation], PlanRounds | None], left_s: Callable[[], float],
                   sync_s: float | None) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any]] | None:
    """The one driver of a plan, synchronous or a job: segmentation (its locks checked in their
    pointings) -> the pointings in rounds (``rounds_for(seg)``: None stops the plan) -> the
    plan's ``time_limit_advice`` (:func:`limit_advice`, ``sync_s``: the longest synchronous
    limit, None for a job) -> the consolidation after the rounds, within ``left_s()``. Its
    segmentation, its pointings' answers and the stats they share."""
    stage(stages.segmentation_stage(pointing_plans.plan_mode(req)))
    seg = segment_plan(req, inst, limit_s)
    pointing_plans.check_pointing_locks(req, seg, inst)
    rounds = rounds_for(seg)
    if rounds is None:
        return None
    pointings_limit_s = rounds_limit_s(req, limit_s, seg)
    history = run_rounds(pointing_needs(seg, req), pointings_limit_s, rounds.compute,
                         spend_margin=spends_margin(req))
    pointings = [rounds.answers[i] for i in range(len(seg.pointings))]
    advice = limit_advice(req, seg, pointings, history, limit_s, sync_s)
    seg, pointings, consolidation = consolidated(req, inst, seg, pointings, history, pointings_limit_s, left_s)
    stage(stages.ASSEMBLING)
    return seg, pointings, {**consolidation, "time_limit_s": limit_s, "rounds": len(history),
                            **({} if advice is None else {"time_limit_advice": advice})}


def plan_pointings(req: PlanRequest, inst: Instrument, progress: Progress = no_progress, *,
                   budget_s: float | None = None, on_stage: Stage = _no_stage,
                   ) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any]]:
    """Segmentation -> per pointing: projection onto the pointing's own tangent plane
    (``position_angle_deg``) -> allocation (all configurations) -> executable motion sequence
    park -> c1 -> ... -> park (:func:`planner.programme.plan_pointing`), in the rounds of
    :func:`planner.programme.run_rounds` (shares by need, then what is left to the pointings
    with a failed leg), computed here one after the other (:func:`plan_programme`).

    The whole plan ends within :func:`plan_limit_s`: a pointing's share is cut to what the
    limit has left when a slow machine left less (then the limit comes first). ``on_stage``
    hears each stage as it begins (:mod:`planner.stages`). The stats hold the plan's
    ``time_limit_advice`` (:func:`limit_advice`) when its limit left a pointing unplanned."""
    limit = plan_limit_s(req, budget_s)
    budget = Budget.start(limit - wall_reserve_s(limit, len(req.targets)))  # the wall clock: outside any effort block
    stage = Stages(on_stage)

    def report(round_: int, done: float, total: int) -> None:
        progress(plan_progress(round_, done, total))
        stage(stages.plan_stage(round_, done, total))

    def rounds_for(seg: Segmentation) -> PlanRounds:
        progress(plan_progress(1, 0, 1))
        answers: dict[int, dict[str, Any]] = {}

        def compute(tasks: Sequence[RoundTask]) -> list[PointingOutcome]:
            for done, task in enumerate(tasks):
                i = task.index
                answer = pointing_plans.pointing_result(
                    round_task(req, seg, task, inst, answers.get(i)), inst,
                    lambda f, d=done, r=task.round: report(r, d + f, len(tasks)),
                    wall_limit_s=max(budget.left_s(), 0.0))
                answers[i] = keep_better(answers.get(i), answer, i)
                report(task.round, done + 1, len(tasks))
            return [outcomes_of(answers[t.index], t.index)[-1] for t in tasks]

        return PlanRounds(compute, answers)

    planned = plan_programme(req, inst, limit, stage, rounds_for, budget.left_s, sync_limit_s(budget_s))
    assert planned is not None  # a synchronous plan always computes its rounds
    seg, pointings, stats = planned
    return seg, pointings, {**stats, "budget_s": budget_s, "elapsed_s": budget.elapsed_s()}


def spends_margin(req: PlanRequest) -> bool:
    """Whether the plan's last steps spend the margin its rounds kept (a pointing with a
    failed leg first, :func:`planner.programme.margin_round`, then the consolidation):
    :func:`planner.consolidation.applies`."""
    return consolidation.applies(pointing_plans.plan_mode(req), req.keep_configurations is not None)


def sync_limit_s(budget_s: float | None) -> float:
    """The longest limit a synchronous plan has: the server's ``budget_s``, else the
    library default (the CLI's, the page's); a field that needs more is planned as a job."""
    return DEFAULT_LIMIT_S if budget_s is None else float(budget_s)


def limit_advice(req: PlanRequest, seg: Segmentation, pointings: Sequence[dict[str, Any]],
                 history: Sequence[Sequence[PointingOutcome]], limit_s: float,
                 sync_s: float | None) -> dict[str, Any] | None:
    """The TimeLimitAdvice dict of a plan whose ``limit_s`` left some pointing unplanned
    (:func:`planner.time_advice.time_advice`), None otherwise; each pointing not planned gets
    its ``not_planned`` reason, naming the limit. ``sync_s``: the longest limit of a
    synchronous plan (None: the plan already runs as a job, so none is suggested)."""
    advice = time_advice(limit_s, pointing_needs(seg, req), history,
                         pointing_plans.plan_mode(req) == "fewest-exposures", n_targets=len(req.targets))
    if advice is None:
        return None
    needed = advice.needed_limit_s
    for i in advice.not_attempted:
        pointings[i]["not_planned"] = (
            f"not planned: the plan's time limit of {limit_s:g} s went to the pointings that fit "
            f"in it (this field needs about {needed:g} s)")
    ids = [pointings[i]["id"] for i in advice.not_attempted]
    missed = sum(len(pointings[i]["target_ids"]) for i in advice.not_attempted)
    use_job = sync_s is not None and needed > sync_s
    planned = sum(1 for p in pointings if p["executable"] and p["configurations"])
    parts = [f"The time limit of {limit_s:g} s is too short for this field: it needs about "
             f"{needed:g} s (time_limit_s; --time-limit on the command line)."]
    if ids:
        parts.append(f"Within {limit_s:g} s, {planned} of {_count(len(pointings), 'pointing')} "
                     f"{'was' if planned == 1 else 'were'} planned whole; {len(ids)} "
                     f"{'was' if len(ids) == 1 else 'were'} not ({_count(missed, 'target')} no_time).")
    if advice.failed:
        parts.append(f"{_count(len(advice.failed), 'pointing')} kept a failed leg when the limit "
                     "ran out.")
    if use_job:
        parts.append(f"That is more than a synchronous plan's {sync_s:g} s: submit it as a plan "
                     "job (POST /v1/jobs, kind 'plan').")
    return {"time_limit_s": limit_s, "needed_limit_s": needed, "use_job": use_job,
            "pointings_total": len(pointings), "pointings_planned": planned,
            "pointings_not_planned": ids,
            "pointings_failed": [pointings[i]["id"] for i in advice.failed],
            "targets_not_planned": missed, "message": " ".join(parts)}


def _count(n: int, word: str) -> str:
    """``n`` and ``word``, plural unless ``n`` is 1."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def today() -> date:
    """The server's date (UTC): a plan without an observation date reports the shifts of its
    moving targets a year after it."""
    return datetime.now(UTC).date()


def at_epoch(req: Any) -> tuple[Any, dict[str, Any]]:
    """``req`` (a plan or segmentation request) with its targets at its ``obs_date``
    (:func:`models.epochs.at_date`: unchanged without one), and ``{"epoch": report}`` for
    :func:`plan_out` (empty when there is nothing to report)."""
    targets, report = adapters.targets_at_epoch(req.targets, req.obs_date, today())
    return req.model_copy(update={"targets": targets}), {} if report is None else {"epoch": report}


def plan(req: PlanRequest, inst: Instrument, progress: Progress = no_progress, *,
         budget_s: float | None = None, on_stage: Stage = _no_stage) -> dict[str, Any]:
    """:func:`plan_pointings` as a PlanResponse dict. A motion leg that cannot be planned is
    returned with status "failed", never as an exception; the pointing and the plan then say
    ``executable: false`` with the reasons. ``on_stage`` hears the stages
    (:mod:`planner.stages`). The targets are first moved to the request's ``obs_date``
    (:func:`at_epoch`)."""
    req, epoch = at_epoch(req)
    req, excluded = plan_locks.without_excluded(req, inst)
    seg, pointings, stats = plan_pointings(req, inst, progress, budget_s=budget_s, on_stage=on_stage)
    out = plan_answer(req, inst, seg, pointings, {**stats, **excluded, **epoch})
    progress(1.0)
    return out


def plan_answer(req: PlanRequest, inst: Instrument, seg: Segmentation, pointings: Sequence[dict[str, Any]],
                stats: dict[str, Any]) -> dict[str, Any]:
    """A plan's PlanResponse dict, with its content hash: its pointings' answers, the stats,
    and every exposure observing few targets with its reasons (:func:`few_target_exposures`)."""
    few = few_target_exposures(pointings, req.targets, inst, req.park_move_limit_s, left_out_of(stats))
    return adapters.with_content_hash(plan_out(seg, pointings, req.targets, stats, few))


def run(kind: str, request: Any, inst: Instrument, progress: Progress = no_progress,
        *, time_limit_s: float, budget_s: float | None = None,
        on_stage: Stage = _no_stage) -> dict[str, Any]:
    """Run one stage by its job kind on an already validated (or raw dict) request
    (``on_stage``: a plan's stages)."""
    model = REQUEST_TYPES[kind]
    req = request if isinstance(request, model) else model.model_validate(request)
    if isinstance(req, SegmentationRequest):
        return segmentation(req, inst, progress)
    if isinstance(req, AllocationRequest):
        return allocation(req, inst, progress, time_limit_s=time_limit_s)
    if isinstance(req, MotionPlanRequest):
        return motion_plan(req, inst, progress, time_limit_s=time_limit_s)
    assert isinstance(req, PlanRequest)
    return plan(req, inst, progress, budget_s=budget_s, on_stage=on_stage)
