"""One Budget object from the caller to the engines: allocate, plan_sequence and plan_motion
take the caller's budget; given one, they plan exactly what the same limit in seconds plans
(on the effort clock, where a plan depends only on its inputs), every leg's budget lies within
the sequence's, and an exhausted budget plans nothing."""

from __future__ import annotations

import numpy as np
import pytest

import planner.sequence as sequence_module
from models import clock
from models.budget import Budget
from models.errors import InputError
from models.instrument import default_instrument
from models.types import Configuration, PlaneTargets
from planner import plan_motion
from planner.sequence import MIN_LEG_S, SequenceOptions, plan_sequence
from solvers.allocation import allocate
from tests.test_sequence import _configuration

INST = default_instrument()
PARK = INST.park_configuration


def _field(n: int, seed: int) -> PlaneTargets:
    rng = np.random.default_rng(seed)
    r = 100.0 * np.sqrt(rng.random(n))
    a = 2 * np.pi * rng.random(n)
    return PlaneTargets(tuple(f"t{i}" for i in range(n)), r * np.cos(a), r * np.sin(a),
                        rng.choice([1, 10, 100, 500], size=n, p=[0.1, 0.4, 0.4, 0.1]))


def _configs() -> list[Configuration]:
    q1 = PARK.copy()
    q1[[1, 5]] = [[2.5, 0.4], [2.4, 0.3]]
    q2 = PARK.copy()
    q2[[2, 4, 9]] = [[2.5, 0.3], [2.45, 0.25], [2.3, 0.5]]
    return [_configuration(0, q1, {1, 5}), _configuration(1, q2, {2, 4, 9})]


def _legs(plan) -> list[tuple]:
    return [(leg.status, leg.failed_arms,
             tuple(np.round(t.theta1_rad, 9).tobytes() for t in leg.trajectories)) for leg in plan.legs]


def test_allocate_with_a_budget_plans_what_the_same_limit_plans() -> None:
    targets = _field(40, 3)
    with clock.effort():
        by_seconds = allocate(INST, targets, configurations="all", time_limit_s=4.0, seed=2)
    with clock.effort():
        by_budget = allocate(INST, targets, configurations="all", budget=Budget.start(4.0), seed=2)
    assert by_budget.configurations == by_seconds.configurations
    assert by_budget.unallocated == by_seconds.unallocated


def test_allocate_refuses_what_is_not_a_budget() -> None:
    with pytest.raises(InputError, match="budget"):
        allocate(INST, _field(3, 1), budget=4.0)  # type: ignore[arg-type]


def test_allocate_on_an_exhausted_budget_allocates_nothing() -> None:
    targets = _field(30, 5)
    with clock.effort():
        spent = Budget.start(0.5)
        clock.charge(1.0)
        out = allocate(INST, targets, configurations="all", budget=spent, seed=1)
    assert not out.configurations
    assert {u.reason for u in out.unallocated} <= {"no_time", "unreachable"}
    assert len(out.unallocated) == len(targets.ids)


def test_plan_motion_with_a_budget_plans_what_the_same_limit_plans() -> None:
    goal = _configs()[1]
    goal_q = np.array([[a.theta1_rad, a.theta2_rad] for a in goal.assignments])
    with clock.effort():
        by_seconds = plan_motion(INST, PARK, goal_q, time_budget_s=3.0, seed=4)
    with clock.effort():
        by_budget = plan_motion(INST, PARK, goal_q, budget=Budget.start(3.0), seed=4)
    assert by_seconds.status == "ok"
    assert _legs(type("P", (), {"legs": [by_budget]})) == _legs(type("P", (), {"legs": [by_seconds]}))


def test_plan_sequence_with_a_budget_plans_what_the_same_limit_plans() -> None:
    with clock.effort():
        by_seconds = plan_sequence(INST, _configs(), SequenceOptions(seed=3, time_limit_s=6.0))
    with clock.effort():
        by_budget = plan_sequence(INST, _configs(), SequenceOptions(seed=3), budget=Budget.start(6.0))
    assert by_seconds.executable
    assert _legs(by_budget) == _legs(by_seconds)


def test_every_leg_gets_a_child_of_the_sequence_budget(monkeypatch) -> None:
    given: list[Budget] = []
    real = sequence_module.plan_motion

    def spy(*args, budget: Budget, **kwargs):
        given.append(budget)
        return real(*args, budget=budget, **kwargs)

    monkeypatch.setattr(sequence_module, "plan_motion", spy)
    with clock.effort():
        whole = Budget.start(5.0)
        plan = plan_sequence(INST, _configs(), SequenceOptions(seed=1), budget=whole)
    assert plan.executable and len(given) >= len(plan.legs) - 1  # park -> park may be stationary
    for leg_budget in given:
        assert whole.start_s <= leg_budget.start_s
        assert leg_budget.deadline_s <= whole.deadline_s
        # a leg is started only while MIN_LEG_S of the sequence is left
        assert leg_budget.start_s <= whole.deadline_s - MIN_LEG_S


def test_an_exhausted_sequence_budget_plans_no_leg(monkeypatch) -> None:
    calls: list[Budget] = []
    monkeypatch.setattr(sequence_module, "plan_motion", lambda *a, budget, **k: calls.append(budget))
    with clock.effort():
        whole = Budget.start(MIN_LEG_S * 0.9)  # less than a leg's least time
        plan = plan_sequence(INST, _configs(), SequenceOptions(seed=1), budget=whole)
    assert not calls
    assert not plan.executable
    assert all("no time left" in why for leg in plan.legs for why in leg.stats["reasons"].values())
