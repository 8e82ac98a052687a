"""Sequenced straight moves: every arm's motion built one straight move at a time (a search).

Prioritized planning (thesis 6.3.3) at the level of whole straight joint-space moves on a
fine time grid (:class:`planner.timeline.Timeline`). Arms are taken in a priority order; each
goes straight to its goal, either theta2 way round, at the earliest departure that keeps clear
of the motions of the arms planned before it. Arms not planned yet are invisible, so an arm
that rests in the way of an earlier one must get out in time (its first move is checked
against its rest at the start), which is what lets arms move together and in turn:

* an arm that cannot go straight goes through one way-point (start -> v -> goal, one stop):
  a step aside, a retraction or a detour, v from a grid of its joint space ranked by travel
  time plus the wait for the planned arms to leave v;
* when an arm cannot be planned at all, the planned arm in its way is held back at its start
  (so that the other gets out of its way first), then the order changes (the failed arm
  just before it); an order tried before is shuffled with the seed;
* two arms each found in the other's way are planned together: the one planned first steps
  aside to a way-point clear of the other's straight path, the other moves, then the first
  goes on to its goal (:meth:`Attempt.step_aside`);
* the search starts from two orders (longest move first; every arm after those whose start
  its goal blocks), each on the leg and on its time reversal (:func:`search_starts`);
* a plan over the makespan target (:func:`makespan_target_s`) is improved, for as long again
  (at most 1 s), with its last arm first in the order, and the shortest plan is kept.

Plans are searched with a quarter of the timeline's Lipschitz margin and re-checked exactly
(:func:`planner.geometry.timed_collisions`); when the re-check finds a pair too close, the
same attempt runs with the full margin. The result has one straight move per arm where that
is safe (zero stops, the MCC2 ideal) and at most ``max_start_stop + 1`` moves per arm; the
driver verifies it (:mod:`planner.verify`). Each attempt is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from models import clock
from models.budget import Budget
from models.kinematics import direct_move_time_s
from planner.clearance import clearance_to_arms
from planner.geometry import ArmGeom, timed_collisions
from planner.strategy import Leg, same_configuration
from planner.timeline import MoveSamples, Timeline

TWO_PI = 2.0 * np.pi

DT_S = 0.1  # the grid of the timeline
VIA_THETA1 = 9  # way-point grid: theta1 values over [theta1_min, theta1_max]
VIA_THETA2 = 24  # and theta2 values over a full turn
MAX_VIAS_TRIED = 60  # way-points tried per detour, cheapest first
MAX_VIAS_LATE = 20  # way-points tried for an arm whose straight move arrives after the target
MAX_VIAS_ASIDE = 12  # way-points tried for an arm stepping aside for another (Attempt.step_aside)
ASIDE_PATH_SAMPLES = 40  # poses of the other arm's straight path a way-point must clear
ASIDE_MARGIN_MM = 0.5  # and by this much more than the buffer (the path between its poses)
RANK_STRIDE = 8  # the way-points' ranking looks at every 8th step


@dataclass
class SequencedResult:
    """The timeline of the shortest plan found (None if none), the arms left over by the last
    failed attempt of the leg itself, counters, and whether the timeline is of the reversed
    leg (goal -> start)."""

    timeline: Timeline | None
    failed_arms: tuple[int, ...]
    stats: dict = field(default_factory=dict)
    reversed: bool = False  # the timeline plans goal -> start


def goal_targets(p: np.ndarray, g: np.ndarray) -> list[np.ndarray]:
    """``g`` with theta2 unwrapped next to ``p``: both ways round, the shorter first (one pose
    when theta2 does not change)."""
    ccw = float(np.mod(g[1] - p[1], TWO_PI))
    if ccw <= 1e-12 or TWO_PI - ccw <= 1e-12:
        return [np.array([g[0], p[1]])]
    turns = sorted((ccw, ccw - TWO_PI), key=abs)
    return [np.array([g[0], p[1] + t]) for t in turns]


def at_goal(p: np.ndarray, g: np.ndarray) -> bool:
    d = float(np.mod(g[1] - p[1], TWO_PI))
    return abs(p[0] - g[0]) <= 1e-9 and min(d, TWO_PI - d) <= 1e-9


def via_grid(geom: ArmGeom, p: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Way-point candidates of an arm at ``p`` bound for ``g`` (theta2 unwrapped within half a
    turn of ``p``), outside the ZoA, by travel time p -> v -> g (shorter first)."""
    t1 = np.linspace(geom.theta1_min, geom.theta1_max, VIA_THETA1)
    t2 = p[1] + np.linspace(-np.pi, np.pi, VIA_THETA2, endpoint=False)
    grid = np.array(np.meshgrid(t1, t2, indexing="ij")).reshape(2, -1).T
    g2 = p[1] + (np.mod(g[1] - p[1] + np.pi, TWO_PI) - np.pi)
    extra = [[geom.theta1_max, p[1]], [geom.theta1_max, g2], [p[0], g2], [g[0], p[1]]]
    for f in (1 / 3, 2 / 3):
        r = p[0] + f * (geom.theta1_max - p[0])
        extra += [[r, p[1]], [r, g2], [r, 0.5 * (p[1] + g2)]]
    v = np.vstack([np.array(extra), grid])
    v = v[~geom.in_zoa(v[:, 0], v[:, 1])]
    gg = np.array([g[0], g2])
    cost = geom.move_time_s(p, v) + geom.move_time_s(v, gg)
    keep = geom.move_time_s(p, v) > 1e-9
    return v[keep][np.argsort(cost[keep], kind="stable")]


class Attempt:
    """One pass of the search in a given arm order (module docstring)."""

    def __init__(self, leg: Leg, order: list[int], budget: Budget, timeline: Timeline,
                 holds: dict[int, int] | None = None, target_s: float = math.inf,
                 yields: dict[int, int] | None = None) -> None:
        self.leg = leg
        self.target_s = float(target_s)
        self.budget = budget
        self.goal = leg.goal_q
        self.tl = timeline.fresh()
        self.order = list(order)
        self.holds = dict(holds or {})  # arm -> the earliest step its first move may depart
        self.yields = dict(yields or {})  # arm -> the arm it steps aside for (step_aside)
        self.done: set[int] = set()  # arms planned in this attempt
        for k in set(range(leg.n_arms)) - set(leg.enabled):  # disabled arms rest where they are
            self.tl.visible[k] = True
        self.stats = {"moves_tried": 0, "vias_tried": 0, "detours": 0}

    # ---------------------------------------------------------------- single moves

    def _best_move(self, k: int, targets: list[np.ndarray]) -> tuple[MoveSamples, int] | None:
        """The target reached first (earliest arrival), with its departure step; else None."""
        tl = self.tl
        best = None
        hold = self.holds.get(k, 0) if not tl.moves[k] else 0
        for ms in (m for m in (tl.samples(k, q) for q in targets) if m is not None):
            self.stats["moves_tried"] += 1
            d, _ = tl.earliest_departure(k, ms, min_step=hold)
            if d >= 0 and (best is None or d * tl.dt_s + ms.duration_s < best[1] * tl.dt_s + best[0].duration_s):
                best = (ms, d)
        return best

    def to_goal(self, k: int) -> bool:
        """Arm k straight to its goal at the earliest departure; when that arrives after the
        makespan target, a detour arriving earlier is taken instead, if there is one."""
        tl = self.tl
        found = self._best_move(k, goal_targets(tl.pose(k), self.goal[k]))
        if found is None:
            return False
        ms, d = found
        arrival_s = d * tl.dt_s + ms.duration_s
        if arrival_s > self.target_s and tl.moves_left(k) >= 2 and self.detour(k, arrival_s, MAX_VIAS_LATE):
            self.stats["earlier_detours"] = self.stats.get("earlier_detours", 0) + 1
            return True
        tl.commit(k, ms, d)
        return True

    def vias(self, k: int) -> np.ndarray:
        """Way-point candidates of arm k, at most MAX_VIAS_TRIED: those where it could rest for
        ever once the planned arms have passed, by travel time plus the wait for them to pass."""
        tl = self.tl
        p, g = tl.pose(k), self.goal[k]
        v = via_grid(tl.geoms[k], p, g)
        if len(v) == 0:
            return v
        last = tl.free_after(k, v, RANK_STRIDE)  # a ranking: the moves are checked in full later
        ok = last < tl.n_steps
        geom = tl.geoms[k]
        g2 = np.array([g[0], p[1] + (np.mod(g[1] - p[1] + np.pi, TWO_PI) - np.pi)])
        t_in = geom.move_time_s(p, v)
        cost = np.maximum(t_in, last * tl.dt_s) + geom.move_time_s(v, g2)
        idx = np.flatnonzero(ok)
        idx = idx[np.argsort(cost[idx], kind="stable")]
        return v[idx[:MAX_VIAS_TRIED]]

    def detour(self, k: int, before_s: float = math.inf, max_vias: int | None = None) -> bool:
        """Arm k start -> v -> goal arriving before ``before_s``, v the cheapest way-point
        from which both moves are safe."""
        tl = self.tl
        if tl.moves_left(k) < 2:
            return False
        for v in self.vias(k)[:max_vias]:
            if self.budget.expired():
                return False
            self.stats["vias_tried"] += 1
            first = self._best_move(k, [v])
            if first is None or first[1] * tl.dt_s + first[0].duration_s >= before_s:
                continue
            tl.commit(k, *first)
            if self.to_goal(k):
                if tl.arrival_s(k) < before_s:
                    self.stats["detours"] += 1
                    return True
                tl.undo(k)
            tl.undo(k)
        return False

    # ---------------------------------------------------------------- the pass

    def culprit(self, k: int) -> int | None:
        """The planned arm without which arm k could go straight to its goal, if there is one
        (the earliest in the order)."""
        tl = self.tl
        targets = [ms for ms in (tl.samples(k, q) for q in goal_targets(tl.pose(k), self.goal[k])) if ms is not None]
        for j in self.order:
            if j == k or not tl.visible[j]:
                continue
            tl.visible[j] = False
            try:
                if any(tl.earliest_departure(k, ms)[0] >= 0 for ms in targets):
                    return j
            finally:
                tl.visible[j] = True
        return None

    def run(self, prefixes: dict | None = None) -> tuple[int, ...]:
        """Plans every arm in order; returns the arm that could not be planned and those after
        it (empty: success); ``self.blamed`` is then the planned arm in its way, if one is.

        ``prefixes`` keeps the moves of every prefix of the order planned so far, by the arms
        and their holds: an arm's plan depends only on the arms before it and its own hold, so
        an attempt takes up where the longest prefix it shares with an earlier one ended."""
        self.blamed: int | None = None
        start = self._resume(prefixes) if prefixes is not None else 0
        for i, k in enumerate(self.order[start:], start):
            if k in self.done:  # planned with the arm it stepped aside for
                continue
            if self.budget.expired():
                return tuple(a for a in self.order[i:] if a not in self.done)
            yielded = k in self.yields and self.yields[k] not in self.done and self.step_aside(k, self.yields[k])
            if not (yielded or self.to_goal(k) or self.detour(k)):
                self.blamed = self.culprit(k)
                return tuple(a for a in self.order[i:] if a not in self.done)
            self.done.add(k)
            if prefixes is not None:
                prefixes[self._prefix_key(i + 1)] = tuple((j, tuple(self.tl.moves[j])) for j in sorted(self.done))
        return ()

    def _prefix_key(self, n: int) -> tuple:
        return tuple((k, self.holds.get(k, 0), self.yields.get(k, -1)) for k in self.order[:n])

    def _resume(self, prefixes: dict) -> int:
        """Restores the longest planned prefix of the order; its length."""
        for n in range(len(self.order), 0, -1):
            planned = prefixes.get(self._prefix_key(n))
            if planned is not None:
                for k, mv in planned:
                    self.tl.restore(k, mv)
                    self.done.add(k)
                self.stats["arms_resumed"] = self.stats.get("arms_resumed", 0) + len(planned)
                return n
        return 0

    # ---------------------------------------------------------------- stepping aside

    def step_aside(self, j: int, k: int) -> bool:
        """Arm j makes way for arm k: j goes to a way-point clear of k's straight path
        (:meth:`aside_vias`), k is planned (straight or by a detour), then j goes on to its
        goal (one stop for j). For two arms each in the other's way whichever goes first."""
        tl = self.tl
        if tl.moves[j] or tl.moves_left(j) < 2:
            return False
        for v in self.aside_vias(j, k)[:MAX_VIAS_ASIDE]:
            if self.budget.expired():
                return False
            self.stats["asides_tried"] = self.stats.get("asides_tried", 0) + 1
            first = self._best_move(j, [v])
            if first is None:
                continue
            tl.commit(j, *first)
            if self.to_goal(k) or self.detour(k):
                if self.to_goal(j):
                    self.done.add(k)
                    self.stats["asides"] = self.stats.get("asides", 0) + 1
                    return True
                self._take_back(k)
            self._take_back(j)
        return False

    def _take_back(self, k: int) -> None:
        while self.tl.moves[k]:
            self.tl.undo(k)
        self.tl.visible[k] = False

    def aside_vias(self, j: int, k: int) -> np.ndarray:
        """Way-points of arm j (:func:`via_grid`, by travel time) at which it clears arm k's
        straight path to its goal and k's goal itself."""
        tl = self.tl
        gj, gk = tl.geoms[j], tl.geoms[k]
        v = via_grid(gj, tl.pose(j), self.goal[j])
        if len(v) == 0:
            return v
        pk = tl.pose(k)
        tk = goal_targets(pk, self.goal[k])[0]
        f = np.linspace(0.0, 1.0, ASIDE_PATH_SAMPLES)[:, None]
        path = pk + f * (tk - pk)
        ks, ke = gk.segments(path[:, 0], path[:, 1])
        vs, ve = gj.segments(v[:, 0], v[:, 1])
        c = clearance_to_arms(vs, ve, gj.radius, ks[:, None], ke[:, None], np.repeat(gk.radius[None], len(path), 0))
        return v[c.min(axis=0) >= tl.buffer_mm + ASIDE_MARGIN_MM]


def direct_times_s(leg: Leg) -> np.ndarray:
    """Each arm's shortest straight move time (thesis eq. 6.23)."""
    inst = leg.instrument
    return direct_move_time_s(leg.start_q, leg.goal_q, inst.arm_array("joint1_speed_rad_s"),
                              inst.arm_array("joint2_speed_rad_s"))


def first_order(leg: Leg) -> list[int]:
    """Longest straight move first (the arms that set the makespan move earliest)."""
    t = direct_times_s(leg)
    return [int(k) for k in sorted(leg.enabled, key=lambda k: (-t[k], k))]


def blocks_start(leg: Leg) -> np.ndarray:
    """``b[k, j]``: arm k resting at its goal comes within the buffer of arm j resting at its
    start, so j must leave before k arrives."""
    n = leg.n_arms
    starts = [leg.geoms[j].segments(leg.start_q[j, :1], leg.start_q[j, 1:]) for j in range(n)]
    S = np.stack([s for s, _ in starts])  # (n, 1, nb, 2): every arm at its start
    E = np.stack([e for _, e in starts])
    R = np.stack([g.radius for g in leg.geoms])
    b = np.zeros((n, n), dtype=bool)
    for k in leg.enabled:
        gs, ge = leg.geoms[k].segments(leg.goal_q[k, :1], leg.goal_q[k, 1:])
        b[k] = clearance_to_arms(gs, ge, leg.geoms[k].radius, S, E, R)[:, 0] < leg.buffer_mm
        b[k, k] = False
    off = np.ones(n, dtype=bool)
    off[list(leg.enabled)] = False
    b[:, off] = False
    return b


def precedence_order(leg: Leg) -> list[int]:
    """:func:`first_order` with every arm after the arms it must wait for (those whose start
    its goal blocks, :func:`blocks_start`): planned first, they leave first, and the arm
    waits for them. Within a cycle, the longest move first."""
    b = blocks_start(leg)
    left, out = first_order(leg), []
    while left:
        free = [k for k in left if not any(b[k, j] for j in left if j != k)]
        k = free[0] if free else left[0]
        out.append(k)
        left.remove(k)
    return out


# the initial orders the search starts from, in turn (plan_sequenced)
ORDERINGS = (first_order, precedence_order)


# the Lipschitz margin of the time grid's threshold (planner.timeline.Timeline): a plan found
# with the bare buffer at the samples is re-checked exactly, and planned again with the full
# margin if it comes too close between samples
MARGINS = (0.25, 1.0)
MAX_IMPROVE_S = 1.0  # at most this long spent improving a plan over the makespan target
HOLD_STEP_S = 10.0  # a blamed arm's departure is held back by this much more in the next attempt
MAX_HOLD_S = 40.0
START_SHARE = 0.5  # each start of search_starts but the last takes this share of the budget left


def _collisions(leg: Leg, tl: Timeline) -> list[tuple[int, int]]:
    """The planner's own exact re-check of a timeline (10 ms, Lipschitz-certified)."""
    return timed_collisions(leg.geoms, [tl.waypoints(k) for k in range(leg.n_arms)], leg.buffer_mm)


def plan_sequenced(leg: Leg, budget: Budget, max_attempts: int = 64) -> SequencedResult:
    """The search of :func:`search_from` from each start of :func:`search_starts` in turn
    (each but the last with START_SHARE of the budget left, the last with all of it; each
    with up to ``max_attempts``) until one finds a plan. A plan of the time-reversed leg (goal -> start) comes back with
    ``reversed`` set: played backwards it is a plan of ``leg`` (collisions, the ZoA, speed
    limits and stops are symmetric in time)."""
    t0 = clock.now()
    o = leg.options
    bases: dict[tuple[bool, float], Timeline] = {}  # one rest state per direction and margin

    def base_of(sub: Leg, rev: bool):
        def base(margin: float) -> Timeline:
            if (rev, margin) not in bases:
                bases[rev, margin] = Timeline(sub.geoms, sub.start_q, horizon_s=o.horizon_s, dt_s=DT_S,
                                              buffer_mm=sub.buffer_mm, max_moves=o.max_start_stop + 1,
                                              margin=margin)
            return bases[rev, margin]
        return base

    starts = search_starts(leg)
    stats: dict = {"attempts": 0, "starts": 0}
    failed = tuple(leg.enabled)
    for i, (sub, rev, order) in enumerate(starts):
        if budget.expired():
            break
        share = 1.0 if i == len(starts) - 1 else START_SHARE
        t_s = clock.now()  # this start's part of what is left; its shares stay fractions of the leg's
        part = replace(budget, start_s=t_s, deadline_s=t_s + share * budget.left_s())
        stats["starts"] += 1
        best, left = search_from(sub, order, part, max_attempts, base_of(sub, rev), stats)
        if best is not None:
            stats["reversed"] = rev
            stats["compute_s"] = clock.now() - t0
            stats["makespan_s"] = best.makespan_s()
            return SequencedResult(best, (), stats, reversed=rev)
        if not rev:
            failed = left
    stats["compute_s"] = clock.now() - t0
    return SequencedResult(None, failed, stats)


def search_starts(leg: Leg) -> list[tuple[Leg, bool, list[int]]]:
    """Where the search starts: (leg, reversed, initial order) for each order of
    ``ORDERINGS`` and each direction. Arms spread out from park more easily than they
    converge onto it (kaiju's premise), so a leg from park is searched forward first and a
    leg to park reversed first; any other leg takes the directions in turn. An order met
    before once is enough."""
    park = leg.instrument.park_configuration
    fwd, rev = (leg, False), (leg.with_ends(leg.goal_q, leg.start_q), True)
    if same_configuration(leg.goal_q, park):
        pairs = [(d, f) for d in (rev, fwd) for f in ORDERINGS]
    elif same_configuration(leg.start_q, park):
        pairs = [(d, f) for d in (fwd, rev) for f in ORDERINGS]
    else:
        pairs = [(d, f) for f in ORDERINGS for d in (fwd, rev)]
    out, seen = [], set()
    for (sub, is_rev), f in pairs:
        order = f(sub)
        if (is_rev, tuple(order)) not in seen:
            seen.add((is_rev, tuple(order)))
            out.append((sub, is_rev, order))
    return out


def search_from(leg: Leg, order: list[int], budget: Budget, max_attempts: int, base, stats: dict
                ) -> tuple[Timeline | None, tuple[int, ...]]:
    """Attempts from ``order`` until one plans every arm (module docstring); the shortest
    plan found (or None) and the arms the last failed attempt left. After a failed attempt,
    the planned arm in the way of the arm that failed (if there is one) is held back at its
    start a little longer, so that the other can get out of its way; once held long enough,
    the failed arm goes just before it in the order instead (else first). Two arms each
    found in the other's way are planned together: the one planned first steps aside for
    the other (:meth:`Attempt.step_aside`). A state tried before gives a shuffled order. A
    plan longer than :func:`makespan_target_s` is improved with the last arm to arrive first
    in the order, for as long again as the first plan took (at most MAX_IMPROVE_S). ``base(margin)`` gives the timeline at rest."""
    t0 = clock.now()
    rng = np.random.default_rng(leg.options.seed)
    hold_step = int(round(HOLD_STEP_S / DT_S))
    holds: dict[int, int] = {}
    yields: dict[int, int] = {}
    blames: set[tuple[int, int]] = set()  # (failed arm, the planned arm in its way)
    direct_s = direct_times_s(leg)
    failed: tuple[int, ...] = tuple(leg.enabled)
    tried: set = set()
    best: Timeline | None = None
    target_s = makespan_target_s(leg.lower_bound_s)
    improve_until = math.inf
    prefixes: dict[float, dict] = {m: {} for m in MARGINS}  # per margin (Attempt.run)
    for _ in range(max_attempts):
        if budget.expired() or clock.now() > improve_until:
            break
        tried.add(_state(order, holds, yields))
        found, failed, blamed = _attempt(leg, order, budget, holds, yields, target_s, base, stats, prefixes)
        if found is not None:
            if best is None or found.makespan_s() < best.makespan_s() - 1e-9:
                best = found
            if best.makespan_s() <= target_s:
                break
            if improve_until == math.inf:
                improve_until = clock.now() + min(clock.now() - t0, MAX_IMPROVE_S)
            late = max(leg.enabled, key=lambda k: (found.arrival_s(k), -k))
            order, holds = [late] + [i for i in order if i != late], {}
        else:
            k, j = failed[0], blamed
            held_s = (holds.get(j, 0) + hold_step) * DT_S if j is not None else math.inf
            mutual = j is not None and (j, k) in blames and yields.get(j) != k
            blames.add((k, j))
            if mutual:
                yields, holds = {**yields, j: k}, {}
            elif j is not None and held_s <= MAX_HOLD_S and held_s + direct_s[j] <= target_s:
                holds = {**holds, j: holds.get(j, 0) + hold_step}
            else:
                holds = {}
                order = [i for i in order if i != k]
                order.insert(order.index(j) if j is not None else 0, k)
        if _state(order, holds, yields) in tried:
            order, holds, yields = [int(i) for i in rng.permutation(order)], {}, {}
    return best, failed


def _state(order: list[int], holds: dict[int, int], yields: dict[int, int]) -> tuple:
    return tuple(order), tuple(sorted(holds.items())), tuple(sorted(yields.items()))


def _attempt(leg: Leg, order: list[int], budget: Budget, holds: dict[int, int], yields: dict[int, int],
             target_s: float, base, stats: dict, prefixes: dict[float, dict]
             ) -> tuple[Timeline | None, tuple[int, ...], int | None]:
    """One attempt, searched at each margin of MARGINS until the exact re-check passes: the
    timeline (None if it failed), the arms left over and the arm blamed. ``prefixes``: the
    planned prefixes of earlier attempts, per margin (:meth:`Attempt.run`)."""
    for margin in MARGINS:
        att = Attempt(leg, order, budget, base(margin), holds, target_s, yields)
        failed = att.run(prefixes[margin])
        stats["attempts"] += 1
        for key, v in att.stats.items():
            stats[key] = stats.get(key, 0) + v
        if failed:
            return None, failed, att.blamed
        if not _collisions(leg, att.tl):
            return att.tl, (), None
        stats["recheck_failures"] = stats.get("recheck_failures", 0) + 1
    return None, tuple(order), None


def makespan_target_s(lower_bound_s: float) -> float:
    """A plan this long is kept at once: 10 % over the lower bound, and at least 6 s over it
    (a few departure steps)."""
    return max(1.10 * lower_bound_s, lower_bound_s + 6.0)
