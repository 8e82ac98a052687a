"""Collision model: capsule fast path and FCL against an independent shapely oracle."""

from __future__ import annotations

import numpy as np
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from models.collision import (
    arm_pair_clearance_mm,
    colliding_arm_pairs,
    configuration_clearances_mm,
    fcl_clearance_mm,
    fcl_configuration_collisions,
    segment_distance_mm,
)
from models.instrument import default_instrument, parse_instrument
from models.kinematics import Links, in_zoa, joint_positions_fov

INS = default_instrument()


def random_feasible_q(rng: np.random.Generator, n: int) -> np.ndarray:
    out = np.empty((0, 2))
    links = Links.of(INS, 0)
    while len(out) < n:
        t1 = rng.uniform(0, np.pi, 2 * n)
        t2 = rng.uniform(0, 2 * np.pi, 2 * n)
        ok = ~in_zoa(t1, t2, links)
        out = np.vstack([out, np.column_stack([t1[ok], t2[ok]])])
    return out[:n]


def shapely_clearance_mm(arm_a: int, q_a, arm_b: int, q_b) -> float:
    """Oracle: exact distance between the unions of buffered body segments (shapely/GEOS)."""

    def bodies(arm, q):
        j = joint_positions_fov(INS, arm, q[0], q[1])
        return [(shapely.LineString([j[b.joint_from], j[b.joint_to]]), b.radius_mm)
                for b in INS.arms[arm].bodies]

    best = np.inf
    for la, ra in bodies(arm_a, q_a):
        for lb, rb in bodies(arm_b, q_b):
            best = min(best, shapely.distance(la, lb) - ra - rb)
    return best


def test_fast_path_and_fcl_agree_with_shapely_on_2000_pairs() -> None:
    rng = np.random.default_rng(11)
    n = 2000
    qa, qb = random_feasible_q(rng, n), random_feasible_q(rng, n)
    arm_a = rng.integers(0, 12, n)
    arm_b = (arm_a + rng.integers(1, 4, n)) % 12  # neighbours collide often: a hard test
    fast = arm_pair_clearance_mm(INS, arm_a, qa, arm_b, qb)
    oracle = np.array([shapely_clearance_mm(arm_a[i], qa[i], arm_b[i], qb[i]) for i in range(n)])
    buffer = INS.collision_buffer_mm
    decided = np.abs(oracle - buffer) > 1e-6
    assert ((fast < buffer) == (oracle < buffer))[decided].all()
    positive = oracle > 0
    assert np.allclose(fast[positive], oracle[positive], atol=1e-6)
    assert 0.05 < (oracle < buffer).mean() < 0.95, "the sample must contain both answers"
    # FCL (exact engine): same answers (it reports 0 for overlapping bodies)
    idx = rng.choice(n, 400, replace=False)
    fcl_d = np.array([fcl_clearance_mm(INS, arm_a[i], qa[i], arm_b[i], qb[i]) for i in idx])
    assert ((fcl_d < buffer) == (oracle[idx] < buffer))[decided[idx]].all()
    assert np.allclose(fcl_d, np.maximum(oracle[idx], 0.0), atol=1e-6)


def test_parked_arms_are_collision_free() -> None:
    park = INS.park_configuration
    assert colliding_arm_pairs(INS, park) == []
    assert fcl_configuration_collisions(INS, park) == []
    c = configuration_clearances_mm(INS, park)
    assert np.isclose(c[c < np.inf].min(), 43.15, atol=0.01)


def test_configuration_check_finds_a_planted_collision() -> None:
    q = INS.park_configuration.copy()
    # arm 0 reaching to the FOV centre, arm 1 too: their tips meet
    from models.kinematics import inverse_fov

    for k in (0, 1):
        s = inverse_fov(INS, k, 0.0, 0.0)
        b = np.flatnonzero(s.valid[0])[0]
        q[k] = s.theta1_rad[0, b], s.theta2_rad[0, b]
    assert (0, 1) in colliding_arm_pairs(INS, q)
    assert (0, 1) in fcl_configuration_collisions(INS, q)
    # a larger buffer only adds pairs
    assert set(colliding_arm_pairs(INS, q)) <= set(colliding_arm_pairs(INS, q, buffer_mm=30.0))


# rounded: GEOS mis-measures lines of sub-normal length (1e-182 mm), which no arm has
coord = st.floats(-100, 100, allow_nan=False).map(lambda v: round(v, 6))


@settings(max_examples=300, deadline=None)
@given(coord, coord, coord, coord, coord, coord, coord, coord)
def test_segment_distance_matches_shapely(ax, ay, bx, by, cx, cy, dx, dy) -> None:
    d = segment_distance_mm(np.array([ax, ay]), np.array([bx, by]), np.array([cx, cy]), np.array([dx, dy]))
    ga = shapely.LineString([(ax, ay), (bx, by)]) if (ax, ay) != (bx, by) else shapely.Point(ax, ay)
    gb = shapely.LineString([(cx, cy), (dx, dy)]) if (cx, cy) != (dx, dy) else shapely.Point(cx, cy)
    # a segment shorter than 1e-6 mm (squared length <= 1e-12) is taken as its first end
    # point: an error of at most its length
    assert abs(float(d) - shapely.distance(ga, gb)) <= 1.5e-6


def test_nearly_parallel_segments_that_cross_touch() -> None:
    """Segments too close to parallel for the general closest-point formula that still
    cross are at distance 0 (shapely), at any rotation; collinear ones keep their end points'
    distance."""
    a0, a1, b0, b1 = np.array([-7.0, 4e-6]), np.array([0.0, 0.0]), np.array([-10.0, 0.0]), np.array([0.0, 4e-6])
    for ang in np.radians([0.0, 17.0, 90.0, 200.0]):
        rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        p = [rot @ v for v in (a0, a1, b0, b1)]
        want = shapely.distance(shapely.LineString(p[:2]), shapely.LineString(p[2:]))
        assert abs(float(segment_distance_mm(*p)) - want) <= 1.5e-6
    assert float(segment_distance_mm(np.array([0.0, 0.0]), np.array([10.0, 0.0]),
                                     np.array([11.0, 0.0]), np.array([20.0, 0.0]))) == 1.0


def test_other_fcl_shapes_from_the_instrument_file() -> None:
    """A box/sphere instrument works through FCL without code changes."""
    import tomllib
    from importlib import resources

    data = tomllib.loads(resources.files("models.instruments").joinpath("miradas.toml").read_text())
    data["arm_defaults"]["bodies"] = [
        {"name": "L1", "shape": "box", "from": "J1", "to": "J3", "width_mm": 16.0},
        {"name": "L3", "shape": "capsule", "from": "J3", "to": "tip", "radius_mm": 10.0},
        {"name": "mirror", "shape": "sphere", "from": "tip", "radius_mm": 12.0},
    ]
    ins = parse_instrument(data)
    park = ins.park_configuration
    assert fcl_configuration_collisions(ins, park) == []
    # sphere at the tip reaches 2 mm further than the capsule: two tips 22 mm apart collide
    from models.kinematics import inverse_fov

    q = park.copy()
    s0 = inverse_fov(ins, 0, 0.0, 11.0)
    s6 = inverse_fov(ins, 6, 0.0, -11.0)
    q[0] = s0.theta1_rad[0, s0.valid[0]][0], s0.theta2_rad[0, s0.valid[0]][0]
    q[6] = s6.theta1_rad[0, s6.valid[0]][0], s6.theta2_rad[0, s6.valid[0]][0]
    assert fcl_clearance_mm(ins, 0, q[0], 6, q[6]) < 0.5
