"""Exact single-configuration allocator (thesis 5.4): oracles, cross-checks, edge cases."""

from __future__ import annotations

import numpy as np
import pytest

from models.collision import arm_pair_clearance_mm, fcl_configuration_collisions
from models.incompatibility import build_assignments, incompatibility_for_targets
from models.instrument import default_instrument
from models.kinematics import tip_fov
from solvers.allocation.cpsat import solve_ilp_cpsat
from solvers.allocation.highs import solve_ilp_highs
from solvers.model import build_model_arrays, safe_weights
from solvers.problem import ConfigProblem, check_solution
from solvers.sequencing import joint_speeds

INS = default_instrument()


def _field(rng, n, radius=125.0):
    r = radius * np.sqrt(rng.random(n))
    a = rng.random(n) * 2 * np.pi
    return r * np.cos(a), r * np.sin(a)


def _problem(x, y, pr, **kw):
    """A problem with a generous time limit: CI machines are loaded, and every assertion
    below is about *proven* optima, never about speed (limits are node counts or
    far above what a small instance needs)."""
    kw.setdefault("time_limit_s", 120.0)
    inc = incompatibility_for_targets(INS, x, y, fixed=kw.pop("fixed", None))
    return ConfigProblem(inc, np.asarray(pr, np.int64), np.ones(len(x), bool), INS.park_configuration,
                         joint_speeds(INS), target_xy_mm=np.column_stack([x, y]), **kw)


def _oracle(x, y, pr) -> int:
    """Brute force by backtracking over arms, with conflicts recomputed from geometry
    (capsule clearances), independent of the incompatibility table."""
    reach = build_assignments(INS, x, y)
    a = reach.assignments
    n = len(a)
    clear = arm_pair_clearance_mm(INS, a.arm[:, None], a.q[:, None, :], a.arm[None, :], a.q[None, :, :])
    ok = clear >= INS.collision_buffer_mm
    same = (a.target[:, None] == a.target[None, :]) & (a.target[:, None] >= 0)
    ok &= ~same
    val = np.where(a.target >= 0, np.asarray(pr)[np.maximum(a.target, 0)], 0)
    best = [-1]
    per_arm = [list(range(a.arm_start[k], a.arm_start[k + 1])) for k in range(INS.n_arms)]
    rest_max = [sum(max(int(val[j]) for j in per_arm[kk]) for kk in range(k, INS.n_arms)) for k in range(INS.n_arms)]
    rest_max.append(0)

    def dfs(k, chosen, total):
        if total + rest_max[k] <= best[0]:
            return
        if k == INS.n_arms:
            best[0] = total
            return
        for j in sorted(per_arm[k], key=lambda j: -val[j]):
            if all(ok[j, c] for c in chosen):
                dfs(k + 1, chosen + [j], total + int(val[j]))
    del n
    dfs(0, [], 0)
    return best[0]


@pytest.mark.parametrize("seed", range(6))
def test_matches_brute_force_oracle(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 6 + seed % 3
    x, y = _field(rng, n, radius=60.0)  # crowded: conflicts matter
    pr = rng.choice([500, 100, 10, 1], size=n)
    p = _problem(x, y, pr)
    expected = _oracle(x, y, pr)
    for sol in (solve_ilp_highs(p), solve_ilp_cpsat(p)):
        assert sol.status == "optimal"
        assert sol.total_priority == expected
        assert check_solution(INS, p, sol.chosen) == []


def test_highs_and_cpsat_agree_on_50_instances() -> None:
    rng = np.random.default_rng(42)
    for _ in range(50):
        n = int(rng.integers(3, 25))
        x, y = _field(rng, n, radius=float(rng.choice([50.0, 125.0])))
        pr = rng.choice([500, 100, 10, 1], size=n)
        p = _problem(x, y, pr)
        h = solve_ilp_highs(p, minimize_move=False, candidates_per_arm=None)
        c = solve_ilp_cpsat(p, minimize_move=False)
        assert h.status == c.status == "optimal"
        assert (h.total_priority, h.arm_yield) == (c.total_priority, c.arm_yield)


def test_aggregated_and_pairwise_same_optimum_and_lazy_equals_full() -> None:
    rng = np.random.default_rng(5)
    for _ in range(6):
        n = int(rng.integers(10, 40))
        x, y = _field(rng, n, radius=80.0)
        pr = rng.choice([500, 100, 10, 1], size=n)
        p = _problem(x, y, pr)
        ref = solve_ilp_cpsat(p, form="pairwise", minimize_move=False, candidates_per_arm=None)
        for sol in (solve_ilp_cpsat(p, form="aggregated", minimize_move=False),
                    solve_ilp_highs(p, form="pairwise", minimize_move=False),
                    solve_ilp_highs(p, form="aggregated", minimize_move=False, candidates_per_arm=None)):
            assert (sol.total_priority, sol.arm_yield) == (ref.total_priority, ref.arm_yield)


def test_aggregated_rows_are_valid_cliques() -> None:
    """Every aggregated row: one assignment plus conflicting assignments of ONE other arm."""
    rng = np.random.default_rng(1)
    x, y = _field(rng, 40)
    p = _problem(x, y, np.ones(40, np.int64))
    m = build_model_arrays(p, "aggregated")
    inc = p.incompatibility
    for i in range(m.n_target_rows, len(m.le_indptr) - 1):
        cols = m.le_indices[m.le_indptr[i]:m.le_indptr[i + 1]]
        head, rest = m.var[cols[0]], m.var[cols[1:]]
        assert len(set(inc.assignments.arm[rest])) == 1
        assert all(not inc.compatible(int(head), int(b)) for b in rest)


def test_solutions_collision_free_by_fcl_and_tips_on_target() -> None:
    rng = np.random.default_rng(9)
    x, y = _field(rng, 60)
    pr = rng.choice([500, 100, 10, 1], size=60)
    p = _problem(x, y, pr)
    for sol in (solve_ilp_highs(p), solve_ilp_cpsat(p)):
        a = p.assignments
        q = a.q[sol.chosen]
        assert fcl_configuration_collisions(INS, q) == []
        tips = tip_fov(INS, np.arange(INS.n_arms), q[:, 0], q[:, 1])
        t = a.target[sol.chosen]
        on = t >= 0
        assert np.hypot(tips[on, 0] - x[t[on]], tips[on, 1] - y[t[on]]).max() < 0.01


def test_disabled_arms_stay_fixed() -> None:
    rng = np.random.default_rng(3)
    x, y = _field(rng, 40)
    fixed = {2: (np.pi, 0.0), 7: (np.pi * 0.9, 0.3)}
    p = _problem(x, y, np.full(40, 100), fixed=fixed)
    for sol in (solve_ilp_highs(p), solve_ilp_cpsat(p)):
        a = p.assignments
        for k, q in fixed.items():
            c = sol.chosen[k]
            assert a.target[c] == -2 and np.allclose(a.q[c], q)
        assert check_solution(INS, p, sol.chosen) == []


def test_nothing_reachable_parks_everything() -> None:
    x, y = np.array([400.0, -500.0]), np.array([0.0, 10.0])
    p = _problem(x, y, [5, 7])
    for sol in (solve_ilp_highs(p), solve_ilp_cpsat(p)):
        assert sol.status == "optimal"
        assert (p.assignments.target[sol.chosen] == -1).all()
        assert sol.total_priority == 0


def test_huge_priorities_keep_their_order() -> None:
    top = 2**32 - 1
    # two targets only one arm can take at once (same spot): the larger priority must win
    x, y = np.array([0.0, 0.001, 60.0]), np.array([0.0, 0.0, 0.0])
    for pr, want in (([top, top - 1, 1], top), ([top - 1, top, 1], top)):
        p = _problem(x, y, pr)
        for sol in (solve_ilp_highs(p), solve_ilp_cpsat(p)):
            t = set(p.assignments.target[sol.chosen].tolist())
            assert sol.total_priority == want + 1 or sol.total_priority == want
            assert (0 in t) == (pr[0] == top) and (1 in t) == (pr[1] == top)
    w, ym, tm = safe_weights(_problem(x, y, [top, top, top]), np.arange(3))
    assert INS.n_arms * int(w.max()) < 2**53


def test_sum_of_small_priorities_vs_one_big() -> None:
    """2^32-1 alone vs (2^32-2) + 1: exact arithmetic decides (they tie; yield breaks it)."""
    top = 2**32 - 1
    x, y = _field(np.random.default_rng(0), 3, radius=20.0)
    p = _problem(x, y, [top, top - 1, 1])
    h, c = solve_ilp_highs(p), solve_ilp_cpsat(p)
    assert h.total_priority == c.total_priority
    assert h.arm_yield == c.arm_yield


def test_pyomo_interface_same_optimum() -> None:
    rng = np.random.default_rng(11)
    x, y = _field(rng, 12)
    pr = rng.choice([500, 100, 10, 1], size=12)
    p = _problem(x, y, pr)
    a = solve_ilp_highs(p, interface="pyomo")
    b = solve_ilp_highs(p)
    assert a.status == "optimal" and (a.total_priority, a.arm_yield) == (b.total_priority, b.arm_yield)
    assert a.longest_move_s == pytest.approx(b.longest_move_s, abs=1e-6)


def test_longest_move_is_minimised_among_optima() -> None:
    rng = np.random.default_rng(4)
    x, y = _field(rng, 30)
    p = _problem(x, y, np.ones(30, np.int64))
    a = solve_ilp_cpsat(p, candidates_per_arm=None)
    b = solve_ilp_cpsat(p, minimize_move=False, candidates_per_arm=None)
    c = solve_ilp_highs(p, candidates_per_arm=None)
    assert (a.total_priority, a.arm_yield) == (b.total_priority, b.arm_yield)
    assert a.longest_move_s <= b.longest_move_s + 1e-6
    assert c.longest_move_s == pytest.approx(a.longest_move_s, abs=1e-5)
