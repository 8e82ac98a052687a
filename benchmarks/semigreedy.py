"""SGPBTA benchmark (issue 5): thesis 5.5 protocol, the 1,200-target dense field, warm starts.

Prints one JSON document. Sections:

* ``protocol``: uniform / heavily clustered (Gaussian sigma 30 mm) / weakly clustered
  (sigma 60 mm) fields of 96/192/384 targets in the 250 mm FOV, priorities 10 % 500,
  40 % 100, 40 % 10, 10 % 1 (thesis 5.5.3). Per family: configurations to 100 %
  completeness for SGPBTA alpha = 0.2 and 0.8; the per-configuration total-priority gap
  against the collision-free matching upper bound (an upper bound on the true gap) and,
  where the exact allocator ran to optimality on the same problem, the true gap; the
  exact allocator's own sequence length where it ran.
* ``dense``: 1,200 targets (Gaussian sigma 60 mm, same priorities), the whole sequence to
  100 %: wall time (median of runs) and configurations.
* ``warm_start``: CP-SAT with and without the heuristic's solution as hints.

The exact allocator is the colleague's ``solvers.ilp`` when importable (HiGHS, time
limit per configuration); the sequencing loop here is a minimal one for this benchmark
only (structure built once with park locations, every configuration starts from park,
allocated targets removed, stop when a configuration allocates nothing).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import numpy as np

from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from solvers.problem import ConfigProblem, check_solution
from solvers.semigreedy import solve_semigreedy, warm_start

INST = default_instrument()
SPEEDS = np.column_stack([INST.arm_array("joint1_speed_rad_s"), INST.arm_array("joint2_speed_rad_s")])
FOV_R = INST.fov_radius_mm
SIGMA = {"uniform": None, "heavy": 30.0, "weak": 60.0}


def make_field(n: int, kind: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    if SIGMA[kind] is None:
        r = FOV_R * np.sqrt(rng.random(n))
        th = rng.random(n) * 2 * np.pi
        x, y = r * np.cos(th), r * np.sin(th)
    else:  # Gaussian about the centre, truncated to the FOV by redrawing
        pts = np.zeros((0, 2))
        while len(pts) < n:
            p = rng.normal(0, SIGMA[kind], (2 * n, 2))
            pts = np.vstack([pts, p[np.hypot(p[:, 0], p[:, 1]) < FOV_R]])
        x, y = pts[:n, 0], pts[:n, 1]
    n500, n100, n10 = round(0.1 * n), round(0.4 * n), round(0.4 * n)
    pri = np.array([500] * n500 + [100] * n100 + [10] * n10 + [1] * (n - n500 - n100 - n10), np.int64)
    rng.shuffle(pri)
    return x, y, pri


def _exact():
    try:
        from solvers.ilp import solve_ilp_highs
    except ImportError:  # the exact allocator has not landed
        return None
    return lambda p: solve_ilp_highs(p, minimize_move=False)


def sequence(inc, x, y, pri, solve, exact=None, check=False, time_limit_s=10.0):
    """Configurations until nothing more is allocated; optional exact solve of each problem."""
    n = len(pri)
    avail = np.ones(n, bool)
    out = {"configs": 0, "time_s": 0.0, "gap_bound": [], "gap_exact": [], "exact_timeouts": 0}
    xy = np.column_stack([x, y])
    while avail.any():
        p = ConfigProblem(inc, pri, avail.copy(), INST.park_configuration, SPEEDS, target_xy_mm=xy,
                          time_limit_s=time_limit_s)
        t0 = time.perf_counter()
        sol = solve(p)
        out["time_s"] += time.perf_counter() - t0
        if check:
            assert check_solution(INST, p, sol.chosen) == []
        t = inc.assignments.target[sol.chosen]
        t = t[t >= 0]
        if not len(t):
            break
        ub = sol.stats.get("upper_bound_priority")
        if ub:
            out["gap_bound"].append((ub - sol.total_priority) / ub)
        if exact is not None:
            e = exact(p)
            if e.status == "optimal" and e.total_priority > 0:
                out["gap_exact"].append((e.total_priority - sol.total_priority) / e.total_priority)
            else:
                out["exact_timeouts"] += 1
        avail[t] = False
        out["configs"] += 1
    out["left"] = int(avail.sum())
    return out


def _mean(v):
    return float(np.mean(v)) if len(v) else None


def protocol(sizes, instances, exact_sizes, sg_opts):
    exact = _exact()
    rows = []
    for kind in ("uniform", "heavy", "weak"):
        for n in sizes:
            res = {f"sg{a}": {"configs": [], "gap_bound": [], "gap_exact": [], "time_s": [], "left": []}
                   for a in (0.2, 0.8)}
            res["exact"] = {"configs": [], "time_s": [], "left": []}
            for i in range(instances):
                x, y, pri = make_field(n, kind, 1000 * n + i)
                inc = incompatibility_for_targets(INST, x, y)
                run_exact = exact is not None and n in exact_sizes
                for a in (0.2, 0.8):
                    r = sequence(inc, x, y, pri, lambda p, a=a, i=i: solve_semigreedy(p, alpha=a, seed=i, **sg_opts),
                                 exact=exact if run_exact else None, check=(i == 0))
                    d = res[f"sg{a}"]
                    d["configs"].append(r["configs"])
                    d["gap_bound"] += r["gap_bound"]
                    d["gap_exact"] += r["gap_exact"]
                    d["time_s"].append(r["time_s"])
                    d["left"].append(r["left"])
                if run_exact:
                    r = sequence(inc, x, y, pri, exact)
                    res["exact"]["configs"].append(r["configs"])
                    res["exact"]["time_s"].append(r["time_s"])
                    res["exact"]["left"].append(r["left"])
            row = {"distribution": kind, "targets": n, "instances": instances,
                   "lower_bound_configs": math.ceil(n / 12)}
            for key, d in res.items():
                row[key] = {
                    "avg_configs": _mean(d["configs"]),
                    "avg_time_s": _mean(d["time_s"]),
                    "avg_left": _mean(d["left"]),
                }
                if key != "exact":
                    row[key]["avg_gap_vs_bound"] = _mean(d["gap_bound"])
                    row[key]["avg_gap_vs_exact"] = _mean(d["gap_exact"])
                    row[key]["configs_compared_with_exact"] = len(d["gap_exact"])
            rows.append(row)
    return rows


def dense(n, runs, sg_opts, with_exact):
    x, y, pri = make_field(n, "weak", 4242)
    t0 = time.perf_counter()
    inc = incompatibility_for_targets(INST, x, y)
    t_inc = time.perf_counter() - t0
    out = {"targets": n, "sigma_mm": SIGMA["weak"], "incompatibility_s": t_inc,
           "lower_bound_configs": math.ceil(n / 12), "options": sg_opts}
    for a in (0.2, 0.8):
        walls, configs, left = [], [], []
        for r in range(runs):
            t0 = time.perf_counter()
            res = sequence(inc, x, y, pri, lambda p, a=a, r=r: solve_semigreedy(p, alpha=a, seed=r, **sg_opts))
            walls.append(time.perf_counter() - t0)
            configs.append(res["configs"])
            left.append(res["left"])
        out[f"sg{a}"] = {"median_wall_s": statistics.median(walls), "walls_s": walls, "configs": configs,
                         "left": left}
    exact = _exact()
    if with_exact and exact is not None:
        t0 = time.perf_counter()
        res = sequence(inc, x, y, pri, exact, time_limit_s=20.0)
        out["exact"] = {"wall_s": time.perf_counter() - t0, "configs": res["configs"], "left": res["left"]}
    return out


def warm_starts(sizes, seeds):
    try:
        from solvers.ilp import solve_ilp_cpsat
    except ImportError:
        return {"skipped": "solvers.ilp not available"}
    rows = []
    for n in sizes:
        for s in seeds:
            x, y, pri = make_field(n, "uniform", 7 * n + s)
            inc = incompatibility_for_targets(INST, x, y)
            p = ConfigProblem(inc, pri, np.ones(n, bool), INST.park_configuration, SPEEDS,
                              target_xy_mm=np.column_stack([x, y]), time_limit_s=20.0)
            t0 = time.perf_counter()
            h = warm_start(p, seed=s)
            t_h = time.perf_counter() - t0
            t0 = time.perf_counter()
            cold = solve_ilp_cpsat(p, minimize_move=False)
            t_cold = time.perf_counter() - t0
            t0 = time.perf_counter()
            warm = solve_ilp_cpsat(p, minimize_move=False, hint=h)
            t_warm = time.perf_counter() - t0
            hp = int(pri[inc.assignments.target[h][inc.assignments.target[h] >= 0]].sum())
            rows.append({"targets": n, "seed": s, "heuristic_s": t_h, "heuristic_priority": hp,
                         "cold_s": t_cold, "cold_status": cold.status, "cold_priority": cold.total_priority,
                         "warm_s": t_warm, "warm_status": warm.status, "warm_priority": warm.total_priority})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, for CI")
    ap.add_argument("--instances", type=int, default=3)
    ap.add_argument("--dense-runs", type=int, default=3)
    ap.add_argument("--exact-sizes", default="96", help="comma list of sizes where the exact allocator runs")
    ap.add_argument("--dense-exact", action="store_true", help="also run the exact allocator on the dense field")
    ap.add_argument("--skip", default="", help="comma list of sections to skip: protocol,dense,warm_start")
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    fast = {"penalty_matrix": "workspace", "max_stall": 5}
    thesis = {"penalty_matrix": "thesis", "n_iter": 30, "gamma": 0.1, "arm_selection": "pbas"}
    exact_sizes = {int(v) for v in args.exact_sizes.split(",") if v}
    out: dict = {"machine_note": "2 shared cores; wall times are noisy"}
    t0 = time.perf_counter()
    if args.smoke:
        out["protocol"] = protocol([96], 1, set(), thesis) if "protocol" not in skip else None
        out["dense"] = dense(300, 1, fast, False) if "dense" not in skip else None
        out["warm_start"] = None
    else:
        if "protocol" not in skip:
            out["protocol_thesis_settings"] = {"options": thesis,
                                               "rows": protocol([96, 192, 384], args.instances, exact_sizes, thesis)}
        if "dense" not in skip:
            out["dense"] = dense(1200, args.dense_runs, fast, args.dense_exact)
            out["dense_thesis_settings"] = dense(1200, 1, thesis, False)
        if "warm_start" not in skip:
            out["warm_start"] = warm_starts([96, 384], [0, 1])
    out["total_s"] = time.perf_counter() - t0
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
