"""Regenerate the sample target lists and request bodies in ``examples/`` (deterministic).

    python examples/make_examples.py

- ``ngc869_targets.csv`` / ``.ecsv``: 60 stars scattered over ~9 arcmin around the
  double cluster h Persei (NGC 869, RA 34.7500, Dec +57.1333) — several pointings.
- ``m13_targets.csv``: 40 stars within 2 arcmin of M13 — one pointing, several configurations.
- ``requests/*.json``: bodies for the curl examples of the README (one per endpoint):
  ``plan.json`` is a small one-pointing field (12 M13 stars) for the synchronous
  ``POST /v1/plans``; ``job.json`` plans the whole NGC 869 field as a job.

Priorities follow the thesis protocol (5.5.3): 10 % 500, 40 % 100, 40 % 10, 10 % 1.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from astropy.table import Table

HERE = Path(__file__).resolve().parent


def _priorities(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.choice([500, 100, 10, 1], size=n, p=[0.1, 0.4, 0.4, 0.1])


def field(name: str, ra0: float, dec0: float, n: int, radius_arcmin: float, seed: int) -> Table:
    rng = np.random.default_rng(seed)
    r = radius_arcmin / 60.0 * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    dec = dec0 + r * np.sin(phi)
    ra = (ra0 + r * np.cos(phi) / np.cos(np.radians(dec0))) % 360.0
    t = Table()
    t["id"] = [f"{name}-{i:03d}" for i in range(n)]
    t["ra_deg"] = np.round(ra, 7)
    t["dec_deg"] = np.round(dec, 7)
    t["priority"] = _priorities(rng, n)
    t["ra_deg"].unit = "deg"
    t["dec_deg"].unit = "deg"
    t.meta["comments"] = [f"{name}: synthetic targets, seed {seed} (examples/make_examples.py)"]
    return t


def _rows(t: Table) -> list[dict]:
    return [
        {"id": str(row["id"]), "ra_deg": float(row["ra_deg"]), "dec_deg": float(row["dec_deg"]),
         "priority": int(row["priority"])}
        for row in t
    ]


def _nearest(t: Table, ra0: float, dec0: float, n: int) -> Table:
    """The ``n`` rows of ``t`` closest to (ra0, dec0), in their table order."""
    d = np.hypot((t["ra_deg"] - ra0) * np.cos(np.radians(dec0)), t["dec_deg"] - dec0)
    return t[np.sort(np.argsort(d)[:n])]


def requests(ngc869: Table, m13: Table) -> dict[str, dict]:
    from models.instrument import default_instrument
    from models.kinematics import inverse_fov

    inst = default_instrument()
    rng = np.random.default_rng(7)
    r = 110.0 * np.sqrt(rng.uniform(0, 1, 24))
    phi = rng.uniform(0, 2 * np.pi, 24)
    plane = [
        {"id": f"p{i:02d}", "x_mm": round(float(r[i] * np.cos(phi[i])), 3),
         "y_mm": round(float(r[i] * np.sin(phi[i])), 3), "priority": int(p)}
        for i, p in enumerate(_priorities(rng, 24))
    ]
    sky = _rows(ngc869)
    park = [{"arm": a.index, "theta1_rad": a.park_theta1_rad, "theta2_rad": a.park_theta2_rad}
            for a in inst.arms]
    ik = inverse_fov(inst, 0, 60.0, 0.0)  # arm 0 reaches a point on its own side of the FOV
    k = int(np.flatnonzero(ik.valid.ravel())[0])
    goal = [dict(s) for s in park]
    goal[0]["theta1_rad"] = round(float(ik.theta1_rad.ravel()[k]), 9)
    goal[0]["theta2_rad"] = round(float(ik.theta2_rad.ravel()[k]), 9)
    return {
        "segmentation": {"targets": sky},
        "allocation": {"targets": plane, "method": "ilp", "solver": "highs",
                       "configurations": "all", "time_limit_s": 10, "seed": 1},
        # the 20 stars nearest the pointing: all inside the 2.5 arcmin FOV radius
        "allocation_sky": {"targets": _rows(_nearest(ngc869, 34.75, 57.1333, 20)),
                           "pointing": {"ra_deg": 34.75, "dec_deg": 57.1333,
                                        "position_angle_deg": 0.0},
                           "method": "semigreedy", "seed": 1},
        "motion_plan": {"start": park, "goal": goal, "seed": 1},
        # a small field for the synchronous endpoint; whole fields go through /v1/jobs
        "plan": {"targets": _rows(_nearest(m13, 250.4235, 36.4613, 12)), "method": "ilp",
                 "time_limit_s": 5, "seed": 1},
        "job": {"kind": "plan", "request": {"targets": sky, "seed": 1}},
    }


def main() -> None:
    ngc869 = field("NGC869", 34.75, 57.1333, 60, 4.5, seed=869)
    ngc869.write(HERE / "ngc869_targets.csv", format="ascii.csv", overwrite=True)
    ngc869.write(HERE / "ngc869_targets.ecsv", format="ascii.ecsv", overwrite=True)
    m13 = field("M13", 250.4235, 36.4613, 40, 2.0, seed=13)
    m13.write(HERE / "m13_targets.csv", format="ascii.csv", overwrite=True)
    for name, body in requests(ngc869, m13).items():
        (HERE / "requests" / f"{name}.json").write_text(json.dumps(body, indent=1) + "\n")


if __name__ == "__main__":
    main()
