"""Cluster strategy (planner.cluster): removal sets and state-time detours for the conflicting arms.

The two chained legs are the ones of ``python -m benchmarks.motion --n 200`` (seed 0,
allocations 128 -> 129 -> 130) that neither the delay CSP (straight moves, both theta2
directions) nor, on a loaded machine, the prioritized fallbacks within the 10 s budget
solved: neighbouring arms sweep each other's start and goal, so several need a detour.
"""

from __future__ import annotations

import numpy as np
import pytest

from models.instrument import default_instrument
from models.types import ArmTrajectory
from planner import delays as D
from planner import plan_motion, stop_count, verify_trajectories
from planner.cluster import plan_cluster, reduced_problem, removal_sets
from planner.commands import compress_waypoints
from planner.geometry import ArmGeom
from planner.options import MotionOptions
from planner.roadmap import RoadmapParams
from planner.single_arm import SearchParams, SearchStats
from planner.strategies.cluster import Cluster
from planner.strategy import Candidate, Leg

INST = default_instrument()
GEOMS = [ArmGeom.of(INST, k) for k in range(12)]
C128 = [[2.251761611715, -0.107030082912], [2.215135168205, 0.116653396764], [2.549763355378, 0.047736295072],
        [2.688722661138, 0.396383414091], [2.678221991248, 0.175910464236], [2.346158024893, 0.352283019445],
        [2.879641437351, 0.326046791379], [2.402995875366, 0.377389683821], [2.39707145254, 0.727332846197],
        [2.372113992117, 0.614447187658], [2.829067866317, 0.034405787868], [2.365409550607, 0.082490985735]]
C129 = [[2.855853300016, 0.242115134469], [2.939813321072, 0.403842920903], [2.900820504226, 2.650282319997],
        [2.443131806316, 0.301079979864], [2.013208973345, 0.636603333893], [2.220922739019, 2.615738008568],
        [2.258927629807, 0.627350488696], [2.269607534831, 2.593205080286], [2.069402228033, 0.564154453522],
        [2.149684301808, 3.782206241368], [2.614034236668, 3.744154654972], [2.852596690469, 0.160218247598]]
C130 = [[2.846781042047, 0.351903150962], [2.399862659309, 0.4052658917], [2.178842093738, 0.703404113526],
        [2.906419435376, 0.428890282415], [2.160626979342, 6.259110092665], [2.760474625662, 6.148576683694],
        [2.394727972028, 0.43510412791], [2.544005032513, 0.457822453168], [2.115427300928, 1.034934198234],
        [2.27240964507, 0.456692330621], [2.387971471745, 0.604145704906], [2.7945005091, 0.477282801931]]
LEG_129 = (np.array(C128), np.array(C129))
PARK_129 = (INST.park_configuration, np.array(C129))
LEG_130 = (np.array(C129), np.array(C130))
ALL = list(range(12))


def _straight(start, goal):
    res = D.plan_delays(GEOMS, start, goal, dt_s=6.0, dt_col_s=0.1, horizon_s=220.0, buffer_mm=5.0,
                        max_start_stop=1, movable=ALL, stats=D.DelayStats(), max_rounds=2)
    assert res.assignment is None  # straight moves fail at any delays and theta2 directions
    assert res.straight is not None
    assert all(o.kind in ("straight", "stay") for opts in res.straight.options for o in opts)
    return res.straight


def _trajs(out):
    trajs = []
    for k, (t, q) in enumerate(out):
        t, q = compress_waypoints(t, q)
        trajs.append(ArmTrajectory(k, t, q[:, 0].copy(), q[:, 1].copy()))
    return trajs


def test_removal_set_of_a_two_arm_cycle():
    start, goal = LEG_130
    prob = _straight(start, goal)
    sets = list(removal_sets(prob, start, ALL, max_size=3, max_sets=3))
    R, rest = sets[0]
    # no single arm is enough: arms 4 and 5 cannot pass each other on straight moves
    assert len(R) == 2 and 4 in R
    for k in range(12):
        red = reduced_problem(prob, set([k]), start)
        assert D.solve(red, D.DelayStats(), node_budget=500)[0] is None
    # the rest's schedule is consistent with every pair table of the rest
    K = prob.K
    for (i, j), tab in prob.tables.items():
        if i in R or j in R:
            continue
        (pi, ti), (pj, tj) = rest[i], rest[j]
        assert tab[pi, pj, tj - ti + K]
    # later sets are supersets with one conflicting neighbour more
    assert any(len(S) == 3 and set(R) < set(S) for S, _ in sets)


@pytest.mark.parametrize("reverse,lead,which", [(False, 0, 0), (True, 0, "456"), (False, 3, 0)])
def test_cluster_plan_is_verified_and_only_the_cluster_stops(reverse, lead, which):
    start, goal = LEG_130
    prob = _straight(start, goal)
    sets = list(removal_sets(prob, start, ALL, max_size=3, max_sets=3))
    if which == "456":
        R, rest = next((S, r) for S, r in sets if sorted(S) == [4, 5, 6])
    else:
        R, rest = sets[which]
    out = plan_cluster(GEOMS, start, goal, prob, R, rest, buffer_mm=5.0,
                       params=SearchParams(max_states_per_arm=3000), rparams=RoadmapParams(max_edges_per_path=2),
                       seed=0, reverse=reverse, stats=SearchStats(), lead_steps=lead)
    assert out is not None
    trajs = _trajs(out)
    rep = verify_trajectories(INST, trajs, start, goal, max_start_stop=1)
    assert rep.ok, rep.violations[:3]
    stops = [stop_count(t.t_s, t.theta1_rad, t.theta2_rad) for t in trajs]
    assert max(stops) <= 1
    assert all(stops[k] == 0 for k in range(12) if k not in R)  # the rest keeps its straight moves


@pytest.mark.parametrize("leg", [LEG_129, LEG_130], ids=["c128-c129", "c129-c130"])
def test_benchmark_cycle_legs_plan(leg):
    start, goal = leg
    plan = plan_motion(INST, start, goal, time_budget_s=30.0)
    assert plan.status == "ok", plan.stats.get("reasons")
    assert verify_trajectories(INST, plan.trajectories, start, goal, max_start_stop=1).ok
    assert max(stop_count(t.t_s, t.theta1_rad, t.theta2_rad) for t in plan.trajectories) <= 1


def _cluster(start, goal, straight, blamed):
    """The cluster strategy on a straight-move problem, without a deadline."""
    leg = Leg.build(INST, start, goal, MotionOptions(collision_buffer_mm=5.0))
    strategy = Cluster(params=SearchParams(max_states_per_arm=1500), rparams=RoadmapParams(max_edges_per_path=2))
    return strategy.plan_straight(leg, straight, blamed, float("inf"))


def test_cluster_solves_a_leg_the_straight_delays_cannot():
    start, goal = LEG_129
    prob = _straight(start, goal)
    out = _cluster(start, goal, prob, [])
    assert isinstance(out, Candidate) and out.strategy == "cluster"
    st = out.stats
    assert verify_trajectories(INST, out.trajectories, start, goal, max_start_stop=1).ok
    # a single arm detouring is not enough here: arm 5 sweeps arm 6's start and goal for 90 s
    assert st["cluster"]["removal_sets"][0] == [6]
    assert len([a for a in st["cluster"]["attempts"] if a.get("clear")]) == 1
    assert len(st["cluster"]["attempts"][-1]["arms"]) == 2


def test_delay_stage_pauses_for_the_cluster_strategy():
    """The straight phase pauses once, on straight options only, when every straight option
    failed; detour rounds known to be futile end at once (no detour round runs)."""
    start, goal = LEG_130
    st = D.DelayStats()
    search = D.DelaySearch(GEOMS, start, goal, dt_s=6.0, dt_col_s=0.1, horizon_s=220.0, buffer_mm=5.0,
                           max_start_stop=1, movable=ALL, stats=st)
    assert search.straight_phase() is None and search.paused
    straight, blamed = search.straight, search.blamed
    assert all(o.kind == "straight" for opts in straight.options for o in opts) and blamed
    # both theta2 directions were offered before giving up on straight moves
    assert sum(len(o) for o in straight.options) == sum(len(D.straight_options(GEOMS[k], start[k], goal[k]))
                                                        for k in ALL)
    st2 = D.DelayStats()
    search2 = D.DelaySearch(GEOMS, start, goal, dt_s=6.0, dt_col_s=0.1, horizon_s=220.0, buffer_mm=5.0,
                            max_start_stop=1, movable=ALL, stats=st2)
    assert search2.straight_phase() is None
    res2 = search2.detour_phase(futile=True)
    assert res2.assignment is None
    assert any(e.get("extend") == "futile" for e in st2.log)
    assert all(o.kind == "straight" for opts in res2.options for o in opts)  # no detour round ran


def test_cluster_runs_even_when_the_delay_stage_is_out_of_time():
    """A loaded machine can use up the delay stage's share on the straight tables alone: the
    search still pauses with the round-0 straight problem, and the cluster strategy (its own
    share) solves the leg from it."""
    import time

    start, goal = LEG_130
    search = D.DelaySearch(GEOMS, start, goal, dt_s=6.0, dt_col_s=0.1, horizon_s=220.0, buffer_mm=5.0,
                           max_start_stop=1, movable=ALL, stats=D.DelayStats())
    assert search.straight_phase(deadline=time.perf_counter()) is None and search.paused
    out = _cluster(start, goal, search.straight, list(search.blamed))
    assert isinstance(out, Candidate)
    assert verify_trajectories(INST, out.trajectories, start, goal, max_start_stop=1).ok


def test_long_cluster_plan_gets_a_shorter_search():
    """park -> c129: the cluster plan (the rest's straight schedule takes the long theta2 way,
    1.43 x the lower bound) is replaced by a shorter plan when one is found."""
    start, goal = PARK_129
    plan = plan_motion(INST, start, goal, time_budget_s=30.0)
    assert plan.status == "ok"
    assert verify_trajectories(INST, plan.trajectories, start, goal, max_start_stop=1).ok
    if "first_makespan_s" in plan.stats:
        assert plan.makespan_s <= plan.stats["first_makespan_s"]
    assert plan.makespan_s <= 120.0


def _from_park(rows: dict) -> np.ndarray:
    q = INST.park_configuration.copy()
    for k, v in rows.items():
        q[k] = v
    return q


# examples/requests/plan.json (dense 12-star M13 field) as service/pipeline.py allocates it:
# the leg c2 -> c3. Arms 1, 4, 7 and 10 each have both theta2 directions of their straight
# move blocked (a parked neighbour on one side, a parked or moving one on the other), so the
# delay CSP's arc consistency empties at once and no set of <= 3 arms can be removed; the
# parked arms 0, 3, 6, 9 blocking the short ways step aside instead (one stop each).
C2 = _from_park({1: [1.201720230552, 2.860555045331], 4: [1.256330123432, 2.779656613261],
                 5: [1.444315923238, 3.049271134635], 7: [1.0741056092, 2.617052626029]})
C3 = _from_park({10: [0.868878796377, 2.640397417669], 11: [0.701528088842, 3.204475107979]})


def test_service_example_leg_c2_c3_plans_by_parked_arms_stepping_aside():
    prob = _straight(C2, C3)
    from planner.cluster import blockers, contradicted_arms

    assert contradicted_arms(prob) == [1, 4, 7, 10]
    assert sorted({j for k in [1, 4, 7, 10] for j in blockers(prob, k)}) == [0, 3, 6, 9]
    sets = [R for R, _ in removal_sets(prob, C2, ALL)]
    assert sets[0] == [0, 3, 6, 9]
    plan = plan_motion(INST, C2, C3, time_budget_s=5.0, seed=1)  # the service's leg budget
    assert plan.status == "ok", plan.stats.get("reasons")
    assert verify_trajectories(INST, plan.trajectories, C2, C3, max_start_stop=1).ok
    assert max(stop_count(t.t_s, t.theta1_rad, t.theta2_rad) for t in plan.trajectories) <= 1
