"""The cutting planes of the programme's bound (solvers.programme.bound).

Oracles: the dense weighing of every disc (the bound's own final check, which does not use
the rounds' member lists), and scipy's LP over every disc at once: on fields small enough
that every disc is a round's disc and holds at most ``arms`` targets, the rounds reach the
full LP's optimum, and the bound is that optimum rounded up per component."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from solvers.programme import bound
from solvers.programme.bound import disc_centres, lower_bound


def _members_of(xy: np.ndarray, centre: np.ndarray, radius_mm: float) -> np.ndarray:
    return np.flatnonzero(np.hypot(*(xy - centre).T) <= radius_mm * (1 + 1e-9) + 1e-9)


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("with_cells", [False, True])
def test_the_rounds_weigh_each_disc_as_the_dense_check(seed: int, with_cells: bool) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 400.0, size=(90, 2))
    R, arms = 125.0, 12
    cell = rng.integers(0, 60, size=len(xy)) if with_cells else None
    cells = None if cell is None else bound._Cells.of(np.unique(cell, return_inverse=True)[1])
    m = len(xy) if cells is None else cells.count
    centres = disc_centres(xy, R)
    w = rng.random(m) * (rng.random(m) < 0.7)  # some zero weights, as the LP gives
    dense, _ = bound._top_sums(xy, w, centres, R, arms, cells)
    padded, tops = bound._padded_top_sums(bound._members(xy, centres, R, cells), w, arms)
    assert np.allclose(dense, padded)
    for j in rng.choice(len(centres), 25, replace=False):  # the top cells are inside the disc
        inside = _members_of(xy, centres[j], R)
        inside_cells = set(inside) if cells is None else {int(c) for c in
                                                          np.unique(cell, return_inverse=True)[1][inside]}
        chosen = {int(c) for c in tops[j] if c >= 0}
        assert chosen <= inside_cells and len(chosen) == min(arms, len(inside_cells))
        assert math.isclose(sum(w[c] for c in chosen), padded[j], abs_tol=1e-12)


def _full_lp_bound(xy: np.ndarray, R: float) -> int:
    """max sum(w) s.t. sum(w over a disc's members) <= 1 for every disc of radius R through
    two targets or about one (every disc holds at most ``arms`` targets here), rounded up
    per component of the 2R-neighbour graph."""
    R = R * (1.0 + bound.RADIUS_SLACK) + 1e-9
    rows = {tuple(_members_of(xy, c, R)) for c in disc_centres(xy, R)}
    A = np.zeros((len(rows), len(xy)))
    for i, r in enumerate(rows):
        A[i, list(r)] = 1.0
    res = linprog(-np.ones(len(xy)), A_ub=A, b_ub=np.ones(len(rows)), bounds=(0, 1), method="highs")
    assert res.status == 0
    pairs = cKDTree(xy).query_pairs(2 * R, output_type="ndarray")
    from scipy import sparse as sp
    g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(xy), len(xy)))
    k, labels = connected_components(g, directed=False)
    per = np.bincount(labels, weights=res.x, minlength=k)
    return sum(math.ceil(v - 1e-7) for v in per)


@pytest.mark.parametrize("seed", range(6))
def test_the_rounds_reach_the_lp_over_every_disc(seed: int) -> None:
    """Sparse fields (about one target per FOV area; every disc holds at most 12): the full
    LP's optimum exceeds the trivial bound, and the rounds must reach it to prove it."""
    rng = np.random.default_rng(100 + seed)
    xy = rng.uniform(0.0, 1400.0, size=(60, 2))
    R, arms = 125.0, 12
    full = _full_lp_bound(xy, R)
    got = lower_bound(xy, R, arms)
    assert got.exposures == max(full, math.ceil(len(xy) / arms))
    assert got.exposures > got.trivial  # the case where the rounds matter
