"""Motion planner (issue 6): conflicts solved and verified, stop limit, dt_col, determinism,
unplannable cases, geometry primitives, motor steps."""

from __future__ import annotations

import numpy as np
import pytest

from models.collision import body_segments_mm
from models.instrument import default_instrument
from models.kinematics import Links, segment_in_zoa
from models.types import ArmTrajectory
from planner import plan_chain, plan_motion, stop_count, to_motor_steps, verify_trajectories
from planner.geometry import ArmGeom, edges_in_zoa
from planner.single_arm import ObstacleTime, SearchStats, _Checker

INST = default_instrument()
PARK = INST.park_configuration
V = INST.max_joint_speed_rad_s
A, B = 0, 1

# two arms (0, 1) move, the other ten stay parked (disabled). Found by a seeded search over
# reachable targets between the two arms (see benchmarks/motion.py for the geometry).
GOAL_CONFLICT = [[3.0136971541900013, 0.18301607390023514], [1.928770938121543, 2.7180407071074124]]
ARM0_ON_ARM1_PARK = (1.81205646, 3.80872934)
THIN = [[1.5068486993930823, 2.592683017496547], [1.3948972100113546, 2.6121715572481228]]
# en-route conflict between arms 0 and 3 (found by a seeded search over crossing tip paths near the
# FOV centre): starts and goals are collision-free, neither straight move sweeps the other arm's
# start or goal, yet the two straight moves started together collide mid-way (t ~ 3.5 s of 7 / 11 s)
EN_ROUTE_ARMS = (0, 3)
EN_ROUTE_START = [[0.878773072458201, 2.867705337737001], [1.4550251279736608, 2.3495517334077203]]
EN_ROUTE_GOAL = [[1.1008431294640253, 2.92703963520059], [1.3759905077268153, 2.70159732393187]]


def _two_arm(goals):
    inst = INST.with_arms_disabled([k for k in range(12) if k not in (A, B)])
    goal = PARK.copy()
    goal[[A, B]] = goals
    return inst, goal


def _straight(k: int, q0: np.ndarray, q1: np.ndarray) -> ArmTrajectory:
    """Both joints at full speed from t = 0, shorter theta2 way: the naive simultaneous move."""
    d = np.array(q1, float) - q0
    d[1] = (d[1] + np.pi) % (2 * np.pi) - np.pi
    T = float(np.abs(d).max() / V)
    if T == 0:
        return ArmTrajectory(k, np.array([0.0]), q0[:1].copy(), q0[1:].copy())
    return ArmTrajectory(k, np.array([0.0, T]), np.array([q0[0], q0[0] + d[0]]), np.array([q0[1], q0[1] + d[1]]))


def _straight_all(start, goal):
    return [_straight(k, start[k], goal[k]) for k in range(len(start))]


def _en_route():
    inst = INST.with_arms_disabled([k for k in range(12) if k not in EN_ROUTE_ARMS])
    start, goal = PARK.copy(), PARK.copy()
    start[list(EN_ROUTE_ARMS)] = EN_ROUTE_START
    goal[list(EN_ROUTE_ARMS)] = EN_ROUTE_GOAL
    return inst, start, goal


@pytest.mark.parametrize("case", ["goal_conflict", "en_route"])
def test_conflict_solved_and_verified(case):
    if case == "goal_conflict":
        inst, goal = _two_arm(GOAL_CONFLICT)
        start, pair = PARK, (A, B)
    else:
        inst, start, goal = _en_route()
        pair = EN_ROUTE_ARMS
    naive = verify_trajectories(inst, _straight_all(start, goal), start, goal)
    hits = [v for v in naive.violations if v.kind == "collision" and v.arms == pair]
    assert hits, "straight motion must collide"
    if case == "en_route":  # the collision is strictly en route: not at departure, not at arrival
        T = [_straight(k, start[k], goal[k]).t_s[-1] for k in pair]
        assert 0.0 < hits[0].t_s < min(T)
    plan = plan_motion(inst, start, goal)
    assert plan.status == "ok", plan.stats
    rep = verify_trajectories(inst, plan.trajectories, start, goal, exhaustive=True)
    assert rep.ok and rep.min_clearance_mm >= 5.0
    for tr in plan.trajectories:
        assert stop_count(tr.t_s, tr.theta1_rad, tr.theta2_rad) <= 1
    assert plan.makespan_s <= 220.0


def test_goal_conflict_is_a_goal_conflict():
    """One arm's straight path sweeps the other's goal (thesis 6.4.1, conflict (i))."""
    inst, goal = _two_arm(GOAL_CONFLICT)
    tr = _straight(A, PARK[A], goal[A])
    still = ArmTrajectory(B, np.array([0.0]), goal[B, :1], goal[B, 1:])
    others = [_straight(k, PARK[k], goal[k]) for k in range(12) if k not in (A, B)]
    rep = verify_trajectories(inst, [tr, still, *others], PARK, goal, max_start_stop=None)
    hits = [v for v in rep.violations if v.kind == "collision"]
    tr_b = _straight(B, PARK[B], goal[B])
    still_a = ArmTrajectory(A, np.array([0.0]), goal[A, :1], goal[A, 1:])
    rep_b = verify_trajectories(inst, [still_a, tr_b, *others], PARK, goal, max_start_stop=None)
    assert hits or [v for v in rep_b.violations if v.kind == "collision"]


def test_stop_limit_zero_holds():
    inst, goal = _two_arm(GOAL_CONFLICT)
    plan = plan_motion(inst, PARK, goal, max_start_stop=0)
    if plan.status == "ok":
        for tr in plan.trajectories:
            assert stop_count(tr.t_s, tr.theta1_rad, tr.theta2_rad) == 0
            assert len(tr.commands) <= 2  # one move per joint at most
    else:
        assert plan.failed_arms


def test_dt_col_catches_thin_obstacle():
    """The straight en-route crossing is clear at every dt = 6 s sample but not in between."""
    inst, goal = _two_arm(THIN)
    ga, gb = ArmGeom.of(inst, A), ArmGeom.of(inst, B)
    n_steps = 37

    ta, tb = _straight(A, PARK[A], goal[A]), _straight(B, PARK[B], goal[B])
    n_move = int(np.ceil(max(ta.t_s[-1], tb.t_s[-1]) / 6.0))
    results = {}
    for m in (1, 60):  # dt_col = dt, dt_col = 100 ms
        t = np.arange(n_steps * m + 1) * (6.0 / m)
        qa = np.column_stack([np.interp(t, ta.t_s, ta.theta1_rad), np.interp(t, ta.t_s, ta.theta2_rad)])
        qb = np.column_stack([np.interp(t, tb.t_s, tb.theta1_rad), np.interp(t, tb.t_s, tb.theta2_rad)])
        obst = ObstacleTime(m=m, n_steps=n_steps, buffer_mm=5.0, nb=3)
        obst.add(ga, qa, n_move)
        chk = _Checker(gb, obst, SearchStats())
        s, e = gb.segments(qb[:, 0], qb[:, 1])
        results[m] = all(chk.clear(s[(k - 1) * m + 1:k * m + 1], e[(k - 1) * m + 1:k * m + 1], (k - 1) * m + 1)
                         for k in range(1, n_move + 1))
    assert results[1] is True and results[60] is False


def test_same_seed_same_plan():
    inst, goal = _two_arm(GOAL_CONFLICT)
    p1 = plan_motion(inst, PARK, goal, seed=3)
    p2 = plan_motion(inst, PARK, goal, seed=3)
    assert p1.status == p2.status == "ok"
    assert p1.makespan_s == p2.makespan_s
    for a, b in zip(p1.trajectories, p2.trajectories, strict=True):
        np.testing.assert_array_equal(a.t_s, b.t_s)
        np.testing.assert_array_equal(a.theta1_rad, b.theta1_rad)
        np.testing.assert_array_equal(a.theta2_rad, b.theta2_rad)
        assert a.commands == b.commands


def test_goal_in_zoa_fails_without_exception():
    goal = PARK.copy()
    goal[4] = (0.0, np.pi)  # J4 beyond its stop: in the ZoA
    assert ArmGeom.of(INST, 4).in_zoa(*goal[4])
    plan = plan_motion(INST, PARK, goal)
    assert plan.status == "failed" and 4 in plan.failed_arms
    assert "zone of avoidance" in plan.stats["reasons"][4]


def test_colliding_goal_fails_naming_both_arms():
    goal = PARK.copy()
    goal[0] = ARM0_ON_ARM1_PARK  # arm 0's goal overlaps arm 1 resting at park
    plan = plan_motion(INST, PARK, goal)
    assert plan.status == "failed"
    assert {0, 1} <= set(plan.failed_arms)


def test_unreachable_within_horizon_fails():
    inst, goal = _two_arm(GOAL_CONFLICT)
    plan = plan_motion(inst, PARK, goal, horizon_s=12.0)
    assert plan.status == "failed" and plan.failed_arms
    assert np.isnan(plan.makespan_s)


def test_start_equals_goal_is_trivial():
    plan = plan_motion(INST, PARK, PARK)
    assert plan.status == "ok" and plan.makespan_s == 0.0
    assert all(len(t.t_s) == 1 for t in plan.trajectories)


def test_chain_park_to_config_to_park():
    inst, goal = _two_arm(GOAL_CONFLICT)
    plans = plan_chain(inst, [goal])
    assert [p.status for p in plans] == ["ok", "ok"]
    end = np.array([[t.theta1_rad[-1], t.theta2_rad[-1]] for t in plans[1].trajectories])
    np.testing.assert_allclose(np.cos(end), np.cos(PARK), atol=1e-9)


def test_invalid_shape_raises_input_error():
    from models.errors import InputError
    with pytest.raises(InputError):
        plan_motion(INST, PARK[:3], PARK)


def test_commands_match_waypoints():
    inst, goal = _two_arm(GOAL_CONFLICT)
    plan = plan_motion(inst, PARK, goal)
    for tr in plan.trajectories:
        for c in tr.commands:
            assert c.speed_rad_s <= V * (1 + 1e-9)
            i = int(np.flatnonzero(np.isclose(tr.t_s, c.t_start_s))[0])
            th = tr.theta1_rad if c.joint == 1 else tr.theta2_rad
            assert th[i] == pytest.approx(c.from_rad) and th[i + 1] == pytest.approx(c.to_rad)


def test_motor_step_rounding_check():
    inst, goal = _two_arm(GOAL_CONFLICT)
    plan = plan_motion(inst, PARK, goal)
    tr = plan.trajectories[A]
    fine = to_motor_steps(inst, tr, 200 * 16 * 100 / (2 * np.pi))  # 1/16 microsteps, 100:1 gear
    assert fine.within_tolerance and fine.tip_error_mm < 0.05
    coarse = to_motor_steps(inst, tr, 10.0)  # 0.1 rad per step: far too coarse
    assert coarse.tip_error_mm > 0.5 and not coarse.within_tolerance
    assert all(isinstance(c.to_steps, int) for c in fine.commands)


# ------------------------------------------------------------------ geometry primitives


def test_arm_geom_matches_body_segments():
    rng = np.random.default_rng(0)
    for k in (0, 5, 11):
        t1 = rng.uniform(0, np.pi, 50)
        t2 = rng.uniform(-7, 7, 50)
        s, e = ArmGeom.of(INST, k).segments(t1, t2)
        s2, e2, r2 = body_segments_mm(INST, k, t1, t2)
        np.testing.assert_allclose(s, s2, atol=1e-9)
        np.testing.assert_allclose(e, e2, atol=1e-9)
        np.testing.assert_allclose(ArmGeom.of(INST, k).radius, r2[0])


def test_edges_in_zoa_agrees_with_segment_in_zoa():
    rng = np.random.default_rng(1)
    g = ArmGeom.of(INST, 3)
    lk = Links.of(INST, 3)
    q0 = np.column_stack([rng.uniform(0, np.pi, 300), rng.uniform(-7, 7, 300)])
    q1 = q0 + rng.normal(0, 0.8, (300, 2))
    q1[:, 0] = np.clip(q1[:, 0], 0, np.pi)
    ours = edges_in_zoa(g, q0, q1)
    ref = np.array([bool(segment_in_zoa(a, b, lk)) for a, b in zip(q0, q1, strict=True)])
    assert ours.any() and (~ours).any()
    np.testing.assert_array_equal(ours, ref)
