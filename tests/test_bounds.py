"""Lower bounds on the configuration count: brute-force and sequencing oracles."""

from __future__ import annotations

import itertools
import math
from functools import partial

import numpy as np

from models.collision import fcl_clearance_mm
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from models.types import PlaneTargets
from solvers.allocation.bnb import solve_ilp_bnb
from solvers.sequencing import (
    PackingOptions,
    SequenceOptions,
    SequencingOptions,
    sequence_configurations,
)
from solvers.sequencing.bounds import crowding_lower_bound, max_simultaneous_targets

INS = default_instrument()


def _central(rng: np.random.Generator, n: int, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    r = radius_mm * np.sqrt(rng.random(n))
    a = rng.random(n) * 2 * np.pi
    return r * np.cos(a), r * np.sin(a)


def _brute_force_max(x: np.ndarray, y: np.ndarray) -> int:
    """Most targets observable at once, by enumeration with FCL (independent of the table)."""
    inc = incompatibility_for_targets(INS, x, y)
    a = inc.assignments
    cols = np.flatnonzero(a.target >= 0)
    ok = {}
    for i, j in itertools.combinations(cols.tolist(), 2):
        if a.arm[i] == a.arm[j] or a.target[i] == a.target[j]:
            ok[i, j] = False
        else:
            ok[i, j] = fcl_clearance_mm(INS, int(a.arm[i]), a.q[i], int(a.arm[j]), a.q[j]) >= INS.collision_buffer_mm
    best = 1 if len(cols) else 0
    for size in range(2, min(len(x), INS.n_arms) + 1):
        found = any(all(ok[p] for p in itertools.combinations(sub, 2))
                    for sub in itertools.combinations(cols.tolist(), size))
        if not found:
            break
        best = size
    return best


def test_max_simultaneous_targets_equals_fcl_enumeration() -> None:
    for seed, radius in ((0, 20.0), (1, 35.0), (2, 50.0)):
        x, y = _central(np.random.default_rng(seed), 5, radius)
        inc = incompatibility_for_targets(INS, x, y)
        m, proven = max_simultaneous_targets(inc, np.arange(5), time_limit_s=30.0)
        assert proven
        assert m == _brute_force_max(x, y)


def test_crowding_bound_is_informative_and_never_beaten() -> None:
    """40 targets within 25 mm of the centre: arms converging on the centre collide, so the
    crowding bound exceeds ceil(t / 12) and the max-flow bound, and no sequence beats it."""
    x, y = _central(np.random.default_rng(3), 40, 25.0)
    inc = incompatibility_for_targets(INS, x, y)
    lb, rows = crowding_lower_bound(inc, np.column_stack([x, y]), np.ones(40, bool), time_limit_s=30.0)
    assert lb > math.ceil(40 / 12)
    assert any(r["proven"] and r["lower_bound"] == lb for r in rows)
    t = PlaneTargets.from_lists([f"t{i}" for i in range(40)], x, y, np.ones(40, np.int64))
    r = sequence_configurations(INS, t, partial(solve_ilp_bnb, fallback=None),
                                SequencingOptions(sequence=SequenceOptions(config_time_limit_s=60.0),
                                                  packing=PackingOptions(enabled=False)), incompatibility=inc,
                                time_limit_s=600.0)
    assert r.stats["field_completeness"] == 1.0
    assert r.stats["n_configurations"] >= lb
    # every configuration observes at most max_at_once targets of each disc
    xy = np.column_stack([x, y])
    for row in rows:
        inside = set(np.flatnonzero(np.hypot(xy[:, 0], xy[:, 1]) <= row["radius_mm"]).tolist())
        for c in r.configurations:
            got = sum(1 for a in c.assignments if a.target_index in inside)
            assert got <= row["max_at_once"]
