"""Whole programmes per exact engine (issue 39, item 7): the plan ``POST /v1/plans`` answers at
its defaults with only ``solver`` changed; prints JSON to stdout, progress to stderr.

    python -m benchmarks.engines_programme                      # 4 programmes, 3 runs each
    python -m benchmarks.engines_programme --n 2 --runs 1 --engines bnb,cpsat

Programmes: ``benchmarks.programme_time.generated`` (the shapes scattered, cluster, two-clump
and cluster-halo in turn, programme *i* from seed ``seed0 + i``, 50-150 stars over 5-15
arcmin, the thesis priority mix).  Each is planned ``--runs`` times per engine by
``service.pipeline.plan`` with ``targets``, ``seed`` and ``solver`` set and everything else at
the request's defaults (the server's 120 s budget, ``MXS_PLAN_BUDGET_S``).  Per plan:
exposures, pointings, total priority observed, priority completeness, targets not observed,
executable, wall time.  The summary per engine: exposures and observed priority summed over
the programmes (the first run), executable plans, and the median wall time of every plan,
with how many programmes the engine observed less priority, or took more exposures, than
``bnb``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.programme_time import SHAPES, generated  # noqa: E402

ENGINES = ("bnb", "highs", "cpsat")
N_RANGE = (50, 150)


def plan_once(prog: dict[str, Any], solver: str) -> dict[str, Any]:
    """One plan of ``prog`` with ``solver`` at the request's defaults, and its figures."""
    from service import pipeline
    from service.schemas import PlanRequest
    from service.settings import Settings

    req = PlanRequest.model_validate({"targets": prog["targets"], "seed": prog["seed"], "solver": solver})
    t0 = time.perf_counter()
    plan = pipeline.plan(req, pipeline.instrument_from(None), budget_s=Settings().plan_budget_s)
    wall_s = time.perf_counter() - t0
    prio = {t["id"]: int(t["priority"]) for t in prog["targets"]}
    observed = {a["target_id"] for p in plan["pointings"] for c in p["configurations"]
                for a in c["assignments"] if a.get("target_id") is not None}
    s = plan["stats"]
    return {"exposures": int(s["configurations"]), "pointings": int(s["pointings"]),
            "priority_observed": sum(prio[t] for t in observed if t in prio),
            "priority_completeness": round(float(s["priority_completeness"]), 4),
            "not_observed": len(prio) - len(observed & prio.keys()),
            "executable": bool(plan["executable"]), "wall_s": round(wall_s, 2)}


def summary(rows: list[dict[str, Any]], engine: str) -> dict[str, Any]:
    """An engine's totals over the programmes (first run) and its median wall time (all runs)."""
    first = [r["engines"][engine][0] for r in rows]
    base = [r["engines"]["bnb"][0] for r in rows] if "bnb" in rows[0]["engines"] else None
    out = {"exposures": sum(x["exposures"] for x in first),
           "priority_observed": sum(x["priority_observed"] for x in first),
           "executable": sum(x["executable"] for x in first), "programmes": len(first),
           "wall_s_median": statistics.median(x["wall_s"] for r in rows for x in r["engines"][engine]),
           "wall_s_max": max(x["wall_s"] for r in rows for x in r["engines"][engine])}
    if base is not None:
        out["less_priority_than_bnb"] = sum(x["priority_observed"] < b["priority_observed"]
                                            for x, b in zip(first, base, strict=True))
        out["more_exposures_than_bnb"] = sum(x["exposures"] > b["exposures"] for x, b in zip(first, base, strict=True))
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=4, help="generated programmes (shapes in turn)")
    ap.add_argument("--seed0", type=int, default=4600, help="the first programme's seed")
    ap.add_argument("--runs", type=int, default=3, help="plans per programme and engine")
    ap.add_argument("--engines", default=",".join(ENGINES), help="comma-separated solvers")
    args = ap.parse_args(argv)
    from service import pipeline

    engines = [e for e in args.engines.split(",") if e]
    progs = generated([(SHAPES[i % len(SHAPES)], args.seed0 + i) for i in range(args.n)], n_range=N_RANGE)
    pipeline.warm_up()
    rows = []
    for prog in progs:
        row: dict[str, Any] = {"name": prog["name"], "stars": len(prog["targets"]),
                               "engines": {e: [] for e in engines}}
        for run in range(args.runs):
            for engine in engines:  # interleaved, so that a change in the machine's load hits every engine
                res = plan_once(prog, engine)
                row["engines"][engine].append(res)
                print(f"{prog['name']} (n={len(prog['targets'])}) run {run} {engine}: {res}",
                      file=sys.stderr, flush=True)
        rows.append(row)
    out = {"protocol": "service.pipeline.plan with targets, seed and solver; defaults otherwise (120 s)",
           "programmes": rows, "summary": {e: summary(rows, e) for e in engines}}
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
