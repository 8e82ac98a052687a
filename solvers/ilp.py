"""Exact single-configuration allocator (thesis 5.4, IPBA, eqs. 5.13–5.18) on HiGHS and CP-SAT.

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

Two HiGHS front-ends build the *same* arrays: ``interface="pyomo"`` (the documented,
readable model, solved through Pyomo's APPSI HiGHS interface) and ``interface="highspy"``
(the same matrix passed to highspy in one call — the hot path; Pyomo expression building
costs seconds at 10^5 non-zeros).
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from solvers.problem import ConfigProblem, ConfigSolution, evaluate

MAX_EXACT_DOUBLE = 2**53
MOVE_TICKS_PER_S = 1_000_000  # CP-SAT works in integer microseconds for x_l
HIGHS_PRESOLVE_NNZ = 150_000

__all__ = ["ModelArrays", "build_model_arrays", "chosen_columns", "coarse_weights", "conflict_adjacency", "cpsat_stage_solver",
           "exact_weight", "greedy_solution", "highs_stage_solver", "hint_vector", "safe_weights", "solve_ilp_cpsat",
           "solve_ilp_highs", "stage_matrix", "validate_problem"]


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


_ADJ: dict[int, tuple[weakref.ref, sparse.csr_matrix]] = {}


def conflict_adjacency(inc) -> sparse.csr_matrix:
    """The incompatibility as a CSR matrix, built once per structure (it does not change
    between the configurations of a sequence; 4 M entries on a dense 1,200-target field)."""
    hit = _ADJ.get(id(inc))
    if hit is not None and hit[0]() is inc:
        return hit[1]
    n = len(inc.assignments)
    adj = sparse.csr_matrix((np.ones(len(inc.indices), np.int8), inc.indices, inc.indptr), shape=(n, n))
    if len(_ADJ) > 8:
        _ADJ.clear()
    _ADJ[id(inc)] = (weakref.ref(inc), adj)
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
    t0 = time.perf_counter()
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
    t_mid = time.perf_counter()
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
    t_end = time.perf_counter()
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
    return _close_over_targets(problem, cand)


def _close_over_targets(problem: ConfigProblem, cand: np.ndarray) -> np.ndarray:
    t = problem.assignments.target
    chosen_t = np.zeros(len(problem.available), bool)
    chosen_t[t[cand & (t >= 0)]] = True
    return cand | ((t >= 0) & chosen_t[np.maximum(t, 0)] & problem.allowed())


def _expand(problem: ConfigProblem, cand: np.ndarray, arms: np.ndarray, step: int) -> np.ndarray:
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
    return _close_over_targets(problem, cand)


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


# --------------------------------------------------------------- the lexicographic lazy loop


def _lazy_solve(problem: ConfigProblem, solve_arrays, *, form: str, minimize_move: bool,
                candidates_per_arm: int | None, backend: str, max_rounds: int = 6,
                hint: np.ndarray | None = None, columns: np.ndarray | None = None) -> ConfigSolution:
    """Lexicographic exact solve with lazy candidate expansion (see build_model_arrays).

    Stage 1 maximises the safe weight; whenever the optimum of the relaxation uses a
    wildcard, the arms using one get their next best assignments and the model is re-solved
    (finite: the candidate set only grows).  Stage 2 minimises the longest move with the
    stage-1 weight fixed, by the same loop (at most ``MAX_STAGE2_ROUNDS`` expansions;
    ``stats["move_optimal"]`` says whether the longest move is proven minimal).  After
    ``max_rounds`` stage-1 rounds or half the time limit, the restricted model without
    wildcards is solved instead: status "feasible", gap against the last relaxation bound.
    ``columns``: an (n_assignments,) bool mask of columns the caller has PROVEN to contain
    every solution at least as good as its hint (solvers.bnb.prune_columns); the model is
    restricted to them without wildcards (no lazy expansion) and remains exact.
    """
    validate_problem(problem)
    t_start = time.perf_counter()
    a = problem.assignments
    n_arms = len(a.arm_start) - 1
    stats: dict = {"backend": backend, "form": form, "rounds": []}
    deadline = t_start + problem.time_limit_s
    if columns is not None:
        candidates_per_arm = None
    cand = None if candidates_per_arm is None else initial_candidates(problem, candidates_per_arm)
    step = candidates_per_arm or 0
    hint_ok = hint is not None and np.shape(hint) == (n_arms,) and (np.asarray(hint) >= 0).all()
    hint = np.asarray(hint, np.int64) if hint_ok else None
    if hint is not None:
        if not problem.allowed()[hint].all():
            hint = None
        elif cand is not None:
            cand[hint] = True  # the hint must be representable in the restricted model
            cand = _close_over_targets(problem, cand)
    stats["hint"] = hint is not None

    def finish(chosen, status, gap):
        stats["total_s"] = time.perf_counter() - t_start
        if chosen is None:
            return ConfigSolution(np.full(n_arms, -1), status, 0, 0, 0.0, None, stats)
        total, yld, longest = evaluate(problem, chosen)
        return ConfigSolution(chosen, status, total, yld, longest, gap, stats)

    best = None  # (chosen, weight)
    stage, w1 = 1, None
    rounds1 = rounds2 = 0
    status1, gap1 = "timeout", None
    relax_bound = None  # optimum of the last wildcard relaxation: a valid upper bound
    while True:
        tb = time.perf_counter()
        rounds1 += stage == 1
        if stage == 1 and cand is not None and (rounds1 > max_rounds or time.perf_counter() - t_start
                                                  > 0.4 * problem.time_limit_s):
            # the relaxation keeps asking for more candidates (dense, collision-bound fields):
            # solve the restricted model without wildcards — feasible for the full problem,
            # not proven optimal; the last relaxation optimum bounds the gap honestly
            m = build_model_arrays(problem, form, cand, wildcards=False)
            remaining = deadline - time.perf_counter()
            if remaining < 0.05:
                break
            status, x, gap, s = solve_arrays(m, 1, None, remaining, hint)
            s.update(stage="restricted", n_vars=m.n_vars)
            stats["rounds"].append(s)
            if x is not None:
                cols = chosen_columns(m, x, n_arms)
                chosen = m.var[cols]
                w = exact_weight(problem, chosen)
                gap = None if relax_bound is None else max(relax_bound - w, 0) / max(w, 1)
                best, status1, gap1 = (chosen, w), "feasible", gap
            break
        m = build_model_arrays(problem, form, cand) if columns is None or cand is not None else \
            build_model_arrays(problem, form, np.asarray(columns, bool), wildcards=False)
        build_s = time.perf_counter() - tb
        if (m.eq_indptr[1:] == m.eq_indptr[:-1]).any():
            return finish(None, "infeasible", None)
        remaining = deadline - time.perf_counter()
        if remaining <= 0.005:
            break
        status, x, gap, s = solve_arrays(m, stage, w1, remaining, best[0] if best is not None else hint)
        s.update(stage=stage, n_vars=m.n_vars, n_rows=m.n_rows, nnz=m.nnz, build_s=build_s)
        stats["rounds"].append(s)
        if x is None:
            if stage == 1:
                status1 = status
            break
        cols = chosen_columns(m, x, n_arms)
        wild = m.var[cols] < 0
        if stage == 1 and status == "optimal":
            relax_bound = int(sum(int(v) for v in m.weight[cols]))
        if stage == 1 and status != "optimal":
            status1, gap1 = status, gap
            if not wild.any():
                best = (m.var[cols], int(sum(int(v) for v in m.weight[cols])))
            break  # time is up: no further rounds
        if wild.any():
            if stage == 2:
                rounds2 += 1
                if rounds2 > MAX_STAGE2_ROUNDS:
                    break
            cand = _expand(problem, cand, np.flatnonzero(wild), step)
            step *= 2
            continue
        chosen = m.var[cols]
        if stage == 1:
            w1 = int(sum(int(v) for v in m.weight[cols]))
            best, status1, gap1 = (chosen, w1), "optimal", None
            if not minimize_move:
                break
            stage = 2
            continue
        # stage 2: exact integer re-check (HiGHS tolerances must not trade away weight)
        w2 = exact_weight(problem, chosen)
        if w2 >= w1 and evaluate(problem, chosen)[2] <= evaluate(problem, best[0])[2]:
            best = (chosen, w2)
            stats["move_optimal"] = status == "optimal"
        else:
            stats["stage2_rejected"] = True
        break
    if best is None:
        if status1 == "infeasible":
            return finish(None, "infeasible", None)
        # no real (wildcard-free) solution in time: fall back to the greedy choice, honestly
        # labelled (feasible, gap against the relaxation bound when there is one)
        g = greedy_solution(problem)
        if g is None:
            return finish(None, "timeout", None)
        w = exact_weight(problem, g)
        stats["fallback"] = "greedy"
        return finish(g, "feasible", None if relax_bound is None else max(relax_bound - w, 0) / max(w, 1))
    stats.setdefault("move_optimal", False)
    stats["candidates"] = None if cand is None else int(cand.sum())
    return finish(best[0], status1, gap1)


MAX_STAGE2_ROUNDS = 3


def exact_weight(problem: ConfigProblem, chosen: np.ndarray) -> int:
    w, _, _ = safe_weights(problem, np.asarray(chosen, int))
    return sum(int(v) for v in w)


# ---------------------------------------------------------------------------------- HiGHS


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


def highs_stage_solver(problem: ConfigProblem, interface: str, highs_presolve: str = "choose"):
    """A stage solver over HiGHS: ``solve(model, stage, w1, time_limit_s, hint)`` returning
    ``(status, x, gap, stats)``.  ``highs_presolve``: HiGHS' own presolve ("choose", "off"
    or "auto": off up to ``HIGHS_PRESOLVE_NNZ`` non-zeros — after the column pruning and
    clique rows of solvers.exact it mostly costs time there — on above, where the root LP
    without it can overrun the time limit several times over)."""
    def solve(m: ModelArrays, stage: int, w1, time_limit_s: float, hint=None):
        A, row_lo, row_hi, cost, integer, sense_max = stage_matrix(m, stage, w1)
        col_hi = np.where(integer, 1.0, np.inf)
        if interface == "pyomo":
            return _pyomo_solve(A, row_lo, row_hi, col_hi, integer, cost, sense_max, problem, time_limit_s)
        start = hint_vector(m, hint)
        if start is not None and stage == 2:
            start = np.r_[start, float(np.max(m.move_s[start > 0.5], initial=0.0))]
        pre = highs_presolve if highs_presolve != "auto" else ("off" if A.nnz <= HIGHS_PRESOLVE_NNZ else "choose")
        return _highspy_solve(A, row_lo, row_hi, col_hi, integer, cost, sense_max, problem, time_limit_s, start, pre)
    return solve


def hint_vector(m: ModelArrays, hint) -> np.ndarray | None:
    """0/1 column vector of a hinted choice (None unless every hinted assignment is a column)."""
    if hint is None:
        return None
    x = np.isin(m.var, np.asarray(hint, np.int64)).astype(float)
    return x if int(x.sum()) == len(hint) else None


def _highspy_solve(A, row_lo, row_hi, col_hi, integer, cost, sense_max, problem, time_limit_s, start=None,
                   presolve: str = "choose"):
    import highspy

    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("presolve", presolve)
    h.setOptionValue("time_limit", float(time_limit_s))
    h.setOptionValue("mip_rel_gap", float(problem.mip_rel_gap))
    # integer objective coefficients: any solution within < 1 of the bound is optimal
    h.setOptionValue("mip_abs_gap", 0.5 if np.all(cost == np.round(cost)) else 1e-6)
    h.setOptionValue("random_seed", int(problem.seed))
    lp = highspy.HighsLp()
    lp.num_col_ = len(cost)
    lp.num_row_ = A.shape[0]
    lp.col_cost_ = np.asarray(cost, float)
    lp.col_lower_ = np.zeros(len(cost))
    lp.col_upper_ = col_hi
    lp.row_lower_ = row_lo
    lp.row_upper_ = row_hi
    lp.sense_ = highspy.ObjSense.kMaximize if sense_max else highspy.ObjSense.kMinimize
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = A.indptr.astype(np.int32)
    lp.a_matrix_.index_ = A.indices.astype(np.int32)
    lp.a_matrix_.value_ = A.data.astype(float)
    lp.integrality_ = [highspy.HighsVarType.kInteger if i else highspy.HighsVarType.kContinuous for i in integer]
    h.passModel(lp)
    if start is not None:
        sol = highspy.HighsSolution()
        sol.col_value = list(start)
        sol.value_valid = True
        h.setSolution(sol)
    t0 = time.perf_counter()
    h.run()
    solve_s = time.perf_counter() - t0
    ms = h.getModelStatus()
    info = h.getInfo()
    has_sol = info.primal_solution_status == 2  # kSolutionStatusFeasible
    x = np.asarray(h.getSolution().col_value) if has_sol else None
    gap = float(info.mip_gap) if has_sol else None
    if ms == highspy.HighsModelStatus.kOptimal:
        status = "optimal" if (problem.mip_rel_gap == 0 or (gap is not None and gap <= 1e-12)) else "feasible"
    elif ms == highspy.HighsModelStatus.kInfeasible:
        status = "infeasible"
    else:
        status = "feasible" if has_sol else "timeout"
    return status, x, gap, {"solve_s": solve_s, "solver_status": str(ms), "nodes": int(info.mip_node_count)}


def _pyomo_solve(A, row_lo, row_hi, col_hi, integer, cost, sense_max, problem, time_limit_s):
    """The documented Pyomo model: the same matrix, solved by Pyomo's APPSI HiGHS interface."""
    import pyomo.environ as pyo
    from pyomo.contrib.appsi.base import TerminationCondition as TC
    from pyomo.core.expr.numeric_expr import LinearExpression

    model = pyo.ConcreteModel("IPBA")
    cols = range(len(cost))
    model.x = pyo.Var(cols, bounds=lambda _, j: (0, None if np.isinf(col_hi[j]) else col_hi[j]),
                      within=lambda _, j: pyo.Binary if integer[j] else pyo.NonNegativeReals)
    xs = [model.x[j] for j in cols]
    model.rows = pyo.ConstraintList()  # eq. 5.13 rows, then 5.14/5.15, then stage-2 rows
    for i in range(A.shape[0]):
        s, e = A.indptr[i], A.indptr[i + 1]
        expr = LinearExpression(constant=0, linear_coefs=A.data[s:e].tolist(),
                                linear_vars=[xs[j] for j in A.indices[s:e]])
        lo = None if np.isinf(row_lo[i]) else float(row_lo[i])
        hi = None if np.isinf(row_hi[i]) else float(row_hi[i])
        if lo is not None and lo == hi:
            model.rows.add(expr == lo)
        elif lo is None:
            model.rows.add(expr <= hi)
        elif hi is None:
            model.rows.add(expr >= lo)
        else:
            model.rows.add(pyo.inequality(lo, expr, hi))
    nz = np.flatnonzero(cost)
    model.obj = pyo.Objective(expr=LinearExpression(constant=0, linear_coefs=[float(cost[j]) for j in nz],
                                                   linear_vars=[xs[j] for j in nz]),
                              sense=pyo.maximize if sense_max else pyo.minimize)  # eq. 5.18
    from pyomo.contrib.appsi.solvers import Highs as AppsiHighs

    opt = AppsiHighs()
    opt.config.time_limit = float(time_limit_s)
    opt.config.mip_gap = float(problem.mip_rel_gap)
    opt.config.load_solution = False
    opt.highs_options = {"mip_abs_gap": 0.5 if np.all(cost == np.round(cost)) else 1e-6,
                         "random_seed": int(problem.seed)}
    t0 = time.perf_counter()
    res = opt.solve(model)
    solve_s = time.perf_counter() - t0
    tc = res.termination_condition
    has_sol = res.best_feasible_objective is not None
    x = None
    if has_sol:
        res.solution_loader.load_vars()
        x = np.array([pyo.value(model.x[j]) for j in cols])
    if tc == TC.optimal:
        status = "optimal" if problem.mip_rel_gap == 0 else "feasible"
    elif tc == TC.infeasible:
        status = "infeasible"
    else:
        status = "feasible" if has_sol else "timeout"
    gap = None
    if has_sol and res.best_objective_bound is not None:
        obj = res.best_feasible_objective
        gap = abs(res.best_objective_bound - obj) / max(abs(obj), 1e-9)
    return status, x, gap, {"solve_s": solve_s, "solver_status": str(tc)}


def solve_ilp_highs(problem: ConfigProblem, *, form: str = "aggregated", interface: str = "highspy",
                    minimize_move: bool = True, candidates_per_arm: int | None = 8,
                    hint: np.ndarray | None = None, staged: bool = True, presolve: bool = True,
                    cliques: bool = True, columns: np.ndarray | None = None,
                    highs_presolve: str | None = None) -> ConfigSolution:
    """Exact allocation of one configuration with HiGHS (thesis eqs. 5.13–5.18).

    ``interface``: ``"highspy"`` (fast path) or ``"pyomo"`` (Pyomo model, APPSI HiGHS).
    ``minimize_move``: lexicographic stage 2 (min longest move, eq. 5.16).
    ``staged`` (default): :func:`solvers.exact.solve_staged` — incumbent, proven column
    pruning (``presolve``), clique rows (``cliques``), one proof per lexicographic tier.
    ``staged=False``: the lazy candidate expansion (``candidates_per_arm``; None = the full
    model at once) with the tie-break folded into the stage-1 weight.
    ``hint``: a feasible choice passed to HiGHS as a MIP start (highspy interface).
    ``highs_presolve``: HiGHS' own presolve, "off", "choose" or "auto" (default: "auto" when
    staged, see :func:`highs_stage_solver`; "choose" otherwise).
    """
    if interface not in ("highspy", "pyomo"):
        raise ValueError(f"interface must be 'highspy' or 'pyomo', got {interface!r}")
    if highs_presolve is None:
        highs_presolve = "auto" if staged else "choose"
    if highs_presolve not in ("off", "choose", "auto"):
        raise ValueError(f"highs_presolve must be 'off', 'choose' or 'auto', got {highs_presolve!r}")
    if staged:
        from solvers.exact import ExactOptions, solve_staged

        def large(p: ConfigProblem, start) -> ConfigSolution:
            return _lazy_solve(p, highs_stage_solver(p, interface, "choose"), form=form, minimize_move=minimize_move,
                               candidates_per_arm=candidates_per_arm, backend=f"highs/{interface}", hint=start)

        return solve_staged(problem, highs_stage_solver(problem, interface, highs_presolve), backend=f"highs/{interface}",
                            minimize_move=minimize_move, hint=hint, columns=columns,
                            options=ExactOptions(presolve=presolve, cliques=cliques, form=form), large=large)
    return _lazy_solve(problem, highs_stage_solver(problem, interface, highs_presolve), form=form, minimize_move=minimize_move,
                       candidates_per_arm=candidates_per_arm, backend=f"highs/{interface}", hint=hint,
                       columns=columns)


# ---------------------------------------------------------------------------------- CP-SAT


def cpsat_stage_solver(problem: ConfigProblem, workers: int | None, linearization_level: int):
    from ortools.sat.python import cp_model

    def solve(m: ModelArrays, stage: int, w1, time_limit_s: float, hint=None):
        t0 = time.perf_counter()
        model = cp_model.CpModel()
        n_arms = len(m.eq_indptr) - 1
        x = [model.NewBoolVar("") for _ in range(m.n_vars)]
        for k in range(n_arms):  # eq. 5.13
            model.AddExactlyOne([x[j] for j in m.eq_indices[m.eq_indptr[k]:m.eq_indptr[k + 1]]])
        lp, li = m.le_indptr, m.le_indices.tolist()
        for i in range(len(lp) - 1):  # eqs. 5.14, 5.15: cliques given 5.13
            model.AddAtMostOne([x[j] for j in li[lp[i]:lp[i + 1]]])
        obj = cp_model.LinearExpr.WeightedSum(x, [int(w) for w in m.weight])  # exact int64
        if stage == 1:
            model.Maximize(obj)
        else:
            model.Add(obj >= int(w1))
            ticks = np.ceil(m.move_s * MOVE_TICKS_PER_S).astype(np.int64)
            xl = model.NewIntVar(0, int(ticks.max(initial=0)), "x_l")
            for k in range(n_arms):
                cols = m.eq_indices[m.eq_indptr[k]:m.eq_indptr[k + 1]]
                model.Add(xl >= cp_model.LinearExpr.WeightedSum([x[j] for j in cols],
                                                                [int(ticks[j]) for j in cols]))
            model.Minimize(xl)
        start = hint_vector(m, hint)
        if start is not None:
            for j in range(m.n_vars):
                model.AddHint(x[j], bool(start[j]))
        build_s = time.perf_counter() - t0
        solver = cp_model.CpSolver()
        p = solver.parameters
        p.max_time_in_seconds = float(max(time_limit_s, 0.001))
        # one worker stalled on an 800-target instance (issue 4): always >= 2
        p.num_workers = max(2, int(workers if workers is not None else problem.threads))
        p.random_seed = int(problem.seed)
        p.linearization_level = int(linearization_level)
        p.relative_gap_limit = float(problem.mip_rel_gap)
        code = solver.Solve(model)
        s = {"solve_s": time.perf_counter() - t0 - build_s, "cp_build_s": build_s,
             "solver_status": solver.StatusName(code), "branches": int(solver.NumBranches())}
        if code == cp_model.INFEASIBLE or code == cp_model.MODEL_INVALID:
            return "infeasible", None, None, s
        if code not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return "timeout", None, None, s
        xv = np.array([solver.BooleanValue(v) for v in x], dtype=float)
        if code == cp_model.OPTIMAL and problem.mip_rel_gap == 0:
            return "optimal", xv, None, s
        o, b = solver.ObjectiveValue(), solver.BestObjectiveBound()
        return "feasible", xv, abs(b - o) / max(abs(o), 1.0), s
    return solve


def solve_ilp_cpsat(problem: ConfigProblem, *, form: str = "aggregated", workers: int | None = None,
                    linearization_level: int = 2, minimize_move: bool = True,
                    candidates_per_arm: int | None = 8, hint: np.ndarray | None = None,
                    columns: np.ndarray | None = None, staged: bool = True, presolve: bool = True,
                    cliques: bool = True) -> ConfigSolution:
    """Exact allocation of one configuration with OR-Tools CP-SAT (same model, exact int64).

    Conflict and clique rows are at-most-one constraints, which CP-SAT handles natively.
    ``workers``: CP-SAT workers (>= 2; default ``problem.threads``).  ``hint``: a feasible
    choice (assignment index per arm, e.g. solvers.semigreedy.warm_start or the
    branch-and-bound incumbent) given to CP-SAT as a solution hint.  ``staged``,
    ``presolve``, ``cliques``, ``columns``: as in :func:`solve_ilp_highs`.
    """
    if staged:
        from solvers.exact import ExactOptions, solve_staged

        def large(p: ConfigProblem, start) -> ConfigSolution:
            return _lazy_solve(p, cpsat_stage_solver(p, workers, linearization_level), form=form,
                               minimize_move=minimize_move, candidates_per_arm=candidates_per_arm, backend="cpsat",
                               hint=start)

        return solve_staged(problem, cpsat_stage_solver(problem, workers, linearization_level), backend="cpsat",
                            minimize_move=minimize_move, hint=hint, columns=columns,
                            options=ExactOptions(presolve=presolve, cliques=cliques, form=form), large=large)
    return _lazy_solve(problem, cpsat_stage_solver(problem, workers, linearization_level), form=form,
                       minimize_move=minimize_move, candidates_per_arm=candidates_per_arm, backend="cpsat",
                       hint=hint, columns=columns)
