"""Request schemas of the v1 HTTP contract (pydantic v2), and the bases of every schema; the
responses are :mod:`service.response_schemas`.

Units are in the field names. Every float is finite (NaN and infinities are rejected),
so invalid input fails validation with HTTP 422 naming the field. Limits that depend on
the deployment (targets per stage, max time limit) are checked in ``service/limits.py``.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    ValidatorFunctionWrapHandler,
    field_validator,
    model_validator,
)

from models.instrument import CONFIGURATION_TIME_GOAL_S
from models.types import MAX_PRIORITY as PRIORITY_MAX
from planner.programme import DEFAULT_SEGMENTATION_MODE
from planner.sky import DEFAULT_SKY_RADIUS_ARCSEC, MAX_SKY_RADIUS_ARCSEC
from planner.telescope_time import DEFAULT_ACQUISITION_S, DEFAULT_EXPOSURE_TIME_S
from service import keep_schemas
from service.angle_schemas import (
    PA_DOC,
    PA_RANGE_DOC,
    PA_SEARCH_NEEDS_AUTO,
    PA_STEP_DOC,
    PlanPositionAngle,
    PositionAngleRange,
    PositionAngleStep,
    check_range,
    check_step,
)
from service.epoch_schemas import (
    OBS_DATE_DOC,
    PARALLAX_DOC,
    PMDEC_DOC,
    PMRA_DOC,
    REF_EPOCH_DOC,
    RV_DOC,
    ObsDate,
    ParallaxMas,
    PmMasYr,
    RadialVelocityKmS,
    RefEpochYr,
    check_obs_date,
)
from service.lock_schemas import EXCLUDED_DOC, LOCKED_DOC, ExcludedTargets, Locked
from service.schema_rules import (
    ONE_TARGET_SOURCE,
    SKY_NEEDS_POINTING,
    branch_errors,
    one_target_source,
    unique_arms,
    unique_arms_check,
    unique_ids,
)
from solvers.allocation.options import DEFAULT_SOLVER
from solvers.programme.segment import MAX_TARGETS

N_ARMS = 12
UNIQUE_ARMS = unique_arms(N_ARMS)
MAX_EXPOSURES = 10_000  # a plan's max_exposures at most
MAX_SKY_POSITIONS = 1_000  # a plan's sky_positions at most (a MOS sky list is 50-100 positions)


def _integral(v: Any) -> Any:
    """JSON has one number type: an integral float (``1.0``, ``1e3``) is that integer; a
    fractional one is an error naming the field (strings and booleans stay errors)."""
    if isinstance(v, float) and math.isfinite(v):
        if not v.is_integer():
            raise ValueError(f"must be an integer, got {v!r}")
        return int(v)
    return v


def Integer(**constraints: Any) -> Any:  # noqa: N802 - a type factory
    """A JSON integer with ``constraints`` (``ge``, ``le``, ``description``); integral floats
    are accepted."""
    return Annotated[int, Field(strict=True, **constraints), BeforeValidator(_integral)]


FiniteFloat = Annotated[float, Field(strict=True, allow_inf_nan=False)]
ArmIndex = Integer(ge=0, le=N_ARMS - 1, description="Arm number 0..11.")
Priority = Integer(ge=1, le=PRIORITY_MAX, description="Integer priority 1..2^32-1.")
TargetId = Annotated[str, Field(min_length=1, max_length=128, description="Unique target id.")]
RaDeg = Annotated[
    float, Field(ge=0.0, lt=360.0, strict=True, allow_inf_nan=False, description="Right ascension, deg.")
]
DecDeg = Annotated[
    float, Field(ge=-90.0, le=90.0, strict=True, allow_inf_nan=False, description="Declination, deg.")
]
AngleRad = Annotated[
    float, Field(ge=-1000.0, le=1000.0, strict=True, allow_inf_nan=False, description="Joint angle, rad.")
]
PositionAngleDeg = Annotated[
    float, Field(ge=-360.0, le=360.0, strict=True, allow_inf_nan=False, description="Position angle, deg.")
]
FocalMm = Annotated[
    float, Field(ge=-1e5, le=1e5, strict=True, allow_inf_nan=False, description="FOV-frame coordinate, mm.")
]
Seed = Integer(ge=0, le=2**31 - 1, description="Random seed.")
TimeLimitS = Annotated[
    float, Field(gt=0.0, le=86400.0, strict=True, allow_inf_nan=False, description="Solver time limit, s.")
]
BufferMm = Annotated[
    float, Field(ge=0.0, le=100.0, strict=True, allow_inf_nan=False, description="Collision buffer, mm.")
]
Method = Literal["ilp", "semigreedy"]
Solver = Literal["highs", "cpsat", "bnb"]  # bnb: exact bitset branch-and-bound (extension)
SOLVER_DESCRIPTION = (
    "Exact engine of method 'ilp' (thesis 5.4): 'cpsat' (OR-Tools CP-SAT), 'highs' (HiGHS) or 'bnb' "
    "(the bitset branch-and-bound alone, CP-SAT finishing proofs past its node limit). CP-SAT and "
    "HiGHS start from a branch-and-bound dive: its incumbent fixes the columns no better solution "
    f"uses and is their start. Default {DEFAULT_SOLVER!r} (solvers.allocation.options.DEFAULT_SOLVER)."
)
SegmentationMode = Literal["complete-linkage", "balanced", "fewest-exposures"]
Stats = dict[str, Any]


class Request(BaseModel):
    """Base of request bodies: unknown fields are an error (they are usually typos)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Response(BaseModel):
    model_config = ConfigDict(extra="allow")


TargetListId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[0-9A-Za-z_-]+$",
                                    description="Id of a stored target list "
                                    "(POST /v1/target-lists).")]
SKY_TARGETS_DOC = ("Sky targets; or give `target_list_id` instead (exactly one of the two).")
TARGET_LIST_DOC = ("A stored target list (POST /v1/target-lists) instead of `targets`; the "
                   "request is then held to the same limits as with the list's targets inline.")


# ------------------------------------------------------------------------ shared parts


class ArmState(Request):
    """Joint configuration of one arm."""

    arm: ArmIndex
    theta1_rad: AngleRad
    theta2_rad: AngleRad


class SkyTarget(Request):
    id: TargetId
    ra_deg: RaDeg
    dec_deg: DecDeg
    priority: Priority
    pmra_mas_yr: PmMasYr | None = Field(None, description=PMRA_DOC)
    pmdec_mas_yr: PmMasYr | None = Field(None, description=PMDEC_DOC)
    parallax_mas: ParallaxMas | None = Field(None, description=PARALLAX_DOC)
    radial_velocity_km_s: RadialVelocityKmS | None = Field(None, description=RV_DOC)
    ref_epoch_yr: RefEpochYr | None = Field(None, description=REF_EPOCH_DOC)


class PlaneTarget(Request):
    """A target already on the focal plane (FOV frame, mm)."""

    id: TargetId
    x_mm: FocalMm
    y_mm: FocalMm
    priority: Priority


class SkyPoint(Request):
    ra_deg: RaDeg
    dec_deg: DecDeg


class TelescopePointing(Request):
    ra_deg: RaDeg
    dec_deg: DecDeg
    position_angle_deg: PositionAngleDeg = 0.0


# ------------------------------------------------------------------------- requests


class SkyTargetSource(Request):
    """Sky targets given inline (``targets``) or as a stored list (``target_list_id``): exactly one."""

    model_config = ConfigDict(json_schema_extra=ONE_TARGET_SOURCE)

    targets: list[SkyTarget] | None = Field(None, min_length=1, description=SKY_TARGETS_DOC)
    target_list_id: TargetListId | None = Field(None, validate_default=True,
                                                description=TARGET_LIST_DOC)

    @field_validator("targets")
    @classmethod
    def _ids_unique(cls, v: list[Any] | None) -> list[Any] | None:
        return None if v is None else unique_ids(v)

    @field_validator("target_list_id")
    @classmethod
    def _one_source(cls, v: str | None, info: ValidationInfo) -> str | None:
        return one_target_source(v, info)


class SegmentationRequest(SkyTargetSource):
    threshold_mm: Annotated[float, Field(gt=0.0, le=1e4, strict=True, allow_inf_nan=False)] | None = Field(
        None, description="Complete-linkage threshold, mm; default sqrt(3) * FOV radius."
    )
    tangent_point: SkyPoint | None = Field(
        None, description="Tangent point of the projection; default the field's centre."
    )
    mode: SegmentationMode = Field(
        "complete-linkage",
        description="'complete-linkage' (thesis ch. 4), 'balanced' (fewer, more even pointings) or "
                    "'fewest-exposures' (the programme optimiser: pointings, position angles and "
                    "members with the fewest exposures, and a proven lower bound on them).",
    )
    seed: Seed | None = None
    obs_date: ObsDate | None = Field(None, description=OBS_DATE_DOC)

    _obs_date = field_validator("obs_date")(check_obs_date)


class AllocationRequest(Request):
    model_config = ConfigDict(json_schema_extra=SKY_NEEDS_POINTING)

    targets: (Annotated[list[PlaneTarget], Field(min_length=1)]
              | Annotated[list[SkyTarget], Field(min_length=1)]) = Field(
        description="Focal-plane targets, or sky targets (then `pointing` is required).",
    )
    pointing: TelescopePointing | None = Field(
        None, description="Telescope pointing; required when `targets` are sky targets."
    )
    method: Method = "ilp"
    solver: Solver = Field(DEFAULT_SOLVER, description=SOLVER_DESCRIPTION)
    configurations: Literal["one", "all"] = "one"
    time_limit_s: TimeLimitS | None = None
    seed: Seed | None = None
    collision_buffer_mm: BufferMm | None = None
    start: list[ArmState] | None = Field(
        None, max_length=N_ARMS, json_schema_extra=UNIQUE_ARMS,
        description="Current configuration of some or all arms, each arm at most once."
    )
    disabled_arms: list[ArmState] | None = Field(
        None, max_length=N_ARMS, json_schema_extra=UNIQUE_ARMS,
        description="Arms out of service, fixed at these angles, each arm at most once."
    )
    locked: Locked | None = Field(None, description=LOCKED_DOC)
    excluded_targets: ExcludedTargets | None = Field(None, description=EXCLUDED_DOC)

    @field_validator("targets", mode="wrap")
    @classmethod
    def _one_branch(cls, v: Any, handler: ValidatorFunctionWrapHandler) -> Any:
        """Errors of the kind of targets given only: sky targets when the first item has
        ``ra_deg`` or ``dec_deg``, focal-plane targets otherwise (named ``targets[i].field``,
        without the other kind's irrelevant complaints)."""
        try:
            return handler(v)
        except ValidationError as exc:
            raise branch_errors(exc, v) from None

    @field_validator("targets")
    @classmethod
    def _ids_unique(cls, v: list[Any]) -> list[Any]:
        return unique_ids(v)

    @field_validator("start")
    @classmethod
    def _start_unique(cls, v: list[ArmState] | None) -> list[ArmState] | None:
        return unique_arms_check(v, "start")

    @field_validator("disabled_arms")
    @classmethod
    def _disabled_unique(cls, v: list[ArmState] | None) -> list[ArmState] | None:
        return unique_arms_check(v, "disabled_arms")

    @model_validator(mode="after")
    def _pointing_for_sky(self) -> AllocationRequest:
        if self.targets and isinstance(self.targets[0], SkyTarget) and self.pointing is None:
            raise ValueError("pointing: required when targets are sky targets (ra_deg/dec_deg)")
        return self

    @property
    def sky(self) -> bool:
        return bool(self.targets) and isinstance(self.targets[0], SkyTarget)


class MotionPlanRequest(Request):
    start: list[ArmState] = Field(min_length=N_ARMS, max_length=N_ARMS, json_schema_extra=UNIQUE_ARMS,
                                  description="Every arm once: where the motion starts.")
    goal: list[ArmState] = Field(min_length=N_ARMS, max_length=N_ARMS, json_schema_extra=UNIQUE_ARMS,
                                 description="Every arm once: where the motion ends.")
    dt_s: Annotated[float, Field(ge=0.1, le=600.0, strict=True, allow_inf_nan=False)] | None = Field(
        None, description="Planning time step, s (default 6; at least 0.1)."
    )
    dt_col_s: Annotated[float, Field(ge=0.01, le=60.0, strict=True, allow_inf_nan=False)] | None = Field(
        None, description="Collision-check time step, s (default 0.1; at least 0.01). The product "
        "(220 s / dt_s) x (220 s / dt_col_s) may not exceed 1e6: smaller steps are refused with 422."
    )
    max_start_stop: Integer(ge=0, le=20) | None = Field(
        None, description="Most intermediate stops per arm (default 1)."
    )
    collision_buffer_mm: BufferMm | None = None
    seed: Seed | None = None
    time_limit_s: TimeLimitS | None = None

    @field_validator("start")
    @classmethod
    def _start_unique(cls, v: list[ArmState]) -> list[ArmState]:
        return unique_arms_check(v, "start") or []

    @field_validator("goal")
    @classmethod
    def _goal_unique(cls, v: list[ArmState]) -> list[ArmState]:
        return unique_arms_check(v, "goal") or []


class PlanRequest(SkyTargetSource):
    model_config = ConfigDict(json_schema_extra={**ONE_TARGET_SOURCE, **PA_SEARCH_NEEDS_AUTO})

    obs_date: ObsDate | None = Field(None, description=OBS_DATE_DOC)
    _obs_date = field_validator("obs_date")(check_obs_date)
    method: Method = "ilp"
    solver: Solver = Field(DEFAULT_SOLVER, description=SOLVER_DESCRIPTION)
    position_angle_deg: PlanPositionAngle = Field(0.0, description=PA_DOC)
    position_angle_range_deg: PositionAngleRange | None = Field(None, description=PA_RANGE_DOC)
    position_angle_step_deg: PositionAngleStep | None = Field(None, description=PA_STEP_DOC)
    _pa_range = field_validator("position_angle_range_deg")(check_range)
    _pa_step = field_validator("position_angle_step_deg")(check_step)
    time_limit_s: TimeLimitS | None = Field(
        None, description="Wall-clock limit of the whole plan, s (its one meaning): "
        "segmentation, then every pointing's allocation and motion legs. The pointings share it "
        "by their size (targets), fixed before any runs, so the plan is the same on any number "
        "of workers; what a pointing leaves unused goes, in later rounds, to the pointings with "
        "a leg not yet planned. Default (and cap) the server's budget: MXS_PLAN_BUDGET_S "
        "(120 s) for POST /v1/plans, MXS_JOB_BUDGET_S for a plan job. A pointing whose share "
        "is under 0.5 s reports its targets `no_time`; plan big fields with POST /v1/jobs."
    )
    seed: Seed | None = None
    locked: Locked | None = Field(None, description=LOCKED_DOC)
    excluded_targets: ExcludedTargets | None = Field(None, description=EXCLUDED_DOC)
    threshold_mm: Annotated[float, Field(gt=0.0, le=1e4, strict=True, allow_inf_nan=False)] | None = Field(
        None, description="Segmentation threshold, mm (default sqrt(3) * FOV radius)."
    )
    segmentation_mode: SegmentationMode | None = Field(
        None, description=f"How the field is split into pointings (see `SegmentationRequest.mode`); "
                          f"null: '{DEFAULT_SEGMENTATION_MODE}' for programmes of at most "
                          f"{MAX_TARGETS:,} targets, 'complete-linkage' beyond.")
    keep_configurations: keep_schemas.KeepConfigurations | None = Field(
        None, description=keep_schemas.KEEP_DOC)
    park_move_limit_s: Annotated[float, Field(gt=0.0, le=86400.0, strict=True, allow_inf_nan=False)] | None = Field(
        CONFIGURATION_TIME_GOAL_S, description="Every target is observed from a location its arm reaches from "
        "park within this many seconds turning J2 the positive way (the way an arm leaves park without "
        "sweeping its neighbour), so that no move from park takes longer than the instrument's "
        "configuration time goal (thesis T_p = 120 s, the default). A target reached only farther away "
        "is reported with reason 'beyond_park_move_limit'. null: no limit (every reachable target, "
        "some moves from park then take up to 200 s)."
    )
    exposure_time_s: Annotated[float, Field(gt=0.0, le=86400.0, strict=True, allow_inf_nan=False)] = Field(
        DEFAULT_EXPOSURE_TIME_S, description="Exposure time of one configuration, s: the plan's telescope "
        "time counts it once per exposure (`stats.telescope_time`)."
    )
    acquisition_s: Annotated[float, Field(ge=0.0, le=86400.0, strict=True, allow_inf_nan=False)] = Field(
        DEFAULT_ACQUISITION_S, description="Acquisition overhead of one pointing (slew, acquisition, fine "
        "positioning of the arms), s: the plan's telescope time counts it once per pointing that has an "
        "exposure."
    )
    max_exposures: Integer(ge=1, le=MAX_EXPOSURES) | None = Field(
        None, description="Stop rule: at most this many exposures (configurations) over the whole plan, "
        "spent on the highest priorities. It is split over the pointings in proportion to their estimated "
        "exposures, each pointing at least one while there are enough; a pointing given none is not "
        "attempted. Targets left out for it are reported with reason 'beyond_max_exposures'. null (the "
        "default): no limit, every target that can be observed is."
    )
    min_priority_per_exposure: Integer(ge=1, le=N_ARMS * PRIORITY_MAX) | None = Field(
        None, description="Stop rule: no exposure observes targets of less summed priority than this; "
        "the targets of the exposures not opened are reported with reason 'below_exposure_threshold'. "
        "null (the default): none."
    )
    min_targets_per_exposure: Integer(ge=1, le=N_ARMS) | None = Field(
        None, description="Stop rule: no exposure observes fewer targets than this; the targets of the "
        "exposures not opened are reported with reason 'below_exposure_threshold'. null (the default): "
        "none."
    )
    sky_positions: Annotated[list[SkyPoint], Field(max_length=MAX_SKY_POSITIONS)] | None = Field(
        None, description="Sky positions (ICRS RA/Dec, deg) for the spare arms: after the science targets "
        "of a configuration are allocated, every arm without a target is placed on one of these (projected "
        "into the pointing's focal plane; nearest its previous place first) where it fits without a "
        "collision, else on blank sky the planner picks, else at park. A position closer than "
        "sky_radius_arcsec to any target of the request is not used (a notice names it). null (the "
        "default): blank sky only."
    )
    sky_radius_arcsec: Annotated[float, Field(ge=0.0, le=MAX_SKY_RADIUS_ARCSEC, strict=True,
                                              allow_inf_nan=False)] = Field(
        DEFAULT_SKY_RADIUS_ARCSEC, description="Least distance (arcsec) of a spare arm's sky position from "
        "every target of the request (all pointings), for sky_positions and blank sky alike. Default "
        f"{DEFAULT_SKY_RADIUS_ARCSEC:g} arcsec (5 mm at 1.2 arcsec/mm): the probe field's half-diagonal "
        "(1.94 arcsec of 3.7 x 1.2, thesis table 2.1) plus twice the 1.2 arcsec seeing the slicer is "
        f"built for, rounded up (docs/allocation.md, 'Sky positions'); at most {MAX_SKY_RADIUS_ARCSEC:g} "
        "(the FOV's diameter)."
    )


REQUEST_TYPES: dict[str, type[Request]] = {
    "segmentation": SegmentationRequest,
    "allocation": AllocationRequest,
    "motion-plan": MotionPlanRequest,
    "plan": PlanRequest,
}
