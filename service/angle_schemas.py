"""The position angle fields of the v1 schemas (:mod:`service.schemas` uses them): a plan's
``position_angle_deg`` (a number or "auto"), the range and step of the "auto" search, and each
pointing's ``position_angle_search`` in the answer. The search itself is
:mod:`solvers.programme.angle`."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationInfo

from models.errors import InputError
from solvers.programme.angle import DEFAULT_STEP_DEG, OBJECTIVE, check_search

AUTO = "auto"
ANGLE_LIMIT_DEG = 360.0

PA_DOC = (
    "Position angle of the instrument, deg East of North, in [-360, 360]; or \"auto\". A number: "
    "every pointing is observed at that angle (mode 'fewest-exposures' turns a pointing away from "
    "it, to the nearest angle every 5 deg, only when the angle loses targets to arm reach within "
    "the park move limit). \"auto\": every pointing takes, of the angles of "
    "`position_angle_range_deg` every `position_angle_step_deg`, the best by this objective: "
    + OBJECTIVE + ". Each pointing reports its angle in `position_angle_deg` and how it was "
    "chosen in `position_angle_search`. Default 0.")
PA_RANGE_DOC = (
    "With `position_angle_deg` \"auto\": the angles searched, [min_deg, max_deg] (both in "
    "[-360, 360], min <= max, both ends included); ties go to the angle nearest the range's "
    "centre. null (the default): any angle, [0, 360), ties to the angle nearest 0. Given with a "
    "numeric `position_angle_deg`: an error.")
PA_STEP_DOC = (
    f"With `position_angle_deg` \"auto\": the step between the angles searched, deg, in (0, 360]. "
    f"null (the default): {DEFAULT_STEP_DEG:g} deg, a sixth of the default instrument's arm pitch "
    "(30 deg), so that the search sees six placements of the arms relative to the targets (72 "
    "angles over a full turn, each one reachability evaluation of the pointing's targets). Given "
    "with a numeric `position_angle_deg`: an error.")


def _angle_or_auto(v: Any) -> Any:
    """A number of degrees in [-360, 360] or the string "auto"; anything else is a ValueError
    (422 naming the field) that says what is accepted."""
    if isinstance(v, str):
        if v == AUTO:
            return v
        raise ValueError(f"must be a number of degrees in [-360, 360] or \"auto\", got {v!r}")
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ValueError(f"must be a number of degrees in [-360, 360] or \"auto\", got {v!r}")
    if not (math.isfinite(v) and -ANGLE_LIMIT_DEG <= v <= ANGLE_LIMIT_DEG):
        raise ValueError(f"must be a number of degrees in [-360, 360] or \"auto\", got {v!r}")
    return float(v)


PlanPositionAngle = Annotated[
    Annotated[float, Field(ge=-ANGLE_LIMIT_DEG, le=ANGLE_LIMIT_DEG, allow_inf_nan=False)] | Literal["auto"],
    BeforeValidator(_angle_or_auto),
]
RangeEndDeg = Annotated[float, Field(ge=-ANGLE_LIMIT_DEG, le=ANGLE_LIMIT_DEG, strict=True, allow_inf_nan=False)]
PositionAngleRange = Annotated[list[RangeEndDeg], Field(min_length=2, max_length=2)]
PositionAngleStep = Annotated[float, Field(gt=0.0, le=360.0, strict=True, allow_inf_nan=False)]


#: JSON Schema of the rule "a range or a step only with \"auto\"" (allOf: it sits beside the
#: request's own if/then), so that what a client generates from the document is accepted
PA_SEARCH_NEEDS_AUTO: dict[str, Any] = {"allOf": [
    {"if": {"required": [name], "properties": {name: {"type": kind}}},
     "then": {"required": ["position_angle_deg"], "properties": {"position_angle_deg": {"const": AUTO}}}}
    for name, kind in (("position_angle_range_deg", "array"), ("position_angle_step_deg", "number"))]}


def check_range(v: list[float] | None, info: ValidationInfo) -> list[float] | None:
    """``position_angle_range_deg``: only with "auto", and not empty (min <= max)."""
    if v is None:
        return None
    if info.data.get("position_angle_deg", AUTO) != AUTO:
        raise ValueError("applies only with position_angle_deg \"auto\" (a number is the one angle used)")
    try:
        check_search(v, DEFAULT_STEP_DEG)
    except InputError as exc:
        raise ValueError(exc.message) from None
    return v


def check_step(v: float | None, info: ValidationInfo) -> float | None:
    """``position_angle_step_deg``: only with "auto"."""
    if v is not None and info.data.get("position_angle_deg", AUTO) != AUTO:
        raise ValueError("applies only with position_angle_deg \"auto\" (a number is the one angle used)")
    return v


class PositionAngleSearchOut(BaseModel):
    """How a pointing's position angle was chosen (:class:`solvers.programme.angle.AngleChoice`)."""

    model_config = ConfigDict(extra="allow")

    tried_deg: list[float] = Field(description="Every angle tried, deg, in the order tried.")
    chosen_deg: float = Field(description="The angle chosen, deg (the pointing's "
                              "`position_angle_deg`).")
    objective: str = Field(description="Why: the objective in words, the chosen angle's terms "
                           "(targets lost to arm reach, exposures by the arm-reach bound, priority "
                           "reached) and the term that settled it.")


PA_USED_DOC = ("The position angle this pointing is observed at, deg: the request's number, the "
               "angle mode 'fewest-exposures' turned it to, or the angle the \"auto\" search chose "
               "(inside `position_angle_range_deg` as given, e.g. -15 rather than 345).")
PA_SEARCH_DOC = ("How this pointing's `position_angle_deg` was chosen: with \"auto\", the search "
                 "over the range (every angle tried, the one chosen and why); with a number in "
                 "mode 'fewest-exposures', the angles tried about the requested one. null: the "
                 "request's angle, used as given.")
