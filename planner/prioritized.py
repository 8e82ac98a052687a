"""Thesis Algorithm 6, the search primitive: arms planned one at a time in priority order.

Each arm is planned against the obstacle-time set of the arms planned before it
(:mod:`planner.single_arm`, Algorithm 7). Priorities follow 6.4.1: the estimated travel
time (eq. 6.23) of each arm's shortest roadmap path, longest first, repaired by the
start/goal conflicts of :func:`conflict_order`. In reverse time (SDSS-V / kaiju, Sayres et
al. 2021) the same search runs goal -> start and :func:`assemble` plays it backwards.

The attempt loop with priority rotation is the strategy
:mod:`planner.strategies.prioritized`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from models.budget import Budget
from models.collision import body_segments_mm, clearance_mm
from models.instrument import Instrument
from models.types import ArmTrajectory
from planner.commands import compress_waypoints, controller_commands
from planner.geometry import ArmGeom
from planner.roadmap import RoadmapPath
from planner.single_arm import (
    ArmPlan,
    ObstacleTime,
    SearchParams,
    SearchStats,
    plan_arm,
    step_samples,
)


def path_samples(path: RoadmapPath, geom: ArmGeom, dt_s: float, n_samples: int) -> np.ndarray:
    """Configurations along a roadmap path at full speed from t = 0, every ``dt_s`` (then at rest)."""
    wp = path.waypoints
    te = np.concatenate([[0.0], np.cumsum(geom.move_time_s(wp[:-1], wp[1:]))]) if len(wp) > 1 else np.zeros(1)
    t = np.arange(n_samples) * dt_s
    return np.column_stack([np.interp(t, te, wp[:, 0]), np.interp(t, te, wp[:, 1])])


def conflict_order(instrument: Instrument, geoms: list[ArmGeom], paths: list[list[RoadmapPath]],
                   start_q: np.ndarray, goal_q: np.ndarray, arms: Sequence[int], est: dict[int, float],
                   buffer_mm: float, dt_s: float = 1.0) -> list[int]:
    """Priority order: longest estimated travel first (thesis 6.4.1), repaired by conflicts.

    Prioritized planning only handles a conflict well one way round: a lower-priority arm
    can wait for a higher one to pass its *goal* (goal conflict, 6.3.4.5), but it cannot
    move out of the way of a higher-priority arm that sweeps through its *start* (the higher
    arm planned without seeing it). So each arm's most promising path, timed at full speed,
    is tested against every other arm parked at its start and at its goal:
    hitting j's start puts j before i, hitting j's goal puts i before j. The order is a
    topological sort of these constraints, choosing the longest estimated travel among the
    free arms (and, on a cycle, among all remaining arms).
    """
    arms = list(arms)
    if len(arms) < 2:
        return arms
    K = int(max(est[k] for k in arms) / dt_s) + 2
    qs = np.stack([path_samples(paths[k][0], geoms[k], dt_s, K) for k in arms])  # (n, K, 2)
    a = np.asarray(arms)
    S, E, R = body_segments_mm(instrument, a[:, None], qs[..., 0], qs[..., 1])  # (n, K, nb, 2)
    Ss, Es, Rs = body_segments_mm(instrument, a, start_q[a, 0], start_q[a, 1])  # (n, nb, 2)
    Sg, Eg, Rg = body_segments_mm(instrument, a, goal_q[a, 0], goal_q[a, 1])
    n = len(a)

    def hits(Sx, Ex, Rx) -> np.ndarray:
        c = clearance_mm((S[:, None], E[:, None], R[:, None]),
                         (Sx[None, :, None], Ex[None, :, None], Rx[None, :, None]))  # (n, n, K)
        h = (c < buffer_mm).any(-1)
        np.fill_diagonal(h, False)
        return h

    before = np.zeros((n, n), bool)  # before[x, y]: x must be planned before y
    hs = hits(Ss, Es, Rs)  # hs[i, j]: path i hits start j -> j before i
    hg = hits(Sg, Eg, Rg)  # hg[i, j]: path i hits goal j -> i before j
    before |= hs.T
    before |= hg
    rank = {k: (-est[k], k) for k in arms}
    remaining = set(range(n))
    order: list[int] = []
    while remaining:
        free = [x for x in remaining if not any(before[y, x] for y in remaining if y != x)]
        pool = free or list(remaining)
        x = min(pool, key=lambda i: rank[arms[i]])
        order.append(arms[x])
        remaining.remove(x)
    return order


def plan_in_order(instrument: Instrument, geoms: Sequence[ArmGeom], paths: list[list[RoadmapPath]],
                  a_start: np.ndarray, order: list[int], disabled: list[int], buffer_mm: float,
                  params: SearchParams, stats: SearchStats,
                  rpp_params: SearchParams | None = None,
                  budget: Budget | None = None) -> tuple[dict[int, ArmPlan], int | None]:
    """One attempt of Algorithm 6: the arms of ``order`` one after the other, each against the
    obstacle-time set of the disabled arms (resting at ``a_start``) and the arms before it.

    Returns (plans per arm, the first arm without a trajectory or None). With ``rpp_params``
    (revised prioritized planning, Cap et al. 2015) an arm first tries to keep clear of the
    arms not yet planned, resting at their starts, so that they can always wait there, and
    falls back to ignoring them. Once ``budget`` (None: no limit) has passed its deadline, the
    next arm is reported as the one without a trajectory.
    """
    m = params.m
    obst = ObstacleTime(m=m, n_steps=params.horizon_steps, buffer_mm=buffer_mm,
                        nb=max(len(a.bodies) for a in instrument.arms))
    for k in disabled:
        obst.add(geoms[k], np.repeat(a_start[k:k + 1], obst.n_samples, axis=0), 0)
    plans: dict[int, ArmPlan] = {k: ArmPlan(k, a_start[k:k + 1].copy(), -1, 1.0) for k in disabled}
    for idx, k in enumerate(order):
        if budget is not None and budget.past_deadline():
            return plans, k
        p = None
        rest = order[idx + 1:]
        if rpp_params is not None and rest:
            p = plan_arm(geoms[k], paths[k], obst.with_static([(geoms[j], a_start[j]) for j in rest]),
                         rpp_params, stats)
        if p is None:
            p = plan_arm(geoms[k], paths[k], obst, params, stats)
        if p is None:
            return plans, k
        plans[k] = p
        obst.add(geoms[k], step_samples(p.q_steps, m, params.horizon_steps), p.arrival_step)
    return plans, None


def assemble(instrument: Instrument, plans: dict[int, ArmPlan], start_q: np.ndarray, dt_s: float,
              reverse: bool) -> tuple[tuple[ArmTrajectory, ...], float]:
    """Per-arm way-points and commands; reversed plans are played backwards (kaiju)."""
    T = max(p.arrival_step for p in plans.values())
    out = []
    for k in range(instrument.n_arms):
        q = plans[k].played_backwards(T, start_q[k, 1]) if reverse else plans[k].q_steps
        t = np.arange(len(q)) * dt_s
        t, q = compress_waypoints(t, q)
        if len(t) > 1 and np.all(np.abs(q - q[0]) <= 1e-15):
            t, q = t[:1], q[:1]
        out.append(ArmTrajectory(k, t, q[:, 0].copy(), q[:, 1].copy(), controller_commands(t, q[:, 0], q[:, 1])))
    return tuple(out), T * dt_s
