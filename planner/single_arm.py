"""Single-arm trajectory search in state-time along roadmap paths (thesis 6.3.4, Algorithms 7-11).

The arms already planned form the obstacle-time set O^Delta (thesis Algorithm 6): their
body capsules sampled every ``dt_col`` over the whole horizon (:class:`ObstacleTime`).
One arm is planned against it along its roadmap paths, most promising first (Algorithm 7,
eq. 6.23), each tried at the velocity-reduction factors alpha (eq. 6.24).

Along one path the search is Find-Edge-Traj (Algorithm 8) generalised to the whole path so
that it may backtrack across way-points: states are z = (edge, k, ns, m, t) where k is the
step index along the edge (s = k / n_edge), ns the start-stop cycles spent, m in {-1, 0, 1}
the motion that reached the state and t the time step. Actions forward / wait / back, one
``dt`` each, explored depth-first with forward first (Algorithm 11 Neigh-DF ordering); ns
grows when a moving arm stops or reverses, and at every intermediate way-point (the MCC2
cannot blend way-points, thesis 3.5.1.2); once ns = nStop only the current motion may go on
(Neigh-maxNS). A node is checked (Algorithm 9 Explore-Node) by interpolating the motion
from its parent every ``dt_col``: all ``dt / dt_col`` samples of the step against all
planned arms whose bounding box in that step overlaps, in one numpy call. On arrival the
goal is checked against the planned arms until every one of them has finished (the goal
conflict check of 6.3.4.5).

Motion model: joints move linearly in time between way-points (constant speed, instant
start/stop). The real MCC2 applies trapezoidal (LSPB) ramps around each commanded move
(thesis 3.5.1); the collision buffer absorbs those small timing differences (6.3.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planner.clearance import clearance_to_arms
from planner.geometry import ArmGeom
from planner.roadmap import RoadmapPath

ALPHAS = (1.0, 0.5, 0.25)  # velocity-reduction factors (thesis table 6.1, eq. 6.24)


@dataclass
class SearchStats:
    collision_checks: int = 0  # arm-pair x dt_col-sample evaluations (as thesis table 6.2)
    states_explored: int = 0
    paths_explored: int = 0


@dataclass
class ObstacleTime:
    """The obstacle-time set O^Delta: planned arms' capsules at every dt_col sample (Algorithm 6).

    Sample j is time j * dt_col; step t covers samples (t - 1) M .. t M with M = dt / dt_col.
    After its arrival an arm stays at its goal until the horizon.
    """

    m: int  # dt_col samples per dt step
    n_steps: int  # horizon in steps
    buffer_mm: float
    nb: int  # bodies per arm (padded to the instrument's maximum)
    arms: list[int] = field(default_factory=list)
    arrival_step: list[int] = field(default_factory=list)
    _s: list[np.ndarray] = field(default_factory=list)  # (N + 1, nb, 2)
    _e: list[np.ndarray] = field(default_factory=list)
    _r: list[np.ndarray] = field(default_factory=list)  # (nb,)
    _bb: list[np.ndarray] = field(default_factory=list)  # (n_steps + 1, 4) xmin ymin xmax ymax
    _stack: tuple | None = None

    @property
    def n_samples(self) -> int:
        return self.n_steps * self.m + 1

    @property
    def last_arrival_step(self) -> int:
        return max(self.arrival_step, default=0)

    def add(self, geom: ArmGeom, q_samples: np.ndarray, arrival_step: int) -> None:
        """Add a planned arm given its configuration at every sample (N + 1, 2)."""
        s, e = geom.segments(q_samples[:, 0], q_samples[:, 1])
        r = geom.radius
        if s.shape[1] < self.nb:  # pad with far-away dummies (instrument with per-arm body lists)
            pad = self.nb - s.shape[1]
            s = np.concatenate([s, np.full((len(s), pad, 2), 1e9)], 1)
            e = np.concatenate([e, np.full((len(e), pad, 2), 1e9)], 1)
            r = np.concatenate([r, np.zeros(pad)])
        self.arms.append(geom.arm)
        self.arrival_step.append(arrival_step)
        self._s.append(s)
        self._e.append(e)
        self._r.append(r)
        self._bb.append(_step_boxes(s, e, self.m, float(r.max())))
        self._stack = None

    def with_static(self, extra: list[tuple[ArmGeom, np.ndarray]]) -> ObstacleTime:
        """A copy that also holds arms resting at the given configurations for the whole horizon."""
        o = ObstacleTime(self.m, self.n_steps, self.buffer_mm, self.nb, list(self.arms), list(self.arrival_step),
                         list(self._s), list(self._e), list(self._r), list(self._bb))
        for g, q in extra:
            o.add(g, np.broadcast_to(np.asarray(q, float), (self.n_samples, 2)), 0)
        return o

    def stacked(self) -> tuple[np.ndarray, ...]:
        if self._stack is None:
            self._stack = (np.stack(self._s), np.stack(self._e), np.stack(self._r), np.stack(self._bb))
        return self._stack

    def __len__(self) -> int:
        return len(self.arms)


def _step_boxes(s: np.ndarray, e: np.ndarray, m: int, pad: float) -> np.ndarray:
    """Bounding box of all bodies over each step's samples (step 0 = sample 0), inflated by ``pad``."""
    n = (len(s) - 1) // m
    pts = np.concatenate([s, e], 1)  # (N + 1, 2 nb, 2)
    lo = pts.min(1)
    hi = pts.max(1)
    out = np.empty((n + 1, 4))
    out[0, :2], out[0, 2:] = lo[0], hi[0]
    if n:
        # samples (t-1) m .. t m inclusive: reduce over blocks of m plus the shared end sample
        blo = lo[1:].reshape(n, m, 2).min(1)
        bhi = hi[1:].reshape(n, m, 2).max(1)
        out[1:, :2] = np.minimum(blo, lo[0:-1:m])
        out[1:, 2:] = np.maximum(bhi, hi[0:-1:m])
    out[:, :2] -= pad
    out[:, 2:] += pad
    return out


@dataclass(frozen=True)
class SearchParams:
    dt_s: float = 6.0
    dt_col_s: float = 0.1
    max_start_stop: int = 1
    horizon_steps: int = 37  # T_f (thesis table 6.1: 220 s at dt = 6 s)
    alphas: tuple[float, ...] = ALPHAS
    max_paths: int = 16  # roadmap paths tried per arm
    max_states_per_path: int = 4000
    max_states_per_departure: int = 400
    max_states_per_arm: int = 6000

    @property
    def m(self) -> int:
        return max(1, int(round(self.dt_s / self.dt_col_s)))


class _Checker:
    """Collision(q, t) of thesis 6.3.2 for one candidate arm against O^Delta, vectorised per step."""

    def __init__(self, geom: ArmGeom, obst: ObstacleTime, stats: SearchStats) -> None:
        self.geom = geom
        self.obst = obst
        self.stats = stats
        self.m = obst.m
        self.r = geom.radius
        self.pad = float(geom.radius.max()) + obst.buffer_mm
        self.empty = len(obst) == 0
        if not self.empty:
            self.S, self.E, self.R, self.BB = obst.stacked()

    def clear(self, cs: np.ndarray, ce: np.ndarray, sample0: int) -> bool:
        """True when the candidate capsules ``cs``/``ce`` (n, nb, 2) at samples sample0.. are clear.

        ``n`` is 1 (a static configuration, broadcast over the step) or M; the samples lie in
        one step so the per-step bounding boxes of the planned arms prefilter the pairs.
        """
        if self.empty:
            return True
        step = (sample0 + self.m - 1) // self.m if sample0 else 0
        pts_lo = np.minimum(cs.min((0, 1)), ce.min((0, 1))) - self.pad
        pts_hi = np.maximum(cs.max((0, 1)), ce.max((0, 1))) + self.pad
        bb = self.BB[:, step]
        act = np.flatnonzero((bb[:, 0] <= pts_hi[0]) & (bb[:, 2] >= pts_lo[0])
                             & (bb[:, 1] <= pts_hi[1]) & (bb[:, 3] >= pts_lo[1]))
        if len(act) == 0:
            return True
        n = self.m if sample0 else 1
        sl = slice(sample0, sample0 + n)
        os_, oe = self.S[act, sl], self.E[act, sl]  # (A, n, nb, 2)
        self.stats.collision_checks += len(act) * n
        d = clearance_to_arms(cs, ce, self.r, os_, oe, self.R[act])
        return bool(d.min() >= self.obst.buffer_mm)

    def static_unsafe_samples(self, q: np.ndarray, first_sample: int, last_sample: int) -> np.ndarray:
        """Sample indices in [first, last] where the arm parked at ``q`` collides (goal check)."""
        if self.empty or last_sample < first_sample:
            return np.empty(0, dtype=int)
        cs, ce = self.geom.segments(np.array([q[0]]), np.array([q[1]]))
        lo = np.minimum(cs.min((0, 1)), ce.min((0, 1))) - self.pad
        hi = np.maximum(cs.max((0, 1)), ce.max((0, 1))) + self.pad
        bb = self.BB[:, :]
        hit = (bb[..., 0] <= hi[0]) & (bb[..., 2] >= lo[0]) & (bb[..., 1] <= hi[1]) & (bb[..., 3] >= lo[1])
        act = np.flatnonzero(hit.any(1))
        if len(act) == 0:
            return np.empty(0, dtype=int)
        sl = slice(first_sample, last_sample + 1)
        os_, oe = self.S[act, sl], self.E[act, sl]
        self.stats.collision_checks += len(act) * (last_sample + 1 - first_sample)
        d = clearance_to_arms(cs, ce, self.r, os_, oe, self.R[act])
        bad = (d < self.obst.buffer_mm).any(0)
        return first_sample + np.flatnonzero(bad)


@dataclass(frozen=True)
class ArmPlan:
    """Result of planning one arm: its position at every dt step until arrival (T + 1, 2)."""

    arm: int
    q_steps: np.ndarray
    path_index: int
    alpha: float

    @property
    def arrival_step(self) -> int:
        return len(self.q_steps) - 1

    def played_backwards(self, n_steps: int, start_theta2_rad: float) -> np.ndarray:
        """A plan found in reverse time (goal -> start, SDSS-V kaiju) as the forward
        (n_steps + 1, 2) steps: wait at the start until n_steps - T, then retrace the reversed
        path; theta2 shifted by whole turns onto the real start (the reverse search ends at
        the start modulo 2 pi)."""
        q = self.q_steps
        q = np.concatenate([np.repeat(q[-1:], n_steps - (len(q) - 1), axis=0), q[::-1]])
        q[:, 1] += 2.0 * np.pi * np.round((start_theta2_rad - q[0, 1]) / (2.0 * np.pi))
        return q


def plan_arm(geom: ArmGeom, paths: list[RoadmapPath], obst: ObstacleTime, params: SearchParams,
             stats: SearchStats) -> ArmPlan | None:
    """Algorithm 7 (Arm-Motion-Plan): the first safe trajectory along the most promising path.

    (path, alpha) pairs are tried in order of estimated travel time (eq. 6.23 divided by
    alpha); paths needing more way-point stops than ``max_start_stop`` are skipped.
    """
    chk = _Checker(geom, obst, stats)
    goal_q = paths[0].waypoints[-1] if paths else None
    if goal_q is None:
        return None
    # goal conflict check (6.3.4.5): the goal must stay clear until every planned arm is done;
    # it depends only on the goal configuration, so compute the earliest admissible arrival once
    last = obst.last_arrival_step * obst.m
    bad = chk.static_unsafe_samples(goal_q, 0, last)
    goal_ready_sample = int(bad.max()) + 1 if len(bad) else 0
    cands = []
    for i in _path_order(geom, paths, obst, chk, params):
        p = paths[i]
        for a in params.alphas:
            if p.n_edges == 0 and a != params.alphas[0]:
                continue
            cands.append((p.rank_s / a, i, a))
    cands.sort(key=lambda c: (round(c[0], 6), c[1]))
    start_states = stats.states_explored
    for _, i, a in cands:
        if stats.states_explored - start_states > params.max_states_per_arm:
            break
        stats.paths_explored += 1
        q = _search_path(paths[i].waypoints, chk, params, a, goal_ready_sample, stats)
        if q is not None:
            return ArmPlan(geom.arm, q, i, a)
    return None


def _path_order(geom: ArmGeom, paths: list[RoadmapPath], obst: ObstacleTime, chk: _Checker,
                params: SearchParams, n_first: int = 6, n_screen: int = 120, n_samples: int = 16) -> list[int]:
    """Indices of the paths to try: the ``n_first`` most promising (eq. 6.23), then, among the
    next ``n_screen``, those that never touch a planned arm resting at its goal.

    A planned arm stays at its goal for ever, so a path through that goal only works if the
    arm passes before the other arrives; a path that avoids every planned goal cannot be
    blocked for good. Screening (a static check of ``n_samples`` configurations per path)
    lets a detour far down the eq. 6.23 ranking be tried early.
    """
    usable = [i for i, p in enumerate(paths) if p.n_edges - 1 <= params.max_start_stop]
    head, rest = usable[:n_first], usable[n_first:n_first + n_screen]
    if chk.empty or not rest:
        return usable[: params.max_paths]
    # planned arms' final capsules: last sample of each obstacle arm
    S, E, R, _ = obst.stacked()
    fs, fe = S[:, -1], E[:, -1]  # (P, nb, 2)
    s = np.linspace(0.0, 1.0, n_samples)
    clear = []
    for i in rest:
        wp = paths[i].waypoints
        seg = np.repeat(np.arange(len(wp) - 1), n_samples)
        f = np.tile(s, len(wp) - 1)
        q = wp[seg] + f[:, None] * (wp[seg + 1] - wp[seg])
        cs, ce = geom.segments(q[:, 0], q[:, 1])  # (n, nb, 2)
        d = clearance_to_arms(cs, ce, chk.r, fs[:, None], fe[:, None], R)
        if d.min() >= obst.buffer_mm:
            clear.append(i)
    return (head + clear)[: params.max_paths]


def _search_path(wp: np.ndarray, chk: _Checker, params: SearchParams, alpha: float,
                 goal_ready_sample: int, stats: SearchStats) -> np.ndarray | None:
    """Algorithms 8-11 over a whole roadmap path; returns the arm position at every step or None."""
    geom, M = chk.geom, chk.m
    dt = params.dt_s
    # discretise each edge (6.3.4.4): n_e steps at the greatest speed <= alpha v_max
    eq0, eq1, n_e = [], [], []
    for q0, q1 in zip(wp[:-1], wp[1:], strict=True):
        te = float(geom.move_time_s(q0, q1))
        if te <= 1e-12:
            continue
        n = max(1, math.ceil(te / (alpha * dt) - 1e-9))
        eq0.append(q0)
        eq1.append(q1)
        n_e.append(n)
    E = len(n_e)
    T = params.horizon_steps
    if E == 0:  # start == goal: stay, provided the goal is clear throughout
        return wp[:1].copy() if goal_ready_sample == 0 else None
    tail = np.concatenate([np.cumsum(n_e[::-1])[::-1][1:], [0]])  # steps of the later edges
    if sum(n_e) > T:
        return None
    # dense capsules along each edge at dt_col resolution
    segs = []
    for q0, q1, n in zip(eq0, eq1, n_e, strict=True):
        s = np.arange(n * M + 1) / (n * M)
        q = q0 + s[:, None] * (q1 - q0)
        segs.append(geom.segments(q[:, 0], q[:, 1]))
    n_stop = params.max_start_stop
    goal_key = (E - 1, n_e[-1])

    def safe(node: tuple[int, int, int, int, int]) -> bool:
        e, k, _, m, t = node
        S, Ee = segs[e]
        if t == 0:
            i = k * M
            return chk.clear(S[i:i + 1], Ee[i:i + 1], 0)
        if m == 0:
            i = k * M
            cs, ce = S[i:i + 1], Ee[i:i + 1]
            # a static configuration: broadcast one sample over the step's samples
            cs = np.broadcast_to(cs, (M,) + cs.shape[1:])
            ce = np.broadcast_to(ce, (M,) + ce.shape[1:])
        elif m == 1:
            cs, ce = S[(k - 1) * M + 1:k * M + 1], Ee[(k - 1) * M + 1:k * M + 1]
        else:
            cs, ce = S[k * M:(k + 1) * M][::-1], Ee[k * M:(k + 1) * M][::-1]
        return chk.clear(cs, ce, (t - 1) * M + 1)

    # Departure delays are an outer loop (waiting at the start costs no stop): plain DFS tries
    # "wait at the start" last, after exhausting every subtree of the early departures, so a
    # bounded search would rarely reach it. Each departure gets its own share of the budget.
    cache: dict[tuple, bool] = {}
    total = 0
    for d in range(0, T + 1):
        if d + sum(n_e) > T or total >= params.max_states_per_path:
            return None
        if d > 0:
            z0 = (0, 0, 0, 0, d)
            if z0 not in cache:
                stats.states_explored += 1
                total += 1
                cache[z0] = safe(z0)
            if not cache[z0]:
                return None  # the start is hit: the arm cannot wait any longer
        res, used = _dfs((0, 0, 0, 0, d), safe, cache, n_e, tail, T, n_stop, goal_key, goal_ready_sample, M,
                         min(params.max_states_per_departure, params.max_states_per_path - total), stats)
        total += used
        if res is not None:
            return _reconstruct(res[0], res[1], eq0, eq1, n_e, wp[0])
    return None


def _dfs(start, safe, cache, n_e, tail, T, n_stop, goal_key, goal_ready_sample, M, budget, stats):
    """Algorithms 8-11 from ``start``; waiting on at the start (k = 0, m = 0, ns = 0) is excluded
    because the caller tries every departure time."""
    E = len(n_e)
    stack: list[tuple[tuple[int, int, int, int, int], tuple | None]] = [(start, None)]
    parent: dict[tuple, tuple | None] = {}
    explored = 0
    while stack:
        z, par = stack.pop()
        if z in parent:
            continue  # status already SAFE or UNSAFE (Algorithm 9)
        parent[z] = par
        e, k, ns, m, t = z
        if par is not None and par[4] == t:
            ok = True  # way-point transition: same place, same time, already checked
        elif par is None:
            ok = True  # the departure node, checked by the caller
        else:
            ok = cache.get(z)
            if ok is None:
                explored += 1
                stats.states_explored += 1
                ok = cache[z] = safe(z)
        if not ok:
            parent[z] = _UNSAFE
            continue
        if (e, k) == goal_key:
            if t * M >= goal_ready_sample:
                return (z, parent), explored
            continue  # arrived too early: a higher-priority arm still passes the goal
        if explored >= budget:
            return None, explored
        if k == n_e[e] and e < E - 1:
            # intermediate way-point: the MCC2 must stop here (3.5.1.2), one start-stop cycle
            ns2 = ns + (1 if m != 0 else 0)
            if ns2 <= n_stop:
                stack.append(((e + 1, 0, ns2, 0, t), z))
            continue
        if t >= T:
            continue
        # Neighbours (Algorithms 10-11): pushed back, wait, forward -> forward explored first
        for m2 in (-1, 0, 1):
            k2 = k + m2
            if k2 < 0 or k2 > n_e[e]:
                continue
            ns2 = ns + (1 if (m != 0 and m2 != m) else 0)
            if ns2 > n_stop:
                continue
            if m2 == -1 and ns2 >= n_stop:
                continue  # backing up needs another reversal later: a dead end (Neigh-maxNS)
            if t + 1 + (n_e[e] - k2) + tail[e] > T:
                continue  # cannot reach the goal before T_f
            if m2 == 0 and k == 0 and m == 0 and ns == 0 and e == 0:
                continue  # a later departure: the caller's outer loop
            z2 = (e, k2, ns2, m2, t + 1)
            if z2 not in parent:
                stack.append((z2, z))
    return None, explored


_UNSAFE = ("unsafe",)


def _reconstruct(z, parent, eq0, eq1, n_e, q_start) -> np.ndarray:
    chain = []
    while z is not None:
        chain.append(z)
        z = parent[z]
    chain.reverse()
    out: dict[int, np.ndarray] = {}
    for e, k, _, _, t in chain:
        out[t] = eq0[e] + (k / n_e[e]) * (eq1[e] - eq0[e])
    return np.array([out.get(t, q_start) for t in range(max(out) + 1)])


def step_samples(q_steps: np.ndarray, m: int, n_steps: int) -> np.ndarray:
    """Configuration at every dt_col sample up to the horizon from per-step positions."""
    T = len(q_steps) - 1
    out = np.empty((n_steps * m + 1, 2))
    if T > 0:
        f = np.arange(m) / m
        a = q_steps[:-1, None, :] + f[None, :, None] * (q_steps[1:] - q_steps[:-1])[:, None, :]
        out[: T * m] = a.reshape(-1, 2)
    out[T * m:] = q_steps[-1]
    return out
