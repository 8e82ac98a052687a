"""The staged, presolved exact solve shared by the HiGHS and CP-SAT back-ends (thesis 5.4).

The model is that of :mod:`solvers.model` (eqs. 5.13–5.16, 5.18); what this module adds is
how it is handed to an engine so that the engine can *prove* the optimum on dense fields:

1. **Incumbent** — a start solution: the caller's ``hint`` or a short depth-first dive of
   :func:`solvers.allocation.bitset.solve_bnb_chosen` (``ExactOptions.incumbent_nodes``
   nodes, as many as the ``bnb`` back-end's own search; its first dive is greedy by weight)
   on the priority/yield objective, then its exact longest-move search among the solutions
   of that weight (``INCUMBENT_MOVE_NODES`` nodes).
2. **Column pruning** (:func:`solvers.allocation.bitset.prune_columns`) against that incumbent: every
   assignment whose probing bound is below the incumbent's priority/yield weight is in no
   solution at least as good, so the model over the kept columns has the same optimum and
   the same optimal solutions.  This is a presolve for every engine, not a heuristic.
3. **Clique rows** (:mod:`solvers.allocation.cliques`) on the kept columns: valid inequalities that
   tighten the LP bound where many arms compete for a small region.
4. **Lexicographic stages**, each proven by the engine unless an exact argument settles it
   first, in the order of the thesis
   criteria (5.1, 7.3) and of :mod:`solvers.allocation.bitset`: (1) priority, then arm yield, in one
   solve with the safe integer weight ``p * (m + 1) + y``; (2) the longest move (eq. 5.16)
   with that weight fixed; (3) the optional tie-break among those, on the columns whose
   move does not exceed the stage-2 optimum.  Stage 1 decides the status (``optimal`` =
   priority and yield proven); ``stats["move_optimal"]`` and ``stats["tie_optimal"]`` say
   whether stages 2 and 3 were proven.  Folding the tie-break into the stage-1 weight, as
   a single weighted sum, makes the proof far harder (many equal-priority solutions differ
   only in the tie-break) for no gain in the criteria that matter first.
   Exact arguments spare the engine a stage: an incumbent that reaches the per-arm bound
   (the sum over arms of their best kept column) is the stage-1 optimum, and so is the
   incumbent of a dive that completed its search; the dive's completed longest-move search
   is then the stage-2 optimum (``stats["rounds"]`` and ``stats["move_proof"]`` say so).
   When stage 1 still needs the engine but less than ``ExactOptions.min_engine_s`` is left
   (a short share of a sequence), the incumbent is returned as ``feasible`` with its gap to
   the per-arm bound, and no model is built (``stats["model"]`` says why).  The later
   stages get a share of the time left (``LATER_TIER_SHARE``), so that in a sequence a
   tie-break that cannot be proven (many equal solutions) does not take the time of the
   next configurations.

Every stage answer is re-evaluated in exact integers; one that would lose anything against
the previous stage is rejected.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from models import clock
from models.budget import Budget
from solvers.allocation.bitset import prepare_field, prune_columns, solve_bnb_chosen
from solvers.allocation.cliques import CliqueOptions, clique_rows, exclusion_matrix
from solvers.effort import HighsMeter
from solvers.model import (
    ModelArrays,
    build_model_arrays,
    chosen_columns,
    coarse_weights,
    conflict_adjacency,
    safe_weights,
    stage_matrix,
    validate_problem,
)
from solvers.problem import ConfigProblem, ConfigSolution, evaluate

__all__ = ["ExactOptions", "add_clique_rows", "presolve_columns", "relaxation_bound", "solve_staged"]

StageSolver = Callable[..., tuple]

# the part of the time left that the longest-move and tie-break tiers may use (each probe of
# the move bisection counts from what is left when it starts): a hard later tier cannot take
# the whole limit, and a best-effort tie-break leaves time for the configurations after it
LATER_TIER_SHARE = {"longest_move": 0.5, "tie_break": 0.5}
# node budget of the incumbent dive's exact longest-move search
INCUMBENT_MOVE_NODES = 5000


@dataclass(frozen=True)
class ExactOptions:
    """``presolve``: incumbent + proven column pruning; ``cliques``: add clique rows;
    ``incumbent_nodes``: node budget of the incumbent dive; ``form``: conflict rows
    (``aggregated`` or ``pairwise``, see :func:`solvers.model.build_model_arrays`);
    ``move_search``: stage 2 as a bisection over move thresholds (``bisect``, see
    :func:`_bisect_move`) or as one min-max model (``native``, eq. 5.16 per arm);
    ``max_columns``: when pruning leaves more columns than this (a weak incumbent, e.g. at a
    tier transition mid-sequence), the caller's ``large`` solve runs instead (the lazy
    candidate model of solvers.allocation.lazy, which answers within short sequence limits);
    ``min_engine_s``: with an incumbent and less time left than this when stage 1 needs a
    model, the incumbent is returned as ``feasible`` (gap against the per-arm bound) without
    building one: on a dense field the model alone takes ~0.1 s per thousand columns, so an
    engine given less could not even start, and in a sequence that time is better spent on
    the configurations after it and on the repair pass; ``min_large_s``: the same for the
    ``large`` solve, which on dense fields needs a second or more to beat the incumbent."""

    presolve: bool = True
    cliques: bool = True
    incumbent_nodes: int = 4000
    form: str = "aggregated"
    move_search: str = "bisect"
    max_columns: int = 2000
    clique_options: CliqueOptions = CliqueOptions()
    min_engine_s: float = 0.3
    min_large_s: float = 1.0

    def __post_init__(self) -> None:
        if self.form not in ("aggregated", "pairwise"):
            raise ValueError(f"form must be 'aggregated' or 'pairwise', got {self.form!r}")
        if self.move_search not in ("bisect", "native"):
            raise ValueError(f"move_search must be 'bisect' or 'native', got {self.move_search!r}")
        if self.incumbent_nodes < 1:
            raise ValueError("incumbent_nodes must be >= 1")
        if not (self.min_engine_s >= 0 and self.min_large_s >= 0):
            raise ValueError("min_engine_s and min_large_s must be >= 0")


def _coarse_total(problem: ConfigProblem, chosen: np.ndarray) -> int:
    return sum(int(v) for v in coarse_weights(problem, np.asarray(chosen, np.int64)))


def _tie_total(problem: ConfigProblem, chosen: np.ndarray) -> int:
    """Sum of the tie-break over the real targets of a choice (0 without a tie-break)."""
    if problem.tie_break is None:
        return 0
    t = problem.assignments.target[np.asarray(chosen, np.int64)]
    return sum(int(v) for v in np.asarray(problem.tie_break, np.int64)[t[t >= 0]])


def presolve_columns(problem: ConfigProblem, hint: np.ndarray | None, nodes: int,
                     budget: Budget | float, defer: bool = False, min_engine_s: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """(kept columns mask, incumbent or None, stats): the incumbent (``hint`` if it is a
    valid choice, else a short branch-and-bound dive) and the proven column pruning.

    ``defer``: when the incumbent reaches the per-arm bound of the allowed columns (so stage
    1 needs no model), the pruning is left to the caller (``stats["pruned"]`` False, every
    allowed column returned): most configurations of a dense sequence then need no model
    of their stage 1 or 2 at all.  So it is when the dive proved its incumbent, or when less
    than ``min_engine_s`` is left in ``budget`` (no engine will run). ``budget`` may be a
    :func:`models.clock.now` instant (:meth:`Budget.ending_at`)."""
    if not isinstance(budget, Budget):
        budget = Budget.ending_at(budget)
    t0 = clock.now()
    f = prepare_field(problem)
    allowed = problem.allowed()
    incumbent = None
    proved = move_proved = False
    if hint is not None:
        incumbent = np.asarray(hint, np.int64)
    else:
        # with the tie-break, a search cut at its node limit gets one more pass in full-weight
        # order over the columns that can reach its incumbent (solvers.allocation.bitset), which often
        # finds the better incumbent at a tier transition
        r = solve_bnb_chosen(problem, node_limit=nodes, minimize_move=True, field=f, tie_node_limit=1000,
                             move_node_limit=INCUMBENT_MOVE_NODES,
                             budget=budget.child(0.2 * problem.time_limit_s))
        if r["chosen"] is not None:
            incumbent = np.asarray(r["chosen"], np.int64)
            # when the dive's exact longest-move search completed, its longest move is the
            # minimum among the solutions of its coarse weight (solvers.allocation.bitset)
            move_proved = bool(r["move_proved"])
            proved = bool(r["proved"])
    stats = {"incumbent_s": clock.now() - t0, "incumbent_proved": proved, "incumbent_move_proved": move_proved}
    if incumbent is None:
        return allowed, None, stats
    inc_c = _coarse_total(problem, incumbent)
    stats.update(incumbent_coarse=inc_c, columns_allowed=int(allowed.sum()), pruned=True)
    if defer and (proved or budget.left_s() < min_engine_s or inc_c >= _kept_arm_bound(problem, allowed)):
        stats.update(pruned=False, columns=int(allowed.sum()))
        return allowed, incumbent, stats
    tp = clock.now()
    cols = prune_columns(problem, inc_c, f) & allowed
    cols[incumbent] = True
    stats.update(prune_s=clock.now() - tp, columns=int(cols.sum()))
    return cols, incumbent, stats


def add_clique_rows(problem: ConfigProblem, m: ModelArrays, options: CliqueOptions | None = None
                    ) -> tuple[ModelArrays, int]:
    """``m`` with clique rows appended to its ``<= 1`` rows (and how many were added)."""
    options = options or CliqueOptions()
    a = problem.assignments
    real = np.flatnonzero(m.var >= 0)
    if not len(real) or len(real) > options.max_columns:
        return m, 0
    cols = m.var[real]
    ex = exclusion_matrix(conflict_adjacency(problem.incompatibility), cols, m.arm_of[real], a.target[cols])
    xy = np.column_stack([a.x_mm[cols], a.y_mm[cols]])
    indptr, indices = clique_rows(ex, xy, options, seed_order=np.argsort(-m.weight[real], kind="stable"))
    if len(indptr) == 1:
        return m, 0
    le_indptr = np.r_[m.le_indptr, m.le_indptr[-1] + indptr[1:]].astype(np.int64)
    le_indices = np.r_[m.le_indices, real[indices]].astype(np.int64)
    return dataclasses.replace(m, le_indptr=le_indptr, le_indices=le_indices), len(indptr) - 1


def _restrict(m: ModelArrays, keep: np.ndarray) -> ModelArrays:
    """``m`` on the columns ``keep`` (bool over its columns): eq. 5.13 rows stay one per arm,
    ``<= 1`` rows keep their surviving members and are dropped below two."""
    new = np.full(m.n_vars, -1, np.int64)
    new[keep] = np.arange(int(keep.sum()))

    def csr(indptr, indices, min_len):
        r = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        c = new[indices]
        ok = c >= 0
        r, c = r[ok], c[ok]
        sizes = np.bincount(r, minlength=len(indptr) - 1)
        row_ok = sizes >= min_len
        sel = row_ok[r]
        return np.r_[0, np.cumsum(sizes[row_ok])].astype(np.int64), c[sel].astype(np.int64), row_ok

    eq_indptr, eq_indices, _ = csr(m.eq_indptr, m.eq_indices, 0)
    le_indptr, le_indices, row_ok = csr(m.le_indptr, m.le_indices, 2)
    return dataclasses.replace(m, var=m.var[keep], arm_of=m.arm_of[keep], weight=m.weight[keep],
                               move_s=m.move_s[keep], eq_indptr=eq_indptr, eq_indices=eq_indices,
                               le_indptr=le_indptr, le_indices=le_indices,
                               n_target_rows=int(row_ok[:m.n_target_rows].sum()))


def _arm_bound(m: ModelArrays) -> int:
    """Sum over arms of the best weight among the arm's columns: the trivial upper bound."""
    best = np.zeros(len(m.eq_indptr) - 1, np.int64)
    np.maximum.at(best, m.arm_of, m.weight)
    return sum(int(v) for v in best)


def build_exact_model(problem: ConfigProblem, columns: np.ndarray, options: ExactOptions,
                      incumbent_coarse: int | None = None) -> tuple[ModelArrays, dict]:
    """The stage-1 model over ``columns`` (bool over assignments): safe *coarse* weights,
    optional clique rows — not when ``incumbent_coarse`` already meets the per-arm bound
    (the LP bound cannot be tighter than that, and the engine proves it at the root).
    Returns (model, stats)."""
    t0 = clock.now()
    m = build_model_arrays(problem, options.form, np.asarray(columns, bool), wildcards=False)
    m = dataclasses.replace(m, weight=coarse_weights(problem, m.var))
    n_cliques = 0
    if options.cliques and (incumbent_coarse is None or incumbent_coarse < _arm_bound(m)):
        m, n_cliques = add_clique_rows(problem, m, options.clique_options)
    return m, {"n_vars": m.n_vars, "n_rows": m.n_rows, "nnz": m.nnz, "clique_rows": n_cliques,
               "model_build_s": clock.now() - t0}


def relaxation_bound(problem: ConfigProblem, m: ModelArrays) -> float:
    """Optimum of the LP relaxation of the stage-1 model ``m`` (HiGHS simplex): an upper
    bound on the priority/yield weight; the tighter the rows, the closer to the optimum."""
    import highspy

    A, lo, hi, cost, _, _ = stage_matrix(m, 1, None)
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("random_seed", int(problem.seed))
    n = len(cost)
    h.addVars(n, np.zeros(n), np.ones(n))
    h.changeColsCost(n, np.arange(n, dtype=np.int32), cost)
    h.addRows(A.shape[0], lo, hi, len(A.data), A.indptr[:-1].astype(np.int32), A.indices.astype(np.int32),
              A.data.astype(float))
    h.changeObjectiveSense(highspy.ObjSense.kMaximize)
    meter = HighsMeter(nnz=len(A.data))
    h.run()
    meter.finish(h.getInfo())
    return float(h.getInfo().objective_function_value)


def _valid_hint(problem: ConfigProblem, hint) -> np.ndarray | None:
    n_arms = len(problem.assignments.arm_start) - 1
    if hint is None or np.shape(hint) != (n_arms,):
        return None
    h = np.asarray(hint, np.int64)
    if (h < 0).any() or not problem.allowed()[h].all() or not np.array_equal(problem.assignments.arm[h],
                                                                              np.arange(n_arms)):
        return None
    return h


def _bisect_move(problem: ConfigProblem, m: ModelArrays, run, chosen: np.ndarray, w1: int, stats: dict) -> np.ndarray:
    """Stage 2 as a bisection over the distinct move times below the current longest move:
    a threshold L is feasible iff the priority/yield optimum ``w1`` is still reached with
    every column of move > L removed.  Each probe first prunes the columns exactly against
    ``w1`` (:func:`solvers.allocation.bitset.prune_columns`; an arm left without a column proves the
    threshold infeasible with no engine call), then asks the engine for the stage-1 optimum
    of what is left.  ``stats["move_optimal"]`` is True when every probe was decided."""
    f = prepare_field(problem)
    longest = evaluate(problem, chosen)[2]
    vals = np.unique(m.move_s[(m.move_s < longest - 1e-9) & (m.var >= 0)])
    real = m.var >= 0
    lo, hi = 0, len(vals)  # vals[hi] (or the current longest when hi == len) is feasible
    proven, probes = True, 0
    while lo < hi:
        mid = (lo + hi) // 2
        probes += 1
        mask = np.zeros(len(problem.assignments), bool)
        mask[m.var[real & (m.move_s <= vals[mid] + 1e-9)]] = True
        mask &= problem.allowed()
        kept = prune_columns(problem, w1, f, allowed=mask) & mask
        keep = np.zeros(m.n_vars, bool)
        keep[real] = kept[m.var[real]]
        if not np.all(np.bincount(m.arm_of[keep], minlength=len(m.eq_indptr) - 1) > 0):
            lo = mid + 1
            continue
        status, c, _ = run(_restrict(m, keep), 1, None, None, "longest_move")
        if c is not None and _coarse_total(problem, c) >= w1:
            chosen = c
            hi = int(np.searchsorted(vals, evaluate(problem, c)[2] - 1e-9))
        elif status in ("optimal", "infeasible"):
            lo = mid + 1
        else:
            proven = False
            break
    stats.update(move_optimal=proven, move_probes=probes)
    return chosen


def _kept_arm_bound(problem: ConfigProblem, cols: np.ndarray) -> int:
    """Sum over arms of the best coarse weight among the kept columns ``cols`` (bool over
    assignments): the trivial upper bound of stage 1 (:func:`_arm_bound` without a model)."""
    idx = np.flatnonzero(cols)
    w = np.asarray(coarse_weights(problem, idx), np.int64)
    best = np.zeros(len(problem.assignments.arm_start) - 1, np.int64)
    np.maximum.at(best, problem.assignments.arm[idx], w)
    return sum(int(v) for v in best)


class _StageModels:
    """The stage models of one solve, built when a stage first needs the engine: the stage-1
    model over the kept columns (:func:`build_exact_model`) and the tie-break model over the
    columns no longer than the stage-2 longest move.  When the exact arguments of stages 1
    and 2 spare the engine, the tie-break model is built from the columns directly (fewer
    columns, no clique rows) and the full model never is."""

    def __init__(self, problem: ConfigProblem, cols: np.ndarray, options: ExactOptions,
                 incumbent_coarse: int | None, stats: dict) -> None:
        self.problem, self.cols, self.options = problem, cols, options
        self.incumbent_coarse, self.stats = incumbent_coarse, stats
        self._full: ModelArrays | None = None

    def full(self) -> ModelArrays:
        if self._full is None:
            if not self.stats.get("pruned", True):  # deferred by presolve_columns: prune now
                tp = clock.now()
                self.cols = self.cols & prune_columns(self.problem, self.incumbent_coarse, prepare_field(self.problem))
                self.stats.update(pruned=True, prune_s=clock.now() - tp, columns=int(self.cols.sum()))
            self._full, s = build_exact_model(self.problem, self.cols, self.options, self.incumbent_coarse)
            self.stats.update(s)
        return self._full

    def tie_break(self, chosen: np.ndarray, w1: int, longest_s: float | None) -> ModelArrays:
        """The stage-3 model (full safe weights) on the kept columns with move <= ``longest_s``
        (None: every kept column) that can reach the stage-1 optimum ``w1``, ``chosen`` included."""
        p = self.problem
        if self._full is not None:
            m = self._full
            keep = (m.move_s <= longest_s + 1e-9) if longest_s is not None else np.ones(m.n_vars, bool)
            m3 = _restrict(m, keep | np.isin(m.var, chosen))
        else:
            cols = self.cols & p.allowed()
            if longest_s is not None:
                cols &= p.move_time_s() <= longest_s + 1e-9
            if not self.stats.get("pruned", True):
                cols &= prune_columns(p, w1, prepare_field(p), allowed=cols)
            cols[chosen] = True
            m3 = build_model_arrays(p, self.options.form, cols, wildcards=False)
        return dataclasses.replace(m3, weight=safe_weights(p, m3.var)[0])


def _stage2(problem: ConfigProblem, m: ModelArrays, run, chosen: np.ndarray, w1: int, options: ExactOptions,
            stats: dict) -> np.ndarray:
    """Stage 2 with the engine: the move bisection (:func:`_bisect_move`) or one min-max model."""
    if options.move_search == "bisect":
        return _bisect_move(problem, m, run, chosen, w1, stats)
    s2, c2, _ = run(m, 2, w1, chosen, "longest_move")
    if c2 is not None and _coarse_total(problem, c2) >= w1 and evaluate(problem, c2)[2] <= evaluate(problem, chosen)[2]:
        stats["move_optimal"] = s2 == "optimal"
        return c2
    if c2 is not None:
        stats["stage2_rejected"] = True
    return chosen


def _finish(problem: ConfigProblem, stats: dict, budget: Budget, chosen: np.ndarray | None, status: str,
            gap: float | None) -> ConfigSolution:
    stats["total_s"] = budget.elapsed_s()
    stats.setdefault("move_optimal", False)
    stats.setdefault("tie_optimal", False)
    if chosen is None:
        return ConfigSolution(np.full(len(problem.assignments.arm_start) - 1, -1), status, 0, 0, 0.0, None, stats)
    total, yld, longest = evaluate(problem, chosen)
    return ConfigSolution(np.asarray(chosen, np.int64), status, total, yld, longest, gap, stats)


def _keep_incumbent(problem: ConfigProblem, stats: dict, budget: Budget, incumbent: np.ndarray, cols: np.ndarray,
                    why: str) -> ConfigSolution:
    """The incumbent as ``feasible``, with its gap to the per-arm bound of ``cols``, no model built."""
    arm_bound = _kept_arm_bound(problem, cols)
    inc = _coarse_total(problem, incumbent)
    stats["model"] = why
    stats["rounds"].append({"stage": "priority_yield", "proof": None, "solve_s": 0.0})
    return _finish(problem, stats, budget, incumbent, "feasible", max(arm_bound - inc, 0) / max(inc, 1))


def _solve_large(problem: ConfigProblem, large, incumbent: np.ndarray | None, cols: np.ndarray, budget: Budget,
                 options: ExactOptions, stats: dict) -> ConfigSolution | None:
    """The ``large`` solve when pruning left more than ``options.max_columns`` columns (or the
    incumbent, when less than ``min_large_s`` is left of ``budget``, the solve's); None when
    no time is left for it."""
    rest = budget.left_s()
    if incumbent is not None and rest < options.min_large_s:
        return _keep_incumbent(problem, stats, budget, incumbent, cols,
                               f"none: {int(cols.sum())} columns, {rest:.2f} s left (min_large_s)")
    if rest <= 0.005:
        return None
    sol = large(dataclasses.replace(problem, time_limit_s=rest), incumbent)
    sol.stats.update(model="lazy", presolve_columns=int(cols.sum()))
    if incumbent is None or ((sol.chosen >= 0).all() and
                             _coarse_total(problem, sol.chosen) >= _coarse_total(problem, incumbent)):
        return sol
    stats["model"] = "lazy (its answer was below the incumbent)"
    return _finish(problem, stats, budget, incumbent, "feasible", sol.gap)


def _stage1_proof(problem: ConfigProblem, incumbent: np.ndarray | None, cols: np.ndarray, stats: dict) -> str | None:
    """The exact argument that makes ``incumbent`` the stage-1 optimum, or None: it meets the
    per-arm bound of the kept columns (the engine's root LP would only confirm it, and on
    dense fields that LP has ~700,000 non-zeros), or the dive that found it completed."""
    if incumbent is None:
        return None
    if _coarse_total(problem, incumbent) >= _kept_arm_bound(problem, cols):
        return "per-arm bound"
    if stats.get("incumbent_proved"):
        return "branch-and-bound"
    return None


def _stage3(problem: ConfigProblem, model: _StageModels, run, chosen: np.ndarray, w1: int, cols: np.ndarray,
            minimize_move: bool, stats: dict) -> np.ndarray:
    """Stage 3: the tie-break among the stage-2 solutions, on the columns no longer than the
    stage-2 longest move; an answer that loses anything of stages 1 and 2 is rejected."""
    tie = None if problem.tie_break is None else np.asarray(problem.tie_break, np.int64)
    t_cols = problem.assignments.target[np.flatnonzero(cols)]
    if tie is None or not (tie[t_cols[t_cols >= 0]] > 0).any():
        stats["tie_optimal"] = True
        return chosen
    longest = evaluate(problem, chosen)[2]
    m3 = model.tie_break(chosen, w1, longest if minimize_move else None)
    s3, c3, _ = run(m3, 1, None, chosen, "tie_break")
    if c3 is not None and _coarse_total(problem, c3) >= w1 and _tie_total(problem, c3) >= _tie_total(problem, chosen) \
            and (not minimize_move or evaluate(problem, c3)[2] <= longest + 1e-9):
        stats["tie_optimal"] = s3 == "optimal"
        return c3
    return chosen


def solve_staged(problem: ConfigProblem, stage_solver: StageSolver, *, backend: str, minimize_move: bool = True,
                 hint: np.ndarray | None = None, columns: np.ndarray | None = None,
                 options: ExactOptions = ExactOptions(),
                 large: Callable[[ConfigProblem, np.ndarray | None], ConfigSolution] | None = None
                 ) -> ConfigSolution:
    """Exact lexicographic solve (see module docstring) with an engine's stage solver
    (:func:`solvers.allocation.highs.highs_stage_solver` /
    :func:`solvers.allocation.cpsat.cpsat_stage_solver`).

    ``columns``: a column mask the caller has PROVEN to hold every solution at least as good
    as ``hint`` (used as given, no further pruning).  ``large``: see ``ExactOptions.max_columns``."""
    validate_problem(problem)
    budget = Budget.start(problem.time_limit_s)
    n_arms = len(problem.assignments.arm_start) - 1
    stats: dict = {"backend": backend, "form": options.form, "presolve": options.presolve,
                   "cliques": options.cliques, "rounds": []}
    hint = _valid_hint(problem, hint)
    if columns is not None:
        cols = np.asarray(columns, bool) & problem.allowed()
        if hint is not None:
            cols[hint] = True
        incumbent = hint
    elif options.presolve:
        cols, incumbent, s = presolve_columns(problem, hint, options.incumbent_nodes, budget, defer=True,
                                              min_engine_s=options.min_engine_s)
        stats.update(s)
    else:
        cols, incumbent = problem.allowed(), hint
    stats["hint"] = incumbent is not None

    def finish(chosen, status, gap):
        return _finish(problem, stats, budget, chosen, status, gap)

    def keep_incumbent(why: str):
        return _keep_incumbent(problem, stats, budget, incumbent, cols, why)

    if large is not None and columns is None and stats.get("pruned", True) and int(cols.sum()) > options.max_columns:
        sol = _solve_large(problem, large, incumbent, cols, budget, options, stats)
        if sol is not None:
            return sol

    if not np.all(np.bincount(problem.assignments.arm[cols], minlength=n_arms) > 0):
        return finish(None, "infeasible", None)
    model = _StageModels(problem, cols, options, None if incumbent is None else _coarse_total(problem, incumbent),
                         stats)

    def run(model: ModelArrays, stage: int, w1, start, name: str):
        remaining = budget.left_s() * LATER_TIER_SHARE.get(name, 1.0)
        if remaining <= 0.005:
            return "timeout", None, None
        status, x, gap, r = stage_solver(model, stage, w1, remaining, start)
        r.update(stage=name, n_vars=model.n_vars, n_rows=model.n_rows, nnz=model.nnz)
        stats["rounds"].append(r)
        chosen = None if x is None else model.var[chosen_columns(model, x, n_arms)]
        return status, chosen, gap

    # stage 1: priority, then yield (the safe coarse weight)
    proof = _stage1_proof(problem, incumbent, cols, stats)
    if proof is not None:
        status, chosen, gap = "optimal", incumbent, 0.0
        stats["rounds"].append({"stage": "priority_yield", "proof": proof, "solve_s": 0.0})
    elif incumbent is not None and budget.left_s() < options.min_engine_s:
        return keep_incumbent(f"none: {budget.left_s():.2f} s left (min_engine_s)")
    else:
        status, chosen, gap = run(model.full(), 1, None, incumbent, "priority_yield")
    if chosen is None or (incumbent is not None and _coarse_total(problem, incumbent) > _coarse_total(problem, chosen)):
        if status == "infeasible":
            return finish(None, "infeasible", None)
        if incumbent is None:
            return finish(None, "timeout", None)
        chosen, status = incumbent, "feasible"
    if status != "optimal":
        return finish(chosen, "feasible" if status in ("feasible", "optimal", "timeout") else status, gap)
    w1 = _coarse_total(problem, chosen)
    # stage 2: the longest move with the coarse weight fixed; an incumbent with the proven
    # coarse optimum whose dive proved its longest move minimal for that weight is the answer
    if minimize_move and stats.get("incumbent_move_proved") and _coarse_total(problem, incumbent) == w1:
        chosen = incumbent
        stats.update(move_optimal=True, move_proof="branch-and-bound")
    elif minimize_move:
        chosen = _stage2(problem, model.full(), run, chosen, w1, options, stats)
    chosen = _stage3(problem, model, run, chosen, w1, cols, minimize_move, stats)
    return finish(chosen, "optimal", None)
