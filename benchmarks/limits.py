"""Benchmark: time-limit overrun and peak memory of every domain stage.

Each case runs in its own process, so its peak RSS (``ru_maxrss``) is its own; the parent
prints one JSON document with one row per case. Peak RSS and the structure's pair counts
do not depend on the machine's load; the overruns do (run serialised on an idle machine).

Cases (``--cases`` picks some):

* ``allocate``: :func:`solvers.allocation.allocate` (exact ILP, bnb, all configurations) on
  1,000 / 2,000 / 5,000 targets, uniform over the FOV and dense Gaussian (sigma 40 mm),
  at ``time_limit_s`` 1 (``--limits`` adds others);
* ``structure``: the incompatibility structure alone, no limit (its full size);
* ``segment``: :func:`solvers.segmentation.segment_field` on 5,000 targets packed into
  18 arcsec, and 5,000 copies of one position;
* ``motion``: :func:`planner.driver.plan_motion` park -> c1 -> c2 -> c3 of a crowded field at
  the finest steps the options allow (dt_s 5 s with dt_col_s 10 ms; dt_s = dt_col_s = 0.25 s)
  with ``time_budget_s`` 1.

    python benchmarks/limits.py                      # everything, limit 1 s
    python benchmarks/limits.py --cases allocate --limits 1 30
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import numpy as np

SIZES = (1_000, 2_000, 5_000)
KINDS = ("uniform", "gauss")


def field_xy(n: int, kind: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        r = 125.0 * np.sqrt(rng.uniform(0, 1, n))
        a = rng.uniform(0, 2 * np.pi, n)
        return r * np.cos(a), r * np.sin(a)
    return rng.normal(0, 40.0, n), rng.normal(0, 40.0, n)


def _targets(x, y):
    from models.types import PlaneTargets

    return PlaneTargets.from_lists([f"t{i}" for i in range(len(x))], x.tolist(), y.tolist(), [1] * len(x))


def case_allocate(n: int, kind: str, limit_s: float) -> dict:
    from models.instrument import default_instrument
    from solvers.allocation import allocate

    t = _targets(*field_xy(n, kind))
    t0 = time.perf_counter()
    res = allocate(default_instrument(), t, configurations="all", time_limit_s=limit_s)
    el = time.perf_counter() - t0
    reasons: dict[str, int] = {}
    for u in res.unallocated:
        reasons[u.reason] = reasons.get(u.reason, 0) + 1
    return {"elapsed_s": el, "overrun_s": el - limit_s, "configurations": len(res.configurations),
            "stop_reason": res.stats.get("stop_reason"), "unallocated": reasons}


def case_structure(n: int, kind: str) -> dict:
    from models.incompatibility import incompatibility_for_targets
    from models.instrument import default_instrument

    t0 = time.perf_counter()
    inc = incompatibility_for_targets(default_instrument(), *field_xy(n, kind))
    size = inc.pairs.nbytes + inc.indices.nbytes + inc.indptr.nbytes + inc.same_target.nbytes
    return {"elapsed_s": time.perf_counter() - t0, "assignments": len(inc.assignments),
            "pairs": int(len(inc.pairs)), "structure_mb": size / 2**20}


def case_segment(kind: str, limit_s: float) -> dict:
    from solvers.segmentation import segment_field

    rng = np.random.default_rng(0)
    span = 0.0 if kind == "one_position" else 0.005
    ra, dec = 180 + rng.uniform(-span, span, 5_000), rng.uniform(-span, span, 5_000)
    t0 = time.perf_counter()
    seg = segment_field(ra, dec, mode="balanced", time_limit_s=limit_s)
    el = time.perf_counter() - t0
    return {"elapsed_s": el, "overrun_s": el - limit_s, "pointings": len(seg.pointings)}


def case_motion(dt_s: float, dt_col_s: float, limit_s: float) -> dict:
    from models.instrument import default_instrument
    from planner.driver import plan_motion
    from solvers.allocation import AllocationOptions, SequenceOptions, allocate

    ins = default_instrument()
    rng = np.random.default_rng(0)
    t = _targets(rng.normal(0, 35.0, 40), rng.normal(0, 35.0, 40))
    res = allocate(ins, t, configurations="all", time_limit_s=10.0,
                   options=AllocationOptions(sequence=SequenceOptions(max_configurations=3)))
    qs = [ins.park_configuration] + [c.q for c in res.configurations]
    legs = []
    for a, b in zip(qs[:-1], qs[1:], strict=True):
        t0 = time.perf_counter()
        p = plan_motion(ins, a, b, dt_s=dt_s, dt_col_s=dt_col_s, time_budget_s=limit_s)
        legs.append({"elapsed_s": time.perf_counter() - t0, "status": p.status})
    return {"legs": legs, "overrun_s": max(leg["elapsed_s"] for leg in legs) - limit_s}


def _child(spec: dict) -> dict:
    fn = {"allocate": case_allocate, "structure": case_structure, "segment": case_segment,
          "motion": case_motion}[spec["case"]]
    out = fn(**spec["args"])
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def specs(cases: list[str], limits: list[float]) -> list[dict]:
    out = []
    for lim in limits:
        if "allocate" in cases:
            out += [{"case": "allocate", "args": {"n": n, "kind": k, "limit_s": lim}} for n in SIZES for k in KINDS]
        if "segment" in cases:
            out += [{"case": "segment", "args": {"kind": k, "limit_s": lim}} for k in ("packed", "one_position")]
        if "motion" in cases:
            out += [{"case": "motion", "args": {"dt_s": d, "dt_col_s": c, "limit_s": lim}}
                    for d, c in ((5.0, 0.01), (0.25, 0.25))]
    if "structure" in cases:
        out += [{"case": "structure", "args": {"n": n, "kind": k}} for n in SIZES for k in KINDS]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=["allocate", "structure", "segment", "motion"])
    ap.add_argument("--limits", type=float, nargs="*", default=[1.0])
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_child(json.loads(args.child))))
        return
    rows = []
    for spec in specs(args.cases, args.limits):
        r = subprocess.run([sys.executable, "-m", "benchmarks.limits", "--child", json.dumps(spec)],
                           capture_output=True, text=True, check=False)
        row = dict(spec)
        try:
            row.update(json.loads(r.stdout.strip().splitlines()[-1]))
        except (IndexError, json.JSONDecodeError):
            row["error"] = r.stderr.strip().splitlines()[-1:] or ["no output"]
        rows.append(row)
        print(json.dumps(row), file=sys.stderr)
    print(json.dumps({"rows": rows, "max_peak_rss_mb": max((r.get("peak_rss_mb", 0) for r in rows), default=0),
                      "max_overrun_s": max((r.get("overrun_s", -1e9) for r in rows), default=None)}, indent=2))


if __name__ == "__main__":
    main()
