"""Straight moves with departure delays: a pairwise-table CSP over motion options.

The MCC2 controllers cannot blend way-points, so the ideal motion of a probe arm is one
straight joint-space move from start to goal (both joints linear, arriving together, the
slower joint scaled down; zero intermediate stops). Conflicts between such moves can very
often be resolved by *when* each arm departs, not by where it goes. This module plans all
arms at once:

* every arm has a few **options** (:class:`Option`): the straight move either way round in
  theta2 (a direction whose segment crosses the ZoA is discarded), and, when asked for,
  one-stop detours start -> v -> goal with a wait at v (v a roadmap vertex or a side-step
  near the start), or a step-aside start -> v -> start for an arm that does not move;
* every option departs after a delay tau in {0, dt, 2 dt, ...} and must arrive within the
  horizon;
* for every arm pair and option pair, the set of collision-free *relative* delays
  tau_j - tau_i is computed vectorised (:func:`planner.delay_tables.pair_table`): both
  motions sampled every dt_col, including the rests before departure and after arrival,
  clearance >= buffer at every sample; a solution's re-check (``check`` of
  :class:`DelaySearch`) forbids what falls between the samples;
* the delay assignment is a small CSP (:func:`solve`): backtracking with forward checking,
  most-constrained arm first, values by earliest arrival, and branch-and-bound on the
  makespan max_k(tau_k + T_k).

Everything is deterministic (no randomness). The strategy :mod:`planner.strategies.delays`
wraps it; the driver (:mod:`planner.driver`) verifies its plans before returning them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models import clock
from models.budget import Budget
from planner.delay_tables import (  # noqa: F401 - the tables' types and builders, used through this module
    DelayProblem,
    DelayStats,
    Option,
    build_problem,
    pair_table,
    prepare,
)
from planner.geometry import ArmGeom, edges_in_zoa

TWO_PI = 2.0 * np.pi


def straight_options(geom: ArmGeom, qs: np.ndarray, qg: np.ndarray) -> list[Option]:
    """Straight moves start -> goal, both theta2 directions, ZoA-free only."""
    ccw = float(np.mod(qg[1] - qs[1], TWO_PI))
    if abs(qg[0] - qs[0]) <= 1e-12 and min(ccw, TWO_PI - ccw) <= 1e-12:
        return [Option(geom.arm, qs[None].copy(), np.zeros(1), 0, "stay")]
    turns = [ccw] if ccw <= 1e-12 else [ccw, ccw - TWO_PI]
    out = []
    for tr in turns:
        e = np.array([qg[0], qs[1] + tr])
        if edges_in_zoa(geom, qs[None], e[None])[0]:
            continue
        T = float(geom.move_time_s(qs, e))
        out.append(Option(geom.arm, np.array([qs, e]), np.array([0.0, T]), 0, "straight"))
    out.sort(key=lambda o: o.duration_s)
    return out


def detour_options(geom: ArmGeom, qs: np.ndarray, qg: np.ndarray, vertices: np.ndarray, waits_s: tuple[float, ...],
                   max_vertices: int, horizon_s: float) -> list[Option]:
    """One-stop options start -> v -> goal (or start -> v -> start when the arm stays), waiting at v."""
    ccw = float(np.mod(qg[1] - qs[1], TWO_PI))
    stay = abs(qg[0] - qs[0]) <= 1e-12 and min(ccw, TWO_PI - ccw) <= 1e-12
    V = np.asarray(vertices, float)
    if len(V) == 0:
        return []
    cand = []
    for sgn in (1, -1):
        t1 = np.mod(V[:, 1] - qs[1], TWO_PI)
        turn1 = np.where(sgn > 0, t1, t1 - TWO_PI)
        v = np.column_stack([V[:, 0], qs[1] + turn1])
        ok1 = ~edges_in_zoa(geom, np.broadcast_to(qs, v.shape), v)
        for sgn2 in (1, -1):
            t2 = np.mod(qg[1] - v[:, 1], TWO_PI)
            turn2 = np.where(sgn2 > 0, t2, t2 - TWO_PI)
            g = np.column_stack([np.full(len(v), qg[0]), v[:, 1] + turn2])
            ok2 = ~edges_in_zoa(geom, v, g)
            T1 = geom.move_time_s(np.broadcast_to(qs, v.shape), v)
            T2 = geom.move_time_s(v, g)
            for i in np.flatnonzero(ok1 & ok2):
                cand.append((float(T1[i] + T2[i]), float(T1[i]), float(T2[i]), v[i], g[i]))
    cand.sort(key=lambda c: c[0])
    out: list[Option] = []
    seen = set()
    for tot, T1, T2, v, g in cand:
        key = (round(v[0], 6), round(v[1], 6), round(g[1], 6))
        if key in seen or T1 < 1e-9 or (T2 < 1e-9 and not stay):
            continue
        seen.add(key)
        for w in waits_s:
            if tot + w > horizon_s:
                continue
            if w > 0:
                wp = np.array([qs, v, v, g])
                tr = np.array([0.0, T1, T1 + w, T1 + w + T2])
            else:
                wp = np.array([qs, v, g])
                tr = np.array([0.0, T1, T1 + T2])
            out.append(Option(geom.arm, wp, tr, 1, "aside" if stay else "detour"))
        if len(seen) >= max_vertices:
            break
    return out


def _support(tab: np.ndarray, dom_j: np.ndarray, K: int) -> np.ndarray:
    """support[p, t]: value (p, t) of arm i has a compatible value in arm j's domain.

    ``tab`` is (Pi, Pj, 2K + 1) over k = t_j - t_i; ``dom_j`` is (Pj, K + 1).
    """
    Pi = tab.shape[0]
    out = np.zeros((Pi, K + 1), bool)
    tj = np.flatnonzero(dom_j.any(0))
    if len(tj) == 0:
        return out
    lo, hi = int(tj.min()), int(tj.max())
    dj = dom_j[:, lo:hi + 1]
    for t in range(K + 1):
        win = tab[:, :, K - t + lo: K - t + hi + 1]  # k = tj - t for tj in [lo, hi]
        out[:, t] = (win & dj[None]).any(axis=(1, 2))
    return out


def arc_consistency(prob: DelayProblem, doms: list[np.ndarray], blame: np.ndarray | None = None,
                    max_rounds: int = 20) -> list[np.ndarray] | None:
    """AC-3 style pruning of every arm's (option, delay) domain; None when a domain empties."""
    doms = list(doms)
    queue = list(range(len(doms)))
    rounds = 0
    while queue and rounds < max_rounds * len(doms):
        rounds += 1
        j = queue.pop(0)
        for i in prob.neighbours[j]:
            sup = _support(prob.tables[(i, j)], doms[j], prob.K)
            nd = doms[i] & sup
            if not nd.any():
                if blame is not None:
                    blame[i] += 1
                    blame[j] += 1
                return None
            if (nd != doms[i]).any():
                doms[i] = nd
                if i not in queue:
                    queue.append(i)
    return doms


def solve(prob: DelayProblem, stats: DelayStats, *, node_budget: int = 20000,
          fixed: dict[int, tuple[int, int]] | None = None,
          budget: Budget | None = None) -> tuple[dict[int, tuple[int, int]] | None, list[int]]:
    """Assign (option, delay) to every arm minimising the makespan (branch and bound), until
    ``budget`` (None: the node budget only) has passed its deadline.

    Returns (assignment or None, the arms most often found with an empty domain).
    """
    n = len(prob.options)
    K = prob.K
    dt = prob.dt_s
    dur = [np.array([o.duration_s for o in opts]) for opts in prob.options]
    # finish[k][p, tau]
    finish = [d[:, None] + dt * np.arange(K + 1)[None, :] for d in dur]
    base = _base_domains(prob, finish, fixed)
    blame = np.zeros(n, int)
    best: dict[int, tuple[int, int]] | None = None
    nodes = 0

    def search(bound: float) -> dict[int, tuple[int, int]] | None:
        nonlocal nodes
        doms = [b & (f <= bound) for b, f in zip(base, finish, strict=True)]
        if any(not d.any() for d in doms):
            return None
        if budget is not None and budget.past_deadline():
            return None
        doms = arc_consistency(prob, doms, blame)
        if doms is None:
            return None
        assign: dict[int, tuple[int, int]] = {}

        def rec(doms: list[np.ndarray]) -> bool:
            nonlocal nodes
            if len(assign) == n:
                return True
            free = [k for k in range(n) if k not in assign]
            # most constrained first; then most neighbours; then index
            k = min(free, key=lambda a: (int(doms[a].sum()), -len(prob.neighbours[a]), a))
            vals = np.argwhere(doms[k])
            order = np.lexsort((vals[:, 0], finish[k][vals[:, 0], vals[:, 1]]))
            for p, t in vals[order]:
                nodes += 1
                clock.work("csp_nodes", 1)
                if nodes > node_budget or (budget is not None and budget.past_deadline()):
                    nodes = node_budget + 1
                    return False
                new = list(doms)
                dead = None
                for j in prob.neighbours[k]:
                    if j in assign:
                        continue
                    tab = prob.tables[(k, j)][p]  # (Pj, 2K + 1)
                    allowed = tab[:, K - t: 2 * K - t + 1]
                    nd = new[j] & allowed
                    if not nd.any():
                        dead = j
                        break
                    new[j] = nd
                if dead is not None:
                    blame[dead] += 1
                    blame[k] += 1
                    continue
                assign[k] = (int(p), int(t))
                if rec(new):
                    return True
                del assign[k]
                if nodes > node_budget:
                    return False
            return False

        return dict(assign) if rec(doms) else None

    bound = prob.horizon_s + 1e-9
    while nodes <= node_budget:
        sol = search(bound)
        if sol is None:
            break
        ms = max(float(finish[k][p, t]) for k, (p, t) in sol.items())
        best = sol
        bound = ms - 1e-6
    stats.nodes += nodes
    if best is not None:
        return best, []
    return None, _blame_order(prob, base, blame)


def _base_domains(prob: DelayProblem, finish: list[np.ndarray],
                  fixed: dict[int, tuple[int, int]] | None) -> list[np.ndarray]:
    """dom[k][p, tau]: arriving within the horizon; a staying arm has one value; fixed arms one."""
    base = []
    for k, opts in enumerate(prob.options):
        m = finish[k] <= prob.horizon_s + 1e-9
        for p, o in enumerate(opts):
            if o.kind == "stay":  # an arm that stays has no departure: one value
                m[p, 1:] = False
        base.append(m)
    for k, (p, t) in (fixed or {}).items():
        m = np.zeros_like(base[k])
        m[p, t] = True
        base[k] = m
    return base


def _blame_order(prob: DelayProblem, base: list[np.ndarray], blame: np.ndarray) -> list[int]:
    """The arms to blame for an unsolvable CSP, most to blame first.

    First the arms of pairs that are infeasible on their own (a cycle between two arms: no
    relative delay of any option pair works); AC wipe-outs elsewhere may be propagated.
    """
    pair_bad: list[int] = []
    for (i, j) in sorted(prob.tables):
        if i < j and not (base[i] & _support(prob.tables[(i, j)], base[j], prob.K)).any():
            pair_bad += [a for a in (i, j) if a not in pair_bad]
    worst = [int(a) for a in np.argsort(-blame, kind="stable") if blame[a] > 0]
    return pair_bad + [a for a in worst if a not in pair_bad]


def trajectory_points(option: Option, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Way-point times and configurations of an option departing at ``tau_s``."""
    if option.kind == "stay":
        return np.zeros(1), option.waypoints[:1].copy()
    t = option.t_rel + tau_s
    q = option.waypoints
    if tau_s > 0:
        t = np.concatenate([[0.0], t])
        q = np.concatenate([q[:1], q])
    return t, q.copy()


def detour_vertices(geom: ArmGeom, qs: np.ndarray, qg: np.ndarray, grid: tuple[int, int],
                    rings_rad: tuple[float, ...] = (0.3, 0.6, 1.0)) -> np.ndarray:
    """Candidate stop vertices: rings around the start (side-steps) and the goal (approach
    from another direction), the two one-joint-at-a-time corners, a retract vertex
    (theta1 = theta1_max) and the roadmap grid (thesis fig. 6.8); all outside the ZoA."""
    from planner.roadmap import grid_vertices

    pts = [[qs[0], qg[1]], [qg[0], qs[1]], [geom.theta1_max, qs[1]], [geom.theta1_max, qg[1]]]
    for c in (qg, qs):
        for r in rings_rad:
            for a in np.arange(8) * np.pi / 4:
                pts.append([c[0] + r * np.cos(a), c[1] + r * np.sin(a)])
    v = np.concatenate([np.asarray(pts, float), grid_vertices(geom, grid)])
    v[:, 1] = np.mod(v[:, 1], TWO_PI)
    return v[~geom.in_zoa(v[:, 0], v[:, 1])]


@dataclass
class DelayResult:
    assignment: dict[int, tuple[int, int]] | None
    options: list[list[Option]]
    blamed: list[int]
    rounds: int
    makespan_s: float = math.nan
    # the last problem with straight options only (both theta2 directions once round 1 ran):
    # the cluster strategy (planner.cluster) reuses its tables
    straight: DelayProblem | None = None


class DelaySearch:
    """The delay CSP over its rounds, in two phases that other strategies can sit between.

    :meth:`straight_phase` runs the rounds with straight options only. Round 0: each movable
    arm's shortest straight move (and the other theta2 direction when it is not longer than
    the lower bound, so it cannot raise the makespan). Round 1: both theta2 directions for
    every arm. It returns the result when it ended (solved, or failed for good), or None
    when every straight option failed and detours may still help: :attr:`straight` then holds
    the straight-move problem (the cluster strategy, :mod:`planner.cluster`, reuses its tables).

    :meth:`detour_phase` goes on: later rounds add, for the arms the CSP blames (if
    ``max_start_stop`` >= 1), one-stop detours start -> v -> goal (a resting arm: start -> v ->
    start) with waits at v of ``detour_waits_steps`` x dt, the detour (wait included) at most
    ``detour_extra_s`` longer than the lower bound or the arm's direct move. One arm is extended
    per round (usually one arm getting out of the way suffices: tables grow as options_i x
    options_j). Tables of option pairs already computed are reused.

    ``check(assignment, options)``, when given, is a collision re-check of a solution: it
    returns the arm pairs found colliding (empty when clear); their (option, relative delay)
    entries are then forbidden and the CSP re-solved, at most ``max_repairs`` times.
    """

    def __init__(self, geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray, *, dt_s: float,
                 dt_col_s: float, horizon_s: float, buffer_mm: float, max_start_stop: int, movable: list[int],
                 stats: DelayStats, grid: tuple[int, int] = (8, 6), max_rounds: int = 5,
                 max_detour_vertices: int = 8, detour_waits_steps: tuple[int, ...] = (0, 2, 5),
                 detour_extra_s: float = 45.0, node_budget: int = 20000, check=None, max_repairs: int = 5):
        self.geoms, self.start_q, self.goal_q = geoms, start_q, goal_q
        self.dt_s, self.dt_col_s, self.horizon_s, self.buffer_mm = dt_s, dt_col_s, horizon_s, buffer_mm
        self.max_start_stop, self.stats, self.grid, self.max_rounds = max_start_stop, stats, grid, max_rounds
        self.max_detour_vertices, self.detour_waits_steps = max_detour_vertices, detour_waits_steps
        self.detour_extra_s, self.node_budget, self.check, self.max_repairs = detour_extra_s, node_budget, check, max_repairs
        n = len(geoms)
        self.mv = set(movable)
        self.opts = [straight_options(geoms[k], start_q[k], goal_q[k]) if k in self.mv
                     else [Option(k, start_q[k][None].copy(), np.zeros(1), 0, "stay")] for k in range(n)]
        self.lb = max((o[0].duration_s for o in self.opts if o), default=0.0)
        self.cur = [[o for i, o in enumerate(op) if i == 0 or o.duration_s <= self.lb + 1e-9] for op in self.opts]
        self.prob: DelayProblem | None = None
        self.straight: DelayProblem | None = None
        self.extended: set[int] = set()
        self.blamed: list[int] = []
        self.seen_blamed: list[int] = []
        self.rnd = 0
        self.result: DelayResult | None = None  # set once the search ended
        self.paused = False  # straight_phase stopped where every straight option had failed
        self._resume_tail = False  # paused mid-round: the detour phase starts with the round's tail

    def _end(self, res: DelayResult) -> DelayResult:
        self.result = res
        return res

    def _failed(self) -> DelayResult:
        return self._end(DelayResult(None, self.cur, self.blamed, self.max_rounds, straight=self.straight))

    def straight_phase(self, deadline: float | None = None, first_round_deadline: float | None = None, *,
                       budget: Budget | None = None, first_round: Budget | None = None) -> DelayResult | None:
        """Straight options only; None when paused (see the class docstring). Round 0's tables
        (the straight problem later strategies start from) are built within ``first_round``
        (None: to the end), the rest within ``budget`` (None: no limit). ``deadline`` and
        ``first_round_deadline``: the same as :func:`models.clock.now` instants, for a caller
        without budgets."""
        budget = _instant_budget(budget, deadline)
        first_round = _instant_budget(first_round, first_round_deadline)
        n = len(self.geoms)
        if any(not o for o in self.opts):
            return self._end(DelayResult(None, self.opts, [k for k in range(n) if not self.opts[k]], 0))
        return self._rounds(budget, pause=True, first_round=first_round)

    def detour_phase(self, budget: Budget | None = None, prefer: list[int] | None = None,
                     futile: bool = False) -> DelayResult:
        """The detour rounds after a paused :meth:`straight_phase`, within ``budget`` (None: no
        limit); ``prefer`` the arms to extend
        first (a removal set, :mod:`planner.cluster`); ``futile`` when detours are known not to
        help (the rounds end at once)."""
        if self.result is not None:
            return self.result
        if self._resume_tail:
            self._resume_tail = False
            step = self._tail(budget, prefer, futile)
            if step == "break":
                return self._failed()
            self.rnd += 1
        out = self._rounds(budget, pause=False, prefer=prefer, futile=futile)
        return out if out is not None else self._failed()

    def _rounds(self, budget: Budget | None, pause: bool, prefer=None, futile=False,
                first_round: Budget | None = None) -> DelayResult | None:
        while self.rnd < self.max_rounds:
            rnd = self.rnd
            nxt = build_problem(self.geoms, self.cur, self.dt_s, self.dt_col_s, self.horizon_s, self.buffer_mm,
                                self.stats, old=self.prob, budget=first_round if rnd == 0 else budget)
            if nxt is None:
                if pause and self.straight is not None and not self.extended:
                    # out of time while adding the other theta2 directions: pause with the
                    # straight problem of round 0 (fewer options, so its schedules stay valid)
                    self.result = DelayResult(None, self.cur, self.blamed, self.max_rounds, straight=self.straight)
                    self.paused = True
                    return None
                return self._failed()
            self.prob = nxt
            if not self.extended:  # a snapshot: later rounds append options to the same lists
                p = self.prob
                self.straight = DelayProblem([list(o) for o in p.options], p.K, p.dt_s, p.horizon_s, p.tables,
                                             p.neighbours)
            sol = self._solve_and_repair(budget)
            if sol is not None:
                ms = max(self.cur[k][p].duration_s + t * self.dt_s for k, (p, t) in sol.items())
                return self._end(DelayResult(sol, self.cur, [], rnd + 1, ms, self.straight))
            timed_out = budget is not None and budget.past_deadline()
            if pause and self.straight is not None and not self.extended and (
                    rnd >= 1 or timed_out or not any(len(self.cur[k]) < len(self.opts[k]) for k in self.mv)):
                self._resume_tail = self.paused = True  # every straight option failed
                return None
            step = self._tail(budget, prefer, futile)
            if step == "break":
                return self._failed()
            self.rnd += 1
        return self._failed()

    def _solve_and_repair(self, budget: Budget | None) -> dict[int, tuple[int, int]] | None:
        prob, cur = self.prob, self.cur
        sol, self.blamed = solve(prob, self.stats, node_budget=self.node_budget, budget=budget)
        repairs = 0
        while sol is not None and self.check is not None and repairs < self.max_repairs:
            bad_pairs = self.check(sol, cur)
            if not bad_pairs:
                break
            repairs += 1
            self.stats.repairs += 1
            for a, b in bad_pairs:
                (pa, ta), (pb, tb) = sol[a], sol[b]
                if (a, b) not in prob.tables:  # the table said "never close": make it explicit
                    Pa, Pb = len(cur[a]), len(cur[b])
                    prob.tables[(a, b)] = np.ones((Pa, Pb, 2 * prob.K + 1), bool)
                    prob.tables[(b, a)] = prob.tables[(a, b)].transpose(1, 0, 2)[:, :, ::-1]
                    prob.neighbours[a].append(b)
                    prob.neighbours[b].append(a)
                prob.tables[(a, b)][pa, pb, tb - ta + prob.K] = False  # the (b, a) view shares memory
            sol, self.blamed = solve(prob, self.stats, node_budget=self.node_budget, budget=budget)
        if sol is not None and (self.check is None or repairs < self.max_repairs):
            return sol
        return None

    def _tail(self, budget: Budget | None, prefer, futile) -> str:
        """The end of a failed round: extend the options; "break" when nothing is left to try."""
        rnd, blamed, cur, opts, mv = self.rnd, self.blamed, self.cur, self.opts, self.mv
        if budget is not None and budget.past_deadline():
            return "break"
        if rnd == 0:
            self.seen_blamed += blamed
            # round 1: both theta2 directions for every arm (a row of neighbours all swinging J2
            # the same long way blocks itself in a chain; some swinging the other way frees it)
            grown = False
            for k in mv:
                for o in opts[k]:
                    if not any(o is c for c in cur[k]):
                        cur[k].append(o)
                        grown = True
            self.stats.log.append({"round": rnd, "blamed": list(blamed), "extend": "both directions"})
            if grown:
                return "continue"
        seen = self.seen_blamed
        seen += [k for k in blamed if k not in seen]
        if (futile or prefer is not None) and self.straight is not None and not self.extended:
            if futile:  # the caller proved the detour rounds futile
                self.stats.log.append({"round": rnd, "blamed": list(blamed), "extend": "futile"})
                return "break"
            first = [k for k in prefer if k in mv]  # extend first the arms of the removal set
            seen[:] = first + [k for k in seen if k not in first]
        new = [k for k in seen if k in mv and k not in self.extended][:1]
        self.stats.log.append({"round": rnd, "blamed": list(blamed), "extend": list(new)})
        if not new:
            return "break"
        for k in new:
            self._extend(k)
        return "continue"

    def _extend(self, k: int) -> None:
        self.extended.add(k)
        for o in self.opts[k]:
            if not any(o is c for c in self.cur[k]):
                self.cur[k].append(o)
        if self.max_start_stop >= 1:
            g, qs, qg = self.geoms[k], self.start_q[k], self.goal_q[k]
            V = detour_vertices(g, qs, qg, self.grid)
            t_direct = min((o.duration_s for o in self.opts[k]), default=0.0)
            self.cur[k].extend(detour_options(g, qs, qg, V, tuple(w * self.dt_s for w in self.detour_waits_steps),
                                              self.max_detour_vertices,
                                              min(self.horizon_s, max(self.lb, t_direct) + self.detour_extra_s)))


def plan_delays(geoms: list[ArmGeom], start_q: np.ndarray, goal_q: np.ndarray, *, budget: Budget | None = None,
                **kwargs) -> DelayResult:
    """Straight moves with departure delays; on failure, one-stop detours for the blamed arms
    (both phases of :class:`DelaySearch` within ``budget``, None: no limit; keyword
    arguments as there)."""
    search = DelaySearch(geoms, start_q, goal_q, **kwargs)
    res = search.straight_phase(budget=budget, first_round=budget)
    return res if res is not None else search.detour_phase(budget)


def _instant_budget(budget: Budget | None, deadline: float | None) -> Budget | None:
    """``budget``, else a budget ending at the instant ``deadline`` (None: no limit)."""
    return budget if budget is not None or deadline is None else Budget.ending_at(deadline)
