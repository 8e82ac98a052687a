"""The ``bnb`` back-end: exact bitset branch-and-bound for one configuration, CP-SAT for hard proofs.

The search itself is :mod:`solvers.allocation.bitset`; this module is the back-end around
it: node budgets per lexicographic stage, the optional semi-greedy incumbent, and the
CP-SAT fallback (through the back-end registry, :mod:`solvers.allocation.backends`) when
stage 1 is not proven within the node limit.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from models import clock
from models.budget import Budget
from solvers.allocation.backends import Backend, get_backend
from solvers.allocation.bitset import prepare_field, prune_columns, solve_bnb_chosen
from solvers.allocation.options import BnbOptions, CpsatOptions, SemiGreedyOptions
from solvers.model import exact_weight, greedy_solution, validate_problem
from solvers.problem import ConfigProblem, ConfigSolution, evaluate

__all__ = ["BACKEND", "WARM_START_ITERATIONS", "solve_ilp_bnb"]

WARM_START_ITERATIONS = 5  # the semi-greedy incumbent: a short multistart, the search improves on it


def solve_ilp_bnb(problem: ConfigProblem, *, node_limit: int = 4_000, minimize_move: bool = True,
                  fallback: str | None = "cpsat", hint: str | None = None, tie_node_limit: int = 2_000,
                  move_node_limit: int = 5_000, fallback_min_s: float = 2.0) -> ConfigSolution:
    """Exact allocation of one configuration: bitset branch-and-bound, CP-SAT for hard proofs.

    Lexicographic: priority, then arm yield (stage 1, proven → status ``optimal``), then
    the longest move (``stats["move_optimal"]``), then the optional tie-break
    (``stats["tie_optimal"]``) — stages 2 and 3 are exact searches with node budgets.
    When stage 1 is not proven within ``node_limit`` nodes (tier transitions where
    collisions decide the optimum and the per-arm bound is weak), ``fallback="cpsat"``
    solves the problem with CP-SAT on the priority/yield objective (then its exact stage 2
    for the longest move), hinted with the incumbent; the tie-break is then not applied.  ``fallback=None``:
    the incumbent is returned as ``feasible`` with a gap against the root bound.
    ``hint="semigreedy"`` seeds the incumbent with a short semi-greedy multistart.
    The fallback runs only when the problem's time limit is >= ``fallback_min_s``: on a
    dense field the CP-SAT model alone takes ~0.5-1.5 s to build (4 M conflict entries), so
    under a tight per-configuration budget it cannot finish and only starves the later
    configurations; the node-limited incumbent is then returned as ``feasible`` + gap.
    """
    validate_problem(problem)
    budget = Budget.start(problem.time_limit_s)
    if problem.time_limit_s < fallback_min_s:
        fallback = None
    n_arms = len(problem.assignments.arm_start) - 1
    f = prepare_field(problem)
    stats: dict = {"backend": "bnb", "prepare_s": budget.elapsed_s()}
    h = None
    if hint == "semigreedy":
        sg = get_backend("semigreedy").solve(problem, SemiGreedyOptions(n_iter=WARM_START_ITERATIONS))
        h = np.asarray(sg.chosen, dtype=np.int64)
    kw = dict(minimize_move=minimize_move, hint=h, field=f, tie_node_limit=tie_node_limit,
              move_node_limit=move_node_limit)
    r = solve_bnb_chosen(problem, node_limit=node_limit, budget=budget.part(0.3 if fallback else 1.0), **kw)
    stats["nodes"] = r["nodes"]
    if not r["proved"] and fallback == "cpsat" and budget.left_s() > 0.05:
        # CP-SAT on priority / yield (then its own exact stage 2 for the longest move), hinted
        cols = None
        if r["chosen"] is not None:
            # exact column fixing against the incumbent: the CP-SAT model shrinks to the
            # assignments that can still reach the incumbent's priority/yield
            tp = clock.now()
            inc_c = sum(f.coarse[k][int(f.pos[r["chosen"][k]])] for k in range(n_arms))
            cols = prune_columns(problem, inc_c, f)
            cols[np.asarray(r["chosen"], np.int64)] = True
            stats.update(prune_s=clock.now() - tp, columns=int(cols.sum()),
                         columns_allowed=int(problem.allowed().sum()))
        coarse = dataclasses.replace(problem, tie_break=None, time_limit_s=max(budget.left_s(), 0.05))
        sol = get_backend("cpsat").solve(coarse, CpsatOptions(minimize_move=minimize_move, candidates_per_arm=None),
                                         hint=r["chosen"], columns=cols)
        stats.update(backend="bnb+cpsat", cpsat_s=sol.stats.get("total_s"), cpsat_status=sol.status)
        if sol.status in ("optimal", "feasible") and (
                r["chosen"] is None or sol.status == "optimal"
                or exact_weight(coarse, sol.chosen) > exact_weight(coarse, r["chosen"])):
            r = {**r, "chosen": sol.chosen, "proved": sol.status == "optimal",
                 "move_proved": bool(sol.stats.get("move_optimal")), "tie_proved": False}
        elif sol.status == "infeasible":
            r = {**r, "chosen": None, "proved": True}
    if r["chosen"] is None and not r["proved"]:
        g = greedy_solution(problem)  # limit hit before any incumbent: the quick greedy choice
        if g is not None:
            r = {**r, "chosen": g}
            stats["fallback"] = "greedy"
    stats.update(move_optimal=bool(r["move_proved"]), tie_optimal=bool(r["tie_proved"]),
                 total_s=budget.elapsed_s())
    if r["chosen"] is None:
        return ConfigSolution(np.full(n_arms, -1), "infeasible" if r["proved"] else "timeout", 0, 0, 0.0, None, stats)
    total, yld, longest = evaluate(problem, r["chosen"])
    if r["proved"]:
        return ConfigSolution(r["chosen"], "optimal", total, yld, longest, None, stats)
    w = exact_weight(problem, r["chosen"])
    return ConfigSolution(r["chosen"], "feasible", total, yld, longest, max(r["bound"] - w, 0) / max(w, 1), stats)


def _solve(problem: ConfigProblem, options: BnbOptions, *, hint: np.ndarray | None = None,
           columns: np.ndarray | None = None) -> ConfigSolution:
    """The registry entry; ``hint`` and ``columns`` (exact-model inputs) do not apply."""
    return solve_ilp_bnb(problem, node_limit=options.node_limit, minimize_move=options.minimize_move,
                         fallback=options.fallback, hint=options.hint, tie_node_limit=options.tie_node_limit,
                         move_node_limit=options.move_node_limit, fallback_min_s=options.fallback_min_s)


BACKEND = Backend(name="bnb", method="ilp", options_type=BnbOptions, solve=_solve, exact=True, rescue="cpsat",
                  description="bnb (cpsat for proofs past its node limit)")
