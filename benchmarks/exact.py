"""Exact engines on dense fields (issue 18): bnb, HiGHS and CP-SAT on the same fields.

Prints one JSON document:

* ``one``: one configuration at ``--targets`` targets (Gaussian sigma 40 mm, sigma 60 mm,
  uniform; priorities 10 % 500 / 40 % 100 / 40 % 10 / 10 % 1, thesis 5.5.3).  Per engine:
  proof status of each lexicographic tier (priority + yield, longest move, tie-break),
  total priority, arm yield, longest move, engine time and the wall time of
  ``allocate(configurations="one")``; per field the LP bound of the priority/yield model
  before (all allowed columns, aggregated rows of eq. 5.15) and after (pruned columns +
  clique rows, solvers.allocation.exact) against the optimum.
* ``tier_transition``: the same LP bounds mid-sequence, where they are not trivially tight.
* ``sequences``: whole dense sequences (``configurations="all"``, sigma 40 / 60): field
  completeness, number of configurations, lower bound, wall, what was left and why.

Objectives and proof status do not depend on load; the times do (run it alone).
``python -m benchmarks.exact`` (``--smoke`` for a quick small run).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from models.types import PlaneTargets
from solvers.allocation import allocate
from solvers.allocation.bnb import solve_ilp_bnb
from solvers.allocation.cpsat import solve_ilp_cpsat
from solvers.allocation.exact import (
    ExactOptions,
    build_exact_model,
    presolve_columns,
    relaxation_bound,
)
from solvers.allocation.highs import solve_ilp_highs
from solvers.model import coarse_weights
from solvers.problem import ConfigProblem
from solvers.sequencing import hard_to_place, joint_speeds

ENGINES = ("bnb", "highs", "cpsat")
SIGMAS_MM = {"sigma40": 40.0, "sigma60": 60.0, "uniform": None}
PRIORITIES = ([500, 100, 10, 1], [0.1, 0.4, 0.4, 0.1])


def dense_field(n: int, sigma_mm: float | None, seed: int, radius_mm: float = 125.0) -> PlaneTargets:
    """``n`` targets in the FOV: Gaussian about the centre (``sigma_mm``) or uniform."""
    rng = np.random.default_rng(seed)
    if sigma_mm is None:
        r = radius_mm * np.sqrt(rng.random(n))
        a = rng.random(n) * 2 * np.pi
        xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    else:
        xy = np.zeros((0, 2))
        while len(xy) < n:
            p = rng.normal(0.0, sigma_mm, (2 * n, 2))
            xy = np.vstack([xy, p[np.hypot(p[:, 0], p[:, 1]) <= radius_mm]])
        xy = xy[:n]
    pr = rng.choice(PRIORITIES[0], size=n, p=PRIORITIES[1]).astype(np.int64)
    return PlaneTargets.from_lists([f"t{i}" for i in range(n)], xy[:, 0], xy[:, 1], pr)


def first_problem(ins, f: PlaneTargets, time_limit_s: float) -> ConfigProblem:
    """The first configuration's problem as the sequencing driver builds it (tie-break on)."""
    x, y = np.asarray(f.x_mm, float), np.asarray(f.y_mm, float)
    inc = incompatibility_for_targets(ins, x, y)
    avail = inc.reachability.arms_per_target > 0
    xy = np.column_stack([x, y])
    return ConfigProblem(inc, np.asarray(f.priority, np.int64), avail, ins.park_configuration.copy(),
                         joint_speeds(ins), time_limit_s=time_limit_s, target_xy_mm=xy,
                         tie_break=hard_to_place(inc, ins.n_arms, xy, avail))


def solve_direct(engine: str, prob: ConfigProblem):
    fn = {"bnb": solve_ilp_bnb, "highs": solve_ilp_highs, "cpsat": solve_ilp_cpsat}[engine]
    t0 = time.perf_counter()
    s = fn(prob)
    wall = time.perf_counter() - t0
    st = s.stats
    return {"status": s.status, "total_priority": s.total_priority, "arm_yield": s.arm_yield,
            "longest_move_s": round(s.longest_move_s, 3), "move_optimal": bool(st.get("move_optimal")),
            "tie_optimal": bool(st.get("tie_optimal")), "backend": st.get("backend"),
            "engine_s": round(wall, 3)}


def lp_bounds(prob: ConfigProblem, optimum_coarse: int) -> dict:
    """LP bound of the priority/yield model before and after the presolve and clique rows."""
    allowed = prob.allowed()
    before, _ = build_exact_model(prob, allowed, ExactOptions(cliques=False))
    full_cliques, s_full = build_exact_model(prob, allowed, ExactOptions(cliques=True))
    cols, _, _ = presolve_columns(prob, None, 300, time.perf_counter() + prob.time_limit_s)
    after, s_after = build_exact_model(prob, cols, ExactOptions(cliques=True))
    return {"optimum": optimum_coarse, "lp_aggregated_all_columns": round(relaxation_bound(prob, before), 2),
            "lp_cliques_all_columns": round(relaxation_bound(prob, full_cliques), 2),
            "lp_pruned_cliques": round(relaxation_bound(prob, after), 2),
            "columns_all": int(allowed.sum()), "columns_pruned": int(cols.sum()),
            "clique_rows_all": s_full["clique_rows"], "clique_rows_pruned": s_after["clique_rows"]}


def tier_transition(ins, n: int, seed: int, after: int, time_limit_s: float) -> dict:
    """LP bounds where they matter: the configuration after ``after`` greedy bnb
    configurations of the sigma-40 field (the 500-priority targets are running out, so
    collisions decide how many fit), before and after clique rows, against the best value
    the three engines find in ``time_limit_s`` (proven only when one says ``optimal``)."""
    import dataclasses

    f = dense_field(n, SIGMAS_MM["sigma40"], seed)
    prob = first_problem(ins, f, 2.0)
    pending = prob.available.copy()
    q = prob.start_q
    xy = prob.target_xy_mm
    for _ in range(after):
        p = dataclasses.replace(prob, available=pending.copy(), start_q=q,
                                tie_break=hard_to_place(prob.incompatibility, ins.n_arms, xy, pending))
        s = solve_ilp_bnb(p)
        t = p.assignments.target[s.chosen]
        pending[t[t >= 0]] = False
        q = p.assignments.q[s.chosen]
    prob = dataclasses.replace(prob, available=pending, start_q=q, time_limit_s=time_limit_s,
                               tie_break=hard_to_place(prob.incompatibility, ins.n_arms, xy, pending))
    engines = {e: solve_direct(e, prob) for e in ENGINES}
    best = max(v["total_priority"] * (ins.n_arms + 1) + v["arm_yield"] for v in engines.values())
    allowed = prob.allowed()
    from solvers.allocation.cliques import CliqueOptions

    wide = ExactOptions(cliques=True, clique_options=CliqueOptions(max_columns=8000, column_seed_max_columns=8000))
    before, _ = build_exact_model(prob, allowed, ExactOptions(cliques=False))
    after_m, s_after = build_exact_model(prob, allowed, wide)
    return {"field": "sigma40", "targets": n, "seed": seed, "after_configurations": after,
            "best_coarse": best, "proven": any(v["status"] == "optimal" for v in engines.values()),
            "lp_aggregated": round(relaxation_bound(prob, before), 2),
            "lp_with_cliques": round(relaxation_bound(prob, after_m), 2),
            "clique_rows": s_after["clique_rows"], "columns": int(allowed.sum()), "engines": engines}


def one_configuration(ins, n: int, seeds: list[int], time_limit_s: float) -> list[dict]:
    rows = []
    for name, sigma in SIGMAS_MM.items():
        for seed in seeds:
            f = dense_field(n, sigma, seed)
            prob = first_problem(ins, f, time_limit_s)
            row = {"field": name, "targets": n, "seed": seed, "engines": {}}
            for e in ENGINES:
                d = solve_direct(e, prob)
                t0 = time.perf_counter()
                r = allocate(ins, f, solver=e, configurations="one", time_limit_s=time_limit_s, seed=seed)
                d.update(wall_s=round(time.perf_counter() - t0, 3),
                         allocate_total_priority=r.configurations[0].total_priority if r.configurations else 0,
                         allocate_status=r.configurations[0].status if r.configurations else None)
                row["engines"][e] = d
            best = max(row["engines"].values(), key=lambda d: (d["total_priority"], d["arm_yield"]))
            chosen = solve_ilp_bnb(prob).chosen
            opt = sum(int(v) for v in coarse_weights(prob, chosen))
            row["lp_bound"] = lp_bounds(prob, opt)
            row["agree"] = len({(d["total_priority"], d["arm_yield"]) for d in row["engines"].values()}) == 1
            row["best_total_priority"] = best["total_priority"]
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def sequences(ins, n: int, seeds: list[int], time_limit_s: float) -> list[dict]:
    rows = []
    for name in ("sigma40", "sigma60"):
        for seed in seeds:
            f = dense_field(n, SIGMAS_MM[name], seed)
            for e in ENGINES:
                t0 = time.perf_counter()
                r = allocate(ins, f, solver=e, configurations="all", time_limit_s=time_limit_s, seed=seed)
                wall = time.perf_counter() - t0
                st = r.stats
                reasons: dict[str, int] = {}
                for u in r.unallocated:
                    reasons[u.reason] = reasons.get(u.reason, 0) + 1
                row = {"field": name, "targets": n, "seed": seed, "engine": e,
                       "field_completeness": st["field_completeness"], "n_configurations": st["n_configurations"],
                       "lower_bound_configurations_proven": st["lower_bound_configurations_proven"],
                       "wall_s": round(wall, 2), "unallocated": reasons, "stop_reason": st["stop_reason"],
                       "n_configurations_greedy": st["n_configurations_greedy"],
                       "timers_s": {k: round(v, 2) for k, v in st["timers_s"].items()},
                       "engines": st.get("engines"),
                       "configurations_proven": sum(c["status"] == "optimal" for c in st["per_configuration"])}
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def summary(one: list[dict], seq: list[dict]) -> dict:
    out: dict = {"one": {}, "sequences": {}}
    for e in ENGINES:
        d = [r["engines"][e] for r in one]
        out["one"][e] = {"proved": sum(x["status"] == "optimal" for x in d), "of": len(d),
                         "median_engine_s": statistics.median(x["engine_s"] for x in d) if d else None,
                         "median_wall_s": statistics.median(x["wall_s"] for x in d) if d else None}
        s = [r for r in seq if r["engine"] == e]
        out["sequences"][e] = {"complete": sum(r["field_completeness"] == 1.0 for r in s), "of": len(s),
                               "configurations": [r["n_configurations"] for r in s],
                               "median_wall_s": statistics.median(r["wall_s"] for r in s) if s else None}
    out["one"]["all_agree"] = all(r["agree"] for r in one)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--smoke", action="store_true", help="200 targets, one seed, short limits")
    ap.add_argument("--targets", type=int, default=1200)
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated field seeds (median over them)")
    ap.add_argument("--one-time-limit", type=float, default=30.0)
    ap.add_argument("--sequence-time-limit", type=float, default=20.0)
    ap.add_argument("--no-sequences", action="store_true")
    args = ap.parse_args()
    ins = default_instrument()
    n = 200 if args.smoke else args.targets
    seeds = [0] if args.smoke else [int(s) for s in args.seeds.split(",")]
    one = one_configuration(ins, n, seeds, 5.0 if args.smoke else args.one_time_limit)
    tier = tier_transition(ins, n, seeds[0], 2 if args.smoke else 10, 5.0 if args.smoke else args.one_time_limit)
    print(json.dumps(tier), flush=True)
    seq = [] if args.no_sequences else sequences(ins, n, seeds[:1] if args.smoke else seeds,
                                                   5.0 if args.smoke else args.sequence_time_limit)
    print(json.dumps({"benchmark": "exact", "one": one, "tier_transition": tier, "sequences": seq,
                      "summary": summary(one, seq)}, indent=1))


if __name__ == "__main__":
    main()
