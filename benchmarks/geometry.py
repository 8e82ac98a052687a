"""Benchmark: the incompatibility structure on crowded, symmetric fields against brute force.

Hypothesis generates crowded fields (2-8 targets within 40 mm of the FOV centre) built from
exact symmetric placements: the centre, points on the axes and on the arm axes, rings at
multiples of 15/30/45 degrees, mirror and rotated copies of earlier points, and points at
exactly the tie distance (two tip radii plus the buffer) from an earlier one. For each field
the structure of :mod:`models.incompatibility` (thesis 5.4) is compared with two
independent oracles:

* reachability: every (arm, target) solved by a root scan of the arm's closure equations
  (theta1 from |tip - J3| = d3tip, then J4 on the ray J3 -> tip at d24 from J2), not by the
  closed-form IK;
* incompatible pairs: every cross-arm pair of assignments (park included) measured with FCL.

A pair is a disagreement when FCL puts it below the buffer and the structure accepts it
(unsafe), or when the structure rejects it although FCL puts it above buffer +
``TIE_TOL_MM`` (over-conservative). Pairs with an FCL clearance in
[buffer, buffer + ``TIE_TOL_MM``) are exact ties; rejecting them is the structure's
documented tie rule, and they are counted. ``worst_margin_mm`` is the smallest
|FCL clearance - buffer| met, i.e. how close to a tie the fields went.

Prints one JSON document; the count measures correctness, not speed.

    python benchmarks/geometry.py                 # 10,000 fields
    python benchmarks/geometry.py --examples 300  # quick look
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field

import fcl
import numpy as np
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st
from scipy.optimize import brentq, minimize_scalar

from models.collision import fcl_arm_objects
from models.incompatibility import Incompatibility, incompatibility_for_targets
from models.instrument import Instrument, default_instrument

FIELD_RADIUS_MM = 40.0
TIE_TOL_MM = 1e-5  # FCL capsule distances agree with exact segment geometry to ~1e-13 mm here
Q_TOL_RAD = 1e-6  # an oracle joint solution matches an IK one within this
ROOT_TOL_MM = 1e-7  # a tangency (double root) counts as a solution below this residual
SCAN_POINTS = 721


# ------------------------------------------------------------------- field generator


def _in_field(p: tuple[float, float]) -> tuple[float, float]:
    """Pull a point into the 40 mm disc along its radius (keeps axis/ring symmetry)."""
    x, y = p
    r = math.hypot(x, y)
    if r > FIELD_RADIUS_MM:
        return (x * FIELD_RADIUS_MM / r, y * FIELD_RADIUS_MM / r)
    return (x, y)


def _polar(r: float, deg: float) -> tuple[float, float]:
    a = math.radians(deg)
    return (r * math.cos(a), r * math.sin(a))


def tie_distance_mm(instrument: Instrument) -> float:
    """Two tip bodies at this centre distance touch the buffer exactly."""
    tip = instrument.arms[0].bodies[-1]
    return 2 * tip.half_width_mm + instrument.collision_buffer_mm


@st.composite
def crowded_fields(draw, tie_mm: float = 25.0) -> list[tuple[float, float]]:
    """2-8 points within 40 mm of the centre, mostly exact symmetric placements."""
    n = draw(st.integers(2, 8))
    coord = st.floats(-FIELD_RADIUS_MM, FIELD_RADIUS_MM, allow_nan=False, allow_infinity=False)
    nice = st.sampled_from([0.0, 5.0, 10.0, 12.5, 15.0, 20.0, 21.65, 25.0, 30.0, 32.0, 35.0, 40.0])
    radius = st.one_of(nice, st.floats(0.0, FIELD_RADIUS_MM))
    angle = st.one_of(st.integers(0, 23).map(lambda k: 15.0 * k), st.integers(0, 7).map(lambda k: 45.0 * k))
    pts: list[tuple[float, float]] = []
    while len(pts) < n:
        kind = draw(st.sampled_from(["centre", "axis", "ring", "arm_axis", "mirror", "rotate", "tie",
                                     "duplicate", "free"]))
        if kind in ("mirror", "rotate", "tie", "duplicate") and not pts:
            kind = "centre"
        if kind == "centre":
            p = (0.0, 0.0)
        elif kind == "axis":
            v = draw(st.one_of(nice, coord)) * draw(st.sampled_from([1.0, -1.0]))
            p = (v, 0.0) if draw(st.booleans()) else (0.0, v)
        elif kind == "ring":
            p = _polar(draw(radius), draw(angle))
        elif kind == "arm_axis":  # on the line from an arm's base through the centre
            p = _polar(draw(radius), 30.0 * draw(st.integers(0, 11)) + 180.0)
        elif kind == "mirror":
            x, y = draw(st.sampled_from(pts))
            p = draw(st.sampled_from([(-x, y), (x, -y), (-x, -y), (y, x)]))
        elif kind == "rotate":
            x, y = draw(st.sampled_from(pts))
            c, s = math.cos(math.radians(draw(angle))), math.sin(math.radians(draw(angle)))
            p = (c * x - s * y, s * x + c * y)
        elif kind == "tie":  # exactly the tie distance from an earlier point
            x, y = draw(st.sampled_from(pts))
            dx, dy = _polar(tie_mm, draw(angle))
            p = (x + dx, y + dy)
        elif kind == "duplicate":
            p = draw(st.sampled_from(pts))
        else:
            p = (draw(coord), draw(coord))
        pts.append(_in_field(p))
    return pts


# ------------------------------------------------------------------- oracles


def _arm_frame(instrument: Instrument, k: int, x: float, y: float) -> tuple[float, float]:
    a = instrument.arms[k]
    ex = (math.cos(a.orientation_rad), math.sin(a.orientation_rad))
    dx, dy = x - a.base_x_mm, y - a.base_y_mm
    return dx * ex[0] + dy * ex[1], -dx * ex[1] + dy * ex[0]


def _roots(f, lo: float, hi: float, tol: float) -> list[float]:
    """Every root of ``f`` (vectorised) on [lo, hi]: sign changes on a scan (refined by Brent) and
    tangencies (a local minimum of |f| refined to a residual below ``tol``)."""
    grid = np.linspace(lo, hi, SCAN_POINTS)
    vals = np.asarray(f(grid), float)  # f is vectorised
    out = []
    for i in range(len(grid) - 1):
        if vals[i] == 0.0:
            out.append(float(grid[i]))
        elif vals[i] * vals[i + 1] < 0:
            out.append(float(brentq(f, grid[i], grid[i + 1], xtol=1e-14, rtol=1e-14)))
    if vals[-1] == 0.0:
        out.append(float(grid[-1]))
    mag = np.abs(vals)
    for i in range(1, len(grid) - 1):
        # a tangency: |f| has a local minimum and f keeps its sign on both sides
        if mag[i] <= mag[i - 1] and mag[i] <= mag[i + 1] and vals[i - 1] * vals[i + 1] > 0 \
                and vals[i - 1] * vals[i] > 0 and vals[i] * vals[i + 1] > 0:
            m = minimize_scalar(lambda t: abs(f(t)), bounds=(grid[i - 1], grid[i + 1]), method="bounded",
                                options={"xatol": 1e-13})
            if abs(f(m.x)) < tol:
                out.append(float(m.x))
    for end in (0, len(grid) - 1):  # a tangency at an end of the range
        j = 1 if end == 0 else len(grid) - 2
        if 0 < mag[end] < tol and vals[end] * vals[j] > 0:
            out.append(float(grid[end]))
    out.sort()
    merged = [r for i, r in enumerate(out) if i == 0 or r - out[i - 1] > 1e-7]
    return merged


def oracle_solutions(instrument: Instrument, k: int, x_mm: float, y_mm: float) -> list[tuple[float, float]]:
    """Feasible (theta1, theta2) of arm k with its tip on (x, y), by root scans.

    theta1 solves |P - J3(theta1)| = d3tip on the arm's theta1 range; for each, J4 = J3 + s u
    (u the unit vector J3 -> P) solves |J4 - J2| = d24 with s strictly between the stops.
    """
    a = instrument.arms[k]
    px, py = _arm_frame(instrument, k, x_mm, y_mm)

    def f1(t1):
        return np.hypot(px - a.d13_mm * np.cos(t1), py - a.d13_mm * np.sin(t1)) - a.d3tip_mm

    out = []
    for t1 in _roots(f1, a.theta1_min_rad, a.theta1_max_rad, ROOT_TOL_MM):
        j3 = (a.d13_mm * math.cos(t1), a.d13_mm * math.sin(t1))
        ux, uy = (px - j3[0]) / a.d3tip_mm, (py - j3[1]) / a.d3tip_mm

        def f2(s, j3=j3, ux=ux, uy=uy):
            return np.hypot(j3[0] + s * ux - a.d12_mm, j3[1] + s * uy) - a.d24_mm

        for s in _roots(f2, a.stop_min_mm, a.stop_max_mm, ROOT_TOL_MM):
            if a.stop_min_mm < s < a.stop_max_mm:
                j4x, j4y = j3[0] + s * ux, j3[1] + s * uy
                out.append((t1, math.atan2(j4y, a.d12_mm - j4x) % (2 * math.pi)))
    return out


def _angle_close(a: float, b: float) -> bool:
    d = (a - b + math.pi) % (2 * math.pi) - math.pi
    return abs(d) < Q_TOL_RAD


def reachability_disagreements(instrument: Instrument, inc: Incompatibility,
                               x: np.ndarray, y: np.ndarray) -> list[dict]:
    """(arm, target) whose structure assignments differ from the oracle's solutions."""
    asg = inc.assignments
    bad = []
    for t in range(len(x)):
        for k in range(instrument.n_arms):
            if not instrument.arms[k].enabled:
                continue
            sel = (asg.arm == k) & (asg.target == t)
            got = list(zip(asg.theta1_rad[sel].tolist(), asg.theta2_rad[sel].tolist(), strict=True))
            want = oracle_solutions(instrument, k, float(x[t]), float(y[t]))
            unmatched_got = [g for g in got if not any(_angle_close(g[0], w[0]) and _angle_close(g[1], w[1])
                                                       for w in want)]
            unmatched_want = [w for w in want if not any(_angle_close(g[0], w[0]) and _angle_close(g[1], w[1])
                                                         for g in got)]
            if unmatched_got or unmatched_want or len(got) != len(want):
                bad.append({"kind": "reachability", "arm": k, "target": t, "xy_mm": [float(x[t]), float(y[t])],
                            "structure": got, "oracle": want})
    reach_arms = {(int(k), int(t)) for k, t in zip(asg.arm, asg.target, strict=True) if t >= 0}
    for t in range(len(x)):
        n_arms = len({k for k, tt in reach_arms if tt == t})
        if int(inc.reachability.arms_per_target[t]) != n_arms:
            bad.append({"kind": "arms_per_target", "target": t, "structure": int(inc.reachability.arms_per_target[t]),
                        "from_assignments": n_arms})
    return bad


@dataclass
class PairCheck:
    """Outcome of the FCL comparison on one field."""

    disagreements: list[dict] = field(default_factory=list)
    ties: int = 0
    pairs: int = 0
    worst_margin_mm: float = math.inf


def pair_disagreements(instrument: Instrument, inc: Incompatibility) -> PairCheck:
    """Every cross-arm assignment pair: structure verdict vs FCL clearance."""
    asg = inc.assignments
    buffer_mm = inc.buffer_mm
    objs = [fcl_arm_objects(instrument, int(asg.arm[i]), float(asg.theta1_rad[i]), float(asg.theta2_rad[i]))
            for i in range(len(asg))]
    got = {tuple(p) for p in inc.pairs.tolist()}
    request = fcl.DistanceRequest()
    out = PairCheck()
    for i in range(len(asg)):
        for j in range(i + 1, len(asg)):
            if asg.arm[i] == asg.arm[j]:
                continue
            out.pairs += 1
            in_structure = (i, j) in got
            if asg.target[i] >= 0 and asg.target[i] == asg.target[j]:
                if not in_structure:
                    out.disagreements.append({"kind": "same_target_missing", "pair": [i, j]})
                continue
            d = min(max(fcl.distance(a, b, request, fcl.DistanceResult()), 0.0) for a in objs[i] for b in objs[j])
            out.worst_margin_mm = min(out.worst_margin_mm, abs(d - buffer_mm))
            if d < buffer_mm and not in_structure:
                kind = "missed_collision"
            elif d >= buffer_mm + TIE_TOL_MM and in_structure:
                kind = "spurious_collision"
            else:
                out.ties += int(buffer_mm <= d < buffer_mm + TIE_TOL_MM)
                continue
            out.disagreements.append({"kind": kind, "pair": [i, j], "fcl_clearance_mm": d,
                                      "arms": [int(asg.arm[i]), int(asg.arm[j])],
                                      "targets": [int(asg.target[i]), int(asg.target[j])]})
    return out


def check_field(instrument: Instrument, points: list[tuple[float, float]]) -> dict:
    """Structure vs both oracles on one field; returns counts and the disagreements."""
    xy = np.asarray(points, float).reshape(-1, 2)
    inc = incompatibility_for_targets(instrument, xy[:, 0], xy[:, 1])
    reach = reachability_disagreements(instrument, inc, xy[:, 0], xy[:, 1])
    pairs = pair_disagreements(instrument, inc)
    return {"disagreements": reach + pairs.disagreements, "ties": pairs.ties, "pairs": pairs.pairs,
            "assignments": len(inc.assignments), "worst_margin_mm": pairs.worst_margin_mm}


# ------------------------------------------------------------------- driver


def run(n_examples: int, seed: int = 0, instrument: Instrument | None = None) -> dict:
    """Check ``n_examples`` hypothesis fields (reproducible for a given ``seed``) and summarise."""
    ins = instrument or default_instrument()
    summary = {"fields": 0, "pairs": 0, "assignments": 0, "ties": 0, "disagreements": 0,
               "worst_margin_mm": math.inf, "examples": []}

    @hypothesis_seed(seed)
    @settings(max_examples=n_examples, database=None, deadline=None,
              phases=[Phase.explicit, Phase.generate], suppress_health_check=list(HealthCheck))
    @given(crowded_fields(tie_distance_mm(ins)))
    def one(points):
        r = check_field(ins, points)
        summary["fields"] += 1
        summary["pairs"] += r["pairs"]
        summary["assignments"] += r["assignments"]
        summary["ties"] += r["ties"]
        summary["worst_margin_mm"] = min(summary["worst_margin_mm"], r["worst_margin_mm"])
        if r["disagreements"]:
            summary["disagreements"] += len(r["disagreements"])
            if len(summary["examples"]) < 20:
                summary["examples"].append({"points_mm": points, "disagreements": r["disagreements"][:5]})

    one()
    return summary


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--examples", type=int, default=10_000, help="hypothesis fields to check")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    out = run(args.examples, args.seed)
    out.update({"requested": args.examples, "field_radius_mm": FIELD_RADIUS_MM, "tie_tolerance_mm": TIE_TOL_MM,
                "command": "python benchmarks/geometry.py " + " ".join(argv if argv is not None else sys.argv[1:])})
    print(json.dumps(out, indent=2, default=float))


if __name__ == "__main__":
    main()
