"""Cluster strategy: straight delayed moves for most arms, state-time detours for the smallest
conflicting set (:mod:`planner.cluster`; thesis Algorithm 6's obstacle-time set, 6.3).

It runs after the "delays" strategy found no straight schedule: the paused delay search in
the leg's cache holds the straight-move problem, whose pair tables give the removal sets
R. For each R the rest keeps its CSP schedule and R is planned by state-time search
against it, forward, in reverse time (kaiju), then with a head start. The removal sets go
back into the cache for the detour rounds (:mod:`planner.strategies.delays`).
"""

from __future__ import annotations

from models import clock
from models.budget import Budget
from planner.cluster import ClusterStats, plan_cluster, removal_sets
from planner.commands import arm_trajectory
from planner.geometry import timed_collisions
from planner.roadmap import RoadmapParams
from planner.single_arm import SearchParams, SearchStats
from planner.strategy import Candidate, Leg, Refusal

# cheapest and most often successful first: forward without head start for every set
TRIES = ((0, False), (0, True), (3, False), (3, True))  # (lead steps, reverse)


def search_params(leg: Leg) -> tuple[SearchParams, RoadmapParams]:
    o = leg.options
    params = SearchParams(dt_s=o.dt_s, dt_col_s=o.dt_col_s, max_start_stop=o.max_start_stop,
                          horizon_steps=o.horizon_steps, max_states_per_arm=1500,
                          max_paths=64)  # a parked arm's step-aside paths tie in rank
    rparams = RoadmapParams(grid=o.grid, max_edges_per_path=o.max_start_stop + 1, turn_sense=o.turn_sense,
                            turn_bias_s=o.turn_bias_s)
    return params, rparams


class Cluster:
    """Removal-set cluster strategy; needs the "delays" strategy's paused search in the cache."""

    name = "cluster"

    def __init__(self, params: SearchParams | None = None, rparams: RoadmapParams | None = None) -> None:
        self.params, self.rparams = params, rparams

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        search = leg.cache.delay_search
        if leg.options.max_start_stop < 1 or search is None or not search.paused or search.straight is None:
            return Refusal()
        t_c = clock.now()
        try:
            return self.plan_straight(leg, search.straight, list(search.blamed), budget)
        finally:
            leg.cache.cluster_s = clock.now() - t_c

    def plan_straight(self, leg: Leg, straight, blamed: list[int], budget: Budget | float) -> Candidate | Refusal:
        """The strategy on a given straight-move problem (:class:`planner.delays.DelayProblem`)
        and the arms the delay CSP blamed, within ``budget`` (or until a
        :func:`models.clock.now` instant); removal sets stored in ``leg.cache``."""
        if not isinstance(budget, Budget):
            budget = Budget.ending_at(budget)
        t_c = clock.now()
        params, rparams = search_params(leg)
        params, rparams = self.params or params, self.rparams or rparams
        cst, st = ClusterStats(), SearchStats()
        out_c = None
        sets = list(removal_sets(straight, leg.start_q, list(leg.enabled), max_size=3, max_sets=3, first=blamed,
                                 budget=budget, stats=cst))
        leg.cache.removal_sets = [R for R, _ in sets]
        # the search was neither cut short nor left undecided by the node budget
        leg.cache.removal_complete = not budget.past_deadline() and cst.inconclusive == 0
        for lead, rev, R, rest in [(lead, rev, R, rest) for lead, rev in TRIES for R, rest in sets]:
            if budget.past_deadline():
                break
            cst.attempts += 1
            out = plan_cluster(list(leg.geoms), leg.start_q, leg.goal_q, straight, R, rest, buffer_mm=leg.buffer_mm,
                               params=params, rparams=rparams, seed=leg.options.seed, reverse=rev, stats=st,
                               budget=budget, lead_steps=lead)
            cst.log.append({"arms": list(R), "reverse": rev, "lead_steps": lead, "planned": out is not None})
            if out is None:
                continue
            clear = not timed_collisions(leg.geoms, out, leg.buffer_mm)
            cst.log[-1]["clear"] = clear
            if clear:
                out_c = tuple(arm_trajectory(k, t, q) for k, (t, q) in enumerate(out))
                break
        stats = {"collision_checks": st.collision_checks, "states_explored": st.states_explored,
                 "cluster": {"removal_tests": cst.removal_tests, "removal_sets": cst.removal_sets,
                             "attempts": cst.log, "compute_s": clock.now() - t_c}}
        if out_c is None:
            stats["attempt_log"] = [{"direction": "cluster", "verified": False}]
            return Refusal((), {}, stats)
        stats["attempt_log"] = [{"direction": "cluster"}]
        stats["attempts"] = 1
        return Candidate(out_c, max(float(tr.t_s[-1]) for tr in out_c), "cluster", stats)
