"""Lower bounds on the number of configurations needed to complete a field.

``ceil(t / arms)`` is the thesis' "theoretical" count (tables 5.1–5.2).  Two bounds that
can exceed it, both rigorous for any allocator:

* :func:`matching_lower_bound` — reach: every target needs an arm that reaches it, and
  each arm observes at most one target per configuration (b-matching by max-flow);
* :func:`crowding_lower_bound` — collisions: the targets inside a disc about the FOV
  centre can only be observed so many at a time, because arms converging on the centre
  collide.  With m(r) the most targets of the disc of radius r that one configuration can
  observe, every configuration holds at most m(r) of its n(r) targets, so at least
  ceil(n(r) / m(r)) configurations are needed.  m(r) is computed over the incompatibility
  structure with every arm not on a disc target *removed* (not parked), so it can only
  over-estimate the true maximum, and the bound stays valid; when CP-SAT cannot prove
  m(r) in time its proven upper bound is used instead.

:func:`configuration_lp_bound` (Farley's bound from the set-partitioning LP) dominates both
where its column generation converges; :func:`radial_lp_bound` makes it converge on crowded
centres by sharing one dual per ring of a small disc about the centre.
"""

from __future__ import annotations

import math

import numpy as np

from models import clock
from models.incompatibility import Incompatibility
from solvers.effort import LP_CELL_S, LP_SOLVE_S, charge_literals, cpsat_solve

# discs about the centre where crowding binds; the larger default discs cost more than they tell
INNER_DISCS_MM = (10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0)


def matching_lower_bound(inc: Incompatibility, targets: np.ndarray) -> int:
    """True lower bound on the number of configurations, beyond ceil(t / arms).

    Each configuration gives every arm at most one target, so C configurations can only
    exist if every target can be matched to an arm that reaches it with each arm taking
    <= C targets (a bipartite b-matching; collisions ignored, hence a lower bound).  The
    minimum such C is found by max-flow (scipy.sparse.csgraph.maximum_flow) and a binary
    search starting at ceil(t / arms).  ``targets``: (n_targets,) bool of those to place.
    """
    from scipy import sparse as sp
    from scipy.sparse.csgraph import maximum_flow

    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    sel = np.flatnonzero(targets)
    t_all = len(sel)
    if t_all == 0:
        return 0
    m = (a.target >= 0)
    m[m] = targets[a.target[m]]
    pairs = np.unique(np.column_stack([a.arm[m], a.target[m]]), axis=0)
    t_idx = np.searchsorted(sel, pairs[:, 1])
    reach = np.bincount(pairs[:, 0], minlength=n_arms) > 0
    n_act = int(reach.sum())
    # nodes: 0 source, 1..n_arms arms, then targets, then sink
    src, sink = 0, 1 + n_arms + t_all

    def flow(c: int) -> int:
        rows = np.r_[np.zeros(n_arms, int), 1 + pairs[:, 0], 1 + n_arms + np.arange(t_all)]
        cols = np.r_[1 + np.arange(n_arms), 1 + n_arms + t_idx, np.full(t_all, sink)]
        cap = np.r_[np.full(n_arms, c), np.ones(len(pairs), int), np.ones(t_all, int)].astype(np.int32)
        g = sp.csr_matrix((cap, (rows, cols)), shape=(sink + 1, sink + 1))
        return int(maximum_flow(g, src, sink).flow_value)

    placeable = flow(t_all)  # targets some arm reaches
    lo = math.ceil(placeable / max(n_act, 1))
    hi = max(lo, 1)
    while flow(hi) < placeable:
        lo, hi = hi + 1, hi * 2
    while lo < hi:
        mid = (lo + hi) // 2
        if flow(mid) >= placeable:
            hi = mid
        else:
            lo = mid + 1
    return lo


def _independent_set_model(inc: Incompatibility, in_subset: np.ndarray):
    """CP-SAT model of one configuration over the targets in ``in_subset`` (bool per target),
    arms not on a subset target absent: a binary per assignment of a subset target, at most
    one per arm and per target, at most one of every incompatible pair (eq. 5.15 pairwise).
    Returns (model, variables, their assignment indices); no objective yet."""
    from ortools.sat.python import cp_model

    a = inc.assignments
    cols = np.flatnonzero((a.target >= 0) & in_subset[np.maximum(a.target, 0)])
    col_of = np.full(len(a), -1, np.int64)
    col_of[cols] = np.arange(len(cols))
    p = inc.pairs
    keep = (col_of[p[:, 0]] >= 0) & (col_of[p[:, 1]] >= 0) & ~inc.same_target
    model = cp_model.CpModel()
    x = [model.NewBoolVar("") for _ in range(len(cols))]
    for key in (a.arm[cols], a.target[cols]):
        order = np.argsort(key, kind="stable")
        cuts = np.flatnonzero(np.diff(key[order])) + 1
        for grp in np.split(order, cuts):
            if len(grp) > 1:
                model.AddAtMostOne([x[i] for i in grp])
    for i, j in col_of[p[keep]].tolist():
        model.AddBoolOr([x[i].Not(), x[j].Not()])
    charge_literals(3 * len(cols) + 4 * int(keep.sum()))  # a Not() costs about a literal
    return model, x, cols


def max_simultaneous_targets(inc: Incompatibility, subset: np.ndarray, *, time_limit_s: float = 2.0,
                             threads: int = 2, seed: int = 0) -> tuple[int, bool]:
    """Upper bound on how many targets of ``subset`` (target indices) one configuration can
    observe, arms not on a subset target being absent; ``(value, proven_optimal)``.

    Independent-set model on the incompatibility pairs (eq. 5.15 pairwise): a binary per
    assignment of a subset target, at most one per arm and per target, at most one of every
    incompatible pair.  When the time limit stops CP-SAT, its best proven bound is returned
    (still an upper bound, so a lower bound computed from it stays valid).
    """
    from ortools.sat.python import cp_model

    in_subset = np.zeros(inc.reachability.n_targets, bool)
    in_subset[np.asarray(subset, np.int64)] = True
    model, x, cols = _independent_set_model(inc, in_subset)
    if not len(cols):
        return 0, True
    model.Maximize(sum(x))
    solver = cp_model.CpSolver()
    solver.parameters.num_workers = max(2, threads)
    solver.parameters.random_seed = int(seed)
    code = cpsat_solve(solver, model, time_limit_s)
    if code == cp_model.OPTIMAL:
        return int(round(solver.ObjectiveValue())), True
    n_arms = len(inc.assignments.arm_start) - 1
    ub = solver.BestObjectiveBound() if code == cp_model.FEASIBLE else min(n_arms, len(cols))
    return int(math.floor(ub + 1e-9)), False


def crowding_lower_bound(inc: Incompatibility, xy_mm: np.ndarray, targets: np.ndarray, *,
                         radii_mm: tuple[float, ...] = (10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0, 75.0, 90.0),
                         time_limit_s: float = 2.0, threads: int = 2) -> tuple[int, list[dict]]:
    """Collision-aware lower bound on the configurations for ``targets`` (bool mask):
    max over discs about the FOV centre of ceil(n(r) / m(r)) (module docstring).  Returns
    the bound and one row per disc (radius, targets, most observable at once, proven)."""
    r_mm = np.hypot(xy_mm[:, 0], xy_mm[:, 1])
    best, rows = 0, []
    for r in radii_mm:
        sub = np.flatnonzero(targets & (r_mm <= r))
        if not len(sub):
            continue
        m, proven = max_simultaneous_targets(inc, sub, time_limit_s=time_limit_s, threads=threads)
        lb = math.ceil(len(sub) / m) if m else 0
        best = max(best, lb)
        rows.append({"radius_mm": r, "targets": int(len(sub)), "max_at_once": m, "proven": proven,
                     "lower_bound": lb})
    return best, rows


def configuration_lp_bound(inc: Incompatibility, targets: np.ndarray, *, time_limit_s: float = 10.0,
                           columns: list[np.ndarray] | None = None, stop_at: int | None = None,
                           price_time_limit_s: float = 2.0, threads: int = 2,
                           seed: int = 0, groups: np.ndarray | None = None) -> tuple[int, dict]:
    """Lower bound on the configurations for ``targets`` (bool mask) from the linear
    relaxation of the set-partitioning model, by column generation.

    Master (LP): minimise sum(lambda_p) over configurations p, every target covered at least
    once.  Any non-negative target weights pi with sum(pi[t] for t in p) <= M for every
    configuration p prove at least sum(pi) / M configurations (Farley's bound, valid at every
    iteration, not only at LP optimality); the crowding bound is the special case pi = 1/m(r)
    on a disc.  pi are the master's duals; M is the pricing problem — the heaviest single
    configuration, solved exactly by CP-SAT on integer weights floor(pi * 1e9) over the
    relaxation of :func:`max_simultaneous_targets` (idle arms absent, so M can only be over-
    estimated; rounding is covered by adding n_arms / 1e9).  Its optimum is the next column.
    ``columns``: target-index arrays of known configurations (e.g. the current sequence) to
    start the master with.  Stops at LP optimality, at ``time_limit_s``, or once the bound
    reaches ``stop_at``.  ``groups`` (one integer per target, e.g. a radial bin; the mask picks): the
    aggregated master — one cover row per group (sum of its targets' rows, so a relaxation of
    the master above and still a valid bound), its duals shared by the group's targets.
    With ~20 rows instead of hundreds it converges in tens of pricings where the full
    master's degenerate duals tail off; on centred clusters the radial weights lose little.
    Returns (bound, info: iterations, LP value, proven).
    """
    from ortools.sat.python import cp_model
    from scipy.optimize import linprog

    t0 = clock.now()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    sel = np.flatnonzero(targets)
    info: dict = {"iterations": 0, "lp_value": None, "converged": False}
    if not len(sel):
        return 0, info
    local = np.full(inc.reachability.n_targets, -1, np.int64)
    local[sel] = np.arange(len(sel))
    model, x, cols_a = _independent_set_model(inc, local >= 0)
    tl_of_col = local[a.target[cols_a]]
    solver = cp_model.CpSolver()
    solver.parameters.num_workers = max(2, threads)
    solver.parameters.random_seed = int(seed)
    # the pricing model is solved again at every iteration with only its objective changed:
    # presolving it each time is work the search does not need, and work CP-SAT's
    # deterministic time hardly counts (two-clump-4006's 169-target core: 92 pricings of
    # 0.2 s each, 20 s in all, charged 1.3 effort seconds, so the pointing overran its share)
    solver.parameters.cp_model_presolve = False
    scale = 1_000_000_000  # integer pricing weights; the rounding margin is n_arms / scale
    master = [np.asarray(c, np.int64) for c in (columns or [])]
    master = [local[c[c >= 0]] for c in master]  # idle arms (< 0) and targets outside the mask dropped
    master = [c[c >= 0] for c in master]
    master += [np.array([t]) for t in range(len(sel))]  # singletons keep the master feasible
    if groups is None:
        row_of = np.arange(len(sel))
    else:
        _, row_of = np.unique(np.asarray(groups)[sel], return_inverse=True)
    n_rows = int(row_of.max()) + 1
    rhs = np.bincount(row_of, minlength=n_rows).astype(float)
    # each column's cover counts per row, computed once when the column joins the master
    col_rows = [np.bincount(row_of[c], minlength=n_rows).astype(float) for c in master]
    best = 0
    while True:
        left = time_limit_s - (clock.now() - t0)
        if left <= 0.05:
            break
        res = linprog(np.ones(len(col_rows)), A_ub=-np.column_stack(col_rows), b_ub=-rhs, bounds=(0, None),
                      method="highs")
        pi = np.maximum(-res.ineqlin.marginals, 0.0)[row_of]  # a group's dual on each of its targets
        info["lp_value"] = float(res.fun)
        clock.charge(LP_SOLVE_S + LP_CELL_S * n_rows * len(col_rows))
        w = np.floor(pi * scale).astype(np.int64)
        model.Maximize(sum(int(w[t]) * x[i] for i, t in enumerate(tl_of_col.tolist()) if w[t] > 0))
        charge_literals(2 * len(x))
        code = cpsat_solve(solver, model, min(left, price_time_limit_s))
        info["iterations"] += 1
        if code not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            if price_time_limit_s >= left:
                break
            price_time_limit_s *= 2  # no answer at all: the same pricing with more time
            continue
        heaviest = (solver.BestObjectiveBound() + n_arms) / scale  # >= max over p of pi(p)
        if heaviest > 0 and math.ceil(float(pi.sum()) / heaviest - 1e-6) > best:
            best = math.ceil(float(pi.sum()) / heaviest - 1e-6)
            info["certificate"] = (sel, pi / heaviest)  # target weights no configuration exceeds 1 of
        if stop_at is not None and best >= stop_at:
            break
        new = np.array(sorted({int(tl_of_col[i]) for i in range(len(x)) if solver.BooleanValue(x[i])}))
        if float(pi[new].sum()) <= 1.0 + 1e-9:
            if code == cp_model.OPTIMAL:
                # no column prices out: the LP optimum is reached (the bound stays Farley's,
                # which covers the rounding of the weights; ceil(lp_value) would not)
                info["converged"] = True
                break
            price_time_limit_s *= 2  # an unproven pricing found nothing better: again, longer
            continue
        col_rows.append(np.bincount(row_of[new], minlength=n_rows).astype(float))
    info["time_s"] = clock.now() - t0
    return best, info


def radial_lp_bound(inc: Incompatibility, xy_mm: np.ndarray, targets: np.ndarray, *,
                    radii_mm: tuple[float, ...] = (15.0, 20.0, 25.0), ring_mm: float = 2.5,
                    time_limit_s: float = 30.0, stop_at: int | None = None,
                    threads: int = 2) -> tuple[int, list[dict]]:
    """Max over discs about the FOV centre of the configuration LP bound of the disc's targets
    with one cover row per ``ring_mm`` ring (:func:`configuration_lp_bound` with ``groups``).
    A disc's targets are a subset of the field, so its bound is the field's; one ring per
    disc is the crowding bound, so rings can only raise it.  On a heavy-384 field (σ 30 mm)
    the full LP over 384 targets was at 11–32 after 60–120 s, this one at 36 in 2.6 s from
    the 82 targets within 20 mm.  ``time_limit_s`` is shared by the discs; ``stop_at`` stops
    once reached.  Returns the bound and one row per disc."""
    r_mm = np.hypot(xy_mm[:, 0], xy_mm[:, 1])
    ring = np.floor(r_mm / ring_mm).astype(np.int64)
    t0 = clock.now()
    best, rows = 0, []
    for i, r in enumerate(radii_mm):
        sub = targets & (r_mm <= r)
        left = time_limit_s - (clock.now() - t0)
        if not sub.any() or left <= 0.1:
            continue
        lb, info = configuration_lp_bound(inc, sub, time_limit_s=left / (len(radii_mm) - i), groups=ring,
                                          stop_at=stop_at, threads=threads)
        best = max(best, lb)
        rows.append({"radius_mm": r, "targets": int(sub.sum()), "lower_bound": lb,
                     "converged": info["converged"], "iterations": info["iterations"]})
        if stop_at is not None and best >= stop_at:
            break
    return best, rows
