"""Overrun of the whole plan pipeline past the request's time limit.

Runs ``service.pipeline.plan`` (what ``POST /v1/plans`` runs) on the example fields with
several ``time_limit_s`` and prints JSON: per run the wall time, the limit and the overrun
(wall - limit; the goal is <= 1 s), plus how much of the field was planned.

    python -m benchmarks.plan_deadline            # M13 (40 stars) and NGC 869 (60), 2/5/10 s
    python -m benchmarks.plan_deadline --smoke    # the 12-star example, 2 s

Overrun is what the stages do with the time they are given; on a shared machine the
planners get less CPU in that time, so run it alone for figures.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from service import pipeline
from service.cli import read_targets
from service.schemas import PlanRequest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def fields(smoke: bool) -> dict[str, list[dict[str, Any]]]:
    if smoke:
        return {"plan.json": json.loads((EXAMPLES / "requests" / "plan.json").read_text())["targets"]}
    return {name: read_targets(EXAMPLES / name) for name in ("m13_targets.csv", "ngc869_targets.csv")}


def run_one(targets: list[dict[str, Any]], limit_s: float, seed: int) -> dict[str, Any]:
    req = PlanRequest(targets=targets, time_limit_s=limit_s, seed=seed)
    inst = pipeline.instrument_from(None)
    t0 = time.monotonic()
    out = pipeline.plan(req, inst, budget_s=120.0)
    wall = time.monotonic() - t0
    s = out["stats"]
    return {"time_limit_s": limit_s, "wall_s": round(wall, 3), "overrun_s": round(wall - limit_s, 3),
            "pointings": s["pointings"], "configurations": s["configurations"],
            "allocated_targets": s["allocated_targets"], "targets": s["targets"],
            "motion_plans_failed": s["motion_plans_failed"], "executable": out["executable"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--limits", type=float, nargs="+", default=None)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    limits = args.limits or ([2.0] if args.smoke else [2.0, 5.0, 10.0])
    runs = [{"field": name, **run_one(targets, limit, args.seed)}
            for name, targets in fields(args.smoke).items() for limit in limits]
    worst = max(r["overrun_s"] for r in runs)
    print(json.dumps({"runs": runs, "worst_overrun_s": worst, "goal_overrun_s": 1.0,
                      "met": worst <= 1.0}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
