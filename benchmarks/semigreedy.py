"""SGPBTA benchmark (issue 5): thesis 5.5 protocol side by side with the exact allocator,
and the 1,200-target dense field. Prints one JSON document.

Both allocators run through ONE sequencing driver, :func:`solvers.sequencing.
sequence_configurations` (what ``solvers.allocation.allocate(configurations="all")``
calls): structure built once per field, each configuration starts where the previous one
ended, every configuration re-checked geometrically, optional CP-SAT tail repacking. Fields
come from ``benchmarks.allocation.make_field`` so the two benchmarks measure the same kind
of field: uniform in the 250 mm FOV, heavily clustered (Gaussian sigma 30 mm) and weakly
clustered (sigma 60 mm) about the centre, priorities drawn 10 % 500 / 40 % 100 / 40 % 10 /
10 % 1 (thesis 5.5.3; the thesis does not print its sigmas).

Sections:

* ``protocol``: per (distribution, size 96/192/384), over ``--instances`` fields:
  configurations to 100 % completeness, before (``greedy``) and after the driver's tail
  repacking, for the exact allocator (``allocate(method="ilp")`` with the driver's default
  exact back-end) and for SGPBTA
  alpha = 0.2 / 0.8 with the thesis settings (eq. 5.21 matrix, 30 runs, gamma 0.1, PBAS)
  -- ``sg*`` through ``allocate(method="semigreedy")`` (the driver's own structure, no
  blank-sky locations) and ``sg*_blank`` on the same driver with a structure holding 8
  blank-sky locations per arm (thesis Alg. 5 padding). For ``sg*_blank`` every
  configuration is also solved exactly on the very same problem: ``avg_gap_vs_exact`` is
  the mean relative total-priority gap per configuration (0 = optimal).
* ``warm_start``: CP-SAT on one configuration, cold and with SGPBTA's solution as hint.
* ``dense``: 1,200 targets (sigma 60 mm), the fast settings (workspace patrolling,
  ``max_stall`` 5), whole sequence to completeness without repacking: wall time (median of
  runs), configurations; incompatibility build time reported separately and in a total.
  The exact allocator on the same field is optional (``--dense-exact``; ~7 min).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
import zlib
from functools import partial

import numpy as np

from benchmarks.allocation import make_field
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from solvers.allocation import allocate
from solvers.semigreedy import solve_semigreedy
from solvers.sequencing import sequence_configurations

INST = default_instrument()
THESIS = {"penalty_matrix": "thesis", "n_iter": 30, "gamma": 0.1, "arm_selection": "pbas"}
FAST = {"penalty_matrix": "workspace", "max_stall": 5}
BLANK_PER_ARM = 8


def field_rng(n: int, dist: str, i: int) -> np.random.Generator:
    """A stable seed per (size, distribution, instance) -- str hash() is salted per process."""
    return np.random.default_rng([n, zlib.crc32(dist.encode()), i])


def _exact_solver():
    from solvers.ilp import solve_ilp_cpsat  # what allocate(method="ilp") uses by default

    return solve_ilp_cpsat


def run_sg_with_gap(targets, alpha, seed, opts, exact, time_limit_s):
    """SGPBTA on the driver with a blank-sky structure; each configuration also solved
    exactly on the same problem (per-configuration total-priority gap)."""
    inc = incompatibility_for_targets(INST, targets.x_mm, targets.y_mm, blank_per_arm=BLANK_PER_ARM, seed=seed)
    gaps: list[float] = []
    not_optimal = [0]

    def solve(p):
        sol = solve_semigreedy(p, alpha=alpha, **opts)
        if exact is not None:
            e = exact(p)
            if e.status != "optimal":
                not_optimal[0] += 1
            elif e.total_priority > 0:
                gaps.append((e.total_priority - sol.total_priority) / e.total_priority)
        return sol

    t0 = time.perf_counter()
    r = sequence_configurations(INST, targets, solve, incompatibility=inc, seed=seed, time_limit_s=time_limit_s,
                                config_time_limit_s=5.0)
    return r, time.perf_counter() - t0, gaps, not_optimal[0]


def protocol(sizes, dists, instances, sg_opts, with_exact, gap_sizes, time_limit_s):
    exact = _exact_solver() if with_exact else None
    rows = []
    for dist in dists:
        for n in sizes:
            acc: dict[str, dict[str, list]] = {}

            def add(key, r, wall, acc=acc):
                d = acc.setdefault(key, {"configs": [], "greedy": [], "wall_s": [], "complete": [], "gap": []})
                d["configs"].append(r.stats["n_configurations"])
                d["greedy"].append(r.stats["n_configurations_greedy"])
                d["wall_s"].append(wall)
                d["complete"].append(r.stats["field_completeness"])

            for i in range(instances):
                targets = make_field(n, dist, field_rng(n, dist, i))
                if with_exact:
                    t0 = time.perf_counter()
                    r = allocate(INST, targets, method="ilp", configurations="all", time_limit_s=time_limit_s, seed=i)
                    add("exact", r, time.perf_counter() - t0)
                for a in (0.2, 0.8):
                    t0 = time.perf_counter()
                    r = allocate(INST, targets, method="semigreedy", configurations="all", time_limit_s=time_limit_s,
                                 seed=i, alpha=a, **sg_opts)
                    add(f"sg{a}", r, time.perf_counter() - t0)
                    r, wall, gaps, not_opt = run_sg_with_gap(targets, a, i, sg_opts,
                                                             exact if n in gap_sizes else None, time_limit_s)
                    add(f"sg{a}_blank", r, wall)
                    acc[f"sg{a}_blank"]["gap"] += gaps
                    acc[f"sg{a}_blank"].setdefault("exact_not_optimal", []).append(not_opt)
            row = {"distribution": dist, "targets": n, "instances": instances, "ceil_t_over_12": math.ceil(n / 12)}
            for key, d in acc.items():
                row[key] = {
                    "avg_configurations": statistics.mean(d["configs"]),
                    "avg_configurations_before_repack": statistics.mean(d["greedy"]),
                    "max_configurations": max(d["configs"]),
                    "avg_field_completeness": statistics.mean(d["complete"]),
                    "median_wall_s": statistics.median(d["wall_s"]),
                }
                if d["gap"] or key.endswith("_blank"):
                    row[key]["avg_gap_vs_exact"] = statistics.mean(d["gap"]) if d["gap"] else None
                    row[key]["share_configurations_optimal"] = (
                        float(np.mean(np.asarray(d["gap"]) <= 1e-12)) if d["gap"] else None)
                    row[key]["configurations_compared"] = len(d["gap"])
            rows.append(row)
            print(json.dumps({"row": row}, default=float), flush=True)  # partial results as they come
    return rows


def dense(n, runs, sg_opts, with_exact, time_limit_s):
    out = {"targets": n, "distribution": "weak (sigma 60 mm)", "options": sg_opts,
           "ceil_t_over_12": math.ceil(n / 12), "runs": []}
    for i in range(runs):
        targets = make_field(n, "weak", np.random.default_rng(100 + i))  # benchmarks/allocation.py's dense
        t0, c0 = time.perf_counter(), time.process_time()
        inc = incompatibility_for_targets(INST, targets.x_mm, targets.y_mm, blank_per_arm=BLANK_PER_ARM, seed=i)
        t_inc, c_inc = time.perf_counter() - t0, time.process_time() - c0
        run = {"field_seed": 100 + i, "incompatibility_s": t_inc, "incompatibility_cpu_s": c_inc}
        for a in (0.2, 0.8):
            t0, c0 = time.perf_counter(), time.process_time()
            r = sequence_configurations(INST, targets, partial(solve_semigreedy, alpha=a, **sg_opts),
                                        incompatibility=inc, seed=i, time_limit_s=time_limit_s, repack=False)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            run[f"sg{a}"] = {"sequence_wall_s": wall, "sequence_cpu_s": cpu,
                             "total_with_incompatibility_s": wall + t_inc,
                             "configurations": r.stats["n_configurations"],
                             "field_completeness": r.stats["field_completeness"],
                             "unallocated": [u.reason for u in r.unallocated]}
        if with_exact:
            t0 = time.perf_counter()
            r = allocate(INST, targets, method="ilp", configurations="all", time_limit_s=3600.0, seed=i)
            run["exact"] = {"wall_s": time.perf_counter() - t0, "configurations": r.stats["n_configurations"],
                            "configurations_before_repack": r.stats["n_configurations_greedy"],
                            "field_completeness": r.stats["field_completeness"]}
        out["runs"].append(run)
    for a in (0.2, 0.8):
        k = f"sg{a}"
        out[k] = {"median_sequence_wall_s": statistics.median(r[k]["sequence_wall_s"] for r in out["runs"]),
                  "median_sequence_cpu_s": statistics.median(r[k]["sequence_cpu_s"] for r in out["runs"]),
                  "median_total_with_incompatibility_s": statistics.median(
                      r[k]["total_with_incompatibility_s"] for r in out["runs"]),
                  "configurations": [r[k]["configurations"] for r in out["runs"]]}
    out["median_incompatibility_s"] = statistics.median(r["incompatibility_s"] for r in out["runs"])
    return out


def warm_starts(cases, seeds):
    """CP-SAT on one configuration, cold and hinted with SGPBTA's solution (``warm_start``)."""
    from solvers.ilp import solve_ilp_cpsat
    from solvers.problem import ConfigProblem
    from solvers.semigreedy import warm_start
    from solvers.sequencing import joint_speeds

    rows = []
    for n, dist in cases:
        for sd in seeds:
            t = make_field(n, dist, field_rng(n, dist, 1000 + sd))
            inc = incompatibility_for_targets(INST, t.x_mm, t.y_mm)
            p = ConfigProblem(inc, np.asarray(t.priority, np.int64), np.ones(n, bool), INST.park_configuration,
                              joint_speeds(INST), target_xy_mm=np.column_stack([t.x_mm, t.y_mm]),
                              time_limit_s=30.0, seed=sd)
            t0 = time.perf_counter()
            h = warm_start(p, seed=sd)
            t_h = time.perf_counter() - t0
            t0 = time.perf_counter()
            cold = solve_ilp_cpsat(p)
            t_cold = time.perf_counter() - t0
            t0 = time.perf_counter()
            warm = solve_ilp_cpsat(p, hint=h)
            t_warm = time.perf_counter() - t0
            rows.append({"targets": n, "distribution": dist, "seed": sd, "heuristic_s": t_h,
                         "heuristic_priority": p.assignment_priority()[h].sum(),
                         "cold_s": t_cold, "cold_status": cold.status, "cold_priority": cold.total_priority,
                         "warm_s": t_warm, "warm_status": warm.status, "warm_priority": warm.total_priority})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, for CI")
    ap.add_argument("--instances", type=int, default=3)
    ap.add_argument("--sizes", default="96,192,384")
    ap.add_argument("--dists", default="uniform,heavy,weak")
    ap.add_argument("--gap-sizes", default="96,192,384", help="sizes where every SGPBTA configuration is also "
                                                             "solved exactly (per-configuration gap)")
    ap.add_argument("--no-exact", action="store_true", help="skip the exact allocator in the protocol")
    ap.add_argument("--dense-runs", type=int, default=3)
    ap.add_argument("--dense-exact", action="store_true", help="also run the exact allocator on the dense field")
    ap.add_argument("--skip", default="", help="comma list of sections to skip: protocol,warm_start,dense")
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    out: dict = {"machine_note": "2 cores shared with other jobs; wall times are noisy"}
    t0 = time.perf_counter()
    sizes = [int(v) for v in args.sizes.split(",") if v]
    gap_sizes = {int(v) for v in args.gap_sizes.split(",") if v}
    dists = [d for d in args.dists.split(",") if d]
    if args.smoke:
        sizes, dists, args.instances, gap_sizes = [96], ["uniform"], 1, {96}
    if "protocol" not in skip:
        out["protocol"] = {"sg_options": THESIS, "blank_per_arm": BLANK_PER_ARM,
                           "rows": protocol(sizes, dists, args.instances, THESIS, not args.no_exact, gap_sizes,
                                            120.0)}
    if "warm_start" not in skip:
        out["warm_start"] = warm_starts([(96, "uniform")] if args.smoke else
                                        [(384, "uniform"), (384, "heavy"), (1200, "weak")], [0] if args.smoke else [0, 1])
    if "dense" not in skip:
        out["dense"] = dense(300 if args.smoke else 1200, 1 if args.smoke else args.dense_runs, FAST,
                             args.dense_exact, 600.0)
    out["total_s"] = time.perf_counter() - t0
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
