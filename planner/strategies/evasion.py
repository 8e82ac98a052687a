"""Evasion strategy: the departure-delay CSP with clear detours and step-aside moves.

For the arm pairs that no departure delay separates (a half turn of J2 sweeps a neighbour
that is in the way at both its start and its goal), :func:`planner.evasion.plan_evasion`
adds one-stop options: detours whose swept path clears the neighbours' start and goal
poses, and step-aside moves of a neighbour off the swinging arm's path; the CSP then
chooses options and departure times for every arm at once. Candidates are re-checked for
collisions inside the CSP (:func:`planner.geometry.timed_collisions`, as the "delays"
strategy does); the driver verifies the result.
"""

from __future__ import annotations

from models import clock
from models.budget import Budget
from planner.delays import DelayStats
from planner.evasion import plan_evasion
from planner.strategies.delays import NO_SCHEDULE, delay_trajectories
from planner.strategy import Candidate, Leg, Refusal


class Evasion:
    """Delays plus evasion options for the infeasible arm pairs (:mod:`planner.evasion`)."""

    name = "evasion"

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        o = leg.options
        if o.max_start_stop < 1:
            return Refusal()
        t0 = clock.now()
        dst = DelayStats()
        search = leg.cache.delay_search  # the "delays" strategy's straight problem, if it ran
        initial = getattr(search, "straight", None) if search is not None else None
        res = plan_evasion(list(leg.geoms), leg.start_q, leg.goal_q, dt_s=o.dt_s, dt_col_s=o.dt_col_s,
                           horizon_s=o.horizon_s, buffer_mm=leg.buffer_mm, movable=list(leg.enabled),
                           stats=dst, budget=budget, initial=initial)
        stats = {"collision_checks": dst.pair_samples, "states_explored": dst.nodes,
                 "evasion": {"rounds": res.rounds, "log": res.log, "compute_s": clock.now() - t0}}
        if res.assignment is None:
            stats["attempt_log"] = [{"direction": "evasion", "failed": True}]
            return Refusal((), {}, stats)
        trajs = delay_trajectories(res.assignment, res.options, leg.n_arms, o.dt_s)
        stats["attempt_log"] = [{"direction": "evasion"}]
        stats["attempts"] = 1
        makespan = max(res.options[k][p].duration_s + t * o.dt_s for k, (p, t) in res.assignment.items())
        return Candidate(trajs, float(makespan), "evasion", stats)


__all__ = ["Evasion", "NO_SCHEDULE"]
