"""The domain's checks of a stage request, run before its work is admitted.

:func:`check_stage` builds what each stage hands the domain, with the very functions the
stage itself uses (:mod:`service.pipeline`, :mod:`service.adapters`), and runs the
domain's own input checks, without the computation: a segmentation's or plan's field
(:func:`solvers.segmentation.field_plane`: targets spread over the whole sphere, a target
>= 90 deg from the tangent point), an allocation's arms and sky projection, a motion
plan's configurations and sampling options. ``POST /v1/<stage>`` and ``POST /v1/jobs``
both call it at submission, so a job is refused with the endpoint's 422, naming the same
field under its own prefix, instead of being queued and failing later.

Together with the request schema and :func:`service.limits.check_request` (this server's
limits), it is everything a stage request is checked against before its work starts.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from models.errors import InputError
from models.instrument import Instrument
from service import adapters, pipeline, plan_locks, pointing_plans
from service.errors import FieldError, parse_loc
from service.schemas import (
    AllocationRequest,
    MotionPlanRequest,
    PlanRequest,
    SegmentationRequest,
)
from solvers.segmentation import field_plane

Loc = tuple[str | int, ...]


def _segmentation(req: SegmentationRequest, inst: Instrument) -> None:
    field_plane(**pipeline.field_args(req, inst))


def _plan(req: PlanRequest, inst: Instrument) -> None:
    req, _ = plan_locks.without_excluded(req, inst)  # the locks' and exclusions' own checks
    _segmentation(pipeline.plan_segmentation(req), inst)


def _allocation(req: AllocationRequest, inst: Instrument) -> None:
    adapters.check_arms(req.start, inst, "start")
    adapters.check_arms(req.disabled_arms, inst, "disabled_arms")
    if req.sky and req.pointing is not None:
        p = req.pointing
        targets = pointing_plans.sky_plane_targets(req.targets, p.ra_deg, p.dec_deg, inst,  # type: ignore[arg-type]
                                             p.position_angle_deg)
    else:
        targets = adapters.plane_targets_of(req.targets)  # type: ignore[arg-type]
    plan_locks.check_allocation_locks(req, targets, inst)


def _motion_plan(req: MotionPlanRequest, inst: Instrument) -> None:
    adapters.full_configuration(req.start, inst, "start")
    adapters.full_configuration(req.goal, inst, "goal")
    pipeline.motion_options(req)


_CHECKS: dict[type, Callable[[Any, Instrument], None]] = {
    SegmentationRequest: _segmentation,
    PlanRequest: _plan,
    AllocationRequest: _allocation,
    MotionPlanRequest: _motion_plan,
}


def check_stage(req: Any, inst: Instrument, prefix: Loc = ("body",)) -> None:
    """Raise :class:`FieldError` (422, ``loc`` under ``prefix``) for what the stage's domain
    refuses in ``req``; return when it would start the work. A request naming a stored
    list must have been resolved (:func:`service.target_lists.resolve`) first."""
    check = _CHECKS.get(type(req))
    if check is None:
        return
    try:
        check(req, inst)
    except FieldError as exc:  # the stage's own 422, named under "body"
        raise FieldError((*prefix, *exc.loc[1:]), exc.bare, exc.type) from exc
    except InputError as exc:  # the domain's, naming the request's field
        raise FieldError((*prefix, *parse_loc(str(exc.field))), exc.message) from exc
