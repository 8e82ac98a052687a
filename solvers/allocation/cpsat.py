"""The CP-SAT back-end: the exact single-configuration model (thesis 5.4) on OR-Tools CP-SAT.

The arrays of :mod:`solvers.model` become at-most-one / exactly-one constraints, which
CP-SAT handles natively, over exact int64 weights; the longest move (eq. 5.16) is in
integer microseconds.
"""

from __future__ import annotations

import numpy as np

from models import clock
from solvers.allocation.backends import Backend, note_incumbent
from solvers.allocation.exact import ExactOptions, solve_staged
from solvers.allocation.lazy import lazy_solve
from solvers.allocation.options import ENGINE_SEQUENCING, CpsatOptions
from solvers.effort import charge_literals, cpsat_solve
from solvers.model import ModelArrays, hint_vector
from solvers.problem import ConfigProblem, ConfigSolution

__all__ = ["BACKEND", "MOVE_TICKS_PER_S", "cpsat_stage_solver", "solve_ilp_cpsat"]

MOVE_TICKS_PER_S = 1_000_000  # CP-SAT works in integer microseconds for x_l
MIN_WORKERS = 2  # one worker stalled on an 800-target instance: always at least two


def cpsat_stage_solver(problem: ConfigProblem, workers: int | None, linearization_level: int):
    from ortools.sat.python import cp_model

    def solve(m: ModelArrays, stage: int, w1, time_limit_s: float, hint=None):
        t0 = clock.now()
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
        if start is not None:  # a complete hint: every variable (x_l too), never a partial one
            for j in range(m.n_vars):
                model.AddHint(x[j], bool(start[j]))
            if stage != 1:
                model.AddHint(xl, int(ticks[start > 0.5].max(initial=0)))
        # the Python loops above: one literal per column, row member and hint (twice in stage 2)
        charge_literals(m.n_vars * (2 if start is not None else 1) + len(m.eq_indices) + len(m.le_indices)
                        + (0 if stage == 1 else 2 * m.n_vars))
        build_s = clock.now() - t0
        solver = cp_model.CpSolver()
        p = solver.parameters
        p.num_workers = max(MIN_WORKERS, int(workers if workers is not None else problem.threads))
        p.random_seed = int(problem.seed)
        p.linearization_level = int(linearization_level)
        p.relative_gap_limit = float(problem.mip_rel_gap)
        code = cpsat_solve(solver, model, max(time_limit_s, 0.001))
        s = {"solve_s": clock.now() - t0 - build_s, "cp_build_s": build_s,
             "solver_status": solver.StatusName(code), "branches": int(solver.NumBranches()),
             "workers": int(p.num_workers)}
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
    choice (assignment index per arm, e.g. the semi-greedy warm start or the
    branch-and-bound incumbent) given to CP-SAT as a solution hint.  ``staged``,
    ``presolve``, ``cliques``, ``columns``: as in :func:`solve_ilp_highs`.
    """
    if staged:
        def large(p: ConfigProblem, start) -> ConfigSolution:
            return lazy_solve(p, cpsat_stage_solver(p, workers, linearization_level), form=form,
                               minimize_move=minimize_move, candidates_per_arm=candidates_per_arm, backend="cpsat",
                               hint=start)

        return solve_staged(problem, cpsat_stage_solver(problem, workers, linearization_level), backend="cpsat",
                            minimize_move=minimize_move, hint=hint, columns=columns,
                            options=ExactOptions(presolve=presolve, cliques=cliques, form=form), large=large)
    return lazy_solve(problem, cpsat_stage_solver(problem, workers, linearization_level), form=form,
                       minimize_move=minimize_move, candidates_per_arm=candidates_per_arm, backend="cpsat",
                       hint=hint, columns=columns)


def _solve(problem: ConfigProblem, options: CpsatOptions, *, hint: np.ndarray | None = None,
           columns: np.ndarray | None = None) -> ConfigSolution:
    sol = solve_ilp_cpsat(problem, form=options.form, workers=options.workers,
                          linearization_level=options.linearization_level, minimize_move=options.minimize_move,
                          candidates_per_arm=options.candidates_per_arm, hint=hint, columns=columns)
    return note_incumbent(sol, hint)


BACKEND = Backend(name="cpsat", method="ilp", options_type=CpsatOptions, solve=_solve, exact=True,
                  rescue="cpsat", description="cpsat", sequencing=ENGINE_SEQUENCING)
