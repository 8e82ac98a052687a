"""The independent trajectory verifier rejects corrupted plans and matches brute force."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from models.instrument import default_instrument
from models.types import ArmTrajectory
from planner import plan_motion, verify_trajectories

INST = default_instrument()
PARK = INST.park_configuration
GOALS = [[3.0136971541900013, 0.18301607390023514], [1.928770938121543, 2.7180407071074124]]


@pytest.fixture(scope="module")
def solved():
    inst = INST.with_arms_disabled(list(range(2, 12)))
    goal = PARK.copy()
    goal[[0, 1]] = GOALS
    plan = plan_motion(inst, PARK, goal)
    assert plan.status == "ok"
    return inst, goal, plan


def _with(plan, k, tr):
    trajs = list(plan.trajectories)
    trajs[k] = tr
    return trajs


def test_valid_plan_passes_and_pruned_equals_exhaustive(solved):
    inst, goal, plan = solved
    a = verify_trajectories(inst, plan.trajectories, PARK, goal)
    b = verify_trajectories(inst, plan.trajectories, PARK, goal, exhaustive=True)
    assert a.ok and b.ok
    assert a.min_clearance_mm == pytest.approx(b.min_clearance_mm, abs=1e-9)
    assert a.pair_samples_checked < b.pair_samples_checked


def test_rejects_collision():
    goal = PARK.copy()
    goal[0] = (1.81205646, 3.80872934)  # overlaps arm 1 resting at park
    trajs = [ArmTrajectory(k, np.array([0.0]), PARK[k, :1], PARK[k, 1:]) for k in range(12)]
    d = goal[0] - PARK[0]
    d[1] = (d[1] + np.pi) % (2 * np.pi) - np.pi
    trajs[0] = ArmTrajectory(0, np.array([0.0, 150.0]), np.array([PARK[0, 0], PARK[0, 0] + d[0]]),
                             np.array([PARK[0, 1], PARK[0, 1] + d[1]]))
    rep = verify_trajectories(INST, trajs, PARK, goal)
    assert not rep.ok
    assert any(v.kind == "collision" and v.arms == (0, 1) for v in rep.violations)


def test_rejects_speed_violation(solved):
    inst, goal, plan = solved
    tr = plan.trajectories[0]
    fast = replace(tr, t_s=tr.t_s * 0.5, commands=())
    rep = verify_trajectories(inst, _with(plan, 0, fast), PARK, goal)
    assert any(v.kind == "speed" and v.arms == (0,) for v in rep.violations)


def test_rejects_zoa_crossing():
    # arm 4 from park turning theta1 to 0 with theta2 fixed: d34 drops through the lower stop
    goal = PARK.copy()
    goal[4] = (0.3, 0.0)
    inst = INST.with_arms_disabled([k for k in range(12) if k != 4])
    tr = ArmTrajectory(4, np.array([0.0, 200.0]), np.array([PARK[4, 0], 0.3]), np.array([0.0, 0.0]))
    trajs = [ArmTrajectory(k, np.array([0.0]), PARK[k, :1], PARK[k, 1:]) for k in range(12)]
    trajs[4] = tr
    rep = verify_trajectories(inst, trajs, PARK, goal)
    kinds = {v.kind for v in rep.violations}
    assert "zoa" in kinds or "joint_limit" in kinds


def test_rejects_too_many_stops_and_wrong_goal(solved):
    inst, goal, plan = solved
    tr = plan.trajectories[0]
    q0 = np.array([tr.theta1_rad[0], tr.theta2_rad[0]])
    q1 = np.array([tr.theta1_rad[-1], tr.theta2_rad[-1]])
    pts = [q0 + f * (q1 - q0) for f in (0, 0.25, 0.5, 0.75, 1.0)]
    t = [0.0, 60.0, 70.0, 130.0, 140.0, 200.0, 210.0, 270.0]
    q = [pts[0], pts[1], pts[1], pts[2], pts[2], pts[3], pts[3], pts[4]]
    stoppy = ArmTrajectory(0, np.array(t), np.array([p[0] for p in q]), np.array([p[1] for p in q]))
    rep = verify_trajectories(inst, _with(plan, 0, stoppy), PARK, goal, max_start_stop=1)
    assert any(v.kind == "stops" for v in rep.violations)
    wrong = replace(tr, theta1_rad=tr.theta1_rad.copy())
    wrong.theta1_rad[-1] -= 0.01
    rep = verify_trajectories(inst, _with(plan, 0, wrong), PARK, goal)
    assert any(v.kind == "goal" for v in rep.violations)


def test_rejects_missing_arm(solved):
    inst, goal, plan = solved
    rep = verify_trajectories(inst, plan.trajectories[1:], PARK, goal)
    assert not rep.ok and rep.violations[0].kind == "structure"
