"""The only place the service touches domain code: HTTP schemas in, plain JSON dicts out.

Each stage function takes a validated request model and an :class:`Instrument` and
returns a dict shaped like the stage's response schema. A stage whose domain module is not
importable raises :class:`StageUnavailable` (HTTP 501). No algorithm lives here.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Callable, Sequence
from functools import lru_cache
from importlib import import_module
from typing import Any

import numpy as np

from models.instrument import Instrument, default_instrument, load_instrument
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
    (sky_to_focal_mm,) = _domain("sky projection", "models.sky", "sky_to_focal_mm")
    x, y = sky_to_focal_mm(
        np.array([t.ra_deg for t in targets], float), np.array([t.dec_deg for t in targets], float),
        ra_deg, dec_deg, inst.plate_scale_arcsec_per_mm, position_angle_deg,
    )
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
    if req.collision_buffer_mm is not None:
        inst = inst.with_collision_buffer(req.collision_buffer_mm)
    ids = [t.id for t in req.targets]
    prio = np.array([t.priority for t in req.targets], dtype=np.int64)
    result = call_domain(
        allocate, x, y, prio,
        instrument=inst, ids=ids, method=req.method, solver=req.solver,
        configurations=req.configurations, time_limit_s=time_limit_s, seed=req.seed,
        start=_states_array(req.start), disabled_arms=_states_array(req.disabled_arms),
        progress=progress,
    )
    progress(1.0)
    return _allocation_out(result, ids, x, y)


def _states_array(states: Sequence[ArmState] | None) -> dict[int, tuple[float, float]] | None:
    if states is None:
        return None
    return {s.arm: (s.theta1_rad, s.theta2_rad) for s in states}


def _allocation_out(result: Any, ids: list[str], x: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    """Domain allocation result -> AllocationResponse dict (adapter; see solvers.allocation)."""
    data = plain(result)
    configs = []
    for i, c in enumerate(data.get("configurations", [])):
        assignments = []
        for a in c["assignments"]:
            t = a.get("target_index")
            tid = a.get("target_id", ids[t] if t is not None and t >= 0 else None)
            assignments.append({
                "arm": a["arm"], "target_id": tid,
                "theta1_rad": a["theta1_rad"], "theta2_rad": a["theta2_rad"],
                "x_mm": a.get("x_mm"), "y_mm": a.get("y_mm"),
            })
        configs.append({
            "index": c.get("index", i), "status": c.get("status", "feasible"),
            "total_priority": c["total_priority"], "arm_yield": c["arm_yield"],
            "assignments": assignments,
        })
    unalloc = []
    for u in data.get("unallocated", []):
        t = u.get("target_index")
        unalloc.append({"target_id": u.get("target_id", ids[t] if t is not None else ""),
                        "reason": u.get("reason", "unknown")})
    return {"configurations": configs, "unallocated": unalloc, "stats": data.get("stats", {})}


# -------------------------------------------------------------------- motion plans


def _check_motion() -> None:
    _domain("motion planning", "planner", "plan_motion", "plan_chain")


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


def motion_chain(
    inst: Instrument, configurations: Sequence[np.ndarray], *, seed: int | None,
    time_limit_s: float,
) -> list[dict[str, Any]]:
    """Motion plans park -> c1 -> ... -> park, each leg from where the previous one ended."""
    (plan_chain,) = _domain("motion planning", "planner", "plan_chain")
    plans = call_domain(plan_chain, inst, list(configurations), seed=seed,
                        time_budget_s=time_limit_s)
    return [_motion_out(p) for p in plans]


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
    req: PlanRequest, inst: Instrument, progress: Progress = _noop, *, time_limit_s: float
) -> dict[str, Any]:
    """Segmentation -> per pointing: allocation (all configurations) -> motion chain."""
    _check_plan()
    seg = segmentation(
        SegmentationRequest(targets=req.targets, threshold_mm=req.threshold_mm,
                            mode=req.segmentation_mode, seed=req.seed), inst
    )
    by_id = {t.id: t for t in req.targets}
    n = max(len(seg["pointings"]), 1)
    progress(0.05)
    out = []
    for i, p in enumerate(seg["pointings"]):
        members = [by_id[t] for t in p["target_ids"]]
        alloc = allocation(
            AllocationRequest(
                targets=members,
                pointing={"ra_deg": p["ra_deg"] % 360.0, "dec_deg": p["dec_deg"],
                          "position_angle_deg": req.position_angle_deg},
                method=req.method, solver=req.solver, configurations="all", seed=req.seed,
            ),
            inst, time_limit_s=time_limit_s,
        )
        progress(0.05 + 0.95 * (i + 0.5) / n)
        configs_q = [
            np.array([[a["theta1_rad"], a["theta2_rad"]] for a in c["assignments"]], float)
            for c in alloc["configurations"]
        ]
        motions = motion_chain(inst, configs_q, seed=req.seed, time_limit_s=time_limit_s)
        out.append({**p, "configurations": alloc["configurations"], "motions": motions,
                    "unallocated": alloc["unallocated"]})
        progress(0.05 + 0.95 * (i + 1) / n)
    n_cfg = sum(len(p["configurations"]) for p in out)
    n_alloc = sum(
        1 for p in out for c in p["configurations"] for a in c["assignments"] if a["target_id"]
    )
    return {
        "tangent_point": seg["tangent_point"],
        "pointings": out,
        "stats": {
            "targets": len(req.targets), "pointings": len(out), "configurations": n_cfg,
            "allocated_targets": n_alloc,
            "motion_plans_failed": sum(
                1 for p in out for m in p["motions"] if m["status"] != "ok"
            ),
            "segmentation": seg["stats"],
        },
    }


_STAGE_CHECKS: dict[str, Callable[[], None]] = {
    "segmentation": _check_segmentation,
    "allocation": _check_allocation,
    "motion-plan": _check_motion,
    "plan": _check_plan,
}


def run(kind: str, request: Any, inst: Instrument, progress: Progress = _noop,
        *, time_limit_s: float) -> dict[str, Any]:
    """Run one stage by its job kind on an already validated (or raw dict) request."""
    model = REQUEST_TYPES[kind]
    req = request if isinstance(request, model) else model.model_validate(request)
    if kind == "segmentation":
        return segmentation(req, inst, progress)  # type: ignore[arg-type]
    if kind == "allocation":
        return allocation(req, inst, progress, time_limit_s=time_limit_s)  # type: ignore[arg-type]
    if kind == "motion-plan":
        return motion_plan(req, inst, progress, time_limit_s=time_limit_s)  # type: ignore[arg-type]
    return plan(req, inst, progress, time_limit_s=time_limit_s)  # type: ignore[arg-type]
