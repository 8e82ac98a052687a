"""Request and response schemas of the v1 HTTP contract (pydantic v2).

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
    PA_SEARCH_DOC,
    PA_SEARCH_NEEDS_AUTO,
    PA_STEP_DOC,
    PA_USED_DOC,
    PlanPositionAngle,
    PositionAngleRange,
    PositionAngleSearchOut,
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
    EpochOut,
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


# ------------------------------------------------------------------------ responses


class Health(Response):
    status: Literal["ok"] = "ok"
    version: str


class Readiness(Response):
    status: Literal["ready", "not_ready"]
    version: str
    jobs: str = Field(description="State of the job database and workers.")
    heavy_in_use: int = Field(ge=0, description="Stage requests computing or waiting now.")
    heavy_capacity: int = Field(ge=1, description="Stage requests admitted at most at once.")


class ErrorResponse(Response):
    """Every non-validation error: a machine code and a human message."""

    error: str
    detail: str


class ValidationErrorItem(Response):
    """One invalid field: where (``loc``, starting with "body", "path" or "query"), why and
    the machine type of the error."""

    loc: list[str | int]
    msg: str
    type: str


class ValidationErrorResponse(Response):
    """HTTP 422: the request is invalid; ``detail[].loc`` names each field, ``message`` sums
    them up in one line ("body.targets[0].dec_deg: ...")."""

    detail: list[ValidationErrorItem]
    message: str


class JointPair(Response):
    theta1_rad: float
    theta2_rad: float


class BodyInfo(Response):
    name: str
    shape: str
    joint_from: str
    joint_to: str
    radius_mm: float
    width_mm: float
    height_mm: float


class ArmInfo(Response):
    arm: int
    enabled: bool
    base_x_mm: float
    base_y_mm: float
    orientation_rad: float
    d12_mm: float
    d13_mm: float
    d24_mm: float
    d3tip_mm: float
    stop_min_mm: float
    stop_max_mm: float
    theta1_min_rad: float
    theta1_max_rad: float
    joint1_speed_rad_s: float
    joint2_speed_rad_s: float
    park: JointPair
    bodies: list[BodyInfo]


class InstrumentInfo(Response):
    name: str
    source: str
    fov_diameter_mm: float
    plate_scale_arcsec_per_mm: float
    collision_buffer_mm: float
    joint_speed_rad_s: float
    arms: list[ArmInfo]


class PointingOut(Response):
    id: str
    ra_deg: float
    dec_deg: float
    x_mm: float
    y_mm: float
    radius_mm: float
    target_ids: list[str]
    position_angle_deg: float | None = Field(
        None, description="The pointing's position angle, deg, when the segmentation chose it "
                          "(mode 'fewest-exposures'); null: the request's.")
    only_here: list[str] = Field(
        default_factory=list, description="Targets of this pointing that no other pointing of "
        "the plan holds (mode 'fewest-exposures'): an exposure observing only a few targets is "
        "kept only for these.")


class TangentPoint(Response):
    ra_deg: float
    dec_deg: float


class SegmentationResponse(Response):
    tangent_point: TangentPoint
    pointings: list[PointingOut]
    stats: Stats = Field(default_factory=dict)


class AssignmentOut(Response):
    """Where one arm is in one configuration (tip position in the FOV frame)."""

    arm: int
    target_id: str | None = Field(description="Allocated target; null = parked / blank sky / fixed.")
    theta1_rad: float
    theta2_rad: float
    x_mm: float
    y_mm: float
    kind: Literal["target", "sky", "park", "fixed", "blank"] | None = Field(
        None,
        description="'target' (observes target_id); 'sky' (a spare arm on sky at least the plan's "
        "sky_radius_arcsec from every target, inside the FOV: sky_ra_deg/sky_dec_deg say where); 'park'; "
        "'fixed' (a disabled arm left where it is); 'blank' (a spare arm resting off park where no "
        "clear sky fits: closer than the radius to a target, or an allocation alone, which has no sky "
        "to check against).",
    )
    sky_ra_deg: float | None = Field(None, description="A 'sky' arm: the RA (ICRS, deg) its tip points "
                                     "at (the focal-plane tip through the pointing's projection); "
                                     "null otherwise.")
    sky_dec_deg: float | None = Field(None, description="A 'sky' arm: the Dec (ICRS, deg) its tip points "
                                      "at; null otherwise.")


class OnlyHereOut(Response):
    target_id: str
    reason: Literal["outside_other_fields", "no_spare_arm", "takers_observe_fewer"] = Field(
        description="'outside_other_fields': no other exposure's field of view holds the target; "
                    "'no_spare_arm': no other exposure whose field holds it has an idle arm (at "
                    "park, on blank sky or on a sky position) that reaches it within the park move "
                    "limit without coming closer to another arm than the collision buffer; "
                    "'takers_observe_fewer' (a target of an exposure observing 2): the only "
                    "exposures that can take it observe 1 target, so moving it there would leave "
                    "as many exposures observing few targets.")


class ConfigurationOut(Response):
    index: int
    status: Literal["optimal", "feasible"]
    total_priority: int = Field(description="Sum of the allocated targets' priorities (exact).")
    arm_yield: int = Field(description="Arms observing a target.")
    assignments: list[AssignmentOut] = Field(description="One entry per arm, sorted by arm.")
    stats: Stats = Field(default_factory=dict, description="Solve time, solver status, "
                         "longest move (s) of this configuration.")


class Unallocated(Response):
    target_id: str
    reason: str = Field(description="Why: 'unreachable', 'conflict', 'no_time', 'not_scheduled' "
                        "(left for configurations the request did not ask for, e.g. with "
                        "configurations 'one'), 'beyond_park_move_limit' (in a plan: reached "
                        "only by a move from park longer than park_move_limit_s), "
                        "'beyond_max_exposures' (in a plan: the request's max_exposures left no "
                        "exposure for it), 'below_exposure_threshold' (in a plan: the exposure "
                        "that would observe it is below min_priority_per_exposure or "
                        "min_targets_per_exposure), ...; in a plan also the reason a target was "
                        "dropped so that every motion leg can be executed; 'excluded' (the "
                        "request's excluded_targets); a locked target's reason is prefixed "
                        "'locked_' (e.g. 'locked_no_time': its lock kept it from every other arm).")


COMPLETENESS = (
    "`n_targets` (every target of the request), `n_reachable` / `n_unreachable` (targets some "
    "enabled arm reaches / none does), `n_allocated` (targets in a configuration); "
    "`field_completeness` = n_allocated / n_targets and `priority_completeness` = allocated "
    "priority / the priority of every target: an unreachable target counts as not observed, "
    "so neither is 1 while a target is unreachable. `stop_reason`, lower bounds on the "
    "number of configurations, timers.")


class AllocationResponse(Response):
    configurations: list[ConfigurationOut]
    unallocated: list[Unallocated]
    stats: Stats = Field(default_factory=dict, description=COMPLETENESS)


class Waypoint(Response):
    t_s: float
    theta1_rad: float
    theta2_rad: float


class Command(Response):
    joint: Literal[1, 2]
    t_start_s: float
    from_rad: float
    to_rad: float
    speed_rad_s: float


class Trajectory(Response):
    arm: int
    waypoints: list[Waypoint]
    commands: list[Command]


class MotionPlanResponse(Response):
    status: Literal["ok", "failed"]
    makespan_s: float | None = Field(description="Time until every arm is at rest at its goal, s.")
    trajectories: list[Trajectory]
    failed_arms: list[int]
    stats: Stats = Field(default_factory=dict)


class PlanChangeOut(Response):
    """One change the motion planner made to a pointing's allocation so that every motion
    leg can be executed."""

    kind: str = Field(description="'via_park' (the leg goes through the park configuration), "
                      "'rest_to_park' (idle arms rest at park instead of on blank sky), "
                      "'other_branch' (an arm reaches its target through another IK branch), "
                      "'moved_target' (blocking targets moved to another configuration), "
                      "'new_configuration' (a configuration added at the end of the sequence) "
                      "or 'dropped_target' (targets no configuration could take).")
    leg: int = Field(description="Index into the pointing's `motions` (leg i goes to "
                     "configuration i + 1; leg 0 starts at park, the last leg ends there).")
    configuration: int | None = Field(description="Index into the pointing's "
                                      "`configurations`; null when no configuration is concerned.")
    arms: list[int] = Field(description="Arms concerned by the change.")
    target_ids: list[str] = Field(description="Targets concerned by the change.")
    reason: str = Field(description="Why the change was made.")


TELESCOPE_TIME = (
    "exposures, acquisitions (pointings with an exposure), exposure_s (exposures x "
    "exposure_time_s), acquisition_s (acquisitions x the request's acquisition_s), "
    "reconfiguration_s (the summed makespans of the planned motion legs park -> c1 -> ... -> "
    "park), total_s (the three summed) and unplanned_legs (legs without a makespan, not "
    "counted: total_s is then a lower bound)")


class PlanTargetOut(Response):
    """A target of one pointing: sky position and focal-plane position in the pointing's frame."""

    id: str
    ra_deg: float
    dec_deg: float
    x_mm: float
    y_mm: float


class PlanPointing(PointingOut):
    position_angle_deg: float | None = Field(None, description=PA_USED_DOC)
    position_angle_search: PositionAngleSearchOut | None = Field(None, description=PA_SEARCH_DOC)
    configurations: list[ConfigurationOut] = Field(
        description="Configurations c1 ... cn, as changed by the motion planner (`changes`)."
    )
    motions: list[MotionPlanResponse] = Field(
        description="Motion plans park -> c1 -> ... -> park (len(configurations) + 1)."
    )
    unallocated: list[Unallocated] = Field(
        description="Targets in no configuration: left out by the allocation or dropped by the "
                    "motion planner."
    )
    changes: list[PlanChangeOut] = Field(
        description="Changes made to the allocation so that every motion leg can be executed."
    )
    executable: bool = Field(description="Every motion leg of this pointing was planned "
                             "(status 'ok').")
    reasons: list[str] = Field(description="One line per failed motion leg: which leg (counted "
                               "from 1 like the configurations: 'leg 1 (park -> c1)' is "
                               "`motions[0]`), which arms, why. Empty when `executable`.")
    targets: list[PlanTargetOut] | None = Field(
        None, description="The pointing's targets (`target_ids`) with their RA/Dec, deg, and focal-plane position in this pointing's frame, mm (gnomonic projection about `ra_deg`/`dec_deg` at `position_angle_deg`): what `POST /v1/validations` re-checks each observed target against.")
    not_planned: str | None = Field(None, description="Why this pointing was not planned (the "
                                    "plan's time limit left it no time: its targets 'no_time'); "
                                    "null when it was.")
    stats: Stats = Field(default_factory=dict, description="Allocation and motion statistics "
                         "of this pointing; `allocation` is the allocator's (its completeness "
                         "before the motion planner's changes, over the pointing's targets); "
                         "`motion` holds legs, budget_s (the effort seconds its legs were "
                         "given), failed_legs, targets_moved, legs_via_park, configurations_added, "
                         "targets_dropped; `compute_s` is the pointing's wall time; `effort` "
                         "holds effort_s (the work its searches were budgeted on, in reference "
                         "seconds) and overran (true when its wall-clock share, not its effort "
                         "budget, stopped them: only then can the same request give another "
                         "plan); `rounds` holds the outcome of every round that planned the "
                         "pointing (round, share_s, effort_s, executable, failed_legs, observed, "
                         "overran, attempted); the plan returned is the best of them; `exposure_rules` holds "
                         "its exposure cap (max_configurations, its share of max_exposures) and "
                         "the exposures and targets the stop rules left out; `telescope_time` is "
                         "what the pointing costs: " + TELESCOPE_TIME + ".")


class TimeLimitAdvice(Response):
    """A plan whose time limit left some pointing unplanned: the limit this field needs."""

    time_limit_s: float = Field(description="The plan's wall-clock limit, s.")
    needed_limit_s: float = Field(description="Estimated limit that plans every pointing, s "
                                  "(from the planner's effort model and its shares of the "
                                  "limit; docs/programme.md).")
    use_job: bool = Field(description="The needed limit is beyond a synchronous plan's: "
                          "submit the plan as a job (POST /v1/jobs, kind 'plan').")
    pointings_total: int = Field(ge=0)
    pointings_planned: int = Field(ge=0, description="Pointings planned whole: an exposure or "
                                   "more, every leg planned.")
    pointings_not_planned: list[str] = Field(description="Pointings the limit left no time "
                                             "for (their targets 'no_time').")
    pointings_failed: list[str] = Field(description="Pointings left with a failed leg when "
                                        "the limit ran out.")
    targets_not_planned: int = Field(ge=0, description="Targets of the pointings not planned.")
    message: str = Field(description="The advice in one sentence, also in `notices`.")


class MovableOut(Response):
    target_id: str
    pointing_id: str = Field(description="The pointing of an exposure that could take the target.")
    configuration: int = Field(description="That exposure's `index` among its pointing's configurations.")
    kept_because: Literal["consolidation_plan_failed"] | None = Field(
        None, description="Why the plan keeps the target where it is: 'consolidation_plan_failed': "
        "the plan's consolidation planned this exposure's pointing or the taker's again with "
        "targets moved, that plan failed (a motion leg, or a target the motion planner dropped; "
        "`stats.consolidation.passes[].failed`), and the later passes leave the pointing out. "
        "Null: nothing in the plan stopped the move.")


class FewTargetExposureOut(Response):
    pointing_id: str
    configuration: int = Field(description="The exposure's `index` among its pointing's configurations.")
    target_ids: list[str] = Field(description="The targets it observes (at most 2).")
    only_here: list[OnlyHereOut] = Field(
        description="Those of them no other exposure of the plan can take, and why, and those "
                    "only exposures observing 1 target can take ('takers_observe_fewer'); a "
                    "target of the exposure missing here could be observed by an exposure "
                    "observing at least 2 (`could_move_to` names one).")
    could_move_to: list[MovableOut] = Field(
        default_factory=list,
        description="Each of its targets missing from `only_here`, with an exposure that could "
                    "observe it as the plan stands, on an idle arm within the park move limit "
                    "and clear of that exposure's other arms: one observing at least 2 targets "
                    "(for an exposure of 1 target, the fullest that can). The plan's "
                    "consolidation moves such targets while the time limit holds the motion "
                    "legs it must plan again (`stats.consolidation`, its `reason` when it stopped); "
                    "`kept_because` says when the consolidation tried and its plan failed.")


class PlanResponse(Response):
    tangent_point: TangentPoint | None = None
    pointings: list[PlanPointing]
    executable: bool = Field(description="Every motion leg of every pointing was planned; false "
                             "when any pointing has a failed leg (do not execute those legs).")
    reasons: list[str] = Field(description="Why the plan is not executable: the pointings' "
                               "`reasons`, each prefixed with 'pointing <id>: '.")
    stats: Stats = Field(default_factory=dict, description="Counts over the whole plan, "
                         "including targets_moved, legs_via_park, configurations_added and "
                         "targets_dropped; `allocated_targets` (targets in a configuration "
                         "as returned), `field_completeness` = allocated_targets / targets "
                         "(every target of the request) and `priority_completeness` (their "
                         "priority over the priority of every target); `telescope_time` is the "
                         "sum of the pointings': " + TELESCOPE_TIME + "; `consolidation` (mode "
                         "fewest-exposures): the exposures emptied into idle arms of the plan's "
                         "other exposures (`exposures_emptied`), the pointings planned again, "
                         "whether their plans were kept (`accepted`, else `reason`) and the "
                         "exposures that saved (`exposures_saved`), summed over the passes "
                         "whose plans were kept; `passes`: each pass's own figures (a pass runs "
                         "again on the plan an accepted pass left).")
    time_limit_advice: TimeLimitAdvice | None = Field(
        None, description="Set when the time limit left a pointing unplanned: the limit this "
        "field needs and whether to plan it as a job.")
    epoch: EpochOut | None = Field(None, description="The epoch step: targets moved to "
                                   "`obs_date` (or, without one, their shift a year ahead); null "
                                   "when no date was given and no target moves.")
    unallocated: list[Unallocated] = Field(default_factory=list, description="Targets of "
                                           "the request in no pointing: those of `excluded_targets` "
                                           "(reason 'excluded').")
    content_hash: str | None = Field(
        None, description="\"sha256:\" + the hex SHA-256 of the plan's canonical JSON: every field but this one, keys sorted, no whitespace, UTF-8, numbers as they read back (docs/validation.md). `POST /v1/validations` and `mxs-planner validate` detect a plan edited after it was written.")
    notices: list[str] = Field(default_factory=list, description="Sentences for the "
                               "astronomer about the plan as a whole (e.g. the time limit it "
                               "needs), shown by the page's banner and the CLI's summary.")
    few_target_exposures: list[FewTargetExposureOut] = Field(
        default_factory=list, description="Every exposure observing at most 2 targets, with those "
        "of its targets no other exposure can take (`stats.few_target_exposures` counts them, "
        "`stats.few_target_exposures_only_here` those whose every target no other exposure can "
        "take, `stats.few_target_exposures_explained` those whose every target is listed in `only_here` or "
        "has a `could_move_to` with its `kept_because`).")


REQUEST_TYPES: dict[str, type[Request]] = {
    "segmentation": SegmentationRequest,
    "allocation": AllocationRequest,
    "motion-plan": MotionPlanRequest,
    "plan": PlanRequest,
}
RESPONSE_TYPES: dict[str, type[Response]] = {
    "segmentation": SegmentationResponse,
    "allocation": AllocationResponse,
    "motion-plan": MotionPlanResponse,
    "plan": PlanResponse,
}
