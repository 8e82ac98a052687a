"""The staged exact ILP (solvers.allocation.exact), its clique rows (solvers.allocation.cliques) and the engine
plumbing of allocate (issue 18): engine agreement, valid inequalities, one-mode limits,
every stage on the chosen engine."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import solvers.allocation.cpsat as cpsat_backend
import solvers.allocation.highs as highs_backend
import solvers.model as model
from models.collision import fcl_clearance_mm
from models.incompatibility import incompatibility_for_targets
from models.instrument import default_instrument
from models.types import PlaneTargets
from solvers.allocation import (
    AllocationOptions,
    PackingOptions,
    RepairOptions,
    SequenceOptions,
    allocate,
)
from solvers.allocation.bnb import solve_ilp_bnb
from solvers.allocation.cliques import CliqueOptions, clique_rows, exclusion_matrix
from solvers.allocation.exact import (
    ExactOptions,
    build_exact_model,
    presolve_columns,
    relaxation_bound,
)
from solvers.problem import ConfigProblem, check_solution
from solvers.sequencing import hard_to_place, joint_speeds

INS = default_instrument()
SPEEDS = joint_speeds(INS)
LIMIT_S = 60.0  # generous: only a PROVEN optimum is accepted below, never a timed-out answer


def _field(rng, n: int, sigma_mm: float | None, priorities=(500, 100, 10, 1)) -> tuple[np.ndarray, np.ndarray]:
    if sigma_mm is None:
        r, a = 125 * np.sqrt(rng.random(n)), rng.random(n) * 2 * np.pi
        return r * np.cos(a), r * np.sin(a)
    xy = rng.normal(0, sigma_mm, (4 * n, 2))
    xy = xy[np.hypot(xy[:, 0], xy[:, 1]) <= 125][:n]
    return xy[:, 0], xy[:, 1]


def _problem(inc, x, y, pr, avail, tie=True, q=None):
    xy = np.column_stack([x, y])
    return ConfigProblem(inc, pr, avail, INS.park_configuration.copy() if q is None else q, SPEEDS,
                         time_limit_s=LIMIT_S, target_xy_mm=xy,
                         tie_break=hard_to_place(inc, INS.n_arms, xy, avail) if tie else None)


def _agree(prob) -> None:
    """bnb (as the library runs it), HiGHS and CP-SAT: all prove the same priority and
    yield, and the same longest move wherever two of them proved it."""
    sols = {"bnb": solve_ilp_bnb(prob),
            "highs": highs_backend.solve_ilp_highs(prob), "cpsat": cpsat_backend.solve_ilp_cpsat(prob)}
    for name, s in sols.items():
        assert s.status == "optimal", (name, s.status, s.stats.get("rounds"))
        assert check_solution(INS, prob, s.chosen) == [], name
    assert len({(s.total_priority, s.arm_yield) for s in sols.values()}) == 1, \
        {k: (s.total_priority, s.arm_yield) for k, s in sols.items()}
    moves = [s.longest_move_s for s in sols.values() if s.stats.get("move_optimal")]
    assert len(moves) >= 2 and max(moves) - min(moves) < 1e-6, moves


def test_engines_agree_on_small_random_instances() -> None:
    """40 instances: 12-40 targets, uniform and clustered, random availability."""
    rng = np.random.default_rng(18)
    for i in range(40):
        n = int(rng.integers(12, 40))
        x, y = _field(rng, n, [None, 25.0, 50.0][i % 3])
        pr = rng.choice([500, 100, 10, 1], size=len(x), p=[0.1, 0.4, 0.4, 0.1]).astype(np.int64)
        inc = incompatibility_for_targets(INS, x, y)
        avail = (inc.reachability.arms_per_target > 0) & (rng.random(len(x)) < 0.8)
        _agree(_problem(inc, x, y, pr, avail, tie=bool(i % 2)))


def test_engines_agree_on_dense_instances() -> None:
    """10 dense fields of 800 targets (Gaussian sigma 40 and 60 mm about the centre, and
    uniform; thesis priority mix), the first configuration with the driver's tie-break."""
    for i in range(1, 11):
        rng = np.random.default_rng(800 + i)
        x, y = _field(rng, 800, [40.0, 60.0, None][i % 3])
        assert len(x) == 800
        pr = rng.choice([500, 100, 10, 1], size=800, p=[0.1, 0.4, 0.4, 0.1]).astype(np.int64)
        inc = incompatibility_for_targets(INS, x, y)
        _agree(_problem(inc, x, y, pr, inc.reachability.arms_per_target > 0))


def test_engines_prove_every_tier_without_the_presolve() -> None:
    """With the presolve off (no incumbent, so neither the per-arm bound nor the dive can
    settle a tier) HiGHS and CP-SAT prove every tier themselves, and agree with bnb."""
    rng = np.random.default_rng(21)
    for i in range(8):
        x, y = _field(rng, int(rng.integers(15, 40)), [None, 30.0][i % 2])
        pr = rng.choice([500, 100, 10, 1], size=len(x), p=[0.1, 0.4, 0.4, 0.1]).astype(np.int64)
        inc = incompatibility_for_targets(INS, x, y)
        prob = _problem(inc, x, y, pr, inc.reachability.arms_per_target > 0)
        ref = solve_ilp_bnb(prob)
        for s in (highs_backend.solve_ilp_highs(prob, presolve=False), cpsat_backend.solve_ilp_cpsat(prob, presolve=False)):
            assert s.status == "optimal" and s.stats["move_optimal"], s.stats
            assert "proof" not in s.stats["rounds"][0] and "move_proof" not in s.stats
            assert (s.total_priority, s.arm_yield) == (ref.total_priority, ref.arm_yield)
            if ref.stats.get("move_optimal"):
                assert abs(s.longest_move_s - ref.longest_move_s) < 1e-6


def test_exact_arguments_settle_easy_tiers_and_are_reported() -> None:
    """A sparse field where every arm can take its best target: the dive's incumbent reaches
    the per-arm bound (stage 1 needs no engine) and its completed longest-move search is the
    stage-2 optimum; both are reported, and the answer equals the engine-only one."""
    rng = np.random.default_rng(4)
    x, y = _field(rng, 60, None)
    pr = np.full(len(x), 100, np.int64)
    inc = incompatibility_for_targets(INS, x, y)
    prob = _problem(inc, x, y, pr, inc.reachability.arms_per_target > 0)
    for solve in (highs_backend.solve_ilp_highs, cpsat_backend.solve_ilp_cpsat):
        fast, engine = solve(prob), solve(prob, presolve=False)
        assert fast.stats["rounds"][0] == {"stage": "priority_yield", "proof": "per-arm bound", "solve_s": 0.0}
        assert fast.stats["move_proof"] == "branch-and-bound" and fast.stats["move_optimal"]
        assert fast.status == engine.status == "optimal" and engine.stats["move_optimal"]
        assert (fast.total_priority, fast.arm_yield) == (engine.total_priority, engine.arm_yield)
        assert abs(fast.longest_move_s - engine.longest_move_s) < 1e-6
        assert check_solution(INS, prob, fast.chosen) == []


def test_highs_is_interrupted_at_its_deadline() -> None:
    """HiGHS checks its own time_limit only between phases; the interrupt callbacks stop a
    hard MIP (a 40-row multidimensional knapsack) inside its search at the wall-clock deadline."""
    import time

    import highspy

    rng = np.random.default_rng(0)
    n, m = 300, 40
    a = rng.integers(1, 30, (m, n)).astype(float)
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("time_limit", 1000.0)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = n, m
    lp.col_cost_ = rng.integers(1, 100, n).astype(float)
    lp.col_lower_, lp.col_upper_ = np.zeros(n), np.ones(n)
    lp.row_lower_, lp.row_upper_ = np.full(m, -highspy.kHighsInf), a.sum(axis=1) / 3
    lp.sense_ = highspy.ObjSense.kMaximize
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = np.arange(0, m * n + 1, n).astype(np.int32)
    lp.a_matrix_.index_ = np.tile(np.arange(n), m).astype(np.int32)
    lp.a_matrix_.value_ = a.ravel()
    lp.integrality_ = [highspy.HighsVarType.kInteger] * n
    h.passModel(lp)
    t0 = time.perf_counter()
    fired = highs_backend.interrupt_at(h, t0 + 0.3)
    h.run()
    assert fired == [True] and h.getModelStatus() == highspy.HighsModelStatus.kInterrupt
    assert time.perf_counter() - t0 < 3.0


def _crowded(seed: int, n: int = 7, radius_mm: float = 14.0):
    rng = np.random.default_rng(seed)
    r, t = radius_mm * np.sqrt(rng.random(n)), rng.random(n) * 2 * np.pi
    x, y = r * np.cos(t), r * np.sin(t)
    return x, y, incompatibility_for_targets(INS, x, y)


def _feasible_configurations(inc) -> list[tuple[int, ...]]:
    """Every configuration (one location per arm) that FCL finds collision-free, each
    target at most once: a brute force independent of the incompatibility table."""
    a = inc.assignments
    n = len(a)
    ok = np.ones((n, n), bool)
    for i, j in itertools.combinations(range(n), 2):
        if a.arm[i] == a.arm[j]:
            continue
        same = a.target[i] >= 0 and a.target[i] == a.target[j]
        clear = fcl_clearance_mm(INS, int(a.arm[i]), a.q[i], int(a.arm[j]), a.q[j])
        ok[i, j] = ok[j, i] = not same and clear >= inc.buffer_mm
    out: list[tuple[int, ...]] = []

    def dfs(k: int, pick: list[int]) -> None:
        if k == INS.n_arms:
            out.append(tuple(pick))
            return
        for c in range(a.arm_start[k], a.arm_start[k + 1]):
            if all(ok[c, p] for p in pick):
                dfs(k + 1, [*pick, c])

    dfs(0, [])
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clique_rows_are_valid_inequalities(seed: int) -> None:
    """No FCL-feasible configuration of a small crowded field has two members of a clique
    row; the rows exist (crowded: at most one arm fits); the optimum is the same with and
    without them, and the LP bound never gets looser."""
    x, y, inc = _crowded(seed)
    pr = np.array([500, 100, 100, 10, 10, 1, 1][:len(x)], np.int64)
    prob = _problem(inc, x, y, pr, inc.reachability.arms_per_target > 0, tie=False)
    a = inc.assignments
    cols = np.arange(len(a))
    ex = exclusion_matrix(model.conflict_adjacency(inc), cols, a.arm, a.target)
    indptr, indices = clique_rows(ex, np.column_stack([a.x_mm, a.y_mm]), CliqueOptions(disc_radius_mm=10.0))
    rows = [indices[indptr[i]:indptr[i + 1]] for i in range(len(indptr) - 1)]
    assert rows and max(len(r) for r in rows) >= 6
    feasible = _feasible_configurations(inc)
    assert len(feasible) > INS.n_arms
    for conf in feasible:
        s = set(conf)
        for r in rows:
            assert sum(int(c) in s for c in r) <= 1, (conf, r.tolist())
    on = highs_backend.solve_ilp_highs(prob, cliques=True)
    off = highs_backend.solve_ilp_highs(prob, cliques=False, presolve=False)
    brute = max(sum(int(pr[t]) for t in a.target[list(c)] if t >= 0) for c in feasible)
    assert on.status == off.status == "optimal"
    assert on.total_priority == off.total_priority == brute
    allowed = prob.allowed()
    lp_on = relaxation_bound(prob, build_exact_model(prob, allowed, ExactOptions(cliques=True))[0])
    lp_off = relaxation_bound(prob, build_exact_model(prob, allowed, ExactOptions(cliques=False))[0])
    opt = on.total_priority * (INS.n_arms + 1) + on.arm_yield
    assert opt - 1e-6 <= lp_on <= lp_off + 1e-6


def test_presolve_keeps_every_optimal_solution() -> None:
    """The pruned columns contain every optimum the brute force finds (column fixing is
    exact), and the incumbent is a feasible configuration."""
    x, y, inc = _crowded(5, n=6, radius_mm=20.0)
    pr = np.array([500, 500, 100, 10, 10, 1], np.int64)
    prob = _problem(inc, x, y, pr, inc.reachability.arms_per_target > 0, tie=False)
    a = inc.assignments
    cols, incumbent, _ = presolve_columns(prob, None, 300, float("inf"))
    assert check_solution(INS, prob, incumbent) == []
    feasible = _feasible_configurations(inc)
    w = model.coarse_weights(prob, np.arange(len(a)))
    best = max(int(w[list(c)].sum()) for c in feasible)
    optima = [c for c in feasible if int(w[list(c)].sum()) == best]
    assert optima and all(cols[list(c)].all() for c in optima)


def test_one_mode_gives_the_engine_the_request_limit(monkeypatch) -> None:
    """configurations="one": a 30 s request hands the engine (nearly) 30 s, not a share."""
    seen: list[float] = []
    real = highs_backend.solve_ilp_highs

    def spy(problem, **kw):
        seen.append(problem.time_limit_s)
        return real(problem, **kw)

    monkeypatch.setattr(highs_backend, "solve_ilp_highs", spy)
    rng = np.random.default_rng(3)
    x, y = _field(rng, 40, 40.0)  # HiGHS is called, and done in well under a second
    pr = rng.choice([500, 100, 10, 1], size=len(x), p=[0.1, 0.4, 0.4, 0.1]).astype(np.int64)
    t = PlaneTargets.from_lists([f"t{i}" for i in range(len(x))], x, y, pr)
    r = allocate(INS, t, solver="highs", configurations="one", time_limit_s=30.0)
    assert len(r.configurations) == 1 and seen
    assert seen[0] >= 29.0, seen
    seen.clear()
    allocate(INS, t, solver="highs", configurations="all", time_limit_s=30.0,
             options=AllocationOptions(sequence=SequenceOptions(max_configurations=2),
                                       packing=PackingOptions(enabled=False)))
    assert seen and max(seen) <= 5.0 + 1e-9  # sequences keep the per-configuration cap and share


def test_rescue_on_a_highs_request_uses_highs(monkeypatch) -> None:
    """Targets on the ring of park tips need the rescue; on a HiGHS request it runs on
    HiGHS (CP-SAT's single-configuration solve is never called) and the response says which
    engine did which part."""
    calls = {"highs": 0}
    real = highs_backend.solve_ilp_highs

    def spy(problem, **kw):
        calls["highs"] += 1
        return real(problem, **kw)

    def no_cpsat(*_a, **_k):
        raise AssertionError("solve_ilp_cpsat called on a highs request")

    monkeypatch.setattr(highs_backend, "solve_ilp_highs", spy)
    monkeypatch.setattr(cpsat_backend, "solve_ilp_cpsat", no_cpsat)
    rng = np.random.default_rng(0)
    n = 40
    r, a = 118 + 8 * rng.random(n), rng.random(n) * 2 * np.pi
    t = PlaneTargets.from_lists([f"t{i}" for i in range(n)], r * np.cos(a), r * np.sin(a), np.ones(n, np.int64))
    res = allocate(INS, t, solver="highs", configurations="all", time_limit_s=120.0,
                   options=AllocationOptions(repair=RepairOptions(enabled=False),
                                             packing=PackingOptions(enabled=False)))
    assert res.stats["n_allocated"] == res.stats["n_reachable"]
    assert res.stats["engines"]["rescue"] == "highs" and res.stats["engines"]["configurations"] == "highs"
    assert any(c.stats.get("rescue") for c in res.configurations)
    assert calls["highs"] >= len(res.configurations)


def _tiered_cluster(seed: int, n: int = 40, sigma_mm: float = 20.0):
    rng = np.random.default_rng(seed)
    x, y = _field(rng, n, sigma_mm)
    pr = rng.choice([500, 100, 10, 1], size=len(x), p=[0.1, 0.4, 0.4, 0.1]).astype(np.int64)
    inc = incompatibility_for_targets(INS, x, y)
    return _problem(inc, x, y, pr, inc.reachability.arms_per_target > 0)


def test_a_completed_dive_settles_stage_one_and_is_reported() -> None:
    """On crowded fields where collisions, not the per-arm bound, decide the optimum, a dive
    that completes within its node budget proves stage 1 (reported as "branch-and-bound");
    its answer is the one the engine proves alone (presolve off)."""
    seen = 0
    for seed in range(10):
        prob = _tiered_cluster(seed, n=20)
        for solve in (highs_backend.solve_ilp_highs, cpsat_backend.solve_ilp_cpsat):
            fast = solve(prob)
            if fast.stats["rounds"][0].get("proof") != "branch-and-bound":
                continue
            seen += 1
            engine = solve(prob, presolve=False)
            assert fast.status == engine.status == "optimal"
            assert (fast.total_priority, fast.arm_yield) == (engine.total_priority, engine.arm_yield)
            assert check_solution(INS, prob, fast.chosen) == []
    assert seen >= 4


def test_too_little_time_keeps_the_incumbent_without_a_model(monkeypatch: pytest.MonkeyPatch) -> None:
    """With less time left than ``min_engine_s`` and an incumbent neither the per-arm bound
    nor a completed dive proves, no model is built: the incumbent comes back ``feasible``
    with a gap that bounds the proven optimum."""
    from solvers.allocation import exact

    def no_model(*a, **k):
        raise AssertionError("a model was built")

    checked = 0
    for seed in range(12):
        prob = _tiered_cluster(seed)
        optimum = solve_ilp_bnb(prob, node_limit=10**7, fallback=None)
        assert optimum.status == "optimal"
        with monkeypatch.context() as m:
            m.setattr(exact, "build_exact_model", no_model)
            m.setattr(exact, "build_model_arrays", no_model)
            s = exact.solve_staged(prob, highs_backend.highs_stage_solver(prob, "highspy", "auto"), backend="highs",
                                   options=ExactOptions(incumbent_nodes=50, min_engine_s=2 * LIMIT_S))
        if s.stats["rounds"][0].get("proof") is not None:  # settled by the per-arm bound or the dive
            continue
        checked += 1
        assert s.status == "feasible" and s.stats["model"].startswith("none")
        assert s.stats["rounds"] == [{"stage": "priority_yield", "proof": None, "solve_s": 0.0}]
        assert check_solution(INS, prob, s.chosen) == []
        inc_c = sum(int(v) for v in model.coarse_weights(prob, s.chosen))
        opt_c = sum(int(v) for v in model.coarse_weights(prob, optimum.chosen))
        assert inc_c <= opt_c <= inc_c * (1 + s.gap) + 1e-9
    assert checked >= 4
