"""Request checks that the schemas cannot make: this server's limits and its instrument.

:func:`check_request` is the one check a stage request passes before any work is admitted,
whether it comes to its own endpoint (``POST /v1/allocations`` ...) or inside a job
(``POST /v1/jobs``): a job is refused with the same 422, naming the same field (under
``body.request``), as the endpoint would give, instead of being accepted and failing later.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from models.instrument import Instrument
from service import pointing_plans
from service.errors import FieldError
from service.schemas import AllocationRequest, ArmState, PlanRequest, SegmentationRequest
from service.settings import Settings

Loc = tuple[str | int, ...]


_STAGES: dict[type, str] = {SegmentationRequest: "segmentation",
                            AllocationRequest: "allocation", PlanRequest: "plan"}


def check_request(req: Any, settings: Settings, inst: Instrument,
                  prefix: Loc = ("body",), *, job: bool = False) -> float:
    """Raise :class:`FieldError` (422) for what this deployment refuses; return the solver
    time limit to use (the request's, else the server default). ``job``: the request runs as
    a job (a plan job has its own target limit). A request naming a stored list must have
    been resolved (:func:`service.target_lists.resolve`) first."""
    _check_targets(req, settings, prefix, job)
    limit = getattr(req, "time_limit_s", None)
    if limit is not None and limit > settings.max_time_limit_s:
        raise FieldError((*prefix, "time_limit_s"),
                         f"must be <= {settings.max_time_limit_s} s on this server",
                         "less_than_equal")
    threshold = getattr(req, "threshold_mm", None)
    diameter_mm = 2.0 * inst.fov_radius_mm
    if threshold is not None and threshold > diameter_mm:
        raise FieldError((*prefix, "threshold_mm"),
                         f"{threshold} mm is larger than the FOV diameter {diameter_mm} mm: "
                         "targets that far apart can never share a pointing", "less_than_equal")
    for name in ("start", "goal", "disabled_arms"):
        _check_arms(getattr(req, name, None), inst, (*prefix, name))
    _check_projection(req, inst, prefix)
    return float(limit if limit is not None else settings.default_time_limit_s)


def _check_targets(req: Any, settings: Settings, prefix: Loc, job: bool) -> None:
    """The stage's target limit, named with its setting (``MXS_MAX_<STAGE>_TARGETS``)."""
    targets = getattr(req, "targets", None)
    stage = _STAGES.get(type(req))
    if targets is None or stage is None:
        return
    stage = "plan-job" if stage == "plan" and job else stage
    most, setting = settings.target_limit(stage)
    if len(targets) > most:
        what = {"plan-job": "plan job", "plan": "synchronous plan (POST /v1/plans; plan "
                "bigger fields as a job)"}.get(stage, stage)
        raise FieldError((*prefix, "targets"), f"at most {most} targets per {what} on this "
                         f"server ({setting}={most}), got {len(targets)}", "too_long")


def _check_projection(req: Any, inst: Instrument, prefix: Loc) -> None:
    """Sky targets of an allocation must project about its pointing (< 90 deg away): the
    same 422 as the endpoint's, before a job is queued."""
    pointing = getattr(req, "pointing", None)
    if not getattr(req, "sky", False) or pointing is None:
        return
    try:
        pointing_plans.sky_to_focal(req.targets, pointing.ra_deg, pointing.dec_deg, inst, pointing.position_angle_deg)
    except FieldError as exc:
        raise FieldError((*prefix, *exc.loc[1:]), exc.bare, exc.type) from exc


def _check_arms(states: Sequence[ArmState] | None, inst: Instrument, loc: Loc) -> None:
    for i, s in enumerate(states or ()):
        if s.arm >= inst.n_arms:
            raise FieldError((*loc, i, "arm"), f"the instrument has arms 0..{inst.n_arms - 1}")
