"""Same seed, same plan, whatever the machine's load: the allocator on the effort clock.

Each engine runs a sequence whose time budget binds (the call stops with ``no_time``) twice
inside :func:`models.clock.effort`: on the machine as it is, and on a machine made slower
(a process spinning on a core, sleeps in hot functions of the allocator, a stall).
Both answers must be identical.  The same slow-down on the wall clock changes the answer,
so the comparison is not vacuous.  The wall-clock guard still stops a call in real time.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

import solvers.allocation.bitset as bitset
import solvers.allocation.bnb as bnb
import solvers.allocation.exact as exact
import solvers.allocation.semigreedy.solve as semigreedy_solve
import solvers.sequencing.state as sequencing_state
from models import clock
from models.instrument import default_instrument
from models.types import AllocationResult, PlaneTargets
from solvers.allocation import allocate

INS = default_instrument()
# on the slowed machine: sleeps in each configuration's geometric check, column pruning
# and semi-greedy construction
SLOW_CHECK_S, SLOW_PRUNE_S, SLOW_CONSTRUCT_S = 0.03, 0.01, 0.005

# engine: (method, solver, targets, Gaussian sigma in mm, time limit in s)
CASES = {
    "bnb": ("ilp", "bnb", 300, 40.0, 1.0),
    "highs": ("ilp", "highs", 200, 60.0, 0.5),
    "cpsat": ("ilp", "cpsat", 200, 60.0, 0.5),
    "semigreedy": ("semigreedy", "bnb", 300, 40.0, 0.75),
}


def thesis_field(n: int, sigma_mm: float, seed: int = 7) -> PlaneTargets:
    """``n`` targets, Gaussian about the FOV centre (clipped to it), priorities 10 % 500,
    40 % 100, 40 % 10, 10 % 1."""
    rng = np.random.default_rng(seed)
    pts = np.zeros((0, 2))
    while len(pts) < n:
        p = rng.normal(0.0, sigma_mm, (2 * n, 2))
        pts = np.vstack([pts, p[np.hypot(p[:, 0], p[:, 1]) <= 125.0]])
    pr = rng.choice([500, 100, 10, 1], size=n, p=[0.1, 0.4, 0.4, 0.1]).astype(np.int64)
    return PlaneTargets.from_lists([f"t{i}" for i in range(n)], pts[:n, 0], pts[:n, 1], pr)


@contextmanager
def slowed(monkeypatch: pytest.MonkeyPatch, stall_s: float = 0.0) -> Iterator[None]:
    """A slower, busier machine: a process spinning on a core, sleeps in hot functions of
    the allocator (each configuration's geometric check, each column pruning of the exact
    engines, each semi-greedy construction), and a stall of ``stall_s`` at the first
    geometric check (as a machine that swaps)."""
    def sleepy(fn, delay_s: float, first_s: float = 0.0):
        calls = [0]

        def slow(*args, **kwargs):
            time.sleep(first_s if not calls[0] and first_s else delay_s)
            calls[0] += 1
            return fn(*args, **kwargs)
        return slow

    check = sleepy(sequencing_state.check_solution, SLOW_CHECK_S, stall_s)
    monkeypatch.setattr(sequencing_state, "check_solution", check)
    for module in (bitset, exact, bnb):
        monkeypatch.setattr(module, "prune_columns", sleepy(bitset.prune_columns, SLOW_PRUNE_S))
    monkeypatch.setattr(semigreedy_solve, "construct", sleepy(semigreedy_solve.construct, SLOW_CONSTRUCT_S))
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()
        monkeypatch.undo()


def signature(r: AllocationResult) -> tuple:
    """Everything of a result that does not hold a wall time: the configurations (every
    arm's location bit for bit), the unallocated targets and the sequence's statistics."""
    confs = tuple((c.index, c.total_priority, c.arm_yield, c.status,
                   tuple((a.arm, a.kind, a.theta1_rad, a.theta2_rad, a.target_index) for a in c.assignments))
                  for c in r.configurations)
    unalloc = tuple((u.target_index, u.reason) for u in r.unallocated)
    s = r.stats
    per = tuple((p["total_priority"], p["arm_yield"], p["status"]) for p in s.get("per_configuration", ()))
    return confs, unalloc, s["stop_reason"], s["n_configurations"], s["n_allocated"], per


def run(engine: str, effort: bool) -> tuple[AllocationResult, clock.EffortClock | None]:
    method, solver, n, sigma_mm, limit_s = CASES[engine]
    targets = thesis_field(n, sigma_mm)
    kw = dict(method=method, solver=solver, configurations="all", time_limit_s=limit_s, seed=3)
    if not effort:
        return allocate(INS, targets, **kw), None
    with clock.effort(wall_limit_s=60.0) as c:
        return allocate(INS, targets, **kw), c


@pytest.mark.parametrize("engine", list(CASES))
def test_same_plan_whatever_the_load(engine: str, monkeypatch: pytest.MonkeyPatch) -> None:
    stall_s = CASES[engine][-1]  # the whole limit, at the first configuration's check
    normal, c1 = run(engine, effort=True)
    with slowed(monkeypatch, stall_s):
        slow, c2 = run(engine, effort=True)
    with slowed(monkeypatch, stall_s):
        wall_slow, _ = run(engine, effort=False)
    # the budget binds: the sequence stopped for lack of time, on both machines
    assert normal.stats["stop_reason"] == "no_time"
    # ... and so do the engines' own limits: some configuration was left unproven
    assert "feasible" in [p["status"] for p in normal.stats["per_configuration"]]
    assert not c1.overran and not c2.overran
    assert signature(slow) == signature(normal)
    assert c2.t_s == pytest.approx(c1.t_s, rel=0, abs=1e-9)
    # on the wall clock the same slow-down changes the answer (the stall alone takes the whole
    # limit, leaving time for one configuration at most); the effort clock's answer has more
    # (a wall-clock run on the machine as it is would depend on what else runs on it)
    assert wall_slow.stats["n_configurations"] <= 1 < normal.stats["n_configurations"]
    assert signature(wall_slow) != signature(normal)


def test_the_wall_guard_still_stops_the_call(monkeypatch: pytest.MonkeyPatch) -> None:
    targets = thesis_field(300, 40.0)
    with slowed(monkeypatch):
        t0 = time.perf_counter()
        with clock.effort(wall_limit_s=0.5) as c:
            r = allocate(INS, targets, configurations="all", time_limit_s=60.0, seed=3)
        wall_s = time.perf_counter() - t0
    assert c.overran
    assert wall_s < 5.0
    assert r.stats["stop_reason"] == "no_time"


def test_position_angles_run_on_effort_clocks_of_their_own(monkeypatch: pytest.MonkeyPatch) -> None:
    """The rotations of the position-angle search run in threads: each on an effort clock of
    its own, whose work is charged to the caller's clock."""
    targets = thesis_field(300, 40.0)
    kw = dict(configurations="all", time_limit_s=0.8, seed=3, position_angles_deg=(0.0, 45.0))
    with clock.effort(wall_limit_s=60.0) as c1:
        normal = allocate(INS, targets, **kw)
    with slowed(monkeypatch), clock.effort(wall_limit_s=60.0) as c2:
        slow = allocate(INS, targets, **kw)
    assert normal.stats["stop_reason"] == "no_time"
    assert signature(slow) == signature(normal)
    assert slow.stats["position_angle_search"] == normal.stats["position_angle_search"]
    assert c1.t_s == c2.t_s and c1.t_s > 2 * 0.8 * 0.9  # both rotations' work charged


def test_engine_table_caches_belong_to_their_thread() -> None:
    """Rotations run in threads: a table one builds is not found (or evicted) by another, so
    a rotation's work does not depend on how the threads interleave."""
    import threading

    from solvers.thread_cache import thread_cache

    mine = thread_cache("bitset.fields")
    mine["k"] = 1
    seen = {}
    t = threading.Thread(target=lambda: seen.update(other=thread_cache("bitset.fields")))
    t.start()
    t.join()
    assert seen["other"] == {} and seen["other"] is not mine
    assert thread_cache("bitset.fields") is mine and mine.pop("k") == 1
