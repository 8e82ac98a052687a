"""The planner's compiled clearance kernel against the numpy reference and shapely.

:mod:`planner.clearance` must give the clearances of :func:`models.collision.segment_distance_xy`
(the verifier's form) on every input, degenerate ones included: zero-length segments, shared
end points, collinear and (nearly) parallel segments, crossings, and arm bodies of real
configurations.
"""

from __future__ import annotations

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from models.collision import segment_distance_xy
from models.instrument import default_instrument
from planner.clearance import (
    clearance_rows,
    clearance_to_arms,
    diagonals_bad,
    rest_clear,
    segment_distance,
)
from planner.geometry import ArmGeom

INS = default_instrument()
coord = st.one_of(st.integers(-4, 4).map(float), st.floats(-200, 200, allow_nan=False, allow_infinity=False, allow_subnormal=False))


def numpy_clearance(sa, ea, ra, sb, eb, rb):
    d = segment_distance_xy(sa[..., :, None, 0], sa[..., :, None, 1], ea[..., :, None, 0], ea[..., :, None, 1],
                            sb[..., None, :, 0], sb[..., None, :, 1], eb[..., None, :, 0], eb[..., None, :, 1])
    return (d - ra[:, None] - rb[None, :]).min(axis=(-2, -1))


@settings(max_examples=400, deadline=None, derandomize=True)
@given(st.lists(coord, min_size=8, max_size=8), st.sampled_from(["free", "point", "shared", "parallel"]))
def test_segment_distance_matches_numpy_and_shapely(xs, shape):
    ax, ay, bx, by, cx, cy, dx, dy = xs
    if shape == "point":
        bx, by = ax, ay
    elif shape == "shared":
        cx, cy = bx, by
    elif shape == "parallel":  # c-d a shifted copy of a-b (collinear when the shift is along it)
        dx, dy = cx + (bx - ax), cy + (by - ay)
    got = segment_distance(ax, ay, bx, by, cx, cy, dx, dy)
    ref = float(segment_distance_xy(*(np.array(v) for v in (ax, ay, bx, by, cx, cy, dx, dy))))
    assert abs(got - ref) <= 1e-9 * max(1.0, abs(ref))

    def geom(p, q):
        return shapely.Point(p) if p == q else shapely.LineString([p, q])

    oracle = geom((ax, ay), (bx, by)).distance(geom((cx, cy), (dx, dy)))
    assert abs(got - oracle) <= 1e-6 * max(1.0, oracle)


def test_arm_bodies_match_numpy_on_real_configurations():
    rng = np.random.default_rng(5)
    ga, gb = ArmGeom.of(INS, 0), ArmGeom.of(INS, 1)
    n = 3000
    sa, ea = ga.segments(rng.uniform(0, np.pi, n), rng.uniform(0, 2 * np.pi, n))
    sb, eb = gb.segments(rng.uniform(0, np.pi, n), rng.uniform(0, 2 * np.pi, n))
    got = clearance_rows(sa, ea, ga.radius, sb, eb, gb.radius)
    ref = numpy_clearance(sa, ea, ga.radius, sb, eb, gb.radius)
    assert got.shape == (n,)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
    assert (got < 0).any() and (got > 0).any()  # both colliding and clear samples were met


def test_broadcasting_follows_the_numpy_form():
    rng = np.random.default_rng(1)
    ga = ArmGeom.of(INS, 3)
    sa, ea = ga.segments(rng.uniform(0, np.pi, 12), rng.uniform(0, 2 * np.pi, 12))
    sa, ea = sa.reshape(3, 4, -1, 2), ea.reshape(3, 4, -1, 2)
    so, eo = ga.segments(np.array([1.0]), np.array([2.0]))  # one pose against a grid of poses
    got = clearance_rows(sa, ea, ga.radius, so[0], eo[0], ga.radius)
    assert got.shape == (3, 4)
    np.testing.assert_allclose(got, numpy_clearance(sa, ea, ga.radius, so[0], eo[0], ga.radius), atol=1e-9)
    assert clearance_rows(sa[:0], ea[:0], ga.radius, so[0], eo[0], ga.radius).shape == (0, 4)


def test_clearance_to_arms_matches_numpy_per_obstacle_radii():
    rng = np.random.default_rng(2)
    g, h = ArmGeom.of(INS, 0), ArmGeom.of(INS, 1)
    cs, ce = g.segments(rng.uniform(0, np.pi, 40), rng.uniform(0, 2 * np.pi, 40))
    S, E = zip(*(h.segments(rng.uniform(0, np.pi, 40), rng.uniform(0, 2 * np.pi, 40)) for _ in range(3)), strict=True)
    S, E = np.stack(S), np.stack(E)
    R = np.stack([h.radius, h.radius + 1.0, h.radius * 0.5])
    got = clearance_to_arms(cs, ce, g.radius, S, E, R)
    ref = np.stack([numpy_clearance(cs, ce, g.radius, S[a], E[a], R[a]) for a in range(3)])
    assert got.shape == (3, 40)
    np.testing.assert_allclose(got, ref, atol=1e-9)
    fixed = clearance_to_arms(cs[:1], ce[:1], g.radius, S, E, R)  # one pose against every sample
    np.testing.assert_allclose(fixed, np.stack([numpy_clearance(cs[:1], ce[:1], g.radius, S[a], E[a], R[a])
                                                for a in range(3)]), atol=1e-9)
    still = clearance_to_arms(cs, ce, g.radius, S[:, :1], E[:, :1], R)  # every sample against fixed poses
    np.testing.assert_allclose(still, np.stack([numpy_clearance(cs, ce, g.radius, S[a, :1], E[a, :1], R[a])
                                                for a in range(3)]), atol=1e-9)


def _neighbour_moves():
    """Two neighbours' straight moves from park to deep configurations (tips near the centre),
    sampled every 0.1 s, and the Lipschitz bound of their clearance per sample of both."""
    from planner.delay_tables import prepare
    from planner.delays import straight_options
    from planner.geometry import body_speed_bound_mm_s

    ga, gb = ArmGeom.of(INS, 4), ArmGeom.of(INS, 5)
    park = INS.park_configuration
    oa = straight_options(ga, park[4], np.array([0.9191, 2.6945]))[0]  # tip at (-5, 3) mm
    ob = straight_options(gb, park[5], np.array([1.2422, 3.032]))[0]  # tip at (-40, 0) mm
    for o, g in ((oa, ga), (ob, gb)):
        prepare(o, g, 0.1)
    la = body_speed_bound_mm_s(ga, ga.v1_max, ga.v2_max) * 0.1
    lb = body_speed_bound_mm_s(gb, gb.v1_max, gb.v2_max) * 0.1
    return oa, ga, ob, gb, la, lb


def test_rest_walk_agrees_with_every_sample_of_real_moves():
    """A moving arm against a neighbour resting at its start, its goal and a pose in between:
    certified or evaluated, ok is exactly clearance >= threshold at every sample (thresholds
    that make the walk jump far, and ones it must step through)."""
    oa, ga, ob, gb, la, _ = _neighbour_moves()
    checked_bad = 0
    for j in (0, ob.n // 2, ob.n):
        ref_c = numpy_clearance(oa.seg[0], oa.seg[1], ga.radius, ob.seg[0][j:j + 1], ob.seg[1][j:j + 1], gb.radius)
        for thr in (0.0, 5.0, 20.0, 60.0):
            ok, n_exact = rest_clear(oa.seg[0], oa.seg[1], ga.radius, oa.box, ob.seg[0], ob.seg[1], gb.radius,
                                     ob.box, j, la, thr)
            np.testing.assert_array_equal(ok, ref_c >= thr)
            checked_bad += int((~ok).sum())
            assert n_exact <= len(ok)
    assert checked_bad > 0  # some thresholds do find close samples


def test_diagonal_walk_agrees_with_every_sample_of_real_moves():
    """Both arms moving, b departing m k samples after a, for every k: a diagonal is bad
    exactly when some sample of it is below the threshold; most samples are never computed."""
    oa, ga, ob, gb, la, lb = _neighbour_moves()
    m, thr = 20, 5.0
    k_lo, k_hi = -oa.n // m, ob.n // m + 1
    bad, n_exact = diagonals_bad(oa.seg[0], oa.seg[1], ga.radius, oa.box, ob.seg[0], ob.seg[1], gb.radius,
                                 ob.box, m, k_lo, k_hi, la + lb, thr)
    total = 0
    for k in range(k_lo, k_hi + 1):
        a = np.arange(max(0, m * k), min(oa.n, ob.n + m * k) + 1)
        total += len(a)
        ref = bool(len(a)) and bool((numpy_clearance(oa.seg[0][a], oa.seg[1][a], ga.radius, ob.seg[0][a - m * k],
                                                     ob.seg[1][a - m * k], gb.radius) < thr).any())
        assert bad[k - k_lo] == ref, k
    assert bad.any() and not bad.all()  # the moves do meet at some delays
    assert n_exact < total // 4
