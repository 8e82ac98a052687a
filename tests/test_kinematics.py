"""Kinematics: FK/IK round trip, branches, ZoA, Jacobian, frames, and the geometry facts."""

from __future__ import annotations

import copy
import tomllib
from importlib import resources

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from models.instrument import default_instrument, parse_instrument
from models.kinematics import (
    Links,
    arm_to_fov,
    d34_mm,
    direct_move_time_s,
    forward_tip,
    fov_to_arm,
    in_zoa,
    inverse,
    inverse_fov,
    inverse_fov_every_arm,
    jacobian,
    joint_displacement,
    joint_distance,
    joint_positions,
    segment_in_zoa,
    tip_fov,
)

INS = default_instrument()


def _fov_grid(step_mm: float = 2.5) -> tuple[np.ndarray, np.ndarray]:
    g = np.arange(-125, 125 + step_mm, step_mm)
    x, y = np.meshgrid(g, g)
    inside = np.hypot(x, y) <= 125.0
    return x[inside], y[inside]


def test_a_tip_at_the_full_reach_is_reachable() -> None:
    """theta1 a rounding below pi with theta2 = 0 stretches the arm to its full reach: the
    J3 circles are tangent there and rounding must not lose the solution."""
    for arm in range(12):
        t1 = float(np.nextafter(np.pi, 0.0))
        tip = tip_fov(INS, arm, t1, 0.0)
        sol = inverse_fov(INS, arm, tip[0], tip[1])
        assert sol.valid.any(), arm
        b = np.flatnonzero(sol.valid[0])[0]
        assert np.hypot(*(tip_fov(INS, arm, sol.theta1_rad[0, b], sol.theta2_rad[0, b]) - tip)) < 1e-6


@settings(max_examples=300, deadline=None)
@given(
    arm=st.integers(0, 11),
    t1=st.floats(0.0, np.pi),
    t2=st.floats(0.0, 2 * np.pi, exclude_max=True),
)
def test_fk_ik_round_trip(arm: int, t1: float, t2: float) -> None:
    links = Links.of(INS, arm)
    if in_zoa(t1, t2, links) or abs(d34_mm(t1, t2, links) - 183.0) < 1e-6:
        return
    tip = tip_fov(INS, arm, t1, t2)
    sol = inverse_fov(INS, arm, tip[0], tip[1])
    assert sol.valid.any(), "a feasible configuration's tip must be reachable"
    # every solution reaches the point ...
    for b in np.flatnonzero(sol.valid[0]):
        back = tip_fov(INS, arm, sol.theta1_rad[0, b], sol.theta2_rad[0, b])
        assert np.hypot(*(back - tip)) < 1e-7
        assert not in_zoa(sol.theta1_rad[0, b], sol.theta2_rad[0, b], links)
    # ... and the original configuration is among them
    dt1 = np.abs(sol.theta1_rad[0] - t1)
    dt2 = np.abs(np.angle(np.exp(1j * (sol.theta2_rad[0] - t2))))
    assert np.nanmin(dt1 + dt2) < 1e-6


def test_both_branches_found_where_both_exist() -> None:
    """Points reached by two distinct feasible configurations give both (upper and lower workspace)."""
    rng = np.random.default_rng(3)
    links = Links.of(INS, 0)
    t1 = rng.uniform(0, np.pi, 20000)
    t2 = rng.uniform(0, 2 * np.pi, 20000)
    ok = ~in_zoa(t1, t2, links)
    t1, t2 = t1[ok], t2[ok]
    tips = forward_tip(t1, t2, links)
    sol = inverse(tips[:, 0], tips[:, 1], links)
    n = sol.valid.sum(axis=1)
    assert (n >= 1).all()
    assert (n >= 2).mean() > 0.3, "a large share of the workspace has two solutions"
    # independent check by brute force: the configuration space grid shows the same point
    # reached by two far-apart configurations
    two = np.flatnonzero(n >= 2)[0]
    th1 = sol.theta1_rad[two][sol.valid[two]]
    th2 = sol.theta2_rad[two][sol.valid[two]]
    assert np.ptp(th1) + np.ptp(th2) > 1e-3
    for a, b in zip(th1, th2, strict=True):
        assert np.allclose(forward_tip(a, b, links), tips[two], atol=1e-7)


def test_unreachable_points_give_no_solution() -> None:
    links = Links.of(INS, 0)
    far = inverse(np.array([600.0, -200.0, 0.0, 50.0]), np.array([0.0, 0.0, 0.0, 0.0]), links)
    # 600 mm is beyond d13 + d3tip; behind the arm; at J1 itself; too close to J1
    assert not far.valid.any()
    assert np.isnan(far.theta1_rad).all()


def test_ik_solutions_match_dense_sampling() -> None:
    """Brute-force oracle: a dense joint grid has no feasible configuration near an IK-empty point."""
    links = Links.of(INS, 0)
    g1, g2 = np.meshgrid(np.linspace(0, np.pi, 700), np.linspace(0, 2 * np.pi, 1400), indexing="ij")
    ok = ~in_zoa(g1, g2, links)
    tips = forward_tip(g1[ok], g2[ok], links)
    rng = np.random.default_rng(0)
    pts = rng.uniform([-200, -300], [420, 300], size=(400, 2))
    sol = inverse(pts[:, 0], pts[:, 1], links)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(tips).query(pts)
    reachable = sol.valid.any(axis=1)
    # grid spacing ~1.4 mm at the tip: points far from every sampled tip are unreachable
    assert not reachable[d > 3.0].any()
    # points right on top of sampled tips (deep inside the workspace) are reachable
    assert reachable[d < 0.3].mean() > 0.9


def test_zoa_fraction_is_about_40_percent() -> None:
    rng = np.random.default_rng(1)
    t1 = rng.uniform(0, np.pi, 200_000)
    t2 = rng.uniform(0, 2 * np.pi, 200_000)
    frac = in_zoa(t1, t2, Links.of(INS, 0)).mean()
    assert 0.35 < frac < 0.45


def test_park_is_feasible_and_122mm_from_centre() -> None:
    park = INS.park_configuration
    links = Links.of(INS, np.arange(12))
    assert not in_zoa(park[:, 0], park[:, 1], links).any()
    tips = tip_fov(INS, np.arange(12), park[:, 0], park[:, 1])
    assert np.allclose(np.hypot(tips[:, 0], tips[:, 1]), 122.0, atol=1e-9)


def test_centre_reachable_by_all_12_arms() -> None:
    sol = inverse_fov(INS, np.arange(12), 0.0, 0.0)
    assert sol.valid.any(axis=-1).all()


def test_every_fov_point_reachable_by_at_least_two_arms() -> None:
    x, y = _fov_grid()
    sol = inverse_fov(INS, np.arange(12)[:, None], x[None, :], y[None, :])
    per_point = sol.valid.any(axis=-1).sum(axis=0)
    assert per_point.min() >= 2
    # about 4.7 (arm, branch) assignments per random FOV point (ARCHITECTURE.md)
    rng = np.random.default_rng(2)
    r = 125 * np.sqrt(rng.uniform(0, 1, 20000))
    a = rng.uniform(0, 2 * np.pi, 20000)
    s = inverse_fov(INS, np.arange(12)[:, None], (r * np.cos(a))[None], (r * np.sin(a))[None])
    assert 4.4 < s.valid.sum(axis=(0, 2)).mean() < 5.0


def test_five_evenly_spaced_arms_cover_the_fov() -> None:
    """ARCHITECTURE.md: 5 evenly spaced arms cover the FOV.

    Measured here: they cover every point within 121 mm of the centre and > 99 % of the
    whole 125 mm FOV; a thin rim band (r > 122 mm) midway between two arms is beyond the
    J4 stops. Three arms leave real holes, so the test can fail.
    """
    data = tomllib.loads(resources.files("models.instruments").joinpath("miradas.toml").read_text())
    five = copy.deepcopy(data)
    five["layout"].update(arm_count=5, step_deg=72.0)
    ins5 = parse_instrument(five)
    x, y = _fov_grid()
    r = np.hypot(x, y)
    sol = inverse_fov(ins5, np.arange(5)[:, None], x[None, :], y[None, :])
    covered = sol.valid.any(axis=-1).any(axis=0)
    assert covered[r <= 121.0].all()
    assert covered.mean() > 0.99
    four = copy.deepcopy(data)
    four["layout"].update(arm_count=3, step_deg=120.0)
    ins4 = parse_instrument(four)
    sol4 = inverse_fov(ins4, np.arange(3)[:, None], x[None, :], y[None, :])
    covered4 = sol4.valid.any(axis=-1).any(axis=0)
    assert not covered4[r <= 121.0].all()


def test_segment_zoa_detects_a_crossing_and_accepts_a_free_move() -> None:
    links = Links.of(INS, 0)
    # find two feasible configurations on one theta1 row whose straight segment crosses the ZoA
    t2 = np.linspace(0, 2 * np.pi, 721)
    for t1 in np.linspace(0.1, np.pi - 0.1, 30):
        col = in_zoa(np.full_like(t2, t1), t2, links)
        enter = np.flatnonzero(~col[:-1] & col[1:])
        if len(enter) and (~col[enter[0] + 1:]).any():
            break
    i = enter[0]
    j = i + 1 + np.flatnonzero(~col[i + 1:])[0]
    q_a, q_b = (t1, t2[i]), (t1, t2[j])
    assert not in_zoa(*q_a, links) and not in_zoa(*q_b, links)
    assert segment_in_zoa(np.array(q_a), np.array(q_b), links)
    # a tiny move near park stays outside
    park = INS.park_configuration[0]
    assert not segment_in_zoa(park, park + np.array([-0.1, 0.1]), links)
    # vectorised over many segments
    many = segment_in_zoa(np.array([q_a, park]), np.array([q_b, park + [-0.1, 0.1]]), links)
    assert many.tolist() == [True, False]


def test_joint_displacement_wraps_theta2_both_ways() -> None:
    d1, ccw, cw = joint_displacement(np.array([0.5, 6.0]), np.array([1.0, 0.2]))
    assert np.isclose(d1, 0.5)
    assert np.isclose(ccw, 0.2 + 2 * np.pi - 6.0)
    assert np.isclose(cw, ccw - 2 * np.pi)
    assert np.isclose(joint_distance(np.array([0.5, 6.0]), np.array([1.0, 0.2])), 0.5)
    t = direct_move_time_s(np.array([0.0, 0.0]), np.array([np.pi, 0.0]), 0.031416, 0.031416)
    assert np.isclose(t, 100.0, rtol=1e-4)  # the longest direct move takes 100 s


def test_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(5)
    links = Links.of(INS, 0)
    t1 = rng.uniform(0.1, 3.0, 500)
    t2 = rng.uniform(0, 2 * np.pi, 500)
    ok = ~in_zoa(t1, t2, links)
    t1, t2 = t1[ok], t2[ok]
    J = jacobian(t1, t2, links)
    h = 1e-6
    d1 = (forward_tip(t1 + h, t2, links) - forward_tip(t1 - h, t2, links)) / (2 * h)
    d2 = (forward_tip(t1, t2 + h, links) - forward_tip(t1, t2 - h, links)) / (2 * h)
    assert np.allclose(J[..., 0], d1, atol=1e-4)
    assert np.allclose(J[..., 1], d2, atol=1e-4)


def test_frames_round_trip_and_orientation() -> None:
    rng = np.random.default_rng(6)
    x, y = rng.uniform(-125, 125, (2, 100))
    for k in range(12):
        a, b = fov_to_arm(INS, k, x, y)
        xx, yy = arm_to_fov(INS, k, a, b)
        assert np.allclose(xx, x) and np.allclose(yy, y)
    # the FOV centre is 350 mm straight ahead of every arm
    a, b = fov_to_arm(INS, np.arange(12), 0.0, 0.0)
    assert np.allclose(a, 350.0) and np.allclose(b, 0.0, atol=1e-9)


def test_joint_positions_respect_link_lengths() -> None:
    rng = np.random.default_rng(7)
    links = Links.of(INS, 0)
    t1 = rng.uniform(0, np.pi, 1000)
    t2 = rng.uniform(0, 2 * np.pi, 1000)
    p = joint_positions(t1, t2, links)
    assert np.allclose(np.linalg.norm(p["J3"] - p["J1"], axis=-1), 77.0)
    assert np.allclose(np.linalg.norm(p["J4"] - p["J2"], axis=-1), 50.0)
    assert np.allclose(np.linalg.norm(p["tip"] - p["J3"], axis=-1), 305.0)
    # tip, J3 and J4 are collinear
    u = p["tip"] - p["J3"]
    w = p["J4"] - p["J3"]
    assert np.allclose(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0], 0.0, atol=1e-8)


def test_every_arm_inverse_equals_the_broadcast_one_at_and_around_the_reach_circles() -> None:
    """inverse_fov_every_arm solves only the points in an arm's annulus of reach: its solutions
    equal inverse_fov's everywhere, bit for bit, on random FOV points and on points at, just
    inside and just outside every arm's inner and outer reach circles (the tangent cases)."""
    rng = np.random.default_rng(7)
    xs, ys = [rng.uniform(-200.0, 200.0, 3000)], [rng.uniform(-200.0, 200.0, 3000)]
    for k, arm in enumerate(INS.arms):
        for r in (abs(arm.d13_mm - arm.d3tip_mm), arm.d13_mm + arm.d3tip_mm):
            for dr in (-1e-6, -1e-12, 0.0, 1e-12, 1e-6, 0.5, -0.5):
                phi = rng.uniform(0.0, np.pi, 40)
                x, y = arm_to_fov(INS, k, (r + dr) * np.cos(phi), (r + dr) * np.sin(phi))
                xs.append(np.asarray(x))
                ys.append(np.asarray(y))
    x, y = np.concatenate(xs), np.concatenate(ys)
    arms = np.arange(INS.n_arms)
    want = inverse_fov(INS, arms[:, None], x[None, :], y[None, :])
    got = inverse_fov_every_arm(INS, x, y)
    assert np.array_equal(got.valid, want.valid)
    assert np.array_equal(got.theta1_rad, want.theta1_rad, equal_nan=True)
    assert np.array_equal(got.theta2_rad, want.theta2_rad, equal_nan=True)
    assert want.valid.any() and not want.valid.all()  # the layout tests both outcomes
