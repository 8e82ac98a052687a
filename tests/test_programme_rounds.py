"""The programme's time policy (planner.programme): shares by need, fixed in advance, and
rounds that give what earlier rounds left to the pointings with a failed leg; checked against
a brute restatement on fakes, and on the reproduction programme of issue 37 end to end."""

from __future__ import annotations

import csv
import itertools
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.instrument import default_instrument
from planner import programme as pp
from planner.programme import SHARES, PointingOutcome, RoundTask

INST = default_instrument()
DATA = Path(__file__).parent / "data"


def fake_compute(cost_s: dict[int, float], needs_share_s: dict[int, float], log: list):
    """A round computer whose pointing ``i`` spends ``cost_s[i]`` effort seconds (at most its
    effort budget) and is executable when its share reaches ``needs_share_s[i]``."""
    def compute(tasks):
        log.append(list(tasks))
        out = []
        for t in tasks:
            budget = SHARES.effort_share * t.share_s
            ok = t.share_s >= needs_share_s.get(t.index, 0.0)
            spent = min(cost_s[t.index], budget) if ok else budget
            out.append(PointingOutcome(t.index, t.round, t.share_s, spent, ok, 0 if ok else 2, 5))
        return out
    return compute


def test_a_pointing_that_fails_on_its_first_share_gets_what_the_others_left() -> None:
    needs = [20.0, 30.0, 30.0, 24.0]
    first = pp.pointing_shares(120.0, needs)
    # pointing 0 fails on less than 70 s of share, spending all it is given; the others
    # spend 1 effort-s each
    log: list = []
    history = pp.run_rounds(needs, 120.0, fake_compute({0: 1e9, 1: 1.0, 2: 1.0, 3: 1.0},
                                                        {0: 50.0, 1: 0.0}, log))
    assert first[0] < 50.0 and [t.share_s for t in log[0]] == pytest.approx(first)
    assert len(history) == 2 and [t.index for t in log[1]] == [0]
    used = first[0] + 3 * 1.0 / SHARES.effort_share
    assert log[1][0].share_s == pytest.approx(pp.usable_s(120.0) - used)
    assert history[1][0].executable


def test_no_round_is_due_when_every_pointing_is_executable_or_nothing_is_left() -> None:
    needs = [10.0, 10.0]
    log: list = []
    history = pp.run_rounds(needs, 60.0, fake_compute({0: 1.0, 1: 1.0}, {}, log))
    assert len(history) == 1
    # a pointing that cannot be planned with any share: every round gives it all that is
    # left, until less than the least share is left or the rounds are done
    log = []
    history = pp.run_rounds(needs, 60.0, fake_compute({0: 1.0, 1: 1.0}, {1: math.inf}, log))
    assert len(history) <= SHARES.rounds
    for r in range(1, len(history)):
        left = pp.usable_s(60.0) - sum(o.spent_s() for h in history[:r] for o in h)
        assert [t.index for t in log[r]] == [1] and log[r][0].share_s == pytest.approx(left)
    left = pp.usable_s(60.0) - sum(o.spent_s() for r in history for o in r)
    assert left < SHARES.min_pointing_s or len(history) == SHARES.rounds


def brute_next_round(needs, limit_s, history):
    """A restatement of next_round's rule, written independently."""
    if len(history) >= SHARES.rounds:
        return []
    usable = limit_s - min(SHARES.reserve_fraction * limit_s, SHARES.reserve_max_s)
    spent = 0.0
    best = {}
    for outcomes in history:
        for o in outcomes:
            spent += min(o.effort_s / SHARES.effort_share, o.share_s) if not o.overran else o.share_s
            key = (o.executable, -o.failed_legs, o.observed)
            if o.index not in best or key > best[o.index]:
                best[o.index] = key
    failed = [i for i in sorted(best) if not best[i][0]]
    left = usable - spent
    if not failed or left < SHARES.min_pointing_s:
        return []
    # the neediest k pointings (ties: lower index first), for the largest k whose shares by
    # need all reach the least share; all of what is left is given
    ranked = sorted(failed, key=lambda i: (-needs[i], i))
    for k in range(len(ranked), 0, -1):
        part = ranked[:k]
        total = sum(needs[i] for i in part)
        if all(left * needs[i] / total >= SHARES.min_pointing_s for i in part):
            return [(i, left * needs[i] / total) for i in sorted(part)]
    return []


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 150), st.floats(0.0, 1.0), st.booleans(), st.booleans()),
                min_size=1, max_size=12),
       st.sampled_from([30.0, 120.0, 600.0]))
def test_next_round_matches_a_brute_restatement(rows, limit_s) -> None:
    needs = [pp.pointing_need(n) for n, *_ in rows]
    shares = pp.pointing_shares(limit_s, needs)
    history = [[PointingOutcome(i, 1, shares[i], f * SHARES.effort_share * shares[i], ok,
                                0 if ok else 1, 3, over)
                for i, (_, f, ok, over) in enumerate(rows)]]
    got = [(t.index, t.share_s) for t in pp.next_round(needs, limit_s, history)]
    want = brute_next_round(needs, limit_s, history)
    assert [i for i, _ in got] == [i for i, _ in want]
    assert [s for _, s in got] == pytest.approx([s for _, s in want])
    # what a round gives is all that the limit has left, never more
    left = pp.usable_s(limit_s) - sum(o.spent_s() for o in history[0])
    assert sum(s for _, s in got) <= left + 1e-9
    assert not got or sum(s for _, s in got) == pytest.approx(left)


@given(st.lists(st.floats(1.0, 500.0), min_size=1, max_size=20), st.floats(0.1, 3600.0))
def test_first_round_shares_are_within_the_limit_and_ordered_by_need(needs, limit_s) -> None:
    shares = pp.pointing_shares(limit_s, needs)
    assert sum(shares) <= pp.usable_s(limit_s) + 1e-9
    given_shares = [(w, s) for w, s in zip(needs, shares, strict=True) if s > SHARES.min_pointing_s]
    for (w1, s1), (w2, s2) in itertools.combinations(given_shares, 2):
        assert (w1 - w2) * (s1 - s2) >= -1e-9  # more need, no less share


def test_round_tasks_are_the_same_whatever_the_order_outcomes_arrive() -> None:
    needs = [30.0, 20.0, 40.0]
    shares = pp.pointing_shares(100.0, needs)
    outcomes = [PointingOutcome(i, 1, s, 0.3 * s, i != 2, 0 if i != 2 else 1, 4)
                for i, s in enumerate(shares)]
    a = pp.next_round(needs, 100.0, [outcomes])
    b = pp.next_round(needs, 100.0, [list(reversed(outcomes))])
    assert a == b and [t.index for t in a] == [2] and a[0] == RoundTask(2, 2, a[0].share_s)


def _case_targets() -> list[dict]:
    with open(DATA / "cluster-halo-60.csv") as f:
        return [{"id": r["id"], "ra_deg": float(r["ra_deg"]), "dec_deg": float(r["dec_deg"]),
                 "priority": int(r["priority"])} for r in csv.DictReader(f)]


def test_the_reproduction_programme_is_executable_at_the_default_limit() -> None:
    """cluster-halo-60, seed 12: executable through the call behind POST /v1/plans with only
    targets and seed (the default segmentation), within the default 120 s budget."""
    from service import pipeline
    from service.schemas import PlanRequest

    req = PlanRequest.model_validate({"targets": _case_targets(), "seed": 12})
    out = pipeline.plan(req, INST, budget_s=120.0)
    assert out["executable"], out["reasons"]
    assert out["stats"]["motion_plans_failed"] == 0
    assert out["stats"]["allocated_targets"] == 60
    assert out["stats"]["elapsed_s"] <= 120.0


def _progress_of_rounds(n_rounds_failing: int) -> list[tuple[int, float]]:
    """(round, progress) after every task of a programme whose pointing 0 fails its first
    ``n_rounds_failing`` rounds, as the plan loop reports it."""
    seen: list[tuple[int, float]] = []
    inner = fake_compute({0: 1.0, 1: 1.0, 2: 1.0}, {}, [])  # each leaves time for the next round

    def compute(tasks):
        out = []
        for done, t in enumerate(tasks):
            (o,) = inner([t])
            if t.index == 0 and t.round <= n_rounds_failing:
                o = PointingOutcome(o.index, o.round, o.share_s, o.effort_s, False, 1, 3)
            out.append(o)
            seen.append((t.round, pp.plan_progress(t.round, done + 1, len(tasks))))
        return out

    pp.run_rounds([30.0, 20.0, 20.0], 120.0, compute)
    return seen


@pytest.mark.parametrize("n_rounds_failing", [0, 1, 2, SHARES.rounds])
def test_progress_never_falls_and_reaches_one_only_when_the_rounds_are_done(n_rounds_failing) -> None:
    seen = _progress_of_rounds(n_rounds_failing)
    values = [p for _, p in seen]
    assert values == sorted(values) and all(0.0 < p <= 1.0 for p in values)
    first = [p for r, p in seen if r == 1]
    assert first[-1] == pytest.approx(pp.FIRST_ROUND_DONE) and pp.FIRST_ROUND_DONE < 1.0
    last_round = seen[-1][0]
    assert last_round == min(n_rounds_failing + 1, SHARES.rounds)
    # only the last possible round ends at 1: earlier rounds leave room for the next one
    assert (values[-1] == pytest.approx(1.0)) == (last_round == SHARES.rounds)


def test_a_synchronous_plan_reports_later_rounds_below_one(monkeypatch) -> None:
    """POST /v1/plans' loop: pointing 0 fails its first round; the progress heard never
    falls, and stays below 1 until the second round has planned it."""
    from service import pipeline, pointing_plans
    from service.schemas import PlanRequest

    def fake_result(task, inst, progress, *, wall_limit_s=None):
        progress(0.5)
        ok = task.index != 0 or task.round > 1
        o = PointingOutcome(task.index, task.round, task.share_s, 0.1, ok, 0 if ok else 1, 2)
        return {"configurations": [], "motions": [], "unallocated": [], "stats": {"rounds": [pointing_plans.outcome_out(o)]}}

    monkeypatch.setattr(pointing_plans, "pointing_result", fake_result)
    heard: list[float] = []
    targets = _case_targets()
    req = PlanRequest.model_validate({"targets": targets, "seed": 12, "segmentation_mode": "complete-linkage"})
    seg, answers, stats = pipeline.plan_pointings(req, INST, heard.append, budget_s=120.0)
    assert stats["rounds"] == 2 and len(answers) == 6
    assert heard == sorted(heard) and heard[-1] < 1.0
    assert sum(p > pp.FIRST_ROUND_DONE for p in heard) == 2  # round 2: its half-way and its end


def test_a_pointing_whose_legs_were_not_planned_is_not_executable() -> None:
    import numpy as np

    from models.types import PlaneTargets
    from planner.sequence import SequencePlan

    targets = PlaneTargets(("a",), np.array([1.0]), np.array([0.0]), np.array([1]))
    unplanned = pp.PointingPlan(targets, None, SequencePlan((), ()), "planner error: boom")
    assert SequencePlan((), ()).executable  # no legs: nothing failed ...
    assert not unplanned.executable  # ... but the pointing's legs were never planned
    assert pp.PointingPlan(targets, None, SequencePlan((), ())).executable


def test_the_wall_clock_keeps_back_the_answer_of_a_larger_plan() -> None:
    """The plan's wall clock keeps back the reserve and a per-target part for the answer's
    account of its small exposures, never more than ``reserve_fraction`` of the limit (unless
    the reserve itself is more), and grows with the targets."""
    for limit_s in (5.0, 30.0, 120.0, 600.0):
        last = 0.0
        for n in (1, 50, 247, 1000, 5000):
            kept = pp.wall_reserve_s(limit_s, n)
            assert kept >= pp.reserve_s(limit_s) and kept >= last
            assert kept <= max(SHARES.reserve_fraction * limit_s, pp.reserve_s(limit_s)) + 1e-12
            want = SHARES.reserve_max_s + SHARES.answer_s_per_target * n
            assert kept == pytest.approx(max(min(SHARES.reserve_fraction * limit_s, want), pp.reserve_s(limit_s)))
            last = kept
    assert pp.wall_reserve_s(120.0, 247) == pytest.approx(0.5 + 0.004 * 247)
    assert pp.wall_reserve_s(None, 300) == pp.wall_reserve_s(math.inf, 300) == 0.0


def test_the_margin_round_gives_a_failed_leg_what_the_rounds_kept_for_a_slower_machine() -> None:
    """With ``spend_margin`` a pointing still failing when no round is due gets one more round:
    what the rounds left with their effort at face value (the consolidation's count), split by
    need; without it, or when every pointing is executable, no such round."""
    needs = [20.0, 30.0, 10.0]
    # pointing 0 spends its whole effort budget and fails on any share; the others spend 1 s
    cost = {0: 1e9, 1: 1.0, 2: 1.0}
    plain = pp.run_rounds(needs, 60.0, fake_compute(cost, {0: 1e9}, []))
    log: list = []
    spent = pp.run_rounds(needs, 60.0, fake_compute(cost, {0: 1e9}, log), spend_margin=True)
    assert len(spent) == len(plain) + 1 and [t.index for t in log[-1]] == [0]
    effort = sum(min(o.effort_s, SHARES.effort_share * o.share_s) for r in plain for o in r)
    assert log[-1][0].share_s == pytest.approx(pp.usable_s(60.0) - effort)
    assert log[-1][0].round == len(plain) + 1
    # the margin is what the effort share kept: a fifth of what pointing 0 was given
    assert log[-1][0].share_s >= (1 - SHARES.effort_share) * sum(o.share_s for r in plain for o in r if o.index == 0) - 1e-9
    ok = pp.run_rounds(needs, 60.0, fake_compute({0: 1.0, 1: 1.0, 2: 1.0}, {}, []), spend_margin=True)
    assert len(ok) == 1
    assert pp.margin_round(needs, None, plain) == [] and pp.margin_round(needs, 60.0, []) == []
