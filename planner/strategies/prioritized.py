"""Prioritized state-time planning with replanning (thesis Algorithm 6, 6.4.1, 6.4.2).

Arms are planned one at a time in priority order (:func:`planner.prioritized.plan_in_order`),
longest estimated travel first (6.4.1). When an arm finds no trajectory the strategy does
not give up (6.4.2 suggests re-running with other priorities); within ``max_attempts`` and
its budget it cycles through:

* priority rotation: the failed arm is promoted to the front of the order (a rotation that
  repeats an order perturbs the rest, seeded);
* time reversal (SDSS-V / kaiju, Sayres et al. 2021): plan goal -> start and play the result
  backwards. Collision-freeness, speeds and stop counts are invariant under t -> T - t; what
  changes is that the crowded end of the move becomes the *start* of the search, where
  goal-conflict waits become departure waits. The directions named in the options
  ("forward", "reverse") alternate, each keeping its own rotated order.

Arms whose start equals their goal are planned like the others, so a resting arm in the way
of a higher-priority arm can step aside along a start -> v -> start roadmap path. A complete
attempt is re-checked for collisions (:func:`planner.geometry.timed_collisions`, what the
dt_col sampling may miss); the arms involved are promoted and the loop goes on.
"""

from __future__ import annotations

import math

import numpy as np

from models.budget import Budget
from planner.geometry import timed_collisions
from planner.prioritized import assemble, conflict_order, plan_in_order
from planner.roadmap import RoadmapParams, RoadmapPath, candidate_paths
from planner.single_arm import SearchParams, SearchStats
from planner.strategy import Candidate, Leg, Refusal

DIRECTIONS = ("forward", "reverse")


def roadmap_paths(leg: Leg, direction: str) -> list[list[RoadmapPath]]:
    """Candidate roadmap paths of every enabled arm (cached per leg and direction, seeded)."""
    if direction not in leg.cache.paths:
        o = leg.options
        rparams = RoadmapParams(grid=o.grid, max_edges_per_path=o.max_start_stop + 1, turn_sense=o.turn_sense,
                                turn_bias_s=o.turn_bias_s)
        a, b = (leg.start_q, leg.goal_q) if direction == "forward" else (leg.goal_q, leg.start_q)
        en = set(leg.enabled)
        leg.cache.paths[direction] = [
            candidate_paths(leg.geoms[k], a[k], b[k], np.random.default_rng([o.seed, k, int(direction == "reverse")]),
                            rparams) if k in en else []
            for k in range(leg.n_arms)
        ]
    return leg.cache.paths[direction]


def _rotate(order: list[int], arm: int, tried: set[tuple[int, ...]], seed: int, attempt: int) -> None:
    """Priority rotation: promote ``arm``; when the order was tried, perturb the rest (seeded)."""
    order.remove(arm)
    order.insert(0, arm)
    if tuple(order) in tried:  # rotation cycles (two arms block each other in both orders)
        rng = np.random.default_rng([seed, attempt])
        tail = order[1:]
        rng.shuffle(tail)
        order[1:] = tail


class Prioritized:
    """Thesis Algorithm 6 with priority rotation and time reversal (stats strategy "forward" /
    "reverse")."""

    name = "prioritized"

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        o = leg.options
        directions = [s for s in o.strategies if s in DIRECTIONS] or list(DIRECTIONS)
        enabled = list(leg.enabled)
        fwd = roadmap_paths(leg, "forward")
        est = {k: (fwd[k][0].est_time_s if fwd[k] else math.inf) for k in enabled}
        no_path = [k for k in enabled if not fwd[k]]
        if no_path:
            return Refusal(tuple(no_path), {k: "no ZoA-free roadmap path from start to goal" for k in no_path},
                           final=True)
        orders = {}
        for d in directions:
            a, b = (leg.start_q, leg.goal_q) if d == "forward" else (leg.goal_q, leg.start_q)
            orders[d] = conflict_order(leg.instrument, list(leg.geoms), roadmap_paths(leg, d), a, b, enabled, est,
                                       leg.buffer_mm)
        return self._attempts(leg, budget, directions, orders)

    def _attempts(self, leg: Leg, budget: Budget, directions: list[str], orders: dict) -> Candidate | Refusal:
        o = leg.options
        params = SearchParams(dt_s=o.dt_s, dt_col_s=o.dt_col_s, max_start_stop=o.max_start_stop,
                              horizon_steps=o.horizon_steps)
        rpp_params = SearchParams(dt_s=o.dt_s, dt_col_s=o.dt_col_s, max_start_stop=o.max_start_stop,
                                  horizon_steps=o.horizon_steps, max_paths=o.rpp_max_paths,
                                  max_states_per_arm=2000) if o.rpp else None
        stats: dict = {"collision_checks": 0, "states_explored": 0, "paths_explored": 0, "attempt_log": []}
        fail_count: dict[int, int] = {}
        tried: dict[str, set[tuple[int, ...]]] = {d: set() for d in directions}
        best_failed: list[int] = []
        last_reason: dict[int, str] = {}
        for attempt in range(o.max_attempts):
            if attempt > 0 and budget.expired():
                break
            direction = directions[attempt % len(directions)]
            order = orders[direction]
            tried[direction].add(tuple(order))
            a_start = leg.start_q if direction == "forward" else leg.goal_q
            st = SearchStats()
            plans, failed = plan_in_order(leg.instrument, leg.geoms, roadmap_paths(leg, direction), a_start, order,
                                          leg.disabled, leg.buffer_mm, params, st, rpp_params, budget)
            stats["attempts"] = attempt + 1
            stats["collision_checks"] += st.collision_checks
            stats["states_explored"] += st.states_explored
            stats["paths_explored"] += st.paths_explored
            log = {"direction": direction, "order": list(order), "failed_arm": failed}
            stats["attempt_log"].append(log)
            if failed is not None:
                fail_count[failed] = fail_count.get(failed, 0) + 1
                last_reason[failed] = "no collision-free trajectory within the horizon"
                _rotate(order, failed, tried[direction], o.seed, attempt)
                continue
            trajs, makespan = assemble(leg.instrument, plans, leg.start_q, o.dt_s, direction == "reverse")
            pairs = timed_collisions(leg.geoms, [(tr.t_s, np.column_stack([tr.theta1_rad, tr.theta2_rad]))
                                                 for tr in trajs], leg.buffer_mm)
            if not pairs:
                return Candidate(trajs, makespan, direction, stats)
            # the re-check found what the dt_col sampling missed: promote the arms involved
            log["collisions"] = [list(p) for p in pairs[:5]]
            arms = sorted({a for p in pairs for a in p})
            for a in arms:
                if a in order:
                    order.remove(a)
                    order.insert(0, a)
                last_reason[a] = "collision found by the re-check of the attempt"
            best_failed = arms
        failed_arms = sorted(fail_count, key=lambda a: (-fail_count[a], a)) or best_failed
        return Refusal(tuple(failed_arms), {int(a): last_reason.get(a, "not planned") for a in failed_arms}, stats)
