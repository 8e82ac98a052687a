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
import re
import time
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
from models.sky import sky_to_focal_mm
from models.types import AllocationResult, PlaneTargets
from planner import consolidation, keep, plan_motion, programme, stages
from planner.kernels import compile_kernels
from planner.known_legs import KnownLegs
from planner.options import MotionOptions
from planner.programme import (
    DEFAULT_LIMIT_S,
    PointingOptions,
    PointingOutcome,
    PointingPlan,
    RoundTask,
    better,
    estimated_exposures,
    exposure_caps,
    plan_progress,
    pointing_need,
    pointing_seed,
    rank,
    run_rounds,
    wall_reserve_s,
)
from planner.sky import SkyRequest
from planner.telescope_time import ObservingRules
from planner.time_advice import time_advice
from service import adapters, plan_locks
from service.errors import FieldError
from service.lock_schemas import target_locks
from service.plan_output import few_target_exposures, left_out_of, plan_out, pointing_plan_out
from service.plan_sky import plan_sky, sky_stats, task_sky
from service.schemas import (
    REQUEST_TYPES,
    AllocationRequest,
    MotionPlanRequest,
    PlanRequest,
    SegmentationRequest,
    SkyTarget,
)
from solvers.allocation import allocate
from solvers.programme import FillOptions, segment_programme
from solvers.programme.segment import searched_angles
from solvers.segmentation import Pointing, Segmentation, segment_field

Progress = Callable[[float], None]
log = logging.getLogger("service")

def warm_up() -> None:
    """Load (or compile once) the planner's compiled kernels, so that no request pays for it."""
    compile_kernels()


def _noop(_: float) -> None:
    pass


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
    req: SegmentationRequest, inst: Instrument, progress: Progress = _noop
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
        locked=target_locks(req.locked), excluded_targets=req.excluded_targets,
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


def plan_limit_s(req: PlanRequest, budget_s: float | None) -> float:
    """The wall-clock limit of a whole plan, its one meaning: the request's ``time_limit_s``
    when it gives one, capped by the server's ``budget_s``; the library default
    (:data:`planner.programme.DEFAULT_LIMIT_S`) when neither bounds it."""
    limits = [float(v) for v in (req.time_limit_s, budget_s) if v is not None]
    return min(limits) if limits else DEFAULT_LIMIT_S


def plan_segmentation(req: PlanRequest) -> SegmentationRequest:
    """The segmentation request of a plan."""
    return SegmentationRequest(targets=req.targets, threshold_mm=req.threshold_mm,
                               mode=plan_mode(req), seed=req.seed)


def plan_mode(req: PlanRequest) -> str:
    """The plan's segmentation mode (:func:`planner.programme.segmentation_mode`)."""
    return programme.segmentation_mode(req.segmentation_mode, len(req.targets))


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


def kept_of(req: PlanRequest, pointing_id: str) -> keep.KeptPointing | None:
    """The kept pointing of the request with id ``pointing_id`` (None: none; the segmentation
    gives the other pointings ids no kept one has)."""
    if req.keep_configurations is None:
        return None
    return next((k for k in adapters.kept_pointings(req.keep_configurations) if k.id == pointing_id), None)


def rounds_limit_s(req: PlanRequest, limit_s: float, seg: Segmentation) -> float:
    """What a plan limited to ``limit_s`` leaves its pointings after its segmentation ``seg``
    (:func:`planner.programme.rounds_limit_s`)."""
    if plan_mode(req) != "fewest-exposures":
        return limit_s
    used_s = (seg.stats.get("optimiser") or {}).get("variants_effort_s", 0.0)
    return programme.rounds_limit_s(limit_s, len(req.targets), used_s)


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


def plan_pointing(task: PointingTask, inst: Instrument, progress: Progress = _noop, *,
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
                    progress: Progress = _noop, *, wall_limit_s: float | None = None,
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


def plan_pointings(req: PlanRequest, inst: Instrument, progress: Progress = _noop, *,
                   budget_s: float | None = None, on_stage: Stage = _no_stage,
                   ) -> tuple[Segmentation, list[dict[str, Any]], dict[str, Any]]:
    """Segmentation -> per pointing: projection onto the pointing's own tangent plane
    (``position_angle_deg``) -> allocation (all configurations) -> executable motion sequence
    park -> c1 -> ... -> park (:func:`planner.programme.plan_pointing`), in the rounds of
    :func:`planner.programme.run_rounds` (shares by need, then what is left to the pointings
    with a failed leg), as a plan job computes them.

    The whole plan ends within :func:`plan_limit_s`: a pointing's share is cut to what the
    limit has left when a slow machine left less (then the limit comes first). ``on_stage``
    hears each stage as it begins (:mod:`planner.stages`). The stats hold the plan's
    ``time_limit_advice`` (:func:`limit_advice`) when its limit left a pointing unplanned."""
    limit = plan_limit_s(req, budget_s)
    budget = Budget.start(limit - wall_reserve_s(limit, len(req.targets)))  # the wall clock: outside any effort block
    stage = Stages(on_stage)
    stage(stages.segmentation_stage(plan_mode(req)))
    seg = segment_plan(req, inst, limit)
    plan_locks.check_pointing_locks(req, seg, inst)
    progress(plan_progress(1, 0, 1))
    answers: dict[int, dict[str, Any]] = {}

    def report(round_: int, done: float, total: int) -> None:
        progress(plan_progress(round_, done, total))
        stage(stages.plan_stage(round_, done, total))

    from service.round_tasks import round_task  # it builds on this module's tasks

    def compute(tasks: Sequence[RoundTask]) -> list[PointingOutcome]:
        for done, task in enumerate(tasks):
            i = task.index
            answer = pointing_result(
                round_task(req, seg, task, inst, answers.get(i)), inst,
                lambda f, d=done, r=task.round: report(r, d + f, len(tasks)),
                wall_limit_s=max(budget.left_s(), 0.0))
            answers[i] = keep_better(answers.get(i), answer, i)
            report(task.round, done + 1, len(tasks))
        return [outcomes_of(answers[t.index], t.index)[-1] for t in tasks]

    history = run_rounds(pointing_needs(seg, req), rounds_limit_s(req, limit, seg), compute,
                         spend_margin=spends_margin(req))
    pointings = [answers[i] for i in range(len(seg.pointings))]
    advice = limit_advice(req, seg, pointings, history, limit, sync_limit_s(budget_s))
    from service.plan_consolidation import consolidated  # it plans pointings with this module

    seg, pointings, consolidation = consolidated(req, inst, seg, pointings, history, rounds_limit_s(req, limit, seg),
                                                 budget.left_s)
    stage(stages.ASSEMBLING)
    return seg, pointings, {
        **consolidation, "time_limit_s": limit, "budget_s": budget_s, "rounds": len(history),
        "elapsed_s": budget.elapsed_s(), **({} if advice is None else {"time_limit_advice": advice})}


def spends_margin(req: PlanRequest) -> bool:
    """Whether the plan's last steps spend the margin its rounds kept (a pointing with a
    failed leg first, :func:`planner.programme.margin_round`, then the consolidation):
    :func:`planner.consolidation.applies`."""
    return consolidation.applies(plan_mode(req), req.keep_configurations is not None)


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
                         plan_mode(req) == "fewest-exposures", n_targets=len(req.targets))
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


def plan(req: PlanRequest, inst: Instrument, progress: Progress = _noop, *,
         budget_s: float | None = None, on_stage: Stage = _no_stage) -> dict[str, Any]:
    """:func:`plan_pointings` as a PlanResponse dict. A motion leg that cannot be planned is
    returned with status "failed", never as an exception; the pointing and the plan then say
    ``executable: false`` with the reasons. ``on_stage`` hears the stages
    (:mod:`planner.stages`). The targets are first moved to the request's ``obs_date``
    (:func:`at_epoch`)."""
    req, epoch = at_epoch(req)
    req, excluded = plan_locks.without_excluded(req, inst)
    seg, pointings, stats = plan_pointings(req, inst, progress, budget_s=budget_s, on_stage=on_stage)
    stats = {**stats, **excluded}
    few = few_target_exposures(pointings, req.targets, inst, req.park_move_limit_s, left_out_of(stats))
    out = plan_out(seg, pointings, req.targets, {**stats, **epoch}, few)
    progress(1.0)
    return adapters.with_content_hash(out)


def run(kind: str, request: Any, inst: Instrument, progress: Progress = _noop,
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
