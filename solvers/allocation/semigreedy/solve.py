"""Semi-Greedy Patrol-Based Target Allocator, SGPBTA (thesis 5.3, Algorithms 3-5).

A GRASP-style multistart heuristic for one observational configuration. Each iteration

1. **constructs** a partial solution target by target (thesis Algorithm 4): a limited
   pool of candidates (LPC) of the targets with the greatest benefit
   ``eta_i = p_i + gamma * r_i / n`` (eq. 5.4), those with ``eta_i >= q(alpha)``
   (eq. 5.5), one drawn at random; then an arm for it, ordered by the patrolling penalty
   matrix (:mod:`solvers.allocation.semigreedy.patrolling`) -- greedy (GAS) or shuffled per penalty level
   (PBAS) -- taking the first one compatible with the assignments already made;
2. **pads** the arms left without a target (thesis Algorithm 5): current position, then
   park, then the blank-sky locations sampled in the free area in front of the arm (when
   the structure has them, ``blank_per_arm``) -- the first compatible one, so padding
   never collides; only if none fits are the blocking assignments undone (a last-resort
   repair, see :func:`pad`), so every returned solution is complete;
3. runs a **local search** (5.3.1.3): swap moves then replace moves, first improvement
   (then ejection moves, a departure, below);
4. keeps the best solution (**solution update**, 5.3.1.4): total priority, then arm
   yield, then (departure, below) the "hard to place" tie-break, then total joint
   displacement (eq. 5.1) -- lexicographically.

Everything runs on the precomputed incompatibility structure (the same CSR adjacency the
exact allocator uses): compatibility of a candidate is ``blocked[a] == 0`` where
``blocked`` counts the chosen assignments incompatible with ``a``, updated in O(degree)
per move. No geometry is evaluated while solving.

Deliberate departures from the thesis pseudo-code, each documented where it occurs:

* targets that can no longer be placed are left out of the pool (the thesis draws them,
  fails at line 19 and moves on);
* padding look-ahead (``lookahead``, default on): construction accepts an arm for a
  target only if every arm still idle keeps a compatible rest location; the idle arms
  are then padded jointly (a tiny depth-first search). In the thesis a solution whose
  padding fails is dropped; here (almost) none fails, so no iteration is wasted;
* the local search runs replace moves first and the swap moves (which only shorten the
  total displacement) only on a solution that can still win the update;
* a multistart stops early once a solution reaches the collision-free upper bound
  (bipartite matching) in priority and yield, and after ``max_stall`` (default 10)
  iterations without improvement -- the thesis always runs all ``n_iter`` (30). On the
  1,200-target dense field most configurations at a priority-tier change never meet the
  matching bound (collisions bind), and the last improvement comes at iteration 9 on
  average; ``max_stall=None`` restores the thesis behaviour;
* targets of priority 0 (already observed sky that the conflict rescue of
  :mod:`solvers.sequencing` offers as a resting place) are rest locations, not targets;
* **crowding tie-break** (``crowding``, default on): among solutions of equal priority and
  yield the solution update, and the replace moves, prefer the one whose targets are hard
  to place -- ``n_arms - (arms reaching it)`` plus the pending targets within
  ``crowding_radius_mm`` (the exact allocator's tie-break, :func:`tie_break_weights`) --
  before the displacement. Priority stays the primary key and the construction (eqs.
  5.4, 5.5) is untouched. Why: a sequence that observes targets one configuration at a
  time ends in a tail of under-filled configurations unless the crowded places (where
  few arms fit at once) are worked from the start; the thesis optimises each
  configuration alone and does not see it. On the 1,200-target dense field (fields
  100-105, both alphas) the mean configuration count went from 106.4 to 102.7 at the
  exact allocator's 15 mm and 101.5 at 25 mm (20 mm: 102.2, 30 mm: 101.4, 35 mm: 101.8;
  the target pairs no configuration can hold together lie within 28 mm of each other in
  99 % of cases), hence the 25 mm default;
* **ejection moves** (``eject_trials``, default 24 per pass; :func:`eject_pass`): after the
  replace moves, an idle arm takes a target blocked by one or two chosen locations whose
  arms move elsewhere -- the move that fills the under-filled tail configurations, where
  the idle arms' rest locations block the last targets (thesis: swap and replace only).
"""

from __future__ import annotations

import numpy as np

from models import clock
from models.kinematics import direct_move_time_s
from solvers.allocation.backends import Backend
from solvers.allocation.options import SEMIGREEDY_SEQUENCING, SemiGreedyOptions
from solvers.allocation.semigreedy.construct import construct, pad
from solvers.allocation.semigreedy.local_search import local_search
from solvers.allocation.semigreedy.prepare import DISP_EPS, Prepared, State, prepare
from solvers.effort import SEMIGREEDY_ITERATION_S, SEMIGREEDY_PREPARE_COLUMN_S
from solvers.problem import ConfigProblem, ConfigSolution

WARM_START_ITERATIONS = 5  # a MIP start / hint: the exact solver improves on it anyway


# ----------------------------------------------------------- multistart (Alg. 3)


def preset_clashes(st: Prepared) -> list[tuple[int, int]]:
    """Pairs of out-of-service arms whose only locations are incompatible with each other.

    Such arms are placed before anything else and never moved, so when any pair clashes no
    complete collision-free choice exists: the problem is infeasible, as the exact model
    finds it."""
    fixed = {int(st.preset[k]): int(k) for k in np.flatnonzero(st.preset >= 0)}
    pairs = set()
    for x, k in fixed.items():
        for y in st.indices[st.indptr[x]:st.indptr[x + 1]].tolist():
            j = fixed.get(int(y))
            if j is not None:
                pairs.add((min(k, j), max(k, j)))
    return sorted(pairs)


def _fallback(st: Prepared) -> State | None:
    """Every arm at rest (current, else park), when compatible: the last resort."""
    s = State.empty(st)
    if pad(st, s):
        return s
    return None


def _evaluate_chosen(problem: ConfigProblem, chosen: np.ndarray) -> tuple[int, int, float]:
    """:func:`solvers.problem.evaluate` with the move times of the chosen locations only."""
    a = problem.assignments
    t = a.target[chosen]
    real = t >= 0
    arms = a.arm[chosen]
    v = problem.joint_speed_rad_s[arms]
    longest = float(direct_move_time_s(problem.start_q[arms], a.q[chosen], v[:, 0], v[:, 1]).max()) \
        if len(chosen) else 0.0
    return sum(int(problem.priority[i]) for i in t[real]), int(real.sum()), longest


def _multistart(st: Prepared, opts: SemiGreedyOptions, rng: np.random.Generator, t0: float,
                limit_s: float) -> tuple[State | None, tuple | None, int, int, int]:
    """The iterations of thesis Algorithm 3: (best state, its key, iterations done, local
    search moves, best iteration)."""
    best: State | None = None
    best_key: tuple | None = None
    n_done = ls_moves = 0
    best_iter = -1
    for it in range(opts.n_iter):
        s = construct(st, opts.alpha, opts.arm_selection, rng, opts.lookahead)
        clock.charge(SEMIGREEDY_ITERATION_S)
        if not pad(st, s):
            continue  # thesis line 9: only complete solutions go on
        if opts.local_search:
            # replace moves first (they decide priority and yield); the swap moves only
            # shorten the displacement, so they run (with replace moves again) only on a
            # solution that can still win the update -- same moves, fewer of them wasted
            ls_moves += local_search(st, s, rng, swaps=False, eject_trials=opts.eject_trials)
            if best_key is None or s.key(st)[:3] >= best_key[:3]:
                ls_moves += local_search(st, s, rng, eject_trials=opts.eject_trials)
        n_done += 1
        key = s.key(st)
        if best_key is None or key[:3] > best_key[:3] or (
                key[:3] == best_key[:3] and key[3] > best_key[3] + DISP_EPS):
            best, best_key, best_iter = s, key, it
        elif opts.max_stall is not None and it - best_iter >= opts.max_stall:
            break
        if opts.early_stop and best_key[0] >= st.ub_priority and best_key[1] >= st.ub_yield:
            break
        if clock.now() - t0 > limit_s:
            break
    return best, best_key, n_done, ls_moves, best_iter


def solve_semigreedy(problem: ConfigProblem, options: SemiGreedyOptions | None = None) -> ConfigSolution:
    """SGPBTA for one configuration (thesis Algorithm 3): multistart construction, padding,
    local search and solution update, with the :class:`SemiGreedyOptions` ``options``
    (default: the thesis parameters and the documented departures).

    ``seed`` defaults to ``problem.seed``; the same problem and options give the same
    solution. ``time_limit_s`` (default ``problem.time_limit_s``) bounds the multistart
    (at least one iteration runs). The returned status is ``"feasible"`` (a heuristic
    proves nothing) or ``"infeasible"`` when no complete collision-free choice was found
    (at once, without iterating, when out-of-service arms clash: :func:`preset_clashes`);
    ``gap`` is the relative gap to the collision-free matching upper bound, an upper
    bound on the true optimality gap. ``stats`` holds the bounds, iterations, timings.
    """
    t0 = clock.now()
    opts = SemiGreedyOptions() if options is None else options
    seed = problem.seed if opts.seed is None else opts.seed
    rng = np.random.default_rng(seed)
    limit = problem.time_limit_s if opts.time_limit_s is None else opts.time_limit_s
    st = prepare(problem, opts)
    clock.charge(len(problem.assignments) * SEMIGREEDY_PREPARE_COLUMN_S)
    t_prep = clock.now()
    clashes = preset_clashes(st)
    best: State | None = None
    best_key: tuple | None = None
    n_done = ls_moves = 0
    best_iter = -1
    if not clashes:
        best, best_key, n_done, ls_moves, best_iter = _multistart(st, opts, rng, t0, limit)
        if best is None:
            best = _fallback(st)
    stats = {
        "method": "semigreedy", "iterations": n_done, "best_iteration": best_iter,
        "local_search_moves": ls_moves, "upper_bound_priority": st.ub_priority_all,
        "upper_bound_priority_patrolled": st.ub_priority, "upper_bound_yield": st.ub_yield,
        "live_targets": int(len(st.eta)), "seed": int(seed) if seed is not None else None,
        "alpha": opts.alpha, "gamma": opts.gamma, "arm_selection": opts.arm_selection,
        "time_prepare_s": t_prep - t0, "time_s": clock.now() - t0,
        "out_of_service_clashes": [list(p) for p in clashes],
    }
    if best is None:
        park = np.array([int(st.current_idx[k]) if st.current_idx[k] >= 0 else int(st.park_idx[k])
                         for k in range(st.n_arms)])
        return ConfigSolution(park, "infeasible", 0, 0, 0.0, None, stats)
    total, yield_, longest = _evaluate_chosen(problem, best.chosen)
    ub = st.ub_priority_all
    gap = (ub - total) / ub if ub > 0 else 0.0
    stats["total_displacement_rad"] = -best_key[3] if best_key else float(st.disp[best.chosen].sum())
    return ConfigSolution(best.chosen.copy(), "feasible", total, yield_, longest, gap, stats)


def warm_start(problem: ConfigProblem, options: SemiGreedyOptions | None = None) -> np.ndarray:
    """The heuristic's chosen assignment indices, (n_arms,), for a MIP start / CP-SAT hints.

    Set ``x_a = 1`` for ``a`` in the result and 0 elsewhere (see :func:`warm_start_vector`);
    the choice is complete and compatible with the incompatibility structure, so it is a
    feasible start for the exact model on the same ``problem``. The default options favour
    speed (``n_iter=WARM_START_ITERATIONS``) since the exact solver improves on it anyway.
    """
    opts = SemiGreedyOptions(n_iter=WARM_START_ITERATIONS) if options is None else options
    sol = solve_semigreedy(problem, opts)
    return np.asarray(sol.chosen, dtype=np.int64)


def warm_start_vector(problem: ConfigProblem, chosen: np.ndarray) -> np.ndarray:
    """(n_assignments,) 0/1 int8 vector of a choice, ready for ``setSolution``/``AddHint``."""
    x = np.zeros(len(problem.assignments), np.int8)
    x[np.asarray(chosen, dtype=np.int64)] = 1
    return x


def _solve(problem: ConfigProblem, options: SemiGreedyOptions, *, hint: np.ndarray | None = None,
           columns: np.ndarray | None = None) -> ConfigSolution:
    """The registry entry; ``hint`` and ``columns`` (exact-model inputs) do not apply."""
    return solve_semigreedy(problem, options)


BACKEND = Backend(name="semigreedy", method="semigreedy", options_type=SemiGreedyOptions, solve=_solve,
                  exact=False, rescue="cpsat", description="semigreedy", sequencing=SEMIGREEDY_SEQUENCING)
