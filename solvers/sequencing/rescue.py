"""The conflict rescue: configurations for targets no configuration of the main structure can take."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

import solvers.effort  # noqa: F401  (prices the work of the incompatibility structure)
from models import clock
from models.budget import Budget
from models.incompatibility import incompatibility_for_targets
from models.types import Configuration
from solvers.problem import ConfigProblem, ConfigSolution
from solvers.sequencing.shares import SHARES
from solvers.sequencing.state import make_configuration, verify

__all__ = ["default_exact_one", "rescue_conflicts"]


def default_exact_one() -> Callable[[ConfigProblem], ConfigSolution]:
    """CP-SAT on the full model without the move stage: the rescue's one-target solve when
    the caller names none (the registry is asked at call time; sequencing imports no engine)."""
    from solvers.allocation.backends import get_backend
    from solvers.allocation.options import CpsatOptions

    return get_backend("cpsat").solver(CpsatOptions(minimize_move=False, candidates_per_arm=None))


def rescue_conflicts(instrument, targets, priority, left, done, q, solve_one, fixed, buffer_mm, speeds,
                      first_index, budget: Budget, config_time_limit_s, threads, seed, max_configs,
                      n_fill: int = SHARES.rescue_fill_targets,
                      blank_per_arm: int = SHARES.rescue_blank_per_arm,
                      exact_one: Callable[[ConfigProblem], ConfigSolution] | None = None,
                      park_move_limit_s: float | None = None,
                      locks: dict[int, tuple[int, int | None]] | None = None) -> list[Configuration]:
    """Configurations for targets no configuration of the main structure can take.

    Their only reaching arms collide with a neighbour's park (the park spot of an arm sits
    inside the FOV ring), and park is the only rest location of the main model.  Here the
    structure is rebuilt for the leftovers plus the ``n_fill`` nearest already observed
    targets at priority 0: an idle arm may rest on one of those (reported as kind
    ``"blank"``: it points at sky already observed) or on ``blank_per_arm`` sampled
    blank-sky locations, and so make room.  Exact per
    configuration like the main loop (same back-end, verified); stops when a configuration
    takes no leftover target.  When a joint configuration takes none, each leftover target
    is tried alone with ``exact_one`` (the chosen engine's exact solve; default CP-SAT).
    ``park_move_limit_s`` limits the rest locations as it does the main structure's, and
    ``locks`` (field target index -> (arm, branch or None)) keep a locked leftover on its arm. Each
    solve gets at most ``config_time_limit_s`` of what is left of ``budget``; none starts
    with ``SHARES.min_solve_s`` or less left.
    """
    if exact_one is None:
        exact_one = default_exact_one()

    x = np.asarray(targets.x_mm, float)
    y = np.asarray(targets.y_mm, float)
    fill = np.flatnonzero(done)
    if len(fill):
        d = np.min(np.hypot(x[fill, None] - x[None, left], y[fill, None] - y[None, left]), axis=1)
        fill = fill[np.argsort(d, kind="stable")[:max(n_fill, 2 * len(left))]]
    sub = np.r_[left, fill].astype(np.int64)
    nl = len(left)
    inc = incompatibility_for_targets(instrument, x[sub], y[sub], buffer_mm=buffer_mm, fixed=fixed,
                                      blank_per_arm=blank_per_arm, seed=seed, park_move_limit_s=park_move_limit_s,
                                      locks={j: locks[int(t)] for j, t in enumerate(left) if int(t) in (locks or {})})
    pr = np.r_[priority[left], np.zeros(len(fill), np.int64)]
    pend = np.zeros(len(sub), bool)
    pend[:nl] = True
    pend[:nl] &= inc.reachability.arms_per_target[:nl] > 0
    xy = np.column_stack([x[sub], y[sub]])
    sub_targets = targets.subset(sub)
    out: list[Configuration] = []
    while pend[:nl].any() and (max_configs is None or len(out) < max_configs):
        remaining = budget.left_s()
        if remaining <= SHARES.min_solve_s:
            break
        avail = pend.copy()
        avail[nl:] = True
        prob = ConfigProblem(inc, pr, avail, q, speeds, time_limit_s=min(config_time_limit_s, remaining),
                             threads=threads, seed=seed + first_index + len(out), target_xy_mm=xy)
        ts = clock.now()
        sol = solve_one(prob)
        dt = clock.now() - ts
        if sol.status in ("timeout", "infeasible") or (sol.chosen < 0).any():
            break
        verify(instrument, prob, sol.chosen)
        tg = prob.assignments.target[sol.chosen]
        real = tg[(tg >= 0) & (tg < nl)]
        if not len(real):
            # nothing jointly: one leftover target at a time, by an exact ILP engine (a
            # node-limited branch-and-bound wanders in the zero-weight rest placements and
            # may miss it)
            one = _one_target_at_a_time(instrument, prob, pend, nl, budget, config_time_limit_s, exact_one)
            if one is None:
                break
            prob, sol, real = one
        pend[real] = False
        c = make_configuration(first_index + len(out), prob, sol.chosen, sub_targets, sol.status,
                               {"solve_s": dt, "status": sol.status, "gap": sol.gap,
                                "longest_move_s": sol.longest_move_s, "rescue": True})
        out.append(_in_field_indices(c, sub, nl, len(real)))
        q = prob.assignments.q[sol.chosen]
    return out


def _one_target_at_a_time(instrument, prob: ConfigProblem, pend: np.ndarray, nl: int, budget: Budget,
                          config_time_limit_s: float, exact_one: Callable[[ConfigProblem], ConfigSolution]):
    """The first leftover target (of the ``nl`` leading ones still ``pend``-ing) that an exact
    solve can place alone: (problem, solution, leftover targets observed), or None."""
    for i in np.flatnonzero(pend[:nl]):
        if budget.left_s() <= SHARES.min_solve_s:
            break
        av1 = np.zeros(len(pend), bool)
        av1[i] = True
        av1[nl:] = True
        p1 = dataclasses.replace(prob, available=av1, time_limit_s=min(config_time_limit_s,
                                                                      budget.left_s()))
        s1 = exact_one(p1)  # exact, small
        if s1.status in ("optimal", "feasible") and (s1.chosen >= 0).all() and \
                i in p1.assignments.target[s1.chosen]:
            verify(instrument, p1, s1.chosen)
            tg = p1.assignments.target[s1.chosen]
            real = tg[(tg >= 0) & (tg < nl)]
            if len(real):
                return p1, s1, real
            return None
    return None


def _in_field_indices(c: Configuration, sub: np.ndarray, nl: int, n_real: int) -> Configuration:
    """A rescue configuration in the field's target indices: an arm resting on an already
    observed target (index >= ``nl`` in the rescue structure) is kind ``"blank"``."""
    assigns = []
    for a_ in c.assignments:
        if a_.target_index is not None and a_.target_index >= nl:  # resting on an observed target
            a_ = dataclasses.replace(a_, kind="blank", target_index=None, target_id=None)
        elif a_.target_index is not None:
            a_ = dataclasses.replace(a_, target_index=int(sub[a_.target_index]))
        assigns.append(a_)
    return dataclasses.replace(c, assignments=tuple(assigns), arm_yield=n_real)
