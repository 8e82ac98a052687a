"""What every SGPBTA iteration shares (thesis 5.3): the per-field static tables, the
per-problem :class:`Prepared` arrays (live targets in benefit order, eq. 5.4; the matching
upper bounds) and the mutable :class:`State` of one solution."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from models.errors import InputError
from models.incompatibility import FIXED, PARK
from models.kinematics import joint_displacement
from solvers.allocation.options import SemiGreedyOptions
from solvers.allocation.semigreedy.patrolling import (
    point_penalties,
    thesis_penalty_matrix,
    validate_penalty_matrix,
)
from solvers.problem import ConfigProblem
from solvers.thread_cache import thread_cache

Q_TOL_RAD = 1e-9  # a rest location "is" the current position within this tolerance
DISP_EPS = 1e-9  # displacement improvements smaller than this are noise


# ------------------------------------------------------------------- static data


@dataclass(frozen=True)
class FieldStatic:
    """What does not change between the configurations of one field: per-assignment
    penalties, reachability counts r_i (eq. 5.4), park locations. Cached per structure."""

    pen: np.ndarray  # (A,) int64 patrol penalty of target assignments, -1 forbidden, 0 rest
    r: np.ndarray  # (n_targets,) distinct arms that reach and may patrol each target
    n_avail: int  # arms in service (n of eq. 5.4)
    park_idx: np.ndarray  # (n_arms,) park assignment or -1
    rn_ptr: np.ndarray  # CSR: per assignment, the incompatible rest locations
    rn_idx: np.ndarray  # (park / current / fixed / blank sky) -- the padding look-ahead
    indices64: np.ndarray  # the structure's CSR indices as intp, its indptr as a list
    indptr_l: list
    reach_h: np.ndarray  # (n_targets,) n_arms - (arms reaching the target), 0 if unreachable
    reachable: np.ndarray  # (n_targets,) bool: some enabled arm reaches the target
    pairs: dict = field(default_factory=dict)  # radius -> [neighbour CSR ptr, idx, last (live, counts)]


_FIELD_CACHE = "semigreedy.fields"  # thread_cache name: key -> (inc, FieldStatic)


@functools.lru_cache(maxsize=8)
def thesis_matrix(n_arms: int) -> np.ndarray:
    m = thesis_penalty_matrix(n_arms)
    m.setflags(write=False)
    return m


def penalty_spec(spec, n_arms: int) -> np.ndarray:
    if isinstance(spec, str):
        if spec == "thesis":
            return thesis_matrix(n_arms)
        if spec == "workspace":
            return np.zeros((n_arms, 1), np.int64)
        raise InputError("penalty_matrix", f"must be 'thesis', 'workspace' or a matrix, got {spec!r}")
    return validate_penalty_matrix(spec, n_arms)


def field_static(problem: ConfigProblem, penalty: np.ndarray, first_slice_deg: float) -> FieldStatic:
    inc = problem.incompatibility
    key = (id(inc), penalty.shape, penalty.tobytes(), float(first_slice_deg),
           None if problem.target_xy_mm is None else id(problem.target_xy_mm))
    cache = thread_cache(_FIELD_CACHE)
    hit = cache.get(key)
    if hit is not None and hit[0] is inc:
        return hit[1]
    a = problem.assignments
    n_arms = len(a.arm_start) - 1
    tgt = a.target.astype(np.int64)
    is_target = tgt >= 0
    n_t = len(problem.priority)
    pen = np.zeros(len(a), np.int64)
    if is_target.any():
        # penalty per target position, not per tip, so both IK branches of a target on a
        # slice border get the same slice
        if problem.target_xy_mm is not None:
            txy = np.asarray(problem.target_xy_mm, float)
        else:
            txy = np.zeros((n_t, 2))
            txy[tgt[is_target]] = np.column_stack([a.x_mm[is_target], a.y_mm[is_target]])
        used = np.unique(tgt[is_target])
        pp = point_penalties(penalty, txy[used, 0], txy[used, 1], first_slice_deg)
        col = np.full(n_t, -1)
        col[used] = np.arange(len(used))
        pen[is_target] = pp[a.arm[is_target], col[tgt[is_target]]]
    ok = is_target & (pen >= 0)
    pair = np.unique(tgt[ok] * n_arms + a.arm[ok])
    r = np.bincount(pair // n_arms, minlength=n_t)
    in_service = np.zeros(n_arms, bool)
    in_service[a.arm[is_target | (tgt == PARK)]] = True
    park_idx = np.full(n_arms, -1)
    pk = np.flatnonzero(tgt == PARK)
    park_idx[a.arm[pk]] = pk
    rn_ptr, rn_idx = rest_neighbours(inc, tgt < 0)
    apt = inc.reachability.arms_per_target
    reach_h = np.where(apt > 0, n_arms - apt, 0).astype(np.int64)
    fs = FieldStatic(pen, r, max(int(in_service.sum()), 1), park_idx, rn_ptr, rn_idx,
                      inc.indices.astype(np.intp), inc.indptr.tolist(), reach_h, apt > 0)
    if len(cache) > 8:
        cache.clear()
    cache[key] = (inc, fs)
    return fs


def rest_neighbours(inc, is_rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR: per assignment, the incompatible assignments among the rest locations ``is_rest``."""
    n = len(is_rest)
    keep = is_rest[inc.indices]
    rows = np.repeat(np.arange(n), np.diff(inc.indptr))
    rn_ptr = np.concatenate([[0], np.cumsum(np.bincount(rows[keep], minlength=n))]).astype(np.int64)
    return rn_ptr, inc.indices[keep].astype(np.int64)


def tie_break_weights(problem: ConfigProblem, fs: FieldStatic, radius_mm: float) -> np.ndarray:
    """(n_targets,) "hard to place" weight, the exact allocator's tie-break (departure).

    ``problem.tie_break`` when the driver supplied one; else what
    :func:`solvers.sequencing.hard_to_place` computes -- ``n_arms - (arms reaching the
    target)`` plus the number of other available, reachable targets within
    ``radius_mm`` -- from the field's fixed neighbour pairs (one k-d tree query per field,
    cached). Along a sequence the pending set only shrinks, so the counts of the previous
    call are updated for the targets observed since (O(their neighbours)); otherwise they
    are counted over all pairs. Without ``target_xy_mm`` only the reach term.
    """
    if problem.tie_break is not None:
        return np.asarray(problem.tie_break, np.int64)
    h = fs.reach_h
    xy = problem.target_xy_mm
    n = len(h)
    if xy is None or not n:
        return h.copy()
    nbr = fs.pairs.get(radius_mm)
    if nbr is None:
        from scipy.spatial import cKDTree

        pairs = cKDTree(np.asarray(xy, float)).query_pairs(radius_mm, output_type="ndarray").astype(np.intp)
        # both directions, as CSR: the neighbours of each target
        src = np.concatenate([pairs[:, 0], pairs[:, 1]])
        dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
        order = np.argsort(src, kind="stable")
        nbr = fs.pairs[radius_mm] = [np.searchsorted(src[order], np.arange(n + 1)), dst[order], None]
    ptr, idx, last = nbr
    live = problem.available & fs.reachable
    if last is not None and not (live & ~last[0]).any():
        gone = np.flatnonzero(last[0] & ~live)  # observed since the last call
        cnt = last[1].copy()
        if len(gone):
            lens = ptr[gone + 1] - ptr[gone]
            nb = idx[np.repeat(ptr[gone] - np.cumsum(lens) + lens, lens) + np.arange(int(lens.sum()))]
            np.subtract.at(cnt, nb[last[0][nb]], 1)
            cnt[gone] = 0
    else:
        src = np.repeat(np.arange(n), np.diff(ptr))
        both = live[src] & live[idx]
        cnt = np.bincount(src[both], minlength=n)
    nbr[2] = (live, cnt)
    return h + cnt


@dataclass(frozen=True)
class Prepared:
    """Per-problem arrays the iterations share (built once per call, O(n_assignments)).

    Targets are renumbered to *live* ids 0..m-1 in decreasing benefit eta (eq. 5.4):
    available targets with at least one allowed, patrolled assignment. ``tc[a]`` is the
    live id of assignment a (-1 otherwise). ``tptr/tasg`` list, per live id, its
    assignments in GAS order (penalty, arm, displacement).
    """

    n_arms: int
    arm: np.ndarray  # (A,) int
    arm_start: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    prio: np.ndarray  # (A,) int64, 0 for rest
    is_target: np.ndarray  # (A,) bool
    disp: np.ndarray  # (A,) total joint displacement from start_q (eq. 5.1)
    hw: np.ndarray  # (A,) tie-break weight ("hard to place") of target assignments, 0 for rest
    score: np.ndarray  # (A,) (prio, hw, -disp) order as one float (see prepare)
    pen: np.ndarray  # (A,) patrol penalty, -1 forbidden (0 for rest locations)
    tok: np.ndarray  # (A,) bool: allowed target assignment on a patrolled slice
    rest_ok: np.ndarray  # (A,) bool: allowed park / current / fixed location
    movable: np.ndarray  # (A,) bool: tok | rest_ok, what a replace move may pick
    tc: np.ndarray  # (A,) live target id or -1
    live_targets: np.ndarray  # (m,) original target index of each live id
    eta: np.ndarray  # (m,) benefit (eq. 5.4), non-increasing
    tptr: np.ndarray
    tasg: np.ndarray
    current_idx: np.ndarray  # (n_arms,) rest assignment at start_q, or -1
    park_idx: np.ndarray  # (n_arms,) park assignment, or -1
    rest_order: np.ndarray  # per arm, its rest locations in padding order (Alg. 5):
    rest_ptr: np.ndarray  # current, park, then blank sky / others by displacement
    rn_ptr: np.ndarray  # per assignment, the rest locations incompatible with it
    rn_idx: np.ndarray
    preset: np.ndarray  # (n_arms,) the only location of an arm with one, else -1
    target_arms: np.ndarray  # (n_arms,) bool: arm can take some live target
    ub_priority: int  # matching bound, patrolled targets (what SGPBTA can reach)
    ub_yield: int
    ub_priority_all: int  # matching bound, every allowed target (bounds the exact optimum)
    # the same data as Python lists / initial values, for the scalar hot loop of construct()
    rn_arm: np.ndarray  # arm of each rn_idx entry
    tasg_l: list  # tasg as a list
    tptr_l: list
    arm_l: list  # arm as a list
    pen_l: list
    chosen0: np.ndarray  # the empty state (only the preset arms placed)
    blocked0: np.ndarray
    cnt0: np.ndarray  # (m,) usable assignments per live target in the empty state
    rest_free0: np.ndarray  # (n_arms,) free rest locations per arm in the empty state
    indices64: np.ndarray  # indices as intp (fancy indexing without a conversion)
    indptr_l: list
    rn_ptr_l: list
    arm_start_l: list


def matching_bound(arm: np.ndarray, tcol: np.ndarray, weight: np.ndarray, n_arms: int, m: int) -> int:
    """Max-weight arm-target matching ignoring collisions: an upper bound on any solution."""
    if m == 0 or len(arm) == 0:
        return 0
    w = np.zeros((n_arms, m))
    w[arm, tcol] = weight  # both IK branches of an (arm, target) pair carry the same weight
    if m > n_arms * n_arms:
        # some optimal matching uses, for every arm, one of its n_arms heaviest targets (an
        # arm on a lighter target has one of its heaviest free -- only n_arms - 1 others
        # are taken -- and moving it there loses nothing): keep only those columns
        top = np.argpartition(-w, n_arms - 1, axis=1)[:, :n_arms]
        w = w[:, np.unique(top)]
    r, c = linear_sum_assignment(w, maximize=True)
    return int(round(w[r, c].sum()))


def prepare(problem: ConfigProblem, opts: SemiGreedyOptions) -> Prepared:
    """Build the per-problem arrays (penalties, benefits, per-target lists, bounds)."""
    a = problem.assignments
    n_arms = len(a.arm_start) - 1
    n_asg = len(a)
    penalty = penalty_spec(opts.penalty_matrix, n_arms)
    fs = field_static(problem, penalty, opts.first_slice_deg)
    pen = fs.pen
    allowed = problem.allowed()
    tgt = a.target
    prio = problem.assignment_priority()
    # an available target of priority 0 (already observed sky, offered by the conflict
    # rescue of solvers.sequencing) is worth nothing: it is a rest location, where an idle
    # arm may point to make room, not a target (it counts neither in yield nor in the pool)
    zero = allowed & (tgt >= 0) & (prio == 0)
    is_target = (tgt >= 0) & ~zero
    d1, ccw, cw = joint_displacement(problem.start_q[a.arm], a.q)
    disp = np.abs(d1) + np.minimum(ccw, -cw)
    tok = allowed & is_target & (pen >= 0)
    rest_ok = allowed & ~is_target
    rn_ptr, rn_idx = (fs.rn_ptr, fs.rn_idx) if not zero.any() else rest_neighbours(problem.incompatibility,
                                                                                    (tgt < 0) | zero)

    n_t = len(problem.priority)
    h_t = tie_break_weights(problem, fs, opts.crowding_radius_mm) if opts.crowding else np.zeros(n_t, np.int64)
    hw = np.where(is_target, h_t[np.where(is_target, tgt, 0)], 0) if n_t else np.zeros(n_asg, np.int64)
    # (prio, hw, -disp) as one float: prio + (hw + 1 - disp / (2 pi + 1)) / (max hw + 2),
    # the fraction in (0, 1) (disp <= 2 pi); replace moves check the order exactly
    score = prio + (hw + 1 - disp / (2 * np.pi + 1)) / (int(hw.max(initial=0)) + 2)

    # live targets sorted by decreasing eta_i = p_i + gamma * r_i / n  (eq. 5.4)
    live_mask = np.zeros(n_t, bool)
    live_mask[tgt[tok]] = True
    ids = np.flatnonzero(live_mask)
    eta_ids = problem.priority[ids].astype(float) + opts.gamma * fs.r[ids] / fs.n_avail
    order = np.argsort(-eta_ids, kind="stable")
    live_targets = ids[order]
    eta = eta_ids[order]
    m = len(live_targets)
    rank = np.full(n_t, -1, np.int64)
    rank[live_targets] = np.arange(m)
    tc = np.where(tok, rank[np.where(is_target, tgt, 0)], -1)

    # per live target, its usable assignments in GAS order: penalty, arm, displacement
    idx = np.flatnonzero(tok)
    # (live id, penalty, arm) as one int64 key, then displacement (same order as a 4-key lexsort)
    k3 = (tc[idx] * (int(pen.max(initial=0)) + 2) + pen[idx] + 1) * (n_arms + 1) + a.arm[idx]
    tasg = idx[np.lexsort((disp[idx], k3))]
    tptr = np.searchsorted(tc[tasg], np.arange(m + 1))

    # rest locations: the one at start_q is "current"; an arm with one location only
    # (out of service) is an obstacle placed before anything else
    current_idx = np.full(n_arms, -1)
    rest = np.flatnonzero(rest_ok & (disp < Q_TOL_RAD))
    current_idx[a.arm[rest[::-1]]] = rest[::-1]  # first one per arm wins
    park_idx = np.where(rest_ok[np.maximum(fs.park_idx, 0)] & (fs.park_idx >= 0), fs.park_idx, -1)
    # padding order per arm: current, park, then the others (blank sky) by displacement
    rest = np.flatnonzero(rest_ok)
    rank_ = np.where(rest == current_idx[a.arm[rest]], 0, np.where(rest == park_idx[a.arm[rest]], 1, 2))
    rest_order = rest[np.lexsort((rest, disp[rest], rank_, a.arm[rest]))]
    rest_ptr = np.searchsorted(a.arm[rest_order], np.arange(n_arms + 1))
    n_loc = np.add.reduceat((tok | rest_ok).astype(np.int64), a.arm_start[:-1]) if n_asg else np.zeros(n_arms)
    n_loc[np.diff(a.arm_start) == 0] = 0
    target_arms = np.zeros(n_arms, bool)
    target_arms[a.arm[tok]] = True
    preset = np.full(n_arms, -1)
    for k in np.flatnonzero((n_loc == 1) & ~target_arms):
        j = int(a.arm_start[k]) + int(np.flatnonzero(rest_ok[a.arm_start[k]:a.arm_start[k + 1]])[0])
        if tgt[j] == FIXED:
            preset[k] = j

    free = preset < 0
    sel = tok & free[a.arm]
    ub_p = matching_bound(a.arm[sel], tc[sel], prio[sel], n_arms, m)
    ub_y = matching_bound(a.arm[sel], tc[sel], 1.0, n_arms, m)
    all_ok = allowed & is_target & free[a.arm]
    if np.array_equal(all_ok, sel):
        ub_all = ub_p
    else:
        all_t, all_c = np.unique(tgt[all_ok], return_inverse=True)
        ub_all = matching_bound(a.arm[all_ok], all_c, prio[all_ok], n_arms, len(all_t))
    # the empty state: preset (out-of-service) arms on their only location
    indptr, indices = problem.incompatibility.indptr, problem.incompatibility.indices
    chosen0 = np.full(n_arms, -1, np.int64)
    blocked0 = np.zeros(n_asg, np.int32)
    for k in np.flatnonzero(preset >= 0):
        x = int(preset[k])
        chosen0[k] = x
        blocked0[indices[indptr[x]:indptr[x + 1]]] += 1
    arm_free0 = (chosen0 < 0) & target_arms
    usable = tok & (blocked0 == 0) & arm_free0[a.arm]
    cnt0 = np.bincount(tc[usable], minlength=m)
    rest_free0 = (np.add.reduceat(np.append(blocked0[rest_order] == 0, False).astype(np.int64), rest_ptr[:-1])
                  * (np.diff(rest_ptr) > 0)) if len(rest_order) else np.zeros(n_arms, np.int64)
    arm64 = a.arm.astype(np.int64)
    return Prepared(
        n_arms=n_arms, arm=arm64, arm_start=np.asarray(a.arm_start, np.int64),
        indptr=indptr, indices=indices,
        prio=prio, is_target=is_target, disp=disp, hw=hw, score=score,
        pen=pen, tok=tok, rest_ok=rest_ok, movable=tok | rest_ok, tc=tc,
        live_targets=live_targets, eta=eta, tptr=tptr, tasg=tasg, current_idx=current_idx,
        park_idx=park_idx, rest_order=rest_order, rest_ptr=rest_ptr, rn_ptr=rn_ptr, rn_idx=rn_idx,
        preset=preset, target_arms=target_arms,
        ub_priority=ub_p, ub_yield=ub_y, ub_priority_all=ub_all,
        rn_arm=arm64[rn_idx], tasg_l=tasg.tolist(), tptr_l=tptr.tolist(), arm_l=arm64.tolist(), pen_l=pen.tolist(),
        chosen0=chosen0, blocked0=blocked0, cnt0=cnt0, rest_free0=rest_free0.astype(np.int64),
        indices64=fs.indices64, indptr_l=fs.indptr_l, rn_ptr_l=rn_ptr.tolist(), arm_start_l=a.arm_start.tolist(),
    )


# ------------------------------------------------------------------ mutable state


@dataclass
class State:
    """A (partial) solution: ``chosen[k]`` (-1 = unassigned) and the blocking counts."""

    chosen: np.ndarray  # (n_arms,) int64
    blocked: np.ndarray  # (A,) int32: chosen assignments incompatible with each assignment
    picked: list[int] = field(default_factory=list)  # live target ids drawn, in order

    @staticmethod
    def empty(st: Prepared) -> State:
        """Nothing chosen but the preset (out-of-service) arms on their only location."""
        return State(st.chosen0.copy(), st.blocked0.copy())

    def place(self, st: Prepared, x: int) -> None:
        self.chosen[st.arm_l[x]] = x
        self.blocked[st.indices64[st.indptr_l[x]:st.indptr_l[x + 1]]] += 1

    def remove(self, st: Prepared, k: int) -> None:
        x = int(self.chosen[k])
        self.blocked[st.indices64[st.indptr_l[x]:st.indptr_l[x + 1]]] -= 1
        self.chosen[k] = -1

    def key(self, st: Prepared) -> tuple[int, int, int, float]:
        """Solution-update order (5.3.1.4): priority, yield, then (departure) the
        tie-break weight ``hw`` summed, then minus total displacement."""
        c = self.chosen[self.chosen >= 0]
        return (int(st.prio[c].sum()), int(st.is_target[c].sum()), int(st.hw[c].sum()), -float(st.disp[c].sum()))
