"""Reachability and the incompatibility matrix (thesis 5.4).

For a set of FOV targets, every *assignment* (arm, target, IK branch) plus each arm's
park location (and optionally its current location, or a fixed location for an arm out
of service); then every incompatible pair: two assignments of different arms whose bodies
are closer than the collision buffer, or two arms on the same target. Both allocators
consume this structure; nothing downstream calls geometry again.

The bulk pair test is vectorised (capsule fast path of :mod:`models.collision`) with a
static broad phase (body pairs that can never meet, whatever the configuration, are
skipped per arm pair) and a per-pair bounding-box prefilter; FCL is the oracle in tests.

The work done is reported to the effort clock as ``clock.work("incompatibility_*", units)``;
what it costs is the allocator's to say (:data:`solvers.effort.INCOMPATIBILITY_WORK_S`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from models import clock
from models.budget import Budget
from models.collision import (
    arm_pair_clearance_mm,
    body_segments_mm,
    segment_distance_mm,
    segment_distance_xy,
)
from models.errors import StructureTooLarge, TimeLimitExceeded
from models.instrument import Instrument
from models.kinematics import inverse_fov_every_arm, positive_turn_move_time_s, tip_fov
from models.locks import allowed_columns

TIE_MM = 1e-6  # clearances within this of the buffer count as collisions in the structure
FLOAT32_BAND_MM = 0.05  # float32 segment distances are good to ~1e-4 mm at FOV scale
PARK = -1  # target index of a park assignment
FIXED = -2  # target index of a current/fixed (out-of-service) location
BLANK = -3  # target index of a blank-sky location (thesis Algorithm 5 padding)
MAX_PAIRS = 60_000_000  # ~1 GB of structure (17 bytes a pair), ~1.9 GB with the allocator: refused beyond


@dataclass(frozen=True)
class Assignments:
    """All candidate locations of every arm, as parallel arrays of length n_assignments.

    ``target`` is the target index, ``PARK`` (-1), ``FIXED`` (-2) or ``BLANK`` (-3). Sorted by arm, then
    target; ``arm_start[k]:arm_start[k+1]`` slices the assignments of arm k.
    """

    arm: np.ndarray
    target: np.ndarray
    branch: np.ndarray
    theta1_rad: np.ndarray
    theta2_rad: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    arm_start: np.ndarray

    def __len__(self) -> int:
        return len(self.arm)

    @property
    def q(self) -> np.ndarray:
        return np.column_stack([self.theta1_rad, self.theta2_rad])

    def of_arm(self, arm: int) -> slice:
        return slice(int(self.arm_start[arm]), int(self.arm_start[arm + 1]))


@dataclass(frozen=True)
class Reachability:
    """Which arms reach which targets."""

    n_targets: int
    arms_per_target: np.ndarray  # (n_targets,) number of distinct enabled arms reaching it
    assignments: Assignments
    # (n_targets,) bool: reached by some enabled arm, but only farther from park than the
    # park move limit (:func:`build_assignments`); None: no limit was set
    beyond_park_move_limit: np.ndarray | None = None

    @property
    def unreachable(self) -> np.ndarray:
        """Indices of targets no enabled arm can reach (within the park move limit, if set)."""
        return np.flatnonzero(self.arms_per_target == 0)

    @property
    def beyond_limit(self) -> np.ndarray:
        """Indices of the unreachable targets that an arm reaches beyond the park move limit."""
        if self.beyond_park_move_limit is None:
            return np.zeros(0, np.int64)
        return np.flatnonzero(self.beyond_park_move_limit)


@dataclass(frozen=True)
class Incompatibility:
    """Incompatible assignment pairs (i < j), also as a symmetric CSR adjacency.

    ``same_target[p]`` marks pairs incompatible only because both arms take the same target.
    """

    reachability: Reachability
    pairs: np.ndarray  # (n_pairs, 2) int32, i < j
    same_target: np.ndarray  # (n_pairs,) bool
    indptr: np.ndarray
    indices: np.ndarray
    buffer_mm: float
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def assignments(self) -> Assignments:
        return self.reachability.assignments

    def neighbours(self, a: int) -> np.ndarray:
        """All assignments incompatible with assignment ``a``."""
        return self.indices[self.indptr[a]:self.indptr[a + 1]]

    def conflicts(self, a: int, arm: int) -> np.ndarray:
        """Assignments of ``arm`` incompatible with assignment ``a`` (thesis eq. 5.15, aggregated)."""
        nb = self.neighbours(a)
        return nb[self.assignments.arm[nb] == arm]

    def compatible(self, a: int, b: int) -> bool:
        nb = self.neighbours(a)
        i = np.searchsorted(nb, b)
        return not (i < len(nb) and nb[i] == b)

    def counts(self) -> dict[str, int]:
        return {
            "targets": int(self.reachability.n_targets),
            "assignments": int(len(self.assignments)),
            "incompatible_pairs": int(len(self.pairs)),
            "geometric_pairs": int((~self.same_target).sum()),
            "same_target_pairs": int(self.same_target.sum()),
            "unreachable_targets": int(len(self.reachability.unreachable)),
        }


def build_assignments(
    instrument: Instrument,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    *,
    include_park: bool = True,
    current: np.ndarray | None = None,
    fixed: dict[int, tuple[float, float]] | None = None,
    blank_per_arm: int = 0,
    seed: int = 0,
    park_move_limit_s: float | None = None,
    locks: Mapping[int, tuple[int, int | None]] | None = None,
    excluded: Sequence[int] | np.ndarray | None = None,
) -> Reachability:
    """Every (arm, target, IK branch) assignment plus park/current locations (thesis 5.4).

    ``locks`` (target index -> (arm, IK branch or None)) keep only that arm's (branch's) columns
    of a target; ``excluded`` target indices keep none (:mod:`models.locks`).

    ``park_move_limit_s``: keep only the target and blank-sky locations an arm reaches from
    park within that time, turning theta2 the positive way
    (:func:`~models.kinematics.positive_turn_move_time_s`), the only way an arm leaves park
    without sweeping its neighbour. With the thesis' configuration time T_p = 120 s (6.3.1),
    every move from park to a configuration of such locations is then at most T_p long. A
    target reached only farther away is marked in ``beyond_park_move_limit``.

    ``blank_per_arm``: that many blank-sky locations per arm, sampled (with ``seed``) in the
    free area the arm covers near its own base, in front of its park position — the
    thesis' padding of idle arms with blank sky (Algorithm 5). They enter the
    incompatibility structure like any location, so allocators need no geometry calls.

    ``current``: optional (n_arms, 2) joint angles added as an extra location per arm (when
    it differs from park). ``fixed``: arm -> (theta1, theta2) for arms out of service; such
    an arm gets that single location and no targets. Disabled arms in the instrument
    without a fixed location stay parked.
    """
    x = np.asarray(x_mm, float).ravel()
    y = np.asarray(y_mm, float).ravel()
    n_t = len(x)
    fixed = dict(fixed or {})
    for k, a in enumerate(instrument.arms):
        if not a.enabled and k not in fixed:
            fixed[k] = a.park
    arms = np.arange(instrument.n_arms)
    active = np.array([k not in fixed for k in arms])
    beyond = None
    if n_t:
        sol = inverse_fov_every_arm(instrument, x, y)  # (n_arms, n_t, 4)
        valid = sol.valid & active[:, None, None] & allowed_columns(instrument.n_arms, n_t, locks, excluded)
        if park_move_limit_s is not None:
            reached = valid.any(axis=(0, 2))
            q = np.stack([sol.theta1_rad, sol.theta2_rad], axis=-1)
            valid &= within_park_move_limit(instrument, arms[:, None, None], q, park_move_limit_s)
            beyond = reached & ~valid.any(axis=(0, 2))
        k_idx, t_idx, b_idx = np.nonzero(valid)
        t1 = sol.theta1_rad[valid]
        t2 = sol.theta2_rad[valid]
    else:
        valid = np.zeros((instrument.n_arms, 0, 4), bool)
        k_idx = t_idx = b_idx = np.zeros(0, int)
        t1 = t2 = np.zeros(0)
    ex_k, ex_t, ex_q = [], [], []
    park = instrument.park_configuration
    for k in arms:
        if k in fixed:
            ex_k.append(k)
            ex_t.append(FIXED)
            ex_q.append(fixed[k])
            continue
        if include_park:
            ex_k.append(k)
            ex_t.append(PARK)
            ex_q.append(park[k])
        if current is not None:
            c = np.asarray(current[k], float)
            if not include_park or not np.allclose(c, park[k]):
                ex_k.append(k)
                ex_t.append(FIXED)
                ex_q.append(c)
        if blank_per_arm:
            blanks = sample_blank_sky(instrument, int(k), blank_per_arm, seed)
            for q in blanks[within_park_move_limit(instrument, k, blanks, park_move_limit_s)]:
                ex_k.append(k)
                ex_t.append(BLANK)
                ex_q.append(q)
    ex_q = np.asarray(ex_q, float).reshape(-1, 2)
    arm = np.concatenate([k_idx, np.asarray(ex_k, int)])
    target = np.concatenate([t_idx, np.asarray(ex_t, int)])
    branch = np.concatenate([b_idx, np.full(len(ex_k), -1)])
    th1 = np.concatenate([t1, ex_q[:, 0]])
    th2 = np.concatenate([t2, ex_q[:, 1]])
    order = np.lexsort((branch, target, arm))
    arm, target, branch, th1, th2 = arm[order], target[order], branch[order], th1[order], th2[order]
    tip = tip_fov(instrument, arm, th1, th2) if len(arm) else np.zeros((0, 2))
    arm_start = np.searchsorted(arm, np.arange(instrument.n_arms + 1))
    assignments = Assignments(arm.astype(np.int32), target.astype(np.int32), branch.astype(np.int8),
                              th1, th2, tip[:, 0], tip[:, 1], arm_start)
    arms_per_target = valid.any(axis=2).sum(axis=0) if n_t else np.zeros(0, int)
    return Reachability(n_t, arms_per_target, assignments, beyond)


def within_park_move_limit(instrument: Instrument, arm, q: np.ndarray, limit_s: float | None) -> np.ndarray:
    """Which joint angles ``q`` (..., 2) of ``arm`` (an index, or indices broadcasting
    against ``q[..., 0]``) an arm reaches from its park within ``limit_s`` turning theta2
    the positive way (None: all)."""
    q = np.asarray(q, float)
    if limit_s is None:
        return np.ones(q.shape[:-1], bool)
    park = instrument.park_configuration[arm]
    v1 = instrument.arm_array("joint1_speed_rad_s")[arm]
    v2 = instrument.arm_array("joint2_speed_rad_s")[arm]
    return positive_turn_move_time_s(park, q, v1, v2) <= limit_s


def sample_blank_sky(instrument: Instrument, arm: int, n: int, seed: int = 0) -> np.ndarray:
    """``n`` feasible, retracted configurations of ``arm`` for blank-sky exposures (thesis
    Algorithm 5 padding), out of the crowded FOV centre.

    Every pose leaves all other arms' park positions free. Half of them lie just in front
    of the park position (tip in the outer FOV ring between
    the neighbours: the poses least likely to block anybody); the other half are spread
    out, sideways poses included, by farthest-point selection on the tip position. The
    spread matters: a rim target right in front of an arm's park is reachable only by its
    neighbours, and the arm then needs a pose that is not in front of its park.
    Deterministic for a given seed.
    """
    from models.kinematics import Links, in_zoa

    if n <= 0:
        return np.zeros((0, 2))
    clock.work("incompatibility_blank", n)
    rng = np.random.default_rng([seed, arm])
    links = Links.of(instrument, arm)
    a = instrument.arms[arm]
    r_fov = instrument.fov_radius_mm
    m = 64 * n
    t1 = rng.uniform(max(a.theta1_min_rad, a.park_theta1_rad - 1.2), a.park_theta1_rad, m)
    t2 = a.park_theta2_rad + rng.uniform(-np.pi, np.pi, m)
    tip = tip_fov(instrument, arm, t1, t2)
    r = np.hypot(tip[:, 0], tip[:, 1])
    ok = ~in_zoa(t1, t2, links) & (r > 0.6 * r_fov) & (r < 1.3 * r_fov)
    # a blank pose must leave every other arm's park free, or resting would cascade
    park = instrument.park_configuration
    cand = np.flatnonzero(ok)
    for other in range(instrument.n_arms):
        if other != arm and len(cand):
            c = arm_pair_clearance_mm(instrument, arm, np.column_stack([t1[cand], t2[cand]]), other, park[other])
            cand = cand[c >= instrument.collision_buffer_mm + TIE_MM]
    ok = np.zeros_like(ok)
    ok[cand] = True
    front = ok & (t1 > a.park_theta1_rad - 0.6) & (np.abs(t2 - a.park_theta2_rad) < 0.8) & (r < r_fov)
    q = np.column_stack([t1, t2])
    n_front = min(int(front.sum()), (n + 1) // 2)
    chosen = list(np.flatnonzero(front)[:n_front])
    pool = np.flatnonzero(ok & ~front)
    if len(pool):
        d = np.full(len(pool), np.inf)
        for c in chosen:
            d = np.minimum(d, np.hypot(*(tip[pool] - tip[c]).T))
        for _ in range(min(n - len(chosen), len(pool))):
            nxt = int(np.argmax(d)) if chosen else 0
            chosen.append(int(pool[nxt]))
            d = np.minimum(d, np.hypot(*(tip[pool] - tip[pool[nxt]]).T))
    return q[np.asarray(chosen, dtype=int)]


def _joint_bounds(instrument: Instrument, k: int) -> dict[str, tuple[np.ndarray, float]]:
    """For each joint of arm k, a disc (centre, radius) holding it in every configuration."""
    a = instrument.arms[k]
    base = np.array([a.base_x_mm, a.base_y_mm])
    ex = np.array([np.cos(a.orientation_rad), np.sin(a.orientation_rad)])
    j2 = base + a.d12_mm * ex
    return {"J1": (base, 0.0), "J2": (j2, 0.0), "J3": (base, a.d13_mm), "J4": (j2, a.d24_mm),
            "tip": (base, a.d13_mm + a.d3tip_mm)}


@lru_cache(maxsize=4096)
def _body_pairs_that_can_meet(instrument: Instrument, k: int, kk: int, buffer_mm: float) -> list[tuple[int, int]]:
    """Body pairs of arms k, kk whose swept regions come within the buffer (static broad phase).

    Each body lies in the convex hull of its two joints' bounding discs, i.e. within a
    capsule of radius max(r1, r2) + half-width between the disc centres.
    """
    jb, jbb = _joint_bounds(instrument, k), _joint_bounds(instrument, kk)
    out = []
    for i, b in enumerate(instrument.arms[k].bodies):
        (c0, r0), (c1, r1) = jb[b.joint_from], jb[b.joint_to]
        for j, bb in enumerate(instrument.arms[kk].bodies):
            (d0, s0), (d1, s1) = jbb[bb.joint_from], jbb[bb.joint_to]
            dist = float(segment_distance_mm(c0, c1, d0, d1))
            reach = max(r0, r1) + b.half_width_mm + max(s0, s1) + bb.half_width_mm
            if dist - reach < buffer_mm:
                out.append((i, j))
    # most conflicts are between the long bodies that reach into the FOV: test those
    # first so later body pairs only see the still-undecided assignment pairs
    out.sort(key=lambda ij: -(instrument.arms[k].bodies[ij[0]].joint_to == "tip")
             - (instrument.arms[kk].bodies[ij[1]].joint_to == "tip"))
    return out


@lru_cache(maxsize=4096)
def _capsules(instrument: Instrument, k: int, buffer_mm: float,
              ) -> tuple[tuple[int, tuple[tuple[int, int], ...], np.ndarray, np.ndarray, np.ndarray], ...]:
    """Per body ``bi`` of arm k: the bodies (arm kk, body bj) of the other arms it can meet
    (:func:`_body_pairs_that_can_meet`) and the capsules they sweep, as arrays: the centres of
    their joints' bounding discs ``c0``, ``c1`` (m, 2) and the capsules' radii ``reach`` (m,).
    They depend on the instrument alone, so every structure build shares them."""
    caps: dict[int, list[tuple[int, int, np.ndarray, np.ndarray, float]]] = {}
    for kk in range(instrument.n_arms):
        if kk == k:
            continue
        lo_k, hi_k = min(k, kk), max(k, kk)
        jb = _joint_bounds(instrument, kk)
        for p in _body_pairs_that_can_meet(instrument, lo_k, hi_k, buffer_mm):
            bi, bj = (p[0], p[1]) if k == lo_k else (p[1], p[0])
            body = instrument.arms[kk].bodies[bj]
            (c0, r0), (c1, r1) = jb[body.joint_from], jb[body.joint_to]
            caps.setdefault(bi, []).append((kk, bj, c0, c1, max(r0, r1) + body.half_width_mm))
    out = tuple((bi, tuple((c[0], c[1]) for c in cs), np.array([c[2] for c in cs], float),
                 np.array([c[3] for c in cs], float), np.array([c[4] for c in cs], float))
                for bi, cs in caps.items())
    for _, _, *arrays in out:  # shared by every build: read-only
        for v in arrays:
            v.setflags(write=False)
    return out


def _static_keep_masks(instrument: Instrument, asg: Assignments, sx, sy, ex, ey, rad,
                       buffer_mm: float, check=lambda: None) -> dict[tuple[int, int, int, int], np.ndarray]:
    """keep[(k, bi, kk, bj)][a]: can body bi of assignment a (of arm k) meet body bj of arm kk?

    Decided against the static region swept by body bj of arm kk (a capsule around its two
    joints' bounding discs, see :func:`_body_pairs_that_can_meet`): O(n) per body pair, and
    it removes most rows/columns for the short bodies near the arm bases.
    """
    keep = {}
    for k in range(instrument.n_arms):
        sl = asg.of_arm(k)
        check()
        for bi, others, c0, c1, reach in _capsules(instrument, k, buffer_mm):
            # every capsule body bi of arm k can meet at once: (capsules, assignments of arm k)
            d = segment_distance_xy(sx[bi, sl][None, :], sy[bi, sl][None, :], ex[bi, sl][None, :],
                                    ey[bi, sl][None, :], c0[:, [0]], c0[:, [1]], c1[:, [0]], c1[:, [1]])
            near = d - rad[bi, sl][None, :] - reach[:, None] < buffer_mm
            for row, (kk, bj) in enumerate(others):
                keep[(k, bi, kk, bj)] = near[row]
    return keep


@dataclass(frozen=True)
class _Bodies:
    """Per body, contiguous coordinate arrays (assignment axis last) in float64 and float32,
    the padded float32 bounding boxes and the static keep masks of one build."""

    f64: tuple[np.ndarray, ...]  # sx, sy, ex, ey, rad: (n_bodies, n_assignments)
    f32: tuple[np.ndarray, ...]
    box: tuple[np.ndarray, ...]  # lox, hix, loy, hiy (float32)
    keep: dict[tuple[int, int, int, int], np.ndarray]
    thr_mm: float


def _bodies(instrument: Instrument, asg: Assignments, buffer_mm: float, check) -> _Bodies:
    seg_s, seg_e, seg_r = body_segments_mm(instrument, asg.arm, asg.theta1_rad, asg.theta2_rad)
    # decided at buffer + TIE_MM: a pair exactly at the buffer (two tips 25 mm apart on a
    # symmetric layout) is incompatible, so rounding can never let the structure accept what
    # the verifiers (clearance < buffer) reject
    thr_mm = buffer_mm + TIE_MM
    sx, sy = np.ascontiguousarray(seg_s[..., 0].T), np.ascontiguousarray(seg_s[..., 1].T)
    ex, ey = np.ascontiguousarray(seg_e[..., 0].T), np.ascontiguousarray(seg_e[..., 1].T)
    rad = np.ascontiguousarray(seg_r.T)
    del seg_s, seg_e, seg_r
    # float32 for the bulk test (3x faster); pairs within FLOAT32_BAND_MM of the buffer
    # are re-decided in float64 so the answer equals the exact computation
    f32 = tuple(v.astype(np.float32) for v in (sx, sy, ex, ey, rad))
    # boxes padded by the float32 band: at an exact tie (boxes touching at the buffer) the
    # rounded float32 bounds must not skip the pair
    box = ((np.minimum(sx, ex) - rad - FLOAT32_BAND_MM).astype(np.float32),
           (np.maximum(sx, ex) + rad + thr_mm + FLOAT32_BAND_MM).astype(np.float32),
           (np.minimum(sy, ey) - rad - FLOAT32_BAND_MM).astype(np.float32),
           (np.maximum(sy, ey) + rad + thr_mm + FLOAT32_BAND_MM).astype(np.float32))
    check()
    keep = _static_keep_masks(instrument, asg, sx, sy, ex, ey, rad, thr_mm, check)
    return _Bodies((sx, sy, ex, ey, rad), f32, box, keep, thr_mm)


def _chunk_pairs(b: _Bodies, body_pairs, target: np.ndarray, k: int, kk: int,
                 a0: int, r0: int, r1: int, b0: int, b1: int, check) -> np.ndarray:
    """Incompatible pairs (i, j) of rows r0:r1 (arm k) x columns b0:b1 (arm kk), int32 (m, 2),
    in row-major order: same target first, then each statically possible body pair through
    the box prefilter, the float32 distance and the float64 re-decision of the band."""
    sx, sy, ex, ey, rad = b.f64
    sx32, sy32, ex32, ey32, rad32 = b.f32
    lox, hix, loy, hiy = b.box
    ta = target[r0:r1]
    hit = (ta[:, None] == target[None, b0:b1]) & (ta[:, None] >= 0)
    for bi, bj in body_pairs:
        check()
        # static prune: a body that stays near its base (L1, L2) only meets the other
        # arm's assignments whose body passes close to that region
        rk = b.keep[(k, bi, kk, bj)][r0 - a0:r1 - a0]
        ck = b.keep[(kk, bj, k, bi)]
        if not rk.any() or not ck.any():
            continue
        ri = np.flatnonzero(rk) + r0
        cj_ = np.flatnonzero(ck) + b0
        cand = lox[bi][ri][:, None] < hix[bj][cj_][None, :]
        cand &= hix[bi][ri][:, None] > lox[bj][cj_][None, :]
        cand &= loy[bi][ri][:, None] < hiy[bj][cj_][None, :]
        cand &= hiy[bi][ri][:, None] > loy[bj][cj_][None, :]
        cand &= ~hit[np.ix_(ri - r0, cj_ - b0)]
        ci, cj = np.nonzero(cand)
        del cand
        if not len(ci):
            continue
        ai, bk = ri[ci], cj_[cj]
        gap = segment_distance_xy(sx32[bi, ai], sy32[bi, ai], ex32[bi, ai], ey32[bi, ai],
                                  sx32[bj, bk], sy32[bj, bk], ex32[bj, bk], ey32[bj, bk])
        gap -= rad32[bi, ai] + rad32[bj, bk] + np.float32(b.thr_mm)
        close = gap < 0
        unsure = np.flatnonzero(np.abs(gap) < FLOAT32_BAND_MM)
        if len(unsure):
            ua, ub = ai[unsure], bk[unsure]
            d64 = segment_distance_xy(sx[bi, ua], sy[bi, ua], ex[bi, ua], ey[bi, ua],
                                      sx[bj, ub], sy[bj, ub], ex[bj, ub], ey[bj, ub])
            close[unsure] = d64 - rad[bi, ua] - rad[bj, ub] < b.thr_mm
        hit[ai[close] - r0, bk[close] - b0] = True
    hi_, hj_ = np.nonzero(hit)
    out = np.empty((len(hi_), 2), np.int32)
    out[:, 0] = hi_ + r0
    out[:, 1] = hj_ + b0
    return out


def _budget_check(budget: Budget | None, limit_s: float | None):
    """A no-argument check raising TimeLimitExceeded once ``budget`` (None: no limit) has
    passed its deadline; every call reads the clock (:meth:`Budget.past_deadline`)."""
    def check() -> None:
        if budget is not None and budget.past_deadline():
            raise TimeLimitExceeded("incompatibility", limit_s)
    return check


def _call_budget(budget: Budget | None, deadline_s: float | None) -> Budget | None:
    """``budget``, else a budget ending at the instant ``deadline_s`` (None: no limit)."""
    if budget is not None or deadline_s is None:
        return budget
    return Budget.ending_at(deadline_s)


def _symmetric_csr(pairs: np.ndarray, n: int, check=lambda: None,
                   slice_pairs: int = 1 << 20) -> tuple[np.ndarray, np.ndarray]:
    """(indptr int64, indices int32) of the symmetric adjacency of ``pairs``, sorted per row.

    ``pairs`` must be in generation order (blocks of arms k < kk, rows ascending within a
    block, row-major within a chunk): then writing every (j, i) entry before every (i, j)
    entry, each in that order, leaves each row's columns ascending, with no sort and no
    temporary larger than one slice of pairs.
    """
    count = np.bincount(pairs[:, 0], minlength=n) + np.bincount(pairs[:, 1], minlength=n)
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(count, out=indptr[1:])
    indices = np.empty(int(indptr[-1]), np.int32)
    fill = indptr[:-1].copy()
    for row_col, other in ((1, 0), (0, 1)):
        for s0 in range(0, len(pairs), slice_pairs):
            check()
            rows = pairs[s0:s0 + slice_pairs, row_col]
            cols = pairs[s0:s0 + slice_pairs, other]
            order = np.argsort(rows, kind="stable")
            rs = rows[order]
            first = np.flatnonzero(np.r_[True, rs[1:] != rs[:-1]])
            group = np.repeat(first, np.diff(np.r_[first, len(rs)]))
            rank = np.arange(len(rs)) - group
            indices[fill[rs] + rank] = cols[order]
            uniq = rs[first]
            fill[uniq] += np.diff(np.r_[first, len(rs)])
    return indptr, indices


def compute_incompatibility(
    instrument: Instrument,
    reachability: Reachability,
    buffer_mm: float | None = None,
    chunk_pairs: int = 1_000_000,
    *,
    deadline_s: float | None = None,
    time_limit_s: float | None = None,
    max_pairs: int = MAX_PAIRS,
    budget: Budget | None = None,
) -> Incompatibility:
    """Every incompatible pair of assignments of different arms (thesis 5.4, set H of eq. 5.15).

    Per arm pair, the statically possible body pairs are tested block by block (at most
    ``chunk_pairs`` assignment pairs at a time): a bounding-box prefilter, then the exact
    capsule distance on the survivors. Pairs on the same target are marked first and never
    re-tested. Memory is the result (17 bytes per pair) plus one block.

    ``budget`` (or, without one, the ``clock.now()`` instant ``deadline_s``; ``time_limit_s``
    is only quoted in the error, by default the budget's limit) is checked between blocks: past its deadline,
    :class:`~models.errors.TimeLimitExceeded`.
    More than ``max_pairs`` pairs raise :class:`~models.errors.StructureTooLarge` (field
    ``targets``) before the memory is spent.
    """
    t0 = clock.now()
    buffer_mm = instrument.collision_buffer_mm if buffer_mm is None else float(buffer_mm)
    asg = reachability.assignments
    call = _call_budget(budget, deadline_s)
    check = _budget_check(call, time_limit_s if time_limit_s is not None or call is None else call.limit_s)
    check()
    clock.work("incompatibility_assignment", len(asg))  # the reach and the bodies
    bodies = _bodies(instrument, asg, buffer_mm, check)
    t_geom = clock.now()
    found: list[np.ndarray] = []
    total = 0
    starts = asg.arm_start
    for k in range(instrument.n_arms):
        a0, a1 = int(starts[k]), int(starts[k + 1])
        for kk in range(k + 1, instrument.n_arms):
            b0, b1 = int(starts[kk]), int(starts[kk + 1])
            if b1 == b0 or a1 == a0:
                continue
            body_pairs = _body_pairs_that_can_meet(instrument, k, kk, bodies.thr_mm)
            step = max(1, chunk_pairs // (b1 - b0))
            for r0 in range(a0, a1, step):
                clock.work("incompatibility_pair", (min(a1, r0 + step) - r0) * (b1 - b0))
                found.append(_chunk_pairs(bodies, body_pairs, asg.target, k, kk, a0, r0, min(a1, r0 + step), b0, b1,
                                          check))
                total += len(found[-1])
                if total > max_pairs:
                    raise StructureTooLarge("targets", f"the incompatibility structure of this field has more than "
                                            f"{max_pairs} assignment pairs; split the field into pointings "
                                            "(segmentation) or lower collision_buffer_mm")
    del bodies
    t_pairs = clock.now()
    # blocks are visited with arm k < kk and assignments are sorted by arm: i < j, no duplicates
    pairs = np.concatenate(found) if found else np.zeros((0, 2), np.int32)
    del found
    clock.work("incompatibility_found_pair", len(pairs))
    check()
    same_target = (asg.target[pairs[:, 0]] >= 0) & (asg.target[pairs[:, 0]] == asg.target[pairs[:, 1]])
    indptr, indices = _symmetric_csr(pairs, len(asg), check)
    t_end = clock.now()
    return Incompatibility(
        reachability=reachability, pairs=pairs, same_target=same_target,
        indptr=indptr, indices=indices, buffer_mm=buffer_mm,
        timings_s={"bodies": t_geom - t0, "pairs": t_pairs - t_geom, "assemble": t_end - t_pairs},
    )


def incompatibility_for_targets(
    instrument: Instrument,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    *,
    buffer_mm: float | None = None,
    include_park: bool = True,
    current: np.ndarray | None = None,
    fixed: dict[int, tuple[float, float]] | None = None,
    blank_per_arm: int = 0,
    seed: int = 0,
    deadline_s: float | None = None,
    time_limit_s: float | None = None,
    max_pairs: int = MAX_PAIRS,
    park_move_limit_s: float | None = None,
    budget: Budget | None = None,
    locks: Mapping[int, tuple[int, int | None]] | None = None,
    excluded: Sequence[int] | np.ndarray | None = None,
) -> Incompatibility:
    """Reachability plus incompatibility for FOV targets, with per-phase timings.

    ``budget`` / ``deadline_s`` / ``time_limit_s`` / ``max_pairs``: see
    :func:`compute_incompatibility`;
    ``park_move_limit_s``, ``locks``, ``excluded``: see :func:`build_assignments`.
    """
    t0 = clock.now()
    reach = build_assignments(instrument, x_mm, y_mm, include_park=include_park, current=current, fixed=fixed,
                              blank_per_arm=blank_per_arm, seed=seed, park_move_limit_s=park_move_limit_s,
                              locks=locks, excluded=excluded)
    t1 = clock.now()
    inc = compute_incompatibility(instrument, reach, buffer_mm, time_limit_s=time_limit_s, max_pairs=max_pairs,
                                  budget=_call_budget(budget, deadline_s))
    inc.timings_s["reachability"] = t1 - t0
    return inc
