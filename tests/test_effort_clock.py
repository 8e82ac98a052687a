"""The effort clock (models.clock): budgets counted in work, so that a search stops at the
same point whatever the machine's speed or load; and the motion planner and a plan's
pointing on it."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from models import clock
from models.instrument import default_instrument
from planner import plan_motion, pointing, programme
from planner import timeline as timeline_module
from planner.effort import PLANNER_WORK_S
from planner.kernels import compile_kernels
from planner.programme import RoundTask
from service import pipeline, pointing_plans
from service.errors import json_safe
from service.schemas import PlanRequest

INST = default_instrument()
LEGS = json.loads((Path(__file__).parent / "data" / "motion_legs.json").read_text())["legs"]


@pytest.fixture(scope="module", autouse=True)
def _compiled() -> None:
    compile_kernels()


# ------------------------------------------------------------------------------ the clock


def test_outside_effort_the_clock_is_the_wall_clock() -> None:
    assert not clock.in_effort() and clock.effort_clock() is None
    a = clock.now()
    time.sleep(0.02)
    assert 0.015 < clock.now() - a < 1.0
    clock.charge(100.0)  # no effect on the wall clock
    clock.work("departure", 1e9)
    assert clock.now() - a < 1.0


def test_the_effort_clock_advances_by_charges_and_readings_only() -> None:
    with clock.effort(tally=True) as c:
        assert clock.in_effort() and clock.effort_clock() is c
        t0 = clock.now()
        time.sleep(0.05)  # real time does not count
        assert clock.now() - t0 == pytest.approx(clock.TICK_S)
        clock.charge(2.5)
        assert clock.now() - t0 == pytest.approx(2.5 + 2 * clock.TICK_S)
        per_call_s, per_unit_s = PLANNER_WORK_S["departure"]
        before = c.t_s
        clock.work("departure", 100)
        clock.work("departure", 50)
        assert c.t_s - before == pytest.approx(2 * per_call_s + 150 * per_unit_s)
        assert c.tally["departure"] == (2, 150.0)
        assert c.reads == 3
    assert not clock.in_effort()


def test_work_is_priced_by_the_registered_tables_and_an_unknown_kind_is_an_error(monkeypatch) -> None:
    """Each layer registers its own cost table; a kind nobody registered costs nothing on the
    wall clock and raises inside ``effort()`` (a misspelt kind cannot make work free)."""
    monkeypatch.setattr(clock, "_COST_TABLES", dict(clock._COST_TABLES))  # this test's kinds stay here
    clock.work("no_such_kind", 5)  # the wall clock: nothing to price
    table = {"test_only_kind": (0.5, 0.25)}
    clock.register_work_costs(table)
    clock.register_work_costs(table)  # the same table again: nothing changes
    with pytest.raises(ValueError):
        clock.register_work_costs({"test_only_kind": (1.0, 0.0)})  # another layer's kind
    with pytest.raises(ValueError):
        clock.register_work_costs({"test_bad_kind": (-1.0, 0.0)})
    with clock.effort(tally=True) as c:
        clock.work("test_only_kind", 4)
        assert c.t_s == pytest.approx(0.5 + 0.25 * 4)
        assert c.tally["test_only_kind"] == (1, 4.0)
        with pytest.raises(KeyError, match="no_such_kind"):
            clock.work("no_such_kind", 5)
    # the planner's and the allocator's tables are registered by importing their layers
    from solvers.effort import INCOMPATIBILITY_WORK_S
    with clock.effort() as c:
        for kind, (per_call_s, per_unit_s) in {**PLANNER_WORK_S, **INCOMPATIBILITY_WORK_S}.items():
            before = c.t_s
            clock.work(kind, 10)
            assert c.t_s - before == pytest.approx(per_call_s + 10 * per_unit_s)


def test_nested_effort_blocks_have_their_own_clock_and_restore_the_outer_one() -> None:
    with clock.effort() as outer:
        clock.charge(7.0)
        with clock.effort() as inner:
            assert clock.effort_clock() is inner and inner.t_s == 0.0
            clock.charge(1.0)
        assert clock.effort_clock() is outer and outer.t_s == pytest.approx(7.0)


def test_the_effort_clock_belongs_to_its_thread() -> None:
    seen = []
    with clock.effort():
        t = threading.Thread(target=lambda: seen.append(clock.in_effort()))
        t.start()
        t.join()
    assert seen == [False]


def test_past_the_wall_limit_every_earlier_deadline_has_passed() -> None:
    with clock.effort(wall_limit_s=0.05) as c:
        deadline = clock.now() + 1000.0  # a budget the effort clock alone would never exhaust
        assert clock.now() < deadline and not c.overran
        time.sleep(0.08)
        assert clock.now() > deadline and c.overran
        later = clock.now() + 1000.0
        assert clock.now() > later  # and every reading after it, too


# ------------------------------------------------------------------- the motion planner


def _slow_departures(monkeypatch, sleep_s: float) -> list[int]:
    """The planner's departure search made ``sleep_s`` slower per call (as on a busy
    machine); the returned list counts the calls."""
    original = timeline_module._first_departure
    calls = [0]

    def slow(*args):
        calls[0] += 1
        time.sleep(sleep_s)
        return original(*args)

    monkeypatch.setattr(timeline_module, "_first_departure", slow)
    return calls


def _signature(plan) -> tuple:
    """Everything a plan says, as comparable values (NaN-free)."""
    trajectories = tuple((tr.arm, tuple(np.round(tr.t_s, 9)), tuple(np.round(tr.theta1_rad, 9)),
                          tuple(np.round(tr.theta2_rad, 9))) for tr in plan.trajectories)
    return (plan.status, json.dumps(json_safe(plan.stats), sort_keys=True), trajectories,
            tuple(plan.failed_arms))


def _plan(leg: dict, budget_s: float):
    with clock.effort(wall_limit_s=120.0) as c:
        plan = plan_motion(INST, np.array(leg["start_q"]), np.array(leg["goal_q"]), seed=0,
                           time_budget_s=budget_s)
    assert not c.overran
    return plan


@pytest.mark.parametrize("index", [1, 4])
def test_a_leg_on_the_effort_clock_is_the_same_on_a_slower_machine(index, monkeypatch) -> None:
    """Two regression legs whose 1 s budget binds (a 3 s budget gives another answer): on the
    effort clock the plan, its stats included, does not change when the machine is slower."""
    leg = LEGS[index]
    fast = _plan(leg, 1.0)
    assert _signature(fast) != _signature(_plan(leg, 3.0))  # the budget binds
    calls = _slow_departures(monkeypatch, 0.002)
    t0 = time.perf_counter()
    slowed = _plan(leg, 1.0)
    assert calls[0] > 50 and time.perf_counter() - t0 > 0.1  # really slowed down
    assert _signature(slowed) == _signature(fast)


# --------------------------------------------------------------------- a plan's pointing


def _content(v):
    if isinstance(v, dict):
        return {k: _content(x) for k, x in v.items() if k != "stats"}
    if isinstance(v, list):
        return [_content(x) for x in v]
    return v


def _pointing(share_s: float) -> dict:
    rng = np.random.default_rng(11)
    prio = rng.choice([500, 100, 10, 1], size=40, p=[0.1, 0.4, 0.4, 0.1])
    ra = 150.0 + rng.normal(0.0, 0.012, 40)
    dec = 20.0 + rng.normal(0.0, 0.012, 40)
    targets = [{"id": f"t{i}", "ra_deg": float(a), "dec_deg": float(d), "priority": int(p)}
               for i, (a, d, p) in enumerate(zip(ra, dec, prio, strict=True))]
    req = PlanRequest.model_validate({"targets": targets, "seed": 4})
    seg = pipeline.segment_plan(req, INST)
    assert len(seg.pointings) == 1
    task = pointing_plans.pointing_task(req, seg, RoundTask(0, 1, share_s))
    return json.loads(json.dumps(json_safe(pointing_plans.pointing_result(task, INST))))


def test_a_pointing_is_planned_the_same_on_a_slower_machine(monkeypatch) -> None:
    """A pointing whose budgets bind (a longer share gives another plan): the same plan when
    the machine is slower. The pointing searches on a quarter of its share here, so that the
    wall-clock share, which a loaded test machine may approach, is never what stops it."""
    monkeypatch.setattr(pointing, "SHARES", replace(programme.SHARES, effort_share=0.25))
    fast = _pointing(6.0)
    assert _content(fast) != _content(_pointing(12.0))
    calls = _slow_departures(monkeypatch, 0.002)
    slowed = _pointing(6.0)
    assert calls[0] * 0.002 > 0.5  # at least half a second slower
    assert not fast["stats"]["effort"]["overran"] and not slowed["stats"]["effort"]["overran"]
    assert _content(slowed) == _content(fast)
    assert slowed["stats"]["effort"]["effort_s"] == fast["stats"]["effort"]["effort_s"]
