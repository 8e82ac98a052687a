"""Executable whole-field plans (planner.sequence) and the evasion options (planner.evasion):
regression legs from real prioritised allocations, time reversal and legs through park checked
by the independent verifier, and a leg made unplannable on purpose."""

from __future__ import annotations

import time

import numpy as np
import pytest

from models.errors import InputError
from models.instrument import default_instrument
from models.kinematics import tip_fov
from models.types import ArmAssignment, ArmTrajectory, Configuration, MotionPlan
from planner import plan_motion, verify_trajectories
from planner.delays import DelayStats
from planner.evasion import plan_evasion
from planner.geometry import ArmGeom
from planner.reassign import park_assignment
from planner.sequence import SequenceOptions, plan_sequence, reversed_leg, via_park_leg
from planner.strategies.delays import delay_trajectories

INST = default_instrument()
PARK = INST.park_configuration

# park -> configuration legs that the straight delays, the cluster and the prioritized strategies
# do not plan in 10 s (configurations 1 and 7 of a uniform and a sigma-60 mm field of
# 150 targets with the thesis priority mix, sequenced by allocate(configurations="all")): deep
# targets need a half turn of J2 whose L3 swing sweeps a neighbour at both its start and goal
DEEP_PAIRS = [[2.376101, 0.187627], [1.249194, 3.330396], [1.036665, 3.797867], [2.67291, 6.12583],
              [2.507024, 6.081404], [1.489474, 3.328246], [2.392603, 0.339543], [2.57164, 0.094639],
              [0.926969, 2.935002], [0.787435, 3.359508], [2.373609, 0.447855], [2.865671, 0.143866]]
PARKED_NEIGHBOURS = [[1.208273, 2.55069], [1.295117, 2.740395], [1.73146, 3.612445], [np.pi, 0.0],
                     [1.016894, 3.279197], [2.262628, 3.017613], [1.251868, 3.332064], [np.pi, 0.0],
                     [2.067543, 3.231324], [2.151545, 2.858661], [np.pi, 0.0], [np.pi, 0.0]]


def _exact(rows) -> np.ndarray:
    return np.array(rows, float)


def _configuration(index: int, q: np.ndarray, arms_on_targets) -> Configuration:
    asg = []
    for k in range(INST.n_arms):
        if k in arms_on_targets:
            x, y = tip_fov(INST, k, q[k, 0], q[k, 1])
            asg.append(ArmAssignment(k, "target", float(q[k, 0]), float(q[k, 1]), float(x), float(y),
                                     index * 100 + k, f"c{index}a{k}"))
        else:
            asg.append(park_assignment(INST, k))
    n = sum(a.kind == "target" for a in asg)
    return Configuration(index, tuple(asg), n, n, "optimal")


def _targets_of(config: Configuration) -> set[str]:
    return {a.target_id for a in config.assignments if a.kind == "target"}


@pytest.mark.parametrize("goal", [DEEP_PAIRS, PARKED_NEIGHBOURS], ids=["deep-pairs", "parked-neighbours"])
def test_evasion_plans_legs_no_delay_schedule_can(goal):
    """The straight-move CSP has no schedule for these legs; with evasion options it has one,
    and the verifier accepts it (stops <= 1)."""
    goal = _exact(goal)
    geoms = [ArmGeom.of(INST, k) for k in range(INST.n_arms)]
    straight = plan_motion(INST, PARK, goal, strategies=("delays",), time_budget_s=20.0)
    assert straight.status == "failed"
    res = plan_evasion(geoms, PARK, goal, dt_s=6.0, dt_col_s=0.1, horizon_s=220.0, buffer_mm=5.0,
                       movable=list(range(INST.n_arms)), stats=DelayStats(), deadline=time.perf_counter() + 60)
    assert res.assignment is not None
    assert any(res.options[k][p].kind in ("detour", "aside") for k, (p, _) in res.assignment.items())
    trajs = delay_trajectories(res.assignment, res.options, INST.n_arms, 6.0)
    rep = verify_trajectories(INST, trajs, PARK, goal, max_start_stop=1)
    assert rep.ok, rep.violations[:3]


def test_reversed_and_via_park_legs_pass_the_verifier():
    """c -> park as the reversal of park -> c, and c1 -> park -> c2, re-checked independently."""
    c1 = _exact(DEEP_PAIRS)
    c2 = PARK.copy()
    c2[[3, 6]] = [[2.5, 0.3], [2.4, 0.2]]
    a = plan_motion(INST, PARK, c1, time_budget_s=30.0)
    b = plan_motion(INST, PARK, c2, time_budget_s=30.0)
    assert a.status == b.status == "ok"
    start = np.array([[t.theta1_rad[-1], t.theta2_rad[-1]] for t in a.trajectories])
    back = reversed_leg(INST, a, start)
    assert back is not None and back.stats["strategy"] == "reversed"
    assert verify_trajectories(INST, back.trajectories, start, PARK, max_start_stop=1).ok
    ends = np.array([[t.theta1_rad[-1], t.theta2_rad[-1]] for t in back.trajectories])
    np.testing.assert_allclose(ends[:, 0], PARK[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.mod(ends[:, 1] + 1e-9, 2 * np.pi) - 1e-9, PARK[:, 1], atol=1e-9)
    via = via_park_leg(INST, a, b, start, c2, b.stats["lower_bound_s"])
    assert via is not None
    rep = verify_trajectories(INST, via.trajectories, start, c2, max_start_stop=3)
    assert rep.ok
    assert via.makespan_s == pytest.approx(a.makespan_s + b.makespan_s)


def test_reversal_of_a_broken_plan_is_refused():
    """A leg composed of pieces is verified as a whole: a plan whose arms pass through each
    other cannot come back as a reversed leg."""
    goal = _exact(DEEP_PAIRS)
    T = 120.0
    trajs = tuple(ArmTrajectory(k, np.array([0.0, T]), np.array([PARK[k, 0], goal[k, 0]]),
                                np.array([PARK[k, 1], goal[k, 1]])) for k in range(INST.n_arms))
    assert not verify_trajectories(INST, trajs, PARK, goal).ok  # all arms at once collide
    naive = MotionPlan("ok", T, trajs, (), {})
    assert reversed_leg(INST, naive, goal) is None


def test_unplannable_configuration_is_changed_not_returned_unverified():
    """Arm 9 must take a half turn of J2 between two disabled, parked neighbours: the planner
    finds no motion. The sequence changes the allocation (another IK branch, another arm or
    configuration) or says the plan is not executable; every leg it returns as ok passes the
    verifier."""
    inst = INST.with_arms_disabled([8, 10])
    deep = PARK.copy()
    deep[9] = [2.466865, 3.197913]
    other = PARK.copy()
    other[[2, 4]] = [[2.5, 0.3], [2.45, 0.25]]
    c1 = _configuration(0, deep, {9})
    c2 = _configuration(1, other, {2, 4})
    direct = plan_motion(inst, PARK, deep, time_budget_s=10.0)
    assert direct.status == "failed"
    sp = plan_sequence(inst, [c1, c2], SequenceOptions(seed=0, leg_time_limit_s=8.0))
    assert len(sp.legs) == len(sp.configurations) + 1
    changed = [c for c in sp.changes if c.kind in ("other_branch", "moved_target")]
    assert changed and changed[0].arms == (9,) and changed[0].target_ids == ("c0a9",)
    observed = {a.target_id: a for c in sp.configurations for a in c.assignments if a.kind == "target"}
    dropped = {u.target_id for u in sp.dropped}
    assert ("c0a9" in observed) != ("c0a9" in dropped)
    if "c0a9" in observed and observed["c0a9"].arm == 9:  # the same arm through another IK branch
        a = observed["c0a9"]
        assert abs(a.theta1_rad - deep[9, 0]) + abs(np.sin(a.theta2_rad - deep[9, 1])) > 1e-3
    assert {"c1a2", "c1a4"} <= set(observed)
    seq = [PARK] + [c.q for c in sp.configurations] + [PARK]
    start = PARK
    for i, leg in enumerate(sp.legs):
        if leg.status != "ok":
            assert not sp.executable and any(r.startswith(f"leg {i + 1} ") for r in sp.reasons)
            start = seq[i + 1]
            continue
        rep = verify_trajectories(inst, leg.trajectories, start, seq[i + 1], max_start_stop=None)
        assert rep.ok, (i, rep.violations[:3])
        start = np.array([[t.theta1_rad[-1], t.theta2_rad[-1]] for t in leg.trajectories])
    if sp.executable:
        assert not sp.failed_legs and not sp.reasons


def test_sequence_without_configurations_is_one_verified_rest():
    sp = plan_sequence(INST, [])
    assert sp.executable and len(sp.legs) == 1 and sp.legs[0].makespan_s == 0.0


def test_sequence_options_are_validated_naming_the_field():
    for kw, field in (({"leg_time_limit_s": 0.0}, "leg_time_limit_s"), ({"seed": 1.5}, "seed"),
                      ({"time_limit_s": -1.0}, "time_limit_s"), ({"max_changes": -1}, "max_changes")):
        with pytest.raises(InputError) as e:
            SequenceOptions(**kw)
        assert e.value.field == field


def test_sequence_reports_progress_per_leg():
    q = PARK.copy()
    q[[2, 4]] = [[2.5, 0.3], [2.45, 0.25]]
    seen: list[float] = []
    sp = plan_sequence(INST, [_configuration(0, q, {2, 4})], SequenceOptions(leg_time_limit_s=5.0),
                       progress=seen.append)
    assert sp.executable and len(sp.legs) == 2
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) == 2


def test_idle_arm_on_blank_sky_goes_to_park():
    """rest_at_park moves a blank-sky rest to park, collision-free, and leaves target arms alone."""
    from dataclasses import replace as dc_replace

    from models.collision import colliding_arm_pairs
    from planner.reassign import rest_at_park

    q = PARK.copy()
    q[[2, 4]] = [[2.5, 0.3], [2.45, 0.25]]
    config = _configuration(0, q, {2, 4})
    blank = dc_replace(config.assignments[3], kind="blank", theta1_rad=2.9, theta2_rad=0.1)
    asg = list(config.assignments)
    asg[3] = blank
    config = dc_replace(config, assignments=tuple(asg))
    moved = rest_at_park(INST, config, [3, 2], INST.collision_buffer_mm)
    assert moved is not None
    assert moved.assignments[3].kind == "park" and moved.assignments[2] == config.assignments[2]
    assert not colliding_arm_pairs(INST, moved.q)
    assert rest_at_park(INST, config, [2, 4], INST.collision_buffer_mm) is None  # no idle arm named
