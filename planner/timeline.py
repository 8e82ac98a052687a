"""A shared time grid of committed arm motions, and the earliest safe departure of a new move.

The search primitive of the sequenced strategy (:mod:`planner.sequenced`). Every arm's
committed motion is a list of straight joint-space moves (both joints linear, arriving
together, thesis eq. 6.23); before its first move an arm rests at its start, after its last
move it rests at the end pose *for ever*. Arms are sampled on one grid of ``dt_s``. Only
*visible* arms (those planned) are obstacles. A new move of arm k from its current end pose
is scheduled at the earliest grid step at which

* every sample of the move keeps the threshold to every visible arm at the same time (the
  move may pass where another arm was, once it has left),
* the end pose keeps it to every visible arm at every later time (the arm rests there until
  it moves again, and every later move of another arm is checked against it), and
* for the arm's first move, the start pose keeps it until the departure.

Because the visible arms' motions were themselves checked against arm k's committed motion
(resting at its current pose for ever), the set stays collision-free as arms are added.

The threshold at a sample is the buffer plus half a step times the speed bounds of both
arms' body points there (:func:`planner.geometry.body_speed_bound_mm_s`, scaled by
``margin``): with ``margin`` 1, two samples a step apart bound the clearance between them
(Lipschitz), so no pose between samples comes below the buffer. The ends of a move are held
to the bare buffer and their neighbours to twice the margin (:func:`margin_speeds`).

Everything hot is in compiled kernels (numba) over the per-step capsule axes, with bounding
boxes per step and per block of steps as pre-filters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from models import clock
from planner.clearance import bodies_clearance
from planner.clearance import box_gap as _box_gap
from planner.geometry import ArmGeom, body_speed_bound_mm_s, edges_in_zoa

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Move:
    """One straight joint-space move of ``arm``: from ``q_from`` to ``q_to`` (theta2
    unwrapped), departing at grid step ``depart_step``, lasting ``duration_s``."""

    arm: int
    q_from: np.ndarray
    q_to: np.ndarray
    depart_step: int
    duration_s: float
    n_steps: int  # grid steps until the arm is at q_to (ceil(duration / dt))


@numba.njit(cache=True)
def _sample_hits(ms, me, mr, mbox, mspd, i, S, E, R, BOX, SPD, REST, vis, arm, m, buf, hdt, memo):
    """Index of a visible arm closer than the threshold to sample ``i`` of the move at step
    ``m``, else -1. The threshold is the buffer plus the distance both arms can close in half a
    step at their speed bounds there (zero for an arm at rest). From step ``REST[j]`` on, arm j
    rests at its final pose for ever: its verdict against sample i is kept in ``memo[i, j]``
    (0 not known, 1 clear, 2 too close)."""
    for j in range(S.shape[0]):
        if j == arm or not vis[j]:
            continue
        rest = m >= REST[j]
        if rest:
            known = memo[i, j]
            if known == 1:
                continue
            if known == 2:
                return j
        thr = buf + hdt * (mspd[i] + SPD[j, m])
        hit = _box_gap(mbox, i, BOX[j], m) < thr and bodies_clearance(ms, me, mr, i, S[j], E[j], R[j], m) < thr
        if rest:
            memo[i, j] = 2 if hit else 1
        if hit:
            return j
    return -1


@numba.njit(cache=True)
def _first_departure(ms, me, mr, mbox, mspd, S, E, R, BOX, SPD, REST, vis, arm, d_lo, d_hi, d_step, buf, hdt,
                     VMAX, STILL, dt):
    """The first step D in range(d_lo, d_hi + 1, d_step) at which every sample i of the move
    clears every other arm at step D + i; -1 when there is none. The sample that failed the
    previous D is tried first (it usually fails the next D too), and the departures at which
    it surely fails again are skipped (:func:`_still_close`)."""
    n1 = ms.shape[0]
    memo = np.zeros((n1, S.shape[0]), np.int8)
    hint = 0
    D = d_lo
    while D <= d_hi:
        j = _sample_hits(ms, me, mr, mbox, mspd, hint, S, E, R, BOX, SPD, REST, vis, arm, D + hint, buf, hdt, memo)
        if j < 0:  # the other samples, outward from the hint (conflicts come in runs)
            for t in range(1, 2 * n1):
                i = hint + (t + 1) // 2 if t % 2 else hint - t // 2
                if i < 0 or i >= n1:
                    continue
                j = _sample_hits(ms, me, mr, mbox, mspd, i, S, E, R, BOX, SPD, REST, vis, arm, D + i, buf, hdt, memo)
                if j >= 0:
                    hint = i
                    break
            if j < 0:
                return D
        skip = _still_close(ms, me, mr, mspd, hint, S, E, R, REST, VMAX, STILL, j, D + hint, buf, hdt, dt)
        if skip < 0:
            return -1
        D += d_step * max(1, -(-skip // d_step))
    return -1


@numba.njit(cache=True)
def _still_close(ms, me, mr, mspd, i, S, E, R, REST, VMAX, STILL, j, m, buf, hdt, dt):
    """Sample i of a move is too close to arm j at step m: the number of steps s such that it
    is surely too close at steps m + 1 .. m + s - 1 too (at least 1), or -1 when for ever (arm j
    rests there from then on). Arm j rests at its pose of step m until step STILL[j, m] (the
    threshold stays the same there: its speed margin is zero), and after that its body points
    move at most VMAX[j] mm/s, so the clearance grows by at most dt * VMAX[j] per step; the
    threshold is at least buf + hdt * mspd[i]."""
    c = bodies_clearance(ms, me, mr, i, S[j], E[j], R[j], m)
    deficit = buf + hdt * mspd[i] - c
    if m >= REST[j] or VMAX[j] <= 0.0:
        return -1 if deficit > 0.0 else 1
    if deficit <= 0.0:
        return 1
    still = STILL[j, m] - m  # arm j rests where it is until step STILL[j, m]
    return max(1, still + int(math.ceil(deficit * (1.0 - 1e-9) / (dt * VMAX[j]))))


SAMPLE_CACHE_BYTES = 64 * 2**20  # sampled moves kept per timeline and its fresh copies
BLOCK = 32  # steps per block of the per-block bounding boxes (rest-pose scans skip whole blocks)


@numba.njit(cache=True)
def _last_conflicts(vs, ve, vr, vbox, S, E, R, BOX, SPD, REST, BBOX, BSPD, vis, arm, buf, hdt, stride):
    """For each pose of ``vs``/``ve`` (one per row, at rest), the last step (of every
    ``stride``-th) at which it comes closer than the threshold to a visible arm; -1 when
    never. An arm at its final rest (from step ``REST[j]``) is checked once; blocks of BLOCK
    steps whose union box (``BBOX``, fastest speed ``BSPD``) is clear of the pose are
    skipped."""
    n_blocks = BBOX.shape[1]
    M = S.shape[1]
    out = np.full(vs.shape[0], -1, np.int64)
    for p in range(vs.shape[0]):
        m_hi = 0  # every arm rests from here on, clear of the pose
        for j in range(S.shape[0]):
            if j == arm or not vis[j]:
                continue
            r = min(max(REST[j], 0), M - 1)
            if _box_gap(vbox, p, BOX[j], r) < buf and bodies_clearance(vs, ve, vr, p, S[j], E[j], R[j], r) < buf:
                out[p] = M - 1
                break
            m_hi = max(m_hi, REST[j])
        if out[p] >= 0:
            continue
        for b in range(min(n_blocks, -(-m_hi // BLOCK)) - 1, -1, -1):
            near = False
            for j in range(S.shape[0]):
                if j != arm and vis[j] and REST[j] > b * BLOCK and _box_gap(vbox, p, BBOX[j], b) < buf + hdt * BSPD[j, b]:
                    near = True
                    break
            if not near:
                continue
            found = -1
            for m in range(min(M, (b + 1) * BLOCK) - 1, b * BLOCK - 1, -stride):
                if m >= m_hi:
                    continue
                for j in range(S.shape[0]):
                    if j == arm or not vis[j] or m >= REST[j]:
                        continue
                    thr = buf + hdt * SPD[j, m]
                    if _box_gap(vbox, p, BOX[j], m) >= thr:
                        continue
                    if bodies_clearance(vs, ve, vr, p, S[j], E[j], R[j], m) < thr:
                        found = m
                        break
                if found >= 0:
                    break
            if found >= 0:
                out[p] = found
                break
    return out


@numba.njit(cache=True)
def _first_conflict(gs, ge, gr, gbox, gspd, S, E, R, BOX, SPD, REST, BBOX, BSPD, vis, arm, buf, hdt):
    """The first step at which pose ``gs``/``ge`` (at rest) comes closer than the threshold to
    a visible arm; the number of steps + 1 when never. Arms at their final rest (from step
    ``REST[j]``) are checked once, and blocks of BLOCK steps in which every moving arm's union
    box is clear of the pose are skipped."""
    A, M = S.shape[0], S.shape[1]
    memo = np.zeros((1, A), np.int8)
    m_hi = 0
    for j in range(A):
        if j != arm and vis[j]:
            m_hi = max(m_hi, min(REST[j], M - 1))
            r = min(REST[j], M - 1)
            thr = buf + hdt * gspd[0]
            hit = _box_gap(gbox, 0, BOX[j], r) < thr and bodies_clearance(gs, ge, gr, 0, S[j], E[j], R[j], r) < thr
            memo[0, j] = 2 if hit else 1
    for b in range(BBOX.shape[1]):
        lo = b * BLOCK
        if lo > m_hi:
            break
        near = False
        for j in range(A):
            if j == arm or not vis[j]:
                continue
            if REST[j] <= lo:
                if memo[0, j] == 2:
                    near = True
                    break
            elif _box_gap(gbox, 0, BBOX[j], b) < buf + hdt * (gspd[0] + BSPD[j, b]):
                near = True
                break
        if not near:
            continue
        for m in range(lo, min(lo + BLOCK, m_hi + 1)):
            if _sample_hits(gs, ge, gr, gbox, gspd, 0, S, E, R, BOX, SPD, REST, vis, arm, m, buf, hdt, memo) >= 0:
                return m
    return M  # from m_hi on every arm rests, and at m_hi it was clear


@numba.njit(cache=True)
def _final_conflicts(ms, me, mr, mbox, mspd, S, E, R, BOX, SPD, REST, vis, arm, buf, hdt, dt):
    """Per other arm, the first sample of the move closer than ``thr`` to that arm's final pose
    (its pose at the last step); -1 when none. Arms clear of the whole move's box are skipped,
    and so are samples that a clear sample certifies: the move's poses are ``dt`` apart in
    time and its body points move at most ``max(mspd)`` mm/s (conservative advancement)."""
    A = S.shape[0]
    m = S.shape[1] - 1
    out = np.full(A, -1, np.int64)
    ub = np.empty((1, 4))
    ub[0, 0], ub[0, 1] = mbox[:, 0].min(), mbox[:, 1].min()
    ub[0, 2], ub[0, 3] = mbox[:, 2].max(), mbox[:, 3].max()
    top = buf + hdt * mspd.max()
    step_mm = dt * mspd.max()
    n1 = ms.shape[0]
    for j in range(A):
        if j == arm or not vis[j] or _box_gap(ub, 0, BOX[j], m) >= top:
            continue
        i = 0
        while i < n1:
            thr = buf + hdt * mspd[i]
            c = _box_gap(mbox, i, BOX[j], m)
            if c < thr:
                c = bodies_clearance(ms, me, mr, i, S[j], E[j], R[j], m)
                if c < thr:
                    out[j] = i
                    break
            i += 1
            if step_mm > 0.0 and c > top:
                i += int((c - top) / step_mm)  # those samples keep at least ``top``
    return out


@numba.njit(cache=True)
def _boxes(s, e, r):
    n, nb = s.shape[0], s.shape[1]
    out = np.empty((n, 4))
    for i in range(n):
        x0 = y0 = np.inf
        x1 = y1 = -np.inf
        for b in range(nb):
            x0 = min(x0, s[i, b, 0] - r[b], e[i, b, 0] - r[b])
            y0 = min(y0, s[i, b, 1] - r[b], e[i, b, 1] - r[b])
            x1 = max(x1, s[i, b, 0] + r[b], e[i, b, 0] + r[b])
            y1 = max(y1, s[i, b, 1] + r[b], e[i, b, 1] + r[b])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x0, y0, x1, y1
    return out


@numba.njit(cache=True)
def _block_boxes(box, spd, b0, bbox, bspd):
    """Union boxes and fastest speeds of each block of BLOCK steps of one arm's rows, from
    block ``b0`` on (written into ``bbox``, ``bspd``)."""
    M = box.shape[0]
    for b in range(b0, bbox.shape[0]):
        lo, hi = b * BLOCK, min((b + 1) * BLOCK, M)
        x0, y0, x1, y1, v = np.inf, np.inf, -np.inf, -np.inf, 0.0
        for m in range(lo, hi):
            x0, y0 = min(x0, box[m, 0]), min(y0, box[m, 1])
            x1, y1 = max(x1, box[m, 2]), max(y1, box[m, 3])
            v = max(v, spd[m])
        bbox[b, 0], bbox[b, 1], bbox[b, 2], bbox[b, 3] = x0, y0, x1, y1
        bspd[b] = v


def boxes(s: np.ndarray, e: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(n, 4) bounding boxes (xmin, ymin, xmax, ymax) of capsules ``s``/``e`` (n, nb, 2)."""
    return _boxes(np.ascontiguousarray(s, dtype=float), np.ascontiguousarray(e, dtype=float),
                  np.ascontiguousarray(radius, dtype=float))


@dataclass(frozen=True)
class MoveSamples:
    """A move's poses at every grid step from its departure until it is at ``q_to``, and the
    speed of its body points at each for the clearance threshold (:func:`margin_speeds` of
    :func:`planner.geometry.body_speed_bound_mm_s`)."""

    q_from: np.ndarray
    q_to: np.ndarray
    duration_s: float
    s: np.ndarray  # (n + 1, nb, 2) capsule axis starts
    e: np.ndarray
    box: np.ndarray  # (n + 1, 4)
    speed: np.ndarray  # (n + 1,) mm/s

    @property
    def n_steps(self) -> int:
        return len(self.s) - 1

    def end(self) -> tuple[np.ndarray, ...]:
        """The last sample alone, at rest (speed 0)."""
        return self.s[-1:], self.e[-1:], self.box[-1:], np.zeros(1)

    def begin(self) -> tuple[np.ndarray, ...]:
        """The first sample alone, at rest."""
        return self.s[:1], self.e[:1], self.box[:1], np.zeros(1)


def still_until(spd: np.ndarray) -> np.ndarray:
    """For each step m, the last step of the run of zero speed margins that contains m (m
    itself when the arm moves there): an arm is at the same pose throughout such a run, since
    a move's margins are zero only at its two ends (:func:`margin_speeds`)."""
    n = len(spd)
    idx = np.arange(n)
    first_moving = np.minimum.accumulate(np.where(spd > 0, idx, n)[::-1])[::-1]
    return np.where(spd > 0, idx, first_moving - 1)


def margin_speeds(n: int, speed_mm_s: float) -> np.ndarray:
    """Per-sample speeds of a move of ``n`` steps for the clearance threshold (buffer + half a
    step times the speeds of both arms at that sample).

    Two samples a step apart bound the clearance between them when their margins add up to a
    step at the speed of the interval (Lipschitz); so the ends of a move, where an arm meets a
    tight start or goal configuration, are held to the bare buffer and their neighbours to
    twice the margin: [0, 2v, v, ..., v, 2v, 0] (one step: [2v, 0])."""
    m = np.full(n + 1, float(speed_mm_s))
    if n == 0:
        return np.zeros(1)
    if n == 1:
        return np.array([2.0 * speed_mm_s, 0.0])
    m[0] = m[-1] = 0.0
    m[1] = m[-2] = 2.0 * speed_mm_s
    return m


class SampleCache:
    """Sampled moves by (arm, from, to), up to ``max_bytes`` of arrays (then emptied)."""

    def __init__(self, max_bytes: int = SAMPLE_CACHE_BYTES) -> None:
        self.max_bytes = int(max_bytes)
        self.n_bytes = 0
        self._moves: dict[tuple, MoveSamples | None] = {}

    def get(self, key: tuple) -> tuple[bool, MoveSamples | None]:
        if key in self._moves:
            return True, self._moves[key]
        return False, None

    def put(self, key: tuple, ms: MoveSamples | None) -> None:
        size = 0 if ms is None else ms.s.nbytes + ms.e.nbytes + ms.box.nbytes + ms.speed.nbytes
        if self.n_bytes + size > self.max_bytes:
            self._moves.clear()
            self.n_bytes = 0
        self._moves[key] = ms
        self.n_bytes += size


class Timeline:
    """Committed moves of every arm on a grid of ``dt_s`` up to ``horizon_s`` (module docstring).

    ``max_moves`` per arm is ``max_start_stop + 1`` (a rest between two moves is one stop).
    ``margin`` scales the Lipschitz margin of the threshold: 1 makes every plan safe between
    samples; 0 checks the bare buffer at the samples (the 0.1 s grid then misses at most
    fractions of a millimetre, which the caller's exact re-check catches). Arms not yet planned are invisible (prioritized planning); the first move of such an arm
    also checks its rest at the start against the visible arms.
    """

    def __init__(self, geoms: tuple[ArmGeom, ...], start_q: np.ndarray, *, horizon_s: float, dt_s: float,
                 buffer_mm: float, max_moves: int, margin: float = 1.0) -> None:
        self.geoms = geoms
        self.dt_s = float(dt_s)
        self.n_steps = int(math.ceil(horizon_s / dt_s - 1e-9))
        self.times_s = np.arange(self.n_steps + 1) * self.dt_s
        self.buffer_mm = float(buffer_mm)
        self.half_step_margin_s = 0.5 * self.dt_s * float(margin)
        self.max_moves = int(max_moves)
        self.start_q = np.array(start_q, float)
        n = len(geoms)
        nb = len(geoms[0].radius)
        if any(len(g.radius) != nb for g in geoms):
            raise ValueError("every arm needs the same number of bodies")
        self.R = np.ascontiguousarray(np.stack([g.radius for g in geoms]), dtype=float)
        self.S = np.empty((n, self.n_steps + 1, nb, 2))
        self.E = np.empty_like(self.S)
        self.BOX = np.empty((n, self.n_steps + 1, 4))
        self.SPD = np.zeros((n, self.n_steps + 1))
        self.REST = np.zeros(n, np.int64)  # the step from which each arm rests at its end pose
        self.VMAX = np.zeros(n)  # each arm's fastest body-point speed bound over its moves (mm/s)
        self.STILL = np.tile(np.arange(self.n_steps + 1), (n, 1))  # last step of the rest at each step
        n_blocks = -(-(self.n_steps + 1) // BLOCK)
        self.BBOX = np.empty((n, n_blocks, 4))
        self.BSPD = np.zeros((n, n_blocks))
        self.moves: list[list[Move]] = [[] for _ in range(n)]
        self.visible = np.zeros(n, dtype=np.bool_)
        self.sample_cache = SampleCache()
        for k in range(n):
            self._set_row(k)
        self.keep_rest_state()

    def fresh(self) -> Timeline:
        """A copy of this timeline with every arm back at its start (nothing planned)."""
        t = object.__new__(Timeline)
        t.__dict__.update(self.__dict__)
        t.moves = [[] for _ in self.moves]
        t.visible = np.zeros_like(self.visible)
        for name in ("S", "E", "BOX", "SPD", "BBOX", "BSPD", "REST", "VMAX", "STILL"):
            setattr(t, name, getattr(self, "_rest_" + name).copy())
        return t

    def keep_rest_state(self) -> None:
        """Remember the current rows as the state :meth:`fresh` returns to."""
        for name in ("S", "E", "BOX", "SPD", "BBOX", "BSPD", "REST", "VMAX", "STILL"):
            setattr(self, "_rest_" + name, getattr(self, name).copy())

    # ------------------------------------------------------------------ state

    def pose(self, k: int) -> np.ndarray:
        """Arm k's current end pose (theta2 unwrapped)."""
        return self.moves[k][-1].q_to if self.moves[k] else self.start_q[k]

    def free_step(self, k: int) -> int:
        """The first step at which arm k may depart again (its last arrival)."""
        if not self.moves[k]:
            return 0
        m = self.moves[k][-1]
        return m.depart_step + m.n_steps

    def moves_left(self, k: int) -> int:
        return self.max_moves - len(self.moves[k])

    def arrival_s(self, k: int) -> float:
        if not self.moves[k]:
            return 0.0
        m = self.moves[k][-1]
        return m.depart_step * self.dt_s + m.duration_s

    def makespan_s(self) -> float:
        return max((self.arrival_s(k) for k in range(len(self.geoms))), default=0.0)

    def waypoints(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Arm k's timed way-points (t from 0, (theta1, theta2))."""
        t, q = [0.0], [self.start_q[k]]
        for mv in self.moves[k]:
            t0 = mv.depart_step * self.dt_s
            if t0 > t[-1] + 1e-12:
                t.append(t0)
                q.append(mv.q_from)
            t.append(t0 + mv.duration_s)
            q.append(mv.q_to)
        return np.array(t), np.array(q, float)

    def _set_row(self, k: int, from_step: int = 0) -> None:
        """Recomputes arm k's samples from ``from_step`` on (they did not change before it)."""
        t, q = self.waypoints(k)
        g = self.geoms[k]
        a = max(0, int(from_step))
        end = max(a, min(self.free_step(k), self.n_steps + 1))  # at rest at q[-1] from here on
        if end > a:
            ts = self.times_s[a:end]
            s, e = g.segments(np.interp(ts, t, q[:, 0]), np.interp(ts, t, q[:, 1]))
            self.S[k, a:end], self.E[k, a:end] = s, e
            self.BOX[k, a:end] = boxes(s, e, g.radius)
        s, e = g.segments(q[-1:, 0], q[-1:, 1])
        self.S[k, end:], self.E[k, end:] = s, e
        self.BOX[k, end:] = boxes(s, e, g.radius)
        spd = np.zeros(self.n_steps + 1)
        for mv in self.moves[k]:
            lo = mv.depart_step
            m = margin_speeds(mv.n_steps, self._speed(k, mv.q_from, mv.q_to, mv.duration_s))
            hi = min(lo + len(m), self.n_steps + 1)
            spd[lo:hi] = np.maximum(spd[lo:hi], m[:hi - lo])
        self.SPD[k] = spd
        self.VMAX[k] = spd.max()
        self.STILL[k] = still_until(spd)
        self.REST[k] = self.free_step(k)
        _block_boxes(self.BOX[k], spd, a // BLOCK, self.BBOX[k], self.BSPD[k])  # blocks before a's unchanged

    def _speed(self, k: int, a: np.ndarray, b: np.ndarray, duration_s: float) -> float:
        if duration_s <= 0:
            return 0.0
        w = np.abs(np.asarray(b, float) - np.asarray(a, float)) / duration_s
        return float(body_speed_bound_mm_s(self.geoms[k], w[0], w[1]))

    # ------------------------------------------------------------------ moves

    def samples(self, k: int, q_to: np.ndarray, q_from: np.ndarray | None = None) -> MoveSamples | None:
        """Arm k's straight move from ``q_from`` (default: its current pose) to ``q_to`` (theta2
        unwrapped) sampled on the grid; None when it crosses the ZoA or a joint limit.

        Moves are kept (:class:`SampleCache`, shared by every :meth:`fresh` copy): a search
        tries the same moves from the same poses attempt after attempt."""
        a = self.pose(k) if q_from is None else np.asarray(q_from, float)
        b = np.asarray(q_to, float)
        key = (k, float(a[0]), float(a[1]), float(b[0]), float(b[1]))
        found, ms = self.sample_cache.get(key)
        if not found:
            ms = self._sample(k, a, b)
            self.sample_cache.put(key, ms)
        return ms

    def _sample(self, k: int, a: np.ndarray, b: np.ndarray) -> MoveSamples | None:
        g = self.geoms[k]
        if edges_in_zoa(g, a[None], b[None])[0]:
            return None
        T = float(g.move_time_s(a, b))
        n = int(math.ceil(T / self.dt_s - 1e-9))
        clock.work("move_samples", n + 1)
        f = np.minimum(np.arange(n + 1) * self.dt_s / T, 1.0) if T > 0 else np.ones(1)
        q = a + (b - a) * f[:, None]
        s, e = g.segments(q[:, 0], q[:, 1])
        speed = margin_speeds(n, self._speed(k, a, b, T))
        return MoveSamples(a, b, T, np.ascontiguousarray(s), np.ascontiguousarray(e), boxes(s, e, g.radius), speed)

    def _world(self, k: int) -> tuple:
        return (self.S, self.E, self.R, self.BOX, self.SPD, self.REST, self.visible, k, self.buffer_mm,
                self.half_step_margin_s)

    def earliest_departure(self, k: int, ms: MoveSamples, min_step: int = 0) -> tuple[int, set[int]]:
        """The earliest grid step at which arm k can make move ``ms`` (module docstring), -1
        when no step within the horizon works; and the visible arms whose final pose is in
        the way of the move (it must pass before they get there). ``min_step``: the earliest
        departure allowed."""
        n = ms.n_steps
        clock.work("departure", n)
        w = self._world(k)
        r = self.R[k]
        first = _final_conflicts(ms.s, ms.e, r, ms.box, ms.speed, *w, self.dt_s)
        blockers = {int(j) for j in np.flatnonzero(first >= 0)}
        d_hi = self.n_steps - n
        for j in blockers:  # sample i must pass before arm j settles in its final pose
            d_hi = min(d_hi, self.free_step(j) - int(first[j]) - 1)
        if not self.visible[k]:  # its rest at the start is not checked yet: it must leave in time
            s0, e0, b0, v0 = ms.begin()
            d_hi = min(d_hi, _first_conflict(s0, e0, r, b0, v0, *w[:6], self.BBOX, self.BSPD, *w[6:]) - 1)
        s1, e1, b1, _ = ms.end()
        last = int(_last_conflicts(s1, e1, r, b1, *w[:6], self.BBOX, self.BSPD, *w[6:], 1)[0])
        d_lo = max(self.free_step(k), last - n + 1, int(min_step), 0)
        if last >= self.n_steps or d_lo > d_hi:
            return -1, blockers
        d = _first_departure(ms.s, ms.e, r, ms.box, ms.speed, *w[:8], d_lo, d_hi, 1, *w[8:], self.VMAX,
                             self.STILL, self.dt_s)
        return int(d), blockers

    def free_after(self, k: int, q: np.ndarray, stride: int = 1) -> np.ndarray:
        """For each pose of ``q`` (n, 2), the last step (of every ``stride``-th in each block of
        BLOCK steps, the block's last included) at which arm k resting there would come too
        close to a visible arm (-1: never; the last step: for ever)."""
        g = self.geoms[k]
        clock.work("free_after", len(q))
        s, e = g.segments(q[:, 0], q[:, 1])
        s, e = np.ascontiguousarray(s), np.ascontiguousarray(e)
        w = self._world(k)
        return _last_conflicts(s, e, self.R[k], boxes(s, e, g.radius), *w[:6], self.BBOX, self.BSPD, *w[6:],
                               int(stride))

    def commit(self, k: int, ms: MoveSamples, depart_step: int) -> Move | None:
        """Arm k makes move ``ms`` at ``depart_step`` (found by :meth:`earliest_departure`); it is
        visible to every later move from then on. A move of zero length only makes it visible
        (resting where it is), and does not count as a move."""
        self.visible[k] = True
        if ms.duration_s <= 0:
            return None
        mv = Move(k, ms.q_from, ms.q_to, int(depart_step), ms.duration_s, ms.n_steps)
        self.moves[k].append(mv)
        self._set_row(k, mv.depart_step)
        return mv

    def restore(self, k: int, moves: tuple[Move, ...]) -> None:
        """Arm k (at rest at its start, nothing planned) makes ``moves``, committed before in a
        timeline of the same start; it is visible."""
        self.moves[k] = list(moves)
        self.visible[k] = True
        if moves:
            self._set_row(k, moves[0].depart_step)

    def undo(self, k: int) -> None:
        """Takes back arm k's last move (invisible again when it was its first)."""
        mv = self.moves[k].pop()
        self.visible[k] = bool(self.moves[k])
        self._set_row(k, mv.depart_step)


def compile_kernels() -> None:
    """Compile (or load from the on-disk cache) this module's kernels."""
    z = np.zeros((1, 1, 2))
    r = np.zeros(1)
    b = np.zeros((1, 4))
    S, E, B, R, P = z[None], z[None], b[None], r[None], r[None]
    v = np.ones(1, np.bool_)
    rest = np.zeros(1, np.int64)
    _first_departure(z, z, r, b, r, S, E, R, B, P, rest, v, 0, 0, 0, 1, 0.0, 0.0, r, rest[None], 1.0)
    _first_conflict(z, z, r, b, r, S, E, R, B, P, rest, B, P, v, 0, 0.0, 0.0)
    _last_conflicts(z, z, r, b, S, E, R, B, P, rest, B, P, v, 0, 0.0, 0.0, 1)
    _final_conflicts(z, z, r, b, r, S, E, R, B, P, rest, v, 0, 0.0, 0.0, 1.0)
    _boxes(z, z, r)
    _block_boxes(b, r, 0, b.copy(), r.copy())
