"""The plan's consolidation (planner.consolidation, service.plan_consolidation): after the
rounds, exposures emptied into the idle arms of the plan's other exposures, the changed
pointings planned again and kept only when better.

Oracles: the independent verifier (planner.validate.validate_plan: every configuration and
trajectory re-checked), the same plan with the consolidation's plans refused (what the rounds
alone gave), forward kinematics and FCL on the regrouped allocations."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

import planner.consolidation as consolidation
from benchmarks import programme_time as PT
from models import clock
from models.budget import Budget
from models.instrument import default_instrument
from models.sky import sky_to_focal_mm
from models.types import ArmAssignment, Configuration
from planner.consolidation import (
    PlannedPointing,
    accepted,
    affordable,
    consolidation_tasks,
    costs,
    left_s,
    regroup,
    replan_costs,
    retry_tasks,
)
from planner.programme import SHARES, PointingOutcome, RoundTask, better, usable_s
from planner.validate import validate_plan
from service import pipeline, plan_consolidation, pointing_plans
from service.schemas import PlanRequest
from solvers.programme.fill import within
from tests.plan_jobs import plan_job_result
from tests.test_programme_consolidate import LIMIT_S, _check_exposures, _overlapping

INST = default_instrument()
#: the module's tests share its module-scoped plans: one pytest-xdist worker runs them all
pytestmark = pytest.mark.xdist_group("test_plan_consolidation")
#: a small scattered programme whose plan has an exposure the consolidation empties (20 targets)
PROGRAMME = ("scattered", 18)
REQUEST = {"seed": 18, "segmentation_mode": "fewest-exposures", "time_limit_s": 20}


def _request() -> dict[str, Any]:
    prog = PT.generated([PROGRAMME], n_range=(20, 20))[0]
    return {**REQUEST, "targets": prog["targets"]}


@pytest.fixture(scope="module")
def plans() -> tuple[dict[str, Any], dict[str, Any]]:
    """The plan, and the same plan with the consolidation's plans refused."""
    req = PlanRequest.model_validate(_request())
    plan = pipeline.plan(req, INST)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plan_consolidation, "accepted", lambda *a: False)
        rounds_only = pipeline.plan(req, INST)
    return plan, rounds_only


def _observed(plan: dict[str, Any]) -> list[str]:
    return sorted(a["target_id"] for p in plan["pointings"] for c in p["configurations"] for a in c["assignments"]
                  if a["target_id"] is not None)


def test_the_plan_takes_fewer_exposures_and_observes_every_target(plans) -> None:
    plan, rounds_only = plans
    c = plan["stats"]["consolidation"]
    assert c["accepted"] and c["exposures_emptied"] >= 1 and c["exposures_saved"] >= 1
    assert plan["stats"]["configurations"] == rounds_only["stats"]["configurations"] - c["exposures_saved"]
    assert _observed(plan) == _observed(rounds_only) == sorted(t["id"] for t in _request()["targets"])
    assert plan["executable"] and validate_plan(INST, plan).valid
    assert plan["stats"]["exposures_gap"] < rounds_only["stats"]["exposures_gap"]


def test_each_pointing_lists_what_it_observes(plans) -> None:
    plan, _ = plans
    ids = [t for p in plan["pointings"] for t in p["target_ids"]]
    assert sorted(ids) == sorted(t["id"] for t in _request()["targets"])  # a partition
    for p in plan["pointings"]:
        seen = {a["target_id"] for c in p["configurations"] for a in c["assignments"] if a["target_id"]}
        assert seen <= set(p["target_ids"])


def test_refused_plans_leave_the_rounds_plan(plans) -> None:
    _, rounds_only = plans
    c = rounds_only["stats"]["consolidation"]
    assert not c["accepted"] and c["exposures_emptied"] >= 1 and "reason" in c
    assert rounds_only["executable"] and validate_plan(INST, rounds_only).valid


#: a small programme for the job flow (two pointings, 12 targets)
JOB_PROGRAMME = ("two-clump", 3)
JOB = {"seed": 3, "segmentation_mode": "fewest-exposures", "time_limit_s": 20}


def _job_body() -> dict[str, Any]:
    return {**JOB, "targets": PT.generated([JOB_PROGRAMME], n_range=(12, 12))[0]["targets"]}


def test_a_plan_job_gives_the_synchronous_plan(tmp_path) -> None:
    """The plan job's flow consolidates its plan as the synchronous plan does: the same
    pointings and exposures, the same passes, a verified plan."""
    body = _job_body()
    plan = pipeline.plan(PlanRequest.model_validate(body), INST)
    result = plan_job_result(tmp_path, body, 20.0)
    assert [(p["target_ids"], len(p["configurations"])) for p in result["pointings"]] == \
        [(p["target_ids"], len(p["configurations"])) for p in plan["pointings"]]
    assert len(result["pointings"]) >= 2
    passes = result["stats"]["consolidation"]["passes"]
    assert passes and [p["pointings"] for p in passes] == \
        [p["pointings"] for p in plan["stats"]["consolidation"]["passes"]]
    assert result["executable"] and validate_plan(INST, result).valid


# ------------------------------------------------------------------------ the domain parts


def _planned(f, pts) -> list[PlannedPointing]:
    out = []
    for p in pts:
        configs = tuple(Configuration(c.index, tuple(
            a if a.target_index is None else ArmAssignment(a.arm, a.kind, a.theta1_rad, a.theta2_rad, a.x_mm, a.y_mm,
                                                           int(p.members[a.target_index]),
                                                           str(int(p.members[a.target_index])))
            for a in c.assignments), c.total_priority, c.arm_yield, c.status) for c in p.allocation.configurations)
        out.append(PlannedPointing(p.centre, p.pa_deg, configs, {}))
    return out


def test_regroup_gives_allocations_of_the_new_members() -> None:
    """Regrouped allocations, read back as the optimiser's pointings, pass the checks of
    tests/test_programme_consolidate.py, and every target is observed once."""
    from solvers.programme.fill import Pointing

    for seed in (1, 4):
        f, pts = _overlapping(seed)
        saved, _, changed = regroup(INST, f.ra_deg, f.dec_deg, f.priority, _planned(f, pts), LIMIT_S, None,
                                    Budget.start(30.0))
        assert saved >= 1 and changed
        new = list(pts)
        for r in changed:
            new[r.index] = Pointing(pts[r.index].centre, pts[r.index].pa_deg, np.array(r.members, np.int64),
                                    len(r.allocation.configurations), allocation=r.allocation)
            assert r.allocation.stats["n_targets"] == len(r.members)
        assert sum(p.exposures for p in new) == sum(p.exposures for p in pts) - saved
        observed = sorted(int(p.members[a.target_index]) for p in new for c in p.allocation.configurations
                          for a in c.assignments if a.target_index is not None)
        assert observed == list(range(18))
        _check_exposures(f, new)


def _outcome(i: int, effort_s: float, share_s: float, allocation_s: float = 0.0,
             overran: bool = False) -> PointingOutcome:
    return PointingOutcome(i, 1, share_s, effort_s, True, 0, 10, overran, True, allocation_s)


def test_costs_and_what_is_left_count_as_the_rounds_do() -> None:
    """A pointing costs what its motion legs spent (its allocation is not searched again), the
    most of its rounds; a round the wall guard stopped, its share; what is left counts every
    round's whole effort, at face value (the rounds' margin for a slower machine is the
    consolidation's to spend), where the rounds count it over their effort share."""
    history = [[_outcome(0, 8.0, 40.0, 2.0), _outcome(1, 4.0, 40.0, 3.0), _outcome(2, 5.0, 6.0, 1.0, True)],
               [_outcome(0, 16.0, 30.0, 12.0)]]
    e, c = SHARES.effort_share, SHARES.consolidation_effort_share
    assert c == 1.0 and e < c
    assert costs(history) == {0: pytest.approx(6.0 / e), 1: pytest.approx(1.0 / e), 2: 6.0}
    assert left_s(120.0, history, 1.0) == pytest.approx(usable_s(120.0) - 28.0 - 6.0 - 1.0)
    rounds_count = sum(o.spent_s() for outcomes in history for o in outcomes)
    assert rounds_count == pytest.approx(28.0 / e + 6.0)  # the rounds' own count keeps the margin


def test_consolidation_tasks_give_each_pointing_at_least_what_it_spent() -> None:
    cost = {0: 20.0, 1: 5.0, 2: 0.1}
    tasks = consolidation_tasks(cost, 51.0, 3, [2, 0])
    assert [t.index for t in tasks] == [0, 2] and all(t.round == 3 for t in tasks)
    assert sum(t.share_s for t in tasks) == pytest.approx(51.0)
    assert tasks[0].share_s >= 20.0 and tasks[1].share_s >= SHARES.min_pointing_s
    assert tasks[0].share_s / tasks[1].share_s == pytest.approx(20.0 / SHARES.min_pointing_s)
    assert consolidation_tasks(cost, 20.0, 3, [0, 2]) == []  # 20.5 needed
    assert consolidation_tasks(cost, 51.0, 3, []) == []


def _tried(i: int, round_: int, share_s: float, effort_s: float, executable: bool) -> PointingOutcome:
    return PointingOutcome(i, round_, share_s, effort_s, executable, 0 if executable else 1, 10, False, True, 0.0)


def test_a_changed_pointing_with_a_failed_leg_is_planned_again_on_what_is_left() -> None:
    """Only the pointings whose best plan of the pass failed, on everything the rounds, the
    pass and its plans left (counted here from the outcomes, as next_round counts a round),
    split by cost, the next round number; none once every one is executable, when too little
    is left, or after ``rounds`` plans."""
    history = [[_outcome(0, 8.0, 40.0, 2.0), _outcome(1, 4.0, 40.0, 3.0), _outcome(2, 4.0, 20.0, 1.0)]]
    cost = costs(history)
    first = [_tried(0, 2, 10.0, 6.0, True), _tried(1, 2, 3.0, 2.4, False), _tried(2, 2, 5.0, 4.0, False)]
    tasks = retry_tasks(cost, 120.0, history, 0.5, [first])
    left = usable_s(120.0) - 16.0 - 0.5 - 12.4  # every outcome's effort at face value
    assert [t.index for t in tasks] == [1, 2] and {t.round for t in tasks} == {3}
    assert sum(t.share_s for t in tasks) == pytest.approx(left)
    assert tasks[1].share_s / tasks[0].share_s == pytest.approx(cost[2] / cost[1])
    # a pointing whose earlier plan of the pass was executable is not planned again
    second = [_tried(1, 3, tasks[0].share_s, 1.0, True), _tried(2, 3, tasks[1].share_s, 2.0, False)]
    assert [t.index for t in retry_tasks(cost, 120.0, history, 0.5, [first, second])] == [2]
    assert [t.index for t in retry_tasks(cost, 120.0, history, 0.5, [first, [_tried(2, 3, 9.0, 2.0, True)]])] == [1]
    assert retry_tasks(cost, 120.0, history, 0.5, [[_tried(1, 2, 3.0, 2.4, True)]]) == []
    assert retry_tasks(cost, 30.0, history, 0.5, [first]) == []  # the rounds left too little
    assert retry_tasks(cost, 120.0, history, 0.5, [first] * SHARES.rounds) == []
    assert retry_tasks(cost, 120.0, history, 0.5, []) == []
    # an executable plan with an exposure the motion planner added is planned again, once
    added = [dataclasses.replace(_tried(1, 2, 3.0, 2.4, True), exposures=5, exposures_added=1)]
    again = retry_tasks(cost, 120.0, history, 0.5, [added])
    assert [(t.index, t.round) for t in again] == [(1, 3)]
    assert retry_tasks(cost, 120.0, history, 0.5, [added, [dataclasses.replace(added[0], round=3)]]) == []
    # a second plan without the addition is the better one, so nothing is due after it
    fewer = dataclasses.replace(added[0], round=3, exposures=4, exposures_added=0)
    assert better(fewer, added[0]) and not better(added[0], fewer)
    assert not better(dataclasses.replace(added[0], round=3), added[0])  # a tie keeps the old


def test_the_pass_plans_a_failed_pointing_again_and_keeps_its_best_plan(monkeypatch) -> None:
    """service.plan_consolidation's loop: every task planned, the failed one again on the
    tasks the policy gives for the outcomes so far, each pointing's best plan kept with every
    outcome recorded."""
    calls = []

    def result(task, inst, progress=None, *, wall_limit_s=None):
        calls.append((task.index, task.round))
        ok = task.index != 1 or task.round >= 4
        out = PointingOutcome(task.index, task.round, task.share_s, 0.5 * task.share_s, ok, 0 if ok else 2, 10)
        return {"id": f"P{task.index}", "executable": ok, "stats": {"rounds": [pointing_plans.outcome_out(out)]}}

    monkeypatch.setattr(pointing_plans, "pointing_result", result)
    monkeypatch.setattr(pointing_plans, "pointing_task", lambda req, seg, t, known=None: t)
    seen = []

    def again(tries):
        seen.append([(o.index, o.round, o.executable) for o in tries[-1]])
        failed = [o.index for o in tries[-1] if not o.executable]
        return [RoundTask(i, tries[-1][0].round + 1, 4.0) for i in failed]

    new, tries = plan_consolidation._replanned(None, INST, None, [RoundTask(0, 3, 2.0), RoundTask(1, 3, 2.0)],
                                               {}, lambda: 100.0, again)
    assert calls == [(0, 3), (1, 3), (1, 4)]
    assert seen == [[(0, 3, True), (1, 3, False)], [(1, 4, True)]]
    assert [[(o.index, o.round, o.executable) for o in t] for t in tries] == seen
    assert new[0]["executable"] and new[1]["executable"]
    assert [r["round"] for r in new[1]["stats"]["rounds"]] == [3, 4]


def test_affordable_leaves_the_costliest_pointing_out_until_the_rest_fits() -> None:
    """Both pointings change when time is plenty; with less left than their new legs cost, the
    pass runs with the cheapest legs first, and when that does not fit either, the costlier
    pointing is left out (it neither gives nor takes): what changes fits."""
    costs_s = {0: 9.0, 1: 1.0}
    for seed in (1, 3, 4):
        f, pts = _overlapping(seed)
        planned = _planned(f, pts)
        args = (INST, f.ra_deg, f.dec_deg, f.priority, planned, LIMIT_S, None)
        free = regroup(*args, Budget.start(30.0))
        assert affordable(*args, Budget.start(30.0), costs_s, math.inf) == free
        assert {r.index for r in free[2]} == {0, 1}, "premise: the pass changes both"

        def cost(changed, planned=planned):
            return sum(max(v, 0.5) for v in replan_costs(costs_s, planned, changed).values())

        thrifty = regroup(*args, Budget.start(30.0), per_leg_s={j: costs_s[j] / (len(p.configurations) + 1)
                                                              for j, p in enumerate(planned)})
        alone = regroup(*args, Budget.start(30.0), frozen=frozenset({0}))
        assert cost(alone[2]) < min(cost(free[2]), cost(thrifty[2])), "premise: pointing 1 alone costs less"
        saved, _, changed = affordable(*args, Budget.start(30.0), costs_s, cost(alone[2]))
        assert all(r.index == 1 for r in changed) and saved == alone[0]
        assert affordable(*args, Budget.start(30.0), costs_s, 0.1) == (0, 0, [])


def test_affordable_spends_nothing_when_no_pointing_could_be_planned_again(monkeypatch) -> None:
    """With less left than one pointing's least plan, no change fits: the pass returns at once
    (no regroup runs, no placement is charged); with that much left it searches."""
    f, pts = _overlapping(1)
    planned = _planned(f, pts)
    args = (INST, f.ra_deg, f.dec_deg, f.priority, planned, LIMIT_S, None)
    runs = []
    real = consolidation.regroup
    monkeypatch.setattr(consolidation, "regroup", lambda *a, **k: runs.append(1) or real(*a, **k))
    least = SHARES.min_pointing_s
    with clock.effort(wall_limit_s=60.0) as effort:
        assert consolidation.affordable(*args, Budget.start(30.0), {0: 0.1, 1: 0.1}, 0.99 * least) == (0, 0, [])
    assert runs == []
    with clock.effort(wall_limit_s=60.0) as searched:
        saved, _, changed = consolidation.affordable(*args, Budget.start(30.0), {0: 0.1, 1: 0.1}, 2 * least)
    assert runs and changed and saved == regroup(*args, Budget.start(30.0))[0]
    assert effort.t_s < 0.01 * searched.t_s  # a clock read, against the pass's placements


def test_accepted_needs_every_plan_executable_every_target_and_fewer_exposures() -> None:
    old, new = [{"a", "b"}, {"c"}], [{"a"}, {"b", "c"}]
    assert accepted(old, new, 3, 2, [True, True])
    assert not accepted(old, new, 3, 3, [True, True])  # not fewer
    assert not accepted(old, new, 3, 2, [True, False])  # a failed leg
    assert not accepted(old, [{"a"}, {"c"}], 3, 2, [True, True])  # b lost
    # as many exposures: kept only with fewer targets in exposures observing few
    assert accepted(old, new, 3, 3, [True, True], old_few=4, new_few=3)
    assert not accepted(old, new, 3, 3, [True, True], old_few=3, new_few=3)
    assert not accepted(old, new, 3, 4, [True, True], old_few=4, new_few=0)
    assert accepted(old, new, 3, 2, [True, True], old_few=0, new_few=2)  # an exposure fewer wins


def test_few_observed_counts_targets_in_exposures_of_at_most_two() -> None:
    from planner.consolidation import few_observed

    assert few_observed([12, 3, 2, 1, 0]) == 3
    assert few_observed([5, 2], few=5) == 7 and few_observed([]) == 0


def test_every_round_records_what_its_allocation_took(plans) -> None:
    """A round's outcome says how much of its effort the allocation took (the consolidation
    prices a pointing's second plan by the rest), and reads back from the answer as it was."""
    plan, _ = plans
    rounds = [r for p in plan["pointings"] for r in p["stats"]["rounds"]]
    assert rounds
    for r in rounds:
        assert 0.0 < r["allocation_effort_s"] <= r["effort_s"]
    for i, p in enumerate(plan["pointings"]):
        back = pointing_plans.outcomes_of(p, i)
        assert [o.allocation_effort_s for o in back] == [r["allocation_effort_s"] for r in p["stats"]["rounds"]]
        assert [(o.exposures, o.exposures_added) for o in back] == [
            (r["exposures"], r["exposures_added"]) for r in p["stats"]["rounds"]]
        # the plan returned is one of its rounds', with its exposures and the motion planner's additions
        assert (len(p["configurations"]), p["stats"]["motion"]["configurations_added"]) in [
            (o.exposures, o.exposures_added) for o in back]


def test_the_cli_summary_says_what_the_consolidation_saved(plans) -> None:
    from service.cli import exposures_summary

    plan, rounds_only = plans
    saved = plan["stats"]["consolidation"]["exposures_saved"]
    line = exposures_summary(plan["stats"])
    assert line.startswith(f"{plan['stats']['configurations']} exposure")
    assert f"{saved} exposure{'' if saved == 1 else 's'} saved by moving targets onto idle arms" in line
    assert "saved" not in exposures_summary(rounds_only["stats"])


def test_the_cli_summary_counts_the_targets_another_exposure_could_take_and_why_they_stay() -> None:
    from service.cli import exposures_summary

    stats = {"configurations": 10, "few_target_exposures": 4, "few_target_exposures_only_here": 1,
             "few_target_exposures_explained": 2,
             "consolidation": {"accepted": False, "reason": "no time left to plan a changed pointing"}}
    line = exposures_summary(stats)
    assert "4 exposures observing at most 2 targets, 1 of them only for targets no other exposure can take" in line
    assert "1 more for targets only exposures of 1 target can take" in line
    assert "2 with a target another exposure could take (only_here, could_move_to in plan.json)" in line
    assert line.endswith("; the consolidation stopped: no time left to plan a changed pointing")
    every = exposures_summary({**stats, "few_target_exposures_explained": 4})
    assert "could" not in every and "stopped" not in every and "(only_here in plan.json)" in every


def test_the_cli_summary_splits_the_optimisers_time() -> None:
    from service.cli import exposures_summary

    seg = {"time_s": 4.12, "own_time_s": 1.15, "allocations_kept_s": 2.97, "pointings_allocated_once": 6}
    line = exposures_summary({"configurations": 32, "segmentation": seg})
    assert line.endswith("; the programme optimiser took 4.1 s: 1.1 s its own and 3.0 s allocating 6 pointings "
                         "the plan observes as allocated there")
    alone = exposures_summary({"configurations": 32, "segmentation": {**seg, "pointings_allocated_once": 0}})
    assert "optimiser" not in alone and "optimiser" not in exposures_summary({"configurations": 32})


def test_only_programme_optimiser_plans_without_kept_configurations_are_consolidated() -> None:
    from planner.consolidation import applies

    assert applies("fewest-exposures", False)
    assert not applies("fewest-exposures", True)
    assert not applies("complete-linkage", False) and not applies("balanced", False)


def test_a_complete_linkage_plan_has_no_consolidation() -> None:
    req = PlanRequest.model_validate({**_job_body(), "segmentation_mode": "complete-linkage"})
    assert "consolidation" not in pipeline.plan(req, INST)["stats"]


def test_the_pass_runs_again_while_it_is_accepted() -> None:
    from planner.consolidation import MAX_PASSES, another_pass

    assert another_pass([]) and another_pass([True]) and another_pass([True] * (MAX_PASSES - 1))
    assert not another_pass([True, False]) and not another_pass([False])
    assert not another_pass([True] * MAX_PASSES)
    # a refused pass whose failed pointings the next one leaves out runs again; one with none does not
    no = frozenset()
    assert another_pass([True, False], left_out=[no, frozenset({3})])
    assert not another_pass([False, False], left_out=[frozenset({3}), no])
    assert another_pass([False, False], left_out=[frozenset({3}), frozenset({1})])
    assert not another_pass([False] * MAX_PASSES, left_out=[frozenset({k}) for k in range(MAX_PASSES)])


def test_each_pass_runs_on_what_the_earlier_passes_left(monkeypatch) -> None:
    """service.plan_consolidation's passes: each on the plan the accepted pass before it left,
    with the outcomes of every earlier pass's plans and what their own work took counted as
    spent; the stats sum the accepted passes and keep each pass's own."""
    from planner.consolidation import pass_wall_s

    rounds = [[PointingOutcome(0, 1, 10.0, 8.0, True, 0, 10)]]
    seen = []

    def one(req, inst, seg, answers, history, limit_s, wall_left_s, spent_s, frozen):
        k = len(seen)
        seen.append((seg, len(history), spent_s))
        assert frozen == frozenset()
        tries = [[PointingOutcome(0, len(history) + 1, 2.0, 1.0, True, 0, 10)]]
        stats = {"exposures_emptied": k + 1, "targets_moved_from_few": k, "effort_s": 0.5 * (k + 1),
                 "pointings": [f"P{k}"], "accepted": k < 2}
        if k < 2:
            return f"seg{k + 1}", answers, {**stats, "exposures_saved": k + 1}, tries, frozenset()
        return seg, answers, {**stats, "reason": "the changed pointings' plans were not better"}, tries, frozenset()

    monkeypatch.setattr(plan_consolidation, "_pass", one)
    monkeypatch.setattr(pointing_plans, "plan_mode", lambda req: "fewest-exposures")
    req = PlanRequest.model_validate(_request())
    seg, _, stats = plan_consolidation.consolidated(req, INST, "seg0", [], rounds, 100.0, lambda: 50.0)
    assert seg == "seg2"  # the last accepted pass's plan
    assert seen == [("seg0", 1, 0.0), ("seg1", 2, pass_wall_s(0.5)), ("seg2", 3, pass_wall_s(0.5) + pass_wall_s(1.0))]
    c = stats["consolidation"]
    assert c["accepted"] and c["exposures_saved"] == 3 and c["exposures_emptied"] == 3
    assert c["targets_moved_from_few"] == 1
    assert c["pointings"] == ["P0", "P1"] and "reason" not in c
    assert c["effort_s"] == pytest.approx(3.0) and len(c["passes"]) == 3
    assert c["passes"][2]["reason"] and not c["passes"][2]["accepted"]




def test_a_plan_names_an_exposure_that_could_take_each_target_it_does_not_explain(plans) -> None:
    """Every target of an exposure observing few is either explained (`only_here`) or named
    with an exposure that could take it (`could_move_to`); FCL and the park move checked on
    that exposure's idle arms (tests.test_spare_arms' brute force) agree that it could, and it
    observes at least 2 targets unless the exposure it would leave observes 1."""
    from tests.test_spare_arms import LIMIT_S as BRUTE_LIMIT_S
    from tests.test_spare_arms import _brute_force

    assert PlanRequest.model_validate(_request()).park_move_limit_s == BRUTE_LIMIT_S
    sky = {t["id"]: (t["ra_deg"], t["dec_deg"]) for t in _request()["targets"]}
    named = 0
    for plan in plans:
        configs = {(p["id"], c["index"]): (p, c) for p in plan["pointings"] for c in p["configurations"]}
        for f in plan["few_target_exposures"]:
            listed = [o["target_id"] for o in f["only_here"]] + [m["target_id"] for m in f["could_move_to"]]
            assert sorted(listed) == sorted(f["target_ids"])
            for m in f["could_move_to"]:
                p, c = configs[(m["pointing_id"], m["configuration"])]
                assert (p["id"], c["index"]) != (f["pointing_id"], f["configuration"])
                arms = sorted(c["assignments"], key=lambda a: a["arm"])
                observed = sum(a["target_id"] is not None for a in arms)
                assert observed >= 2 or len(f["target_ids"]) == 1
                q = np.array([[a["theta1_rad"], a["theta2_rad"]] for a in arms])
                idle = np.array([a["kind"] in ("park", "blank", "sky") for a in arms])
                ra, dec = sky[m["target_id"]]
                x, y = sky_to_focal_mm(np.array([ra]), np.array([dec]), p["ra_deg"], p["dec_deg"],
                                       INST.plate_scale_arcsec_per_mm, p["position_angle_deg"])
                fits, edge = _brute_force(q, idle, float(x[0]), float(y[0]))
                assert fits or edge, m
                named += 1
    assert named, "premise: the plans leave a target another exposure could take"


def test_a_pass_with_no_time_left_changes_nothing_and_says_why(plans) -> None:
    """A pass after rounds that spent the whole limit changes no pointing and says that time,
    not the plan, stopped it; the same pass with the limit's time left searches the plan."""
    _, rounds_only = plans
    req = PlanRequest.model_validate(_request())
    answers = rounds_only["pointings"]
    spent = [[PointingOutcome(0, 1, 200.0, 0.8 * 200.0, True, 0, 10)]]
    _, out, stats, tries, failed = plan_consolidation._pass(req, INST, None, answers, spent, 120.0,
                                                            lambda: 50.0, 0.0)
    assert out is answers and tries == [] and failed == frozenset()
    assert stats["pointings"] == [] and not stats["accepted"]
    assert stats["reason"] == "no time left to plan a changed pointing"
    left = []
    with pytest.MonkeyPatch.context() as mp:  # with the limit's time left, the pass searches
        mp.setattr(plan_consolidation, "affordable", lambda *a, **k: left.append(a[-1]) or (0, 0, []))
        _, _, searched, _, _ = plan_consolidation._pass(req, INST, None, answers, [], 120.0, lambda: 50.0, 0.0)
    assert left and left[0] > 100.0 and "reason" not in searched


def test_a_refused_pass_runs_again_without_the_pointings_whose_plans_failed(monkeypatch) -> None:
    """service.plan_consolidation's passes: a pass refused for the failed plans of pointings 2
    and 5 is followed by one that leaves them out; one refused with no failed pointing ends
    the passes."""
    seen = []

    def one(req, inst, seg, answers, history, limit_s, wall_left_s, spent_s, frozen):
        seen.append(frozen)
        stats = {"exposures_emptied": 1, "targets_moved_from_few": 0, "effort_s": 0.1, "pointings": ["P1"],
                 "accepted": len(seen) == 2}
        if len(seen) == 1:
            return seg, answers, {**stats, "reason": "not better"}, [], frozenset({2, 5})
        if len(seen) == 2:
            return "seg1", answers, {**stats, "exposures_saved": 1}, [], frozenset()
        return seg, answers, {**stats, "reason": "not better"}, [], frozenset()

    monkeypatch.setattr(plan_consolidation, "_pass", one)
    monkeypatch.setattr(pointing_plans, "plan_mode", lambda req: "fewest-exposures")
    req = PlanRequest.model_validate(_request())
    seg, _, stats = plan_consolidation.consolidated(req, INST, "seg0", [], [], 100.0, lambda: 50.0)
    assert seen == [frozenset(), frozenset({2, 5}), frozenset({2, 5})]
    assert seg == "seg1" and stats["consolidation"]["exposures_saved"] == 1


def _two_pointings(seed: int):
    """Two pointings 60 mm apart over 30 targets all inside both fields: A allocated on 20,
    B on 10, each to completeness on its own."""
    from tests.test_programme_consolidate import _field, _pointing

    rng = np.random.default_rng(seed)
    r = 85.0 * np.sqrt(rng.random(30))
    a = 2 * np.pi * rng.random(30)
    f = _field(np.column_stack([30.0 + r * np.cos(a), r * np.sin(a)]), seed)
    return f, [_pointing(f, np.arange(20), (0.0, 0.0)), _pointing(f, np.arange(20, 30), (60.0, 0.0))]


def test_targets_leave_exposures_of_few_targets_for_fuller_ones() -> None:
    """After the pass, no exposure observing two targets has one that an idle arm of an
    exposure observing two or more could take (solvers.programme.spare.spare_arm_for on the
    result); every exposure passes FCL and the reach checks, every target is still observed
    once, and the targets in exposures of at most two fall by the targets moved."""
    from planner.consolidation import few_observed
    from solvers.programme.fill import Pointing
    from solvers.programme.spare import IDLE_KINDS, spare_arm_for

    def applied(pts, changed):
        new = list(pts)
        for r in changed:
            new[r.index] = Pointing(pts[r.index].centre, pts[r.index].pa_deg, np.array(r.members, np.int64),
                                    len(r.allocation.configurations), allocation=r.allocation)
        return new

    moved_any = 0
    for seed in (1, 6, 12, 19):
        f, pts = _two_pointings(seed)
        saved, moved, changed = regroup(INST, f.ra_deg, f.dec_deg, f.priority, _planned(f, pts), LIMIT_S, None,
                                        Budget.start(30.0))
        assert saved and not moved  # a pass that empties an exposure moves nothing else
        pts = applied(pts, changed)  # the next pass runs on the plan this one left
        saved, moved, changed = regroup(INST, f.ra_deg, f.dec_deg, f.priority, _planned(f, pts), LIMIT_S, None,
                                        Budget.start(30.0))
        moved_any += moved
        new = applied(pts, changed)
        _check_exposures(f, new)
        observed = sorted(int(p.members[a.target_index]) for p in new for c in p.allocation.configurations
                          for a in c.assignments if a.target_index is not None)
        assert observed == list(range(30))
        assert sum(p.exposures for p in new) == sum(p.exposures for p in pts) - saved

        def counts(ps):
            return [sum(a.target_index is not None for a in c.assignments) for p in ps
                    for c in p.allocation.configurations]
        if not saved:
            assert few_observed(counts(new)) == few_observed(counts(pts)) - moved
        fuller = [(p, c) for p in new for c in p.allocation.configurations
                  if sum(a.target_index is not None for a in c.assignments) >= 2]
        for p in new:
            for c in p.allocation.configurations:
                if sum(a.target_index is not None for a in c.assignments) != 2:
                    continue
                for a in c.assignments:
                    if a.target_index is None:
                        continue
                    t = int(p.members[a.target_index])
                    for q, d in fuller:
                        if d is c or not within(f, np.array([t]), q.centre)[0]:
                            continue
                        x, y = sky_to_focal_mm(f.ra_deg[[t]], f.dec_deg[[t]], q.centre[0], q.centre[1], f.scale,
                                               q.pa_deg)
                        arms = sorted(d.assignments, key=lambda b: b.arm)
                        qq = np.array([[b.theta1_rad, b.theta2_rad] for b in arms])
                        idle = np.array([b.kind in IDLE_KINDS for b in arms])
                        assert spare_arm_for(INST, qq, idle, float(x[0]), float(y[0]), LIMIT_S) is None, (seed, t)
    assert moved_any >= 3


#: a 20-target scattered programme whose plan moves a target out of an exposure of two
MOVES = ("scattered", 5)


def test_a_plan_moves_targets_out_of_exposures_of_two() -> None:
    """The plan's pass moves a target of an exposure of two into a fuller exposure, saving no
    exposure, and runs again until a pass is not kept; then every exposure of at most two
    targets has each of its targets listed with a reason (the spare-arm test of
    solvers.programme.spare on the plan as returned), every target is observed and the
    independent verifier passes the plan."""
    prog = PT.generated([MOVES], n_range=(20, 20))[0]
    req = PlanRequest.model_validate({**REQUEST, "seed": MOVES[1], "targets": prog["targets"]})
    plan = pipeline.plan(req, INST)
    c = plan["stats"]["consolidation"]
    assert c["accepted"] and c["targets_moved_from_few"] >= 1 and c["exposures_saved"] == 0
    assert [p["accepted"] for p in c["passes"]] == [True, False]
    few = pipeline.few_target_exposures(plan["pointings"], req.targets, INST, req.park_move_limit_s)
    assert few == plan["few_target_exposures"] and few
    assert all({o["target_id"] for o in f["only_here"]} == set(f["target_ids"]) for f in few)
    assert _observed(plan) == sorted(t["id"] for t in prog["targets"])
    assert plan["executable"] and validate_plan(INST, plan).valid


@pytest.mark.parametrize("seed", range(6))
def test_groups_are_the_connected_pointings_of_the_exchanges(seed) -> None:
    """planner.consolidation.groups_of against a restatement: two pointings share a group
    exactly when a chain of exchanges links them; each group is named by its least pointing."""
    from planner.consolidation import groups_of

    rng = np.random.default_rng(seed)
    exchanges = [frozenset(int(j) for j in rng.choice(12, rng.integers(1, 4), replace=False))
                 for _ in range(rng.integers(0, 6))]
    group = groups_of(exchanges)
    linked = {j: {j} for ex in exchanges for j in ex}
    for _ in range(12):  # the transitive closure, by repeated merging
        for ex in exchanges:
            union = set().union(*(linked[j] for j in ex))
            for j in union:
                linked[j] = union
    assert set(group) == set(linked)
    for j, members in linked.items():
        assert group[j] == min(members)


def test_each_group_of_pointings_is_kept_or_refused_on_its_own() -> None:
    """service.plan_consolidation._kept_groups: group 0 (pointings 0 and 2) saves an exposure
    with every plan executable and is kept; group 1 (pointing 1) has a failed leg and is
    refused, and its pointing is the one the later passes leave out."""
    from models.types import AllocationResult
    from planner.consolidation import Regrouped

    def answer(exposures: list[list[str]], executable: bool = True) -> dict:
        return {"executable": executable,
                "configurations": [{"assignments": [{"target_id": t} for t in ids]} for ids in exposures]}

    old = [answer([["a", "b"], ["c"]]), answer([["d"], ["e"]]), answer([["f", "g"]])]
    new = {0: answer([["a", "b"]]), 1: answer([["d", "e"]], executable=False), 2: answer([["f", "g", "c"]])}
    alloc = AllocationResult((), (), {})
    changed = [Regrouped(0, (), alloc, 0), Regrouped(1, (), alloc, 1), Regrouped(2, (), alloc, 0)]
    assert plan_consolidation._kept_groups(changed, old, new) == {0}
    assert plan_consolidation._failed([r for r in changed if r.group == 1], new) == frozenset({1})
    new[1] = answer([["d", "e"]])
    assert plan_consolidation._kept_groups(changed, old, new) == {0, 1}
    new[2] = answer([["f", "g"]])  # c lost: group 0 refused
    assert plan_consolidation._kept_groups(changed, old, new) == {1}


#: a 30-target halo programme whose complete-linkage plan (no consolidation) keeps exposures of
#: at most two targets that an exposure of another pointing could take
KEPT = ("cluster-halo", 3)


def test_a_target_whose_move_the_consolidation_tried_and_failed_says_so(monkeypatch) -> None:
    """service.pipeline.few_target_exposures: a target another exposure could take carries
    kept_because 'consolidation_plan_failed' exactly when its exposure's pointing or the
    taker's is one the consolidation left out (its new plan failed), and the plan counts such
    exposures as explained (stats.few_target_exposures_plan_failed); the plan stays valid."""
    prog = PT.generated([KEPT], n_range=(30, 30))[0]
    req = PlanRequest.model_validate({"seed": KEPT[1], "segmentation_mode": "complete-linkage",
                                      "time_limit_s": 30, "targets": prog["targets"]})
    planned = []  # the pointings' plans, planned once: the second plan reads them again

    def once(*args, real=pipeline.plan_pointings, **kwargs):
        if not planned:
            planned.append(real(*args, **kwargs))
        return planned[0]

    monkeypatch.setattr(pipeline, "plan_pointings", once)
    plan = pipeline.plan(req, INST)
    movable = [(f["pointing_id"], m["pointing_id"]) for f in plan["few_target_exposures"] for m in f["could_move_to"]]
    assert movable and all(m["kept_because"] is None for f in plan["few_target_exposures"] for m in f["could_move_to"])
    ids = sorted({p["id"] for p in plan["pointings"]})
    for left_out in [frozenset(), *(frozenset({i}) for i in ids), frozenset(ids)]:
        few = pipeline.few_target_exposures(plan["pointings"], req.targets, INST, req.park_move_limit_s, left_out)
        got = [(f["pointing_id"], m["pointing_id"], m["kept_because"]) for f in few for m in f["could_move_to"]]
        assert [(a, b) for a, b, _ in got] == movable
        assert all((why is not None) == bool({a, b} & left_out) for a, b, why in got), left_out
        assert all(why in (None, consolidation.PLAN_FAILED_REASON) for _, _, why in got)
    stats = {"consolidation": {"passes": [{"failed": ["P0002"]}, {"failed": []}, {}]}}
    assert pipeline.left_out_of(stats) == frozenset({"P0002"}) and pipeline.left_out_of({}) == frozenset()
    taker = movable[0][1]
    monkeypatch.setattr(pipeline, "left_out_of", lambda stats: frozenset({taker}))
    again = pipeline.plan(req, INST)
    s = again["stats"]
    hit = [f for f in again["few_target_exposures"] if any(m["kept_because"] for m in f["could_move_to"])]
    assert hit and s["few_target_exposures_plan_failed"] == len(hit)
    whole = [f for f in again["few_target_exposures"]
             if {o["target_id"] for o in f["only_here"]} | {m["target_id"] for m in f["could_move_to"]
                                                            if m["kept_because"]} >= set(f["target_ids"])]
    assert s["few_target_exposures_explained"] == len(whole) > plan["stats"]["few_target_exposures_explained"]
    assert validate_plan(INST, again).valid


def test_the_cli_summary_counts_the_exposures_whose_moves_the_consolidation_tried() -> None:
    from service.cli import exposures_summary

    stats = {"configurations": 10, "few_target_exposures": 5, "few_target_exposures_only_here": 1,
             "few_target_exposures_explained": 4, "few_target_exposures_plan_failed": 2}
    line = exposures_summary(stats)
    assert "1 more for targets only exposures of 1 target can take" in line
    assert "2 more whose targets' moves the consolidation planned and failed (kept_because)" in line
    assert "1 with a target another exposure could take" in line


def test_a_changed_pointings_plan_keeps_back_the_margin_for_its_answer(monkeypatch) -> None:
    """service.plan_consolidation._replanned plans each changed pointing with a wall-clock
    guard of what the plan has left less REPLAN_WALL_MARGIN of it (planner.consolidation.
    replan_wall_s), so the work after the guard (the answer built and verified) fits in the
    plan's limit."""
    seen: list[float | None] = []

    class Stop(Exception):
        pass

    def result(task, inst, progress=None, *, wall_limit_s=None):
        seen.append(wall_limit_s)
        raise Stop

    monkeypatch.setattr(pointing_plans, "pointing_task", lambda req, seg, t, known=None: t)
    monkeypatch.setattr(pointing_plans, "pointing_result", result)
    lefts = (60.0, 12.0, 0.8, -1.0)
    for left in lefts:
        with pytest.raises(Stop):
            plan_consolidation._replanned(None, INST, None, [RoundTask(0, 2, 5.0)], {}, lambda v=left: v,
                                          lambda tries: [])
    m, least = consolidation.REPLAN_WALL_MARGIN, consolidation.REPLAN_WALL_MARGIN_MIN_S
    assert 0.0 < m < 0.2 and 0.0 < least <= 2.0 and 12.0 * m < least < 60.0 * m
    want = [60.0 * (1 - m), 12.0 - least, 0.0, 0.0]
    assert seen == [pytest.approx(w) for w in want]
    assert all(s <= max(v, 0.0) - min(least, max(v, 0.0)) + 1e-9 for s, v in zip(seen, lefts, strict=True))
