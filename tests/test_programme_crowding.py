"""Crowding in the programme's bound (solvers.programme.crowding, solvers.programme.bound).

Oracles:

* FCL: every pair of arms that reaches two targets closer than the exclusion distance
  (every IK branch of each) collides there, at random places and directions in the FOV;
  just beyond it, some pair of arms observes both;
* pairwise distances: every cell is a clique of the "closer than d_min" graph;
* a brute-force cover: the fewest sets of at most 12 targets, pairwise at least d_min apart,
  each inside one disc of radius R, that cover a small programme; the bound never exceeds it;
* the allocator: every configuration it builds on a crowded field (FCL-checked by its own
  tests) keeps its targets at least d_min apart, and its exposures are at least the bound.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from models.collision import fcl_clearance_mm
from models.instrument import default_instrument
from models.kinematics import inverse_fov
from models.types import PlaneTargets
from solvers.allocation import allocate
from solvers.programme.bound import lower_bound
from solvers.programme.crowding import crowding_cells, exclusion_distance_mm

INST = default_instrument()
D_MIN = exclusion_distance_mm(INST)
R_MM = INST.fov_radius_mm


def _solutions(arm: int, x_mm: float, y_mm: float) -> list[tuple[float, float]]:
    ik = inverse_fov(INST, arm, np.array([x_mm]), np.array([y_mm]))
    return [(float(ik.theta1_rad[0, b]), float(ik.theta2_rad[0, b])) for b in range(4) if ik.valid[0, b]]


def _min_clearance(p: tuple[float, float], q: tuple[float, float]) -> float | None:
    """The largest FCL clearance of any two distinct arms with their tips on p and q (None:
    no two arms reach them)."""
    best = None
    for a, b in itertools.permutations(range(INST.n_arms), 2):
        for qa in _solutions(a, *p):
            for qb in _solutions(b, *q):
                c = fcl_clearance_mm(INST, a, qa, b, qb)
                best = c if best is None else max(best, c)
    return best


def test_the_exclusion_distance_is_the_tip_bodies_and_the_buffer() -> None:
    assert D_MIN == pytest.approx(10.0 + 10.0 + INST.collision_buffer_mm, rel=1e-3)


@pytest.mark.parametrize("seed", range(3))
def test_no_two_arms_observe_targets_closer_than_the_exclusion_distance(seed: int) -> None:
    rng = np.random.default_rng(seed)
    checked = 0
    while checked < 4:
        r = R_MM * 0.8 * np.sqrt(rng.random())
        a = rng.random() * 2 * np.pi
        p = (r * np.cos(a), r * np.sin(a))
        d = D_MIN * (0.97 + 0.03 * rng.random())  # just inside
        b = rng.random() * 2 * np.pi
        q = (p[0] + d * np.cos(b), p[1] + d * np.sin(b))
        best = _min_clearance(p, q)
        if best is None:
            continue
        checked += 1
        assert best < INST.collision_buffer_mm, (p, q, best)


def test_just_beyond_the_exclusion_distance_two_arms_can_observe_both() -> None:
    """The distance is not padded: at d_min + 3 mm two neighbouring arms fit."""
    found = 0
    for a in np.linspace(0, 2 * np.pi, 12, endpoint=False):
        p = (40.0 * np.cos(a), 40.0 * np.sin(a))
        q = (p[0] - (D_MIN + 3.0) * np.sin(a), p[1] + (D_MIN + 3.0) * np.cos(a))
        best = _min_clearance(p, q)
        found += best is not None and best >= INST.collision_buffer_mm
    assert found >= 6


@pytest.mark.parametrize("seed", range(5))
def test_cells_are_cliques_and_a_partition(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.normal(0.0, 15.0 + 10 * seed, (120, 2))
    cells = crowding_cells(xy, D_MIN)
    assert cells.cell.shape == (120,) and cells.cell.min() == 0 and cells.cell.max() == cells.count - 1
    assert cells.size.sum() == 120
    for c in range(cells.count):
        m = xy[cells.cell == c]
        d = np.hypot(*(m[:, None, :] - m[None, :, :]).transpose(2, 0, 1))
        assert np.all(d[~np.eye(len(m), dtype=bool)] < D_MIN)


def _enclosing_radius(pts: np.ndarray) -> float:
    """The radius of the smallest circle holding 1-3 points (exact)."""
    if len(pts) == 1:
        return 0.0
    sides = [float(np.hypot(*(pts[i] - pts[j]))) for i, j in itertools.combinations(range(len(pts)), 2)]
    if len(pts) == 2:
        return sides[0] / 2
    a, b, c = sorted(sides)
    if c * c >= a * a + b * b:  # right or obtuse: the longest side is a diameter
        return c / 2
    s = (a + b + c) / 2
    return a * b * c / (4.0 * np.sqrt(s * (s - a) * (s - b) * (s - c)))


def _brute_force_cover(xy: np.ndarray, arms: int) -> int:
    """Fewest exposure sets covering ``xy``: each of at most ``arms`` (<= 3) targets pairwise
    at least D_MIN apart and inside one disc of radius R (exact enclosing circles)."""
    n = len(xy)
    feasible = []
    for size in range(1, min(arms, n) + 1):
        for s in itertools.combinations(range(n), size):
            pts = xy[list(s)]
            if any(np.hypot(*(pts[i] - pts[j])) < D_MIN for i, j in itertools.combinations(range(size), 2)):
                continue
            if _enclosing_radius(pts) <= R_MM:
                feasible.append(sum(1 << i for i in s))
    full = (1 << n) - 1
    best = {0: 0}
    frontier = [0]
    for k in range(1, n + 1):
        nxt = []
        for cov in frontier:
            for f in feasible:
                c = cov | f
                if c not in best:
                    best[c] = k
                    nxt.append(c)
        if full in best:
            return best[full]
        frontier = nxt
    raise AssertionError("no cover")


@pytest.mark.parametrize("seed", range(6))
def test_the_crowded_bound_never_exceeds_a_brute_force_cover(seed: int) -> None:
    """Small programmes (9 targets, 3 arms): clumps of crowded targets and a few far ones."""
    rng = np.random.default_rng(100 + seed)
    centres = rng.uniform(-250, 250, (3, 2))
    xy = centres[rng.integers(0, 3, 9)] + rng.normal(0, 12.0, (9, 2))
    cells = crowding_cells(xy, D_MIN)
    bound = lower_bound(xy, R_MM, 3, cell=cells.cell)
    exact = _brute_force_cover(xy, 3)
    assert bound.exposures <= exact
    assert bound.exposures >= cells.size.max()


def test_the_crowded_bound_counts_a_cell_of_m_targets_as_m_exposures() -> None:
    xy = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0], [5.0, 5.0], [2.5, 2.5]])
    assert lower_bound(xy, R_MM, 12).exposures == 1
    assert lower_bound(xy, R_MM, 12, cell=crowding_cells(xy, D_MIN).cell).exposures == 5


def test_the_allocator_never_beats_the_crowded_bound() -> None:
    """A dense cluster: the allocator's configurations keep every two targets at least d_min
    apart, and its exposures are at least the bound with crowding."""
    rng = np.random.default_rng(7)
    xy = rng.normal(0.0, 18.0, (40, 2))
    targets = PlaneTargets(tuple(f"t{i}" for i in range(40)), xy[:, 0], xy[:, 1], np.ones(40, np.int64))
    result = allocate(INST, targets, configurations="all", time_limit_s=30.0, seed=1)
    for c in result.configurations:
        idx = [a.target_index for a in c.assignments if a.target_index is not None]
        for i, j in itertools.combinations(idx, 2):
            assert np.hypot(*(xy[i] - xy[j])) >= D_MIN
    bound = lower_bound(xy, R_MM, 12, cell=crowding_cells(xy, D_MIN).cell)
    observed = sum(1 for c in result.configurations for a in c.assignments if a.target_index is not None)
    assert observed == 40
    assert len(result.configurations) >= bound.exposures > lower_bound(xy, R_MM, 12).exposures


@pytest.mark.parametrize("seed", range(6))
def test_the_dominant_rows_are_the_cells_that_outnumber_a_sets_exposures_over_the_arms(seed: int) -> None:
    """With ``arms``, :func:`crowding_rows` keeps exactly the rows (candidate j, cell c) whose
    members m of c in S_j exceed ceil(|S_j| / arms), m >= 2; without, every row with m >= 2.
    Checked against a count over every (set, cell) pair."""
    from solvers.programme.crowding import crowding_rows

    rng = np.random.default_rng(seed)
    n, arms = 40, 3
    xy = rng.normal(0.0, 20.0, (n, 2))
    cells = crowding_cells(xy, 25.0)
    sets = [np.sort(rng.choice(n, size=rng.integers(1, 16), replace=False)) for _ in range(12)]
    col_set = np.concatenate([np.full(len(s), j) for j, s in enumerate(sets)])
    member = np.concatenate(sets)
    kept = []
    for limit in (None, arms):
        start, entries, row_set, cap = crowding_rows(col_set, member, cells, limit)
        kept.append(len(row_set))
        got = {(int(row_set[g]), frozenset(int(member[e]) for e in entries[start[g]:start[g + 1]]))
               for g in range(len(row_set))}
        want = set()
        for j, s in enumerate(sets):
            for c in np.unique(cells.cell[s]):
                m = s[cells.cell[s] == c]
                if len(m) >= 2 and (limit is None or len(m) > -(-len(s) // limit)):
                    want.add((j, frozenset(int(t) for t in m)))
        assert got == want and len(got) == len(row_set) and np.all(cap == 1.0)
        assert all(np.all(col_set[entries[start[g]:start[g + 1]]] == row_set[g]) for g in range(len(row_set)))
    assert 0 < kept[1] < kept[0]  # both kinds of row occur
