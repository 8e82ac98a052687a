"""Set-partitioning LP bound on the configuration count (solvers.sequencing.bounds.configuration_lp_bound).

Oracles, all independent of the column generation:

* the exact optimum, from CP-SAT packings (``pack_targets`` with ``tabu_fraction=0``) into
  n = 1, 2, ... configurations, every n below the optimum proven infeasible;
* the simpler rigorous bounds: ceil(t / 12), the max-flow bound, the crowding bound (a
  special case of the LP's dual, so never above the converged LP bound);
* an enumeration with FCL clearances of every set of targets one configuration can observe
  (the LP's relaxation: idle arms absent), which checks the certificate and the LP value;
* for the ring-aggregated master (``groups``, :func:`radial_lp_bound`): the same
  enumeration with the rows summed per ring, and the crowding bound it generalises;
* constructed clusters whose targets are pairwise exclusive (``max_simultaneous_targets``
  proves 1), so each needs a configuration of its own.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from models.collision import fcl_clearance_mm
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from solvers.sequencing import pack_targets
from solvers.sequencing.bounds import (
    configuration_lp_bound,
    crowding_lower_bound,
    matching_lower_bound,
    max_simultaneous_targets,
    radial_lp_bound,
)

INS = default_instrument()
# generous limits: every instance below converges in well under a second on one core
LP_LIMITS = {"time_limit_s": 120.0, "price_time_limit_s": 60.0}


def _central(rng: np.random.Generator, n: int, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    r = radius_mm * np.sqrt(rng.random(n))
    a = rng.random(n) * 2 * np.pi
    return r * np.cos(a), r * np.sin(a)


def _exact_optimum(inc, pool: np.ndarray) -> int:
    """Fewest configurations for ``pool``: CP-SAT packings into n = 1, 2, ..., every n below
    the returned one proven infeasible (instances chosen to solve in a few seconds)."""
    for n in range(1, len(pool) + 1):
        status: dict = {}
        packed = pack_targets(inc, pool, n, time_limit_s=120.0, status_out=status, tabu_fraction=0.0)
        if packed is not None:
            return n
        assert status["infeasible"], f"CP-SAT neither packed nor refuted {n} configurations"
    raise AssertionError("no packing into one configuration per target")


def _compatible_target_sets(x: np.ndarray, y: np.ndarray) -> list[frozenset[int]]:
    """Every non-empty set of targets that one configuration can observe with the arms not
    on them absent (the LP's relaxation), by depth-first enumeration over the reachable
    assignments with pairwise FCL clearances (independent of the incompatibility table)."""
    inc = incompatibility_for_targets(INS, x, y)
    a = inc.assignments
    cols = np.flatnonzero(a.target >= 0).tolist()
    by_target: dict[int, list[int]] = {}
    for c in cols:
        by_target.setdefault(int(a.target[c]), []).append(c)
    ok: dict[tuple[int, int], bool] = {}
    for i, j in itertools.combinations(cols, 2):
        if a.arm[i] == a.arm[j] or a.target[i] == a.target[j]:
            ok[i, j] = ok[j, i] = False
        else:
            ok[i, j] = ok[j, i] = (fcl_clearance_mm(INS, int(a.arm[i]), a.q[i], int(a.arm[j]), a.q[j])
                                   >= INS.collision_buffer_mm)
    targets = sorted(by_target)
    found: set[frozenset[int]] = set()

    def dfs(d: int, chosen: list[int]) -> None:
        if d == len(targets):
            if chosen:
                found.add(frozenset(int(a.target[c]) for c in chosen))
            return
        dfs(d + 1, chosen)
        for c in by_target[targets[d]]:
            if all(ok[c, o] for o in chosen):
                dfs(d + 1, chosen + [c])

    dfs(0, [])
    return sorted(found, key=sorted)


def test_lp_bound_never_exceeds_the_exact_optimum() -> None:
    """Crowded fields (12-24 targets within 30-60 mm of the centre, where the bound is
    strong): the LP bound is at most the CP-SAT optimum.  Field 3 has a gap (bound 5,
    optimum 6 when written), so the check is not only ``bound == optimum``."""
    for seed, n, radius in ((3, 24, 60.0), (10, 24, 60.0), (12, 12, 30.0), (17, 12, 30.0)):
        x, y = _central(np.random.default_rng(seed), n, radius)
        inc = incompatibility_for_targets(INS, x, y)
        mask = inc.reachability.arms_per_target > 0
        bound, info = configuration_lp_bound(inc, mask, **LP_LIMITS)
        opt = _exact_optimum(inc, np.flatnonzero(mask))
        assert info["converged"]
        assert 1 <= bound <= opt, (seed, bound, opt)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(8, 36), radius=st.sampled_from([20.0, 40.0, 60.0, 125.0]),
       keep=st.floats(0.5, 1.0))
def test_converged_lp_bound_dominates_the_simple_bounds(seed: int, n: int, radius: float, keep: float) -> None:
    """Every rigorous bound below is a feasible dual of the LP (ceil(t/12): weights 1/12;
    crowding: 1/m(r) on a disc; max-flow: a fractional b-matching from the LP solution), so
    the converged LP bound is at least each of them — on a random subset of the targets."""
    rng = np.random.default_rng(seed)
    x, y = _central(rng, n, radius)
    inc = incompatibility_for_targets(INS, x, y)
    mask = (inc.reachability.arms_per_target > 0) & (rng.random(n) < keep)
    mask[int(np.flatnonzero(inc.reachability.arms_per_target > 0)[0])] = True
    bound, info = configuration_lp_bound(inc, mask, **LP_LIMITS)
    assert info["converged"]
    t = int(mask.sum())
    crowd, _ = crowding_lower_bound(inc, np.column_stack([x, y]), mask, time_limit_s=30.0)
    assert bound >= math.ceil(t / INS.n_arms)
    assert bound >= crowd
    assert bound >= matching_lower_bound(inc, mask)
    assert bound == math.ceil(info["lp_value"] - 1e-6)
    assert bound <= t  # one target per configuration always covers the LP


def test_certificate_checked_by_fcl_enumeration() -> None:
    """Tiny crowded fields: the certificate's weights are on exactly the masked targets,
    non-negative, no configuration of the relaxation (enumerated with FCL) weighs more than
    1, and ceil(sum w) is the bound; the converged LP value equals the LP solved over all
    enumerated configurations."""
    for seed, n, radius, drop in ((0, 7, 20.0, None), (1, 8, 40.0, 3), (2, 8, 60.0, None), (11, 8, 60.0, None)):
        x, y = _central(np.random.default_rng(seed), n, radius)
        inc = incompatibility_for_targets(INS, x, y)
        mask = inc.reachability.arms_per_target > 0
        if drop is not None:
            mask[drop] = False  # a target outside the mask gets no weight and is not needed
        bound, info = configuration_lp_bound(inc, mask, **LP_LIMITS)
        assert info["converged"]
        sel, w = info["certificate"]
        assert np.array_equal(np.asarray(sel), np.flatnonzero(mask))
        assert len(w) == len(sel) and (np.asarray(w) >= 0).all()
        weight = dict(zip(np.asarray(sel).tolist(), np.asarray(w, float).tolist(), strict=True))
        sets = [s & set(weight) for s in _compatible_target_sets(x, y)]
        sets = [s for s in sets if s]
        heaviest = max(sum(weight[t] for t in s) for s in sets)
        assert heaviest <= 1.0 + 1e-9
        assert math.ceil(float(np.sum(w)) - 1e-6) == bound
        # the relaxation's LP over every enumerated configuration
        order = sorted(weight)
        a_ub = np.array([[1.0 if t in s else 0.0 for s in sets] for t in order])
        res = linprog(np.ones(len(sets)), A_ub=-a_ub, b_ub=-np.ones(len(order)), bounds=(0, None), method="highs")
        assert res.status == 0
        assert abs(res.fun - info["lp_value"]) < 1e-6
        assert bound == math.ceil(res.fun - 1e-6)


def test_pairwise_exclusive_clusters_need_one_configuration_each() -> None:
    """k targets a few mm apart (on the centre and off it, with spread background targets):
    no two can be observed at once (max_simultaneous_targets proves 1), so the bound is at
    least k — off the centre, where the crowding discs do not see the cluster, too."""
    for (cx, cy), spread, k in (((0.0, 0.0), 3.0, 5), ((40.0, 20.0), 3.0, 4), ((-70.0, 30.0), 2.0, 3)):
        rng = np.random.default_rng(k)
        ang = np.arange(k) * 2 * np.pi / k + rng.random()
        bx, by = _central(rng, 10, 120.0)
        x = np.r_[cx + spread * np.cos(ang), bx]
        y = np.r_[cy + spread * np.sin(ang), by]
        inc = incompatibility_for_targets(INS, x, y)
        assert max_simultaneous_targets(inc, np.arange(k), time_limit_s=30.0) == (1, True)
        mask = inc.reachability.arms_per_target > 0
        assert mask[:k].all()
        bound, info = configuration_lp_bound(inc, mask, **LP_LIMITS)
        assert info["converged"]
        assert bound >= k
        # the cluster alone: exactly k (k singletons cover it)
        only = np.zeros(len(x), bool)
        only[:k] = True
        assert configuration_lp_bound(inc, only, **LP_LIMITS)[0] == k


def test_stop_at_stops_early() -> None:
    """stop_at below the full bound ends the column generation at the first iteration whose
    Farley bound reaches it (here the first); stop_at at or above the LP bound gives the
    full bound."""
    x, y = _central(np.random.default_rng(20), 24, 60.0)
    inc = incompatibility_for_targets(INS, x, y)
    mask = inc.reachability.arms_per_target > 0
    full, info = configuration_lp_bound(inc, mask, **LP_LIMITS)
    assert info["converged"] and info["iterations"] > 2
    low = math.ceil(int(mask.sum()) / INS.n_arms)
    assert low < full  # otherwise the instance says nothing
    for stop in (1, low):
        # the singleton master's duals are all 1, so the first Farley bound is
        # ceil(t / heaviest configuration) >= ceil(t / 12): one iteration, not the full run
        bound, early = configuration_lp_bound(inc, mask, stop_at=stop, **LP_LIMITS)
        assert low <= bound <= full
        assert early["iterations"] == 1 < info["iterations"]
        assert not early["converged"]
    # at the full bound: stops when the Farley bound reaches it (at the latest in the
    # iteration that would have proven convergence), with the same bound
    bound, at = configuration_lp_bound(inc, mask, stop_at=full, **LP_LIMITS)
    assert bound == full
    # beyond what the LP gives: runs to convergence, same bound
    bound, late = configuration_lp_bound(inc, mask, stop_at=full + 1, **LP_LIMITS)
    assert late["converged"] and bound == full


def test_known_columns_do_not_change_the_converged_bound() -> None:
    """Starting the master with a CP-SAT packing's configurations (target indices) gives
    the same converged bound and LP value as starting from singletons (on a mask without
    the first targets, so target indices and the mask's own numbering differ)."""
    x, y = _central(np.random.default_rng(14), 24, 60.0)
    inc = incompatibility_for_targets(INS, x, y)
    mask = inc.reachability.arms_per_target > 0
    mask[:3] = False
    pool = np.flatnonzero(mask)
    opt = _exact_optimum(inc, pool)
    packed = pack_targets(inc, pool, opt, time_limit_s=120.0, tabu_fraction=0.0)
    assert packed is not None
    t = inc.assignments.target
    columns = [t[ch][t[ch] >= 0] for ch in packed]
    plain, info = configuration_lp_bound(inc, mask, **LP_LIMITS)
    seeded, info_s = configuration_lp_bound(inc, mask, columns=columns, **LP_LIMITS)
    assert info["converged"] and info_s["converged"]
    assert seeded == plain <= opt
    assert abs(info["lp_value"] - info_s["lp_value"]) < 1e-6


def test_grouped_lp_certificate_checked_by_fcl_enumeration() -> None:
    """Rows summed per 10 mm ring: the certificate gives every target of a ring the same
    weight, no enumerated configuration (FCL) weighs more than 1, ceil(sum w) is the bound;
    the LP value equals the aggregated LP over every enumerated configuration, and the
    bound is never above the per-target master's (it is a relaxation of it)."""
    for seed, n, radius in ((0, 7, 20.0), (2, 8, 60.0), (11, 8, 60.0)):
        x, y = _central(np.random.default_rng(seed), n, radius)
        inc = incompatibility_for_targets(INS, x, y)
        mask = inc.reachability.arms_per_target > 0
        ring = np.floor(np.hypot(x, y) / 10.0).astype(int)
        bound, info = configuration_lp_bound(inc, mask, groups=ring, **LP_LIMITS)
        assert info["converged"]
        sel, w = info["certificate"]
        sel, w = np.asarray(sel), np.asarray(w, float)
        assert np.array_equal(sel, np.flatnonzero(mask)) and (w >= 0).all()
        for g in np.unique(ring[sel]):
            assert np.ptp(w[ring[sel] == g]) < 1e-12
        weight = dict(zip(sel.tolist(), w.tolist(), strict=True))
        sets = [s & set(weight) for s in _compatible_target_sets(x, y)]
        sets = [s for s in sets if s]
        assert max(sum(weight[t] for t in s) for s in sets) <= 1.0 + 1e-9
        assert math.ceil(float(w.sum()) - 1e-6) == bound
        rings = np.unique(ring[sel])
        a_ub = np.array([[sum(1.0 for t in s if ring[t] == g) for s in sets] for g in rings])
        b = np.array([float(np.sum(ring[sel] == g)) for g in rings])
        res = linprog(np.ones(len(sets)), A_ub=-a_ub, b_ub=-b, bounds=(0, None), method="highs")
        assert res.status == 0
        assert abs(res.fun - info["lp_value"]) < 1e-6
        assert bound <= configuration_lp_bound(inc, mask, **LP_LIMITS)[0]


def test_radial_lp_bound_between_crowding_and_the_exact_optimum() -> None:
    """Crowded fields: the radial LP bound is at least the crowding bound over the same discs
    (one ring per disc is the crowding bound's dual) and at most the CP-SAT optimum."""
    radii = (20.0, 30.0, 60.0)
    for seed, n, radius in ((3, 24, 60.0), (12, 12, 30.0), (17, 12, 30.0)):
        x, y = _central(np.random.default_rng(seed), n, radius)
        xy = np.column_stack([x, y])
        inc = incompatibility_for_targets(INS, x, y)
        mask = inc.reachability.arms_per_target > 0
        bound, rows = radial_lp_bound(inc, xy, mask, radii_mm=radii, ring_mm=5.0, time_limit_s=300.0)
        assert rows and all(r["converged"] for r in rows)
        crowd, _ = crowding_lower_bound(inc, xy, mask, radii_mm=radii, time_limit_s=30.0)
        opt = _exact_optimum(inc, np.flatnonzero(mask))
        assert crowd <= bound <= opt, (seed, crowd, bound, opt)
