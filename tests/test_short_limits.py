"""A limit too short for the programme: the plan plans whole the pointings that fit, names the
limit for the others, and says which limit the field needs (issue 40 item 4).

The policy (planner.programme.first_round_shares, next_round, rank; planner.time_advice) is
checked against restatements written here from its definition, on fake rounds; the M67-like
case of the issue end to end through the call behind POST /v1/plans."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner import programme as pp
from planner import time_advice as ta
from planner.programme import SHARES, PointingOutcome
from service.response_schemas import PlanResponse

DATA = Path(__file__).parent / "data"


def expected_share_s(need: float, typical: bool = False) -> float:
    """What a pointing of ``need`` (its targets + 12) is expected to be planned in, from the
    table's definition."""
    rate = SHARES.typical_effort_per_target_s if typical else SHARES.enough_effort_per_target_s
    return 0.0 if need <= 0 else max(max(need - SHARES.fixed_need_targets, 1) * rate / SHARES.effort_share,
                                     SHARES.least_planned_s)


def short_compute(log: list):
    """Fake rounds: a pointing is planned whole (executable, spending 60 % of its effort
    budget) when its share reaches its expected share, else it fails on all of it; a share
    of 0 is not attempted."""
    def compute(tasks):
        log.append(list(tasks))
        out = []
        for t in tasks:
            need = NEEDS[t.index]
            if t.share_s <= 0:
                out.append(PointingOutcome(t.index, t.round, 0.0, 0.0, True, 0, 0, attempted=False))
                continue
            budget = SHARES.effort_share * t.share_s
            ok = t.share_s >= expected_share_s(need) - 1e-9
            out.append(PointingOutcome(t.index, t.round, t.share_s, 0.6 * budget if ok else budget,
                                       ok, 0 if ok else 3, int(need) - 12))
        return out
    return compute


NEEDS = [84.0, 24.0, 24.0, 24.0, 15.0, 14.0, 21.0, 17.0, 17.0, 24.0, 17.0, 13.0]  # M67-like


def test_a_short_limit_plans_whole_the_neediest_pointings_that_fit() -> None:
    limit = 12.0
    usable = pp.usable_s(limit)
    shares = pp.first_round_shares(limit, NEEDS)
    chosen = [i for i, s in enumerate(shares) if s > 0]
    # restatement: neediest first (ties: lower index), each taken while its expected share fits
    left, want = usable, []
    for i in sorted(range(len(NEEDS)), key=lambda i: (-NEEDS[i], i)):
        if expected_share_s(NEEDS[i]) <= left:
            want.append(i)
            left -= expected_share_s(NEEDS[i])
    assert chosen == sorted(want) and 0 < len(chosen) < len(NEEDS)
    assert sum(shares) == pytest.approx(usable)
    assert all(shares[i] >= expected_share_s(NEEDS[i]) - 1e-9 for i in chosen)
    # the pointings left out do not fit in what the chosen ones leave
    spare = usable - sum(expected_share_s(NEEDS[i]) for i in chosen)
    assert all(expected_share_s(NEEDS[i]) > spare for i in range(len(NEEDS)) if i not in chosen)


def test_a_short_limit_finishes_pointings_where_an_even_split_finishes_none() -> None:
    """With shares by need over every pointing (the split that a long limit gets), the fake
    plans finish no pointing at 12 s; the short limit's choice finishes the ones it starts,
    and leaves no failed leg."""
    log: list = []
    history = pp.run_rounds(NEEDS, 12.0, short_compute(log))
    best = {}
    for r in history:
        for o in r:
            if o.index not in best or pp.better(o, best[o.index]):
                best[o.index] = o
    planned = [i for i, o in best.items() if o.attempted and o.executable]
    assert planned and not [i for i, o in best.items() if o.attempted and not o.executable]
    even = pp.pointing_shares(12.0, NEEDS)
    assert not [i for i, s in enumerate(even) if s >= expected_share_s(NEEDS[i])]


def test_a_limit_that_holds_the_typical_shares_keeps_the_split_by_need() -> None:
    limit = ta.needed_limit_s(sum(expected_share_s(w, typical=True) for w in NEEDS), optimiser=False)
    assert pp.first_round_shares(limit, NEEDS) == pp.pointing_shares(limit, NEEDS)
    assert pp.first_round_shares(None, NEEDS) == pp.pointing_shares(None, NEEDS)
    assert pp.first_round_shares(limit - 1.0, NEEDS) != pp.pointing_shares(limit - 1.0, NEEDS)


def test_time_left_by_the_first_round_plans_the_pointings_still_waiting() -> None:
    needs = [24.0, 24.0, 20.0]
    first = [PointingOutcome(0, 1, 7.0, 0.5, True, 0, 12), PointingOutcome(1, 1, 0.0, 0.0, True, 0, 0,
                                                                            attempted=False),
             PointingOutcome(2, 1, 0.0, 0.0, True, 0, 0, attempted=False)]
    left = pp.usable_s(10.0) - first[0].spent_s()
    tasks = pp.next_round(needs, 10.0, [first])
    assert [t.index for t in tasks] == [1] and tasks[0].share_s == pytest.approx(left)
    assert left >= expected_share_s(24.0) > left - expected_share_s(20.0)
    # a pointing with a failed leg comes first: the waiting ones wait
    failed = [PointingOutcome(0, 1, 7.0, 0.5, False, 1, 12), *first[1:]]
    assert [t.index for t in pp.next_round(needs, 10.0, [failed])] == [0]


def test_a_plan_not_attempted_never_replaces_one_that_was() -> None:
    """A later round cut by the deadline (not attempted: no leg, nothing observed) is no
    better than the earlier plan with a failed leg that observes 71 targets."""
    planned = PointingOutcome(0, 1, 2.4, 1.4, False, 1, 71)
    cut = PointingOutcome(0, 4, 1.3, 0.0, True, 0, 0, overran=True, attempted=False)
    assert not pp.better(cut, planned) and pp.better(planned, cut)


def test_a_plan_the_wall_clock_cut_with_a_failed_leg_leaves_its_pointing_not_planned() -> None:
    """A later round's plan that the wall guard cut (overran) with a leg unplanned is no plan:
    the pointing stays not planned for lack of time (executable, nothing observed), and the
    advice names it with an estimate of at least ``failed_growth`` times the share it had."""
    needs = [24.0, 24.0]
    first = [PointingOutcome(0, 1, 7.0, 0.5, True, 0, 12),
             PointingOutcome(1, 1, 0.0, 0.0, True, 0, 0, attempted=False)]
    cut = PointingOutcome(1, 2, 6.0, 6.0 * SHARES.effort_share, False, 2, 9, overran=True)
    assert not pp.planned(cut) and pp.planned(first[0]) and not pp.planned(first[1])
    assert not pp.better(cut, first[1]) and pp.better(first[1], cut)
    assert pp.best_outcomes([first, [cut]])[1] is first[1]
    advice = ta.time_advice(10.0, needs, [first, [cut]], optimiser=False)
    assert advice is not None and advice.not_attempted == (1,) and advice.failed == ()
    want = first[0].spent_s() + max(SHARES.failed_growth * 6.0, expected_share_s(24.0))
    assert advice.needed_limit_s == ta.needed_limit_s(want, optimiser=False) > 10.0
    # cut with every leg planned, or a failed leg within its share: a plan, kept over none
    for o in (PointingOutcome(1, 2, 6.0, 6.0 * SHARES.effort_share, True, 0, 9, overran=True),
              PointingOutcome(1, 2, 6.0, 6.0 * SHARES.effort_share, False, 2, 9)):
        assert pp.planned(o) and pp.better(o, first[1])


@settings(max_examples=150, deadline=None)
@given(st.floats(0.0, 3000.0), st.booleans())
def test_the_needed_limit_is_the_least_whole_second_that_holds_the_pointings(pointings_s, optimiser) -> None:
    needed = ta.needed_limit_s(pointings_s, optimiser)
    assert needed == math.floor(needed)
    if pointings_s > 0:
        assert ta.pointings_part_s(needed, optimiser) >= pointings_s - 1e-9
        assert ta.pointings_part_s(needed - 1.0, optimiser) < pointings_s


def test_advice_only_when_the_limit_left_a_pointing_unplanned() -> None:
    needs = [24.0, 24.0, 13.0]
    done = [[PointingOutcome(i, 1, 5.0, 1.0, True, 0, 3) for i in range(3)]]
    assert ta.time_advice(20.0, needs, done, optimiser=False) is None
    waiting = [[PointingOutcome(0, 1, 9.0, 4.0, True, 0, 12),
                PointingOutcome(1, 1, 0.0, 0.0, True, 0, 0, attempted=False),
                PointingOutcome(2, 1, 0.0, 0.0, True, 0, 0, attempted=False)]]
    advice = ta.time_advice(10.0, needs, waiting, optimiser=False)
    assert advice is not None and advice.not_attempted == (1, 2) and advice.failed == ()
    # the estimate: what pointing 0 spent, the others' expected shares
    want = waiting[0][0].spent_s() + expected_share_s(24.0) + expected_share_s(13.0)
    assert advice.needed_limit_s == ta.needed_limit_s(want, optimiser=False) > 10.0
    # a failed leg with the limit spent: advised; with time left (the rounds' number stopped
    # them), not
    spent = [[PointingOutcome(0, 1, 9.5, 9.5 * SHARES.effort_share, False, 1, 12)]]
    assert ta.time_advice(10.0, [24.0], spent, optimiser=False).failed == (0,)
    idle = [[PointingOutcome(0, 1, 9.5, 0.1, False, 1, 12)]]
    assert ta.time_advice(10.0, [24.0], idle, optimiser=False) is None


@pytest.fixture(scope="module")
def m67_short() -> dict:
    """The issue's case: the M67-like 150-star list at 10 s, as POST /v1/plans plans it on a
    server whose synchronous plans have 60 s."""
    from service import pipeline
    from service.schemas import PlanRequest
    from service.tables import read_targets

    targets = read_targets(DATA / "m67-like-150-vizier.csv")
    req = PlanRequest.model_validate({"targets": targets, "time_limit_s": 10, "seed": 0})
    return pipeline.plan(req, pipeline.instrument_from(None), budget_s=60.0)


def test_the_m67_case_at_10_s_plans_what_fits_and_says_what_it_needs(m67_short) -> None:
    out = m67_short
    advice = out["time_limit_advice"]
    assert advice is not None and advice["time_limit_s"] == 10.0
    assert advice["needed_limit_s"] > 60.0 and advice["use_job"]
    assert out["notices"] == [advice["message"]]
    assert "POST /v1/jobs" in advice["message"] and f"{advice['needed_limit_s']:g} s" in advice["message"]
    waiting = [p for p in out["pointings"] if p["not_planned"] is not None]
    started = [p for p in out["pointings"] if p["not_planned"] is None]
    assert [p["id"] for p in waiting] == advice["pointings_not_planned"] and waiting
    assert all("10 s" in p["not_planned"] for p in waiting)
    assert all({u["reason"] for u in p["unallocated"]} == {"no_time"} and not p["configurations"]
               for p in waiting)
    assert advice["targets_not_planned"] == sum(len(p["target_ids"]) for p in waiting)
    # a pointing not planned has nothing to execute; the plan of the others is executable, and
    # the independent validator agrees
    assert all(p["executable"] and not p["configurations"] for p in waiting)
    assert out["executable"] is True
    from planner.validate import validate_plan
    from service import pipeline

    report = validate_plan(pipeline.instrument_from(None), out)
    assert report.valid, [(v.pointing, v.kind, v.message) for v in report.violations]
    # the pointings it started are planned whole, and they observe targets
    assert started and all(p["executable"] and p["configurations"] for p in started)
    assert out["stats"]["motion_plans_failed"] == 0 and advice["pointings_failed"] == []
    assert advice["pointings_planned"] == len(started)
    assert out["stats"]["elapsed_s"] <= 10.0
    typed = PlanResponse.model_validate(out)  # the typed fields of the answer's schema
    assert typed.time_limit_advice is not None and typed.time_limit_advice.use_job
    assert [p.not_planned is not None for p in typed.pointings] == [p in waiting for p in out["pointings"]]
