"""Cluster strategy: straight delayed moves for most arms, a state-time detour for a conflicting few.

When the departure-delay CSP (:mod:`planner.delays`) finds no schedule, the conflict is
usually local: a cycle of two or three neighbouring arms that sweep each other's start and
goal, so that every arm of the cycle needs a detour (e.g. arm a's straight move hits b's
start and b's hits a's, whatever the delays and theta2 directions). Everybody else can keep
its straight, zero-stop move. This module

1. finds **removal sets** R: the smallest sets of arms (one, then two, then three) whose
   removal makes the straight-move CSP of the other arms solvable (the pair tables are the
   ones the delay stage already computed, so each test is a quick AC + backtracking run);
2. fixes that CSP schedule for the other arms (moving obstacles, thesis Algorithm 6's
   obstacle-time set) and plans only the arms of R, one after the other in every order, with
   the single-arm state-time search along roadmap paths (:func:`planner.single_arm.plan_arm`:
   waits, forward/back, at most ``max_start_stop`` stops, goal-conflict checks), so an arm
   of R can step aside to a roadmap vertex, wait there while its neighbours pass, and go on
   (the thesis' future work "move an arrived arm out of the way", per conflicting arm);
3. does the same in reverse time (SDSS-V / kaiju): the fixed schedule played backwards is a
   valid schedule of the reversed problem, the arms of R are planned goal -> start against
   it and the whole is played forwards again. Forward handles an R arm whose *goal* is swept
   late (it waits before arriving); reverse handles an R arm whose *start* is swept early.

The strategy :mod:`planner.strategies.cluster` wraps it; its result is only a candidate,
which the driver (:mod:`planner.driver`) verifies before returning it.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from models.budget import Budget
from planner.delays import DelayProblem, DelayStats, Option, solve, trajectory_points
from planner.geometry import ArmGeom
from planner.roadmap import RoadmapParams, candidate_paths
from planner.single_arm import ObstacleTime, SearchParams, SearchStats, plan_arm, step_samples


@dataclass
class ClusterStats:
    removal_tests: int = 0
    inconclusive: int = 0  # removal tests that ran out of nodes (no proof of infeasibility)
    removal_sets: list = field(default_factory=list)
    attempts: int = 0
    log: list = field(default_factory=list)


def reduced_problem(prob: DelayProblem, removed: set[int], start_q: np.ndarray) -> DelayProblem:
    """``prob`` without the arms in ``removed`` (each left a single 'stay' option without constraints)."""
    opts = [[Option(k, start_q[k][None].copy(), np.zeros(1), 0, "stay")] if k in removed else o
            for k, o in enumerate(prob.options)]
    red = DelayProblem(opts, prob.K, prob.dt_s, prob.horizon_s, {}, [[] for _ in opts])
    for (i, j), tab in prob.tables.items():
        if i not in removed and j not in removed:
            red.tables[(i, j)] = tab
            red.neighbours[i].append(j)
    return red


def removal_sets(prob: DelayProblem, start_q: np.ndarray, movable: list[int], *, max_size: int = 3,
                 max_sets: int = 4, budget: Budget | None = None, stats: ClusterStats | None = None,
                 first: list[int] | None = None, max_greedy: int = 6):
    """Yield (R, rest assignment): smallest arm sets whose removal makes the rest solvable.

    Only arms with a conflict (a pair table) are candidates; sets of size three are only
    formed from arms adjacent in the conflict graph to a two-arm candidate, to stay cheap.
    ``first`` (e.g. the delay stage's blamed arms) orders the candidates. After the minimal
    sets (at most ``max_sets``), each is yielded again with one conflict-graph neighbour added.
    When no set of at most ``max_size`` arms works, a greedy one (up to ``max_greedy`` arms,
    :func:`contradicted_arms` plus the most blamed) is tried. Once ``budget`` (None: no
    limit) has passed its deadline, no further set is tried.
    """
    cand = [k for k in movable if prob.neighbours[k]]
    pref = {a: i for i, a in enumerate(first or [])}
    cand.sort(key=lambda a: (pref.get(a, len(pref)), a))
    found = 0
    minimal: list[tuple[list[int], dict]] = []
    C = contradicted_arms(prob)
    # a set that neither holds a contradicted arm nor one of its neighbours leaves that arm
    # contradicted: such sets are skipped without a test
    hoods = [set(prob.neighbours[k]) | {k} for k in C]
    for size in range(1, max_size + 1):
        combos = itertools.combinations(cand, size)
        if size == 3:
            # connected triples only (a cycle of neighbours sweeping each other)
            combos = (c for c in combos
                      if sum(1 for x, y in itertools.combinations(c, 2) if y in prob.neighbours[x]) >= 2)
        for R in combos:
            if budget is not None and budget.past_deadline():
                return
            if not all(any(a in h for a in R) for h in hoods):
                continue
            if stats is not None:
                stats.removal_tests += 1
            dst = DelayStats()
            sol, _ = solve(reduced_problem(prob, set(R), start_q), dst, node_budget=500, budget=budget)
            if sol is None and dst.nodes > 500 and stats is not None:
                stats.inconclusive += 1  # node budget, not infeasibility
            if sol is not None:
                found += 1
                if stats is not None:
                    stats.removal_sets.append(list(R))
                minimal.append((list(R), sol))
                yield list(R), sol
                if found >= max_sets:
                    break
        if found:
            break
    if not minimal and (yield from _greedy_sets(prob, C, start_q, movable, max_greedy, budget, stats, minimal)):
        return  # out of time
    # then each minimal set with one conflicting neighbour more (the rest stays solvable: fewer
    # constraints): a neighbour that sweeps the set's start and goal may need its own detour
    seen = set()
    for R, sol in minimal:
        for j in sorted({j for a in R for j in prob.neighbours[a]} - set(R)):
            key = tuple(sorted(R + [j]))
            if key in seen or j not in movable or len(key) > max_size:
                continue
            seen.add(key)
            if budget is not None and budget.past_deadline():
                return
            if stats is not None:
                stats.removal_sets.append(list(R) + [j])
            yield list(R) + [j], {k: v for k, v in sol.items() if k != j}


def _greedy_sets(prob: DelayProblem, C: list[int], start_q: np.ndarray, movable: list[int], max_greedy: int,
                 budget: Budget | None, stats: ClusterStats | None, minimal: list):
    """Removal sets when no small one works: several independent local conflicts (e.g. four
    arms, each with a parked neighbour on either side blocking both its theta2 directions).

    First the arms blocking each contradicted arm's shortest move (often parked neighbours
    that only need to step aside while it passes), then the contradicted arms ``C``
    themselves plus the most blamed arms, one at a time. Yields (R, rest assignment), appends
    them to ``minimal``; returns True when out of time.
    """
    B = sorted({j for k in C for j in blockers(prob, k)} & set(movable))
    if B and len(B) <= max_greedy:
        if stats is not None:
            stats.removal_tests += 1
        sol, _ = solve(reduced_problem(prob, set(B), start_q), DelayStats(), node_budget=500, budget=budget)
        if sol is not None:
            minimal.append((B, sol))
            if stats is not None:
                stats.removal_sets.append(B)
            yield B, sol
    G = [k for k in C if k in movable]
    while G and len(G) <= max_greedy:
        if budget is not None and budget.past_deadline():
            return True
        if stats is not None:
            stats.removal_tests += 1
        sol, blamed = solve(reduced_problem(prob, set(G), start_q), DelayStats(), node_budget=500,
                            budget=budget)
        if sol is not None:
            minimal.append((sorted(G), sol))
            if stats is not None:
                stats.removal_sets.append(sorted(G))
            yield sorted(G), sol
            break
        more = [k for k in blamed if k in movable and k not in G]
        if not more:
            break
        G.append(more[0])
    return False


def contradicted_arms(prob: DelayProblem) -> list[int]:
    """Arms none of whose options is compatible (at some relative delay) with every neighbour.

    For each neighbour the option must work with at least one of the neighbour's options;
    an arm for which these pairwise conditions exclude every option needs a detour (or a
    neighbour must move out of its way) whatever the delays.
    """
    out = []
    for k, nbrs in enumerate(prob.neighbours):
        ok = np.ones(len(prob.options[k]), bool)
        for j in nbrs:
            ok &= prob.tables[(k, j)].any(axis=(1, 2))
        if not ok.any():
            out.append(k)
    return out


def blockers(prob: DelayProblem, k: int) -> list[int]:
    """Neighbours that rule out arm k's shortest option (index 0) at every relative delay."""
    return [j for j in prob.neighbours[k] if not prob.tables[(k, j)][0].any()]


def _timed(option: Option, tau_steps: int, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    return trajectory_points(option, tau_steps * dt_s)


def _sample(t: np.ndarray, q: np.ndarray, ts: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(ts, t, q[:, 0]), np.interp(ts, t, q[:, 1])])


def plan_cluster(geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray, prob: DelayProblem,
                 R: list[int], rest: dict[int, tuple[int, int]], *, buffer_mm: float, params: SearchParams,
                 rparams: RoadmapParams, seed: int, reverse: bool, stats: SearchStats,
                 budget: Budget | None = None, max_orders: int = 6, lead_steps: int = 0,
                 ) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Timed way-points (t, q) of every arm: the rest on its fixed straight schedule, the arms of
    ``R`` planned by state-time search against it (in reverse time when ``reverse``).

    ``lead_steps`` delays the whole rest schedule by that many dt (relative delays, hence its
    collision-freeness, unchanged): the arms of ``R`` get a head start to leave their starts
    (forward) or, in reverse, may arrive at their goals that long after the rest finished.
    None once ``budget`` (None: no limit) has passed its deadline."""
    n = len(geoms)
    dt = params.dt_s
    m = params.m
    H = params.horizon_steps
    ts = np.arange(H * m + 1) * (dt / m)
    timed = {k: _timed(prob.options[k][p], t + (0 if reverse else lead_steps), dt)
             for k, (p, t) in rest.items() if k not in R}
    finish = {k: float(tq[0][-1]) for k, tq in timed.items()}
    Tr = max(finish.values(), default=0.0)
    Nr = int(math.ceil(Tr / dt - 1e-9)) + (lead_steps if reverse else 0)  # rest span in whole steps
    if Nr > H:
        return None
    if reverse:
        a_q, b_q = goal_q, start_q
        # the rest played backwards about Nr dt: arm k rests at its goal, then retraces its move
        obs = {k: (Nr * dt - t[::-1], q[::-1]) for k, (t, q) in timed.items()}
    else:
        a_q, b_q = start_q, goal_q
        obs = timed
    nb = max(len(g.radius) for g in geoms)
    paths = {k: candidate_paths(geoms[k], a_q[k], b_q[k], np.random.default_rng([seed, k, int(reverse), 7]),
                                rparams) for k in R}
    if any(not paths[k] for k in R):
        return None
    # arms of a large set are mostly independent (separate local conflicts): few orders
    orders = list(itertools.permutations(R))[:max_orders if len(R) <= 3 else 2]
    for order in orders:
        if budget is not None and budget.past_deadline():
            return None
        obst = ObstacleTime(m=m, n_steps=H, buffer_mm=buffer_mm, nb=nb)
        for k, (t, q) in obs.items():
            arr = int(math.ceil(float(t[-1]) / dt - 1e-9))
            if len(t) == 1 or np.all(np.abs(q - q[0]) <= 1e-15):
                arr = 0
            obst.add(geoms[k], _sample(t, q, ts), arr)
        plans = {}
        for k in order:
            if budget is not None and budget.past_deadline():
                return None
            p = plan_arm(geoms[k], paths[k], obst, params, stats)
            if p is None:
                break
            plans[k] = p
            obst.add(geoms[k], step_samples(p.q_steps, m, H), p.arrival_step)
        if len(plans) < len(R):
            continue
        out: list[tuple[np.ndarray, np.ndarray]] = []
        Np = max([Nr] + [p.arrival_step for p in plans.values()])
        for k in range(n):
            if k in plans:
                q = plans[k].played_backwards(Np, start_q[k, 1]) if reverse else plans[k].q_steps
                t = np.arange(len(q)) * dt
                out.append((t, q))
            else:
                t, q = timed[k]
                if reverse and Np > Nr:  # everything in the reversed world ended (Np - Nr) dt later
                    shift = (Np - Nr) * dt
                    t = np.concatenate([[0.0], t + shift])
                    q = np.concatenate([q[:1], q])
                out.append((t, q))
        return out
    return None

