"""Benchmark: reachability + incompatibility matrix for uniform random FOV fields.

Prints one JSON document. Time is the median of ``--repeats`` runs; peak memory is the
tracemalloc peak of a separate run (numpy allocations are traced), plus the process
max RSS. For the smallest field the brute-force FCL oracle is timed too.

    python benchmarks/incompatibility.py            # 32 / 300 / 1200 / 5000 targets
    python benchmarks/incompatibility.py --smoke    # tiny, for CI
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import time
import tracemalloc

import numpy as np

from models.collision import fcl_clearance_mm
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument


def uniform_fov(n: int, seed: int, radius_mm: float = 125.0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    r = radius_mm * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    return r * np.cos(a), r * np.sin(a)


def fcl_brute_force_s(instrument, inc, max_pairs: int = 20_000) -> dict:
    """Time per pair of the FCL path (Python loop), extrapolated to all cross-arm pairs."""
    a = inc.assignments
    i, j = np.triu_indices(len(a), 1)
    cross = a.arm[i] != a.arm[j]
    i, j = i[cross], j[cross]
    take = min(max_pairs, len(i))
    t0 = time.perf_counter()
    for p in range(take):
        fcl_clearance_mm(instrument, int(a.arm[i[p]]), a.q[i[p]], int(a.arm[j[p]]), a.q[j[p]])
    per_pair = (time.perf_counter() - t0) / take
    return {"fcl_s_per_pair": per_pair, "fcl_estimated_total_s": per_pair * len(i), "cross_arm_pairs": int(len(i))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="*", default=[32, 300, 1200, 5000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--smoke", action="store_true")
    args = ap.parse_args()
    if args.smoke:
        args.sizes, args.repeats = [32, 120], 2
    ins = default_instrument()
    incompatibility_for_targets(ins, *uniform_fov(20, 0))  # warm caches/imports
    rows = []
    for n in args.sizes:
        x, y = uniform_fov(n, seed=n)
        times, phases = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            inc = incompatibility_for_targets(ins, x, y)
            times.append(time.perf_counter() - t0)
            phases.append(inc.timings_s)
        tracemalloc.start()
        incompatibility_for_targets(ins, x, y)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        c = inc.counts()
        row = {
            "targets": n,
            "median_s": statistics.median(times),
            "min_s": min(times),
            "runs_s": times,
            "phases_median_s": {k: statistics.median(p[k] for p in phases) for k in phases[0]},
            "peak_traced_mb": peak / 2**20,
            "assignments": c["assignments"],
            "incompatible_pairs": c["incompatible_pairs"],
            "same_target_pairs": c["same_target_pairs"],
            "pair_fraction": c["incompatible_pairs"] / max(1, len(inc.assignments) ** 2 / 2),
        }
        if n <= 300:
            row.update(fcl_brute_force_s(ins, inc, max_pairs=2_000 if args.smoke else 20_000))
        rows.append(row)
    print(json.dumps({
        "benchmark": "incompatibility",
        "machine": {"python": platform.python_version(), "cpus": __import__("os").cpu_count()},
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "results": rows,
    }, indent=2))


if __name__ == "__main__":
    main()
