"""Locks and exclusions, honoured by every allocation engine (issue 39 item 3): random
single-pointing programmes (6-30 targets, the thesis priority mix) with random valid locks and
exclusions, 20 for each of highs, cpsat, bnb and the semi-greedy method (80 distinct programmes:
each engine has its own seeds), through ``solvers.allocation.allocate`` to completeness (its
post-passes included).

Oracles independent of the allocator: which (arm, branch) reaches a target within the park
move limit comes from ``models.kinematics`` directly (IK and the positive-turn move time), the
branch of an observed target from matching its joint angles against the IK solutions, and the
configurations' freedom from collisions from FCL's clearances."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from models import clock
from models.collision import fcl_clearance_mm
from models.instrument import CONFIGURATION_TIME_GOAL_S, default_instrument
from models.kinematics import inverse_fov, positive_turn_move_time_s
from models.locks import TargetLock
from models.types import AllocationResult, PlaneTargets
from solvers.allocation import allocate
from solvers.allocation.options import AllocationOptions, PackingOptions
from solvers.sequencing.options import SequenceOptions

INST = default_instrument()
N_FIELDS = 20  # per engine
LIMIT_S = CONFIGURATION_TIME_GOAL_S  # the plan's park move limit
NEAR_MM = 1e-3  # clearances this close to the buffer are left to either model's rounding
ENGINES = [("ilp", "highs"), ("ilp", "cpsat"), ("ilp", "bnb"), ("semigreedy", "bnb")]
# repacking off here, to keep 80 sequences within the test's time (tests/test_locks.py runs the
# post-passes, repacking included, on locked fields); the rescue and the repair stay on
OPTIONS = AllocationOptions(sequence=SequenceOptions(park_move_limit_s=LIMIT_S),
                            packing=PackingOptions(enabled=False))


def reach(x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
    """(n_arms, n_targets, 4): which IK branch of which arm reaches each target within the
    park move limit (the oracle of a valid lock)."""
    arms = np.arange(INST.n_arms)
    ik = inverse_fov(INST, arms[:, None], x_mm[None, :], y_mm[None, :])
    park = INST.park_configuration[arms][:, None, None, :]
    q = np.stack([ik.theta1_rad, ik.theta2_rad], axis=-1)
    v1 = INST.arm_array("joint1_speed_rad_s")[:, None, None]
    v2 = INST.arm_array("joint2_speed_rad_s")[:, None, None]
    t_s = positive_turn_move_time_s(park, q, v1, v2)
    return ik.valid & (t_s <= LIMIT_S)


def field(seed: int) -> tuple[PlaneTargets, list[TargetLock], list[str], np.ndarray]:
    """A random programme, random valid locks (0-4) and exclusions (0-3), and its reach."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(6, 31))
    r = 120.0 * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    x, y = r * np.cos(a), r * np.sin(a)
    pr = rng.choice([500, 100, 10, 1], n, p=[0.1, 0.4, 0.4, 0.1])
    targets = PlaneTargets.from_lists([f"t{i}" for i in range(n)], x, y, pr)
    ok = reach(x, y)
    candidates = [i for i in range(n) if ok[:, i, :].any()]
    chosen = rng.permutation(candidates)[:int(rng.integers(0, 5))]
    locks = []
    for i in chosen:
        arm, branch = ok[:, i, :].nonzero()
        j = int(rng.integers(len(arm)))
        locks.append(TargetLock(f"t{i}", int(arm[j]), int(branch[j]) if rng.uniform() < 0.5 else None))
    rest = [i for i in range(n) if f"t{i}" not in {lk.target_id for lk in locks}]
    excluded = [f"t{i}" for i in rng.permutation(rest)[:int(rng.integers(0, 4))]]
    return targets, locks, excluded, ok


def branch_of(arm: int, x_mm: float, y_mm: float, q: tuple[float, float]) -> int | None:
    ik = inverse_fov(INST, arm, np.array([x_mm]), np.array([y_mm]))
    d1 = np.abs(ik.theta1_rad[0] - q[0])
    d2 = np.abs((ik.theta2_rad[0] - q[1] + np.pi) % (2 * np.pi) - np.pi)
    hit = np.flatnonzero(ik.valid[0] & (d1 < 1e-6) & (d2 < 1e-6))
    return int(hit[0]) if len(hit) else None


def check(r: AllocationResult, targets: PlaneTargets, locks: list[TargetLock], excluded: list[str]) -> None:
    seen: dict[str, list[tuple[int, int | None]]] = {}
    for c in r.configurations:
        for a in c.assignments:
            if a.target_id is not None:
                i = targets.ids.index(a.target_id)
                assert np.hypot(a.x_mm - targets.x_mm[i], a.y_mm - targets.y_mm[i]) < 0.01
                seen.setdefault(a.target_id, []).append(
                    (a.arm, branch_of(a.arm, a.x_mm, a.y_mm, (a.theta1_rad, a.theta2_rad))))
        for (ka, qa), (kb, qb) in itertools.combinations(
                [(a.arm, (a.theta1_rad, a.theta2_rad)) for a in c.assignments], 2):
            assert fcl_clearance_mm(INST, ka, qa, kb, qb) >= INST.collision_buffer_mm - NEAR_MM, (c.index, ka, kb)
    assert all(len(v) == 1 for v in seen.values()), seen
    reasons = {u.target_id: u.reason for u in r.unallocated}
    for t in excluded:
        assert t not in seen and reasons[t] == "excluded"
    for lk in locks:
        if lk.target_id in seen:
            arm, branch = seen[lk.target_id][0]
            assert arm == lk.arm, (lk, seen[lk.target_id])
            assert lk.branch is None or branch == lk.branch, (lk, seen[lk.target_id])
        else:
            # reachable alone by construction: only the time may leave it out, and it says so
            assert reasons[lk.target_id] == "locked_no_time", (lk, reasons[lk.target_id], r.stats["stop_reason"])


@pytest.mark.parametrize("method,solver", ENGINES)
def test_every_engine_honours_random_locks_and_exclusions(method: str, solver: str) -> None:
    n_locks = n_observed = 0
    first = ENGINES.index((method, solver)) * N_FIELDS
    for seed in range(first, first + N_FIELDS):
        targets, locks, excluded, _ = field(seed)
        with clock.effort(wall_limit_s=60.0):  # budgets in work: the same answer under any load
            r = allocate(INST, targets, method=method, solver=solver, configurations="all", time_limit_s=3.0,
                         seed=seed, options=OPTIONS, locked=locks, excluded_targets=excluded)
        check(r, targets, locks, excluded)
        observed = {a.target_id for c in r.configurations for a in c.assignments}
        n_locks += len(locks)
        n_observed += sum(lk.target_id in observed for lk in locks)
    assert n_locks >= N_FIELDS  # the fields hold enough locks to mean something (31-39 here)
    assert n_observed == n_locks  # 3 effort seconds are plenty for these small fields


def test_the_fields_lock_targets_other_arms_would_take() -> None:
    """The property above is not vacuous: without the locks, the allocator puts some locked
    targets on another arm or branch (so the structure, not chance, keeps them there)."""
    moved = 0
    for seed in range(10):
        targets, locks, _, _ = field(seed)
        r = allocate(INST, targets, method="ilp", solver="bnb", configurations="all", time_limit_s=3.0,
                     seed=seed, options=OPTIONS)
        where = {a.target_id: (a.arm, branch_of(a.arm, a.x_mm, a.y_mm, (a.theta1_rad, a.theta2_rad)))
                 for c in r.configurations for a in c.assignments if a.target_id}
        moved += sum(lk.target_id in where and (where[lk.target_id][0] != lk.arm or (
            lk.branch is not None and where[lk.target_id][1] != lk.branch)) for lk in locks)
    assert moved >= 3
