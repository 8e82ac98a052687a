"""Evasion options for the departure-delay CSP: detours around neighbours, and step-aside moves.

On prioritised fields most arms of a configuration reach deep into the field, and reaching
deep takes a half turn of J2 (the J4 pin goes to the far side of J2). A half turn swings the
L3 link sideways, through the space of a neighbour. When that neighbour sits in the way both
at its start and at its goal (it moves little, or it stays parked), no departure delay
separates the two arms: the pair is infeasible in the CSP of :mod:`planner.delays` whatever
the delays. Two kinds of one-stop options resolve it:

* **clear detours** (:func:`clear_detours`): start -> v -> goal for the swinging arm, with the
  stop vertex v chosen so that the whole swept path keeps the collision buffer to its
  neighbours' start and goal poses. Such a path is compatible with any timing of those
  neighbours' short moves;
* **step-aside moves** (:func:`aside_detours`): when no such path exists (a deep arm between two
  parked neighbours: measured, no one-stop path clears both), one neighbour leaves the swing's
  swept area first: start -> v -> goal, waiting at v while the other arm passes (the
  thesis' future work, "moving an arrived arm out of the way", 6.5).

Both are plain :class:`planner.delays.Option` lists; the delay CSP then chooses options and
departure times for every arm at once, and the driver verifies the result. Candidate
vertices are searched vectorised over a grid of the arm's joint space, shortest path first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.budget import Budget
from planner.delays import DelayProblem, DelayStats, Option, build_problem, solve, straight_options
from planner.geometry import ArmGeom, clearance_between, edges_in_zoa

TWO_PI = 2.0 * np.pi
SAMPLES_PER_SEGMENT = 48  # joint-space sampling of a candidate path (<= 0.13 rad apart)
SAMPLING_MARGIN_MM = 3.0  # added to the buffer: the candidate search samples coarsely
SHORT_MOVE_S = 40.0  # a neighbour moving less than this is in the way at both ends
BATCH = 96  # candidate paths checked per vectorised batch, shortest first


@dataclass(frozen=True)
class Pose:
    """A static obstacle: one arm held at one configuration."""

    geom: ArmGeom
    q: np.ndarray  # (2,)


def vertex_grid(geom: ArmGeom, n_theta1: int = 14, n_theta2: int = 28) -> np.ndarray:
    """Stop-vertex candidates: a grid over theta1 x theta2, outside the ZoA."""
    t1 = np.linspace(geom.theta1_min, geom.theta1_max, n_theta1)
    t2 = np.linspace(0.0, TWO_PI, n_theta2, endpoint=False)
    v = np.array(np.meshgrid(t1, t2, indexing="ij")).reshape(2, -1).T
    return v[~geom.in_zoa(v[:, 0], v[:, 1])]


def _turns(frm: np.ndarray, to: np.ndarray) -> list[np.ndarray]:
    """theta2 of ``to`` unwrapped relative to ``frm`` both ways round."""
    ccw = np.mod(to - frm, TWO_PI)
    return [frm + ccw, frm + ccw - TWO_PI]


def one_stop_paths(geom: ArmGeom, qs: np.ndarray, qg: np.ndarray, vertices: np.ndarray,
                   max_duration_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """ZoA-free paths start -> v -> goal over ``vertices`` and both turns of each segment.

    Returns (v (m, 2), g (m, 2) with theta2 unwrapped, T1 (m,), T2 (m,)), sorted by T1 + T2.
    """
    vs, gs = [], []
    for v2 in _turns(np.full(len(vertices), qs[1]), vertices[:, 1]):
        v = np.column_stack([vertices[:, 0], v2])
        for g2 in _turns(v2, np.full(len(vertices), qg[1])):
            vs.append(v)
            gs.append(np.column_stack([np.full(len(v), qg[0]), g2]))
    v, g = np.concatenate(vs), np.concatenate(gs)
    T1 = geom.move_time_s(np.broadcast_to(qs, v.shape), v)
    T2 = geom.move_time_s(v, g)
    keep = (T1 + T2 <= max_duration_s) & (T1 > 1e-9)
    v, g, T1, T2 = v[keep], g[keep], T1[keep], T2[keep]
    order = np.argsort(T1 + T2, kind="stable")
    v, g, T1, T2 = v[order], g[order], T1[order], T2[order]
    bad = edges_in_zoa(geom, np.broadcast_to(qs, v.shape), v) | edges_in_zoa(geom, v, g)
    return v[~bad], g[~bad], T1[~bad], T2[~bad]


def _path_poses(qs: np.ndarray, v: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(m, 2 N, 2) configurations along start -> v -> goal, N per segment."""
    s = np.linspace(0.0, 1.0, SAMPLES_PER_SEGMENT)[None, :, None]
    a = qs[None, None, :] + s * (v[:, None, :] - qs[None, None, :])
    b = v[:, None, :] + s * (g[:, None, :] - v[:, None, :])
    return np.concatenate([a, b], axis=1)


def _clear_of(geom: ArmGeom, poses: np.ndarray, obstacles: list[Pose], thr_mm: float) -> np.ndarray:
    """(m,) True where every pose of each path (m, n, 2) keeps ``thr_mm`` to every obstacle."""
    m, n = poses.shape[:2]
    s, e = geom.segments(poses[..., 0].ravel(), poses[..., 1].ravel())
    ok = np.ones(m * n, bool)
    for ob in obstacles:
        so, eo = ob.geom.segments(np.array([ob.q[0]]), np.array([ob.q[1]]))
        c = clearance_between(s[ok], e[ok], geom.radius, so[0], eo[0], ob.geom.radius)
        idx = np.flatnonzero(ok)
        ok[idx[c < thr_mm]] = False
    return ok.reshape(m, n).all(axis=1)


def _options(geom: ArmGeom, qs: np.ndarray, v: np.ndarray, g: np.ndarray, T1: float, T2: float,
             waits_s: tuple[float, ...], horizon_s: float, kind: str) -> list[Option]:
    out = []
    for w in waits_s:
        if T1 + T2 + w > horizon_s:
            continue
        if w > 0:
            out.append(Option(geom.arm, np.array([qs, v, v, g]), np.array([0.0, T1, T1 + w, T1 + w + T2]), 1, kind))
        else:
            out.append(Option(geom.arm, np.array([qs, v, g]), np.array([0.0, T1, T1 + T2]), 1, kind))
    return out


def clear_detours(geom: ArmGeom, qs: np.ndarray, qg: np.ndarray, obstacles: list[Pose], *,
                  buffer_mm: float, max_duration_s: float, max_paths: int = 2,
                  waits_s: tuple[float, ...] = (0.0,), horizon_s: float = math.inf,
                  vertices: np.ndarray | None = None, kind: str = "detour") -> list[Option]:
    """The shortest one-stop paths of one arm (through ``vertices``, default the grid) whose
    every pose clears every obstacle pose, as options of ``kind``."""
    V = vertex_grid(geom) if vertices is None else vertices
    v, g, T1, T2 = one_stop_paths(geom, qs, qg, V, max_duration_s)
    found: list[Option] = []
    thr = buffer_mm + SAMPLING_MARGIN_MM
    for lo in range(0, len(v), BATCH):
        sl = slice(lo, lo + BATCH)
        ok = _clear_of(geom, _path_poses(qs, v[sl], g[sl]), obstacles, thr)
        for i in np.flatnonzero(ok):
            j = lo + int(i)
            found += _options(geom, qs, v[j], g[j], float(T1[j]), float(T2[j]), waits_s, horizon_s, kind)
            if len(found) >= max_paths * len(waits_s):
                return found
    return found


def swept_poses(option: Option, step_rad: float = 0.05) -> np.ndarray:
    """Configurations along an option's way-points, at most ``step_rad`` apart."""
    wp = option.waypoints
    out = [wp[:1]]
    for a, b in zip(wp[:-1], wp[1:], strict=True):
        n = max(1, int(math.ceil(np.abs(b - a).max() / step_rad)))
        s = np.linspace(0.0, 1.0, n + 1)[1:, None]
        out.append(a + s * (b - a))
    return np.concatenate(out)


def aside_detours(geom: ArmGeom, qs: np.ndarray, qg: np.ndarray, passing: ArmGeom, passing_option: Option,
                  obstacles: list[Pose], *, buffer_mm: float, max_duration_s: float, max_paths: int = 3,
                  waits_s: tuple[float, ...], horizon_s: float) -> list[Option]:
    """One-stop moves start -> v -> goal of an arm whose stop pose v clears the whole swept
    path of ``passing_option`` (another arm's move), and whose path clears ``obstacles``."""
    V = vertex_grid(geom)
    sw = swept_poses(passing_option)
    ok = _clear_of(geom, V[:, None, :], [Pose(passing, q) for q in sw[:: max(1, len(sw) // 40)]],
                   buffer_mm + SAMPLING_MARGIN_MM)
    if not ok.any():
        return []
    return clear_detours(geom, qs, qg, obstacles, buffer_mm=buffer_mm, max_duration_s=max_duration_s,
                         max_paths=max_paths, waits_s=waits_s, horizon_s=horizon_s, vertices=V[ok], kind="aside")


def step_aside(ga: ArmGeom, a_start: np.ndarray, a_goal: np.ndarray, a_obstacles: list[Pose],
               a_options: list[Option], gb: ArmGeom, b_start: np.ndarray, b_goal: np.ndarray,
               b_obstacles: list[Pose], *, buffer_mm: float, max_duration_s: float,
               waits_s: tuple[float, ...], horizon_s: float,
               max_candidates: int = 12) -> tuple[list[Option], list[Option]]:
    """Arm a passes, arm b steps aside: the shortest move of a that clears its other
    neighbours (``a_obstacles``) and leaves b a pose off its swept area, with b's one-stop
    moves through such poses. Returns (a's options, b's options); both empty if none."""
    thr = buffer_mm + SAMPLING_MARGIN_MM
    straight = [o for o in a_options if o.kind == "straight"
                and _clear_of(ga, swept_poses(o)[None], a_obstacles, thr)[0]]
    cands = straight + clear_detours(ga, a_start, a_goal, a_obstacles, buffer_mm=buffer_mm,
                                     max_duration_s=max_duration_s, max_paths=max_candidates)
    for cand in sorted(cands, key=lambda o: o.duration_s)[:max_candidates]:
        aside = aside_detours(gb, b_start, b_goal, ga, cand, b_obstacles, buffer_mm=buffer_mm,
                              max_duration_s=max_duration_s, waits_s=waits_s, horizon_s=horizon_s)
        if aside:
            if cand.kind == "straight":
                return [cand], aside
            v = cand.waypoints[1]
            T1 = float(cand.t_rel[1])
            T2 = float(cand.t_rel[-1] - T1)
            return _options(ga, a_start, v, cand.waypoints[-1], T1, T2, (0.0,) + waits_s[:2], horizon_s,
                            "detour"), aside
    return [], []


@dataclass
class EvasionResult:
    assignment: dict[int, tuple[int, int]] | None  # arm -> (option index, departure step)
    options: list[list[Option]]
    rounds: int
    log: list


def _infeasible_pairs(prob: DelayProblem) -> list[tuple[int, int]]:
    """Arm pairs for which no option pair at any relative delay is collision-free."""
    return [(i, j) for (i, j), tab in sorted(prob.tables.items()) if i < j and not tab.any()]


def _neighbour_poses(geoms: list[ArmGeom], prob: DelayProblem, arm: int, start_q: np.ndarray,
                     goal_q: np.ndarray, skip: tuple[int, ...] = (), strict: bool = True) -> list[Pose]:
    """Start and goal poses of the arms near ``arm``; with ``strict=False`` only of those that
    move little (in the way whatever their departure time), the others being left to the
    delay CSP's timing."""
    out = []
    n = len(geoms)
    for k in sorted(set(prob.neighbours[arm]) | {(arm - 1) % n, (arm + 1) % n}):
        if k == arm or k in skip:
            continue
        if not strict and float(geoms[k].move_time_s(start_q[k], goal_q[k])) > SHORT_MOVE_S:
            continue
        out.append(Pose(geoms[k], start_q[k]))
        if np.any(np.abs(goal_q[k] - start_q[k]) > 1e-9):
            out.append(Pose(geoms[k], goal_q[k]))
    return out


def plan_evasion(geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray, *, dt_s: float,
                 dt_col_s: float, horizon_s: float, buffer_mm: float, movable: list[int],
                 stats: DelayStats, deadline: float | None = None, max_rounds: int = 8,
                 waits_steps: tuple[int, ...] = (0, 2, 5), node_budget: int = 20000,
                 initial: DelayProblem | None = None, budget: Budget | None = None) -> EvasionResult:
    """Straight moves with delays, then clear detours and step-aside moves for the arm pairs
    that no delay separates, re-solving the delay CSP after each round of new options.

    ``initial``: the straight-move problem the "delays" strategy already solved on the same
    leg (same steps and horizon); its options and pair tables are reused, not recomputed.
    The rounds stop once ``budget`` has passed its deadline (without one: the
    :func:`models.clock.now` instant ``deadline``; neither: no limit)."""
    budget = Budget.ending_at(deadline) if budget is None else budget
    n = len(geoms)
    mv = set(movable)
    opts = _straight_options(geoms, start_q, goal_q, mv, initial)
    lb = max(o[0].duration_s for o in opts)
    limit_s = min(horizon_s, lb + 60.0)
    waits = tuple(w * dt_s for w in waits_steps)
    log: list = []
    prob = initial if initial is not None and len(initial.options) == n else None
    tried: set[tuple[str, int, int]] = set()
    for rnd in range(max_rounds + 1):
        prob = build_problem(geoms, opts, dt_s, dt_col_s, horizon_s, buffer_mm, stats, old=prob, budget=budget)
        if prob is None:
            break
        sol, blamed = solve(prob, stats, node_budget=node_budget, budget=budget)
        if sol is not None:
            return EvasionResult(sol, opts, rnd, log)
        if budget.past_deadline() or rnd == max_rounds:
            break
        grown = False
        for a, o, b in _blocked_options(prob, opts, mv):
            grown |= _aside_of(geoms, prob, opts, a, o, b, start_q, goal_q, mv, tried, buffer_mm, limit_s,
                               waits, horizon_s, log)
            if budget.past_deadline():
                break
        bad = [] if grown else _infeasible_pairs(prob)
        if not grown and not bad and len(blamed) >= 2:  # a cycle of three or more arms: the two most blamed
            bad = [tuple(sorted(blamed[:2]))]
        for i, j in bad:
            grown |= _evade_pair(geoms, prob, opts, i, j, start_q, goal_q, mv, tried, buffer_mm, limit_s,
                                 waits, horizon_s, log)
            if budget.past_deadline():
                break
        log.append({"round": rnd, "infeasible_pairs": [list(p) for p in bad], "grown": grown})
        if not grown:
            break
    return EvasionResult(None, opts, max_rounds, log)


def _straight_options(geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray, mv: set[int],
                      initial: DelayProblem | None) -> list[list[Option]]:
    """Both straight moves of every movable arm ("stay" for the others), the options of
    ``initial`` first (in its order, so that its tables stay valid)."""
    out: list[list[Option]] = []
    for k in range(len(geoms)):
        have = list(initial.options[k]) if initial is not None and len(initial.options) == len(geoms) else []
        for o in straight_options(geoms[k], start_q[k], goal_q[k]) if k in mv else []:
            if not any(len(h.waypoints) == len(o.waypoints) and np.allclose(h.waypoints, o.waypoints) for h in have):
                have.append(o)
        out.append(have or [Option(k, start_q[k][None].copy(), np.zeros(1), 0, "stay")])
    return out


def _blocked_options(prob: DelayProblem, opts: list[list[Option]], mv: set[int]) -> list[tuple[int, int, int]]:
    """(arm a, option index o, arm b) where every option of a is blocked and a's option o is
    blocked by b alone: no option of b at any relative delay lets o pass. Shortest o first."""
    out = []
    for a in sorted(mv):
        blockers = []
        for o in range(len(opts[a])):
            bs = [b for b in prob.neighbours[a] if not prob.tables[(a, b)][o].any()]
            blockers.append(bs)
        if all(blockers):
            for o in sorted(range(len(opts[a])), key=lambda i: opts[a][i].duration_s):
                if len(blockers[o]) == 1:
                    out.append((a, o, blockers[o][0]))
    return out


def _aside_of(geoms, prob, opts, a, o, b, start_q, goal_q, mv, tried, buffer_mm, limit_s, waits, horizon_s,
              log) -> bool:
    """Step-aside moves of arm b off the swept path of arm a's option o."""
    if b not in mv or ("aside-of", b, a * 1000 + o) in tried:
        return False
    tried.add(("aside-of", b, a * 1000 + o))
    for strict in (True, False):
        new = aside_detours(geoms[b], start_q[b], goal_q[b], geoms[a], opts[a][o],
                            _neighbour_poses(geoms, prob, b, start_q, goal_q, skip=(a,), strict=strict),
                            buffer_mm=buffer_mm, max_duration_s=limit_s,
                            waits_s=waits + tuple(w * 2 for w in waits[1:]), horizon_s=horizon_s)
        if new:
            break
    opts[b] += new
    log.append({"aside": b, "of": [a, o], "strict": strict, "options": len(new)})
    return bool(new)


def _evade_pair(geoms, prob, opts, i, j, start_q, goal_q, mv, tried, buffer_mm, limit_s, waits, horizon_s,
                log) -> bool:
    """New options for one infeasible pair: clear detours for either arm, else a step-aside."""
    grown = False
    for a in (i, j):
        if a in mv and ("clear", a, -1) not in tried:
            tried.add(("clear", a, -1))
            for strict in (True, False):
                new = clear_detours(geoms[a], start_q[a], goal_q[a],
                                    _neighbour_poses(geoms, prob, a, start_q, goal_q, strict=strict),
                                    buffer_mm=buffer_mm, max_duration_s=limit_s, waits_s=waits,
                                    horizon_s=horizon_s)
                if new:
                    break
            opts[a] += new
            grown |= bool(new)
            log.append({"clear": a, "strict": strict, "options": len(new)})
    if grown:
        return True
    # a step-aside: the arm that moves more passes; one of its neighbours (the other arm of
    # the pair first) leaves the swept area of a move that clears all its other neighbours
    move = [max((o.duration_s for o in opts[k]), default=0.0) for k in (i, j)]
    a, first = (i, j) if move[0] >= move[1] else (j, i)
    n = len(geoms)
    for b in dict.fromkeys([first, (a - 1) % n, (a + 1) % n]):
        if b not in mv or ("aside", b, a) in tried:
            continue
        tried.add(("aside", b, a))
        for strict in (True, False):
            pa, pb = step_aside(geoms[a], start_q[a], goal_q[a],
                                _neighbour_poses(geoms, prob, a, start_q, goal_q, skip=(b,), strict=strict),
                                opts[a], geoms[b], start_q[b], goal_q[b],
                                _neighbour_poses(geoms, prob, b, start_q, goal_q, skip=(a,), strict=strict),
                                buffer_mm=buffer_mm, max_duration_s=limit_s,
                                waits_s=waits + tuple(w * 2 for w in waits[1:]), horizon_s=horizon_s)
            if pb:
                break
        log.append({"aside": b, "passing": a, "strict": strict, "passing_options": len(pa), "options": len(pb)})
        if pb:
            opts[a] += [o for o in pa if not any(o is c for c in opts[a])]
            opts[b] += pb
            return True
    return False
