"""Sequenced strategy: straight moves planned one arm at a time on a shared time grid.

:func:`planner.sequenced.plan_sequenced` takes the arms in a priority order and gives each
its earliest safe straight move, or a one-stop detour through a way-point, against the
motions already planned (:class:`planner.timeline.Timeline`); the order adapts to the arm
that could not be planned. It solves legs the departure-delay CSP cannot: arms that must
wait for a neighbour to clear, and neighbours that must get out of an arm's way before it
arrives. The driver verifies the result.
"""

from __future__ import annotations

from models.budget import Budget
from planner.commands import arm_trajectory
from planner.sequenced import plan_sequenced
from planner.strategies.reversed import reverse_trajectories
from planner.strategy import Candidate, Leg, Refusal

NO_ORDER = "no priority order tried let every arm move"


class Sequenced:
    """Prioritized straight moves and one-stop detours on a time grid (:mod:`planner.sequenced`)."""

    name = "sequenced"

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        res = plan_sequenced(leg, budget)
        stats = {"sequenced": res.stats, "attempts": res.stats.get("attempts", 0)}
        if res.timeline is None:
            stats["attempt_log"] = [{"direction": "sequenced", "failed": True}]
            arms = tuple(sorted(res.failed_arms[:1]))
            return Refusal(arms, {k: NO_ORDER for k in arms}, stats)
        tl = res.timeline
        trajs = tuple(arm_trajectory(k, *tl.waypoints(k)) for k in range(leg.n_arms))
        if res.reversed:
            trajs = reverse_trajectories(trajs, leg.start_q, tl.makespan_s())
        stats["attempt_log"] = [{"direction": "sequenced"}]
        return Candidate(trajs, float(tl.makespan_s()), "sequenced", stats)


__all__ = ["Sequenced", "NO_ORDER"]
