"""Hard legs of a pointing's sequence (planner.sequence): a leg that fails on its share of the
sequence's time is planned once more on a larger share before any target is moved, and a leg
blocked by an arm resting at park moves a target of the arms beside it.

The configurations (tests/data/crowded_legs.json) are the planner's own, from programmes of
the programme benchmark at the plan defaults: the first configuration of a 66-star cluster
pointing (nine arms leaving park together) and two consecutive configurations of a 157-star
two-clump pointing whose leg between them names only a parked arm."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import planner.sequence as sequence
from models import clock
from models.budget import Budget
from models.instrument import default_instrument
from models.types import ArmAssignment, Configuration, MotionPlan
from planner.sequence import SequenceOptions, plan_sequence
from planner.verify import verify_trajectories

INST = default_instrument()
DATA = json.loads((Path(__file__).parent / "data" / "crowded_legs.json").read_text())


def _configuration(d: dict) -> Configuration:
    arms = tuple(ArmAssignment(**a) for a in d["assignments"])
    observed = sum(a.kind == "target" for a in arms)
    return Configuration(int(d["index"]), arms, observed, observed, "feasible")


def _sequence(configs: list[Configuration], seed: int, budget_s: float):
    options = SequenceOptions(seed=seed, park_move_limit_s=DATA["park_move_limit_s"])
    with clock.effort(None):  # effort seconds: the same plan on any machine
        return plan_sequence(INST, configs, options, budget=Budget.start(budget_s))


@pytest.mark.parametrize("escalation", [sequence.ESCALATION, 1.0])
def test_a_crowded_leg_from_park_gets_more_time_before_a_target_moves(monkeypatch, escalation) -> None:
    """Ten exposures of the crowded configuration in 6 effort seconds: the leg from park fails
    on its share (about 0.5 s) and plans on four times it, so no target moves; planned once
    only (no escalation), the same leg loses a target to a repair, which observes it in an
    exposure more."""
    monkeypatch.setattr(sequence, "ESCALATION", escalation)
    c1 = _configuration(DATA["crowded_first"])
    plan = _sequence([c1] * 10, DATA["seed_first"], 6.0)
    if escalation > 1.0:
        assert plan.executable and not plan.changes
        assert len(plan.configurations) == 10
        first = plan.legs[0]
        report = verify_trajectories(INST, first.trajectories, INST.park_configuration, c1.q,
                                     max_start_stop=None)
        assert report.ok  # an independent check of the leg the escalation planned
    else:
        assert any(ch.kind == "moved_target" for ch in plan.changes)
        assert len(plan.configurations) > 10


def _ring_neighbours(k: int) -> set[int]:
    """The arms whose bases come just before and after arm k round the field centre."""
    x, y = INST.arm_array("base_x_mm"), INST.arm_array("base_y_mm")
    order = list(np.argsort(np.arctan2(y, x)))
    at = order.index(k)
    return {int(order[at - 1]), int(order[(at + 1) % len(order)])}


@pytest.mark.parametrize("arm", range(12))
def test_the_arms_beside_an_arm_are_its_neighbours_on_the_ring(arm: int) -> None:
    seq = sequence._Sequencer(INST, [], SequenceOptions(), {}, Budget.start(1.0))
    assert set(seq._beside((arm,))) == _ring_neighbours(arm)
    assert arm not in seq._beside((arm,))


def test_a_leg_blocked_by_a_parked_arm_moves_a_target_of_an_arm_beside_it() -> None:
    """The repair of a leg whose failure names only an arm resting at park (no target of its
    own to move) takes out the lowest-priority target of the arms beside it, and plans the leg;
    without that fallback the repair has nothing to move and the leg stays failed."""
    c6, c7 = (_configuration(d) for d in DATA["idle_blocked"])
    parked = [a.arm for a in c7.assignments if a.kind == "park" and c6.assignments[a.arm].kind == "park"]
    assert parked  # the blocking arm rests at park in both configurations
    k = parked[0]
    failed = MotionPlan("failed", math.nan, (), (k,), {"reasons": {k: "no priority order tried let every arm move"}})
    options = SequenceOptions(seed=DATA["seed_idle"], park_move_limit_s=DATA["park_move_limit_s"])
    with clock.effort(None):
        seq = sequence._Sequencer(INST, [c6, c7], options, {}, Budget.start(20.0))
        seq.pending = []
        leg = seq._change(1, c6.q, failed)
    moved = [ch for ch in seq.changes if ch.kind == "moved_target"]
    assert moved and moved[0].arms[0] in _ring_neighbours(k)
    assert seq.configs[1].assignments[moved[0].arms[0]].kind != "target"
    assert leg is not None and leg.status == "ok"
    assert verify_trajectories(INST, leg.trajectories, c6.q, seq.configs[1].q, max_start_stop=None).ok

    with clock.effort(None):
        bare = sequence._Sequencer(INST, [c6, c7], options, {}, Budget.start(20.0))
        bare.pending = []
        bare._beside = lambda arms: ()
        again = bare._change(1, c6.q, failed)
    assert again is failed and not bare.changes
