"""Crowded, symmetric fields: the incompatibility structure against brute-force oracles.

The field generator and both oracles (root-scan reachability, FCL on every cross-arm pair)
live in ``benchmarks/geometry.py``, which runs the same check on 10,000 fields.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from hypothesis import HealthCheck, given, settings

from benchmarks.geometry import (
    FIELD_RADIUS_MM,
    check_field,
    crowded_fields,
    oracle_solutions,
    pair_disagreements,
    reachability_disagreements,
    tie_distance_mm,
)
from models.collision import arm_pair_clearance_mm
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from models.kinematics import inverse_fov

INS = default_instrument()
TIE_MM = tie_distance_mm(INS)


@settings(max_examples=50, derandomize=True, database=None, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(crowded_fields(TIE_MM))
def test_crowded_fields_agree_with_fcl_and_root_scan(points) -> None:
    assert 2 <= len(points) <= 8
    assert all(math.hypot(x, y) <= FIELD_RADIUS_MM + 1e-9 for x, y in points)
    r = check_field(INS, points)
    assert r["pairs"] > 0
    assert r["disagreements"] == [], r["disagreements"][:3]


def test_generator_makes_exact_symmetric_placements() -> None:
    """The strategy really produces centres, axis points, mirror pairs and exact ties."""
    from hypothesis import find

    find(crowded_fields(TIE_MM), lambda p: (0.0, 0.0) in p and len(p) >= 3)
    find(crowded_fields(TIE_MM), lambda p: any(x == 0.0 and y != 0.0 for x, y in p))
    find(crowded_fields(TIE_MM), lambda p: any((-x, y) in p and x != 0 for x, y in p))
    find(crowded_fields(TIE_MM), lambda p: any(abs(math.dist(a, b) - TIE_MM) < 1e-9 for a in p for b in p))


def test_pair_oracle_catches_a_dropped_and_an_added_pair() -> None:
    """The FCL oracle fails a structure that misses one collision or invents one."""
    inc = incompatibility_for_targets(INS, np.array([0.0, 0.0]), np.array([0.0, 25.0]))
    assert pair_disagreements(INS, inc).disagreements == []
    a = inc.assignments
    clear = [float(arm_pair_clearance_mm(INS, int(a.arm[i]), a.q[i], int(a.arm[j]), a.q[j])) for i, j in inc.pairs]
    deep = next(p for p, same in enumerate(inc.same_target) if not same and clear[p] < inc.buffer_mm - 1.0)
    dropped = dataclasses.replace(inc, pairs=np.delete(inc.pairs, deep, axis=0))
    kinds = [d["kind"] for d in pair_disagreements(INS, dropped).disagreements]
    assert kinds == ["missed_collision"]
    have = {tuple(p) for p in inc.pairs.tolist()}
    far = next((i, j) for i in range(len(a)) for j in range(i + 1, len(a))
               if a.arm[i] != a.arm[j] and (i, j) not in have and a.target[i] == -1 and a.target[j] == -1)
    added = dataclasses.replace(inc, pairs=np.vstack([inc.pairs, far]))
    kinds = [d["kind"] for d in pair_disagreements(INS, added).disagreements]
    assert kinds == ["spurious_collision"]


def test_reachability_oracle_matches_ik_and_catches_a_missing_branch() -> None:
    for k in (0, 4, 11):
        for x, y in ((0.0, 0.0), (-32.0, 0.0), (20.0, -35.0)):
            sol = inverse_fov(INS, k, x, y)
            want = oracle_solutions(INS, k, x, y)
            assert len(want) == int(sol.valid.sum())
    x, y = np.array([0.0, 10.0]), np.array([0.0, 0.0])
    inc = incompatibility_for_targets(INS, x, y)
    assert reachability_disagreements(INS, inc, x, y) == []
    a = inc.assignments
    drop = int(np.flatnonzero(a.target == 1)[0])
    keep = np.arange(len(a)) != drop
    fields = {f.name: getattr(a, f.name)[keep] for f in dataclasses.fields(a) if f.name != "arm_start"}
    fewer = dataclasses.replace(a, **fields)
    broken = dataclasses.replace(inc, reachability=dataclasses.replace(inc.reachability, assignments=fewer))
    bad = reachability_disagreements(INS, broken, x, y)
    assert any(d["kind"] == "reachability" and d["target"] == 1 for d in bad)
