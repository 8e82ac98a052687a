"""Whole programmes as astronomers submit them, through the call behind ``POST /v1/plans`` at
its default settings: prints JSON to stdout.

    python benchmarks/programmes.py                      # 30 programmes, seeds 100..129
    python benchmarks/programmes.py --n 12 --seed0 500   # other programmes
    python benchmarks/programmes.py --smoke              # two small programmes, for CI

Each programme is a target list (RA, Dec, integer priority in the thesis mix: 10 % 500,
40 % 100, 40 % 10, 10 % 1) of one of these shapes, its size and scales drawn from its seed:

- ``cluster``: a Plummer sphere of 40-200 stars, core radius 0.3-1.5 arcmin;
- ``cluster-halo``: the same core with 25-45 % of the stars in a sparse uniform halo out to
  5-9 arcmin;
- ``clumps``: 3-6 small Plummer clumps (core 0.2-0.6 arcmin) spread over 10-16 arcmin;
- ``scattered``: stars uniform over a 8-15 arcmin square.

``programme_targets`` also draws, for ``benchmarks/programme_time.py``, a ``two-clump`` shape
(two Plummer clumps, core 0.2-0.8 arcmin, 30-70 % of the stars in the first, the pair spanning
5-15 arcmin) and, on request, other sizes (``n_range``) and extents (``extent_arcmin``: the
square's side, the cluster's or halo's diameter, the clumps' spread); the default run and the
four shapes above at their defaults are unchanged for a seed.

It is planned by ``service.pipeline.plan`` with only ``targets`` and ``seed`` set, under the
server's default budget (``MXS_PLAN_BUDGET_S``, 120 s), as ``POST /v1/plans`` plans it. Per
programme: the number of pointings, whether the plan is executable, the legs planned, the
limit's time used, the exposures (configurations), the targets observed and why the others
are not, and the wall time. The summary counts the executable programmes and the failed
plans that used less than half of their limit (none may).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PRIORITY_VALUES = (500, 100, 10, 1)
PRIORITY_SHARES = (0.1, 0.4, 0.4, 0.1)
SHAPES = ("cluster", "cluster-halo", "clumps", "scattered")
#: Every shape ``programme_targets`` draws: ``SHAPES`` (this script's default run), then the
#: shapes added for other benchmarks (appended, so that each shape keeps its random stream).
ALL_SHAPES = SHAPES + ("two-clump",)
#: The stars of a programme and its extent when the caller names none.
N_RANGE = (40, 200)
TWO_CLUMP_EXTENT_ARCMIN = (5.0, 15.0)


def _plummer_arcmin(rng: np.random.Generator, n: int, core_arcmin: float,
                    r_max_arcmin: float, truncate: bool = False) -> np.ndarray:
    """``n`` projected positions (arcmin) of a Plummer sphere of core radius ``core_arcmin``,
    none beyond ``r_max_arcmin``: drawn from the profile truncated there (``truncate``), or
    drawn from the whole profile with the stars beyond it put on it (the original shapes)."""
    # projected Plummer profile: the fraction within R is R^2 / (R^2 + a^2)
    r2, a2 = r_max_arcmin ** 2, core_arcmin ** 2
    u = rng.uniform(0.0, r2 / (r2 + a2) if truncate else 1.0, n)
    r = np.minimum(core_arcmin * np.sqrt(u / (1.0 - u)), r_max_arcmin)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi)])


def programme_targets(shape: str, seed: int, *, n_range: tuple[int, int] = N_RANGE,
                      extent_arcmin: tuple[float, float] | None = None,
                      ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The target list of programme ``(shape, seed)`` and the parameters drawn for it: between
    ``n_range`` stars (inclusive); ``extent_arcmin``: the range of the programme's extent (the
    scattered square's side, the cluster's or the halo's diameter, the clumps' spread or the
    two clumps' span) instead of each shape's own. At the defaults, the four ``SHAPES`` draw
    what they always drew for a seed."""
    if shape not in ALL_SHAPES:
        raise ValueError(shape)
    rng = np.random.default_rng([seed, ALL_SHAPES.index(shape)])
    n = int(rng.integers(n_range[0], n_range[1] + 1))
    params: dict[str, Any] = {"shape": shape, "seed": seed, "n": n}

    def extent(lo: float, hi: float) -> float:
        return float(rng.uniform(*(extent_arcmin or (lo, hi))))

    if shape == "cluster":
        core = float(rng.uniform(0.3, 1.5))
        r_max = 8.0 if extent_arcmin is None else float(rng.uniform(*extent_arcmin)) / 2
        xy = _plummer_arcmin(rng, n, core, r_max, truncate=extent_arcmin is not None)
        params["core_arcmin"] = round(core, 2)
        if extent_arcmin is not None:
            params["radius_arcmin"] = round(r_max, 2)
    elif shape == "cluster-halo":
        core, halo_frac = float(rng.uniform(0.3, 1.5)), float(rng.uniform(0.25, 0.45))
        halo_r = extent(10.0, 18.0) / 2
        n_halo = int(round(halo_frac * n))
        r = halo_r * np.sqrt(rng.uniform(0.0, 1.0, n_halo))
        phi = rng.uniform(0.0, 2.0 * np.pi, n_halo)
        xy = np.vstack([_plummer_arcmin(rng, n - n_halo, core, min(4.0, halo_r),
                                        truncate=extent_arcmin is not None),
                        np.column_stack([r * np.cos(phi), r * np.sin(phi)])])
        params.update(core_arcmin=round(core, 2), halo_fraction=round(halo_frac, 2),
                      halo_radius_arcmin=round(halo_r, 2))
    elif shape == "clumps":
        k, spread = int(rng.integers(3, 7)), extent(10.0, 16.0)
        centres = rng.uniform(-spread / 2, spread / 2, (k, 2))
        sizes = rng.multinomial(n, np.full(k, 1.0 / k))
        xy = np.vstack([c + _plummer_arcmin(rng, int(m), float(rng.uniform(0.2, 0.6)), 3.0)
                        for c, m in zip(centres, sizes, strict=True)])
        params.update(clumps=k, spread_arcmin=round(spread, 2))
    elif shape == "scattered":
        side = extent(8.0, 15.0)
        xy = rng.uniform(-side / 2, side / 2, (n, 2))
        params["side_arcmin"] = round(side, 2)
    else:  # two-clump
        span = extent(*TWO_CLUMP_EXTENT_ARCMIN)
        frac, angle = float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.0, np.pi))
        r_max = min(2.0, span / 4)  # each clump within a quarter of the span of the pair
        half = (span / 2 - r_max) * np.array([np.cos(angle), np.sin(angle)])
        n1 = int(round(frac * n))
        xy = np.vstack([c + _plummer_arcmin(rng, m, float(rng.uniform(0.2, 0.8)), r_max,
                                            truncate=True)
                        for c, m in ((half, n1), (-half, n - n1))])
        params.update(span_arcmin=round(span, 2), first_clump_fraction=round(frac, 2))
    ra0, dec0 = float(rng.uniform(0.0, 360.0)), float(rng.uniform(-30.0, 60.0))
    dec = dec0 + xy[:, 1] / 60.0
    ra = (ra0 + xy[:, 0] / 60.0 / np.cos(np.radians(dec))) % 360.0
    prio = rng.choice(PRIORITY_VALUES, size=len(xy), p=PRIORITY_SHARES)
    targets = [{"id": f"s{i}", "ra_deg": float(a), "dec_deg": float(d), "priority": int(p)}
               for i, (a, d, p) in enumerate(zip(ra, dec, prio, strict=True))]
    return targets, params


def plan_programme(targets: list[dict[str, Any]], seed: int, mode: str | None = None,
                   ) -> tuple[dict[str, Any], float]:
    """The plan ``POST /v1/plans`` answers for ``{"targets": ..., "seed": seed}`` (and
    ``segmentation_mode``, when ``mode`` is given) on a server with default settings, and its
    wall time."""
    from service import pipeline
    from service.schemas import PlanRequest
    from service.settings import Settings

    settings = Settings()
    body = {"targets": targets, "seed": seed}
    req = PlanRequest.model_validate(body if mode is None else {**body, "segmentation_mode": mode})
    inst = pipeline.instrument_from(None)
    t0 = time.perf_counter()
    plan = pipeline.plan(req, inst, budget_s=settings.plan_budget_s)
    return plan, time.perf_counter() - t0


def summarise(plan: dict[str, Any], wall_s: float) -> dict[str, Any]:
    s = plan["stats"]
    motions = s["motion_plans"]
    return {
        "pointings": s["pointings"], "executable": plan["executable"],
        "legs_planned": motions - s["motion_plans_failed"], "legs": motions,
        "exposures": s["configurations"], "targets": s["targets"],
        "observed": s["allocated_targets"],
        "not_observed_by_reason": s["unallocated_by_reason"],
        "priority_completeness": round(s["priority_completeness"], 4),
        "limit_s": s["time_limit_s"], "elapsed_s": round(s["elapsed_s"], 2),
        "time_used": round(s["elapsed_s"] / s["time_limit_s"], 3),
        "rounds": s.get("rounds"), "wall_s": round(wall_s, 2),
        "overran": sum(bool(p["stats"].get("effort", {}).get("overran")) for p in plan["pointings"]),
    }


def run(programmes: list[tuple[str, int]], max_targets: int | None = None,
        mode: str | None = None) -> dict[str, Any]:
    from service import pipeline

    pipeline.warm_up()
    rows = []
    for shape, seed in programmes:
        targets, params = programme_targets(shape, seed)
        if max_targets is not None:
            targets = targets[:max_targets]
            params["n"] = len(targets)
        plan, wall_s = plan_programme(targets, seed, mode)
        row = {**params, **summarise(plan, wall_s)}
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    failed = [r for r in rows if not r["executable"]]
    multi = [r for r in rows if r["pointings"] > 1]
    return {
        "protocol": "POST /v1/plans defaults: targets + seed only, MXS_PLAN_BUDGET_S = 120 s",
        "machine": {"python": platform.python_version(), "cpus": _cpus()},
        "programmes": len(rows),
        "executable": sum(r["executable"] for r in rows),
        "multi_pointing": len(multi),
        "multi_pointing_executable": sum(r["executable"] for r in multi),
        "legs_planned": sum(r["legs_planned"] for r in rows), "legs": sum(r["legs"] for r in rows),
        "failed_under_half_limit": sum(r["time_used"] < 0.5 for r in failed),
        "pointings_median": statistics.median(r["pointings"] for r in rows),
        "pointings_range": [min(r["pointings"] for r in rows), max(r["pointings"] for r in rows)],
        "exposures_total": sum(r["exposures"] for r in rows),
        "observed_fraction": round(sum(r["observed"] for r in rows) / sum(r["targets"] for r in rows), 4),
        "time_used_median": statistics.median(r["time_used"] for r in rows),
        "time_used_max": max(r["time_used"] for r in rows),
        "wall_s_median": statistics.median(r["wall_s"] for r in rows),
        "wall_s_max": max(r["wall_s"] for r in rows),
        "overran_pointings": sum(r["overran"] for r in rows),
        "rows": rows,
    }


def _cpus() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=30, help="programmes (shapes in turn)")
    ap.add_argument("--seed0", type=int, default=100, help="the first programme's seed")
    ap.add_argument("--shapes", nargs="+", default=list(SHAPES), choices=ALL_SHAPES)
    ap.add_argument("--smoke", action="store_true", help="two small programmes (CI)")
    ap.add_argument("--segmentation-mode", default=None,
                    help="the plans' segmentation_mode (default: the plan's default)")
    args = ap.parse_args(argv)
    if args.smoke:
        programmes = [("clumps", 2), ("scattered", 7)]
    else:
        programmes = [(args.shapes[i % len(args.shapes)], args.seed0 + i) for i in range(args.n)]
    out = {"params": vars(args), **run(programmes, 30 if args.smoke else None, args.segmentation_mode)}
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
