"""The single-configuration integer program (thesis 5.4, IPBA, eqs. 5.13–5.18) as plain arrays.

Shared by every exact back-end (:mod:`solvers.allocation.highs`, :mod:`solvers.allocation.cpsat`,
:mod:`solvers.allocation.bnb`) and by the multi-configuration packing models of
:mod:`solvers.sequencing`.  The model:

One binary per *allowed* assignment (``ConfigProblem.allowed()``: targets still to observe
plus each arm's park / current / fixed location):

* eq. 5.13 — every arm takes exactly one location;
* eq. 5.14 — every target at most one arm;
* eq. 5.15 — no incompatible pair.  Default *aggregated* form: for assignment ``a`` of arm
  ``k`` and each other arm ``k'``, ``x_a + sum(x_b, b in conflicts(a, k')) <= 1`` — valid
  because arm ``k'`` takes exactly one location, so the right-hand set is a clique in the
  conflict graph *given 5.13*; it implies every pair row of ``a`` with ``k'`` and gives a
  tighter LP bound with fewer rows.  A singleton row ``x_a + x_b <= 1`` is dropped when the
  reverse row of ``b`` (which contains ``a``) already implies it.  ``form="pairwise"`` writes
  eq. 5.15 literally (one row per geometric pair; same-target pairs are covered by 5.14);
* eq. 5.16 — the longest move ``x_l``.  Because each arm takes one location we write it as
  ``x_l >= sum_{a in arm k} d_a x_a`` per arm (12 rows, implies 5.16 and is tighter);
* eq. 5.18 — maximise total priority.

Lexicographic criteria (thesis 5.1 and 7.3), done exactly:

1. *priority, then arm yield, then tie-break* in ONE solve with provably safe integer
   weights: ``c_a = (p_a * (m + 1) + y_a) * (H + 1) + h_a`` where ``y_a = 1`` for a real
   target, ``m`` the number of arms and ``h_a >= 0`` the optional tie-break
   (``ConfigProblem.tie_break``, e.g. "hard to place") with ``H = m * max h``.  Since a
   solution has at most ``m`` targets, ``sum y <= m < m + 1`` and ``sum h <= H < H + 1``, so
   one unit of priority outweighs any yield / tie-break difference and one unit of yield
   any tie-break difference.  All coefficients and sums stay below 2^53 (checked; exact in
   HiGHS's doubles) and below 2^63 (CP-SAT's int64).
2. *min longest move*: a second solve with ``sum c_a x_a >= OPT_1`` fixed as a constraint and
   ``min x_l``.  CP-SAT does this in exact integers (move times in integer microseconds).
   HiGHS works in doubles with feasibility tolerances, so its stage-2 answer is re-evaluated
   in exact integers and rejected (stage-1 answer kept, ``stats["stage2"] = "rejected"``)
   if it lost anything.

The lazy candidate loop is :mod:`solvers.allocation.lazy`, the staged, presolved solve
:mod:`solvers.allocation.exact`.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from models import clock
from solvers.effort import MODEL_COLUMN_S, MODEL_NONZERO_S
from solvers.problem import ConfigProblem
from solvers.thread_cache import thread_cache

MAX_EXACT_DOUBLE = 2**53

__all__ = ["ModelArrays", "build_model_arrays", "chosen_columns", "close_over_targets", "coarse_weights",
           "conflict_adjacency", "exact_weight", "expand_candidates", "greedy_solution", "hint_vector",
           "initial_candidates", "safe_weights", "stage_matrix", "validate_problem"]


# ----------------------------------------------------------------------------- model arrays


@dataclass(frozen=True)
class ModelArrays:
    """The integer program as plain arrays, shared by every back-end.

    ``var`` maps model columns to assignment indices.  Rows are CSR over columns:
    ``eq_*`` (= 1, one per arm, eq. 5.13) and ``le_*`` (<= 1: targets eq. 5.14 then
    conflicts eq. 5.15).  ``weight`` is the safe lexicographic integer objective (Python
    ints inside an object array would be slow; int64 is exact below 2^63).
    """

    var: np.ndarray  # (n,) assignment index of each column
    arm_of: np.ndarray  # (n,) arm of each column
    weight: np.ndarray  # (n,) int64 objective coefficient c_a
    move_s: np.ndarray  # (n,) direct-move time from start (eq. 5.1)
    eq_indptr: np.ndarray
    eq_indices: np.ndarray
    le_indptr: np.ndarray
    le_indices: np.ndarray
    n_target_rows: int
    form: str
    timings_s: dict

    @property
    def n_vars(self) -> int:
        return len(self.var)

    @property
    def n_rows(self) -> int:
        return len(self.eq_indptr) - 1 + len(self.le_indptr) - 1

    @property
    def nnz(self) -> int:
        return int(len(self.eq_indices) + len(self.le_indices))


def coarse_weights(problem: ConfigProblem, assignment_index: np.ndarray) -> np.ndarray:
    """``p * (m + 1) + y`` per assignment: the priority and yield part of the safe weight."""
    a = problem.assignments
    t = a.target[assignment_index]
    real = t >= 0
    p = np.zeros(len(t), dtype=np.int64)
    p[real] = np.asarray(problem.priority, np.int64)[t[real]]
    n_arms = len(a.arm_start) - 1
    return p * (n_arms + 1) + real


def safe_weights(problem: ConfigProblem, assignment_index: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Safe lexicographic weights ``c_a`` (see module docstring) and the multipliers used.

    Returns ``(weights int64, yield_mult, tie_mult)``; ``weight = (p*yield_mult + y)*tie_mult + h``.
    The tie-break is dropped (``tie_mult = 1``) if it would push sums past 2^53.
    """
    a = problem.assignments
    n_arms = len(a.arm_start) - 1
    t = a.target[assignment_index]
    real = t >= 0
    coarse = coarse_weights(problem, assignment_index)
    h = np.zeros(len(t), dtype=np.int64)
    tie = getattr(problem, "tie_break", None)
    if tie is not None:
        h[real] = np.asarray(tie, dtype=np.int64)[t[real]]
        if (h < 0).any():
            raise ValueError("tie_break must be >= 0")
    yield_mult = n_arms + 1
    tie_mult = n_arms * int(h.max(initial=0)) + 1
    p_max = int(coarse.max(initial=0)) // yield_mult  # y <= 1 < yield_mult
    if n_arms * (p_max * yield_mult + n_arms) * tie_mult >= MAX_EXACT_DOUBLE:
        tie_mult, h[:] = 1, 0
    w = coarse * tie_mult + h
    return w, yield_mult, tie_mult


_ADJ = "model.adjacency"  # thread_cache name: id(inc) -> (weakref to inc, CSR matrix)


def conflict_adjacency(inc) -> sparse.csr_matrix:
    """The incompatibility as a CSR matrix, built once per structure (it does not change
    between the configurations of a sequence; 4 M entries on a dense 1,200-target field)."""
    cache = thread_cache(_ADJ)
    hit = cache.get(id(inc))
    if hit is not None and hit[0]() is inc:
        return hit[1]
    n = len(inc.assignments)
    adj = sparse.csr_matrix((np.ones(len(inc.indices), np.int8), inc.indices, inc.indptr), shape=(n, n))
    if len(cache) > 8:
        cache.clear()
    cache[id(inc)] = (weakref.ref(inc), adj)
    return adj


def build_model_arrays(problem: ConfigProblem, form: str = "aggregated",
                       candidates: np.ndarray | None = None, wildcards: bool = True) -> ModelArrays:
    """Rows of eqs. 5.13–5.15 for the allowed assignments, vectorised (no loop over pairs).

    ``candidates`` (n_assignments,) bool restricts the real-target columns to a candidate
    set; every arm with allowed assignments left outside it gets one *wildcard* column
    (``var == -1``) in its eq. 5.13 row only, worth the best outside weight and the
    shortest outside move.  Any full solution maps onto the restricted model (outside
    assignments -> wildcards, which conflict with nothing) with weight >= and longest move
    <=, so the restricted model is a relaxation: an optimum without wildcards is optimal
    for the full problem (see :func:`_lazy_solve`).
    """
    if form not in ("aggregated", "pairwise"):
        raise ValueError(f"form must be 'aggregated' or 'pairwise', got {form!r}")
    t0 = clock.now()
    inc = problem.incompatibility
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    allowed = problem.allowed()
    all_w, _, _ = safe_weights(problem, np.arange(len(a)))
    all_move = problem.move_time_s()
    if candidates is not None:
        inside = allowed & (candidates | (a.target < 0))
        outside = allowed & ~inside
    else:
        inside, outside = allowed, np.zeros(len(a), bool)
    var = np.flatnonzero(inside)
    arm_of = a.arm[var].astype(np.int64)
    # wildcards: appended after the real columns (conflict rows only index real columns)
    w_arms = np.unique(a.arm[outside]).astype(np.int64) if wildcards else np.zeros(0, np.int64)
    w_weight = np.zeros(len(w_arms), np.int64)
    w_move = np.zeros(len(w_arms))
    for i, k in enumerate(w_arms):
        o = np.flatnonzero(outside[a.of_arm(int(k))]) + int(a.arm_start[k])
        w_weight[i] = all_w[o].max()
        w_move[i] = all_move[o].min()
    # eq. 5.13: one row per arm over its columns (incl. wildcard)
    arm_all = np.r_[arm_of, w_arms]
    eq_indices = np.argsort(arm_all, kind="stable").astype(np.int64)
    eq_indptr = np.searchsorted(arm_all[eq_indices], np.arange(n_arms + 1)).astype(np.int64)
    # eq. 5.14: targets with >= 2 allowed assignments
    tgt = a.target[var]
    real_cols = np.flatnonzero(tgt >= 0)
    order = real_cols[np.argsort(tgt[real_cols], kind="stable")]
    tv = tgt[order]
    starts = np.flatnonzero(np.r_[True, tv[1:] != tv[:-1]]) if len(tv) else np.zeros(0, int)
    sizes = np.diff(np.r_[starts, len(tv)])
    keep = np.repeat(sizes >= 2, sizes)
    t_indices = order[keep]
    t_indptr = np.r_[0, np.cumsum(sizes[sizes >= 2])].astype(np.int64)
    # conflicts restricted to allowed columns
    adj = conflict_adjacency(inc)
    sub = adj[var][:, var]
    sub.sort_indices()  # rows ascending by construction; columns sorted within each row
    r = np.repeat(np.arange(sub.shape[0], dtype=np.int64), np.diff(sub.indptr))
    c = sub.indices.astype(np.int64)
    t_mid = clock.now()
    if form == "pairwise":
        geometric = tgt[r] != tgt[c]
        geometric |= tgt[r] < 0
        m = (r < c) & geometric
        pr, pc = r[m], c[m]
        c_indptr = np.arange(0, 2 * len(pr) + 1, 2, dtype=np.int64)
        c_indices = np.column_stack([pr, pc]).ravel()
    else:
        # group each row's neighbours by the neighbour's arm (contiguous: columns sorted by arm)
        key = r * n_arms + arm_of[c]
        g_start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, int)
        g_size = np.diff(np.r_[g_start, len(key)])
        g_key = key[g_start]
        g_row = r[g_start]
        # dominance: a singleton row {a, b} is implied by the reverse row of b if that row
        # has >= 2 members, or (both singletons) by the one written for min(a, b)
        single = g_size == 1
        b = c[g_start[single]]
        rev_key = b * n_arms + arm_of[g_row[single]]
        pos = np.searchsorted(g_key, rev_key)
        rev_size = g_size[np.minimum(pos, len(g_key) - 1)]
        keep_single = (rev_size == 1) & (g_row[single] < b)
        keep_g = np.ones(len(g_start), bool)
        keep_g[np.flatnonzero(single)[~keep_single]] = False
        g_start, g_size, g_row = g_start[keep_g], g_size[keep_g], g_row[keep_g]
        # row = [a] + its neighbours of arm k'
        row_len = g_size + 1
        c_indptr = np.r_[0, np.cumsum(row_len)].astype(np.int64)
        c_indices = np.empty(int(c_indptr[-1]), dtype=np.int64)
        c_indices[c_indptr[:-1]] = g_row
        member = np.ones(len(c_indices), bool)
        member[c_indptr[:-1]] = False
        # neighbour positions in c for each kept group, in order
        idx = np.repeat(g_start - np.r_[0, np.cumsum(g_size)[:-1]], g_size) + np.arange(int(g_size.sum()))
        c_indices[member] = c[idx]
    le_indptr = np.r_[t_indptr, t_indptr[-1] + c_indptr[1:]].astype(np.int64)
    le_indices = np.r_[t_indices, c_indices].astype(np.int64)
    weight = np.r_[all_w[var], w_weight]
    move = np.r_[all_move[var], w_move]
    var = np.r_[var, np.full(len(w_arms), -1)]
    arm_of = arm_all
    clock.charge(len(var) * MODEL_COLUMN_S + (len(c) + len(le_indices)) * MODEL_NONZERO_S)
    t_end = clock.now()
    return ModelArrays(var, arm_of, weight, move, eq_indptr, eq_indices, le_indptr, le_indices,
                       len(t_indptr) - 1, form,
                       {"rows_targets_s": t_mid - t0, "rows_conflicts_s": t_end - t_mid})


# ------------------------------------------------------------------------- solution helpers


def chosen_columns(m: ModelArrays, x: np.ndarray, n_arms: int) -> np.ndarray:
    """One column per arm: the column of each arm's eq. 5.13 row with the largest value."""
    cols = np.full(n_arms, -1, dtype=np.int64)
    for k in range(n_arms):
        row = m.eq_indices[m.eq_indptr[k]:m.eq_indptr[k + 1]]
        if len(row):
            cols[k] = row[int(np.argmax(x[row]))]
    return cols


def validate_problem(problem: ConfigProblem) -> None:
    if not (problem.time_limit_s > 0 and math.isfinite(problem.time_limit_s)):
        raise ValueError("time_limit_s must be a positive finite number")
    if not (0 <= problem.mip_rel_gap < 1):
        raise ValueError("mip_rel_gap must be in [0, 1)")


def initial_candidates(problem: ConfigProblem, per_arm: int) -> np.ndarray:
    """(n_assignments,) bool: each arm's ``per_arm`` best allowed target assignments by weight
    (then shorter move), plus every assignment on a chosen target (so arms can swap)."""
    a = problem.assignments
    allowed = problem.allowed() & (a.target >= 0)
    w, _, _ = safe_weights(problem, np.arange(len(a)))
    move = problem.move_time_s()
    cand = np.zeros(len(a), bool)
    for k in range(len(a.arm_start) - 1):
        sl = a.of_arm(k)
        idx = np.flatnonzero(allowed[sl]) + sl.start
        if len(idx) > per_arm:
            idx = idx[np.lexsort((move[idx], -w[idx]))[:per_arm]]
        cand[idx] = True
    return close_over_targets(problem, cand)


def close_over_targets(problem: ConfigProblem, cand: np.ndarray) -> np.ndarray:
    t = problem.assignments.target
    chosen_t = np.zeros(len(problem.available), bool)
    chosen_t[t[cand & (t >= 0)]] = True
    return cand | ((t >= 0) & chosen_t[np.maximum(t, 0)] & problem.allowed())


def expand_candidates(problem: ConfigProblem, cand: np.ndarray, arms: np.ndarray, step: int) -> np.ndarray:
    """Add, for each arm in ``arms``, its next ``step`` best outside assignments."""
    a = problem.assignments
    allowed = problem.allowed() & (a.target >= 0)
    w, _, _ = safe_weights(problem, np.arange(len(a)))
    move = problem.move_time_s()
    cand = cand.copy()
    for k in arms:
        sl = a.of_arm(int(k))
        idx = np.flatnonzero(allowed[sl] & ~cand[sl]) + sl.start
        idx = idx[np.lexsort((move[idx], -w[idx]))[:step]]
        cand[idx] = True
    return close_over_targets(problem, cand)


def greedy_solution(problem: ConfigProblem) -> np.ndarray | None:
    """A quick feasible choice: every arm at its first rest location (park / fixed), then
    arms greedily moved onto the best compatible allowed target (weight order).

    Used as the fallback answer when an exact solve runs out of time (reported as
    ``feasible`` with ``stats["fallback"] = "greedy"``) and as a CP-SAT hint.  None when
    the rest locations themselves conflict.
    """
    inc = problem.incompatibility
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    allowed = problem.allowed()
    chosen = np.full(n_arms, -1, dtype=np.int64)
    for k in range(n_arms):
        sl = a.of_arm(k)
        rest = np.flatnonzero((a.target[sl] < 0) & allowed[sl]) + sl.start
        if not len(rest):
            return None
        chosen[k] = rest[0]
    for k in range(n_arms):
        for j in range(k + 1, n_arms):
            if not inc.compatible(int(chosen[k]), int(chosen[j])):
                return None
    w, _, _ = safe_weights(problem, np.arange(len(a)))
    cand = np.flatnonzero(allowed & (a.target >= 0))
    cand = cand[np.argsort(-w[cand], kind="stable")]
    placed = np.zeros(n_arms, bool)
    used: set[int] = set()
    for c in cand:
        k = int(a.arm[c])
        t = int(a.target[c])
        if placed[k] or t in used:
            continue
        nb = inc.neighbours(int(c))
        others = np.delete(chosen, k)
        if np.isin(others, nb).any():
            continue
        chosen[k] = c
        placed[k] = True
        used.add(t)
        if placed.all():
            break
    return chosen



def exact_weight(problem: ConfigProblem, chosen: np.ndarray) -> int:
    w, _, _ = safe_weights(problem, np.asarray(chosen, int))
    return sum(int(v) for v in w)





def stage_matrix(m: ModelArrays, stage: int, w1: int | None):
    """(A, row_lo, row_hi, cost, integer, sense_max) of stage 1 or 2 over the model arrays."""
    n = m.n_vars
    n_arms = len(m.eq_indptr) - 1
    n_cols = n + (stage == 2)
    eq = sparse.csr_matrix((np.ones(len(m.eq_indices)), m.eq_indices, m.eq_indptr), shape=(n_arms, n_cols))
    le = sparse.csr_matrix((np.ones(len(m.le_indices)), m.le_indices, m.le_indptr),
                           shape=(len(m.le_indptr) - 1, n_cols))
    blocks = [eq, le]
    lo = [np.ones(n_arms), np.full(le.shape[0], -np.inf)]
    hi = [np.ones(n_arms), np.ones(le.shape[0])]
    if stage == 1:
        cost = m.weight.astype(float)
    else:
        # keep the stage-1 optimum; integer weights, so ">= w1 - 0.5" is ">= w1"
        blocks.append(sparse.csr_matrix((m.weight.astype(float), (np.zeros(n, int), np.arange(n))), shape=(1, n_cols)))
        lo.append(np.array([w1 - 0.5]))
        hi.append(np.array([np.inf]))
        # x_l >= sum_{a in arm k} d_a x_a (eq. 5.16 aggregated per arm)
        rows = np.repeat(np.arange(n_arms), np.diff(m.eq_indptr))
        blocks.append(sparse.csr_matrix((np.r_[m.move_s[m.eq_indices], -np.ones(n_arms)],
                                         (np.r_[rows, np.arange(n_arms)], np.r_[m.eq_indices, np.full(n_arms, n)])),
                                        shape=(n_arms, n_cols)))
        lo.append(np.full(n_arms, -np.inf))
        hi.append(np.zeros(n_arms))
        cost = np.zeros(n_cols)
        cost[n] = 1.0
    A = sparse.vstack(blocks, format="csr")
    integer = np.r_[np.ones(n, bool), np.zeros(n_cols - n, bool)]
    return A, np.concatenate(lo), np.concatenate(hi), cost, integer, stage == 1


def hint_vector(m: ModelArrays, hint) -> np.ndarray | None:
    """0/1 column vector of a hinted choice (None unless every hinted assignment is a column)."""
    if hint is None:
        return None
    x = np.isin(m.var, np.asarray(hint, np.int64)).astype(float)
    return x if int(x.sum()) == len(hint) else None

