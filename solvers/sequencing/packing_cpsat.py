"""CP-SAT models for packing targets into a fixed number of configurations.

The same question as :mod:`solvers.sequencing.tabu` (can these targets be observed in ``n``
configurations, each obeying eqs. 5.13–5.15?), asked two ways because CP-SAT is good at
different halves of it:

* :func:`exact_cover` — every pooled target exactly once, configurations ordered by what
  one arm observes (symmetry breaking).  Proves infeasibility in seconds where one exists
  on the protocol's fields, but as a pure feasibility model it gives CP-SAT's
  large-neighbourhood workers nothing to improve: on weakly clustered 192-target fields it
  found no packing into 16 in minutes, where one exists.
* :func:`max_cover` — every pooled target at most once, maximise how many are observed,
  no symmetry breaking.  A partial packing is a solution, so the LNS workers improve on it;
  the same four weak-192 packings took 6–41 s with 2 workers and a light presolve (three
  seeds; one of twelve runs missed its packing in 45 s), and the
  symmetry-broken version of this model found none of them in 60 s.  It reaches the
  maximum (= every target) or proves a smaller one, which is also a proof.

Both return per configuration the (n_arms,) chosen assignment indices (idle arms on a rest
location) or None, and say whether None is a proof; max-cover also returns its best
partial packing.  Neither builds a model whose building would take longer than its time
limit (:func:`fits_in_time`): Python adds the literals one by one and CP-SAT loads them
before its clock starts, so on a dense field (1,200 targets about the centre, a 400-target
pool in 27 configurations: 11.9 M literals) a 1.2 s packing attempt took 4.5 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.incompatibility import Incompatibility
from solvers.effort import CPSAT_LITERAL_S, charge_literals, cpsat_solve
from solvers.model import ModelArrays, build_model_arrays
from solvers.problem import ConfigProblem

__all__ = ["PackingOutcome", "exact_cover", "fits_in_time", "max_cover", "packing_columns"]


@dataclass(frozen=True)
class PackingOutcome:
    packing: list[np.ndarray] | None
    infeasible: bool  # True only when CP-SAT proved that no packing exists
    # max-cover's best solution when it is not a packing: valid configurations that leave
    # some pooled targets out (a packing into one more configuration may take those)
    partial: list[np.ndarray] | None = None


def packing_columns(inc: Incompatibility, pool: np.ndarray) -> ModelArrays | None:
    """Columns and rows of one configuration (eqs. 5.13–5.15) over the pooled targets and
    every rest location; None when some arm has no column at all."""
    a = inc.assignments
    n_t = inc.reachability.n_targets
    avail = np.zeros(n_t, bool)
    avail[pool] = True
    n_arms = len(a.arm_start) - 1
    dummy = ConfigProblem(inc, np.ones(n_t, np.int64), avail, np.zeros((n_arms, 2)), np.ones((n_arms, 2)))
    m = build_model_arrays(dummy, "aggregated", None, wildcards=False)
    if (m.eq_indptr[1:] == m.eq_indptr[:-1]).any():
        return None
    return m


def model_literals(m: ModelArrays, n_configs: int) -> int:
    """Literals of a packing model over ``m``'s columns in ``n_configs`` configurations: its
    variables, per-configuration rows and cover rows."""
    return n_configs * (2 * m.n_vars + len(m.eq_indices) + len(m.le_indices))


def fits_in_time(m: ModelArrays, n_configs: int, time_limit_s: float) -> bool:
    """Whether building the model (at :data:`solvers.effort.CPSAT_LITERAL_S` per literal, the
    effort clock's cost, a little under what building takes on the reference machine:
    0.43-0.50 us a literal on the crowded fields of ``tests/test_packing_cpsat.py``) fits in
    ``time_limit_s``."""
    return model_literals(m, n_configs) * CPSAT_LITERAL_S <= time_limit_s


def _configurations(model, m: ModelArrays, n_configs: int, n_arms: int):
    """Boolean x[c][j] per configuration and column with eqs. 5.13 and 5.15 per configuration
    (the target rows, eq. 5.14, are replaced by the callers' cover rows across configurations)."""
    x = [[model.NewBoolVar("") for _ in range(m.n_vars)] for _ in range(n_configs)]
    # per configuration: its columns, rows and the callers' cover rows over the same columns
    charge_literals(model_literals(m, n_configs))
    li = m.le_indices.tolist()
    for c in range(n_configs):
        for k in range(n_arms):
            model.AddExactlyOne([x[c][j] for j in m.eq_indices[m.eq_indptr[k]:m.eq_indptr[k + 1]]])
        for i in range(m.n_target_rows, len(m.le_indptr) - 1):
            model.AddAtMostOne([x[c][j] for j in li[m.le_indptr[i]:m.le_indptr[i + 1]]])
    return x


def _solve(model, time_limit_s: float, seed: int, threads: int, light_presolve: bool = False):
    from ortools.sat.python import cp_model

    solver = cp_model.CpSolver()
    if light_presolve:
        # the default presolve spent 11.6 s of a 26 s weak-192 packing on 1.6 M at-most-one
        # literals (probing, symmetry, repeated passes); without them the max-cover model
        # reached its packings sooner (weak-192 fields 1, 12, 16 at 16: median ~19 s
        # against ~28 s, three seeds)
        solver.parameters.cp_model_probing_level = 0
        solver.parameters.max_presolve_iterations = 1
        solver.parameters.symmetry_level = 0
    # one worker stalls on mid-size instances (brief, known traps)
    solver.parameters.num_workers = max(2, threads)
    solver.parameters.random_seed = int(seed)
    return solver, cpsat_solve(solver, model, max(time_limit_s, 0.05))


def _read(solver, x, m: ModelArrays, n_configs: int, n_arms: int) -> list[np.ndarray]:
    out = []
    for c in range(n_configs):
        xv = np.array([solver.BooleanValue(v) for v in x[c]], dtype=float)
        ch = np.full(n_arms, -1, np.int64)
        for k in range(n_arms):
            row = m.eq_indices[m.eq_indptr[k]:m.eq_indptr[k + 1]]
            ch[k] = m.var[row[int(np.argmax(xv[row]))]]
        out.append(ch)
    return out


def exact_cover(inc: Incompatibility, m: ModelArrays, pool: np.ndarray, n_configs: int, *,
                time_limit_s: float, seed: int = 0, threads: int = 2,
                hint: list[np.ndarray] | None = None) -> PackingOutcome:
    """Every pooled target in exactly one of ``n_configs`` configurations; the
    configurations are ordered by the target of the arm with the most pooled targets."""
    from ortools.sat.python import cp_model

    if not fits_in_time(m, n_configs, time_limit_s):
        return PackingOutcome(None, False)

    a = inc.assignments
    n_t = inc.reachability.n_targets
    n_arms = len(a.arm_start) - 1
    model = cp_model.CpModel()
    x = _configurations(model, m, n_configs, n_arms)
    tgt = a.target[m.var]
    for t in pool:
        cols = np.flatnonzero(tgt == t)
        model.AddExactlyOne([x[c][j] for c in range(n_configs) for j in cols])
    # redundant but helps the search: exactly n_arms * n_configs - |pool| rest placements
    rest = np.flatnonzero(tgt < 0)
    model.Add(sum(x[c][j] for c in range(n_configs) for j in rest) == n_arms * n_configs - len(pool))
    # symmetry breaking: configurations are interchangeable, so order them by what the arm
    # with the most pooled targets observes (its rest locations ranked last, ties allowed)
    arm_of = a.arm[m.var]
    k_sym = int(np.argmax(np.bincount(arm_of[tgt >= 0], minlength=n_arms)))
    cols_k = np.flatnonzero(arm_of == k_sym)
    rank = np.where(tgt[cols_k] >= 0, tgt[cols_k], n_t).astype(np.int64)
    rank_of = dict(zip(m.var[cols_k].tolist(), rank.tolist(), strict=True))
    key = [sum(int(r) * x[c][j] for r, j in zip(rank, cols_k, strict=True)) for c in range(n_configs)]
    for c in range(n_configs - 1):
        model.Add(key[c] <= key[c + 1])
    if hint:
        hint = sorted(hint[:n_configs], key=lambda ch: rank_of.get(int(ch[k_sym]), n_t))
        _add_hint(model, x, m, hint)
    solver, code = _solve(model, time_limit_s, seed, threads)
    if code in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        return PackingOutcome(_read(solver, x, m, n_configs, n_arms), False)
    return PackingOutcome(None, code == cp_model.INFEASIBLE)


def max_cover(inc: Incompatibility, m: ModelArrays, pool: np.ndarray, n_configs: int, *,
              time_limit_s: float, seed: int = 0, threads: int = 2,
              hint: list[np.ndarray] | None = None) -> PackingOutcome:
    """Every pooled target in at most one configuration, as many as possible; a packing
    when all of them are observed, a proof of infeasibility when CP-SAT's bound drops
    below the pool."""
    from ortools.sat.python import cp_model

    if not fits_in_time(m, n_configs, time_limit_s):
        return PackingOutcome(None, False)

    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    model = cp_model.CpModel()
    x = _configurations(model, m, n_configs, n_arms)
    tgt = a.target[m.var]
    observed = []
    for t in pool:
        cols = np.flatnonzero(tgt == t)
        lits = [x[c][j] for c in range(n_configs) for j in cols]
        model.AddAtMostOne(lits)
        observed += lits
    # the count as a variable bounded by the pool: with the light presolve CP-SAT did not
    # derive that bound itself and ran to its time limit after finding the packing
    n_observed = model.NewIntVar(0, len(pool), "observed")
    model.Add(n_observed == sum(observed))
    model.Maximize(n_observed)
    if hint:
        _add_hint(model, x, m, hint[:n_configs])
    solver, code = _solve(model, time_limit_s, seed, threads, light_presolve=True)
    if code in (cp_model.OPTIMAL, cp_model.FEASIBLE) and round(solver.ObjectiveValue()) == len(pool):
        return PackingOutcome(_read(solver, x, m, n_configs, n_arms), False)
    solved = code in (cp_model.OPTIMAL, cp_model.FEASIBLE)
    proven = code == cp_model.INFEASIBLE or (solved and solver.BestObjectiveBound() < len(pool) - 0.5)
    return PackingOutcome(None, proven, _read(solver, x, m, n_configs, n_arms) if solved else None)


def _add_hint(model, x, m: ModelArrays, hint: list[np.ndarray]) -> None:
    col_of = {int(v): j for j, v in enumerate(m.var)}
    for c, ch in enumerate(hint):
        for v in ch:
            if int(v) in col_of:
                model.AddHint(x[c][col_of[int(v)]], True)
