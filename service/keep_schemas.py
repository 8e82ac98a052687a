"""The ``keep_configurations`` field of a plan request (:mod:`service.schemas` uses it):
configurations c1..ck of a previous plan's pointings, kept as they were while the rest is
planned again (:mod:`planner.keep` checks and uses them)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from service.lock_schemas import _integral

N_ARMS = 12
MAX_KEPT_POINTINGS = 1_000
MAX_KEPT_CONFIGURATIONS = 10_000
MAX_KEPT_MEMBERS = 100_000


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def _float(lo: float, hi: float, description: str) -> object:
    return Annotated[float, Field(ge=lo, le=hi, strict=True, allow_inf_nan=False, description=description)]


class KeptAssignment(_In):
    """One arm of a kept configuration: an entry of the previous plan's
    ``ConfigurationOut.assignments`` (its ``x_mm``, ``y_mm`` and ``kind`` may be sent as they
    are: x/y are checked against the joint angles)."""

    arm: Annotated[int, Field(ge=0, le=N_ARMS - 1, strict=True), BeforeValidator(_integral)] = Field(
        description="Arm number 0..11.")
    target_id: Annotated[str, Field(min_length=1, max_length=128)] | None = Field(
        None, description="The target the arm observes (a member of the pointing); null: idle (park, blank sky).")
    theta1_rad: _float(-1000.0, 1000.0, "Joint angle J1, rad, as in the previous plan.")  # type: ignore[valid-type]
    theta2_rad: _float(-1000.0, 1000.0, "Joint angle J2, rad, as in the previous plan.")  # type: ignore[valid-type]
    x_mm: _float(-1e5, 1e5, "Tip x, mm (optional; must be the tip of the joint angles).") | None = None  # type: ignore[valid-type]
    y_mm: _float(-1e5, 1e5, "Tip y, mm (optional; must be the tip of the joint angles).") | None = None  # type: ignore[valid-type]
    kind: Literal["target", "park", "blank", "fixed", "sky"] | None = Field(
        None, description="As in the previous plan (optional; null: 'target' with a target, else "
        "'park' at the park angles, else 'blank').")


KeptConfiguration = Annotated[list[KeptAssignment], Field(min_length=1, max_length=64, description=(
    "One configuration: one entry per arm."))]


class KeptPointingIn(_In):
    """A previous plan's pointing (a ``PlanPointing``) whose first configurations are kept."""

    id: Annotated[str, Field(min_length=1, max_length=64)] = Field(
        description="The previous plan's pointing id; the answer keeps it.")
    ra_deg: _float(0.0, 360.0, "Pointing centre, RA, deg (the previous plan's).")  # type: ignore[valid-type]
    dec_deg: _float(-90.0, 90.0, "Pointing centre, Dec, deg (the previous plan's).")  # type: ignore[valid-type]
    position_angle_deg: _float(-360.0, 360.0, "Position angle the previous plan used, deg; "  # type: ignore[valid-type]
                               "null: the request's `position_angle_deg`.") | None = None
    target_ids: list[Annotated[str, Field(min_length=1, max_length=128)]] = Field(
        min_length=1, max_length=MAX_KEPT_MEMBERS,
        description="The pointing's members (the previous plan's `target_ids`): each a target of "
        "the request, in no other kept pointing. Those its kept configurations do not observe are "
        "allocated again in this pointing, after them.")
    configurations: list[KeptConfiguration] = Field(
        min_length=1, max_length=MAX_KEPT_CONFIGURATIONS,
        description="c1..ck of the pointing, in order: kept as given (arms, targets, joint angles) "
        "and checked again (one entry per arm, joint angles outside the zone of avoidance, each "
        "observing arm's tip on its target, no target twice, no two arms closer than the "
        "collision buffer).")


KEEP_DOC = ("Keep configurations c1..ck of a previous plan's pointings as they were and plan the "
            "rest again: each kept pointing is reused as it is (centre, position angle, members), "
            "its kept configurations come first, its other members are allocated from ck's arm "
            "states, and every motion leg park -> c1 -> ... -> park is planned and verified as "
            "usual (the motion planner never changes a kept configuration). Request targets in no "
            "kept pointing are segmented as usual into pointings after the kept ones. Build it "
            "from a previous PlanResponse (CLI: `--keep plan.json:K`). null (the default): "
            "nothing kept.")


class KeepConfigurations(_In):
    """Configurations of a previous plan to keep (``PlanRequest.keep_configurations``)."""

    pointings: list[KeptPointingIn] = Field(min_length=1, max_length=MAX_KEPT_POINTINGS,
                                            description="The kept pointings, in the order the plan "
                                            "lists them.")
