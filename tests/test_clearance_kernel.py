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
from planner.clearance import clearance_rows, clearance_to_arms, indexed_clearance, segment_distance
from planner.geometry import ArmGeom

INS = default_instrument()
coord = st.one_of(st.integers(-4, 4).map(float), st.floats(-200, 200, allow_nan=False, allow_infinity=False))


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


def test_indexed_clearance_is_exact_below_the_threshold_and_a_lower_bound_above():
    rng = np.random.default_rng(3)
    ga, gb = ArmGeom.of(INS, 0), ArmGeom.of(INS, 4)  # box gaps both below and above the threshold
    sa, ea = ga.segments(rng.uniform(0, np.pi, 300), rng.uniform(0, 2 * np.pi, 300))
    sb, eb = gb.segments(rng.uniform(0, np.pi, 200), rng.uniform(0, 2 * np.pi, 200))

    def boxes(s, e, r):
        lo, hi = np.minimum(s, e) - r[None, :, None], np.maximum(s, e) + r[None, :, None]
        return np.concatenate([lo.min(axis=1), hi.max(axis=1)], axis=1)

    ia, ib = rng.integers(0, 300, 5000), rng.integers(0, 200, 5000)
    below = 30.0
    got, n_exact = indexed_clearance(sa, ea, ga.radius, boxes(sa, ea, ga.radius), ia,
                                     sb, eb, gb.radius, boxes(sb, eb, gb.radius), ib, below)
    ref = numpy_clearance(sa[ia], ea[ia], ga.radius, sb[ib], eb[ib], gb.radius)
    exact = np.isclose(got, ref, atol=1e-9)
    assert (got <= ref + 1e-9).all()  # never above the true clearance
    assert exact[ref < below].all()  # exact wherever the clearance is below the threshold
    assert 0 < n_exact < len(ia) and n_exact >= (ref < below).sum()
