"""The lexicographic lazy candidate loop shared by the HiGHS and CP-SAT back-ends (thesis 5.4).

Each arm starts with its best few candidate assignments plus one *wildcard* column (see
:func:`solvers.model.build_model_arrays`); a relaxation optimum that uses a wildcard
expands the candidates of its arms and is re-solved.  The engine is a *stage solver*
``solve(model, stage, w1, time_limit_s, hint) -> (status, x, gap, stats)``
(:func:`solvers.allocation.highs.highs_stage_solver`,
:func:`solvers.allocation.cpsat.cpsat_stage_solver`).
"""

from __future__ import annotations

import numpy as np

from models import clock
from models.budget import Budget
from solvers.model import (
    build_model_arrays,
    chosen_columns,
    close_over_targets,
    exact_weight,
    expand_candidates,
    greedy_solution,
    initial_candidates,
    validate_problem,
)
from solvers.problem import ConfigProblem, ConfigSolution, evaluate

__all__ = ["MAX_STAGE2_ROUNDS", "lazy_solve"]

MAX_STAGE2_ROUNDS = 3  # candidate expansions of the move stage before its answer is taken as is


def lazy_solve(problem: ConfigProblem, solve_arrays, *, form: str, minimize_move: bool,
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
    every solution at least as good as its hint (solvers.allocation.bitset.prune_columns); the model is
    restricted to them without wildcards (no lazy expansion) and remains exact.
    """
    validate_problem(problem)
    budget = Budget.start(problem.time_limit_s)
    a = problem.assignments
    n_arms = len(a.arm_start) - 1
    stats: dict = {"backend": backend, "form": form, "rounds": []}
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
            cand = close_over_targets(problem, cand)
    stats["hint"] = hint is not None

    def finish(chosen, status, gap):
        stats["total_s"] = budget.elapsed_s()
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
        tb = clock.now()
        rounds1 += stage == 1
        if stage == 1 and cand is not None and (rounds1 > max_rounds or budget.elapsed_s()
                                                  > 0.4 * problem.time_limit_s):
            # the relaxation keeps asking for more candidates (dense, collision-bound fields):
            # solve the restricted model without wildcards — feasible for the full problem,
            # not proven optimal; the last relaxation optimum bounds the gap honestly
            m = build_model_arrays(problem, form, cand, wildcards=False)
            remaining = budget.left_s()
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
        build_s = clock.now() - tb
        if (m.eq_indptr[1:] == m.eq_indptr[:-1]).any():
            return finish(None, "infeasible", None)
        remaining = budget.left_s()
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
            cand = expand_candidates(problem, cand, np.flatnonzero(wild), step)
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
