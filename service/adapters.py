"""Adapters between the HTTP schemas and the plain domain types (``models.types``, the
segmentation and the sequence plan): request models in, domain values out, and domain
results in, JSON-ready dicts shaped like the response schemas out.

Nothing here computes anything beyond a change of representation; the pipeline
(:mod:`service.pipeline`) composes the stages on the domain types and calls these only at
the HTTP edge.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from datetime import date
from typing import Any

import numpy as np

from models.epochs import MOTION_FIELDS, EpochReport, Motions, at_date
from models.instrument import Instrument
from models.types import (
    AllocationResult,
    ArmAssignment,
    ArmTrajectory,
    Configuration,
    MotionPlan,
    PlaneTargets,
    Unallocated,
)
from planner.commands import controller_commands
from planner.keep import FIELD as KEEP_FIELD
from planner.keep import KeptArm, KeptPointing
from planner.known_legs import KnownLegs
from planner.sequence import SequencePlan
from planner.sky import SkyField, arm_sky
from planner.telescope_time import TelescopeTime
from service.errors import FieldError
from service.schemas import ArmState, PlaneTarget, SkyTarget
from solvers.programme.angle import DEFAULT_STEP_DEG, AngleChoice, AngleSearch
from solvers.segmentation import Pointing, Segmentation

# ------------------------------------------------------------------ generic values


def plain(obj: Any) -> Any:
    """Domain output (dataclasses, numpy, tuples) as JSON-ready Python; NaN/inf -> None."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [plain(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)


def _finite_or_none(v: float) -> float | None:
    f = float(v)
    return f if math.isfinite(f) else None


# ------------------------------------------------------------------ requests -> domain


def plane_targets(ids: Sequence[str], x_mm: np.ndarray, y_mm: np.ndarray,
                  priority: Sequence[int]) -> PlaneTargets:
    """``PlaneTargets`` with exact int64 priorities (1..2^32-1 fit)."""
    return PlaneTargets.from_lists(ids, x_mm, y_mm, np.array(priority, dtype=np.int64))


def plane_targets_of(targets: Sequence[PlaneTarget]) -> PlaneTargets:
    """Focal-plane request targets as ``PlaneTargets``."""
    return plane_targets([t.id for t in targets], np.array([t.x_mm for t in targets], float),
                         np.array([t.y_mm for t in targets], float),
                         [t.priority for t in targets])


def targets_at_epoch(targets: Sequence[SkyTarget], obs_date: str | None, today: date,
                     ) -> tuple[list[SkyTarget], EpochReport | None]:
    """The targets at the observation date and the report of :func:`models.epochs.at_date`
    (the epoch policy); a target that does not move is returned as given."""
    ra = np.array([t.ra_deg for t in targets], float)
    dec = np.array([t.dec_deg for t in targets], float)
    motions = Motions.of(len(targets), **{f: [getattr(t, f) for t in targets]
                                          for f in MOTION_FIELDS})
    new_ra, new_dec, report = at_date(ra, dec, motions, obs_date, today)
    moved = [t if (r, d) == (t.ra_deg, t.dec_deg)
             else t.model_copy(update={"ra_deg": float(r), "dec_deg": float(d)})
             for t, r, d in zip(targets, new_ra, new_dec, strict=True)]
    return moved, report


def check_arms(states: Sequence[ArmState] | None, inst: Instrument, field: str) -> None:
    """Every listed arm exists on ``inst`` (the schema knows only the default 12)."""
    for i, s in enumerate(states or ()):
        if s.arm >= inst.n_arms:
            raise FieldError(
                ("body", field, i, "arm"), f"the instrument has arms 0..{inst.n_arms - 1}"
            )


def states_dict(states: Sequence[ArmState] | None) -> dict[int, tuple[float, float]]:
    """``{arm: (theta1_rad, theta2_rad)}`` of the listed arms."""
    return {s.arm: (s.theta1_rad, s.theta2_rad) for s in states or ()}


def kept_pointings(spec: Any) -> list[KeptPointing]:
    """A request's ``keep_configurations`` (:class:`service.keep_schemas.KeepConfigurations`)
    as the domain's :class:`planner.keep.KeptPointing` list, each naming its field."""
    return [KeptPointing(p.id, float(p.ra_deg), float(p.dec_deg),
                         None if p.position_angle_deg is None else float(p.position_angle_deg),
                         tuple(p.target_ids),
                         tuple(tuple(KeptArm(a.arm, a.target_id, float(a.theta1_rad), float(a.theta2_rad),
                                             a.x_mm, a.y_mm, a.kind) for a in c) for c in p.configurations),
                         f"{KEEP_FIELD}.pointings[{i}]")
            for i, p in enumerate(spec.pointings)]


def start_configuration(states: Sequence[ArmState] | None, inst: Instrument,
                        fixed: dict[int, tuple[float, float]]) -> np.ndarray | None:
    """(n_arms, 2) current configuration: listed arms where given, others parked; disabled
    arms where they are fixed. None when nothing was given (the allocator assumes park)."""
    if not states and not fixed:
        return None
    q = inst.park_configuration.copy()
    for k, v in states_dict(states).items():
        q[k] = v
    for k, v in fixed.items():
        q[k] = v
    return q


def full_configuration(states: Sequence[ArmState], inst: Instrument, field: str) -> np.ndarray:
    """(n_arms, 2) joint angles from a list naming every arm once (422 naming ``field``)."""
    check_arms(states, inst, field)
    q = np.full((inst.n_arms, 2), np.nan)
    for s in states:
        q[s.arm] = (s.theta1_rad, s.theta2_rad)
    missing = [k for k in range(inst.n_arms) if np.isnan(q[k, 0])]
    if missing:
        raise FieldError(("body", field), f"arms {missing} missing; give every arm once")
    return q


# ------------------------------------------------------------------ domain -> responses


def instrument_out(inst: Instrument) -> dict[str, Any]:
    """``Instrument`` -> InstrumentInfo dict."""
    arms = [{
        "arm": a.index, "enabled": a.enabled, "base_x_mm": a.base_x_mm, "base_y_mm": a.base_y_mm,
        "orientation_rad": a.orientation_rad, "d12_mm": a.d12_mm, "d13_mm": a.d13_mm,
        "d24_mm": a.d24_mm, "d3tip_mm": a.d3tip_mm, "stop_min_mm": a.stop_min_mm,
        "stop_max_mm": a.stop_max_mm, "theta1_min_rad": a.theta1_min_rad,
        "theta1_max_rad": a.theta1_max_rad, "joint1_speed_rad_s": a.joint1_speed_rad_s,
        "joint2_speed_rad_s": a.joint2_speed_rad_s,
        "park": {"theta1_rad": a.park_theta1_rad, "theta2_rad": a.park_theta2_rad},
        "bodies": [
            {"name": b.name, "shape": b.shape, "joint_from": b.joint_from, "joint_to": b.joint_to,
             "radius_mm": b.radius_mm, "width_mm": b.width_mm, "height_mm": b.height_mm}
            for b in a.bodies
        ],
    } for a in inst.arms]
    return plain({
        "name": inst.name, "source": inst.source, "fov_diameter_mm": inst.fov_diameter_mm,
        "plate_scale_arcsec_per_mm": inst.plate_scale_arcsec_per_mm,
        "collision_buffer_mm": inst.collision_buffer_mm,
        "joint_speed_rad_s": inst.max_joint_speed_rad_s, "arms": arms,
    })


def pointing_out(p: Pointing, ids: Sequence[str] | Mapping[int, str]) -> dict[str, Any]:
    """``solvers.segmentation.Pointing`` -> PointingOut dict (``ids`` of the segmented targets)."""
    return {"id": str(p.id), "ra_deg": float(p.ra_deg), "dec_deg": float(p.dec_deg),
            "x_mm": float(p.x_mm), "y_mm": float(p.y_mm), "radius_mm": float(p.radius_mm),
            "target_ids": [ids[int(i)] for i in p.target_indices],
            "position_angle_deg": None if p.position_angle_deg is None else float(p.position_angle_deg),
            "only_here": [ids[int(i)] for i in p.only_here]}


def segmentation_out(seg: Segmentation, ids: Sequence[str]) -> dict[str, Any]:
    """``solvers.segmentation.Segmentation`` -> SegmentationResponse dict."""
    return plain({
        "tangent_point": {"ra_deg": seg.tangent_ra_deg, "dec_deg": seg.tangent_dec_deg},
        "pointings": [pointing_out(p, ids) for p in seg.pointings],
        "stats": seg.stats,
    })


def configuration_out(c: Configuration, inst: Instrument | None = None,
                      sky: SkyField | None = None) -> dict[str, Any]:
    """``models.types.Configuration`` -> ConfigurationOut dict (priorities stay exact ints).
    With ``inst`` (a plan), an idle arm resting off park is reported as
    :func:`planner.sky.arm_sky` classifies it ("sky" with the RA/Dec it points at, or "blank")
    and ``stats.sky_arms`` counts the "sky" arms; without it (an allocation alone) as "blank"."""
    assignments = [assignment_out(a, inst, sky) for a in sorted(c.assignments, key=lambda a: a.arm)]
    stats = plain(c.stats)
    if inst is not None:
        stats["sky_arms"] = sum(a["kind"] == "sky" for a in assignments)
    return {
        "index": int(c.index), "status": c.status, "total_priority": int(c.total_priority),
        "arm_yield": int(c.arm_yield), "assignments": assignments, "stats": stats,
    }


def assignment_out(a: ArmAssignment, inst: Instrument | None = None,
                   sky: SkyField | None = None) -> dict[str, Any]:
    """``models.types.ArmAssignment`` -> AssignmentOut dict (see :func:`configuration_out`)."""
    rest = None if inst is None else arm_sky(inst, a, sky)
    return {"arm": int(a.arm), "kind": a.kind if rest is None else rest.kind,
            "target_id": None if a.target_id is None else str(a.target_id),
            "theta1_rad": float(a.theta1_rad), "theta2_rad": float(a.theta2_rad),
            "x_mm": float(a.x_mm), "y_mm": float(a.y_mm),
            "sky_ra_deg": None if rest is None else rest.ra_deg,
            "sky_dec_deg": None if rest is None else rest.dec_deg}


def unallocated_out(u: Unallocated) -> dict[str, Any]:
    return {"target_id": str(u.target_id), "reason": str(u.reason)}


def allocation_out(result: AllocationResult) -> dict[str, Any]:
    """``models.types.AllocationResult`` -> AllocationResponse dict."""
    return {"configurations": [configuration_out(c) for c in result.configurations],
            "unallocated": [unallocated_out(u) for u in result.unallocated],
            "stats": plain(result.stats)}


def trajectory_out(t: ArmTrajectory) -> dict[str, Any]:
    """``models.types.ArmTrajectory`` (parallel arrays) -> Trajectory dict (way-points)."""
    waypoints = [{"t_s": float(ts), "theta1_rad": float(a), "theta2_rad": float(b)}
                 for ts, a, b in zip(t.t_s, t.theta1_rad, t.theta2_rad, strict=True)]
    return {"arm": int(t.arm), "waypoints": waypoints, "commands": [plain(c) for c in t.commands]}


def motion_out(m: MotionPlan) -> dict[str, Any]:
    """``models.types.MotionPlan`` -> MotionPlanResponse dict."""
    return {"status": m.status, "makespan_s": _finite_or_none(m.makespan_s),
            "trajectories": [trajectory_out(t) for t in m.trajectories],
            "failed_arms": [int(a) for a in m.failed_arms], "stats": plain(m.stats)}


def motion_in(d: Mapping[str, Any]) -> MotionPlan:
    """A MotionPlanResponse dict (as :func:`motion_out` wrote it) back as the domain's
    :class:`MotionPlan` (its commands recomputed from the way-points)."""
    trajs = []
    for tr in d["trajectories"]:
        w = tr["waypoints"]
        t = np.array([p["t_s"] for p in w], float)
        th1, th2 = np.array([p["theta1_rad"] for p in w], float), np.array([p["theta2_rad"] for p in w], float)
        trajs.append(ArmTrajectory(int(tr["arm"]), t, th1, th2, controller_commands(t, th1, th2)))
    makespan = d["makespan_s"]
    return MotionPlan(d["status"], math.nan if makespan is None else float(makespan), tuple(trajs),
                      tuple(int(a) for a in d["failed_arms"]), dict(d.get("stats") or {}))


def assignment_in(a: Mapping[str, Any], target_index: int | None, target_id: str | None) -> ArmAssignment:
    """An AssignmentOut dict back as an :class:`ArmAssignment`: on its target when
    ``target_index`` is given, else at park or fixed as it says, and an idle arm off park
    (reported "sky" or "blank") as "blank" (a plan places its sky again)."""
    kind = "target" if target_index is not None else a["kind"] if a["kind"] in ("park", "fixed") else "blank"
    return ArmAssignment(int(a["arm"]), kind, float(a["theta1_rad"]), float(a["theta2_rad"]), float(a["x_mm"]),
                         float(a["y_mm"]), target_index, None if target_index is None else target_id)


def known_legs_in(inst: Instrument, p: Mapping[str, Any]) -> KnownLegs:
    """The verified legs of a PlanPointing dict (:class:`planner.known_legs.KnownLegs`), by
    the joint angles of the configurations they end at."""
    configs = [np.array([[a["theta1_rad"], a["theta2_rad"]] for a in sorted(c["assignments"], key=lambda a: a["arm"])],
                        float) for c in p["configurations"]]
    if len(p["motions"]) != len(configs) + 1:  # legs not planned: nothing to reuse
        return KnownLegs()
    return KnownLegs.of_plan(np.asarray(inst.park_configuration, float), configs,
                             [motion_in(m) for m in p["motions"]])


def failed_motion_out(inst: Instrument, reason: str) -> dict[str, Any]:
    """A MotionPlanResponse dict for a leg the planner could not attempt."""
    return {"status": "failed", "makespan_s": None, "trajectories": [],
            "failed_arms": list(range(inst.n_arms)), "stats": {"error": reason}}


def telescope_time_in(d: Mapping[str, Any]) -> TelescopeTime:
    """A pointing's ``stats.telescope_time`` dict (as :func:`plain` wrote it) back as the
    domain's :class:`TelescopeTime` (``total_s`` is recomputed from its parts)."""
    return TelescopeTime(int(d["exposures"]), int(d["acquisitions"]), float(d["exposure_s"]),
                         float(d["acquisition_s"]), float(d["reconfiguration_s"]),
                         int(d["unplanned_legs"]))


CHANGE_COUNTS = ("targets_moved", "legs_via_park", "configurations_added", "targets_dropped")


def change_counts(changes: Sequence[dict[str, Any]], dropped: int) -> dict[str, int]:
    """How many targets were moved, legs sent through park, configurations added and
    targets dropped by the ``changes`` (PlanChangeOut dicts) of one plan."""
    return {
        "targets_moved": sum(len(c["target_ids"]) for c in changes if c["kind"] == "moved_target"),
        "legs_via_park": sum(1 for c in changes if c["kind"] == "via_park"),
        "configurations_added": sum(1 for c in changes if c["kind"] == "new_configuration"),
        "targets_dropped": int(dropped),
    }


def sequence_out(sp: SequencePlan, inst: Instrument | None = None,
                 sky: SkyField | None = None) -> dict[str, Any]:
    """``planner.sequence.SequencePlan`` -> the motion part of a PlanPointing dict:
    ``configurations`` (their idle arms as :func:`configuration_out` reports them with
    ``inst`` and ``sky``), ``motions``, ``changes``, ``dropped``, ``executable``, ``reasons``
    and ``stats`` (change counts and the planner's own statistics under ``sequence``)."""
    changes = [
        {"kind": str(c.kind), "leg": int(c.leg),
         "configuration": None if c.configuration is None else int(c.configuration),
         "arms": [int(a) for a in c.arms], "target_ids": [str(t) for t in c.target_ids],
         "reason": str(c.reason)}
        for c in sp.changes
    ]
    return {
        "configurations": [configuration_out(c, inst, sky) for c in sp.configurations],
        "motions": [motion_out(m) for m in sp.legs],
        "changes": changes,
        "dropped": [unallocated_out(u) for u in sp.dropped],
        "executable": bool(sp.executable),
        "reasons": [str(r) for r in sp.reasons],
        "stats": {**change_counts(changes, len(sp.dropped)), "sequence": plain(sp.stats)},
    }


# ------------------------------------------------------------------ plan files


def plan_targets_out(members: Sequence[Any], plane: PlaneTargets) -> list[dict[str, Any]]:
    """A pointing's targets as PlanTargetOut dicts: ``plane`` (their projection about the
    pointing), each with the RA/Dec of the sky target of its id in ``members``."""
    sky = {str(t.id): t for t in members}
    return [{"id": str(i), "ra_deg": float(sky[str(i)].ra_deg), "dec_deg": float(sky[str(i)].dec_deg),
             "x_mm": float(x), "y_mm": float(y)}
            for i, x, y in zip(plane.ids, plane.x_mm, plane.y_mm, strict=True)]


def with_content_hash(plan: Mapping[str, Any]) -> dict[str, Any]:
    """The PlanResponse dict as the service writes it (validated and dumped as JSON values by
    :class:`service.response_schemas.PlanResponse`, as the routes do) with its ``content_hash``
    (:func:`planner.plan_file.content_hash`): the one place a plan gets its hash, at the
    exit of the synchronous plan, the plan job and the CLI."""
    from planner.plan_file import HASH_FIELD, content_hash
    from service.response_schemas import PlanResponse

    out = PlanResponse.model_validate({**plan, HASH_FIELD: None}).model_dump(mode="json", by_alias=True)
    out[HASH_FIELD] = content_hash(out)
    return out


# ------------------------------------------------------------------ position angle


def requested_angle_deg(position_angle_deg: float | str) -> float:
    """The request's ``position_angle_deg`` as the angle a pointing without a search of its
    own takes: the number, or 0 for "auto" (whose pointings all carry their searched angle)."""
    return 0.0 if position_angle_deg == "auto" else float(position_angle_deg)


def angle_search_in(position_angle_deg: float | str, range_deg: Sequence[float] | None,
                    step_deg: float | None) -> AngleSearch | None:
    """The request's "auto" as the domain's :class:`~solvers.programme.angle.AngleSearch`
    (None for a number: that angle is used)."""
    if position_angle_deg != "auto":
        return None
    rng = None if range_deg is None else (float(range_deg[0]), float(range_deg[1]))
    return AngleSearch(rng, DEFAULT_STEP_DEG if step_deg is None else float(step_deg))


def angle_out(used_deg: float, choice: AngleChoice | None) -> dict[str, Any]:
    """A PlanPointing's ``position_angle_deg`` (the angle it is observed at) and
    ``position_angle_search`` (None when the angle was used as given)."""
    search = None if choice is None else {
        "tried_deg": [float(a) for a in choice.tried_deg], "chosen_deg": float(choice.chosen_deg),
        "objective": str(choice.objective)}
    return {"position_angle_deg": float(used_deg), "position_angle_search": search}
