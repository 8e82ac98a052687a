"""The motion-planning driver: strategies tried in order, one verifier at the exit (thesis 6.3).

:func:`plan_motion` builds the options (:class:`planner.options.MotionOptions`) and the leg
(:class:`planner.strategy.Leg`) once, rejects unplannable ends (6.3.1 assumes feasible
ends), then tries the strategies (:mod:`planner.strategies`) in this order:

1. "delays": straight zero-stop moves with departure delays;
2. "sequenced": straight moves and one-stop detours planned arm by arm on a time grid, the
   order adapting to the arm that could not be planned (it plans almost every leg the
   delays leave);
   then "evasion", "cluster" (with ``max_start_stop`` >= 1): state-time detours for the
   smallest conflicting arm set, and "detours": the delay CSP's one-stop detour rounds.
   A leg from park tries "evasion" before "sequenced": it plans in well under a second
   most of the park legs on which the sequenced search spends its whole share, and costs
   little on the others; on chained legs it rarely succeeds and only delays the sequenced
   search;
3. "prioritized" when "forward" / "reverse" are named: thesis Algorithm 6 with priority
   rotation and time reversal;
4. any other registered strategy named in ``strategies``, in the given order;
5. "via" (when named, or after the prioritized strategy when ``via`` is set): two zero-stop
   legs through park or another configuration.

Every candidate goes through :func:`planner.verify.verify_trajectories` exactly once; a
rejected candidate is logged in ``stats["attempt_log"]`` and the next strategy is tried.
A verified plan from the delays, evasion or cluster strategies longer than
``SEQUENCED_SHORTER_RATIO`` x the lower bound lets the sequenced strategy try for a shorter
one with part of the remaining budget (the prioritized strategy, above
``CLUSTER_MAKESPAN_RATIO``, when "sequenced" is not among the strategies); the shorter
verified plan is kept. The
budget shares are those of :mod:`planner.options`.

Only the driver imports the verifier. Unplannable input fails fast with status "failed";
only malformed input raises :class:`models.errors.InputError`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

import planner.strategies  # noqa: F401 - registers the strategies
from models import clock
from models.budget import Budget
from models.instrument import Instrument
from models.kinematics import positive_turn_move_time_s
from models.types import ArmTrajectory, MotionPlan
from planner import options as sh
from planner.commands import stop_count
from planner.options import DEFAULT_STRATEGIES, MotionOptions
from planner.registry import STRATEGIES
from planner.strategy import (
    Candidate,
    Leg,
    LegCache,
    Refusal,
    Strategy,
    merge_stats,
    same_configuration,
    stage_budget,
    unplannable,
)
from planner.verify import verify_trajectories

PRIORITIZED_NAMES = ("forward", "reverse", "prioritized")


def strategy_sequence(options: MotionOptions, from_park: bool = False) -> list[Strategy]:
    """The strategies of ``options.strategies`` in the driver's order (module docstring);
    ``from_park``: the leg starts at park, and "evasion" goes before "sequenced"."""
    names = options.strategies
    seq: list[Strategy] = []
    if "delays" in names:
        seq.append(STRATEGIES["delays"])
    middle = [n for n in (("evasion", "sequenced") if from_park else ("sequenced", "evasion")) if n in names]
    seq += [STRATEGIES[n] for n in middle]
    if "delays" in names:
        seq += ([STRATEGIES["cluster"]] if "cluster" in names else []) + [STRATEGIES["detours"]]
    prio = any(n in names for n in PRIORITIZED_NAMES)
    if prio:
        seq.append(STRATEGIES["prioritized"])
    for n in dict.fromkeys(names):
        if n not in ("delays", "cluster", "evasion", "sequenced", "via") + PRIORITIZED_NAMES:
            seq.append(STRATEGIES[n])
    if "via" in names or (prio and options.via is not None):
        seq.append(STRATEGIES["via"])
    return seq


def failed_plan(leg: Leg, arms: Sequence[int], stats: dict) -> MotionPlan:
    """Status "failed": every arm resting at its start, ``arms`` named."""
    q = leg.start_q
    trajs = tuple(ArmTrajectory(k, np.array([0.0]), q[k, :1].copy(), q[k, 1:].copy()) for k in range(leg.n_arms))
    return MotionPlan("failed", float("nan"), trajs, tuple(sorted({int(a) for a in arms})), stats)


def _verify(leg: Leg, cand: Candidate, stats: dict):
    """The one verification of a candidate; the result stamped on its attempt-log entry."""
    rep = verify_trajectories(leg.instrument, cand.trajectories, leg.start_q, leg.goal_q,
                              collision_buffer_mm=leg.buffer_mm, max_start_stop=leg.options.max_start_stop)
    log = stats.setdefault("attempt_log", [])
    if not cand.stats.get("attempt_log"):
        log.append({"direction": cand.strategy})
    log[-1]["verified"] = rep.ok
    stats["verify_pair_samples"] = rep.pair_samples_checked
    if rep.ok:
        stats["strategy"] = cand.strategy
        stats["min_clearance_mm"] = rep.min_clearance_mm
    else:
        log[-1]["violations"] = [(v.kind, v.arms, v.detail) for v in rep.violations[:5]]
    return rep


def _shorter_searches(leg: Leg, strategy: str) -> list[tuple[Strategy, float]]:
    """The strategies that may look for a shorter plan than one of ``strategy``, each with the
    makespan / lower bound ratio above which it does (and above MAKESPAN_GOAL_S whatever the
    ratio): the straight delays again on FINE_DELAY_STEP_S after a delays plan (only over
    MAKESPAN_GOAL_S), "sequenced" after the straight delays, evasion or cluster
    (SEQUENCED_SHORTER_RATIO), then "prioritized" after evasion, cluster or sequenced
    (CLUSTER_MAKESPAN_RATIO)."""
    o = leg.options
    out: list[tuple[Strategy, float]] = []
    if strategy == "delays" and o.dt_s > sh.FINE_DELAY_STEP_S:
        out.append((STRATEGIES["delays"], math.inf))  # only over MAKESPAN_GOAL_S, on the fine step
    if strategy in sh.SEQUENCED_SHORTER_AFTER and "sequenced" in o.strategies:
        out.append((STRATEGIES["sequenced"], sh.SEQUENCED_SHORTER_RATIO))
    if strategy in sh.SHORTER_SEARCH_AFTER and any(s in o.strategies for s in ("forward", "reverse")):
        out.append((STRATEGIES["prioritized"], sh.CLUSTER_MAKESPAN_RATIO))
    return out


def positive_turn_bound_s(leg: Leg) -> float:
    """The longest straight move of the leg with every arm turning theta2 the positive way (s)."""
    v1 = leg.instrument.arm_array("joint1_speed_rad_s")
    v2 = leg.instrument.arm_array("joint2_speed_rad_s")
    return float(np.max(positive_turn_move_time_s(leg.start_q, leg.goal_q, v1, v2), initial=0.0))


def at_positive_turn_bound(leg: Leg, makespan_s: float) -> bool:
    """A plan from park as long as its positive-turn bound (up to POSITIVE_BOUND_TOL_S longer).

    Such a plan is as short as any plan turning the bounding arm the positive way; a shorter
    one must turn it the negative way, through its neighbour's side of the gap between them
    (docs/motion.md, "Leaving park one way round"). The sequenced search rarely finds those: on
    the measured legs it spent up to 3.7 s each without shortening such a plan by more than
    0.2 s. The prioritized search still runs: its time-reversed attempts sometimes take the
    negative way.
    """
    if not same_configuration(leg.start_q, leg.instrument.park_configuration):
        return False
    return 0.0 <= makespan_s - positive_turn_bound_s(leg) + 1e-6 <= sh.POSITIVE_BOUND_TOL_S


def fine_step_leg(leg: Leg) -> Leg:
    """The leg with departures on FINE_DELAY_STEP_S and a cache of its own (the delay
    tables depend on the step)."""
    opts = dataclasses.replace(leg.options, dt_s=sh.FINE_DELAY_STEP_S, via=None)
    return Leg(leg.instrument, leg.start_q, leg.goal_q, opts, leg.buffer_mm, leg.geoms, leg.enabled,
               leg.lower_bound_s, LegCache())


def _shorter(leg: Leg, cand: Candidate, budget: Budget, stats: dict) -> MotionPlan | None:
    """The driver's "keep the shorter plan" policy after a long verified candidate: the
    shortest verified plan of the searches of :func:`_shorter_searches`, if shorter. The
    sequenced search is not run on a plan at its positive-turn bound
    (:func:`at_positive_turn_bound`)."""
    o = leg.options
    best: MotionPlan | None = None
    best_s = cand.makespan_s
    opts = dataclasses.replace(o, max_attempts=min(o.max_attempts, sh.SHORTER_SEARCH_ATTEMPTS), via=None)
    alt_leg = Leg(leg.instrument, leg.start_q, leg.goal_q, opts, leg.buffer_mm, leg.geoms, leg.enabled,
                  leg.lower_bound_s, dataclasses.replace(leg.cache))
    for searcher, ratio in _shorter_searches(leg, cand.strategy):
        long = best_s > ratio * leg.lower_bound_s or best_s > sh.MAKESPAN_GOAL_S
        if not (leg.lower_bound_s > 0 and budget.left_s() > sh.SHARES.shorter_search_min_left_s and long):
            continue
        if searcher.name == "sequenced" and at_positive_turn_bound(leg, best_s):
            stats["shorter_search_skipped"] = "sequenced: at the positive-turn bound"
            continue
        t_a = clock.now()
        on = fine_step_leg(leg) if searcher.name == "delays" else alt_leg
        out = searcher.plan(on, sh.SHARES.share(budget, sh.SHARES.shorter_search, budget.left_s()))
        alt_stats = merge_stats({}, out.stats)
        ok = isinstance(out, Candidate) and _verify(on, out, alt_stats).ok
        stats["first_makespan_s"] = cand.makespan_s
        stats.setdefault("shorter_search", []).append(
            {"strategy": searcher.name, "status": "ok" if ok else "failed",
             "makespan_s": out.makespan_s if ok else math.nan, "compute_s": clock.now() - t_a})
        if ok and out.makespan_s < best_s:
            merge_stats(stats, alt_stats)
            best_s = float(out.makespan_s)
            best = MotionPlan("ok", best_s, out.trajectories, (), stats)
    return best


def plan_leg(leg: Leg, budget: Budget, sequence: Sequence[Strategy] | None = None) -> MotionPlan:
    """Plan one leg: precheck, the strategies in order, each candidate verified once."""
    t0 = clock.now()
    stats: dict = {"lower_bound_s": leg.lower_bound_s, "attempts": 0, "collision_checks": 0,
                   "states_explored": 0, "paths_explored": 0, "attempt_log": []}
    reasons = unplannable(leg)
    if reasons:
        stats["reasons"] = {int(k): v for k, v in reasons.items()}
        stats["compute_s"] = clock.now() - t0
        return failed_plan(leg, list(reasons), stats)
    refusal: Refusal | None = None
    rejected: tuple[tuple[int, ...], dict[int, str]] | None = None
    timed_out = False
    if sequence is None:
        sequence = strategy_sequence(leg.options, same_configuration(leg.start_q, leg.instrument.park_configuration))
    for strategy in sequence:
        if budget.expired():  # the leg's time limit: no further strategy is started
            timed_out = True
            break
        out = strategy.plan(leg, stage_budget(strategy.name, leg, budget))
        merge_stats(stats, out.stats)
        if isinstance(out, Refusal):
            if out.arms:
                refusal = out
            if out.final:
                break
            continue
        rep = _verify(leg, out, stats)
        if rep.ok:
            plan = _shorter(leg, out, budget, stats) or MotionPlan("ok", float(out.makespan_s), out.trajectories, (),
                                                                    stats)
            # counted here, once, on the trajectories returned (a shorter search's plan may
            # have replaced the first candidate): the strategies do not report it
            stats["max_stops"] = max_stops(plan.trajectories)
            stats["compute_s"] = clock.now() - t0
            return plan
        kind = rep.violations[0].kind if rep.violations else "unknown"
        rejected = (rep.arms, {int(a): "verification failed: " + kind for a in rep.arms})
    if refusal is not None:
        arms, why = refusal.arms, refusal.reasons
    elif rejected is not None:
        arms, why = rejected
    else:
        arms, why = tuple(leg.enabled), {int(a): "time budget exhausted" if timed_out else "no strategy left"
                                         for a in leg.enabled}
    stats["reasons"] = {int(a): why.get(a, "not planned") for a in arms}
    stats["compute_s"] = clock.now() - t0
    return failed_plan(leg, arms, stats)


def plan_motion(
    instrument: Instrument,
    start_q: np.ndarray,
    goal_q: np.ndarray,
    *,
    dt_s: float = 6.0,
    dt_col_s: float = 0.1,
    max_start_stop: int = 1,
    collision_buffer_mm: float | None = None,
    seed: int = 0,
    horizon_s: float = 220.0,
    max_attempts: int = 10,
    time_budget_s: float = 10.0,
    grid: tuple[int, int] = (8, 6),
    strategies: Sequence[str] = DEFAULT_STRATEGIES,
    rpp: bool = False,
    rpp_max_paths: int = 8,
    turn_sense: int = 1,
    turn_bias_s: float = 0.0,
    via: np.ndarray | None | str = "park",
    options: MotionOptions | None = None,
    budget: Budget | None = None,
) -> MotionPlan:
    """Collision-free, verified trajectories of all arms from ``start_q`` to ``goal_q`` (thesis 6.3).

    ``start_q`` / ``goal_q`` are (n_arms, 2) joint angles (theta1, theta2) in rad; the
    start's theta2 may be unwrapped (continuing a previous trajectory), the goal's counts
    modulo 2 pi. Returns a :class:`~models.types.MotionPlan`: per arm timed way-points
    (linear joint motion between them; the MCC2 really executes each move as a trapezoidal
    LSPB profile from rest to rest) and controller commands per joint. ``status`` is "ok"
    only when the independent verifier passed; "failed" plans name ``failed_arms`` and give
    reasons in ``stats["reasons"]`` (never an exception for an unplannable case).

    The keywords are the fields of :class:`~planner.options.MotionOptions` (thesis table
    6.1: ``dt_s`` the motion-action step, ``dt_col_s`` the collision-check step,
    ``max_start_stop`` the stops allowed per arm, ``horizon_s`` T_f); ``options``, when
    given, replaces them all. ``budget`` (on the caller's clock; default:
    ``time_budget_s`` from now) is shared by the strategies (module docstring). Same input,
    ``seed`` and budget -> same plan.
    """
    if options is None:
        options = MotionOptions(dt_s=dt_s, dt_col_s=dt_col_s, max_start_stop=max_start_stop,
                                collision_buffer_mm=collision_buffer_mm, seed=seed, horizon_s=horizon_s,
                                max_attempts=max_attempts, grid=grid, strategies=tuple(strategies), rpp=rpp,
                                rpp_max_paths=rpp_max_paths, turn_sense=turn_sense, turn_bias_s=turn_bias_s,
                                via=via)
    budget = Budget.start(time_budget_s) if budget is None else budget
    return plan_leg(Leg.build(instrument, start_q, goal_q, options), budget)


def max_stops(trajectories: Sequence[ArmTrajectory]) -> int:
    """The most start-stop cycles any arm makes on ``trajectories`` (thesis 6.3.4.4; 0: none)."""
    return max((int(stop_count(t.t_s, t.theta1_rad, t.theta2_rad)) for t in trajectories), default=0)


def verified_plan(instrument: Instrument, trajectories: Sequence[ArmTrajectory], start_q: np.ndarray,
                  goal_q: np.ndarray, *, max_start_stop: int | None, stats: dict) -> MotionPlan | None:
    """A plan composed of verified pieces (a time reversal, two legs joined at park), verified
    once as a whole; None when the verifier rejects it. ``max_start_stop`` None leaves the
    stop count to the caller (a leg through park stops there once more)."""
    rep = verify_trajectories(instrument, trajectories, start_q, goal_q, max_start_stop=max_start_stop)
    if not rep.ok:
        return None
    stats = {**stats, "min_clearance_mm": rep.min_clearance_mm, "max_stops": max_stops(trajectories),
             "verify_pair_samples": rep.pair_samples_checked}
    return MotionPlan("ok", max(float(t.t_s[-1]) for t in trajectories), tuple(trajectories), (), stats)


def plan_chain(instrument: Instrument, configurations: Sequence[np.ndarray], *,
               start_q: np.ndarray | None = None, end_q: np.ndarray | None = None,
               **kwargs) -> list[MotionPlan]:
    """Plans park -> c1 -> c2 -> ... -> park (one :class:`MotionPlan` per leg, len = len(configs) + 1).

    ``start_q`` / ``end_q`` default to the park configuration. Each leg starts where the
    previous one really ended (theta2 unwrapped); after a failed leg the next one starts
    from that leg's intended goal (the arms must be brought there by other means first).
    ``kwargs`` go to :func:`plan_motion`.
    """
    park = instrument.park_configuration
    seq = [park if start_q is None else np.asarray(start_q, float)]
    seq += [np.asarray(c, float) for c in configurations]
    seq.append(park if end_q is None else np.asarray(end_q, float))
    out = []
    cur = seq[0]
    for goal in seq[1:]:
        p = plan_motion(instrument, cur, goal, **kwargs)
        out.append(p)
        if p.status == "ok":
            cur = np.array([[tr.theta1_rad[-1], tr.theta2_rad[-1]] for tr in p.trajectories])
        else:
            cur = goal
    return out


__all__ = ["plan_motion", "plan_chain", "plan_leg", "strategy_sequence", "failed_plan", "verified_plan"]
