"""Multi-arm motion planning: departure-delay CSP first, prioritized planning as fallback; chains.

``plan_motion`` tries, in order: (1) "delays" (:mod:`planner.delays`): every arm makes one
straight joint-space move (zero stops, the MCC2 ideal) departing after a delay chosen by a
small CSP over pairwise relative-delay tables; when that fails, (1b) "cluster"
(:mod:`planner.cluster`): the smallest set of arms whose removal makes that CSP solvable is
planned by state-time search against the others' fixed straight schedule, and then the
delay CSP's one-stop detour rounds, starting with that set's arms; (2) the prioritized
state-time planning below; (3) two zero-stop legs through park (or another ``via``
configuration). Every result passes the verifier before "ok". The time budget is shared:
the delay stage gets at most 30 % (<= 3 s), the cluster strategy its own 25 % (<= 2.5 s),
and 15 % (<= 1.5 s) is kept for the two-leg fallback; the prioritized stage has the rest.

Thesis Algorithm 6: arms are planned one at a time in priority order, each against the
obstacle-time set of the arms planned before it (:mod:`planner.single_arm`). Priorities
follow 6.4.1: the estimated travel time (eq. 6.23) of each arm's shortest roadmap path,
longest first, so the arm that bounds the makespan gets the empty workspace.

When an arm finds no trajectory the planner does not give up (thesis 6.4.2 suggests
re-running with other priorities); within ``max_attempts`` / ``time_budget_s`` it cycles
through strategies:

* priority rotation: the failed arm is promoted to the front of the order;
* time reversal (SDSS-V / kaiju, Sayres et al. 2021): plan goal -> start instead and play
  the result backwards. Collision-freeness, speeds and stop counts are invariant under
  t -> T - t; what changes is that the crowded end of the move becomes the *start* of the
  search, where prioritized planning's goal-conflict waits become departure waits. Forward
  and reversed attempts alternate, each direction keeping its own rotated order.

Arms whose start equals their goal are planned like the others, so a resting arm in the way
of a higher-priority arm can step aside along a start -> v -> start roadmap path (the
thesis' "move an arrived arm out of the way" future work, in its simplest form).

``plan_motion`` returns status "ok" only after :func:`planner.verify.verify_trajectories`
passes; otherwise "failed" with the failing arms named. Unplannable input (a start or goal
in the ZoA, colliding goal configurations) fails fast; only malformed input raises
:class:`models.errors.InputError`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from models.collision import body_segments_mm, clearance_mm, colliding_arm_pairs
from models.errors import InputError
from models.instrument import Instrument
from models.kinematics import direct_move_time_s
from models.types import ArmTrajectory, MotionPlan
from planner.cluster import ClusterStats, plan_cluster, removal_sets
from planner.commands import compress_waypoints, controller_commands, stop_count
from planner.delays import DelayStats, plan_delays, trajectory_points
from planner.geometry import ArmGeom
from planner.roadmap import RoadmapParams, RoadmapPath, candidate_paths
from planner.single_arm import (
    ArmPlan,
    ObstacleTime,
    SearchParams,
    SearchStats,
    plan_arm,
    step_samples,
)
from planner.verify import verify_trajectories

TWO_PI = 2.0 * np.pi
# a cluster plan longer than this times the lower bound lets the prioritized stage try for a
# shorter one (rare: the rest's straight schedule, not the detouring arms, sets its length)
CLUSTER_MAKESPAN_RATIO = 1.25


def _check_q(instrument: Instrument, q, name: str) -> np.ndarray:
    a = np.asarray(q, dtype=float)
    if a.shape != (instrument.n_arms, 2):
        raise InputError(name, f"expected shape ({instrument.n_arms}, 2), got {a.shape}")
    bad = np.argwhere(~np.isfinite(a))
    if len(bad):
        raise InputError(f"{name}[{bad[0][0]}]", "joint angles must be finite")
    return a


def _failed(instrument: Instrument, start_q: np.ndarray, arms: Sequence[int], stats: dict) -> MotionPlan:
    trajs = tuple(ArmTrajectory(k, np.array([0.0]), start_q[k, :1].copy(), start_q[k, 1:].copy())
                  for k in range(instrument.n_arms))
    return MotionPlan("failed", float("nan"), trajs, tuple(sorted({int(a) for a in arms})), stats)


def _same_angle(a: float, b: float, tol: float = 1e-9) -> bool:
    return abs((a - b + np.pi) % TWO_PI - np.pi) <= tol


def _precheck(instrument: Instrument, geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray,
              buffer_mm: float) -> dict[int, str]:
    """Reasons why arms cannot be planned at all (thesis 6.3.1 assumes feasible ends)."""
    reasons: dict[int, str] = {}
    enabled = set(instrument.enabled_arms)
    for k, g in enumerate(geoms):
        if g.in_zoa(start_q[k, 0], start_q[k, 1]):
            reasons[k] = "start in zone of avoidance or beyond joint limits"
        elif g.in_zoa(goal_q[k, 0], goal_q[k, 1]):
            reasons[k] = "goal in zone of avoidance or beyond joint limits"
        elif k not in enabled and not (abs(start_q[k, 0] - goal_q[k, 0]) <= 1e-9
                                       and _same_angle(start_q[k, 1], goal_q[k, 1])):
            reasons[k] = "arm is disabled but its goal differs from its start"
    for name, q in (("goal", goal_q), ("start", start_q)):
        for a, b in colliding_arm_pairs(instrument, q, buffer_mm):
            for x, y in ((a, b), (b, a)):
                reasons.setdefault(x, f"{name} configuration collides with arm {y}")
    return reasons


def _path_samples(path: RoadmapPath, geom: ArmGeom, dt_s: float, n_samples: int) -> np.ndarray:
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
    qs = np.stack([_path_samples(paths[k][0], geoms[k], dt_s, K) for k in arms])  # (n, K, 2)
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


def _assemble(instrument: Instrument, plans: dict[int, ArmPlan], start_q: np.ndarray, dt_s: float,
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


def _delay_trajectories(assignment: dict[int, tuple[int, int]], options, n: int,
                        dt_s: float) -> tuple[ArmTrajectory, ...]:
    """Way-points and controller commands of a delay-CSP assignment (option, departure step)."""
    out = []
    for k in range(n):
        p, tau = assignment[k]
        t, q = trajectory_points(options[k][p], tau * dt_s)
        t, q = compress_waypoints(t, q)
        out.append(ArmTrajectory(k, t, q[:, 0].copy(), q[:, 1].copy(), controller_commands(t, q[:, 0], q[:, 1])))
    return tuple(out)


def _try_delays(instrument: Instrument, geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray,
                enabled: list[int], dt_s: float, dt_col_s: float, horizon_s: float, buffer_mm: float,
                max_start_stop: int, grid: tuple[int, int], stats: dict,
                deadline: float, cluster: dict | None = None) -> tuple[MotionPlan | None, list[int]]:
    """First strategy: straight moves with departure delays (+ one-stop detours), verified.

    With ``cluster`` (keyword arguments of :func:`_try_cluster` plus ``share_s``), when every
    straight option fails the cluster strategy runs before the detour rounds, and the detour
    rounds extend first the arms of the smallest removal set (:mod:`planner.cluster`).
    """
    dst = DelayStats()
    t_d = time.perf_counter()
    last: dict = {}
    hooks: dict = {}
    if cluster is not None:
        found: dict = {}

        def on_straight_fail(straight, blamed):
            c_dl = time.perf_counter() + cluster["share_s"]  # its own share, not the delay stage's
            return _try_cluster(instrument, geoms, start_q, goal_q, straight, blamed, enabled, buffer_mm,
                                max_start_stop, stats, c_dl, sets_out=found, **cluster["kw"])

        def prefer(straight, blamed):
            sets = found.get("sets")
            if sets is None:
                sets = [R for R, _ in removal_sets(straight, start_q, enabled, max_size=3, max_sets=1,
                                                   first=blamed, deadline=deadline)]
            if not sets and found.get("complete", False):
                # removing any one or two arms (or three connected ones) leaves the straight CSP
                # unsolvable, so detours for them cannot help either (a removed arm is the loosest
                # detour; beyond pairs this is a heuristic): end the delay stage and leave the
                # time to the prioritized fallbacks
                return None
            return sets[0] if sets else []

        hooks = dict(on_straight_fail=on_straight_fail, prefer=prefer, after_hook_s=cluster["after_s"])

    def check(assignment, options) -> list[tuple[int, int]]:
        trajs = _delay_trajectories(assignment, options, len(start_q), dt_s)
        rep = verify_trajectories(instrument, trajs, start_q, goal_q, collision_buffer_mm=buffer_mm,
                                  max_start_stop=max_start_stop)
        last["rep"], last["trajs"] = rep, trajs
        if rep.ok:
            return []
        pairs = [tuple(v.arms) for v in rep.violations if v.kind == "collision" and len(v.arms) == 2]
        return pairs or [(-1, -1)]

    def safe_check(assignment, options):
        pairs = check(assignment, options)
        if pairs == [(-1, -1)]:  # a non-collision violation: cannot be repaired by delays
            raise _Unrepairable
        return pairs

    try:
        res = plan_delays(geoms, start_q, goal_q, dt_s=dt_s, dt_col_s=dt_col_s, horizon_s=horizon_s,
                          buffer_mm=buffer_mm, max_start_stop=max_start_stop, movable=enabled, stats=dst,
                          grid=grid, deadline=deadline, check=safe_check, **hooks)
    except _Unrepairable:
        res = None
    if res is not None and res.external is not None:
        stats["collision_checks"] += dst.pair_samples
        stats["states_explored"] += dst.nodes
        stats["delay_csp"] = {"pair_tables": dst.tables, "nodes": dst.nodes, "repairs": dst.repairs,
                              "rounds": res.rounds, "compute_s": time.perf_counter() - t_d}
        return res.external, []
    stats["collision_checks"] += dst.pair_samples
    stats["states_explored"] += dst.nodes
    stats["delay_csp"] = {"pair_tables": dst.tables, "nodes": dst.nodes, "repairs": dst.repairs,
                          "rounds": getattr(res, "rounds", 0), "compute_s": time.perf_counter() - t_d}
    if res is None or res.assignment is None:
        stats["attempt_log"].append({"direction": "delays", "failed_arms": list(getattr(res, "blamed", []))})
        return None, list(getattr(res, "blamed", []))
    rep, trajs = last["rep"], last["trajs"]
    if not rep.ok:  # cannot happen: plan_delays only returns checked assignments
        return None, list(rep.arms)
    stats["attempts"] = 1
    stats["attempt_log"].append({"direction": "delays", "verified": True})
    stats["strategy"] = "delays"
    stats["min_clearance_mm"] = rep.min_clearance_mm
    stats["verify_pair_samples"] = rep.pair_samples_checked
    stats["max_stops"] = max(res.options[k][p].stops for k, (p, _) in res.assignment.items())
    return MotionPlan("ok", float(res.makespan_s), trajs, (), stats), []


def _try_cluster(instrument: Instrument, geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray,
                 straight, blamed: list[int], enabled: list[int], buffer_mm: float, max_start_stop: int,
                 stats: dict, deadline: float, *, params: SearchParams, rparams: RoadmapParams,
                 seed: int, sets_out: dict | None = None) -> MotionPlan | None:
    """Cluster strategy (:mod:`planner.cluster`): straight delayed moves for all arms but the
    smallest removal set R, state-time detours for R (forward, reverse, then with a head
    start), verified."""
    t_c = time.perf_counter()
    cst = ClusterStats()
    st = SearchStats()
    plan = None
    try:
        sets = list(removal_sets(straight, start_q, enabled, max_size=3, max_sets=3, first=blamed,
                                 deadline=deadline, stats=cst))
        if sets_out is not None:
            sets_out["sets"] = [R for R, _ in sets]
            # the search was neither cut short nor left undecided by the node budget
            sets_out["complete"] = time.perf_counter() <= deadline and cst.inconclusive == 0
        # cheapest and most often successful first: forward without head start for every set
        tries = [(lead, rev, R, rest) for lead, rev in ((0, False), (0, True), (3, False), (3, True))
                 for R, rest in sets]
        for lead, rev, R, rest in tries:
            if time.perf_counter() > deadline:
                break
            cst.attempts += 1
            out = plan_cluster(geoms, start_q, goal_q, straight, R, rest, buffer_mm=buffer_mm, params=params,
                               rparams=rparams, seed=seed, reverse=rev, stats=st, deadline=deadline,
                               lead_steps=lead)
            cst.log.append({"arms": list(R), "reverse": rev, "lead_steps": lead, "planned": out is not None})
            if out is None:
                continue
            trajs = []
            for k, (t, q) in enumerate(out):
                t, q = compress_waypoints(t, q)
                trajs.append(ArmTrajectory(k, t, q[:, 0].copy(), q[:, 1].copy(),
                                           controller_commands(t, q[:, 0], q[:, 1])))
            rep = verify_trajectories(instrument, trajs, start_q, goal_q, collision_buffer_mm=buffer_mm,
                                      max_start_stop=max_start_stop)
            cst.log[-1]["verified"] = rep.ok
            if rep.ok:
                stats["strategy"] = "cluster"
                stats["min_clearance_mm"] = rep.min_clearance_mm
                stats["verify_pair_samples"] = rep.pair_samples_checked
                stats["max_stops"] = max(stop_count_of(tr) for tr in trajs)
                stats["attempts"] = 1
                plan = MotionPlan("ok", max(float(tr.t_s[-1]) for tr in trajs), tuple(trajs), (), stats)
                break
    finally:
        stats["collision_checks"] += st.collision_checks
        stats["states_explored"] += st.states_explored
        stats["cluster"] = {"removal_tests": cst.removal_tests, "removal_sets": cst.removal_sets,
                            "attempts": cst.log, "compute_s": time.perf_counter() - t_c}
        stats["attempt_log"].append({"direction": "cluster", "verified": plan is not None})
    return plan


def stop_count_of(tr: ArmTrajectory) -> int:
    """Start-stop cycles of one arm's trajectory (thesis 6.3.4.4)."""
    return int(stop_count(tr.t_s, tr.theta1_rad, tr.theta2_rad))


class _Unrepairable(Exception):
    pass


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
    strategies: Sequence[str] = ("delays", "cluster", "forward", "reverse"),
    rpp: bool = False,
    rpp_max_paths: int = 8,
    turn_sense: int = 1,
    turn_bias_s: float = 0.0,
    via: np.ndarray | None | str = "park",
) -> MotionPlan:
    """Collision-free, verified trajectories of all arms from ``start_q`` to ``goal_q`` (thesis 6.3).

    ``start_q`` / ``goal_q`` are (n_arms, 2) joint angles (theta1, theta2) in rad; the
    start's theta2 may be unwrapped (continuing a previous trajectory), the goal's counts
    modulo 2 pi. Returns a :class:`~models.types.MotionPlan`: per arm timed way-points
    (linear joint motion between them; the MCC2 really executes each move as a trapezoidal
    LSPB profile from rest to rest) and controller commands per joint. ``status`` is "ok"
    only when the independent verifier passed; "failed" plans name ``failed_arms`` and give
    reasons in ``stats["reasons"]`` (never an exception for an unplannable case).

    Parameters follow thesis table 6.1: ``dt_s`` the motion-action step, ``dt_col_s`` the
    collision-check step (a sub-multiple of ``dt_s``), ``max_start_stop`` the stops allowed
    per arm, ``horizon_s`` T_f. Replanning (priority rotation, time reversal) runs within
    ``max_attempts`` and ``time_budget_s``. Same input and ``seed`` -> same plan.

    Strategies, in order: "delays" (straight moves with departure delays; with "cluster",
    state-time detours for the smallest conflicting arm set, :mod:`planner.cluster`; then
    one-stop detours for the arms in conflict; :mod:`planner.delays`), then prioritized state-time
    planning "forward" / "reverse". If all fail and ``via`` is given ("park" or an
    (n_arms, 2) configuration) and differs from both ends, the move is planned as two legs
    start -> via -> goal with zero-stop legs (each arm then stops at most once, at ``via``)
    and the concatenation is verified as a whole.
    """
    t0 = time.perf_counter()
    start_q = _check_q(instrument, start_q, "start_q")
    goal_q = _check_q(instrument, goal_q, "goal_q")
    if not (dt_s > 0 and dt_col_s > 0 and math.isfinite(dt_s) and math.isfinite(dt_col_s)):
        raise InputError("dt_s", "dt_s and dt_col_s must be positive")
    m = max(1, int(round(dt_s / dt_col_s)))
    if abs(m * dt_col_s - dt_s) > 1e-6 * dt_s:
        raise InputError("dt_col_s", "must divide dt_s into a whole number of collision steps")
    if max_start_stop < 0:
        raise InputError("max_start_stop", "must be >= 0")
    buffer_mm = instrument.collision_buffer_mm if collision_buffer_mm is None else float(collision_buffer_mm)
    n = instrument.n_arms
    geoms = [ArmGeom.of(instrument, k) for k in range(n)]
    v1 = instrument.arm_array("joint1_speed_rad_s")
    v2 = instrument.arm_array("joint2_speed_rad_s")
    lower_bound = float(np.max(direct_move_time_s(start_q, goal_q, v1, v2), initial=0.0))
    stats: dict = {"lower_bound_s": lower_bound, "attempts": 0, "collision_checks": 0,
                   "states_explored": 0, "paths_explored": 0, "attempt_log": []}

    reasons = _precheck(instrument, geoms, start_q, goal_q, buffer_mm)
    if reasons:
        stats["reasons"] = {int(k): v for k, v in reasons.items()}
        stats["compute_s"] = time.perf_counter() - t0
        return _failed(instrument, start_q, list(reasons), stats)

    params = SearchParams(dt_s=dt_s, dt_col_s=dt_col_s, max_start_stop=max_start_stop,
                          horizon_steps=max(1, math.ceil(horizon_s / dt_s - 1e-9)))
    rpp_params = SearchParams(dt_s=dt_s, dt_col_s=dt_col_s, max_start_stop=max_start_stop,
                              horizon_steps=params.horizon_steps, max_paths=rpp_max_paths,
                              max_states_per_arm=2000)
    rparams = RoadmapParams(grid=grid, max_edges_per_path=max_start_stop + 1, turn_sense=turn_sense,
                            turn_bias_s=turn_bias_s)
    enabled = [k for k in instrument.enabled_arms]
    disabled = [k for k in range(n) if k not in set(enabled)]

    blamed: list[int] = []
    if "delays" in strategies:
        cluster = None
        if "cluster" in strategies and max_start_stop >= 1:
            cl_params = SearchParams(dt_s=dt_s, dt_col_s=dt_col_s, max_start_stop=max_start_stop,
                                     horizon_steps=params.horizon_steps, max_states_per_arm=1500,
                                     max_paths=64)  # a parked arm's step-aside paths tie in rank
            # the detour rounds after a failed cluster stage rarely succeed where it failed:
            # they get at most 10 % (<= 1 s) more, the rest goes to the prioritized stage
            cluster = {"share_s": min(0.25 * time_budget_s, 2.5), "after_s": min(0.1 * time_budget_s, 1.0),
                       "kw": dict(params=cl_params, rparams=rparams, seed=seed)}
        # fair shares of the budget: the delay stage (its cluster hook included) may not starve
        # the prioritized fallbacks, and those may not starve the two-leg fallback
        ok_plan, blamed = _try_delays(instrument, geoms, start_q, goal_q, enabled, dt_s, dt_col_s, horizon_s,
                                      buffer_mm, max_start_stop, grid, stats,
                                      t0 + min(0.3 * time_budget_s, 3.0), cluster)
        if ok_plan is not None:
            prio = [s for s in strategies if s in ("forward", "reverse")]
            left = time_budget_s - (time.perf_counter() - t0)
            if (stats.get("strategy") == "cluster" and prio and lower_bound > 0 and left > 1.0
                    and ok_plan.makespan_s > CLUSTER_MAKESPAN_RATIO * lower_bound):
                # the rest's straight schedule made the cluster plan long: let the prioritized
                # stage try (one forward, one reverse attempt, <= 30 % of the budget) for a shorter
                # one, keep the better
                alt = plan_motion(instrument, start_q, goal_q, dt_s=dt_s, dt_col_s=dt_col_s,
                                  max_start_stop=max_start_stop, collision_buffer_mm=buffer_mm, seed=seed,
                                  horizon_s=horizon_s, max_attempts=min(max_attempts, 2),
                                  time_budget_s=min(left, 0.3 * time_budget_s), grid=grid,
                                  strategies=prio, rpp=rpp, rpp_max_paths=rpp_max_paths, turn_sense=turn_sense,
                                  turn_bias_s=turn_bias_s, via=None)
                stats["cluster_makespan_s"] = ok_plan.makespan_s
                stats["shorter_search"] = {"status": alt.status, "makespan_s": alt.makespan_s,
                                           "compute_s": alt.stats.get("compute_s")}
                if alt.status == "ok" and alt.makespan_s < ok_plan.makespan_s:
                    alt.stats["compute_s"] = time.perf_counter() - t0
                    alt.stats["cluster_makespan_s"] = ok_plan.makespan_s
                    for key in ("collision_checks", "states_explored"):
                        alt.stats[key] += stats[key]
                    return alt
            stats["compute_s"] = time.perf_counter() - t0
            return ok_plan
        strategies = [s for s in strategies if s not in ("delays", "cluster")]
        if not strategies:
            stats["reasons"] = {int(a): "no collision-free departure-delay schedule" for a in blamed}
            stats["compute_s"] = time.perf_counter() - t0
            return _failed(instrument, start_q, blamed or enabled, stats)

    strategies = [s for s in strategies if s in ("forward", "reverse")]  # "cluster" runs inside "delays"
    if not strategies:
        stats["reasons"] = {int(a): "no strategy left" for a in (blamed or enabled)}
        stats["compute_s"] = time.perf_counter() - t0
        return _failed(instrument, start_q, blamed or enabled, stats)
    paths_cache: dict[str, list[list[RoadmapPath]]] = {}

    def paths_for(direction: str) -> list[list[RoadmapPath]]:
        if direction not in paths_cache:
            a, b = (start_q, goal_q) if direction == "forward" else (goal_q, start_q)
            paths_cache[direction] = [
                candidate_paths(geoms[k], a[k], b[k], np.random.default_rng([seed, k, int(direction == "reverse")]),
                                rparams) if k in enabled else []
                for k in range(n)
            ]
        return paths_cache[direction]

    # priorities (6.4.1): estimated travel time of the shortest roadmap path, longest first
    fwd = paths_for("forward")
    est = {k: (fwd[k][0].est_time_s if fwd[k] else math.inf) for k in enabled}
    no_path = [k for k in enabled if not fwd[k]]
    if no_path:
        stats["reasons"] = {k: "no ZoA-free roadmap path from start to goal" for k in no_path}
        stats["compute_s"] = time.perf_counter() - t0
        return _failed(instrument, start_q, no_path, stats)
    orders = {}
    for s in strategies:
        a, b = (start_q, goal_q) if s == "forward" else (goal_q, start_q)
        orders[s] = conflict_order(instrument, geoms, paths_for(s), a, b, enabled, est, buffer_mm)
    via_q = instrument.park_configuration if isinstance(via, str) and via == "park" else via
    via_reserve_s = min(0.15 * time_budget_s, 1.5) if via_q is not None and max_start_stop >= 1 else 0.0
    fail_count: dict[int, int] = {}
    tried: dict[str, set[tuple[int, ...]]] = {s: set() for s in strategies}
    best_failed: list[int] = []
    last_reason: dict[int, str] = {}

    for attempt in range(max_attempts):
        if attempt > 0 and time.perf_counter() - t0 > time_budget_s - via_reserve_s:
            break
        direction = strategies[attempt % len(strategies)]
        order = orders[direction]
        paths = paths_for(direction)
        tried[direction].add(tuple(order))
        a_start = start_q if direction == "forward" else goal_q
        obst = ObstacleTime(m=m, n_steps=params.horizon_steps, buffer_mm=buffer_mm,
                            nb=max(len(a.bodies) for a in instrument.arms))
        for k in disabled:
            obst.add(geoms[k], np.repeat(a_start[k:k + 1], obst.n_samples, axis=0), 0)
        st = SearchStats()
        plans: dict[int, ArmPlan] = {
            k: ArmPlan(k, a_start[k:k + 1].copy(), -1, 1.0) for k in disabled
        }
        failed = None
        for idx, k in enumerate(order):
            p = None
            rest = [j for j in order[idx + 1:]]
            if rpp and rest:
                # revised prioritized planning (Cap et al. 2015): first try to keep clear of
                # the arms not yet planned, resting at their starts, so that they can always
                # wait there; fall back to ignoring them (thesis Algorithm 6)
                p = plan_arm(geoms[k], paths[k], obst.with_static([(geoms[j], a_start[j]) for j in rest]),
                             rpp_params, st)
            if p is None:
                p = plan_arm(geoms[k], paths[k], obst, params, st)
            if p is None:
                failed = k
                break
            plans[k] = p
            obst.add(geoms[k], step_samples(p.q_steps, m, params.horizon_steps), p.arrival_step)
        stats["attempts"] = attempt + 1
        stats["collision_checks"] += st.collision_checks
        stats["states_explored"] += st.states_explored
        stats["paths_explored"] += st.paths_explored
        log = {"direction": direction, "order": list(order), "failed_arm": failed}
        stats["attempt_log"].append(log)
        if failed is not None:
            fail_count[failed] = fail_count.get(failed, 0) + 1
            last_reason[failed] = "no collision-free trajectory within the horizon"
            order.remove(failed)
            order.insert(0, failed)  # priority rotation: promote the failed arm
            if tuple(order) in tried[direction]:
                # rotation cycles (two arms block each other in both orders): perturb the rest
                rng = np.random.default_rng([seed, attempt])
                tail = order[1:]
                rng.shuffle(tail)
                order[1:] = tail
            continue
        trajs, makespan = _assemble(instrument, plans, start_q, dt_s, direction == "reverse")
        rep = verify_trajectories(instrument, trajs, start_q, goal_q, collision_buffer_mm=buffer_mm,
                                  max_start_stop=max_start_stop)
        log["verified"] = rep.ok
        stats["verify_pair_samples"] = rep.pair_samples_checked
        if rep.ok:
            stats["strategy"] = direction
            stats["min_clearance_mm"] = rep.min_clearance_mm
            stats["compute_s"] = time.perf_counter() - t0
            return MotionPlan("ok", makespan, trajs, (), stats)
        # the verifier found what the dt_col sampling missed: promote the arms involved
        log["violations"] = [(v.kind, v.arms, v.detail) for v in rep.violations[:5]]
        for a in rep.arms:
            if a in order:
                order.remove(a)
                order.insert(0, a)
            last_reason[a] = "verification failed: " + rep.violations[0].kind
        best_failed = list(rep.arms)

    failed_arms = sorted(fail_count, key=lambda a: (-fail_count[a], a)) or best_failed
    stats["reasons"] = {int(a): last_reason.get(a, "not planned") for a in failed_arms}
    if via_q is not None and not isinstance(via_q, str) and max_start_stop >= 1:
        two = _plan_via(instrument, start_q, np.asarray(via_q, float), goal_q, buffer_mm, max_start_stop,
                        dict(dt_s=dt_s, dt_col_s=dt_col_s, seed=seed, horizon_s=horizon_s, grid=grid,
                             time_budget_s=max(0.5, time_budget_s - (time.perf_counter() - t0))), stats)
        if two is not None:
            stats["compute_s"] = time.perf_counter() - t0
            return two
    stats["compute_s"] = time.perf_counter() - t0
    return _failed(instrument, start_q, failed_arms, stats)


def _same_configuration(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(np.abs(a[:, 0] - b[:, 0]) <= 1e-9)
                and all(_same_angle(x, y) for x, y in zip(a[:, 1], b[:, 1], strict=True)))


def _plan_via(instrument: Instrument, start_q: np.ndarray, via_q: np.ndarray, goal_q: np.ndarray,
              buffer_mm: float, max_start_stop: int, kw: dict, stats: dict) -> MotionPlan | None:
    """start -> via -> goal as two zero-stop legs (e.g. through park for a chained move).

    Each leg has no intermediate stop, so an arm that moves in both legs stops once (at
    ``via``) and the whole respects ``max_start_stop`` >= 1. Time reversal would give the
    same first leg (a verified via -> start plan played backwards has the same clearances,
    speeds and stops); the delay CSP plans start -> via directly just as well.
    """
    if _same_configuration(via_q, start_q) or _same_configuration(via_q, goal_q):
        return None
    if _precheck(instrument, [ArmGeom.of(instrument, k) for k in range(instrument.n_arms)], via_q, via_q, buffer_mm):
        return None
    legs = []
    cur = start_q
    for target in (via_q, goal_q):
        p = plan_motion(instrument, cur, target, max_start_stop=0, collision_buffer_mm=buffer_mm,
                        strategies=("delays",), via=None, **kw)
        if p.status != "ok":
            stats.setdefault("attempt_log", []).append({"direction": "via", "failed_arms": list(p.failed_arms)})
            return None
        legs.append(p)
        cur = np.array([[tr.theta1_rad[-1], tr.theta2_rad[-1]] for tr in p.trajectories])
    T1 = legs[0].makespan_s
    trajs = []
    for k in range(instrument.n_arms):
        a, b = legs[0].trajectories[k], legs[1].trajectories[k]
        t = np.concatenate([a.t_s, b.t_s + T1])
        q = np.column_stack([np.concatenate([a.theta1_rad, b.theta1_rad]), np.concatenate([a.theta2_rad, b.theta2_rad])])
        keep = np.concatenate([np.diff(t) > 1e-12, [True]])  # drop the duplicated junction point
        t, q = compress_waypoints(t[keep], q[keep])
        trajs.append(ArmTrajectory(k, t, q[:, 0].copy(), q[:, 1].copy(), controller_commands(t, q[:, 0], q[:, 1])))
    rep = verify_trajectories(instrument, trajs, start_q, goal_q, collision_buffer_mm=buffer_mm,
                              max_start_stop=max_start_stop)
    stats.setdefault("attempt_log", []).append({"direction": "via", "verified": rep.ok})
    if not rep.ok:
        return None
    for key in ("collision_checks", "states_explored"):
        stats[key] = stats.get(key, 0) + sum(leg.stats.get(key, 0) for leg in legs)
    stats["strategy"] = "via"
    stats["min_clearance_mm"] = rep.min_clearance_mm
    return MotionPlan("ok", float(T1 + legs[1].makespan_s), tuple(trajs), (), stats)


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
