"""Legs reused from an earlier plan (planner.known_legs): a plan of the same configurations
reuses every leg, a plan with one configuration changed plans only the legs next to it, a
start whole turns away is shifted onto, and every reused leg passes the independent verifier."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from models import clock
from models.instrument import default_instrument
from models.types import AllocationResult, Configuration, PlaneTargets
from planner import verify_trajectories
from planner.consolidation import PlannedPointing, Regrouped, replan_costs
from planner.known_legs import KnownLegs, new_legs
from planner.sequence import SequenceOptions, SequencePlan, end_of, plan_sequence
from planner.shares import SHARES
from solvers.allocation import allocate

INST = default_instrument()
PARK = np.asarray(INST.park_configuration, float)
OPTIONS = SequenceOptions(seed=3, time_limit_s=60.0)


def _targets(n: int, seed: int) -> PlaneTargets:
    rng = np.random.default_rng(seed)
    r = INST.fov_radius_mm * 0.9 * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    return PlaneTargets(tuple(f"t{i}" for i in range(n)), r * np.cos(phi), r * np.sin(phi),
                        rng.choice([1, 10, 100, 500], n).astype(np.int64))


@pytest.fixture(scope="module")
def planned() -> tuple[tuple[Configuration, ...], SequencePlan]:
    """Four configurations of a 45-target field and their plan."""
    alloc = allocate(INST, _targets(45, 7), method="semigreedy", configurations="all", seed=1)
    configs = tuple(alloc.configurations[:4])
    seq = plan_sequence(INST, configs, OPTIONS)
    assert seq.executable and len(seq.configurations) == len(configs) == 4
    return seq.configurations, seq


def _known(seq: SequencePlan) -> KnownLegs:
    return KnownLegs.of_plan(PARK, [c.q for c in seq.configurations], seq.legs)


def _check_legs(seq: SequencePlan) -> None:
    """Every leg, checked by the verifier from where the previous one left the arms."""
    start = PARK
    goals = [c.q for c in seq.configurations] + [PARK]
    for leg, goal in zip(seq.legs, goals, strict=True):
        rep = verify_trajectories(INST, leg.trajectories, start, goal, max_start_stop=None)
        assert rep.ok, rep.violations[:3]
        start = end_of(leg)


def test_the_same_configurations_reuse_every_leg(planned) -> None:
    configs, seq = planned
    again = plan_sequence(INST, configs, OPTIONS, known=_known(seq))
    assert again.stats["plans"] == 0 and again.stats["reused_legs"] == len(seq.legs)
    for a, b in zip(again.legs, seq.legs, strict=True):
        assert a.stats["reused"] is True
        for ta, tb in zip(a.trajectories, b.trajectories, strict=True):
            np.testing.assert_array_equal(ta.t_s, tb.t_s)
            np.testing.assert_array_equal(ta.theta2_rad, tb.theta2_rad)
    _check_legs(again)


def test_a_removed_configuration_plans_only_the_leg_that_replaces_it(planned) -> None:
    configs, seq = planned
    fewer = configs[:1] + configs[2:]
    again = plan_sequence(INST, fewer, OPTIONS, known=_known(seq))
    assert again.executable and again.stats["plans"] == new_legs(configs, fewer) == 1
    assert again.stats["reused_legs"] == len(again.legs) - 1
    _check_legs(again)


def test_a_reordered_plan_plans_the_moves_it_did_not_make(planned) -> None:
    configs, seq = planned
    order = (configs[0], configs[2], configs[1], configs[3])
    again = plan_sequence(INST, order, OPTIONS, known=_known(seq))
    assert again.executable
    assert again.stats["plans"] == new_legs(configs, order) == 3  # c1->c3, c3->c2, c2->c4
    _check_legs(again)


def test_a_start_whole_turns_away_is_shifted_onto() -> None:
    """A leg known from a start whose theta2 differs by whole turns is the same motion: it is
    shifted onto the arms' start and verified from there; an arm elsewhere gets none."""
    alloc = allocate(INST, _targets(12, 11), method="semigreedy", configurations="all", seed=1)
    c1, c2 = alloc.configurations[:2]
    leg = plan_sequence(INST, (c1, c2), OPTIONS).legs[1]
    known = KnownLegs.of_plan(PARK, [c1.q, c2.q], [_failed(), leg, _failed()])
    start = np.array([[tr.theta1_rad[0], tr.theta2_rad[0]] for tr in leg.trajectories])
    turned = start.copy()
    turned[3, 1] += 2 * np.pi
    turned[7, 1] -= 4 * np.pi
    shifted = known.leg(INST, turned, c2.q)
    assert shifted is not None
    assert shifted.trajectories[3].theta2_rad[0] == turned[3, 1]
    np.testing.assert_allclose(shifted.trajectories[7].theta2_rad, leg.trajectories[7].theta2_rad - 4 * np.pi)
    assert verify_trajectories(INST, shifted.trajectories, turned, c2.q, max_start_stop=None).ok
    elsewhere = start.copy()
    elsewhere[5, 0] += 1e-6
    assert known.leg(INST, elsewhere, c2.q) is None
    assert known.leg(INST, start, c1.q) is None  # no known leg ends there


def _failed():
    from models.types import MotionPlan

    return MotionPlan("failed", float("nan"), (), tuple(range(INST.n_arms)))


def _brute_new_legs(old: list[int], new: list[int]) -> int:
    made = {(a, b) for a, b in itertools.pairwise([-1, *old, -1])}
    return sum((a, b) not in made for a, b in itertools.pairwise([-1, *new, -1]))


@pytest.mark.parametrize("seed", range(6))
def test_new_legs_counts_the_moves_the_old_plan_did_not_make(planned, seed) -> None:
    configs, _ = planned
    rng = np.random.default_rng(seed)
    old = list(rng.permutation(len(configs))[: rng.integers(0, len(configs) + 1)])
    new = list(rng.choice(len(configs), rng.integers(0, len(configs) + 1), replace=False))
    as_configs = lambda ix: [configs[i] for i in ix]  # noqa: E731
    assert new_legs(as_configs(old), as_configs(new)) == _brute_new_legs(old, new)
    # a configuration whose joint angles differ is another configuration
    moved = replace(configs[0], assignments=(replace(configs[0].assignments[0],
                                                     theta1_rad=configs[0].assignments[0].theta1_rad + 1e-12),
                                             *configs[0].assignments[1:]))
    assert new_legs([configs[0]], [moved]) == 2


def test_a_plan_answers_legs_read_back_are_the_same_verified_legs(planned) -> None:
    """motion_out -> motion_in keeps every way-point and command, and the legs read back from
    a PlanPointing-shaped dict are reused by a plan of the same configurations."""
    from service.adapters import known_legs_in, motion_in, motion_out

    configs, seq = planned
    for leg in seq.legs:
        back = motion_in(motion_out(leg))
        assert back.status == leg.status and back.makespan_s == leg.makespan_s
        for a, b in zip(back.trajectories, leg.trajectories, strict=True):
            np.testing.assert_array_equal(a.theta1_rad, b.theta1_rad)
            assert a.commands == b.commands
    answer = {"configurations": [{"assignments": [{"arm": a.arm, "theta1_rad": a.theta1_rad,
                                                   "theta2_rad": a.theta2_rad} for a in reversed(c.assignments)]}
                                 for c in configs],
              "motions": [motion_out(m) for m in seq.legs]}
    again = plan_sequence(INST, configs, OPTIONS, known=known_legs_in(INST, answer))
    assert again.stats["plans"] == 0 and again.stats["reused_legs"] == len(seq.legs)
    _check_legs(again)


def test_a_known_leg_through_park_is_reported_as_one(planned) -> None:
    """A reused leg that goes through park (two verified halves) is recorded as a via-park
    change, so the validator allows its stop at park (planner.validate.via_park_legs)."""
    from planner.sequence import via_park_leg
    from planner.validate import allowed_stops

    configs, seq = planned
    c1, c2 = configs[:2]
    a, b = seq.legs[0], plan_sequence(INST, (c2,), OPTIONS).legs[0]
    via = via_park_leg(INST, a, b, c1.q, c2.q, 0.0)
    assert via is not None and via.stats["strategy"] == "via_park"
    known = KnownLegs.of_plan(PARK, [c1.q, c2.q], [a, via, _failed()])
    again = plan_sequence(INST, (c1, c2), OPTIONS, known=known)
    assert again.executable and again.legs[1].stats["reused"] and again.legs[1].stats["strategy"] == "via_park"
    assert [(c.kind, c.leg) for c in again.changes] == [("via_park", 1)]
    stops = max(_stops(tr) for tr in again.legs[1].trajectories)
    assert allowed_stops(False) < stops <= allowed_stops(True), "premise: the leg stops at park"


def _stops(tr) -> int:
    from planner.commands import stop_count

    return stop_count(tr.t_s, tr.theta1_rad, tr.theta2_rad)


@pytest.fixture(scope="module")
def round_plan() -> tuple[tuple[Configuration, ...], SequencePlan, float]:
    """Five configurations of a 60-target field, the plan of its first four as a round plans
    them, and what that plan cost in wall-clock seconds of share (effort over effort_share)."""
    alloc = allocate(INST, _targets(60, 5), method="semigreedy", configurations="all", seed=2)
    configs = tuple(alloc.configurations[:5])
    assert len(configs) == 5, "premise: five configurations"
    with clock.effort() as effort:
        seq = plan_sequence(INST, configs[:4], OPTIONS)
    assert seq.executable
    return configs, seq, effort.t_s / SHARES.effort_share


@pytest.mark.parametrize("order", [(0, 2, 3), (0, 1, 4, 3), (0, 2, 1, 3), (4, 1, 2, 3), (0, 1, 2, 3)])
def test_replan_costs_cover_what_the_changed_plan_takes(round_plan, order) -> None:
    """planner.consolidation.replan_costs against a measurement: the changed configurations
    (one removed, replaced, swapped, the first replaced, none) planned again with the round's
    legs known take no more effort than it estimates, and less than the round took when most
    legs are reused."""
    configs, seq, round_s = round_plan
    new = tuple(configs[i] for i in order)
    with clock.effort() as effort:
        again = plan_sequence(INST, new, OPTIONS, known=_known(seq))
    assert again.executable and again.stats["plans"] == new_legs(seq.configurations, new)
    old = PlannedPointing((0.0, 0.0), 0.0, seq.configurations, {})
    changed = Regrouped(0, (), AllocationResult(new, (), {}))
    estimate_s = replan_costs({0: round_s}, [old], [changed])[0]
    assert effort.t_s / SHARES.effort_share <= estimate_s
    if new_legs(seq.configurations, new) <= 1:
        assert estimate_s < 0.5 * round_s


def test_every_leg_through_park_of_a_plan_is_listed_as_one() -> None:
    """A known leg through park reused on a repair's path (not only as a transition's first
    try) is listed among the pointing's changes, so the independent validator allows its stop
    at park: cluster-halo-24003 (300 stars, fewest-exposures, the plan's defaults) reuses such
    a leg in P0001's leg 18 and answered it unlisted (2 stops > 1 for arms 3 and 8)."""
    from benchmarks.programme_time import EXTENT_ARCMIN, plan_programme
    from benchmarks.programmes import programme_targets
    from planner.validate import validate_plan

    targets, _ = programme_targets("cluster-halo", 24003, extent_arcmin=EXTENT_ARCMIN, n_range=(300, 300))
    plan, _ = plan_programme(targets, 24003, "fewest-exposures", None)
    for p in plan["pointings"]:
        listed = {c["leg"] for c in p.get("changes") or [] if c["kind"] == "via_park"}
        through = {i for i, m in enumerate(p["motions"]) if (m.get("stats") or {}).get("strategy") == "via_park"}
        assert through <= listed, (p["id"], sorted(through - listed))
    report = validate_plan(INST, plan)
    assert report.valid, report.violations[:3]
