"""Field segmentation benchmark (issue 3): prints JSON to stdout.

    python benchmarks/segmentation.py            # full: 2,000 / 20,000 / 100,000 targets
    python benchmarks/segmentation.py --smoke    # tiny, for CI

Scattered fields: 70 % uniform over a square patch plus 30 % in 25 Gaussian clumps
(sigma 1 arcmin), generated on a tangent plane and projected to RA/Dec; 2,000 targets over
0.5 x 0.5 deg (the thesis' UKIDSS fields), 20,000 over 1 deg^2, 100,000 over 4 deg^2.
Time is the median of 3 runs of segment_field; peak memory is tracemalloc's peak in a
separate run (numpy buffers are traced), plus the process max RSS at the end.
Thesis synthetic cases (sec. 4.3.3.1) call the clustering core directly, without the FOV
check (250 mm > sqrt(3) R); the 270 points fill a 300 mm square (the thesis gives no size).
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from models.sky import focal_mm_to_sky  # noqa: E402
from solvers.segmentation import segment_field, threshold_complete_linkage  # noqa: E402
from solvers.segmentation.enclosing_circle import smallest_enclosing_circle  # noqa: E402

SCALE = 1.2  # arcsec/mm


def scattered_field(n: int, side_deg: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    half = side_deg * 3600 / SCALE / 2
    n_clump = int(0.3 * n)
    xy = rng.uniform(-half, half, (n, 2))
    centres = rng.uniform(-0.8 * half, 0.8 * half, (25, 2))
    xy[:n_clump] = centres[rng.integers(0, 25, n_clump)] + rng.normal(0, 60 / SCALE, (n_clump, 2))
    return focal_mm_to_sky(xy[:, 0], xy[:, 1], 266.4, -29.0, SCALE)  # toward the Galactic centre


def timed(fn, runs: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def peak_mib(fn) -> float:
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def field_case(n: int, side_deg: float, runs: int) -> dict:
    ra, dec = scattered_field(n, side_deg)
    case = {"case": f"scattered_{n}", "n_targets": n, "area_deg2": side_deg**2, "modes": {}}
    for mode in ("complete-linkage", "balanced"):
        t, seg = timed(lambda m=mode: segment_field(ra, dec, mode=m), runs)
        s = seg.stats
        case["modes"][mode] = {
            "time_s_median": round(t, 4),
            "peak_tracemalloc_mib": round(peak_mib(lambda m=mode: segment_field(ra, dec, mode=m)), 1),
            "n_pointings": s["n_pointings"],
            "n_repaired_clusters": s["n_repaired_clusters"],
            "members_min": s["members_min"], "members_max": s["members_max"],
            "members_mean": round(s["members_mean"], 2), "members_std": round(s["members_std"], 2),
            "max_radius_mm": round(s["max_radius_mm"], 3),
        }
    return case


def thesis_synthetic(runs: int) -> list[dict]:
    out = []
    for name, n, side, t in (("thesis_20_points_50mm_t25", 20, 50.0, 25.0),
                             ("thesis_270_points_300mm_t250", 270, 300.0, 250.0)):
        pts = np.random.default_rng(2019).uniform(0, side, (n, 2))
        row = {"case": name, "n_points": n, "square_side_mm": side, "threshold_mm": t}
        for method in ("nn-chain", "sparse", "scipy"):
            tm, lab = timed(
                lambda m=method, p=pts, t=t: threshold_complete_linkage(p, t, method=m), runs)
            row[f"time_s_{method}"] = round(tm, 5)
        radii = [smallest_enclosing_circle(pts[lab == k])[2] for k in np.unique(lab)]
        sizes = np.bincount(lab)
        row.update(n_clusters=int(lab.max() + 1), members=sizes.tolist(),
                   enclosing_radius_max_mm=round(max(radii), 3))
        out.append(row)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, one run")
    args = ap.parse_args()
    runs = 1 if args.smoke else 3
    sizes = [(300, 0.2), (1000, 0.35)] if args.smoke else [(2000, 0.5), (20000, 1.0), (100000, 2.0)]
    result = {
        "benchmark": "segmentation",
        "machine": {"python": platform.python_version(), "cpus": __import__("os").cpu_count()},
        "smoke": args.smoke,
        "fields": [field_case(n, side, runs) for n, side in sizes],
        "thesis_synthetic": thesis_synthetic(runs),
    }
    result["process_max_rss_mib"] = round(
        resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
