"""SGPBTA benchmark (issue 5): thesis 5.5 protocol side by side with the exact allocator,
and the 1,200-target dense field. Prints one JSON document.

Both allocators run through ONE sequencing driver, :func:`solvers.sequencing.
sequence_configurations` (what ``solvers.allocation.allocate(configurations="all")``
calls): structure built once per field, each configuration starts where the previous one
ended, every configuration re-checked geometrically, targets left as ``conflict`` rescued.
Fields come from ``benchmarks.allocation.make_field``: uniform in the 250 mm FOV, heavily
clustered (Gaussian sigma 30 mm) and weakly clustered (sigma 60 mm) about the centre,
priorities drawn 10 % 500 / 40 % 100 / 40 % 10 / 10 % 1 (thesis 5.5.3; the thesis does not
print its sigmas). Field i of a cell is seeded by (size, distribution, i).

Sections:

* ``protocol``: per (distribution, size 96/192/384), over ``--instances`` fields (default
  20), configurations to 100 % completeness and completeness reached, for

  - ``exact``: ``allocate(method="ilp", solver="bnb")`` (the branch-and-bound) with a
    modest per-configuration limit ``config_time_limit_s = EXACT_CONFIG_S``, one
    configuration at a time as in the thesis protocol: no ejection repair, no repacking
    (``--exact-repack``: with the driver's repair and CP-SAT tail repacking, much slower);
  - ``sg0.2`` / ``sg0.8``: SGPBTA at its defaults (thesis 5.5.3.1: eq. 5.21 matrix, 30 runs,
    gamma 0.1, PBAS) with alpha 0.2 / 0.8, on a structure with ``BLANK_PER_ARM`` blank-sky
    locations per arm (Algorithm 5 padding), one configuration at a time too: no
    sequence repair, no tail repacking (a CP-SAT model, not the heuristic). Every configuration SGPBTA returns is also solved exactly on the
    very same problem (``bnb``, ``GAP_CONFIG_S`` per configuration):
    ``avg_gap_vs_exact`` is the mean relative total-priority gap per configuration
    (0 = optimal), over the configurations whose exact optimum was proven.

  ``--exact-json FILE`` reuses the per-instance exact records of an earlier output.
* ``warm_start``: CP-SAT on one configuration, cold and with SGPBTA's solution as hint.
* ``dense``: 1,200 targets (sigma 60 mm), fields seeded 100, 101, ...: the whole sequence
  to completeness through ``allocate(method="semigreedy", configurations="all")`` at the
  SGPBTA defaults (only alpha set), ``blank_per_arm=BLANK_PER_ARM``, ``repack=False``:
  ``sg<alpha>`` SGPBTA alone (``repair=False``, ``time_limit_s=DENSE_BUDGET_S``);
  ``sg<alpha>+repair`` (``--dense-repair``) with the driver's ejection repair of the
  whole sequence (solvers.sequencing.repair, no geometry, no CP-SAT) inside a call budget of
  ``time_limit_s=DENSE_REPAIR_BUDGET_S``, which also bounds the repair;
  wall time INCLUDING the incompatibility structure, medians over fields x repeats.
  ``--dense-exact`` also runs the exact allocator on the same fields (20 s budget).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import time
import zlib

import numpy as np

from benchmarks.allocation import make_field
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from solvers.allocation import (
    AllocationOptions,
    PackingOptions,
    RepairOptions,
    SemiGreedyOptions,
    SequenceOptions,
    allocate,
)
from solvers.allocation.semigreedy import solve_semigreedy
from solvers.sequencing import SequencingOptions, sequence_configurations

INST = default_instrument()
BLANK_PER_ARM = 16  # blank-sky locations per arm in SGPBTA's structure (Alg. 5 padding)
EXACT_CONFIG_S = 2.0  # per-configuration limit of the exact column
EXACT_FIELD_S = 60.0  # whole-sequence limit of one field, both columns
GAP_CONFIG_S = 2.0  # per-configuration limit of the exact re-solve behind the gap
ALPHAS = (0.2, 0.8)
# the dense call's budget: allocate()'s default 10 s includes the structure and, on a
# heavily loaded machine, ran out before the first configuration
DENSE_BUDGET_S = 60.0
# with the sequence repair: the whole call, structure included, limited to this (the repair
# gets at most half of what is left, so the budget bounds it)
DENSE_REPAIR_BUDGET_S = 3.0


def field_rng(n: int, dist: str, i: int) -> np.random.Generator:
    """A stable seed per (size, distribution, instance) -- str hash() is salted per process."""
    return np.random.default_rng([n, zlib.crc32(dist.encode()), i])


def run_exact(targets, seed: int, repack: bool = False, field_limit_s: float | None = None) -> dict:
    t0 = time.perf_counter()
    r = allocate(INST, targets, method="ilp", solver="bnb", configurations="all",
                 time_limit_s=field_limit_s or EXACT_FIELD_S, seed=seed,
                 options=AllocationOptions(sequence=SequenceOptions(config_time_limit_s=EXACT_CONFIG_S),
                                           repair=RepairOptions(enabled=repack),
                                           packing=PackingOptions(enabled=repack)))
    return {"wall_s": time.perf_counter() - t0, "configurations": r.stats["n_configurations"],
            "before_repack": r.stats["n_configurations_greedy"],
            "complete": r.stats["field_completeness"], "stop": r.stats["stop_reason"]}


def run_sg(targets, alpha: float, seed: int, with_gap: bool, gap_every: int = 1) -> dict:
    """SGPBTA at its defaults through the driver; each configuration re-solved exactly.

    ``tie_break=False`` as in ``allocate(method="semigreedy")``: SGPBTA then uses its own
    crowding weights (25 mm), not the driver's (15 mm)."""
    from solvers.allocation.bnb import solve_ilp_bnb

    gaps: list[float] = []
    not_optimal = [0]
    t_gap = [0.0]

    n_solved = [0]

    def solve(p):
        sol = solve_semigreedy(p, SemiGreedyOptions(alpha=alpha))
        n_solved[0] += 1
        if with_gap and (n_solved[0] - 1) % gap_every == 0:
            tg = time.perf_counter()
            e = solve_ilp_bnb(dataclasses.replace(p, time_limit_s=GAP_CONFIG_S))
            t_gap[0] += time.perf_counter() - tg
            if e.status != "optimal":
                not_optimal[0] += 1
            elif e.total_priority > 0:
                gaps.append((e.total_priority - sol.total_priority) / e.total_priority)
        return sol

    t0 = time.perf_counter()
    r = sequence_configurations(INST, targets, solve,
                                SequencingOptions(sequence=SequenceOptions(blank_per_arm=BLANK_PER_ARM,
                                                                           tie_break=False),
                                                  repair=RepairOptions(enabled=False),
                                                  packing=PackingOptions(enabled=False)), seed=seed,
                                time_limit_s=EXACT_FIELD_S + 100 * with_gap)
    return {"wall_s": time.perf_counter() - t0 - t_gap[0], "configurations": r.stats["n_configurations"],
            "complete": r.stats["field_completeness"], "stop": r.stats["stop_reason"],
            "gaps": gaps, "exact_not_optimal": not_optimal[0]}


def _summary(recs: list[dict]) -> dict:
    out = {"avg_configurations": statistics.mean(r["configurations"] for r in recs),
           "max_configurations": max(r["configurations"] for r in recs),
           "avg_field_completeness": statistics.mean(r["complete"] for r in recs),
           "instances_complete": sum(r["complete"] >= 1.0 for r in recs),
           "median_wall_s": statistics.median(r["wall_s"] for r in recs)}
    if "before_repack" in recs[0]:
        out["avg_configurations_before_repack"] = statistics.mean(r["before_repack"] for r in recs)
    if "gaps" in recs[0]:
        g = [x for r in recs for x in r["gaps"]]
        out["avg_gap_vs_exact"] = statistics.mean(g) if g else None
        out["max_gap_vs_exact"] = max(g) if g else None
        out["share_configurations_optimal"] = float(np.mean(np.asarray(g) <= 1e-12)) if g else None
        out["configurations_compared"] = len(g)
        out["configurations_exact_not_proven"] = sum(r["exact_not_optimal"] for r in recs)
    return out


def protocol(sizes, dists, instances, sides, with_gap, exact_cache, exact_repack=False, first=0, gap_every=1,
             field_limit_s=None):
    rows = []
    for dist in dists:
        for n in sizes:
            recs: dict[str, list[dict]] = {}
            for i in range(first, instances):
                targets = make_field(n, dist, field_rng(n, dist, i))
                if "exact" in sides:
                    key = f"{dist}/{n}/{i}"
                    rec = exact_cache.get(key) or run_exact(targets, i, exact_repack, field_limit_s)
                    rec["key"] = key
                    recs.setdefault("exact", []).append(rec)
                if "sg" in sides:
                    for a in ALPHAS:
                        recs.setdefault(f"sg{a}", []).append(run_sg(targets, a, i, with_gap, gap_every))
                print(json.dumps({"instance": {"distribution": dist, "targets": n, "i": i,
                                               **{k: v[-1] for k, v in recs.items()}}}, default=float), flush=True)
            row = {"distribution": dist, "targets": n, "instances": instances - first,
                   "ceil_t_over_12": math.ceil(n / 12)}
            for k, v in recs.items():
                row[k] = _summary(v)
            if "exact" in recs:
                row["exact_instances"] = recs["exact"]
            rows.append(row)
            print(json.dumps({"row": {k: v for k, v in row.items() if k != "exact_instances"}}, default=float),
                  flush=True)  # partial results as they come
    return rows


def dense(n, fields, repeats, with_exact, with_repair=False):
    out = {"targets": n, "distribution": "weak (sigma 60 mm)", "blank_per_arm": BLANK_PER_ARM, "repack": False,
           "repair_budget_s": DENSE_REPAIR_BUDGET_S, "ceil_t_over_12": math.ceil(n / 12),
           "load_before": os.getloadavg(), "runs": []}
    variants = [(a, False) for a in ALPHAS] + ([(a, True) for a in ALPHAS] if with_repair else [])
    for i in range(fields):
        targets = make_field(n, "weak", np.random.default_rng(100 + i))  # benchmarks/allocation.py's dense
        for rep in range(repeats):
            for a, repair in variants:
                t0, c0 = time.perf_counter(), time.process_time()
                r = allocate(INST, targets, method="semigreedy", configurations="all", seed=i,
                             time_limit_s=DENSE_REPAIR_BUDGET_S if repair else DENSE_BUDGET_S,
                             options=AllocationOptions(engine=SemiGreedyOptions(alpha=a),
                                                       sequence=SequenceOptions(blank_per_arm=BLANK_PER_ARM),
                                                       repair=RepairOptions(enabled=repair),
                                                       packing=PackingOptions(enabled=False)))
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                out["runs"].append({"field_seed": 100 + i, "repeat": rep, "alpha": a, "repair": repair,
                                    "wall_s": wall, "cpu_s": cpu, "load": os.getloadavg()[0],
                                    "incompatibility_s": r.stats["timers_s"]["incompatibility_s"],
                                    "rescue_s": r.stats["timers_s"].get("rescue_s", 0.0),
                                    "repair_s": r.stats["timers_s"].get("repair_s", 0.0),
                                    "configurations": r.stats["n_configurations"],
                                    "before_repair": r.stats["n_configurations_greedy"],
                                    "field_completeness": r.stats["field_completeness"],
                                    "stop_reason": r.stats["stop_reason"],
                                    "unallocated": [u.reason for u in r.unallocated]})
        if with_exact:
            t0 = time.perf_counter()
            r = allocate(INST, targets, method="ilp", solver="bnb", configurations="all", time_limit_s=20.0, seed=i)
            out.setdefault("exact", []).append({"field_seed": 100 + i, "wall_s": time.perf_counter() - t0,
                                                "configurations": r.stats["n_configurations"],
                                                "field_completeness": r.stats["field_completeness"]})
    for a, repair in variants:
        runs = [r for r in out["runs"] if r["alpha"] == a and r["repair"] == repair]
        out[f"sg{a}" + ("+repair" if repair else "")] = {
            "median_wall_s_with_incompatibility": statistics.median(r["wall_s"] for r in runs),
            "max_wall_s_with_incompatibility": max(r["wall_s"] for r in runs),
            "median_cpu_s": statistics.median(r["cpu_s"] for r in runs),
            "median_incompatibility_s": statistics.median(r["incompatibility_s"] for r in runs),
            "configurations_per_field_and_repeat": [[r["configurations"] for r in runs if r["field_seed"] == 100 + i]
                                                    for i in range(fields)],
            "all_complete": all(r["field_completeness"] >= 1.0 for r in runs),
            # a run cut short by the call budget (stop_reason no_time) leaves targets out: its
            # configuration count is not comparable
            "incomplete_runs": sum(r["field_completeness"] < 1.0 for r in runs)}
    out["load_after"] = os.getloadavg()
    return out


def warm_starts(cases, seeds):
    """CP-SAT on one configuration, cold and hinted with SGPBTA's solution (``warm_start``)."""
    from solvers.allocation.cpsat import solve_ilp_cpsat
    from solvers.allocation.semigreedy import warm_start
    from solvers.problem import ConfigProblem
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
            h = warm_start(p, SemiGreedyOptions(seed=sd))
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
    ap.add_argument("--instances", type=int, default=20)
    ap.add_argument("--first-instance", type=int, default=0, help="run instances first..instances-1 (to split a "
                                                                   "cell over processes)")
    ap.add_argument("--gap-every", type=int, default=1, help="re-solve every k-th SGPBTA configuration exactly")
    ap.add_argument("--field-limit", type=float, default=EXACT_FIELD_S, help="whole-sequence limit of the exact "
                                                                            "column per field, s")
    ap.add_argument("--sizes", default="96,192,384")
    ap.add_argument("--dists", default="uniform,heavy,weak")
    ap.add_argument("--sides", default="exact,sg", help="protocol columns: exact, sg or both")
    ap.add_argument("--no-gap", action="store_true", help="skip the exact re-solve of every SGPBTA configuration")
    ap.add_argument("--exact-json", help="reuse the per-instance exact records of an earlier output")
    ap.add_argument("--exact-repack", action="store_true", help="exact column with the driver's CP-SAT tail "
                                                                "repacking (default: one configuration at a "
                                                                "time, the thesis protocol, as SGPBTA)")
    ap.add_argument("--dense-fields", type=int, default=3)
    ap.add_argument("--dense-repeats", type=int, default=3)
    ap.add_argument("--dense-exact", action="store_true", help="also run the exact allocator on the dense fields")
    ap.add_argument("--dense-repair", action="store_true", help="also run SGPBTA + the driver's sequence repair "
                                                                "(time_limit_s=DENSE_REPAIR_BUDGET_S)")
    ap.add_argument("--skip", default="warm_start", help="comma list of sections to skip: protocol,warm_start,dense")
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    out: dict = {"machine_note": "2 cores shared with other jobs; wall times are noisy",
                 "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "load_start": os.getloadavg()}
    t0 = time.perf_counter()
    sizes = [int(v) for v in args.sizes.split(",") if v]
    dists = [d for d in args.dists.split(",") if d]
    sides = set(args.sides.split(","))
    if args.smoke:
        sizes, dists, args.instances, args.dense_fields, args.dense_repeats = [96], ["uniform"], 1, 1, 1
    cache: dict = {}
    if args.exact_json:
        with open(args.exact_json) as fh:
            for row in json.load(fh)["protocol"]["rows"]:
                for rec in row.get("exact_instances", []):
                    cache[rec["key"]] = rec
    if "protocol" not in skip:
        out["protocol"] = {"exact_config_time_limit_s": EXACT_CONFIG_S, "field_time_limit_s": args.field_limit,
                           "gap_config_time_limit_s": GAP_CONFIG_S, "sg_blank_per_arm": BLANK_PER_ARM,
                           "exact_repack": args.exact_repack,
                           "gap_every": args.gap_every,
                           "rows": protocol(sizes, dists, args.instances, sides, not args.no_gap, cache,
                                            args.exact_repack, args.first_instance, args.gap_every,
                                            args.field_limit)}
    if "warm_start" not in skip:
        out["warm_start"] = warm_starts([(96, "uniform")] if args.smoke else
                                        [(384, "uniform"), (384, "heavy"), (1200, "weak")], [0] if args.smoke else [0, 1])
    if "dense" not in skip:
        out["dense"] = dense(300 if args.smoke else 1200, args.dense_fields, args.dense_repeats, args.dense_exact,
                             args.dense_repair)
    out["total_s"] = time.perf_counter() - t0
    out["load_end"] = os.getloadavg()
    print(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
