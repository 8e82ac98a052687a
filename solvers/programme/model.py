"""The programme model: choose pointings among the candidates and give each target to one of
them, with the fewest exposures (then the fewest pointings). Solved by HiGHS.

Variables, for candidate j (member set S_j) and target i in S_j::

    e_j  integer >= 0     exposures at pointing j
    y_j  binary           pointing j is used (one acquisition)
    x_ij in [0, 1]        target i is observed at pointing j

    min   sum_j e_j + delta * sum_j y_j
    s.t.  sum_{j : i in S_j} x_ij = 1            every target observed once       (1)
          sum_{i in S_j} x_ij <= cap_j * e_j     an exposure observes <= cap_j     (2)
          x_ij <= y_j                            only at a used pointing            (3)
          y_j <= e_j <= |S_j| * y_j              a used pointing has an exposure   (4)

``cap_j`` is the arms (12) in the bound; the optimiser may lower it for a pointing whose
allocation needed more exposures. The x are continuous: for fixed integer e and y, (1)-(2)
are a bipartite transportation polytope with integer capacities, whose vertices are
integral; with rows (5) each target goes to the pointing of its largest x.

**Bound.** ``delta = 1 / (2 (n + 1))`` keeps ``delta * sum y < 1/2``, so any proven dual
bound D of the objective gives ``exposures >= ceil(D - 1/2)``. With the complete candidate
family (:mod:`.candidates`) and cap 12 this is a lower bound for any plan: a real pointing's
targets lie in some maximal set, and merging pointings on one set never needs more exposures
(ceil(a/12) + ceil(b/12) >= ceil((a + b)/12)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse as sp

from models.budget import Budget
from solvers.effort import HighsMeter, interrupt_at
from solvers.programme.candidates import Candidates

__all__ = ["CoverSolution", "ReachRows", "greedy_cover", "greedy_solution", "solve_cover"]

#: the HiGHS meter counts this many non-zeros per non-zero of the model: its MIP search
#: works harder per callback than the allocator's models the meter's costs were fitted on
#: (wall / effort seconds of about 4 on M67-like programmes with the plain count)
MODEL_WORK_FACTOR = 3
#: the LP solver of the MIP's root: HiGHS calls back in no root LP solve, so the root LP runs
#: whole before the effort meter can stop the search; the interior-point solver takes a quarter
#: of the dual simplex's time on the M67-like case's first model (0.55 s against 2.3 s), and
#: the stop, at a callback, depends on the work done only, not on how fast the machine is
ROOT_LP_SOLVER = "ipm"
#: rows (3) are written for the sets of at most this many targets
STRONG_ROWS_MAX_SET = 24


@dataclass(frozen=True)
class CoverSolution:
    """``exposures[j]`` at candidate j (0: unused); ``objective``, ``dual_bound`` of the
    model; ``exposures_bound``: the proven bound on the exposures it implies; ``status``:
    "optimal", "feasible", "greedy" (the greedy start, not searched) or "timeout" (no
    solution); ``owner[i]``: the candidate
    observing target i (its largest x; -1 without a solution)."""

    exposures: np.ndarray
    owner: np.ndarray
    objective: float
    dual_bound: float
    exposures_bound: int
    status: str
    nodes: int


@dataclass(frozen=True)
class ReachRows:
    """Rows (5) of the plan's model: ``sum of x over entries[start[g]:start[g+1]] <=
    cap[g] * e_{set[g]}`` (entries index ``cand.index``): targets of a pointing that only a
    few arms reach take at most that many per exposure. Not part of the bound."""

    start: np.ndarray
    entries: np.ndarray
    set: np.ndarray
    cap: np.ndarray


class _Rows:
    """A sparse matrix built one block of rows at a time."""

    def __init__(self) -> None:
        self.r, self.rows, self.cols, self.vals, self.lo, self.hi = 0, [], [], [], [], []

    def add(self, n_rows: int, parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], lo, hi) -> None:
        """``n_rows`` rows; ``parts``: (row within the block, column, value) arrays."""
        for row, col, val in parts:
            self.rows.append(self.r + np.asarray(row))
            self.cols.append(np.asarray(col))
            self.vals.append(np.broadcast_to(np.asarray(val, float), np.shape(row)))
        self.lo.append(np.broadcast_to(np.asarray(lo, float), (n_rows,)))
        self.hi.append(np.broadcast_to(np.asarray(hi, float), (n_rows,)))
        self.r += n_rows

    def matrix(self, n_cols: int):
        A = sp.csr_matrix((np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
                          shape=(self.r, n_cols))
        return A, np.concatenate(self.lo), np.concatenate(self.hi)


def _matrix(cand: Candidates, n: int, cap: np.ndarray, reach: ReachRows | None = None):
    """Rows (1)-(5) over columns [x (nnz), e (k), y (k)]."""
    k, nx = len(cand), len(cand.index)
    col_set = np.repeat(np.arange(k), cand.sizes)
    xs, ar = np.arange(nx), np.arange(k)
    e0, y0 = nx, nx + k
    m = _Rows()
    present = np.zeros(n)
    present[cand.index] = 1.0
    m.add(n, [(cand.index, xs, 1.0)], present, present)  # (1), on the targets the sets hold
    m.add(k, [(col_set, xs, 1.0), (ar, e0 + ar, -cap)], -np.inf, 0.0)  # (2)
    # (3) on the small sets only: it tightens the relaxation where a set is thin; (2) and
    # (4) already keep an unused pointing empty
    x3 = xs[cand.sizes[col_set] <= STRONG_ROWS_MAX_SET]
    r3 = np.arange(len(x3))
    m.add(len(x3), [(r3, x3, 1.0), (r3, y0 + col_set[x3], -1.0)], -np.inf, 0.0)
    m.add(k, [(ar, y0 + ar, 1.0), (ar, e0 + ar, -1.0)], -np.inf, 0.0)  # (4) y <= e
    m.add(k, [(ar, e0 + ar, 1.0), (ar, y0 + ar, -cand.sizes.astype(float))], -np.inf, 0.0)  # e <= |S| y
    if reach is not None and len(reach.set):  # (5)
        g = len(reach.set)
        m.add(g, [(np.repeat(np.arange(g), np.diff(reach.start)), reach.entries, 1.0),
                  (np.arange(g), e0 + reach.set, -np.asarray(reach.cap, float))], -np.inf, 0.0)
    return m.matrix(nx + 2 * k)


def solve_cover(cand: Candidates, n: int, budget: Budget, cap: np.ndarray | None = None,
                arms: int = 12, seed: int = 0, reach: ReachRows | None = None,
                allowed: np.ndarray | None = None, pointing_cost: float | None = None) -> CoverSolution:
    """Solve the programme model (module docstring) within ``budget``; ``reach``: rows (5);
    ``allowed``: per entry of ``cand.index``, whether the target may be observed there
    (False: no arm reaches it from that pointing); ``pointing_cost``: the weight of a
    pointing against an exposure (None: ``delta``, the bound's; any other value minimises
    telescope time, and ``exposures_bound`` is then 0: no bound is claimed)."""
    import highspy

    k, nx = len(cand), len(cand.index)
    cap = np.full(k, float(arms)) if cap is None else np.asarray(cap, float)
    A, lo, hi = _matrix(cand, n, cap, reach)
    cost = np.r_[np.zeros(nx), np.ones(k), np.full(k, _pointing_weight(n, pointing_cost))]
    x_hi = np.ones(nx) if allowed is None else np.asarray(allowed, float)
    col_hi = np.r_[x_hi, cand.sizes.astype(float), np.ones(k)]
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("random_seed", int(seed))
    h.setOptionValue("presolve", "off")  # presolve polls no interrupt: the budget comes first
    h.setOptionValue("mip_abs_gap", 0.5)  # enough to prove the exposures (module docstring)
    meter = HighsMeter(nnz=A.nnz * MODEL_WORK_FACTOR)
    limit_s = max(budget.left_s(), 1e-3)
    h.setOptionValue("mip_lp_solver", ROOT_LP_SOLVER)
    # on the effort clock the meter stops the run (:func:`interrupt_at`); the wall-clock time
    # limit is the effort clock's guard only, so a plan is the same on a slower machine
    h.setOptionValue("time_limit", limit_s if meter.effort is None else meter.wall_guard_s(limit_s))
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = A.shape[1], A.shape[0]
    lp.col_cost_ = cost
    lp.col_lower_, lp.col_upper_ = np.zeros(A.shape[1]), col_hi
    lp.row_lower_, lp.row_upper_ = lo, hi
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = A.indptr.astype(np.int32)
    lp.a_matrix_.index_ = A.indices.astype(np.int32)
    lp.a_matrix_.value_ = A.data.astype(float)
    kinds = highspy.HighsVarType
    lp.integrality_ = [kinds.kContinuous] * nx + [kinds.kInteger] * (2 * k)
    h.passModel(lp)
    start = greedy_cover(cand, n, cap, allowed, reach)
    if start is not None:
        sol = highspy.HighsSolution()
        sol.col_value = list(_start_vector(cand, start, nx, cap, reach))
        sol.value_valid = True
        h.setSolution(sol)
    interrupt_at(h, meter.now() + limit_s, meter)
    h.run()
    info = h.getInfo()
    meter.finish(info)
    has = info.primal_solution_status == 2
    dual = float(info.mip_dual_bound) if math.isfinite(info.mip_dual_bound) else 0.0
    bound = max(math.ceil(dual - 0.5 - 1e-7), 0) if pointing_cost is None else 0
    if not has:
        return CoverSolution(np.zeros(k, np.int64), np.full(n, -1, np.int64), math.inf, dual, bound, "timeout", int(info.mip_node_count))
    col = np.asarray(h.getSolution().col_value)
    e = np.rint(col[nx:nx + k]).astype(np.int64)
    owner = _owner(cand, n, col[:nx] * (e[np.repeat(np.arange(k), cand.sizes)] > 0))
    optimal = h.getModelStatus() == highspy.HighsModelStatus.kOptimal
    return CoverSolution(e, owner, float(info.objective_function_value), dual, bound,
                         "optimal" if optimal else "feasible", int(info.mip_node_count))


def greedy_solution(cand: Candidates, n: int, arms: int = 12, reach: ReachRows | None = None,
                    allowed: np.ndarray | None = None, pointing_cost: float | None = None) -> CoverSolution:
    """The model's greedy start (:func:`greedy_cover`) as its solution, without a search
    (status "greedy"; "timeout" when the sets leave a target no allowed entry holds): what
    :func:`solve_cover` returns for a model whose search finds nothing better in its budget."""
    k, nx = len(cand), len(cand.index)
    cap = np.full(k, float(arms))
    start = greedy_cover(cand, n, cap, allowed, reach)
    if start is None:
        return CoverSolution(np.zeros(k, np.int64), np.full(n, -1, np.int64), math.inf, 0.0, 0, "timeout", 0)
    col = _start_vector(cand, start, nx, cap, reach)
    e = np.rint(col[nx:nx + k]).astype(np.int64)
    owner = _owner(cand, n, col[:nx] * (e[np.repeat(np.arange(k), cand.sizes)] > 0))
    objective = float(e.sum() + _pointing_weight(n, pointing_cost) * np.count_nonzero(e))
    return CoverSolution(e, owner, objective, 0.0, 0, "greedy", 0)


def _pointing_weight(n: int, pointing_cost: float | None) -> float:
    """The weight of a used pointing in the objective: ``pointing_cost``, else the bound's
    ``delta = 1 / (2 (n + 1))`` (module docstring)."""
    return 1.0 / (2.0 * (n + 1)) if pointing_cost is None else float(pointing_cost)


def greedy_cover(cand: Candidates, n: int, cap: np.ndarray, allowed: np.ndarray | None = None,
                 reach: ReachRows | None = None) -> np.ndarray | None:
    """A first solution: (n,) candidate of each target the sets hold (-1: none), taking again
    and again the set whose uncovered members fill its exposures best (members per
    exposure, then more members), its exposures counted by rows (2) and (5)."""
    k = len(cand)
    col_set = np.repeat(np.arange(k), cand.sizes)
    ok = np.ones(len(cand.index), bool) if allowed is None else np.asarray(allowed, bool)
    owner = np.full(n, -1, dtype=np.int64)
    present = np.unique(cand.index)
    while np.any(owner[present] < 0):
        free = (owner[cand.index] < 0) & ok
        u = np.bincount(col_set[free], minlength=k).astype(float)
        if not u.any():
            return None
        exp = np.ceil(u / cap)
        if reach is not None and len(reach.set):
            f = np.add.reduceat(free[reach.entries].astype(float), reach.start[:-1]) if len(reach.entries) else 0
            need = np.zeros(k)
            np.maximum.at(need, reach.set, np.ceil(f / reach.cap))
            exp = np.maximum(exp, need)
        fill = np.where(u > 0, u / np.maximum(exp, 1.0), 0.0)
        j = int(np.lexsort((-u, -fill))[0])
        sel = slice(cand.start[j], cand.start[j + 1])
        m = cand.index[sel][ok[sel]]
        owner[m[owner[m] < 0]] = j
    return owner


def _start_vector(cand: Candidates, owner: np.ndarray, nx: int, cap: np.ndarray,
                  reach: ReachRows | None = None) -> np.ndarray:
    """The model's columns for an assignment ``owner`` (target -> candidate)."""
    k = len(cand)
    col_set = np.repeat(np.arange(k), cand.sizes)
    x = (owner[cand.index] == col_set).astype(float)
    load = np.bincount(col_set, weights=x, minlength=k)
    e = np.ceil(load / cap)
    if reach is not None and len(reach.entries):
        f = np.add.reduceat(x[reach.entries], reach.start[:-1])
        np.maximum.at(e, reach.set, np.ceil(f / reach.cap))
    return np.r_[x, e, (e > 0).astype(float)]


def _owner(cand: Candidates, n: int, x: np.ndarray) -> np.ndarray:
    """(n,) the candidate of each target's largest x (ties: the first)."""
    col_set = np.repeat(np.arange(len(cand)), cand.sizes)
    order = np.lexsort((col_set, -x, cand.index))
    first = np.r_[True, np.diff(cand.index[order]) != 0]
    owner = np.full(n, -1, dtype=np.int64)
    owner[cand.index[order][first]] = col_set[order][first]
    return owner
