"""The two CP-SAT packing models (solvers.packing_cpsat) and the tabu search's partial
packing that seeds the max-cover one.

Oracles: each model against the other (exact cover with symmetry breaking vs. max cover
without: same verdict on every field and count), FCL and the tip check on every returned
configuration (tests.test_packing._check_packing), and the incompatibility structure for
the partial packings.  Time limits are far above what these fields need.
"""

from __future__ import annotations

import math

import numpy as np

from solvers.sequencing import complete_partial
from solvers.sequencing.packing_cpsat import exact_cover, max_cover, packing_columns
from solvers.sequencing.tabu import tabu_pack
from tests.test_packing import EASY_FIELDS, INS, _check_packing, _field, _reachable

LONG_S = 120.0


def _crowded(seed: int, n: int, radius_mm: float):
    rng = np.random.default_rng(seed)
    r, ang = radius_mm * np.sqrt(rng.random(n)), rng.random(n) * 2 * np.pi
    from models.incompatibility import incompatibility_for_targets
    x, y = r * np.cos(ang), r * np.sin(ang)
    return x, y, incompatibility_for_targets(INS, x, y)


def _fewest_configurations(inc, m, pool) -> int:
    """The fewest configurations exact cover packs the pool into, from ⌈t/12⌉ up."""
    n = math.ceil(len(pool) / INS.n_arms)
    while exact_cover(inc, m, pool, n, time_limit_s=LONG_S).packing is None:
        n += 1
    return n


CROWDED = [_crowded(12, 12, 30.0), _crowded(3, 20, 45.0)]
FIELDS = [_field(s, n, sg, b) for s, n, sg, b in EASY_FIELDS[:5]] + CROWDED


def test_max_cover_agrees_with_exact_cover() -> None:
    """On every field: exact cover finds the fewest configurations n (every count below
    refuted), and max cover packs n (checked by FCL and the tips) and refutes n - 1."""
    for x, y, inc in FIELDS:
        pool = _reachable(inc)
        m = packing_columns(inc, pool)
        assert m is not None
        n = math.ceil(len(pool) / INS.n_arms)
        while True:
            out = exact_cover(inc, m, pool, n, time_limit_s=LONG_S)
            if out.packing is not None:
                break
            assert out.infeasible, f"exact cover neither packed nor refuted {n}"
            n += 1
        _check_packing(inc, x, y, pool, out.packing, n)
        found = max_cover(inc, m, pool, n, time_limit_s=LONG_S)
        assert not found.infeasible
        _check_packing(inc, x, y, pool, found.packing, n)
        if n > math.ceil(len(pool) / INS.n_arms):
            # never a packing where exact cover refuted one; the max-cover model is not the
            # one for proofs (a 29-target field into 3: bound 36 after 60 s), but on the
            # crowded fields it proves n - 1 impossible in well under a second
            refuted = max_cover(inc, m, pool, n - 1, time_limit_s=10.0)
            assert refuted.packing is None
            if any(inc is c[2] for c in CROWDED):
                assert refuted.infeasible


def test_max_cover_is_not_fooled_by_a_partial_hint() -> None:
    """Seeded with the tabu search's best partial packing at a count that is impossible,
    max cover still proves it (and at the feasible count completes the packing)."""
    x, y, inc = CROWDED[0]
    pool = _reachable(inc)
    m = packing_columns(inc, pool)
    n = _fewest_configurations(inc, m, pool)
    assert n >= 2, "the crowded field must need more than its count bound"
    partial: list = []
    assert tabu_pack(inc, pool, n - 1, time_limit_s=LONG_S, max_iterations=2000, partial_out=partial) is None
    refuted = max_cover(inc, m, pool, n - 1, time_limit_s=LONG_S, hint=partial)
    assert refuted.packing is None and refuted.infeasible
    # the same partial packing (n - 1 configurations) as a start for n: completed
    found = max_cover(inc, m, pool, n, time_limit_s=LONG_S, hint=partial)
    _check_packing(inc, x, y, pool, found.packing, n)


def test_tabu_partial_packing_is_valid_and_its_best() -> None:
    """The partial packing a failed tabu search hands over: n_configs configurations, at most
    one location per arm in each, pairwise compatible, every pooled target at most once
    across them, and as many unplaced as the search's reported best."""
    for _x, _y, inc in CROWDED:
        pool = _reachable(inc)
        m = packing_columns(inc, pool)
        n = _fewest_configurations(inc, m, pool)
        for n_configs in (n - 1, n - 2):
            stats: dict = {}
            partial: list = []
            assert tabu_pack(inc, pool, n_configs, time_limit_s=LONG_S, max_iterations=3000, stats=stats,
                             partial_out=partial) is None
            assert len(partial) == n_configs
            a = inc.assignments
            seen: list[int] = []
            for locs in partial:
                locs = np.asarray(locs)
                assert (a.target[locs] >= 0).all()
                assert len(set(a.arm[locs].tolist())) == len(locs)
                for i in range(len(locs)):
                    for j in range(i + 1, len(locs)):
                        assert inc.compatible(int(locs[i]), int(locs[j]))
                seen += a.target[locs].tolist()
            assert len(seen) == len(set(seen))
            assert set(seen) <= set(pool.tolist())
            assert len(pool) - len(seen) == stats["best_unplaced"]
            assert len(seen) > 0


def test_max_cover_partial_completes_to_a_packing() -> None:
    """At an impossible count max cover still hands over its best partial packing; with its
    leftover targets in more configurations (solvers.sequencing.complete_partial) that is a
    packing checked by FCL and the tips, and never more configurations than allowed."""
    for x, y, inc in CROWDED:
        pool = _reachable(inc)
        m = packing_columns(inc, pool)
        n = _fewest_configurations(inc, m, pool)
        out = max_cover(inc, m, pool, n - 1, time_limit_s=LONG_S)
        assert out.packing is None and out.partial is not None and len(out.partial) == n - 1
        a = inc.assignments
        observed = np.concatenate([a.target[ch] for ch in out.partial])
        observed = observed[observed >= 0]
        assert len(observed) == len(set(observed.tolist())) < len(pool)
        done = complete_partial(inc, pool, out.partial, n + 1, time_limit_s=LONG_S)
        assert done is not None and len(done) <= n + 1
        _check_packing(inc, x, y, pool, done, len(done))
        # no packing into fewer than the fewest: n - 1 is refuted above, so never returned
        assert complete_partial(inc, pool, out.partial, n - 1, time_limit_s=10.0) is None


def test_a_model_too_large_for_its_limit_is_not_built(monkeypatch) -> None:
    """A packing model whose building would take longer than the attempt's limit is not
    built (no packing, no proof); with the time for it, the same model is built and solved."""
    import time

    import solvers.sequencing.packing_cpsat as pc
    from solvers.effort import CPSAT_LITERAL_S

    x, y, inc = CROWDED[1]
    pool = _reachable(inc)
    m = packing_columns(inc, pool)
    n = _fewest_configurations(inc, m, pool)
    need_s = pc.model_literals(m, n) * CPSAT_LITERAL_S
    assert 0 < need_s < 1.0
    built = []
    real = pc._configurations
    monkeypatch.setattr(pc, "_configurations", lambda *a: built.append(1) or real(*a))
    for cover in (exact_cover, max_cover):
        t0 = time.perf_counter()
        out = cover(inc, m, pool, n, time_limit_s=0.5 * need_s)
        assert (out.packing, out.infeasible, built) == (None, False, [])
        assert time.perf_counter() - t0 < 0.1
        out = cover(inc, m, pool, n, time_limit_s=LONG_S)
        assert out.packing is not None and built
        _check_packing(inc, x, y, pool, out.packing, n)
        built.clear()
