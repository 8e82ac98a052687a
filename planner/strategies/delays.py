"""Departure-delay strategies: straight zero-stop moves with delays, then one-stop detours.

Two strategies over one :class:`planner.delays.DelaySearch` kept in the leg's cache:

* "delays" (:class:`Delays`): every arm makes one straight joint-space move (zero stops, the
  MCC2 ideal) departing after a delay chosen by the pairwise-table CSP, either theta2 way
  round. When every straight option fails it refuses without naming arms and leaves the
  paused search, with its straight-move problem, in the cache: the cluster strategy
  (:mod:`planner.strategies.cluster`) reads it from there.
* "detours" (:class:`Detours`): resumes that search with one-stop detours for the blamed arms,
  extending first the arms of the cluster strategy's smallest removal set when it ran (and
  not at all when it proved them futile). Its plans are reported as strategy "delays".

Candidates are re-checked for collisions by :func:`planner.geometry.timed_collisions` inside
the CSP (an offending relative delay is forbidden and the CSP re-solved); the driver
verifies the result.
"""

from __future__ import annotations

from dataclasses import replace

from models import clock
from models.budget import Budget
from models.types import ArmTrajectory
from planner.commands import arm_trajectory
from planner.delays import DelayResult, DelaySearch, DelayStats, trajectory_points
from planner.geometry import timed_collisions
from planner.strategy import Candidate, Leg, Refusal

NO_SCHEDULE = "no collision-free departure-delay schedule"


def delay_trajectories(assignment: dict[int, tuple[int, int]], options, n: int,
                       dt_s: float) -> tuple[ArmTrajectory, ...]:
    """Way-points and controller commands of a delay-CSP assignment (option, departure step)."""
    return tuple(arm_trajectory(k, *trajectory_points(options[k][assignment[k][0]], assignment[k][1] * dt_s))
                 for k in range(n))


def collision_check(leg: Leg):
    """The CSP's repair oracle: colliding arm pairs of an assignment (planner-internal check)."""
    dt = leg.options.dt_s

    def check(assignment, options) -> list[tuple[int, int]]:
        timed = [trajectory_points(options[k][p], tau * dt) for k, (p, tau) in sorted(assignment.items())]
        return timed_collisions(leg.geoms, timed, leg.buffer_mm)

    return check


def _report(search: DelaySearch, stats: dict) -> None:
    """Counters since the last report, and the CSP's totals so far, into ``stats``."""
    dst: DelayStats = search.stats
    done = getattr(search, "_reported", (0, 0))
    stats["collision_checks"] = dst.pair_samples - done[0]
    stats["states_explored"] = dst.nodes - done[1]
    search._reported = (dst.pair_samples, dst.nodes)
    rounds = search.result.rounds if search.result is not None else search.rnd + 1
    stats["delay_csp"] = {"pair_tables": dst.tables, "nodes": dst.nodes, "repairs": dst.repairs,
                          "rounds": rounds, "compute_s": clock.now() - search.t0}


def finish(leg: Leg, search: DelaySearch, res: DelayResult) -> Candidate | Refusal:
    """The delay CSP's final answer as a candidate or a refusal naming the blamed arms."""
    search.finished = True
    stats: dict = {}
    _report(search, stats)
    if res.assignment is None:
        stats["attempt_log"] = [{"direction": "delays", "failed_arms": list(res.blamed)}]
        return Refusal(tuple(res.blamed), {int(a): NO_SCHEDULE for a in res.blamed}, stats)
    trajs = delay_trajectories(res.assignment, res.options, leg.n_arms, leg.options.dt_s)
    stats["attempts"] = 1
    stats["attempt_log"] = [{"direction": "delays"}]
    return Candidate(trajs, float(res.makespan_s), "delays", stats)


class Delays:
    """Straight moves with departure delays (rounds with straight options only)."""

    name = "delays"

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        o = leg.options
        search = DelaySearch(list(leg.geoms), leg.start_q, leg.goal_q, dt_s=o.dt_s, dt_col_s=o.dt_col_s,
                             horizon_s=o.horizon_s, buffer_mm=leg.buffer_mm, max_start_stop=o.max_start_stop,
                             movable=list(leg.enabled), stats=DelayStats(), grid=o.grid, check=collision_check(leg))
        search.t0 = clock.now()
        search.finished = False
        leg.cache.delay_search = search
        leg.cache.delay_deadline = budget.deadline_s
        res = search.straight_phase(budget=budget, first_round=replace(budget, deadline_s=budget.hard_deadline_s))
        if res is None:  # paused: every straight option failed, the detour rounds may go on
            stats: dict = {}
            _report(search, stats)
            return Refusal((), {}, stats)
        return finish(leg, search, res)


class Detours:
    """The delay CSP's one-stop detour rounds, resuming the paused "delays" search."""

    name = "detours"

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        search = leg.cache.delay_search
        if search is None or search.finished:
            return Refusal()
        prefer, futile = None, False
        sets = leg.cache.removal_sets
        if sets is not None:  # the cluster strategy ran: its smallest removal set first
            prefer = sets[0] if sets else []
            # removing any one or two arms (or three connected ones) leaves the straight CSP
            # unsolvable, so detours for them cannot help either (a removed arm is the loosest
            # detour; beyond pairs this is a heuristic): leave the time to later strategies
            futile = not sets and leg.cache.removal_complete
        return finish(leg, search, search.detour_phase(budget, prefer=prefer, futile=futile))
