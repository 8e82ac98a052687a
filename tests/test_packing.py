"""Tabu search packing targets into n configurations (solvers.sequencing.tabu.tabu_pack).

Oracles, independent of the search: FCL on every returned configuration (the search only
reads the incompatibility structure), the tip-on-target check, the multiset of observed
targets, and CP-SAT (``pack_targets`` with ``tabu_fraction=0``: no tabu inside) for
which packings exist and which are proven impossible.  The searches run with iteration
limits and time limits far above what they need, so outcomes do not depend on load.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from models.collision import fcl_configuration_collisions
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from models.kinematics import tip_fov
from solvers.sequencing import pack_targets
from solvers.sequencing.tabu import tabu_pack

INS = default_instrument()
LONG_S = 120.0  # time limits never reached: the searches below end on iterations


def _field(seed: int, n: int, sigma_mm: float | None = None, blank_per_arm: int = 0):
    """Uniform over the FOV, or Gaussian about the centre; (x, y, incompatibility)."""
    rng = np.random.default_rng(seed)
    if sigma_mm is None:
        r = 125.0 * np.sqrt(rng.random(n))
        ang = rng.random(n) * 2 * np.pi
        x, y = r * np.cos(ang), r * np.sin(ang)
    else:
        x, y = rng.normal(0, sigma_mm, n), rng.normal(0, sigma_mm, n)
        keep = np.hypot(x, y) < 124.0
        x, y = x[keep], y[keep]
    return x, y, incompatibility_for_targets(INS, x, y, blank_per_arm=blank_per_arm)


def _reachable(inc) -> np.ndarray:
    return np.flatnonzero(inc.reachability.arms_per_target > 0)


def _check_packing(inc, x, y, pool, packing, n_configs: int) -> None:
    """n_configs configurations, each with one location per arm in arm order, collision-free
    by FCL, every tip on its target, idle arms on rest locations; the observed targets are
    exactly the pool, each once."""
    a = inc.assignments
    assert packing is not None
    assert len(packing) == n_configs
    seen: list[int] = []
    for ch in packing:
        ch = np.asarray(ch)
        assert ch.shape == (INS.n_arms,)
        assert a.arm[ch].tolist() == list(range(INS.n_arms))
        q = a.q[ch]
        assert fcl_configuration_collisions(INS, q) == []
        tips = tip_fov(INS, np.arange(INS.n_arms), q[:, 0], q[:, 1])
        for k, loc in enumerate(ch):
            tg = int(a.target[loc])
            if tg >= 0:
                assert np.hypot(tips[k, 0] - x[tg], tips[k, 1] - y[tg]) < 0.01
                seen.append(tg)
    assert sorted(seen) == sorted(np.asarray(pool).tolist())


def _target_sets(inc, configs) -> list[list[int]]:
    t = inc.assignments.target
    return sorted(sorted(int(g) for g in t[np.asarray(ch)] if g >= 0) for ch in configs)


def _cp_sat_packing(inc, pool) -> tuple[int, list[np.ndarray]]:
    """The fewest configurations CP-SAT packs the pool into (from ceil(t/12) up; each count
    below it proven infeasible) and its packing."""
    for n in range(math.ceil(len(pool) / INS.n_arms), len(pool) + 1):
        status: dict = {}
        packed = pack_targets(inc, pool, n, time_limit_s=LONG_S, status_out=status, tabu_fraction=0.0)
        if packed is not None:
            return n, packed
        assert status["infeasible"], f"CP-SAT neither packed nor refuted {n} configurations"
    raise AssertionError("unreachable: one target per configuration always packs")


# Fields with idle arms in the tight packing (t < 12 n).  Every one packs in CP-SAT in a
# fraction of a second.  (Before the fix, tabu_pack gave up here: when a complete placement
# left an idle arm without a compatible rest, it picked the ejection over *all* idle arms,
# an idle arm with a free rest won with zero blockers, and nothing was ejected.)
EASY_FIELDS = [  # (seed, n targets, sigma_mm or None for uniform, blank_per_arm)
    (0, 24, None, 0), (2, 24, None, 0), (0, 30, 60.0, 0), (2, 30, 60.0, 0), (3, 40, None, 0),
    (0, 20, None, 16), (4, 20, None, 16),
]

def test_finds_the_packings_cp_sat_finds() -> None:
    """Where CP-SAT packs the field into its fewest configurations, the tabu search finds a
    packing into as many too (20,000 iterations; these fields need a few hundred at most)."""
    for seed, n, sigma, blank in EASY_FIELDS:
        x, y, inc = _field(seed, n, sigma, blank)
        pool = _reachable(inc)
        n_configs, packed = _cp_sat_packing(inc, pool)
        _check_packing(inc, x, y, pool, packed, n_configs)  # the oracle itself
        stats: dict = {}
        found = tabu_pack(inc, pool, n_configs, time_limit_s=LONG_S, max_iterations=20_000, stats=stats)
        assert found is not None, (seed, n, sigma, blank, n_configs, stats)
        _check_packing(inc, x, y, pool, found, n_configs)


def test_returns_none_when_no_packing_exists() -> None:
    """More targets than arm slots, no configuration at all, an unreachable target, and a
    crowded field CP-SAT proves cannot fit: None (fast, on iterations)."""
    x, y, inc = _field(1, 36)
    pool = _reachable(inc)
    assert len(pool) > 2 * INS.n_arms
    assert tabu_pack(inc, pool, 2, time_limit_s=LONG_S, max_iterations=2000) is None
    assert tabu_pack(inc, pool, 0, time_limit_s=LONG_S, max_iterations=2000) is None
    assert tabu_pack(inc, pool[:0], 0, time_limit_s=LONG_S, max_iterations=2000) == []
    # a target out of every arm's reach
    xo, yo = np.r_[x[:5], 400.0], np.r_[y[:5], 0.0]
    inc_o = incompatibility_for_targets(INS, xo, yo)
    assert inc_o.reachability.arms_per_target[5] == 0
    assert tabu_pack(inc_o, np.arange(6), 3, time_limit_s=LONG_S, max_iterations=2000) is None
    # 12 targets within 30 mm of the centre: CP-SAT proves one fewer than its packing impossible
    rng = np.random.default_rng(12)
    r, ang = 30.0 * np.sqrt(rng.random(12)), rng.random(12) * 2 * np.pi
    xc, yc = r * np.cos(ang), r * np.sin(ang)
    inc_c = incompatibility_for_targets(INS, xc, yc)
    pool_c = _reachable(inc_c)
    n_opt, _ = _cp_sat_packing(inc_c, pool_c)
    status: dict = {}
    assert pack_targets(inc_c, pool_c, n_opt - 1, time_limit_s=LONG_S, status_out=status, tabu_fraction=0.0) is None
    assert status["infeasible"]
    for weighting in (True, False):
        stats: dict = {}
        assert tabu_pack(inc_c, pool_c, n_opt - 1, time_limit_s=LONG_S, max_iterations=2000,
                         stats=stats, weighting=weighting) is None
        assert stats["iterations"] > 0


def test_valid_hint_is_returned_without_a_move() -> None:
    """A CP-SAT packing given as the hint is complete and valid: tabu_pack returns it before
    its first move (max_iterations=0 allows none), configuration by configuration — also
    shuffled and with an extra all-rest configuration that must be the one left out."""
    for seed, n, sigma in ((0, 24, None), (2, 30, 60.0)):
        x, y, inc = _field(seed, n, sigma)
        a = inc.assignments
        pool = _reachable(inc)
        n_configs, packed = _cp_sat_packing(inc, pool)
        parked = np.array([int(np.flatnonzero(a.target[a.of_arm(k)] < 0)[0]) + int(a.arm_start[k])
                           for k in range(INS.n_arms)])
        assert fcl_configuration_collisions(INS, a.q[parked]) == []
        order = np.random.default_rng(seed).permutation(n_configs + 1)
        extended = [packed[i] if i < n_configs else parked for i in order]
        for hint in (packed, extended):
            stats: dict = {}
            found = tabu_pack(inc, pool, n_configs, time_limit_s=LONG_S, hint=hint, max_iterations=0,
                              stats=stats, seed=seed)
            _check_packing(inc, x, y, pool, found, n_configs)
            assert stats["iterations"] == 0
            assert _target_sets(inc, found) == _target_sets(inc, packed)


def test_same_seed_same_search() -> None:
    """Same input and seed: the same packing and the same search (iterations, fewest
    unplaced), weighted or not; also when the search fails (iteration-limited)."""
    x, y, inc = _field(2, 20, None, 16)
    pool = _reachable(inc)
    for weighting in (True, False):
        runs = []
        for _ in range(2):
            stats: dict = {}
            found = tabu_pack(inc, pool, 2, time_limit_s=LONG_S, max_iterations=20_000, seed=5,
                              stats=stats, weighting=weighting)
            _check_packing(inc, x, y, pool, found, 2)
            runs.append((found, stats))
        (f1, s1), (f2, s2) = runs
        assert s1 == s2
        assert all(np.array_equal(c1, c2) for c1, c2 in zip(f1, f2, strict=True))
    # a failing search (36 targets, perfect packing into 3 not found) retraces itself too
    _, _, inc36 = _field(7, 36)
    pool36 = _reachable(inc36)
    trace = []
    for _ in range(2):
        stats = {}
        out = tabu_pack(inc36, pool36, 3, time_limit_s=LONG_S, max_iterations=3000, seed=1, stats=stats)
        trace.append((None if out is None else _target_sets(inc36, out), stats))
    assert trace[0] == trace[1]


def test_unweighted_variant_packs_validly() -> None:
    """weighting=False (plain PartialCol costs) finds packings too, every one valid."""
    for (seed, n, sigma, blank), n_configs in (((2, 20, None, 16), 2), ((0, 24, None, 16), 3),
                                                ((3, 30, 60.0, 0), 6)):
        x, y, inc = _field(seed, n, sigma, blank)
        pool = _reachable(inc)
        found = tabu_pack(inc, pool, n_configs, time_limit_s=LONG_S, max_iterations=20_000, weighting=False)
        _check_packing(inc, x, y, pool, found, n_configs)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(6, 40), sigma=st.sampled_from([None, 30.0, 60.0]),
       blank=st.sampled_from([0, 16]), extra=st.integers(0, 2), weighting=st.booleans(),
       subset=st.booleans(), search_seed=st.integers(0, 100))
def test_any_returned_packing_is_valid(seed, n, sigma, blank, extra, weighting, subset, search_seed) -> None:
    """Random fields, pools (all reachable targets or a random part), counts and variants:
    the answer is None or a valid packing of exactly the pool."""
    x, y, inc = _field(seed, n, sigma, blank)
    pool = _reachable(inc)
    if subset:
        pool = pool[np.random.default_rng(seed).random(len(pool)) < 0.6]
    n_configs = math.ceil(len(pool) / INS.n_arms) + extra
    found = tabu_pack(inc, pool, n_configs, time_limit_s=LONG_S, max_iterations=2000, seed=search_seed,
                      weighting=weighting)
    if found is not None:
        _check_packing(inc, x, y, pool, found, n_configs)
