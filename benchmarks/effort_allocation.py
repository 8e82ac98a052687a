"""Calibration of the allocator's work costs (``solvers.effort``, "costs of the allocator's work").

Runs ``allocate`` inside ``clock.effort()`` on the thesis fields (priorities 10 % 500,
40 % 100, 40 % 10, 10 % 1; uniform in the FOV or Gaussian about its centre, clipped) and
prints, per call, the effort seconds charged against the CPU seconds the process used
(``time.process_time``: the load of other processes does not count; CP-SAT's workers do).
A ratio near 1 means the costs match this machine; the summary gives the median and range
per method.

    python -m benchmarks.effort_allocation [--sizes 100 400 1200] [--limit 5] [--methods bnb highs cpsat semigreedy]
    python -m benchmarks.effort_allocation --sizes 40 100 400 --limit 5 --methods bnb semigreedy
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from benchmarks.allocation import sigma_field
from models import clock
from models.instrument import default_instrument
from models.types import PlaneTargets
from solvers.allocation import allocate

METHODS = {"bnb": ("ilp", "bnb"), "highs": ("ilp", "highs"), "cpsat": ("ilp", "cpsat"),
           "semigreedy": ("semigreedy", "bnb")}
DISTRIBUTIONS = {"uniform": None, "gauss40": 40.0, "gauss60": 60.0}


def thesis_field(n: int, sigma_mm: float | None, seed: int) -> PlaneTargets:
    """``n`` targets, uniform in the FOV (``sigma_mm`` None) or Gaussian about its centre."""
    return sigma_field(n, sigma_mm, np.random.default_rng(seed))


def measure(method: str, targets: PlaneTargets, configurations: str, limit_s: float, seed: int = 0) -> dict:
    """One call on the effort clock: its effort and CPU seconds."""
    m, s = METHODS[method]
    cpu0, wall0 = time.process_time(), time.perf_counter()
    with clock.effort(wall_limit_s=4 * limit_s + 5) as c:
        r = allocate(default_instrument(), targets, method=m, solver=s, configurations=configurations,
                     time_limit_s=limit_s, seed=seed)
    cpu = time.process_time() - cpu0
    return {"effort_s": round(c.t_s, 3), "cpu_s": round(cpu, 3), "wall_s": round(time.perf_counter() - wall0, 3),
            "ratio": round(c.t_s / max(cpu, 1e-3), 3), "overran": c.overran,
            "n_configurations": r.stats["n_configurations"], "stop_reason": r.stats["stop_reason"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 400, 1200])
    ap.add_argument("--limit", type=float, default=5.0)
    ap.add_argument("--methods", nargs="+", default=list(METHODS))
    ap.add_argument("--configurations", nargs="+", default=["all"])
    ap.add_argument("--distributions", nargs="+", default=list(DISTRIBUTIONS))
    args = ap.parse_args()
    allocate(default_instrument(), thesis_field(50, None, 0), time_limit_s=2.0)  # imports, caches
    rows = []
    for method in args.methods:
        for dist in args.distributions:
            for n in args.sizes:
                for conf in args.configurations:
                    row = {"method": method, "field": dist, "n": n, "configurations": conf,
                           **measure(method, thesis_field(n, DISTRIBUTIONS[dist], seed=n), conf, args.limit)}
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    for method in args.methods:
        r = np.array([x["ratio"] for x in rows if x["method"] == method and x["cpu_s"] > 0.05])
        if len(r):
            print(f"{method}: effort/CPU median {np.median(r):.2f}, range {r.min():.2f}-{r.max():.2f} ({len(r)} calls)")


if __name__ == "__main__":
    main()
