"""What a programme's plan spends per target: the measurement behind
``planner.programme.ProgrammeShares.typical_effort_per_target_s`` and
``enough_effort_per_target_s``, from which a plan's ``time_limit_advice`` names a limit.
Prints JSON to stdout.

    python benchmarks/time_need.py                          # programmes of seeds 500..509
    python benchmarks/time_need.py --seeds 500 501 --case tests/data/m67-like-150-vizier.csv
    python benchmarks/time_need.py --smoke                  # one small programme, for CI

Each programme (``benchmarks/programmes.py``'s shapes, or a target table given with
``--case``) is planned through the call behind ``POST /v1/plans`` at the default limit
(120 s). Per pointing: its targets, the effort seconds of the round whose plan was kept, and
their ratio; per programme the summed effort over the summed targets, the limit
``planner.time_advice.needed_limit_s`` estimates from the table (before planning) and the
wall time the plan took. The summary gives the per-programme ratios and the percentiles of
the per-pointing ones (the table's typical figure is their median, its figure of enough
their 90th percentile).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def measure(name: str, targets: list[dict[str, Any]], seed: int) -> dict[str, Any]:
    """One programme planned at the default limit, and what its pointings spent."""
    from planner import programme
    from planner.time_advice import needed_limit_s
    from service import pipeline
    from service.schemas import PlanRequest

    req = PlanRequest.model_validate({"targets": targets, "seed": seed})
    t0 = time.perf_counter()
    plan = pipeline.plan(req, pipeline.instrument_from(None), budget_s=programme.DEFAULT_LIMIT_S)
    wall_s = time.perf_counter() - t0
    rows = []
    for p in plan["pointings"]:
        need = programme.pointing_need(len(p["target_ids"]))
        kept = max(p["stats"]["rounds"], key=lambda r: (r.get("attempted", True), r["executable"],
                                                        -r["failed_legs"], r["observed"]))
        rows.append({"targets": len(p["target_ids"]), "need": need, "effort_s": round(kept["effort_s"], 3),
                     "effort_per_target": round(kept["effort_s"] / len(p["target_ids"]), 4),
                     "executable": p["executable"]})
    mode = plan["stats"]["segmentation"]["mode"]
    expected = sum(programme.expected_share_s(r["need"]) for r in rows)
    return {"programme": name, "targets": len(targets), "mode": mode, "pointings": len(rows),
            "executable": plan["executable"],
            "effort_per_target": round(sum(r["effort_s"] for r in rows) / len(targets), 4),
            "needed_limit_s": needed_limit_s(expected, mode == "fewest-exposures"),
            "wall_s": round(wall_s, 1), "pointing_rows": rows}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=list(range(500, 510)))
    ap.add_argument("--case", action="append", default=[], help="a target table (CSV, ...)")
    ap.add_argument("--smoke", action="store_true", help="one programme of 20 stars")
    args = ap.parse_args(argv)
    from benchmarks.programmes import SHAPES, programme_targets
    from service import pipeline
    from service.tables import read_targets

    pipeline.warm_up()
    runs = []
    if args.smoke:
        targets, _ = programme_targets("clumps", 3, n_range=(20, 20))
        runs.append(("clumps-3", targets, 3))
    else:
        for seed in args.seeds:
            shape = SHAPES[seed % len(SHAPES)]
            runs.append((f"{shape}-{seed}", programme_targets(shape, seed)[0], seed))
        runs += [(Path(c).name, read_targets(c), 0) for c in args.case]
    rows = []
    for name, targets, seed in runs:
        rows.append(measure(name, targets, seed))
        print(json.dumps({k: v for k, v in rows[-1].items() if k != "pointing_rows"}),
              file=sys.stderr, flush=True)
    per_pointing = np.array([r["effort_per_target"] for row in rows for r in row["pointing_rows"]])
    return {"protocol": "POST /v1/plans defaults (120 s), targets + seed only",
            "programmes": len(rows), "pointings": int(per_pointing.size),
            "effort_per_target_by_programme": [r["effort_per_target"] for r in rows],
            "effort_per_target_pointing_percentiles": {
                str(q): round(float(np.percentile(per_pointing, q)), 4) for q in (50, 75, 90, 95, 100)},
            "rows": rows}


if __name__ == "__main__":
    print(json.dumps(main(), indent=1))
