"""Semi-Greedy Patrol-Based Target Allocator, SGPBTA (thesis 5.3, Algorithms 3-5).

A GRASP-style multistart heuristic for one observational configuration. Each iteration

1. **constructs** a partial solution target by target (thesis Algorithm 4): a limited
   pool of candidates (LPC) of the targets with the greatest benefit
   ``eta_i = p_i + gamma * r_i / n`` (eq. 5.4), those with ``eta_i >= q(alpha)``
   (eq. 5.5), one drawn at random; then an arm for it, ordered by the patrolling penalty
   matrix (:mod:`solvers.patrolling`) -- greedy (GAS) or shuffled per penalty level
   (PBAS) -- taking the first one compatible with the assignments already made;
2. **pads** the arms left without a target (thesis Algorithm 5): current position, then
   park, then the blank-sky locations sampled in the free area in front of the arm (when
   the structure has them, ``blank_per_arm``) -- the first compatible one, so padding
   never collides; only if none fits are the blocking assignments undone (a last-resort
   repair, see :func:`pad`), so every returned solution is complete;
3. runs a **local search** (5.3.1.3): swap moves then replace moves, first improvement
   (then ejection moves, a departure, below);
4. keeps the best solution (**solution update**, 5.3.1.4): total priority, then arm
   yield, then (departure, below) the "hard to place" tie-break, then total joint
   displacement (eq. 5.1) -- lexicographically.

Everything runs on the precomputed incompatibility structure (the same CSR adjacency the
exact allocator uses): compatibility of a candidate is ``blocked[a] == 0`` where
``blocked`` counts the chosen assignments incompatible with ``a``, updated in O(degree)
per move. No geometry is evaluated while solving.

Deliberate departures from the thesis pseudo-code, each documented where it occurs:

* targets that can no longer be placed are left out of the pool (the thesis draws them,
  fails at line 19 and moves on);
* padding look-ahead (``lookahead``, default on): construction accepts an arm for a
  target only if every arm still idle keeps a compatible rest location; the idle arms
  are then padded jointly (a tiny depth-first search). In the thesis a solution whose
  padding fails is dropped; here (almost) none fails, so no iteration is wasted;
* the local search runs replace moves first and the swap moves (which only shorten the
  total displacement) only on a solution that can still win the update;
* a multistart stops early once a solution reaches the collision-free upper bound
  (bipartite matching) in priority and yield, and after ``max_stall`` (default 10)
  iterations without improvement -- the thesis always runs all ``n_iter`` (30). On the
  1,200-target dense field most configurations at a priority-tier change never meet the
  matching bound (collisions bind), and the last improvement comes at iteration 9 on
  average; ``max_stall=None`` restores the thesis behaviour;
* targets of priority 0 (already observed sky that the conflict rescue of
  :mod:`solvers.sequencing` offers as a resting place) are rest locations, not targets;
* **crowding tie-break** (``crowding``, default on): among solutions of equal priority and
  yield the solution update, and the replace moves, prefer the one whose targets are hard
  to place -- ``n_arms - (arms reaching it)`` plus the pending targets within
  ``crowding_radius_mm`` (the exact allocator's tie-break, :func:`tie_break_weights`) --
  before the displacement. Priority stays the primary key and the construction (eqs.
  5.4, 5.5) is untouched. Why: a sequence that observes targets one configuration at a
  time ends in a tail of under-filled configurations unless the crowded places (where
  few arms fit at once) are worked from the start; the thesis optimises each
  configuration alone and does not see it. On the 1,200-target dense field (fields
  100-105, both alphas) the mean configuration count went from 106.4 to 102.7 at the
  exact allocator's 15 mm and 101.5 at 25 mm (20 mm: 102.2, 30 mm: 101.4, 35 mm: 101.8;
  the target pairs no configuration can hold together lie within 28 mm of each other in
  99 % of cases), hence the 25 mm default;
* **ejection moves** (``eject_trials``, default 24 per pass; :func:`eject_pass`): after the
  replace moves, an idle arm takes a target blocked by one or two chosen locations whose
  arms move elsewhere -- the move that fills the under-filled tail configurations, where
  the idle arms' rest locations block the last targets (thesis: swap and replace only).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.optimize import linear_sum_assignment

from models.errors import InputError
from models.incompatibility import FIXED, PARK
from models.kinematics import direct_move_time_s, joint_displacement
from solvers.patrolling import point_penalties, thesis_penalty_matrix, validate_penalty_matrix
from solvers.problem import ConfigProblem, ConfigSolution

ArmSelection = Literal["gas", "pbas"]
PatrolSpec = Literal["thesis", "workspace"]

_Q_TOL_RAD = 1e-9  # a rest location "is" the current position within this tolerance
_DISP_EPS = 1e-9  # displacement improvements smaller than this are noise


@dataclass(frozen=True)
class SemiGreedyOptions:
    """Parameters of SGPBTA (thesis 5.5.3.1 defaults: 30 runs, gamma 0.1, PBAS, eq. 5.21 matrix).

    ``penalty_matrix``: ``"thesis"`` (eq. 5.3), ``"workspace"`` (any reachable target,
    penalty 0) or an (n_arms, n_slices) integer matrix. ``first_slice_deg`` is the azimuth
    of the centre of slice 0 (arm 0's azimuth in the default instrument).
    ``time_limit_s`` defaults to the problem's. ``early_stop`` ends the multistart when
    a solution meets the matching upper bound in priority and yield; ``max_stall`` ends it
    after that many iterations without improvement (default 10; ``None`` runs all
    ``n_iter`` as the thesis does). ``crowding`` / ``crowding_radius_mm``: the hard-to-place
    tie-break in the solution update and replace moves (``problem.tie_break`` when the
    driver supplies one); ``eject_trials``: ejection moves evaluated per local-search pass
    (0 = the thesis' swap and replace moves only). Both are departures, see the module
    docstring.
    """

    alpha: float = 0.2
    gamma: float = 0.1
    n_iter: int = 30
    seed: int | None = None
    arm_selection: ArmSelection = "pbas"
    penalty_matrix: PatrolSpec | np.ndarray = "thesis"
    first_slice_deg: float = 0.0
    local_search: bool = True
    lookahead: bool = True
    early_stop: bool = True
    max_stall: int | None = 10
    time_limit_s: float | None = None
    crowding: bool = True
    crowding_radius_mm: float = 25.0
    eject_trials: int = 24


def _validate_options(opts: SemiGreedyOptions) -> None:
    for name, lo, hi in (("alpha", 0.0, 1.0), ("gamma", 0.0, 10.0)):
        v = getattr(opts, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= v <= hi):
            raise InputError(name, f"must be a number in [{lo:g}, {hi:g}], got {v!r}")
    if isinstance(opts.n_iter, bool) or not isinstance(opts.n_iter, (int, np.integer)) or opts.n_iter < 1:
        raise InputError("n_iter", f"must be an integer >= 1, got {opts.n_iter!r}")
    if opts.arm_selection not in ("gas", "pbas"):
        raise InputError("arm_selection", f"must be 'gas' or 'pbas', got {opts.arm_selection!r}")
    if opts.max_stall is not None and (isinstance(opts.max_stall, bool) or opts.max_stall < 1):
        raise InputError("max_stall", f"must be an integer >= 1 or None, got {opts.max_stall!r}")
    if not isinstance(opts.crowding, bool):
        raise InputError("crowding", f"must be true or false, got {opts.crowding!r}")
    r = opts.crowding_radius_mm
    if isinstance(r, bool) or not isinstance(r, (int, float)) or not (np.isfinite(r) and r > 0):
        raise InputError("crowding_radius_mm", f"must be a number > 0, got {r!r}")
    e = opts.eject_trials
    if isinstance(e, bool) or not isinstance(e, (int, np.integer)) or e < 0:
        raise InputError("eject_trials", f"must be an integer >= 0, got {e!r}")
    if opts.time_limit_s is not None and not opts.time_limit_s > 0:
        raise InputError("time_limit_s", f"must be > 0, got {opts.time_limit_s!r}")


# ------------------------------------------------------------------- static data


@dataclass(frozen=True)
class _FieldStatic:
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


_FIELD_CACHE: dict[tuple, tuple[object, _FieldStatic]] = {}


@functools.lru_cache(maxsize=8)
def _thesis_matrix(n_arms: int) -> np.ndarray:
    m = thesis_penalty_matrix(n_arms)
    m.setflags(write=False)
    return m


def _penalty_spec(spec, n_arms: int) -> np.ndarray:
    if isinstance(spec, str):
        if spec == "thesis":
            return _thesis_matrix(n_arms)
        if spec == "workspace":
            return np.zeros((n_arms, 1), np.int64)
        raise InputError("penalty_matrix", f"must be 'thesis', 'workspace' or a matrix, got {spec!r}")
    return validate_penalty_matrix(spec, n_arms)


def _field_static(problem: ConfigProblem, penalty: np.ndarray, first_slice_deg: float) -> _FieldStatic:
    inc = problem.incompatibility
    key = (id(inc), penalty.shape, penalty.tobytes(), float(first_slice_deg),
           None if problem.target_xy_mm is None else id(problem.target_xy_mm))
    hit = _FIELD_CACHE.get(key)
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
    rn_ptr, rn_idx = _rest_neighbours(inc, tgt < 0)
    apt = inc.reachability.arms_per_target
    reach_h = np.where(apt > 0, n_arms - apt, 0).astype(np.int64)
    fs = _FieldStatic(pen, r, max(int(in_service.sum()), 1), park_idx, rn_ptr, rn_idx,
                      inc.indices.astype(np.intp), inc.indptr.tolist(), reach_h, apt > 0)
    if len(_FIELD_CACHE) > 8:
        _FIELD_CACHE.clear()
    _FIELD_CACHE[key] = (inc, fs)
    return fs


def _rest_neighbours(inc, is_rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR: per assignment, the incompatible assignments among the rest locations ``is_rest``."""
    n = len(is_rest)
    keep = is_rest[inc.indices]
    rows = np.repeat(np.arange(n), np.diff(inc.indptr))
    rn_ptr = np.concatenate([[0], np.cumsum(np.bincount(rows[keep], minlength=n))]).astype(np.int64)
    return rn_ptr, inc.indices[keep].astype(np.int64)


def tie_break_weights(problem: ConfigProblem, fs: _FieldStatic, radius_mm: float) -> np.ndarray:
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


def _matching_bound(arm: np.ndarray, tcol: np.ndarray, weight: np.ndarray, n_arms: int, m: int) -> int:
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
    penalty = _penalty_spec(opts.penalty_matrix, n_arms)
    fs = _field_static(problem, penalty, opts.first_slice_deg)
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
    rn_ptr, rn_idx = (fs.rn_ptr, fs.rn_idx) if not zero.any() else _rest_neighbours(problem.incompatibility,
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
    rest = np.flatnonzero(rest_ok & (disp < _Q_TOL_RAD))
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
    ub_p = _matching_bound(a.arm[sel], tc[sel], prio[sel], n_arms, m)
    ub_y = _matching_bound(a.arm[sel], tc[sel], 1.0, n_arms, m)
    all_ok = allowed & is_target & free[a.arm]
    if np.array_equal(all_ok, sel):
        ub_all = ub_p
    else:
        all_t, all_c = np.unique(tgt[all_ok], return_inverse=True)
        ub_all = _matching_bound(a.arm[all_ok], all_c, prio[all_ok], n_arms, len(all_t))
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


# ------------------------------------------------------------ construction (Alg. 4)


def lpc(eta: np.ndarray, candidates: np.ndarray, alpha: float) -> np.ndarray:
    """Limited pool of candidates (eq. 5.5): those with eta >= eta_max - alpha (eta_max - eta_min)."""
    e = eta[candidates]
    hi, lo = e.max(), e.min()
    q = hi - alpha * (hi - lo)
    return candidates[e >= q - 1e-12 * max(1.0, abs(hi))]


def construct(st: Prepared, alpha: float, arm_selection: ArmSelection, rng: np.random.Generator,
              lookahead: bool = True) -> State:
    """Semi-greedy patrol-based construction (thesis Algorithm 4), vectorised.

    ``cnt[t]`` counts the assignments of live target t still usable (arm free, not
    blocked by any assignment made); a target with ``cnt == 0`` is left out of the pool:
    in the thesis it would be drawn, fail every arm (line 13) and land in T^o (line 19)
    with no other effect. Live ids are sorted by decreasing eta, so the pool of eq. 5.5
    is the live part of a prefix. The candidate list of the drawn target holds only
    usable assignments, so the first arm in GAS/PBAS order is the one lines 10-18 accept.

    ``lookahead`` (a departure, default on): a candidate is accepted only if every arm
    still without a location keeps at least one compatible rest location (current, park,
    blank sky), so padding (Algorithm 5) cannot fail; in the thesis such a solution is
    built, fails padding and is dropped (Algorithm 3, line 9). Off: Algorithm 4 verbatim.
    """
    s = State.empty(st)
    m = len(st.eta)
    if m == 0:
        return s
    blocked, chosen = s.blocked, s.chosen
    arm, arm_l, tok, tc = st.arm, st.arm_l, st.tok, st.tc
    indptr_l, indices, rn_ptr, rn_idx, rn_arm = st.indptr_l, st.indices64, st.rn_ptr_l, st.rn_idx, st.rn_arm
    tasg_l, tptr_l, pen_l, arm_start_l = st.tasg_l, st.tptr_l, st.pen_l, st.arm_start_l
    n_arms = st.n_arms
    eta = st.eta
    neg_eta = -eta
    tol = 1e-12 * max(1.0, abs(float(eta[0])))
    arm_free = (chosen < 0) & st.target_arms
    arm_free_l = arm_free.tolist()
    n_free = int(arm_free.sum())
    idle = chosen < 0  # arms without a location yet (they will need a rest location)
    elig = tok & arm_free[arm]  # target assignments of free arms (usable unless blocked)
    cnt = st.cnt0.copy()
    live = cnt > 0  # drawable: not drawn yet and still some usable assignment
    rest_free = st.rest_free0.copy()
    pbas = arm_selection == "pbas"
    # uniform draws in batches (one Generator call per 64 draws)
    buf = rng.random(64).tolist()
    first, last, end = 0, m - 1, -1  # live ids are sorted by decreasing eta

    while n_free:
        if not live[first]:
            first += int(live[first:].argmax())
            if not live[first]:
                break
            end = -1
        if not live[last]:
            last -= int(live[last::-1].argmax())
            end = -1
        if end < 0:  # the pool bound of eq. 5.5 moves only with the live extremes
            hi = eta[first]
            q = hi - alpha * (hi - eta[last])
            end = int(np.searchsorted(neg_eta, -q + tol, side="right"))
        # a uniform draw from the live ids in [first, end): rejection sampling (exact), the
        # explicit list only when live ids are sparse in the window
        t = -1
        for _ in range(4):
            if not buf:
                buf = rng.random(64).tolist()
            j = first + int(buf.pop() * (end - first))
            if live[j]:
                t = j
                break
        if t < 0:
            pool = np.flatnonzero(live[first:end])
            if not buf:
                buf = rng.random(64).tolist()
            t = first + int(pool[int(buf.pop() * len(pool))])
        live[t] = False
        s.picked.append(t)
        cand = [x for x in tasg_l[tptr_l[t]:tptr_l[t + 1]] if arm_free_l[arm_l[x]] and not blocked[x]]
        if pbas and len(cand) > 1:
            # PBAS: per penalty level, the arms in random order (each arm's assignments keep
            # their displacement order: the sort is stable); GAS keeps penalty, arm, displacement
            ks = {arm_l[c] for c in cand}
            if len(ks) > 1:
                if len(buf) < len(ks):
                    buf += rng.random(64).tolist()
                r = {k: buf.pop() for k in sorted(ks)}
                cand.sort(key=lambda c: (pen_l[c], r[arm_l[c]]))
        # the first candidate that leaves every idle arm a rest location (departure from
        # the thesis: there a solution whose padding fails is dropped at Alg. 3 line 9)
        x = -1
        lost_rest = None
        for c in cand:
            k = arm_l[c]
            r0, r1 = rn_ptr[c], rn_ptr[c + 1]
            if r0 == r1:
                x = c
                break
            lost_rest = np.bincount(rn_arm[r0:r1][blocked[rn_idx[r0:r1]] == 0], minlength=n_arms)
            if lookahead:
                starved = (lost_rest > 0) & (lost_rest >= rest_free) & idle
                starved[k] = False
                if starved.any():
                    lost_rest = None
                    continue
            x = c
            break
        if x < 0:
            continue
        k = arm_l[x]
        s0, s1 = arm_start_l[k], arm_start_l[k + 1]
        lost = elig[s0:s1] & (blocked[s0:s1] == 0)  # arm k's usable assignments go away
        dec = tc[s0:s1][lost]
        elig[s0:s1] = False
        arm_free_l[k] = False
        idle[k] = False
        n_free -= 1
        if lost_rest is not None:
            rest_free -= lost_rest
        nb = indices[indptr_l[x]:indptr_l[x + 1]]
        bnb = blocked[nb]
        free_nb = bnb == 0
        blocked[nb] = bnb + 1
        chosen[k] = x
        dec2 = tc[nb[free_nb & elig[nb]]]  # usable assignments of other free arms now blocked
        for d in (dec, dec2):
            if len(d):
                np.subtract.at(cnt, d, 1)
                live[d[cnt[d] == 0]] = False
    return s


# ------------------------------------------------------------------ padding (Alg. 5)


def pad(st: Prepared, s: State) -> bool:
    """Solution padding (thesis Algorithm 5): each arm left without a target goes to the
    first compatible rest location in the order current position, park, blank sky.

    Blank-sky locations are the ones sampled in the free area in front of each arm
    (``models.incompatibility.sample_blank_sky``, target ``BLANK``) when the structure
    was built with ``blank_per_arm``; they are tried by increasing displacement (the
    thesis samples the area at random; the sample is already random, and the shorter
    move is what the solution update prefers). All are locations of the structure, so
    compatibility is the same ``blocked == 0`` test and padding can never collide. The
    pending arms are placed jointly (:func:`_pad_search`, most constrained arm first), since
    one arm's blank-sky location may take a neighbour's last free one.

    Last resort (no blank-sky sample fits, or the structure has none): the assignments
    blocking the arm's preferred rest location are undone and their arms padded in turn
    -- where the thesis would return an incomplete solution and drop the iteration. It
    keeps every iteration complete; the local search can re-fill those arms. Returns
    False only if no complete solution was reached.
    """
    pending = [int(k) for k in np.flatnonzero(s.chosen < 0)]
    for k in [k for k in pending if st.rest_ptr[k] == st.rest_ptr[k + 1]]:
        # an arm with no rest location at all: any compatible location of it
        sl = np.arange(int(st.arm_start[k]), int(st.arm_start[k + 1]))
        ok = sl[st.movable[sl] & (s.blocked[sl] == 0)]
        if not len(ok):
            return False
        s.place(st, int(ok[0]))
        pending.remove(k)
    for _ in range(4 * st.n_arms):
        if not pending or _pad_search(st, s, pending):
            return True
        # last resort: undo the target assignment that blocks the most rest locations of
        # the pending arms (the lowest priority among equals); its arm is padded in turn
        busy = [int(j) for j in np.flatnonzero((s.chosen >= 0) & (st.preset < 0)) if st.is_target[s.chosen[j]]]
        pend_arm = np.zeros(st.n_arms, bool)
        pend_arm[pending] = True
        best = None
        for j in busy:
            c = int(s.chosen[j])
            rn = st.rn_idx[st.rn_ptr[c]:st.rn_ptr[c + 1]]
            hits = int(pend_arm[st.arm[rn]].sum())
            if hits and (best is None or (-hits, int(st.prio[c])) < best[0]):
                best = ((-hits, int(st.prio[c])), j)
        if best is None:  # only out-of-service arms or rest locations in the way
            return False
        s.remove(st, best[1])
        pending.append(best[1])
    return not pending


def _pad_search(st: Prepared, s: State, pending: list[int], max_nodes: int = 2000) -> bool:
    """Place every pending arm on a free rest location jointly (depth-first, most
    constrained arm first, each arm's options in padding order). On success the arms are
    placed and True is returned; on failure ``s`` is left unchanged."""
    order, ptr, blocked = st.rest_order, st.rest_ptr, s.blocked
    placed: list[int] = []
    nodes = 0

    def dfs(left: list[int]) -> bool:
        nonlocal nodes
        if not left:
            return True
        frees = [order[ptr[j]:ptr[j + 1]][blocked[order[ptr[j]:ptr[j + 1]]] == 0] for j in left]
        i = min(range(len(left)), key=lambda q: len(frees[q]))
        rest = left[:i] + left[i + 1:]
        for r in frees[i].tolist():
            nodes += 1
            if nodes > max_nodes:
                return False
            s.place(st, r)
            placed.append(left[i])
            if dfs(rest):
                return True
            s.remove(st, placed.pop())
        return False

    if dfs(list(pending)):
        pending.clear()
        return True
    return False


# ------------------------------------------------------------- local search (5.3.1.3)


def swap_pass(st: Prepared, s: State, rng: np.random.Generator) -> bool:
    """One first-improvement pass of swap moves; True if a move was made.

    Two arms on targets exchange them (each arm must patrol the other's target). Priority
    and yield are unchanged, so a swap can only shorten the total displacement. Pairs of
    adjacent arms are tried first, the others in random order (thesis 5.3.1.3).
    """
    chosen = s.chosen
    on_target = chosen[chosen >= 0]
    on_target = on_target[st.tc[on_target] >= 0]
    if len(on_target) < 2:
        return False
    # x2: an assignment of another busy arm k2 on the target held by k1
    lists = [st.tasg[st.tptr[t]:st.tptr[t + 1]] for t in st.tc[on_target]]
    x2s = np.concatenate(lists)
    holder = np.repeat(st.arm[on_target], [len(v) for v in lists])
    k2s = st.arm[x2s]
    c2s = chosen[k2s]
    # x2's only blocker must be the holder of its target (same-target conflict)
    keep = (k2s != holder) & (c2s >= 0) & (s.blocked[x2s] == 1)
    keep[keep] &= st.tc[c2s[keep]] >= 0
    if not keep.any():
        return False
    x2s, k1s, k2s = x2s[keep], holder[keep], k2s[keep]
    n = st.n_arms
    dist = np.minimum((k1s - k2s) % n, (k2s - k1s) % n)
    order = np.lexsort((rng.random(len(x2s)), dist > 1))
    disp, blocked = st.disp, s.blocked
    for i in order.tolist():
        k1, k2, x2 = int(k1s[i]), int(k2s[i]), int(x2s[i])
        c1, c2 = int(chosen[k1]), int(chosen[k2])
        t2 = int(st.tc[c2])
        for x1 in st.tasg[st.tptr[t2]:st.tptr[t2 + 1]].tolist():
            if arm_of(st, x1) != k1 or blocked[x1] != 1:
                continue
            if disp[x1] + disp[x2] - disp[c1] - disp[c2] >= -_DISP_EPS:
                continue
            nb = st.indices[st.indptr[x1]:st.indptr[x1 + 1]]
            j = int(np.searchsorted(nb, x2))
            if j < len(nb) and nb[j] == x2:
                continue
            s.remove(st, k1)
            s.remove(st, k2)
            s.place(st, x1)
            s.place(st, x2)
            return True
    return False


def arm_of(st: Prepared, x: int) -> int:
    return int(st.arm[x])


def replace_pass(st: Prepared, s: State, rng: np.random.Generator) -> int:
    """One pass of replace moves over the arms in random order; returns #moves made.

    An arm moves to another location (a pending target it patrols, or a rest location)
    compatible with the others. First improvement over arms: each arm whose
    neighbourhood holds an improving move is moved at once and the scan goes on; within
    one arm all its replacements are scored in one vectorised step, so the best of them
    (priority, then displacement; yield follows priority since targets have p >= 1) is
    taken -- it costs the same as the first. The thesis restricts the new target to the
    arm's own and adjacent slices; here any slice the penalty matrix allows is taken.
    """
    score = np.where(st.movable & (s.blocked == 0), st.score, -np.inf)
    chosen = s.chosen
    # arms whose best compatible location beats the current one (the float score ranks
    # exactly as (priority, -displacement) up to _DISP_EPS): the others have no move, and
    # the moves of other arms in this pass only block locations, never free better ones...
    # except the location an arm leaves, hence the rescan of arms after a move
    busy = chosen >= 0
    cur = np.where(busy, st.score[np.maximum(chosen, 0)], np.inf)
    best = np.maximum.reduceat(score, st.arm_start[:-1]) if len(score) else np.full(st.n_arms, -np.inf)
    best[np.diff(st.arm_start) == 0] = -np.inf
    if not ((best > cur) & (st.preset < 0)).any():
        return 0
    made = 0
    arm_start = st.arm_start_l
    for k in rng.permutation(st.n_arms).tolist():
        c = int(chosen[k])
        if c < 0 or st.preset[k] >= 0:
            continue
        if not made and not best[k] > cur[k]:
            continue
        s0, s1 = arm_start[k], arm_start[k + 1]
        if made:  # earlier moves of this pass changed what is blocked
            sc = np.where(st.movable[s0:s1] & (s.blocked[s0:s1] == 0), st.score[s0:s1], -np.inf)
        else:
            sc = score[s0:s1]
        j = s0 + int(sc.argmax())
        if j == c:
            continue
        # exact lexicographic check (the float score only ranks)
        dp = int(st.prio[j]) - int(st.prio[c])
        dh = int(st.hw[j]) - int(st.hw[c])
        if dp > 0 or (dp == 0 and (dh > 0 or (dh == 0 and st.disp[j] < st.disp[c] - _DISP_EPS))):
            s.remove(st, k)
            s.place(st, j)
            made += 1
    return made


def _better(dp: int, dy: int, dh: int, dd: float) -> bool:
    """A change (priority, yield, tie-break weight, displacement) improves the key."""
    if dp or dy or dh:
        return (dp, dy, dh) > (0, 0, 0)
    return dd < -_DISP_EPS


def eject_pass(st: Prepared, s: State, rng: np.random.Generator, max_blockers: int = 2,
               max_trials: int = 24) -> int:
    """Ejection moves (a departure, beyond the swap and replace moves of 5.3.1.3).

    An arm at rest takes a target location ``x`` blocked by at most ``max_blockers``
    chosen locations of other arms; each of those arms moves, in turn, to its best location
    (score order: priority, tie-break weight, displacement) compatible with the others and
    ``x``. Kept if the solution key improves, undone otherwise. A replace move cannot do
    it: ``x`` is free only once its blockers have left, and a blocker leaving alone
    usually loses something. In the under-filled tail of a sequence the idle arms' rest
    locations and the few arms on targets block the last targets (e.g. a rim target whose
    arm collides with both neighbours' blank-sky rests); this is the move that frees them.
    First improvement; returns #moves (0 or 1).
    """
    chosen = s.chosen
    n = st.n_arms
    idle = [k for k in range(n) if chosen[k] >= 0 and st.preset[k] < 0 and not st.is_target[chosen[k]]
            and st.target_arms[k]]
    if not idle:
        return 0
    blocked = s.blocked
    cands = []
    for k in idle:
        s0, s1 = st.arm_start_l[k], st.arm_start_l[k + 1]
        b = blocked[s0:s1]
        cands.append(s0 + np.flatnonzero(st.tok[s0:s1] & (b >= 1) & (b <= max_blockers)))
    xs = np.concatenate(cands)
    if not len(xs):
        return 0
    owner = np.full(len(blocked), -1, np.intp)
    placed = chosen >= 0
    owner[chosen[placed]] = np.flatnonzero(placed)
    order = np.lexsort((rng.random(len(xs)), -st.score[xs]))
    indices, indptr_l, arm_start_l = st.indices64, st.indptr_l, st.arm_start_l
    prio, is_t, hw, disp = st.prio, st.is_target, st.hw, st.disp
    arm_l, movable, score = st.arm_l, st.movable, st.score

    def prio_l(c: int) -> int:
        return int(prio[c])

    for x in xs[order].tolist():
        k = st.arm_l[x]
        js = owner[indices[indptr_l[x]:indptr_l[x + 1]]]
        js = js[js >= 0].tolist()
        if len(js) > max_blockers or k in js or any(st.preset[j] >= 0 for j in js):
            continue
        if max_trials <= 0:
            break
        max_trials -= 1
        # evaluate without touching the state: each blocker's new blocking counts on its
        # own slice = now - (rows of the locations left) + (rows of the locations taken)
        old = [int(chosen[k])] + [int(chosen[j]) for j in js]
        new = [x]
        for j in js:
            s0, s1 = arm_start_l[j], arm_start_l[j + 1]
            b = blocked[s0:s1].copy()
            for c in old:
                if arm_l[c] != j:  # an arm's own locations never block each other
                    b[_row_in(st, c, s0, s1)] -= 1
            for c in new:
                b[_row_in(st, c, s0, s1)] += 1
            sc = np.where(movable[s0:s1] & (b == 0), score[s0:s1], -np.inf)
            y = int(sc.argmax())
            if sc[y] == -np.inf:
                break
            new.append(s0 + y)
        if len(new) < len(old):
            continue
        dp = sum(prio_l(c) for c in new) - sum(prio_l(c) for c in old)
        dy = sum(is_t[c] for c in new) - sum(is_t[c] for c in old)
        dh = sum(int(hw[c]) for c in new) - sum(int(hw[c]) for c in old)
        dd = sum(float(disp[c]) for c in new) - sum(float(disp[c]) for c in old)
        if _better(int(dp), int(dy), dh, dd):
            for j in [k] + js:
                s.remove(st, j)
            for y in new:
                s.place(st, y)
            return 1
    return 0


def _row_in(st: Prepared, c: int, s0: int, s1: int) -> np.ndarray:
    """The assignments in [s0, s1) incompatible with ``c``, as offsets from s0 (CSR rows are sorted)."""
    nb = st.indices64[st.indptr_l[c]:st.indptr_l[c + 1]]
    return nb[nb.searchsorted(s0):nb.searchsorted(s1)] - s0


def local_search(st: Prepared, s: State, rng: np.random.Generator, max_moves: int = 1000,
                 swaps: bool = True, eject_trials: int = 0) -> int:
    """Swap moves to a local optimum, then replace moves, repeated until neither improves
    (thesis 5.3.1.3), then ejection moves (:func:`eject_pass`, a departure) when those find
    nothing. Every move strictly improves the lexicographic key. Returns #moves.
    ``swaps=False``: no swap moves; ``eject_trials``: ejection moves evaluated per pass
    (0: none)."""
    moves = 0
    while moves < max_moves:
        made = 0
        while swaps and moves + made < max_moves and swap_pass(st, s, rng):
            made += 1
        made += replace_pass(st, s, rng)
        if not made and eject_trials > 0:
            made += eject_pass(st, s, rng, max_trials=eject_trials)
        moves += made
        if not made:  # a replace can enable new swaps: repeat until a quiet round
            break
    return moves


# ----------------------------------------------------------- multistart (Alg. 3)


def _fallback(st: Prepared) -> State | None:
    """Every arm at rest (current, else park), when compatible: the last resort."""
    s = State.empty(st)
    if pad(st, s):
        return s
    return None


def _evaluate_chosen(problem: ConfigProblem, chosen: np.ndarray) -> tuple[int, int, float]:
    """:func:`solvers.problem.evaluate` with the move times of the chosen locations only."""
    a = problem.assignments
    t = a.target[chosen]
    real = t >= 0
    arms = a.arm[chosen]
    v = problem.joint_speed_rad_s[arms]
    longest = float(direct_move_time_s(problem.start_q[arms], a.q[chosen], v[:, 0], v[:, 1]).max()) \
        if len(chosen) else 0.0
    return sum(int(problem.priority[i]) for i in t[real]), int(real.sum()), longest


def solve_semigreedy(problem: ConfigProblem, **options) -> ConfigSolution:
    """SGPBTA for one configuration (thesis Algorithm 3): multistart construction, padding,
    local search and solution update; keyword options are :class:`SemiGreedyOptions`.

    ``seed`` defaults to ``problem.seed``; the same problem and options give the same
    solution. ``time_limit_s`` (default ``problem.time_limit_s``) bounds the multistart
    (at least one iteration runs). The returned status is ``"feasible"`` (a heuristic
    proves nothing) or ``"infeasible"`` when no complete collision-free choice was found;
    ``gap`` is the relative gap to the collision-free matching upper bound, an upper
    bound on the true optimality gap. ``stats`` holds the bounds, iterations, timings.
    """
    t0 = time.perf_counter()
    unknown = set(options) - set(SemiGreedyOptions.__dataclass_fields__)
    if unknown:
        raise InputError(sorted(unknown)[0], "unknown semigreedy option")
    opts = SemiGreedyOptions(**options)
    _validate_options(opts)
    seed = problem.seed if opts.seed is None else opts.seed
    rng = np.random.default_rng(seed)
    limit = problem.time_limit_s if opts.time_limit_s is None else opts.time_limit_s
    st = prepare(problem, opts)
    t_prep = time.perf_counter()

    best: State | None = None
    best_key: tuple | None = None
    n_done = 0
    ls_moves = 0
    best_iter = -1
    for it in range(opts.n_iter):
        s = construct(st, opts.alpha, opts.arm_selection, rng, opts.lookahead)
        if not pad(st, s):
            continue  # thesis line 9: only complete solutions go on
        if opts.local_search:
            # replace moves first (they decide priority and yield); the swap moves only
            # shorten the displacement, so they run (with replace moves again) only on a
            # solution that can still win the update -- same moves, fewer of them wasted
            ls_moves += local_search(st, s, rng, swaps=False, eject_trials=opts.eject_trials)
            if best_key is None or s.key(st)[:3] >= best_key[:3]:
                ls_moves += local_search(st, s, rng, eject_trials=opts.eject_trials)
        n_done += 1
        key = s.key(st)
        if best_key is None or key[:3] > best_key[:3] or (
                key[:3] == best_key[:3] and key[3] > best_key[3] + _DISP_EPS):
            best, best_key, best_iter = s, key, it
        elif opts.max_stall is not None and it - best_iter >= opts.max_stall:
            break
        if opts.early_stop and best_key[0] >= st.ub_priority and best_key[1] >= st.ub_yield:
            break
        if time.perf_counter() - t0 > limit:
            break
    if best is None:
        best = _fallback(st)
    stats = {
        "method": "semigreedy", "iterations": n_done, "best_iteration": best_iter,
        "local_search_moves": ls_moves, "upper_bound_priority": st.ub_priority_all,
        "upper_bound_priority_patrolled": st.ub_priority, "upper_bound_yield": st.ub_yield,
        "live_targets": int(len(st.eta)), "seed": int(seed) if seed is not None else None,
        "alpha": opts.alpha, "gamma": opts.gamma, "arm_selection": opts.arm_selection,
        "time_prepare_s": t_prep - t0, "time_s": time.perf_counter() - t0,
    }
    if best is None:
        park = np.array([int(st.current_idx[k]) if st.current_idx[k] >= 0 else int(st.park_idx[k])
                         for k in range(st.n_arms)])
        return ConfigSolution(park, "infeasible", 0, 0, 0.0, None, stats)
    total, yield_, longest = _evaluate_chosen(problem, best.chosen)
    ub = st.ub_priority_all
    gap = (ub - total) / ub if ub > 0 else 0.0
    stats["total_displacement_rad"] = -best_key[3] if best_key else float(st.disp[best.chosen].sum())
    return ConfigSolution(best.chosen.copy(), "feasible", total, yield_, longest, gap, stats)


def warm_start(problem: ConfigProblem, **options) -> np.ndarray:
    """The heuristic's chosen assignment indices, (n_arms,), for a MIP start / CP-SAT hints.

    Set ``x_a = 1`` for ``a`` in the result and 0 elsewhere (see :func:`warm_start_vector`);
    the choice is complete and compatible with the incompatibility structure, so it is a
    feasible start for the exact model on the same ``problem``. Defaults favour speed
    (``n_iter=5``) since the exact solver improves on it anyway.
    """
    options.setdefault("n_iter", 5)
    sol = solve_semigreedy(problem, **options)
    return np.asarray(sol.chosen, dtype=np.int64)


def warm_start_vector(problem: ConfigProblem, chosen: np.ndarray) -> np.ndarray:
    """(n_assignments,) 0/1 int8 vector of a choice, ready for ``setSolution``/``AddHint``."""
    x = np.zeros(len(problem.assignments), np.int8)
    x[np.asarray(chosen, dtype=np.int64)] = 1
    return x
