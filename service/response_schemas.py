"""Response schemas of the v1 HTTP contract (pydantic v2): what every route answers, the
plan's pointings, configurations, motions and the accounts around them. Units are in the
field names. The requests are :mod:`service.schemas`."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from service.angle_schemas import PA_SEARCH_DOC, PA_USED_DOC, PositionAngleSearchOut
from service.epoch_schemas import EpochOut
from service.schemas import Response, Stats


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


RESPONSE_TYPES: dict[str, type[Response]] = {
    "segmentation": SegmentationResponse,
    "allocation": AllocationResponse,
    "motion-plan": MotionPlanResponse,
    "plan": PlanResponse,
}
