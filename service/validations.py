"""``POST /v1/validations``: re-check a plan file (:func:`planner.validate.validate_plan`).

The body is a plan as ``POST /v1/plans``, a plan job or ``mxs-planner plan`` wrote it, taken
as raw JSON (not reshaped by the PlanResponse model) so that its content hash is checked
against exactly what was sent. The check runs as a heavy request (a slot of the bounded
executor and its worker process, 503 with ``Retry-After`` when every slot is taken, stopped
when the client leaves, killed beyond ``MXS_MAX_TIME_LIMIT_S``); the body is held to
``MXS_MAX_JOB_BODY_BYTES`` (a plan job's result can be large). A body that is not a plan (a
field missing or of the wrong type) is a 422 naming the field; a plan that fails a check is a
200 with ``valid: false`` and the violations.
"""

from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import APIRouter, Body, Request
from fastapi.responses import Response as HttpResponse
from pydantic import Field

from models.errors import InputError
from models.instrument import Instrument
from service.auth import Auth
from service.errors import FieldError
from service.heavy_answer import answer_heavy
from service.schemas import Response

router = APIRouter(tags=["validation"])


class ViolationOut(Response):
    """One failed check; `configuration` and `leg` counted from 1 (leg 1: park -> c1)."""

    pointing: str | None = Field(description="Pointing id; null for the plan as a whole (hash, "
                                 "executable).")
    configuration: int | None = Field(description="Configuration c<k> of the pointing, k from 1.")
    leg: int | None = Field(description="Motion leg, from 1: leg k goes c<k-1> -> c<k> (c0 and "
                            "c<n+1>: park).")
    arm: int | None = Field(description="Arm concerned (the first of a colliding pair).")
    kind: str = Field(description="Which check: 'hash', 'structure', 'geometry' (tip not where "
                      "the assignment says), 'target' (tip not on the target's position from "
                      "its RA/Dec), 'joint_limit', 'zoa', 'collision', 'start', 'goal', 'speed', "
                      "'stops', 'commands', 'makespan', 'executable'.")
    message: str


class ValidationResponse(Response):
    valid: bool = Field(description="The hash matches and every check passed.")
    hash_ok: bool = Field(description="`content_hash` matches the plan's canonical JSON.")
    executable: bool = Field(description="Every motion leg of every pointing is planned (the "
                             "plan says so and its legs agree).")
    violations: list[ViolationOut] = Field(description="The first failed checks (at most 100).")
    violations_total: int = Field(ge=0, description="Failed checks in all.")
    checked: dict[str, int] = Field(description="What was checked: pointings, configurations, "
                                    "assignments, targets, legs, legs_failed (not planned, not "
                                    "checked), trajectories, waypoints, samples (time samples "
                                    "of the re-simulation) and pair_samples (arm-pair clearances "
                                    "computed).")


PLAN_BODY = ("A plan: the JSON answer of `POST /v1/plans` (PlanResponse), a plan job's `result`, "
             "or the CLI's plan.json, as written.")


def field_loc(field: str) -> tuple[str | int, ...]:
    """``"pointings[0].motions[2].status"`` -> ``("body", "pointings", 0, "motions", 2, "status")``."""
    loc: list[str | int] = ["body"]
    for name, index in re.findall(r"([^.\[\]]+)|\[(\d+)\]", field):
        loc.append(int(index) if index else name)
    return tuple(loc)


def validation(plan: Any, inst: Instrument, progress: Any) -> dict[str, Any]:
    """The ValidationResponse dict of ``plan`` (a 422 naming the field when it is no plan)."""
    from planner.validate import validate_plan
    from service.adapters import plain

    try:
        report = validate_plan(inst, plan, progress)
    except InputError as exc:
        raise FieldError(field_loc(exc.field), exc.message) from None
    return plain(report)


@router.post("/v1/validations", operation_id="create_validation", response_model=ValidationResponse,
             dependencies=[Auth])
async def create_validation(
    request: Request,
    plan: Annotated[dict[str, Any], Body(description=PLAN_BODY)],
) -> HttpResponse:
    """Re-check a plan file with the independent verifier: every configuration (each tip on
    its target's focal-plane position recomputed from the target's RA/Dec, the pointing's
    centre and position angle; joint limits, zone of avoidance, every arm pair's clearance
    >= the collision buffer), every motion leg park -> c1 -> ... -> park (starts and ends,
    joint limits and zone of avoidance along it, joint speeds, clearance every 10 ms,
    start-stop cycles, controller commands) and the `content_hash`. A plan whose checks pass
    answers `valid: true`; a plan that says `executable: false` is checked for what it holds
    and answers `executable: false`. The checks and tolerances: docs/validation.md."""
    return await answer_heavy(request, request.app.state.mxs, ValidationResponse, validation, plan)
