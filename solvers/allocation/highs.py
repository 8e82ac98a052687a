"""The HiGHS back-end: the exact single-configuration model (thesis 5.4) on HiGHS.

Two HiGHS front-ends build the *same* arrays (:mod:`solvers.model`): ``interface="pyomo"``
(the documented, readable model, solved through Pyomo's APPSI HiGHS interface) and
``interface="highspy"`` (the same matrix passed to highspy in one call — the hot path;
Pyomo expression building costs seconds at 10^5 non-zeros).  HiGHS works in doubles with
feasibility tolerances, so every answer is re-evaluated in exact integers by the callers
(:mod:`solvers.allocation.exact`, :mod:`solvers.allocation.lazy`).
"""

from __future__ import annotations

import numpy as np

from models import clock
from solvers.allocation.backends import Backend, note_incumbent
from solvers.allocation.exact import ExactOptions, solve_staged
from solvers.allocation.lazy import lazy_solve
from solvers.allocation.options import ENGINE_SEQUENCING, HighsOptions
from solvers.effort import HighsMeter, interrupt_at
from solvers.model import ModelArrays, hint_vector, stage_matrix
from solvers.problem import ConfigProblem, ConfigSolution

__all__ = ["BACKEND", "highs_stage_solver", "interrupt_at", "solve_ilp_highs"]


def highs_stage_solver(problem: ConfigProblem, interface: str, highs_presolve: str = "choose"):
    """A stage solver over HiGHS: ``solve(model, stage, w1, time_limit_s, hint)`` returning
    ``(status, x, gap, stats)``.  ``highs_presolve``: HiGHS' own presolve ("choose", "off"
    or "auto" = "off").  Off by default: after the column pruning and clique rows of
    solvers.allocation.exact it mostly costs time, and it polls neither ``time_limit`` nor the
    interrupt callbacks, so on dense models (~700,000 non-zeros, mid-sequence at 1,200
    targets) it ran tens of seconds past a 5 s limit; without it the root LP and the search
    stop at the deadline (:func:`interrupt_at`)."""
    def solve(m: ModelArrays, stage: int, w1, time_limit_s: float, hint=None):
        A, row_lo, row_hi, cost, integer, sense_max = stage_matrix(m, stage, w1)
        col_hi = np.where(integer, 1.0, np.inf)
        if interface == "pyomo":
            return _pyomo_solve(A, row_lo, row_hi, col_hi, integer, cost, sense_max, problem, time_limit_s)
        start = hint_vector(m, hint)
        if start is not None and stage == 2:
            start = np.r_[start, float(np.max(m.move_s[start > 0.5], initial=0.0))]
        pre = "off" if highs_presolve == "auto" else highs_presolve
        return _highspy_solve(A, row_lo, row_hi, col_hi, integer, cost, sense_max, problem, time_limit_s, start, pre)
    return solve


def _highspy_solve(A, row_lo, row_hi, col_hi, integer, cost, sense_max, problem, time_limit_s, start=None,
                   presolve: str = "choose"):
    import highspy

    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("presolve", presolve)
    meter = HighsMeter(nnz=len(A.data))
    # in effort mode HiGHS' own limit is the wall-clock guard; the callback stops the run
    wall_s = float(time_limit_s) if meter.effort is None else meter.wall_guard_s(time_limit_s)
    h.setOptionValue("time_limit", wall_s)
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
    t0 = meter.now()
    interrupted = interrupt_at(h, t0 + float(time_limit_s), meter)
    h.run()
    info = h.getInfo()
    meter.finish(info)
    solve_s = meter.now() - t0
    ms = h.getModelStatus()
    has_sol = info.primal_solution_status == 2  # kSolutionStatusFeasible
    x = np.asarray(h.getSolution().col_value) if has_sol else None
    gap = float(info.mip_gap) if has_sol else None
    if ms == highspy.HighsModelStatus.kOptimal:
        status = "optimal" if (problem.mip_rel_gap == 0 or (gap is not None and gap <= 1e-12)) else "feasible"
    elif ms == highspy.HighsModelStatus.kInfeasible:
        status = "infeasible"
    else:
        status = "feasible" if has_sol else "timeout"
    return status, x, gap, {"solve_s": solve_s, "solver_status": str(ms), "nodes": int(info.mip_node_count),
                            "interrupted": bool(interrupted[0])}


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
    t0 = clock.now()
    res = opt.solve(model)
    solve_s = clock.now() - t0
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
    ``staged`` (default): :func:`solvers.allocation.exact.solve_staged` — incumbent, proven column
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
        def large(p: ConfigProblem, start) -> ConfigSolution:
            return lazy_solve(p, highs_stage_solver(p, interface, highs_presolve), form=form, minimize_move=minimize_move,
                               candidates_per_arm=candidates_per_arm, backend=f"highs/{interface}", hint=start)

        return solve_staged(problem, highs_stage_solver(problem, interface, highs_presolve), backend=f"highs/{interface}",
                            minimize_move=minimize_move, hint=hint, columns=columns,
                            options=ExactOptions(presolve=presolve, cliques=cliques, form=form), large=large)
    return lazy_solve(problem, highs_stage_solver(problem, interface, highs_presolve), form=form, minimize_move=minimize_move,
                       candidates_per_arm=candidates_per_arm, backend=f"highs/{interface}", hint=hint,
                       columns=columns)


def _solve(problem: ConfigProblem, options: HighsOptions, *, hint: np.ndarray | None = None,
           columns: np.ndarray | None = None) -> ConfigSolution:
    sol = solve_ilp_highs(problem, form=options.form, interface=options.interface,
                          minimize_move=options.minimize_move, candidates_per_arm=options.candidates_per_arm,
                          hint=hint, columns=columns)
    return note_incumbent(sol, hint)


BACKEND = Backend(name="highs", method="ilp", options_type=HighsOptions, solve=_solve, exact=True,
                  rescue="highs", description="highs", sequencing=ENGINE_SEQUENCING)
