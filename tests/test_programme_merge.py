"""Step 6 of the programme optimiser (solvers.programme.merge): two pointings one FOV holds
become one when their members' allocation together takes no more exposures.

Oracles: the checks of tests/test_programme_consolidate.py (forward kinematics of every
observing arm onto its target projected about the merged pointing, FCL clearances between
every pair of arms, the move from park within the limit), the smallest enclosing circle
found again by scipy's optimiser over the centre, and counts of the targets observed."""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from models.budget import Budget
from models.sky import sky_to_focal_mm
from solvers.programme.merge import merge_pointings
from tests.test_programme_consolidate import OPTS, _check_exposures, _field, _observed, _pointing


def _two(seed: int, n_a: int, n_b: int, offset_mm: float, spread_mm: float):
    rng = np.random.default_rng(seed)
    n = n_a + n_b
    r = spread_mm * np.sqrt(rng.random(n))
    a = 2 * np.pi * rng.random(n)
    xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    xy[n_a:] += (offset_mm, 0.0)
    f = _field(xy, seed)
    return f, [_pointing(f, np.arange(n_a), (0.0, 0.0)), _pointing(f, np.arange(n_a, n), (offset_mm, 0.0))]


def _enclosing_radius_mm(f, members, centre) -> float:
    x, y = sky_to_focal_mm(f.ra_deg[members], f.dec_deg[members], centre[0], centre[1], f.scale, 0.0)
    return float(np.hypot(x, y).max())


def test_two_thin_pointings_over_one_sky_become_one() -> None:
    """Five and three targets 40 mm apart: each pointing takes one exposure with idle arms;
    together they fit one FOV and take at most the two exposures, observed by one acquisition."""
    for seed in (1, 2, 3, 4):
        f, pts = _two(seed, 5, 3, 40.0, 35.0)
        before = _observed(pts)
        exposures = sum(p.exposures for p in pts)
        assert merge_pointings(f, pts, OPTS, Budget.start(30.0)) == 1
        assert len(pts) == 1
        (p,) = pts
        assert p.exposures <= exposures
        assert _observed(pts) == before == list(range(8))
        assert sorted(int(i) for i in p.members) == list(range(8))
        _check_exposures(f, pts)
        # the centre is the smallest enclosing circle's, as an independent optimiser finds it
        x, y = sky_to_focal_mm(f.ra_deg, f.dec_deg, p.centre[0], p.centre[1], f.scale, 0.0)
        best = minimize(lambda c, x=x, y=y: np.hypot(x - c[0], y - c[1]).max(), np.zeros(2), method="Nelder-Mead",
                        options={"xatol": 1e-6, "fatol": 1e-6})
        assert _enclosing_radius_mm(f, p.members, p.centre) <= best.fun + 0.05


def test_pointings_one_fov_cannot_hold_stay_apart() -> None:
    """Members 230 mm apart: no FOV (r 124 mm) holds both sets, nothing is allocated again."""
    f, pts = _two(7, 6, 4, 230.0, 20.0)
    kept = [(p.centre, p.exposures, p.members.copy()) for p in pts]
    assert merge_pointings(f, pts, OPTS, Budget.start(30.0)) == 0
    assert [(p.centre, p.exposures) for p in pts] == [(c, e) for c, e, _ in kept]
    assert all(np.array_equal(p.members, m) for p, (_, _, m) in zip(pts, kept, strict=True))


def test_a_merge_never_takes_more_exposures_and_an_expired_budget_merges_nothing() -> None:
    """Programmes of two overlapping pointings over crowded and open sky: whatever merges,
    the exposures never grow, the pointings fall by the merges, every target observed stays
    observed, and every exposure is one the instrument can hold."""
    merges = 0
    for seed in range(5, 13):
        f, pts = _two(seed, 13, 6, 70.0, 45.0 if seed % 2 else 80.0)
        before, exposures = _observed(pts), sum(p.exposures for p in pts)
        assert merge_pointings(f, [*pts], OPTS, Budget.start(0.0)) == 0
        n = merge_pointings(f, pts, OPTS, Budget.start(60.0))
        merges += n
        assert len(pts) == 2 - n
        assert sum(p.exposures for p in pts) <= exposures
        assert _observed(pts) == before
        _check_exposures(f, pts)
    assert merges >= 1  # the case is not vacuous
