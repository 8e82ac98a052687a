"""The only place the service touches domain code: HTTP schemas in, plain JSON dicts out.

Each stage function takes a validated request model and an :class:`Instrument` and
returns a dict shaped like the stage's response schema. A stage whose domain module is not
importable raises :class:`StageUnavailable` (HTTP 501). No algorithm lives here.
"""

from __future__ import annotations

import dataclasses
import inspect
import logging
import math
import re
import time
from collections.abc import Callable, Sequence
from functools import lru_cache
from importlib import import_module
from typing import Any

import numpy as np

from models.instrument import Instrument, default_instrument, load_instrument
from planner.sequence import SequenceOptions, SequencePlan, plan_sequence
from service.errors import FieldError, StageUnavailable
from service.schemas import (
    REQUEST_TYPES,
    AllocationRequest,
    ArmState,
    MotionPlanRequest,
    PlanRequest,
    SegmentationRequest,
    SkyTarget,
)

Progress = Callable[[float], None]
log = logging.getLogger("service")


def _noop(_: float) -> None:
    pass


# ------------------------------------------------------------------------ utilities


def plain(obj: Any) -> Any:
    """Domain output (dataclasses, numpy, tuples) as JSON-ready Python; NaN/inf -> None."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if hasattr(obj, "model_dump"):
        return plain(obj.model_dump())
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


def call_domain(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """Call ``fn`` passing only the keyword arguments it accepts (and not None ones)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):  # pragma: no cover - builtins
        return fn(*args, **{k: v for k, v in kwargs.items() if v is not None})
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        accepted = {k: v for k, v in kwargs.items() if v is not None}
    else:
        accepted = {k: v for k, v in kwargs.items() if k in params and v is not None}
    return fn(*args, **accepted)


def _domain(stage: str, module: str, *names: str) -> tuple[Any, ...]:
    """Named attributes of a domain module, or StageUnavailable when it has not landed."""
    try:
        mod = import_module(module)
    except ImportError as exc:
        raise StageUnavailable(stage, f"module {module} is not installed ({exc})") from exc
    missing = [n for n in names if not hasattr(mod, n)]
    if missing:
        raise StageUnavailable(stage, f"{module} does not provide {', '.join(missing)}")
    return tuple(getattr(mod, n) for n in names)


def require_stage(kind: str) -> None:
    """Raise :class:`StageUnavailable` unless the domain code behind job ``kind`` imports."""
    _STAGE_CHECKS[kind]()


def stage_available(kind: str) -> bool:
    try:
        require_stage(kind)
    except StageUnavailable:
        return False
    return True


@lru_cache(maxsize=8)
def instrument_from(path: str | None) -> Instrument:
    return default_instrument() if path is None else load_instrument(path)


# ----------------------------------------------------------------------- instrument


def instrument_info(inst: Instrument) -> dict[str, Any]:
    arms = []
    for a in inst.arms:
        arms.append({
            "arm": a.index,
            "enabled": a.enabled,
            "base_x_mm": a.base_x_mm,
            "base_y_mm": a.base_y_mm,
            "orientation_rad": a.orientation_rad,
            "d12_mm": a.d12_mm,
            "d13_mm": a.d13_mm,
            "d24_mm": a.d24_mm,
            "d3tip_mm": a.d3tip_mm,
            "stop_min_mm": a.stop_min_mm,
            "stop_max_mm": a.stop_max_mm,
            "theta1_min_rad": a.theta1_min_rad,
            "theta1_max_rad": a.theta1_max_rad,
            "joint1_speed_rad_s": a.joint1_speed_rad_s,
            "joint2_speed_rad_s": a.joint2_speed_rad_s,
            "park": {"theta1_rad": a.park_theta1_rad, "theta2_rad": a.park_theta2_rad},
            "bodies": [
                {
                    "name": b.name, "shape": b.shape, "joint_from": b.joint_from,
                    "joint_to": b.joint_to, "radius_mm": b.radius_mm, "width_mm": b.width_mm,
                    "height_mm": b.height_mm,
                }
                for b in a.bodies
            ],
        })
    return plain({
        "name": inst.name,
        "source": inst.source,
        "fov_diameter_mm": inst.fov_diameter_mm,
        "plate_scale_arcsec_per_mm": inst.plate_scale_arcsec_per_mm,
        "collision_buffer_mm": inst.collision_buffer_mm,
        "joint_speed_rad_s": inst.max_joint_speed_rad_s,
        "arms": arms,
    })


def park_states(inst: Instrument) -> list[ArmState]:
    return [
        ArmState(arm=a.index, theta1_rad=a.park_theta1_rad, theta2_rad=a.park_theta2_rad)
        for a in inst.arms
    ]


def _check_arms(states: Sequence[ArmState] | None, inst: Instrument, field: str) -> None:
    for i, s in enumerate(states or ()):
        if s.arm >= inst.n_arms:
            raise FieldError(
                ("body", field, i, "arm"), f"the instrument has arms 0..{inst.n_arms - 1}"
            )


# --------------------------------------------------------------------------- sky


def sky_to_focal(
    targets: Sequence[SkyTarget], ra_deg: float, dec_deg: float, inst: Instrument,
    position_angle_deg: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Gnomonic projection of ``targets`` about (``ra_deg``, ``dec_deg``) onto the FOV frame.

    A target the projection cannot take (>= 90 deg from the pointing) is a 422 naming
    ``targets[i]`` (indices of ``targets`` as given)."""
    (sky_to_focal_mm,) = _domain("sky projection", "models.sky", "sky_to_focal_mm")
    from models.errors import InputError

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


# ------------------------------------------------------------------- segmentation


def _check_segmentation() -> None:
    _domain("segmentation", "solvers.segmentation", "segment_field")


def segmentation(
    req: SegmentationRequest, inst: Instrument, progress: Progress = _noop
) -> dict[str, Any]:
    (segment_field,) = _domain("segmentation", "solvers.segmentation", "segment_field")
    ra = np.array([t.ra_deg for t in req.targets], float)
    dec = np.array([t.dec_deg for t in req.targets], float)
    tp = req.tangent_point
    seg = call_domain(
        segment_field, ra, dec,
        threshold_mm=req.threshold_mm,
        tangent_point=(tp.ra_deg, tp.dec_deg) if tp else None,
        instrument=inst,
        plate_scale_arcsec_per_mm=inst.plate_scale_arcsec_per_mm,
        fov_radius_mm=inst.fov_radius_mm,
        mode=req.mode,
        seed=req.seed,
    )
    ids = [t.id for t in req.targets]
    pointings = [
        {
            "id": str(p.id), "ra_deg": float(p.ra_deg), "dec_deg": float(p.dec_deg),
            "x_mm": float(p.x_mm), "y_mm": float(p.y_mm), "radius_mm": float(p.radius_mm),
            "target_ids": [ids[int(i)] for i in p.target_indices],
        }
        for p in seg.pointings
    ]
    progress(1.0)
    return plain({
        "tangent_point": {"ra_deg": seg.tangent_ra_deg, "dec_deg": seg.tangent_dec_deg},
        "pointings": pointings,
        "stats": getattr(seg, "stats", {}) or {},
    })


# --------------------------------------------------------------------- allocation


def _check_allocation() -> None:
    _domain("allocation", "solvers.allocation", "allocate")


def allocation(
    req: AllocationRequest, inst: Instrument, progress: Progress = _noop, *, time_limit_s: float
) -> dict[str, Any]:
    """``solvers.allocation.allocate`` on the request's targets (sky targets are projected
    about ``pointing`` first). ``time_limit_s`` bounds the whole call (already capped by the
    server's limits in ``app.py``)."""
    (allocate,) = _domain("allocation", "solvers.allocation", "allocate")
    _check_arms(req.start, inst, "start")
    _check_arms(req.disabled_arms, inst, "disabled_arms")
    if req.sky:
        assert req.pointing is not None
        x, y = sky_to_focal(
            req.targets, req.pointing.ra_deg, req.pointing.dec_deg, inst,  # type: ignore[arg-type]
            req.pointing.position_angle_deg,
        )
    else:
        x = np.array([t.x_mm for t in req.targets], float)  # type: ignore[union-attr]
        y = np.array([t.y_mm for t in req.targets], float)  # type: ignore[union-attr]
    ids = [t.id for t in req.targets]
    targets = plane_targets(ids, x, y, [t.priority for t in req.targets])
    fixed = _states_dict(req.disabled_arms)
    start_q = _start_q(req.start, inst, fixed)
    result = _allocate(
        allocate, inst, targets, method=req.method, solver=req.solver,
        configurations=req.configurations, time_limit_s=time_limit_s, seed=req.seed,
        collision_buffer_mm=req.collision_buffer_mm, start_q=start_q, fixed=fixed,
        progress=progress,
    )
    progress(1.0)
    return allocation_out(result)


def plane_targets(ids: Sequence[str], x: np.ndarray, y: np.ndarray, priority: Sequence[int]) -> Any:
    """``models.types.PlaneTargets`` with exact int64 priorities (1..2^32-1 fit)."""
    from models.types import PlaneTargets

    return PlaneTargets.from_lists(ids, x, y, np.array(priority, dtype=np.int64))


def _allocate(
    allocate: Callable[..., Any], inst: Instrument, targets: Any, *, method: str, solver: str,
    configurations: str, time_limit_s: float, seed: int | None,
    collision_buffer_mm: float | None = None, start_q: np.ndarray | None = None,
    fixed: dict[int, tuple[float, float]] | None = None, progress: Progress = _noop,
) -> Any:
    def report(p: float, _message: str = "") -> None:
        progress(min(max(float(p), 0.0), 1.0) * 0.99)

    try:
        return allocate(
            inst, targets, method=method, solver=solver, configurations=configurations,
            time_limit_s=float(time_limit_s), seed=int(seed or 0),
            collision_buffer_mm=collision_buffer_mm, start_q=start_q, fixed=fixed or None,
            progress=report,
        )
    except NotImplementedError as exc:  # e.g. a back-end that is not installed
        raise StageUnavailable("allocation", str(exc)) from exc


def _states_dict(states: Sequence[ArmState] | None) -> dict[int, tuple[float, float]]:
    return {s.arm: (s.theta1_rad, s.theta2_rad) for s in states or ()}


def _start_q(
    states: Sequence[ArmState] | None, inst: Instrument, fixed: dict[int, tuple[float, float]]
) -> np.ndarray | None:
    """(n_arms, 2) current configuration: listed arms where given, others parked; disabled
    arms where they are fixed. None when nothing was given (the allocator assumes park)."""
    if not states and not fixed:
        return None
    q = inst.park_configuration.copy()
    for k, v in _states_dict(states).items():
        q[k] = v
    for k, v in fixed.items():
        q[k] = v
    return q


def _opt_float(v: Any) -> float | None:
    return None if v is None else float(v)


def allocation_out(result: Any) -> dict[str, Any]:
    """``models.types.AllocationResult`` -> AllocationResponse dict (one entry per arm).

    Priorities stay Python ints end to end (exact up to 2^32-1 and their sums)."""
    return {"configurations": [configuration_out(c) for c in result.configurations],
            "unallocated": [unallocated_out(u) for u in result.unallocated],
            "stats": plain(result.stats or {})}


def configuration_out(c: Any) -> dict[str, Any]:
    """``models.types.Configuration`` -> ConfigurationOut dict."""
    return {
        "index": int(c.index),
        "status": c.status,
        "total_priority": int(c.total_priority),
        "arm_yield": int(c.arm_yield),
        "assignments": [
            {
                "arm": int(a.arm), "kind": a.kind,
                "target_id": None if a.target_id is None else str(a.target_id),
                "theta1_rad": float(a.theta1_rad), "theta2_rad": float(a.theta2_rad),
                "x_mm": float(a.x_mm), "y_mm": float(a.y_mm),
            }
            for a in sorted(c.assignments, key=lambda a: a.arm)
        ],
        "stats": plain(c.stats or {}),
    }


def unallocated_out(u: Any) -> dict[str, Any]:
    return {"target_id": str(u.target_id), "reason": str(u.reason)}


# -------------------------------------------------------------------- motion plans


def _check_motion() -> None:
    _domain("motion planning", "planner", "plan_motion")


def _full_configuration(states: Sequence[ArmState], inst: Instrument, field: str) -> np.ndarray:
    _check_arms(states, inst, field)
    q = np.full((inst.n_arms, 2), np.nan)
    for s in states:
        q[s.arm] = (s.theta1_rad, s.theta2_rad)
    missing = [k for k in range(inst.n_arms) if np.isnan(q[k, 0])]
    if missing:
        raise FieldError(("body", field), f"arms {missing} missing; give every arm once")
    return q


def motion_plan(
    req: MotionPlanRequest, inst: Instrument, progress: Progress = _noop, *, time_limit_s: float
) -> dict[str, Any]:
    (plan_motion,) = _domain("motion planning", "planner", "plan_motion")
    start = _full_configuration(req.start, inst, "start")
    goal = _full_configuration(req.goal, inst, "goal")
    result = call_domain(
        plan_motion, inst, start, goal,
        dt_s=req.dt_s, dt_col_s=req.dt_col_s, max_start_stop=req.max_start_stop,
        collision_buffer_mm=req.collision_buffer_mm, seed=req.seed, time_budget_s=time_limit_s,
    )
    progress(1.0)
    return _motion_out(result)


def motion_sequence(
    inst: Instrument, configurations: Sequence[Any], *, targets: Any, seed: int | None,
    leg_time_limit_s: float, time_limit_s: float | None, progress: Progress = _noop,
) -> dict[str, Any]:
    """``planner.sequence.plan_sequence`` on one pointing's configurations
    (``models.types.Configuration``) and targets (``models.types.PlaneTargets``, as given to
    the allocator), as the motion part of a PlanPointing dict: ``configurations`` (as changed
    by the planner), ``motions`` (legs park -> c1 -> ... -> park), ``changes``, ``dropped``
    (Unallocated dicts), ``executable``, ``reasons`` and ``stats`` (change counts, the
    planner's own statistics).

    ``leg_time_limit_s`` is each leg's planning budget, ``time_limit_s`` the whole sequence's
    (None: no limit beyond the legs'). Never raises: should the planner itself break, every
    leg is reported failed with the reason rather than an unverified plan."""
    options = SequenceOptions(seed=int(seed or 0), leg_time_limit_s=float(leg_time_limit_s),
                              time_limit_s=_opt_float(time_limit_s))
    try:
        sp = plan_sequence(inst, tuple(configurations), options, targets=targets, progress=progress)
    except Exception as exc:  # noqa: BLE001 - reported as failed legs, never a 5xx
        log.exception("motion sequence planning failed")
        reason = f"planner error: {type(exc).__name__}: {exc}"
        out = sequence_out(SequencePlan(tuple(configurations), ()))
        out["motions"] = [_failed_motion(inst, reason) for _ in range(len(configurations) + 1)]
        out["executable"], out["reasons"] = False, [reason]
        return out
    return sequence_out(sp)


def sequence_out(sp: SequencePlan) -> dict[str, Any]:
    """``planner.sequence.SequencePlan`` -> the motion part of a PlanPointing dict."""
    changes = [
        {"kind": str(c.kind), "leg": int(c.leg),
         "configuration": None if c.configuration is None else int(c.configuration),
         "arms": [int(a) for a in c.arms], "target_ids": [str(t) for t in c.target_ids],
         "reason": str(c.reason)}
        for c in sp.changes
    ]
    return {
        "configurations": [configuration_out(c) for c in sp.configurations],
        "motions": [_motion_out(m) for m in sp.legs],
        "changes": changes,
        "dropped": [unallocated_out(u) for u in sp.dropped],
        "executable": bool(sp.executable),
        "reasons": [str(r) for r in sp.reasons],
        "stats": {**change_counts(changes, len(sp.dropped)), "sequence": plain(sp.stats or {})},
    }


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


def _failed_motion(inst: Instrument, reason: str) -> dict[str, Any]:
    return {"status": "failed", "makespan_s": None, "trajectories": [],
            "failed_arms": list(range(inst.n_arms)), "stats": {"error": reason}}


def _motion_out(result: Any) -> dict[str, Any]:
    """Domain motion plan -> MotionPlanResponse dict (adapter; see planner)."""
    data = plain(result)
    for tr in data.get("trajectories", []):
        if "waypoints" not in tr:  # models.types.ArmTrajectory holds parallel arrays
            tr["waypoints"] = [
                {"t_s": t, "theta1_rad": a, "theta2_rad": b}
                for t, a, b in zip(tr.pop("t_s"), tr.pop("theta1_rad"), tr.pop("theta2_rad"),
                                   strict=True)
            ]
        tr.setdefault("commands", [])
    return {
        "status": data.get("status", "failed"),
        "makespan_s": data.get("makespan_s"),
        "trajectories": data.get("trajectories", []),
        "failed_arms": data.get("failed_arms", []),
        "stats": data.get("stats", {}),
    }


# -------------------------------------------------------------------- whole pipeline


def _check_plan() -> None:
    _check_segmentation()
    _check_allocation()
    _check_motion()
    _domain("sky projection", "models.sky", "sky_to_focal_mm")


def plan(
    req: PlanRequest, inst: Instrument, progress: Progress = _noop, *, time_limit_s: float,
    budget_s: float | None = None,
) -> dict[str, Any]:
    """Segmentation -> per pointing: projection onto the pointing's own tangent plane
    (``position_angle_deg``) -> allocation (all configurations) -> executable motion
    sequence park -> c1 -> ... -> park (``planner.sequence.plan_sequence``, which may change
    the configurations so that every leg can be executed).

    ``time_limit_s`` bounds every solver call (each pointing's allocation, each motion
    leg). ``budget_s`` (synchronous HTTP requests) bounds the whole request: it is shared
    out over the pointings still to do, and a pointing reached after it ran out gets no
    configurations (its targets ``no_time``). A motion leg that cannot be planned is
    returned with status "failed", never as an exception; the pointing and the plan then
    say ``executable: false`` with the reasons."""
    _check_plan()
    (allocate,) = _domain("allocation", "solvers.allocation", "allocate")
    t0 = time.monotonic()
    deadline = None if budget_s is None else t0 + float(budget_s)

    def left() -> float:
        return math.inf if deadline is None else deadline - time.monotonic()

    seg = segmentation(
        SegmentationRequest(targets=req.targets, threshold_mm=req.threshold_mm,
                            mode=req.segmentation_mode, seed=req.seed), inst
    )
    progress(0.05)
    by_id = {t.id: t for t in req.targets}
    n = max(len(seg["pointings"]), 1)
    seed = int(req.seed or 0)
    out = []
    for i, p in enumerate(seg["pointings"]):
        lo, hi = 0.05 + 0.95 * i / n, 0.05 + 0.95 * (i + 1) / n
        members = [by_id[t] for t in p["target_ids"]]
        ra, dec = p["ra_deg"] % 360.0, p["dec_deg"]
        x, y = sky_to_focal(members, ra, dec, inst, req.position_angle_deg)
        share = left() / (n - i)  # this pointing's part of what is left of the budget
        pstats: dict[str, Any] = {}
        configs: Sequence[Any] = ()
        targets = plane_targets([t.id for t in members], x, y, [t.priority for t in members])
        if share < _MIN_STAGE_S:
            unalloc = [{"target_id": t.id, "reason": "no_time"} for t in members]
            pstats["allocation"] = {"skipped": "request time budget exhausted"}
        else:
            result = _allocate(
                allocate, inst, targets, method=req.method, solver=req.solver, configurations="all",
                time_limit_s=min(time_limit_s, 0.5 * share), seed=seed,
                progress=lambda f, lo=lo, hi=hi: progress(lo + 0.5 * (hi - lo) * f),
            )
            configs = result.configurations
            unalloc = [unallocated_out(u) for u in result.unallocated]
            pstats["allocation"] = plain(result.stats or {})
        progress(lo + 0.5 * (hi - lo))
        legs = len(configs) + 1
        remaining = deadline - time.monotonic() - (n - i - 1) * share if deadline else math.inf
        leg_budget = max(min(time_limit_s, remaining / legs), _MIN_STAGE_S)
        tm = time.monotonic()
        seq = motion_sequence(inst, configs, targets=targets, seed=seed,
                              leg_time_limit_s=leg_budget,
                              time_limit_s=None if deadline is None
                              else max(remaining, _MIN_STAGE_S),
                              progress=lambda f, lo=lo, hi=hi: progress(lo + (0.5 + 0.5 * f) * (hi - lo)))
        motions = seq["motions"]
        pstats["motion"] = {"legs": len(motions), "leg_budget_s": leg_budget,
                            "compute_s": time.monotonic() - tm,
                            "failed_legs": sum(m["status"] != "ok" for m in motions),
                            **{k: seq["stats"][k] for k in CHANGE_COUNTS}}
        pstats["sequence"] = seq["stats"]["sequence"]
        out.append({**p, "ra_deg": ra, "configurations": seq["configurations"],
                    "motions": motions, "unallocated": unalloc + seq["dropped"],
                    "changes": seq["changes"], "executable": seq["executable"],
                    "reasons": seq["reasons"], "stats": pstats})
        progress(hi)
    reasons: dict[str, int] = {}
    for p in out:
        for u in p["unallocated"]:
            reasons[u["reason"]] = reasons.get(u["reason"], 0) + 1
    progress(1.0)
    return {
        "tangent_point": seg["tangent_point"],
        "pointings": out,
        "executable": all(p["executable"] for p in out),
        "reasons": [f"pointing {p['id']}: {r}" for p in out for r in p["reasons"]],
        "stats": plain({
            "targets": len(req.targets), "pointings": len(out),
            "configurations": sum(len(p["configurations"]) for p in out),
            "allocated_targets": sum(
                1 for p in out for c in p["configurations"] for a in c["assignments"]
                if a["target_id"] is not None
            ),
            "unallocated_by_reason": reasons,
            "motion_plans": sum(len(p["motions"]) for p in out),
            "motion_plans_failed": sum(
                1 for p in out for m in p["motions"] if m["status"] != "ok"
            ),
            **{k: sum(p["stats"]["motion"][k] for p in out) for k in CHANGE_COUNTS},
            "time_limit_s": time_limit_s,
            "budget_s": budget_s,
            "elapsed_s": time.monotonic() - t0,
            "segmentation": seg["stats"],
        }),
    }


_MIN_STAGE_S = 0.5  # below this share of the request budget a pointing is not attempted


_STAGE_CHECKS: dict[str, Callable[[], None]] = {
    "segmentation": _check_segmentation,
    "allocation": _check_allocation,
    "motion-plan": _check_motion,
    "plan": _check_plan,
}


def run(kind: str, request: Any, inst: Instrument, progress: Progress = _noop,
        *, time_limit_s: float, budget_s: float | None = None) -> dict[str, Any]:
    """Run one stage by its job kind on an already validated (or raw dict) request."""
    model = REQUEST_TYPES[kind]
    req = request if isinstance(request, model) else model.model_validate(request)
    if kind == "segmentation":
        return segmentation(req, inst, progress)  # type: ignore[arg-type]
    if kind == "allocation":
        return allocation(req, inst, progress, time_limit_s=time_limit_s)  # type: ignore[arg-type]
    if kind == "motion-plan":
        return motion_plan(req, inst, progress, time_limit_s=time_limit_s)  # type: ignore[arg-type]
    return plan(req, inst, progress, time_limit_s=time_limit_s,  # type: ignore[arg-type]
                budget_s=budget_s)
