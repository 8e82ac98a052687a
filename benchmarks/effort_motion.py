"""How well the effort clock tracks the motion planner's real cost.

Inside :func:`models.clock.effort` a leg's budget is counted in reference seconds of work
(:data:`planner.effort.PLANNER_WORK_S`), so the same leg stops at the same point on any
machine. This benchmark plans the legs of the allocator's own sequences (thesis protocol,
as ``benchmarks/motion.py``: park -> c1 -> ... -> park and park -> every configuration) on
the effort clock, and reports, per leg, the effort seconds against the CPU seconds the same
call took (``time.process_time``, which another process on the machine hardly moves), plus
a least-squares fit of every kind of work's cost on these legs (what the constants in
:mod:`planner.effort` come from).

    python benchmarks/effort_motion.py --fields 2 --seed 5

Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from motion import thesis_field  # noqa: E402

from models import clock  # noqa: E402
from models.instrument import default_instrument  # noqa: E402
from planner import plan_motion  # noqa: E402
from planner.effort import PLANNER_WORK_S  # noqa: E402
from planner.kernels import compile_kernels  # noqa: E402
from solvers.allocation import allocate  # noqa: E402

KINDS = tuple(PLANNER_WORK_S)


def legs_of(inst, seed: int, n_fields: int, method: str):
    """(field, kind, start_q, goal_q) of every leg of the allocator's sequences."""
    park = inst.park_configuration
    for f in range(n_fields):
        _, targets = thesis_field(150, seed, f)
        result = allocate(inst, targets, method=method, configurations="all", seed=seed,
                          time_limit_s=10.0)
        qs = [c.q for c in result.configurations]
        for i, (a, b) in enumerate(zip([park, *qs], [*qs, park], strict=True)):
            yield f, ("park" if i == 0 else "to_park" if i == len(qs) else "chained"), a, b
        for q in qs[1:]:
            yield f, "park", park, q


def plan_on_effort(inst, start_q, goal_q, budget_s: float, seed: int) -> dict:
    with clock.effort(wall_limit_s=5 * budget_s, tally=True) as c:
        t_cpu, t_wall = time.process_time(), time.perf_counter()
        plan = plan_motion(inst, start_q, goal_q, seed=seed, time_budget_s=budget_s)
        cpu_s, wall_s = time.process_time() - t_cpu, time.perf_counter() - t_wall
    return {"status": plan.status, "effort_s": c.t_s, "cpu_s": cpu_s, "wall_s": wall_s,
            "overran": c.overran, "reads": c.reads, "tally": dict(c.tally)}


def fit(rows: list[dict]) -> dict:
    """Non-negative least squares of CPU seconds on (calls, units) of every kind, plus the
    clock readings' tick; relative to each leg's CPU time so that short legs count too."""
    X = np.array([[r["tally"].get(k, (0, 0.0))[j] for k in KINDS for j in (0, 1)] for r in rows], float)
    y = np.array([r["cpu_s"] - r["reads"] * clock.TICK_S for r in rows])
    w = 1.0 / np.maximum(np.array([r["cpu_s"] for r in rows]), 0.05)
    coef, _ = nnls(X * w[:, None], y * w)
    return {k: (float(coef[2 * i]), float(coef[2 * i + 1])) for i, k in enumerate(KINDS)}


def ratios(rows: list[dict]) -> dict:
    r = np.array([x["effort_s"] / max(x["cpu_s"], 1e-6) for x in rows])
    q = np.percentile(r, [1, 10, 50, 90, 99])
    return {"n": len(r), "p1": q[0], "p10": q[1], "median": q[2], "p90": q[3], "p99": q[4],
            "min": float(r.min()), "max": float(r.max()),
            "within_0.5_2": float(np.mean((r >= 0.5) & (r <= 2.0)))}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fields", type=int, default=4)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--method", default="ilp", choices=["ilp", "semigreedy"])
    ap.add_argument("--budget-s", type=float, default=10.0)
    args = ap.parse_args(argv)
    inst = default_instrument()
    compile_kernels()
    rows = []
    for f, kind, a, b in legs_of(inst, args.seed, args.fields, args.method):
        row = plan_on_effort(inst, a, b, args.budget_s, args.seed)
        rows.append({"field": f, "kind": kind, **row})
        print(f"field {f} {kind}: {row['status']} effort {row['effort_s']:.2f} s, "
              f"cpu {row['cpu_s']:.2f} s", file=sys.stderr, flush=True)
    out = {"params": vars(args), "legs": len(rows),
           "ok": sum(r["status"] == "ok" for r in rows),
           "overran": sum(r["overran"] for r in rows),
           "effort_over_cpu": ratios(rows),
           "fitted_work_s": fit(rows),
           "rows": [{k: v for k, v in r.items() if k != "tally"} for r in rows]}
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
