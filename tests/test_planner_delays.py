"""Straight moves with departure delays (planner.delays): pair tables, CSP, detours, via park."""

from __future__ import annotations

import itertools

import numpy as np

from models import clock
from models.budget import Budget
from models.collision import arm_pair_clearance_mm
from models.instrument import default_instrument
from planner import delays as D
from planner import plan_motion, stop_count, verify_trajectories
from planner.geometry import ArmGeom

INST = default_instrument()
PARK = INST.park_configuration
GEOMS = [ArmGeom.of(INST, k) for k in range(12)]
# arms 0 and 1 (others disabled at park): the shortest straight moves admit no departure delays
# (found by a seeded search); the other theta2 direction of a straight move does
CYCLE = [[2.307244239239147, 0.9156473406068187], [1.143913656737312, 3.2163729290477128]]
GOAL_CONFLICT = [[3.0136971541900013, 0.18301607390023514], [1.928770938121543, 2.7180407071074124]]
# en-route conflict of arms 0 and 3 (tests/test_planner.py): simultaneous departure collides
ER_ARMS = (0, 3)
ER_START = [[0.878773072458201, 2.867705337737001], [1.4550251279736608, 2.3495517334077203]]
ER_GOAL = [[1.1008431294640253, 2.92703963520059], [1.3759905077268153, 2.70159732393187]]


def _goal(two, arms=(0, 1)):
    g = PARK.copy()
    g[list(arms)] = two
    return g


def _sample(option: D.Option, tau: float, t: np.ndarray) -> np.ndarray:
    tt, q = D.trajectory_points(option, tau)
    return np.column_stack([np.interp(t, tt, q[:, 0]), np.interp(t, tt, q[:, 1])])



def _delays(start, goal, **kw):
    """planner.delays.plan_delays with the thesis table 6.1 settings used throughout."""
    return D.plan_delays(GEOMS, start, goal, dt_s=6.0, dt_col_s=0.1, horizon_s=220.0, buffer_mm=5.0, **kw)

def test_pair_table_matches_brute_force_sampling():
    start, goal = _goal(ER_START, ER_ARMS), _goal(ER_GOAL, ER_ARMS)
    A, B = ER_ARMS
    oa = D.straight_options(GEOMS[A], start[A], goal[A])
    ob = D.straight_options(GEOMS[B], start[B], goal[B])
    for o in oa + ob:
        D.prepare(o, GEOMS[o.arm], 0.1)
    K, M = 36, 60
    st = D.DelayStats()
    for a, b in itertools.product(oa, ob):
        tab = D.pair_table(a, GEOMS[A], b, GEOMS[B], M, K, 5.0, (1.2, 1.2), st)
        for k in range(-K, K + 1, 3):
            ta, tb = max(0, -k) * 6.0, max(0, k) * 6.0
            T = max(ta + a.duration_s, tb + b.duration_s)
            t = np.arange(0.0, T + 0.1, 0.1)
            c = arm_pair_clearance_mm(INST, A, _sample(a, ta, t), B, _sample(b, tb, t))
            assert tab[k + K] == bool((c >= 5.0).all()), (k, c.min())
    # the case is a real conflict: departing together collides, departing 6 s apart does not
    tab0 = D.pair_table(oa[0], GEOMS[A], ob[0], GEOMS[B], M, K, 5.0, (1.2, 1.2), st)
    assert not tab0[K] and tab0[K + 1]


def test_delay_search_stops_at_its_budget_and_a_generous_one_changes_nothing():
    start, goal = _goal(ER_START, ER_ARMS), _goal(ER_GOAL, ER_ARMS)
    kw = dict(max_start_stop=0, movable=list(ER_ARMS), max_rounds=1)
    free = _delays(start, goal, stats=D.DelayStats(), **kw)
    assert free.assignment is not None
    past = _delays(start, goal, stats=D.DelayStats(), budget=Budget.ending_at(clock.now() - 1.0), **kw)
    assert past.assignment is None
    with clock.effort() as e_free:
        a = _delays(start, goal, stats=D.DelayStats(), **kw)
    with clock.effort() as e_long:
        b = _delays(start, goal, stats=D.DelayStats(), budget=Budget.start(1e6), **kw)
    assert a.assignment == b.assignment == free.assignment
    assert e_long.reads > e_free.reads  # the budget is polled on the effort clock


def test_csp_finds_minimum_makespan():
    start, goal = _goal(ER_START, ER_ARMS), _goal(ER_GOAL, ER_ARMS)
    st = D.DelayStats()
    res = _delays(start, goal, max_start_stop=0, movable=list(ER_ARMS), stats=st, max_rounds=1)
    assert res.assignment is not None
    A, B = ER_ARMS
    # brute force over both arms' (option, delay) values with the same tables
    prob = D.build_problem(GEOMS, res.options, 6.0, 0.1, 220.0, 5.0, D.DelayStats())
    tab = prob.tables[(A, B)]
    best = np.inf
    for pa, pb in itertools.product(range(len(res.options[A])), range(len(res.options[B]))):
        for ta, tb in itertools.product(range(prob.K + 1), repeat=2):
            fa = res.options[A][pa].duration_s + 6 * ta
            fb = res.options[B][pb].duration_s + 6 * tb
            if max(fa, fb) <= 220 and tab[pa, pb, tb - ta + prob.K]:
                best = min(best, max(fa, fb))
    assert abs(res.makespan_s - best) < 1e-9
    lower = max(o[0].duration_s for o in res.options)
    assert res.makespan_s > lower  # the conflict costs one departure delay here


def test_delay_plan_has_zero_stops_and_is_verified():
    inst = INST.with_arms_disabled([k for k in range(12) if k not in ER_ARMS])
    start, goal = _goal(ER_START, ER_ARMS), _goal(ER_GOAL, ER_ARMS)
    plan = plan_motion(inst, start, goal, strategies=("delays",))
    assert plan.status == "ok" and plan.stats["strategy"] == "delays"
    assert all(stop_count(t.t_s, t.theta1_rad, t.theta2_rad) == 0 for t in plan.trajectories)
    assert plan.stats["max_stops"] == 0
    assert verify_trajectories(inst, plan.trajectories, start, goal, exhaustive=True).ok
    # one arm departs one dt later than the other
    departs = sorted(float(plan.trajectories[k].t_s[1]) if len(plan.trajectories[k].t_s) > 2 else 0.0
                     for k in ER_ARMS)
    assert departs == [0.0, 6.0]
    # the default strategies keep a plan at least as short (here the sequenced shorter search,
    # departures on a 0.1 s grid), with zero stops too
    best = plan_motion(inst, start, goal)
    assert best.status == "ok" and best.makespan_s <= plan.makespan_s + 1e-9
    assert all(stop_count(t.t_s, t.theta1_rad, t.theta2_rad) == 0 for t in best.trajectories)


def test_goal_conflict_needs_a_detour():
    """Thesis 6.4.1 goal conflict: straight moves fail at any delays; a one-stop detour solves it."""
    inst = INST.with_arms_disabled(list(range(2, 12)))
    goal = _goal(GOAL_CONFLICT)
    st = D.DelayStats()
    straight = _delays(PARK, goal, max_start_stop=1, movable=[0, 1], stats=st, max_rounds=1)
    assert straight.assignment is None and straight.blamed
    both = _delays(PARK, goal, max_start_stop=0, movable=[0, 1], stats=st, max_rounds=4)
    assert both.assignment is None  # not even with both theta2 directions
    plan = plan_motion(inst, PARK, goal, strategies=("delays",))  # the detour rounds alone
    assert plan.status == "ok" and plan.stats["strategy"] == "delays"
    stops = [stop_count(t.t_s, t.theta1_rad, t.theta2_rad) for t in plan.trajectories]
    assert max(stops) == 1
    assert verify_trajectories(inst, plan.trajectories, PARK, goal, exhaustive=True).ok
    # no stop allowed: the delay strategy cannot solve it, and nothing breaks
    p0 = plan_motion(inst, PARK, goal, max_start_stop=0, strategies=("delays",))
    assert p0.status == "failed" and set(p0.failed_arms) & {0, 1}


def test_other_direction_resolves_cycle():
    inst = INST.with_arms_disabled(list(range(2, 12)))
    goal = _goal(CYCLE)
    st = D.DelayStats()
    r0 = _delays(PARK, goal, max_start_stop=0, movable=[0, 1], stats=st, max_rounds=1)
    assert r0.assignment is None
    plan = plan_motion(inst, PARK, goal)
    assert plan.status == "ok" and plan.stats["strategy"] == "delays"
    assert verify_trajectories(inst, plan.trajectories, PARK, goal).ok


def test_two_legs_via_a_configuration():
    """c1 -> via -> c2 as two zero-stop legs (the driver's fallback uses via = park): one stop
    per moving arm, at via, and the concatenation verified as a whole."""
    inst = INST.with_arms_disabled([k for k in range(12) if k not in ER_ARMS])
    c1, c2 = _goal(ER_START, ER_ARMS), _goal(ER_GOAL, ER_ARMS)
    via = c1.copy()  # arm 0 80 % of the way, arm 3 20 %: collision-free (the midpoint is not)
    via[0] += 0.8 * (c2[0] - c1[0])
    via[3] += 0.2 * (c2[3] - c1[3])
    plan = plan_motion(inst, c1, c2, collision_buffer_mm=5.0, max_start_stop=1, strategies=("via",), via=via,
                       time_budget_s=5.0)
    assert plan.status == "ok" and plan.stats["strategy"] == "via"
    rep = verify_trajectories(inst, plan.trajectories, c1, c2, exhaustive=True)
    assert rep.ok
    stops = [stop_count(t.t_s, t.theta1_rad, t.theta2_rad) for t in plan.trajectories]
    assert max(stops) == 1  # (an arm whose two legs are collinear at one speed does not stop)
    # an arm that stops, stops at via
    for k in [k for k in ER_ARMS if stops[k] == 1]:
        tr = plan.trajectories[k]
        at_via = np.isclose(tr.theta1_rad, via[k, 0]) & np.isclose(tr.theta2_rad, via[k, 1])
        assert at_via[1:-1].any()
    # via == start: not a detour
    assert plan_motion(inst, PARK, c2, strategies=("via",), via=PARK, time_budget_s=5.0).status == "failed"


def test_delay_plans_deterministic():
    goal = _goal(CYCLE)
    inst = INST.with_arms_disabled(list(range(2, 12)))
    p1, p2 = plan_motion(inst, PARK, goal, seed=1), plan_motion(inst, PARK, goal, seed=1)
    for a, b in zip(p1.trajectories, p2.trajectories, strict=True):
        np.testing.assert_array_equal(a.t_s, b.t_s)
        np.testing.assert_array_equal(a.theta2_rad, b.theta2_rad)
