"""The sequenced strategy and its time-grid primitive (planner/sequenced.py, planner/timeline.py).

Oracles: the driver's independent verifier with exhaustive 10 ms sampling, and a brute-force
departure search written with the numpy capsule distance of models.collision.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from models.budget import Budget
from models.collision import segment_distance_mm
from models.instrument import default_instrument
from planner import options as planner_options
from planner import plan_motion
from planner.driver import at_positive_turn_bound, positive_turn_bound_s
from planner.options import MotionOptions
from planner.registry import STRATEGIES
from planner.sequenced import (
    Attempt,
    at_goal,
    blocks_start,
    first_order,
    goal_targets,
    plan_sequenced,
    precedence_order,
    search_starts,
    via_grid,
)
from planner.strategy import Candidate, Leg
from planner.timeline import Timeline
from planner.verify import verify_trajectories

INST = default_instrument()
PARK = INST.park_configuration
DATA = json.loads((Path(__file__).parent / "data" / "motion_legs.json").read_text())
LEGS = DATA["legs"]
TO_PARK = DATA["to_park_leg"]


def _leg(start, goal, **kw) -> Leg:
    return Leg.build(INST, np.array(start, float), np.array(goal, float), MotionOptions(**kw))


def _capsule_clearance(s, e, r, S, E, R) -> np.ndarray:
    """Clearance (mm) of capsules s/e (..., nb, 2) of radii r against S/E (..., nb, 2) of
    radii R, leading axes broadcast, with the numpy distance of models.collision."""
    d = segment_distance_mm(s[..., :, None, :], e[..., :, None, :], S[..., None, :, :], E[..., None, :, :])
    return (d - r[:, None] - R[None, :]).min(axis=(-2, -1))


def _clear_brute(tl: Timeline, k: int, ms, D: int) -> bool:
    """Move ``ms`` of arm k departing at step D against every visible arm, in numpy."""
    n = ms.n_steps
    hdt = tl.half_step_margin_s
    for j in np.flatnonzero(tl.visible):
        if j == k:
            continue
        m = np.arange(D, D + n + 1)
        c = _capsule_clearance(ms.s, ms.e, tl.R[k], tl.S[j, m], tl.E[j, m], tl.R[j])
        if np.any(c < tl.buffer_mm + hdt * (ms.speed + tl.SPD[j, m])):
            return False
        rest = np.arange(D + n, tl.n_steps + 1)  # at rest at the end from D + n on
        c = _capsule_clearance(ms.s[-1:], ms.e[-1:], tl.R[k], tl.S[j, rest], tl.E[j, rest], tl.R[j])
        if np.any(c < tl.buffer_mm + hdt * tl.SPD[j, rest]):
            return False
        if not tl.visible[k]:  # resting at the start until D
            before = np.arange(0, D + 1)
            c = _capsule_clearance(ms.s[:1], ms.e[:1], tl.R[k], tl.S[j, before], tl.E[j, before], tl.R[j])
            if np.any(c < tl.buffer_mm + hdt * tl.SPD[j, before]):
                return False
    return True


@pytest.mark.parametrize("dt_s", [1.0, 0.4])
@pytest.mark.parametrize("leg_index", range(len(LEGS)))
def test_earliest_departure_matches_brute_force(leg_index, dt_s):
    """On a real leg, every arm's earliest departure (after the arms before it in the order are
    committed) is the first step the numpy brute force accepts. The kernels skip departures
    and samples by Lipschitz bounds in steps of ``dt_s``: a finer grid skips more of them."""
    spec = LEGS[leg_index]
    leg = _leg(spec["start_q"], spec["goal_q"], horizon_s=160.0)
    tl = Timeline(leg.geoms, leg.start_q, horizon_s=160.0, dt_s=dt_s, buffer_mm=leg.buffer_mm, max_moves=2)
    checked = 0
    for k in first_order(leg):
        for q in goal_targets(tl.pose(k), leg.goal_q[k]):
            ms = tl.samples(k, q)
            if ms is None or ms.n_steps == 0:
                continue
            d, _ = tl.earliest_departure(k, ms)
            brute = next((D for D in range(0, tl.n_steps - ms.n_steps + 1) if _clear_brute(tl, k, ms, D)), -1)
            assert d == brute, (k, d, brute)
            checked += 1
            if d >= 0:
                tl.commit(k, ms, d)
                break
    moving = sum(not at_goal(leg.start_q[k], leg.goal_q[k]) for k in range(leg.n_arms))
    assert moving >= 9 and checked >= moving


@pytest.mark.parametrize("spec", LEGS, ids=[s["name"] for s in LEGS])
def test_real_failing_legs_plan_and_verify(spec):
    """Legs of the allocator's own sequences and of the M13 example that the other strategies
    could not plan. The strategy runs alone with a generous budget (the driver caps its share
    at a few seconds), so that a slow or shared machine does not decide the outcome."""
    start, goal = np.array(spec["start_q"]), np.array(spec["goal_q"])
    leg = _leg(start, goal)
    out = STRATEGIES["sequenced"].plan(leg, Budget.start(60.0))
    assert isinstance(out, Candidate), out.reasons
    rep = verify_trajectories(INST, out.trajectories, start, goal, max_start_stop=1, exhaustive=True)
    assert rep.ok and rep.min_clearance_mm >= INST.collision_buffer_mm
    assert out.makespan_s <= 1.2 * leg.lower_bound_s


def test_sequenced_plan_is_deterministic_and_within_stops():
    spec = LEGS[0]
    leg = _leg(spec["start_q"], spec["goal_q"], seed=3)
    a = plan_sequenced(leg, Budget.start(30.0))
    b = plan_sequenced(leg, Budget.start(30.0))
    assert a.timeline is not None and b.timeline is not None
    for k in range(leg.n_arms):
        ta, qa = a.timeline.waypoints(k)
        tb, qb = b.timeline.waypoints(k)
        assert np.array_equal(ta, tb) and np.array_equal(qa, qb)
        assert len(a.timeline.moves[k]) <= 2  # max_start_stop = 1


def test_no_stop_allowed_means_straight_moves_only():
    spec = LEGS[1]
    leg = _leg(spec["start_q"], spec["goal_q"], max_start_stop=0)
    res = plan_sequenced(leg, Budget.start(5.0))
    if res.timeline is not None:
        assert all(len(m) <= 1 for m in res.timeline.moves)
    else:
        assert res.failed_arms


def test_swap_through_each_other_is_refused_or_verified():
    """Two neighbours whose goals are each other's side: the driver never returns an
    unverified plan, whatever the strategy answers."""
    goal = PARK.copy()
    goal[0] = (2.0, 2.6)
    goal[1] = (2.0, -2.6 % (2 * np.pi))
    plan = plan_motion(INST, PARK, goal, strategies=("sequenced",), time_budget_s=10.0)
    if plan.status == "ok":
        rep = verify_trajectories(INST, plan.trajectories, PARK, goal, max_start_stop=1, exhaustive=True)
        assert rep.ok
    else:
        assert plan.failed_arms


def test_arms_already_at_goal_stay_and_are_obstacles():
    """A leg where nothing moves: every arm stays where it is (no move) and counts as an obstacle."""
    leg = _leg(PARK, PARK)
    tl = Timeline(leg.geoms, leg.start_q, horizon_s=60.0, dt_s=0.1, buffer_mm=leg.buffer_mm, max_moves=2)
    att = Attempt(leg, first_order(leg), Budget.start(5.0), tl)
    assert att.run() == ()
    assert all(not m for m in att.tl.moves) and att.tl.visible.all()


def test_via_grid_outside_zoa_and_sorted_by_travel_time():
    g = _leg(PARK, PARK).geoms[3]
    p, q = np.array([2.0, 1.0]), np.array([1.5, 2.5])
    v = via_grid(g, p, q)
    assert len(v) > 50 and not g.in_zoa(v[:, 0], v[:, 1]).any()
    cost = g.move_time_s(p, v) + g.move_time_s(v, q)
    assert np.all(np.diff(cost) >= -1e-9)


def _legs_spec(name: str) -> dict:
    return json.loads((Path(__file__).parent / "data" / "motion_legs.json").read_text())[name]


def test_long_straight_delay_plan_gets_a_sequenced_shorter_search(monkeypatch):
    """A leg whose departure-delay plan is 1.27 x the lower bound: the driver lets the
    sequenced strategy look for a shorter plan and keeps the shorter verified one (here with
    the fine-step delay search off, as on a leg planned with departures on the fine step)."""
    monkeypatch.setattr(planner_options, "FINE_DELAY_STEP_S", 6.0)
    spec = _legs_spec("long_delays_leg")
    start, goal = np.array(spec["start_q"]), np.array(spec["goal_q"])
    plan = plan_motion(INST, start, goal, time_budget_s=30.0)
    assert plan.status == "ok"
    searches = plan.stats.get("shorter_search", [])
    assert plan.stats.get("first_makespan_s", 0) > 1.1 * plan.stats["lower_bound_s"]
    assert [s["strategy"] for s in searches][:1] == ["sequenced"]
    assert plan.makespan_s < plan.stats["first_makespan_s"]
    assert verify_trajectories(INST, plan.trajectories, start, goal, max_start_stop=1).ok


@pytest.mark.parametrize("name", ["long_delays_leg", "fine_step_leg"])
def test_delay_plan_over_120s_is_searched_again_on_the_fine_step(name: str):
    """A straight departure-delay plan over 120 s: the driver first re-solves the delays with
    departures on FINE_DELAY_STEP_S and keeps the shorter verified plan. On the second leg
    (every arm within 120 s of park the positive way) the 6 s step gives 122.2 s, the fine
    step a plan within 120 s; on the first, the fine step reaches its positive-turn bound."""
    spec = _legs_spec(name)
    goal = np.array(spec["goal_q"])
    start = np.array(spec["start_q"]) if "start_q" in spec else INST.park_configuration
    plan = plan_motion(INST, start, goal, time_budget_s=10.0)
    assert plan.status == "ok" and plan.stats["strategy"] == "delays"
    first = plan.stats["shorter_search"][0]
    assert first["strategy"] == "delays" and first["status"] == "ok"
    assert plan.stats["first_makespan_s"] > planner_options.MAKESPAN_GOAL_S
    assert plan.makespan_s == pytest.approx(first["makespan_s"]) and plan.makespan_s < plan.stats["first_makespan_s"]
    bound = _positive_way_s(start, goal)
    assert plan.makespan_s <= max(bound, planner_options.MAKESPAN_GOAL_S) + 1e-6
    if name == "fine_step_leg":
        assert bound <= 120.0 and plan.makespan_s <= 120.0
    # straight moves with departure delays: zero stops
    assert verify_trajectories(INST, plan.trajectories, start, goal, max_start_stop=0).ok


# a development field of the thesis protocol (seed 7, field 3), park -> c2: the straight delay
# plan takes 123.0 s, arm 0's move turning theta2 the positive way
AT_BOUND_GOAL = np.array([
    [0.956426162402, 3.473473101344], [3.14159265359, 0.0], [2.242443888261, 0.819312844271],
    [0.914418106056, 2.870725018393], [0.867348517629, 3.360975411303], [3.066376927393, 0.226876659763],
    [2.707877917443, 1.045642631979], [1.851250057188, 1.272140665835], [1.257621993112, 2.56178618973],
    [1.989010176523, 2.549828797037], [1.604283466022, 2.171468833319], [2.308706720503, 3.864074163968]])


def _positive_way_s(start: np.ndarray, goal: np.ndarray) -> float:
    """Longest straight move turning theta2 counterclockwise, from atan2 (an independent form)."""
    v1, v2 = INST.arm_array("joint1_speed_rad_s"), INST.arm_array("joint2_speed_rad_s")
    out = 0.0
    for k in range(len(start)):
        d2 = math.atan2(math.sin(goal[k, 1] - start[k, 1]), math.cos(goal[k, 1] - start[k, 1]))
        ccw = d2 if d2 >= 0 else d2 + 2 * math.pi
        out = max(out, abs(goal[k, 0] - start[k, 0]) / v1[k], ccw / v2[k])
    return out


def test_positive_turn_bound_matches_an_atan2_oracle():
    rng = np.random.default_rng(5)
    for _ in range(40):
        start = np.column_stack([rng.uniform(0.5, np.pi, 12), rng.uniform(-7, 7, 12)])
        goal = np.column_stack([rng.uniform(0.5, np.pi, 12), rng.uniform(0, 2 * np.pi, 12)])
        leg = Leg(INST, start, goal, MotionOptions(), 5.0, (), tuple(range(12)), 0.0)
        assert positive_turn_bound_s(leg) == pytest.approx(_positive_way_s(start, goal), abs=1e-6)


def test_at_positive_turn_bound_only_from_park_and_within_the_tolerance():
    leg = _leg(PARK, AT_BOUND_GOAL)
    bound_s = _positive_way_s(PARK, AT_BOUND_GOAL)
    assert at_positive_turn_bound(leg, bound_s) and at_positive_turn_bound(leg, bound_s + 0.9)
    assert not at_positive_turn_bound(leg, bound_s + 1.5)
    # shorter than the bound: the bounding arm already turns the negative way
    assert not at_positive_turn_bound(leg, bound_s - 0.5) and not at_positive_turn_bound(leg, bound_s - 1.5)
    moved = PARK.copy()
    moved[6] = [2.5, 0.3]
    other = _leg(moved, AT_BOUND_GOAL)
    assert not at_positive_turn_bound(other, positive_turn_bound_s(other))


def test_plan_from_park_at_its_positive_turn_bound_skips_the_sequenced_shorter_search():
    """The plan is 1.32 x the lower bound and over 120 s, yet exactly as long as arm 0's
    positive-way move: the sequenced search for a shorter plan does not run, and the plan is
    verified."""
    plan = plan_motion(INST, PARK, AT_BOUND_GOAL, time_budget_s=10.0)
    assert plan.status == "ok"
    assert verify_trajectories(INST, plan.trajectories, PARK, AT_BOUND_GOAL, max_start_stop=1).ok
    bound_s = _positive_way_s(PARK, AT_BOUND_GOAL)
    assert plan.makespan_s > 120.0 and plan.makespan_s > 1.25 * plan.stats["lower_bound_s"]
    assert abs(plan.makespan_s - bound_s) <= 1.0
    assert plan.stats.get("shorter_search_skipped") == "sequenced: at the positive-turn bound"
    assert not any(x["strategy"] == "sequenced" for x in plan.stats.get("shorter_search", []))
    arm0 = plan.trajectories[0]
    assert arm0.theta2_rad[-1] - arm0.theta2_rad[0] > np.pi  # arm 0 turned the positive way

def _pose_clearance_mm(leg: Leg, k: int, qk: np.ndarray, j: int, qj: np.ndarray) -> float:
    """Numpy capsule distance (models.collision) between arm k at qk and arm j at qj."""
    sk, ek = leg.geoms[k].segments(qk[:1], qk[1:])
    sj, ej = leg.geoms[j].segments(qj[:1], qj[1:])
    d = segment_distance_mm(sk[0][:, None, :], ek[0][:, None, :], sj[0][None, :, :], ej[0][None, :, :])
    return float((d - leg.geoms[k].radius[:, None] - leg.geoms[j].radius[None, :]).min())


@pytest.mark.parametrize("spec", LEGS, ids=[s["name"] for s in LEGS])
def test_blocks_start_matches_numpy_distances(spec):
    leg = _leg(spec["start_q"], spec["goal_q"])
    b = blocks_start(leg)
    for k in range(leg.n_arms):
        for j in range(leg.n_arms):
            want = j != k and _pose_clearance_mm(leg, k, leg.goal_q[k], j, leg.start_q[j]) < leg.buffer_mm
            assert b[k, j] == want, (k, j)


def _reaches(b: np.ndarray) -> np.ndarray:
    """Transitive closure of the relation ``b`` (Floyd-Warshall on booleans)."""
    r = b.copy()
    for m in range(len(r)):
        r |= r[:, m:m + 1] & r[m:m + 1, :]
    return r


@pytest.mark.parametrize("spec", LEGS, ids=[s["name"] for s in LEGS])
def test_precedence_order_puts_arms_after_those_they_wait_for(spec):
    """Arm k waits for arm j (k's goal blocks j's start): outside a cycle, j comes first."""
    leg = _leg(spec["start_q"], spec["goal_q"])
    b = blocks_start(leg)
    order = precedence_order(leg)
    assert sorted(order) == sorted(leg.enabled)
    pos = {k: i for i, k in enumerate(order)}
    r = _reaches(b)
    for k, j in zip(*np.nonzero(b), strict=True):
        if not r[j, k]:
            assert pos[j] < pos[k], (k, j)


def test_a_chain_of_waiting_arms_is_ordered_and_planned():
    """c13 -> c14 of a semi-greedy sequence: arms each waiting for the next to leave."""
    spec = next(s for s in LEGS if s["name"] == "semigreedy_seed8_field4_chained_13")
    leg = _leg(spec["start_q"], spec["goal_q"])
    b = blocks_start(leg)
    chain = [(k, j) for k, j in zip(*np.nonzero(b), strict=True) if not _reaches(b)[j, k]]
    assert len(chain) >= 3
    assert precedence_order(leg) != first_order(leg)


def test_search_directions_from_and_to_park():
    spec = LEGS[0]
    from_park = _leg(PARK, spec["goal_q"])
    to_park = _leg(TO_PARK["start_q"], TO_PARK["goal_q"])
    chained = _leg(spec["start_q"], spec["goal_q"])
    flags = {name: [r for _, r, _ in search_starts(leg)]
             for name, leg in (("from", from_park), ("to", to_park), ("chained", chained))}
    assert flags["from"][0] is False and flags["from"] == sorted(flags["from"])  # forward first
    assert flags["to"][0] is True and flags["to"] == sorted(flags["to"], reverse=True)  # reversed first
    assert flags["chained"][:2] == [False, True]  # in turn
    assert all(True in f and False in f for f in flags.values())
    for sub, rev, order in search_starts(to_park):
        want_start = to_park.goal_q if rev else to_park.start_q
        assert np.array_equal(sub.start_q, want_start) and sorted(order) == sorted(to_park.enabled)


def test_leg_to_park_is_planned_reversed_and_verifies():
    """The time reversal of a leg from park (kaiju): the plan starts exactly where the arms
    are, ends at park, and passes the exhaustive verifier."""
    start, goal = np.array(TO_PARK["start_q"]), np.array(TO_PARK["goal_q"])
    plan = plan_motion(INST, start, goal, strategies=("sequenced",), time_budget_s=30.0)
    assert plan.status == "ok", plan.stats.get("reasons")
    assert plan.stats["sequenced"]["reversed"] is True
    rep = verify_trajectories(INST, plan.trajectories, start, goal, max_start_stop=1, exhaustive=True)
    assert rep.ok
    for tr in plan.trajectories:
        assert tr.t_s[0] == 0.0
        assert (tr.theta1_rad[0], tr.theta2_rad[0]) == (start[tr.arm, 0], start[tr.arm, 1])


def _planned(spec, order=None, prefixes=None, holds=None) -> Attempt:
    leg = _leg(spec["start_q"], spec["goal_q"])
    base = Timeline(leg.geoms, leg.start_q, horizon_s=leg.options.horizon_s, dt_s=0.1, buffer_mm=leg.buffer_mm,
                    max_moves=2, margin=0.25)
    att = Attempt(leg, order or first_order(leg), Budget.start(60.0), base, holds)
    att.run(prefixes)
    return att


def test_free_after_matches_brute_force_with_two_move_arms():
    """The last conflict step of poses at rest (the kernel skips arms at their final rest and
    far blocks) equals a numpy scan of every step, on a timeline whose arms made detours."""
    spec = next(s for s in LEGS if s["name"] == "examples_m13_c3_to_c4")
    tl = _planned(spec).tl
    assert any(len(m) == 2 for m in tl.moves), "the fixture needs an arm with a way-point"
    rng = np.random.default_rng(3)
    hdt = tl.half_step_margin_s
    for k in range(len(tl.geoms)):
        g = tl.geoms[k]
        q = np.column_stack([rng.uniform(g.theta1_min, g.theta1_max, 40), rng.uniform(-np.pi, np.pi, 40)])
        q = np.vstack([q, tl.start_q[k], tl.pose(k)])
        got = tl.free_after(k, q)
        s, e = g.segments(q[:, 0], q[:, 1])
        for p in range(len(q)):
            last = -1
            for j in np.flatnonzero(tl.visible):
                if j == k:
                    continue
                d = segment_distance_mm(s[p][None, :, None, :], e[p][None, :, None, :], tl.S[j][:, None], tl.E[j][:, None])
                c = (d - g.radius[None, :, None] - tl.R[j][None, None, :]).min(axis=(1, 2))
                hit = np.flatnonzero(c < tl.buffer_mm + hdt * tl.SPD[j])
                last = max(last, int(hit[-1]) if len(hit) else -1)
            assert got[p] == last, (k, p, got[p], last)


def test_resumed_prefixes_give_the_same_plan():
    """An attempt that takes up an earlier attempt's planned prefix ends with the moves it makes
    from scratch."""
    spec = next(s for s in LEGS if s["name"] == "semigreedy_seed8_field4_chained_13")
    leg = _leg(spec["start_q"], spec["goal_q"])
    order = first_order(leg)
    prefixes: dict = {}
    _planned(spec, order, prefixes)
    assert prefixes, "the first attempt planned no arm"
    changed = order[:4] + order[4:][::-1]  # shares the first four arms
    holds = {order[5]: 50}
    resumed = _planned(spec, changed, prefixes, holds)
    fresh = _planned(spec, changed, None, holds)
    assert resumed.stats.get("arms_resumed", 0) >= 4
    for k in range(leg.n_arms):
        a, b = resumed.tl.waypoints(k), fresh.tl.waypoints(k)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]), k
    assert np.array_equal(resumed.tl.S, fresh.tl.S) and np.array_equal(resumed.tl.BBOX, fresh.tl.BBOX)


def _pair_clearance(s, e, r, S, E, R) -> np.ndarray:
    """Clearance (mm) of capsules s/e (n, nb, 2) of radii r against S/E (m, nb, 2), (n, m)."""
    return _capsule_clearance(s[:, None], e[:, None], r, S[None], E[None], R)


def _brute_departure(tl: Timeline, k: int, ms) -> tuple[int, dict[int, int]]:
    """The first clear departure step of ``ms`` (as :func:`_clear_brute`, every step and every
    sample in numpy) and, per visible arm, the first sample too close to its final pose."""
    n, hdt, buf = ms.n_steps, tl.half_step_margin_s, tl.buffer_mm
    steps = np.arange(tl.n_steps + 1)
    bad_move = np.zeros((n + 1, tl.n_steps + 1), bool)
    bad_end = np.zeros(tl.n_steps + 1, bool)
    bad_start = np.zeros(tl.n_steps + 1, bool)
    final: dict[int, int] = {}
    for j in np.flatnonzero(tl.visible):
        if j == k:
            continue
        c = _pair_clearance(ms.s, ms.e, tl.R[k], tl.S[j], tl.E[j], tl.R[j])
        bad_move |= c < buf + hdt * (ms.speed[:, None] + tl.SPD[j][None, :])
        bad_end |= c[-1] < buf + hdt * tl.SPD[j]
        bad_start |= c[0] < buf + hdt * tl.SPD[j]
        hit = np.flatnonzero(c[:, -1] < buf + hdt * ms.speed)
        final[int(j)] = int(hit[0]) if len(hit) else -1
    for D in range(tl.n_steps - n + 1):
        i = np.arange(n + 1)
        if bad_move[i, D + i].any() or bad_end[steps >= D + n].any():
            continue
        if not tl.visible[k] and bad_start[: D + 1].any():
            continue
        return D, final
    return -1, final


@pytest.mark.parametrize("dt_s", [0.5, 0.25])
def test_departure_kernels_match_brute_force_on_crowded_moves(dt_s):
    """Moves of the arms not yet planned to random poses (most of them blocked for a while or
    for ever) against half a leg planned on the grid: the earliest departure and each visible
    arm's first sample too close to its final pose equal a numpy scan of every step and sample.
    The kernels skip departures, samples and blocks by Lipschitz bounds; a skip one step too
    long shows here."""
    from planner.timeline import _final_conflicts

    spec = next(s for s in LEGS if s["name"] == "examples_m13_c3_to_c4")
    leg = _leg(spec["start_q"], spec["goal_q"], horizon_s=150.0)
    tl = Timeline(leg.geoms, leg.start_q, horizon_s=150.0, dt_s=dt_s, buffer_mm=leg.buffer_mm, max_moves=2)
    order = first_order(leg)
    for k in order[:6]:
        for q in goal_targets(tl.pose(k), leg.goal_q[k]):
            ms = tl.samples(k, q)
            d = -1 if ms is None else tl.earliest_departure(k, ms)[0]
            if d >= 0:
                tl.commit(k, ms, d)
                break
    assert tl.visible.sum() >= 5
    rng = np.random.default_rng(11)
    outcomes = {"now": 0, "later": 0, "never": 0}
    for k in order[6:]:
        g = tl.geoms[k]
        for target in goal_targets(tl.start_q[k], leg.goal_q[k]) * 4:  # near its goal, either way round
            q = target + rng.uniform(-0.15, 0.15, 2)
            q[0] = np.clip(q[0], g.theta1_min, g.theta1_max)
            ms = tl.samples(k, q)
            if ms is None or ms.n_steps == 0:
                continue
            d, _ = tl.earliest_departure(k, ms)
            brute, final = _brute_departure(tl, k, ms)
            assert d == brute, (k, q, d, brute)
            w = tl._world(k)
            first = _final_conflicts(ms.s, ms.e, tl.R[k], ms.box, ms.speed, *w, tl.dt_s)
            assert {j: int(first[j]) for j in final} == final
            outcomes["now" if d == 0 else "later" if d > 0 else "never"] += 1
    assert min(outcomes.values()) >= 2, outcomes


def test_final_pose_conflicts_match_brute_force_on_random_moves():
    """The first sample of a move too close to a neighbour's final pose (the kernel jumps over
    samples a clear one certifies) equals a numpy scan of every sample, over random moves
    of arm 0 and random final poses of arms 1 and 11, on the planner's 0.1 s grid."""
    from planner.timeline import _final_conflicts

    leg = _leg(PARK, PARK)
    rng = np.random.default_rng(5)
    hits = 0
    for _ in range(60):
        tl = Timeline(leg.geoms, PARK, horizon_s=120.0, dt_s=0.1, buffer_mm=leg.buffer_mm, max_moves=2)
        for j in (1, 11):
            g = tl.geoms[j]
            q = np.array([rng.uniform(1.6, g.theta1_max), rng.uniform(-2.0, 2.0)])
            ms = tl.samples(j, q)
            if ms is not None:
                tl.commit(j, ms, 0)
        g = tl.geoms[0]
        ms = tl.samples(0, np.array([rng.uniform(1.6, g.theta1_max), rng.uniform(-3.0, 3.0)]))
        if ms is None or not tl.visible.any():
            continue
        first = _final_conflicts(ms.s, ms.e, tl.R[0], ms.box, ms.speed, *tl._world(0), tl.dt_s)
        for j in np.flatnonzero(tl.visible):
            c = _pair_clearance(ms.s, ms.e, tl.R[0], tl.S[j, -1:], tl.E[j, -1:], tl.R[j])[:, 0]
            bad = np.flatnonzero(c < tl.buffer_mm + tl.half_step_margin_s * ms.speed)
            assert first[j] == (bad[0] if len(bad) else -1), (j, first[j], bad[:3])
            hits += len(bad) > 0 and bad[0] > 0
    assert hits >= 10
