"""The sequencing driver: configurations until a field is complete (thesis 5.5).

The thesis protocol: allocate one configuration, remove its targets, repeat with the
pending ones until every target is observed.  Here:

* the reachability / incompatibility structure is computed ONCE for the whole field; each
  configuration is a :class:`ConfigProblem` over it with ``available`` = still pending;
* every solution is re-checked by :func:`solvers.problem.check_solution` (geometry, not the
  table) before it becomes a :class:`Configuration` — an unverified one raises;
* the next configuration's ``start_q`` is the previous configuration's arm positions
  (longest-move criterion, eq. 5.16);
* beyond the thesis: a tie-break among equal-priority, equal-yield, equal-longest-move
  solutions in favour of hard-to-place targets — few arms reach them, or many pending
  targets crowd within 15 mm of them (near the FOV centre only one arm at a time fits, so
  a crowded spot must be started early) — with weights that cannot trade priority or
  yield away (:func:`solvers.model.safe_weights`); then the named post-passes of
  :mod:`solvers.sequencing.passes` (rescue, repair, packing, bounds, repacking) over one
  :class:`~solvers.sequencing.state.SequenceState`, within the budget of
  :mod:`solvers.sequencing.shares`.  Lower bounds (:mod:`solvers.sequencing.bounds`:
  max-flow, crowding, the configuration LP bound, CP-SAT infeasibility) are reported, so a
  count can be shown optimal, and repacking never tries a count below them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

import solvers.effort  # noqa: F401  (prices the work of the incompatibility structure)
from models import clock
from models.budget import Budget
from models.incompatibility import Incompatibility, incompatibility_for_targets
from models.instrument import Instrument
from models.locks import LockColumns
from models.types import AllocationResult, PlaneTargets, Unallocated
from solvers.problem import ConfigProblem, ConfigSolution
from solvers.sequencing.bounds import matching_lower_bound
from solvers.sequencing.options import SequencingOptions
from solvers.sequencing.passes import POST_PASSES, PassContext
from solvers.sequencing.shares import SHARES
from solvers.sequencing.state import (
    SequenceState,
    Step,
    active_arms,
    hard_to_place,
    joint_speeds,
    make_configuration,
    observed,
    verify,
)

__all__ = ["Progress", "sequence_configurations"]

Progress = Callable[[float, str], None]
PROGRESS_READY, PROGRESS_LOOP = 0.05, 0.85  # progress after the structure; the loop's share


def precedence(priority: np.ndarray, locked: Sequence[int]) -> np.ndarray:
    """The priorities the engines weigh: a locked target counts its own priority plus the
    field's largest, so that it outweighs any one unlocked target it competes with (for its
    arm, or for room next to it) and is observed as early as it can be. Reported priorities
    stay the targets' own (:func:`_result`)."""
    p = np.asarray(priority, dtype=np.int64).copy()
    if len(locked) and len(p):
        p[np.asarray(locked, int)] += int(p.max())
    return p


def _initial_state(instrument: Instrument, targets: PlaneTargets, inc: Incompatibility,
                   start_q: np.ndarray | None, seed: int, options: SequencingOptions,
                   locked: Sequence[int] = ()) -> SequenceState:
    n = len(targets)
    x = np.asarray(targets.x_mm, float)
    y = np.asarray(targets.y_mm, float)
    unreachable = np.zeros(n, bool)
    unreachable[inc.reachability.unreachable] = True
    pending = ~unreachable
    n_reachable = int(pending.sum())
    n_active = len(active_arms(inc, instrument.n_arms))
    lower_bound = math.ceil(n_reachable / max(n_active, 1)) if n_reachable else 0
    flow_bound = matching_lower_bound(inc, pending) if (n_reachable and options.sequence.lower_bound_flow) \
        else lower_bound
    q = instrument.park_configuration.copy() if start_q is None else np.asarray(start_q, float).copy()
    tie = hard_to_place(inc, instrument.n_arms) if options.sequence.tie_break else None
    return SequenceState(instrument, targets, inc, precedence(targets.priority, locked), unreachable,
                         pending, n_reachable, n_active, lower_bound, flow_bound, joint_speeds(instrument),
                         np.column_stack([x, y]), tie, q, q.copy(), seed, options.sequence.threads)


def _greedy(s: SequenceState, ctx: PassContext, progress: Progress | None) -> None:
    """One configuration after another, each the engine's best over the pending targets."""
    opt = ctx.options.sequence
    t_solve = 0.0
    while s.pending.any():
        if opt.max_configurations is not None and len(s.steps) >= opt.max_configurations:
            s.stop_reason = "max_configurations"
            break
        remaining = ctx.budget.left_s()
        if remaining <= SHARES.min_solve_s:
            s.stop_reason = "no_time"
            break
        limit_i = SHARES.config_limit_s(remaining, ctx.budget, int(s.pending.sum()), s.n_active,
                                        opt.config_time_limit_s, opt.adaptive_limits, opt.reserve_fraction)
        if opt.tie_break and opt.tie_break != "reach":
            s.tie = hard_to_place(s.inc, s.n_arms, s.xy, s.pending)
        prob = ConfigProblem(s.inc, s.priority, s.pending.copy(), s.q, s.speeds, time_limit_s=limit_i,
                             mip_rel_gap=opt.mip_rel_gap, threads=opt.threads, seed=s.seed + len(s.steps),
                             target_xy_mm=s.xy, tie_break=s.tie)
        ts = clock.now()
        sol = ctx.solve_one(prob)
        dt = clock.now() - ts
        t_solve += dt
        if sol.status in ("timeout", "infeasible") or (sol.chosen < 0).any():
            s.stop_reason = f"solver_{sol.status}"
            break
        verify(s.instrument, prob, sol.chosen)
        tg = prob.assignments.target[sol.chosen]
        tg = tg[tg >= 0]
        if not len(tg):
            s.stop_reason = "conflict"
            break
        stats = {"solve_s": dt, "status": sol.status, "gap": sol.gap, "longest_move_s": sol.longest_move_s,
                 "time_limit_s": limit_i}
        if "incumbent" in sol.stats:  # where an exact-model engine's start came from (backends.note_incumbent)
            stats["incumbent"] = sol.stats["incumbent"]
        s.steps.append(Step(prob, sol.chosen, sol.status, stats))
        s.pending[tg] = False
        s.q = prob.assignments.q[sol.chosen]
        if ctx.options.rescue.enabled and len(tg) < s.n_active and \
                0 < s.pending.sum() <= ctx.options.rescue.tail_fraction * s.n_reachable:
            # the under-filled tail: what is left is mostly blocked by parked neighbours;
            # finish it where idle arms may rest on observed targets (the rescue pass)
            s.stop_reason = "tail"
            break
        if progress:
            progress(PROGRESS_READY + PROGRESS_LOOP * (1 - s.pending.sum() / max(s.n_reachable, 1)),
                     f"configuration {len(s.steps)}")
    s.timers["sequence_s"] = t_solve
    s.greedy_count = len(s.steps)


def _result(s: SequenceState, budget: Budget, engines: dict[str, str] | None) -> AllocationResult:
    """The configurations (main, then rescue), the unallocated targets with their reason, the stats."""
    targets, n = s.targets, len(s.targets)
    own = np.asarray(targets.priority, dtype=np.int64)
    out = [make_configuration(i, st.problem, st.chosen, targets, st.status, st.stats)
           for i, st in enumerate(s.steps)]
    out += [dataclasses.replace(c, index=len(s.steps) + i) for i, c in enumerate(s.extra)]
    if not np.array_equal(own, s.priority):  # locked targets weighed more: report their own
        out = [dataclasses.replace(c, total_priority=sum(int(own[t]) for t in observed(c))) for c in out]
    allocated = np.zeros(n, bool)
    for c in out:
        for a in c.assignments:
            if a.target_index is not None:
                allocated[a.target_index] = True
    reason_left = "no_time" if s.stop_reason in ("no_time", "solver_timeout") else "conflict"
    if s.stop_reason == "max_configurations":  # left for configurations the request did not ask for
        reason_left = "not_scheduled"
    beyond = np.zeros(n, bool)
    beyond[s.inc.reachability.beyond_limit] = True
    unalloc = [Unallocated(int(i), targets.ids[i], "beyond_park_move_limit" if beyond[i]
                           else "unreachable" if s.unreachable[i] else reason_left)
               for i in np.flatnonzero(~allocated)]
    total_p = sum(int(p) for p in own)
    got_p = sum(int(p) for p in own[allocated])
    s.timers["total_s"] = budget.elapsed_s()
    stats = {
        "n_targets": n,
        "n_reachable": s.n_reachable,
        "n_configurations": len(out),
        "n_configurations_greedy": s.greedy_count,
        "lower_bound_configurations": s.lower_bound,
        "lower_bound_configurations_flow": s.flow_bound,
        # CP-SAT proved the allocated targets cannot be packed into fewer configurations
        "lower_bound_configurations_proven": max(s.proven_bound, s.flow_bound, s.crowd_bound, s.lp_bound,
                                                 s.floor_proof),
        "lower_bound_configurations_crowding": s.crowd_bound,
        "lower_bound_configurations_lp": s.lp_bound,
        # completeness over every target of the request: an unreachable target counts as
        # not observed (n_allocated == n_reachable says the allocator took all it could)
        "n_allocated": int(allocated.sum()),
        "n_unreachable": n - s.n_reachable,
        "n_beyond_park_move_limit": int(beyond.sum()),
        "field_completeness": float(allocated.sum() / n) if n else 1.0,
        "priority_completeness": got_p / total_p if total_p else 1.0,
        "stop_reason": s.stop_reason,
        "per_configuration": [{"total_priority": c.total_priority, "arm_yield": c.arm_yield, "status": c.status,
                               "solve_s": c.stats.get("solve_s")} for c in out],
        "timers_s": s.timers,
        "incompatibility": s.inc.counts(),
    }
    if engines is not None:
        stats["engines"] = dict(engines)
    return AllocationResult(tuple(out), tuple(unalloc), stats)


def sequence_configurations(
    instrument: Instrument,
    targets: PlaneTargets,
    solve_one: Callable[[ConfigProblem], ConfigSolution],
    options: SequencingOptions | None = None,
    *,
    start_q: np.ndarray | None = None,
    fixed: dict[int, tuple[float, float]] | None = None,
    buffer_mm: float | None = None,
    time_limit_s: float = 60.0,
    seed: int = 0,
    progress: Progress | None = None,
    incompatibility: Incompatibility | None = None,
    exact_one: Callable[[ConfigProblem], ConfigSolution] | None = None,
    engines: dict[str, str] | None = None,
    budget: Budget | None = None,
    locks: LockColumns | None = None,
    excluded: Sequence[int] | None = None,
) -> AllocationResult:
    """Configurations until every reachable target is allocated or nothing more can be.

    ``solve_one``: the engine of one configuration; ``options``: the typed options of the
    loop and its post-passes (:class:`~solvers.sequencing.options.SequencingOptions`;
    fields left at None take the driver's defaults).  ``budget`` (on the caller's clock;
    default: ``time_limit_s`` from now) bounds the whole sequence, and its shares are
    fractions of its ``total_s`` (pending targets then get reason ``no_time``); ``config_time_limit_s`` caps
    each single solve, and with ``adaptive_limits`` each solve gets at most twice its share
    of the remaining time (remaining / ceil(pending / arms)), so a few hard configurations
    cannot starve the rest; a solve cut short reports ``feasible`` with its gap.
    ``max_configurations=1`` is the "one configuration" mode.  Unallocated targets:
    ``unreachable`` (no enabled arm reaches them), ``conflict`` (reachable but no further
    configuration could take them), ``no_time``, ``not_scheduled`` (beyond
    ``max_configurations``), ``beyond_park_move_limit`` (reached only by moves from park
    longer than ``SequenceOptions.park_move_limit_s``; counted in ``n_unreachable`` too).  ``incompatibility``: the structure, when the caller built it;
    ``exact_one``: the exact single-configuration solve the rescue uses for one leftover
    target at a time (default: CP-SAT); ``engines`` (which engine did which part) is
    returned as ``stats["engines"]``.  ``locks`` (target index -> (arm, branch or None)) and
    ``excluded`` (target indices) restrict the structure when it is built here (a caller's
    ``incompatibility`` must be built with them) and the rescue's; locked targets take
    precedence (:func:`precedence`).
    """
    budget = Budget.start(time_limit_s) if budget is None else budget
    opts = (SequencingOptions() if options is None else options).resolved()
    x = np.asarray(targets.x_mm, float)
    y = np.asarray(targets.y_mm, float)
    if incompatibility is None:
        incompatibility = incompatibility_for_targets(instrument, x, y, buffer_mm=buffer_mm, fixed=fixed,
                                                      blank_per_arm=opts.sequence.blank_per_arm, seed=seed,
                                                      park_move_limit_s=opts.sequence.park_move_limit_s,
                                                      locks=locks, excluded=excluded)
    t_inc = budget.elapsed_s()
    if progress:
        progress(PROGRESS_READY, "incompatibility ready")
    s = _initial_state(instrument, targets, incompatibility, start_q, seed, opts, sorted(locks or {}))
    s.timers["incompatibility_s"] = t_inc
    ctx = PassContext(opts, budget, solve_one, exact_one, fixed, buffer_mm, dict(locks or {}))
    _greedy(s, ctx, progress)
    for post_pass in POST_PASSES:
        if post_pass.applies(s, ctx):
            post_pass.run(s, ctx)
    result = _result(s, budget, engines)
    if progress:
        progress(1.0, "done")
    return result
