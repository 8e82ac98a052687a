"""Position angle and the park move limit (issue 38): targets a plan's pointings lose to arm
reach within the park move limit, against those some position angle would reach; prints JSON.

Protocol: the thesis fields of ``benchmarks/motion.py`` (6.4.2; ``--targets`` targets in the
250 mm FOV, uniform and Gaussian clusters of sigma 40, 60, 90 mm, the thesis priority mix),
put on the sky about (150, 2) deg and segmented as ``POST /v1/plans`` segments them at its
defaults (mode fewest-exposures, park move limit 120 s, limit 120 s), with
``position_angle_deg`` "auto" (the angle search) and with 0 (the requested angle, which the
optimiser turns only when it loses targets).

For every member of every pointing, an oracle independent of the planner's reach tables
(models.kinematics.inverse_fov for every arm and IK branch, and the move from park,
positive_turn_move_time_s, within the limit) says whether an arm reaches it at the pointing's
chosen angle, and whether one reaches it at any angle of the range (every 0.5 deg). A member
``lost`` is not reached at the chosen angle; ``lost_but_reachable`` is lost while some angle
reaches it; ``lost_beyond_best_angle``: the members lost at the chosen angle beyond the fewest
any one angle loses (the goal: 0; several rim members may need angles no one angle gives).

Usage:
    python benchmarks/pa_rim.py                 # 20 fields of 100 targets
    python benchmarks/pa_rim.py --fields 4 --targets 40     # a quick run
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.motion_fields import thesis_field, thesis_field_parameters  # noqa: E402
from models.instrument import Instrument  # noqa: E402
from models.kinematics import inverse_fov, positive_turn_move_time_s  # noqa: E402
from models.sky import focal_mm_to_sky, sky_to_focal_mm  # noqa: E402

CENTRE_DEG = (150.0, 2.0)
LIMIT_S = 120.0
SCAN_STEP_DEG = 0.5


def reached(inst: Instrument, x_mm: np.ndarray, y_mm: np.ndarray, limit_s: float = LIMIT_S) -> np.ndarray:
    """(n,) whether some enabled arm, on some IK branch, reaches each FOV point with a move from
    park of at most ``limit_s``."""
    arms = np.array([a.index for a in inst.arms if a.enabled])
    ik = inverse_fov(inst, arms[:, None], np.asarray(x_mm)[None, :], np.asarray(y_mm)[None, :])
    q = np.stack([ik.theta1_rad, ik.theta2_rad], axis=-1)
    park = inst.park_configuration[arms][:, None, None, :]
    v1 = inst.arm_array("joint1_speed_rad_s")[arms][:, None, None]
    v2 = inst.arm_array("joint2_speed_rad_s")[arms][:, None, None]
    t_s = positive_turn_move_time_s(park, q, v1, v2)
    return np.any(ik.valid & (t_s <= limit_s), axis=(0, 2))


def reached_at_some_angle(inst: Instrument, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """(n,) whether some position angle (every SCAN_STEP_DEG) brings each point (given at
    angle 0) within reach: a turn of the field by a is a turn of the point by a."""
    out = np.zeros(len(x_mm), bool)
    for a in np.arange(0.0, 360.0, SCAN_STEP_DEG):
        c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
        out |= reached(inst, c * x_mm - s * y_mm, s * x_mm + c * y_mm)
        if out.all():
            break
    return out


def fewest_lost(inst: Instrument, x_mm: np.ndarray, y_mm: np.ndarray) -> int:
    """The fewest points (given at angle 0) any one position angle (every SCAN_STEP_DEG) leaves
    out of reach."""
    best = len(x_mm)
    for a in np.arange(0.0, 360.0, SCAN_STEP_DEG):
        c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
        best = min(best, int((~reached(inst, c * x_mm - s * y_mm, s * x_mm + c * y_mm)).sum()))
        if best == 0:
            break
    return best


def field_request(n: int, seed: int, index: int, position_angle) -> tuple[str, object]:
    from service.schemas import PlanRequest

    shape, t = thesis_field(n, seed, index)
    ra, dec = focal_mm_to_sky(t.x_mm, t.y_mm, CENTRE_DEG[0], CENTRE_DEG[1], 1.2)
    targets = [{"id": f"t{i}", "ra_deg": float(ra[i]), "dec_deg": float(dec[i]), "priority": int(t.priority[i])}
               for i in range(len(t.ids))]
    return shape, PlanRequest.model_validate({"targets": targets, "seed": seed, "position_angle_deg": position_angle})


def field_losses(inst: Instrument, req, shape: str) -> dict:
    from service import pipeline

    t0 = time.perf_counter()
    seg = pipeline.segment_plan(req, inst, 120.0)
    wall_s = time.perf_counter() - t0
    ra = np.array([t.ra_deg for t in req.targets])
    dec = np.array([t.dec_deg for t in req.targets])
    lost = lost_reachable = members = beyond = 0
    for p in seg.pointings:
        m = np.asarray(p.target_indices)
        pa = float(p.position_angle_deg or 0.0)
        x, y = sky_to_focal_mm(ra[m], dec[m], p.ra_deg, p.dec_deg, 1.2, pa)
        miss = ~reached(inst, x, y)
        members += len(m)
        lost += int(miss.sum())
        if miss.any():
            lost_reachable += int(reached_at_some_angle(inst, x[miss], y[miss]).sum())
            x0, y0 = sky_to_focal_mm(ra[m], dec[m], p.ra_deg, p.dec_deg, 1.2, 0.0)
            beyond += int(miss.sum()) - fewest_lost(inst, x0, y0)
    return {"shape": shape, "targets": len(ra), "pointings": len(seg.pointings), "members": members,
            "lost": lost, "lost_but_reachable": lost_reachable, "lost_beyond_best_angle": beyond,
            "segmentation_s": round(wall_s, 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fields", type=int, default=20)
    ap.add_argument("--targets", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    from service import pipeline

    inst = pipeline.instrument_from(None)
    out = {"protocol": "thesis 6.4.2 fields on the sky, segmented at the plan defaults",
           "parameters": {**vars(args), **thesis_field_parameters(), "park_move_limit_s": LIMIT_S,
                          "scan_step_deg": SCAN_STEP_DEG}, "modes": {}}
    for label, pa in (("auto", "auto"), ("fixed_0", 0.0)):
        rows = []
        for i in range(args.fields):
            shape, req = field_request(args.targets, args.seed, i, pa)
            rows.append(field_losses(inst, req, shape))
            print(f"[{label} {i + 1}/{args.fields}] {rows[-1]}", file=sys.stderr)
        out["modes"][label] = {"fields": rows, "lost": sum(r["lost"] for r in rows),
                               "lost_but_reachable": sum(r["lost_but_reachable"] for r in rows),
                               "lost_beyond_best_angle": sum(r["lost_beyond_best_angle"] for r in rows),
                               "members": sum(r["members"] for r in rows)}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
