"""Sequencing of observational configurations until a field is complete (thesis 5.5).

The thesis protocol: allocate one configuration, remove its targets, repeat with the
pending ones until every target is observed.  Here:

* the reachability / incompatibility structure is computed ONCE for the whole field; each
  configuration is a :class:`ConfigProblem` over it with ``available`` = still pending;
* every solution is re-checked by :func:`solvers.problem.check_solution` (geometry, not the
  table) before it becomes a :class:`Configuration` — an unverified one raises;
* the next configuration's ``start_q`` is the previous configuration's arm positions
  (longest-move criterion, eq. 5.16);
* beyond the thesis: (1) a tie-break among equal-priority, equal-yield, equal-longest-move
  solutions in favour of hard-to-place targets — few arms reach them, or many pending
  targets crowd within 15 mm of them (near the FOV centre only one arm at a time fits, so
  a crowded spot must be started early) — with weights that cannot trade priority or
  yield away (solvers.ilp.safe_weights); (2) *repacking* by one multi-configuration CP-SAT
  model (:func:`pack_targets`: each pooled target exactly once, per-configuration eqs.
  5.13–5.15, configurations ordered to break symmetry): the under-filled tail into the
  b-matching bound (:func:`_repack_bulk`), then bottom-up the longest suffix of <= 200
  targets into as few configurations as bisection finds, keeping the longest prefix of
  maximum-priority configurations (:func:`_pack_fewest`), then one configuration fewer at
  a time (:func:`_repack_prefix`); (3) before that, a tabu search (solvers.packing) tries to
  pack the whole field into the best cheap lower bound, and it is also the first stage of
  every :func:`pack_targets` call.  Lower bounds (solvers.bounds: max-flow, crowding, the
  configuration LP bound, CP-SAT infeasibility) are reported, so a count can be shown
  optimal, and repacking never tries a count below them.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable

import numpy as np

from models.incompatibility import Incompatibility, incompatibility_for_targets
from models.instrument import Instrument
from models.types import AllocationResult, ArmAssignment, Configuration, PlaneTargets, Unallocated
from solvers.bounds import (
    INNER_DISCS_MM,
    configuration_lp_bound,
    crowding_lower_bound,
    matching_lower_bound,
)
from solvers.packing import tabu_pack
from solvers.packing_cpsat import exact_cover, max_cover, packing_columns
from solvers.problem import ConfigProblem, ConfigSolution, check_solution, evaluate
from solvers.repair import absorb_configurations

Progress = Callable[[float, str], None]


class UnverifiedConfigurationError(RuntimeError):
    """A back-end returned a configuration that fails the independent geometric re-check."""


# the whole-field CP-SAT packing at the floor pays up to this pool size: on weak 192 it
# found the perfect packings; on weak 384 (32.1 with the tabu search alone, 32.3 with it) it
# took the budget the prefix repacking needed to go from 33 to 32
MAX_COVER_POOL = 250


def joint_speeds(instrument: Instrument) -> np.ndarray:
    return np.column_stack([instrument.arm_array("joint1_speed_rad_s"), instrument.arm_array("joint2_speed_rad_s")])


def hard_to_place(incompatibility: Incompatibility, n_arms: int, xy_mm: np.ndarray | None = None,
                  pending: np.ndarray | None = None, crowding_radius_mm: float = 15.0) -> np.ndarray:
    """(n_targets,) tie-break weight: n_arms - (arms reaching the target), plus, with
    ``xy_mm``, the number of other still ``pending`` (default: reachable) targets within
    ``crowding_radius_mm`` — near the FOV centre arms converging on one spot collide, so a
    crowded neighbourhood can only be observed about one target per configuration and must
    be started early (see solvers.bounds.crowding_lower_bound); 0 if unreachable."""
    apt = incompatibility.reachability.arms_per_target
    h = np.where(apt > 0, n_arms - apt, 0).astype(np.int64)
    if xy_mm is not None and len(h):
        from scipy.spatial import cKDTree

        live = np.flatnonzero((apt > 0) if pending is None else (pending & (apt > 0)))
        if len(live):
            near = cKDTree(xy_mm[live]).query_ball_point(xy_mm[live], crowding_radius_mm, return_length=True)
            h[live] += np.asarray(near, np.int64) - 1
    return h


def make_configuration(index: int, problem: ConfigProblem, chosen: np.ndarray, targets: PlaneTargets,
                       status: str, stats: dict) -> Configuration:
    """One :class:`Configuration` with one ArmAssignment per arm (kind target/park/fixed)."""
    a = problem.assignments
    out = []
    for k, c in enumerate(np.asarray(chosen, int)):
        t = int(a.target[c])
        kind = "target" if t >= 0 else {-1: "park", -2: "fixed", -3: "blank"}.get(t, "fixed")
        out.append(ArmAssignment(k, kind, float(a.theta1_rad[c]), float(a.theta2_rad[c]), float(a.x_mm[c]),
                                 float(a.y_mm[c]), t if t >= 0 else None, targets.ids[t] if t >= 0 else None))
    total, yld, _ = evaluate(problem, chosen)
    return Configuration(index, tuple(out), total, yld, "optimal" if status == "optimal" else "feasible", stats)


def _verify(instrument: Instrument, problem: ConfigProblem, chosen: np.ndarray) -> None:
    errors = check_solution(instrument, problem, chosen)
    if errors:
        raise UnverifiedConfigurationError("; ".join(errors))


def sequence_configurations(
    instrument: Instrument,
    targets: PlaneTargets,
    solve_one: Callable[[ConfigProblem], ConfigSolution],
    *,
    max_configurations: int | None = None,
    start_q: np.ndarray | None = None,
    fixed: dict[int, tuple[float, float]] | None = None,
    buffer_mm: float | None = None,
    time_limit_s: float = 60.0,
    config_time_limit_s: float = 5.0,
    mip_rel_gap: float = 0.0,
    threads: int = 2,
    seed: int = 0,
    tie_break: bool | str = True,
    repack: bool = True,
    repair: bool = True,
    repair_time_limit_s: float = 5.0,
    repack_max_window: int = 6,
    repack_time_limit_s: float = 2.0,
    lp_bound_time_limit_s: float = 10.0,
    progress: Progress | None = None,
    incompatibility: Incompatibility | None = None,
    adaptive_limits: bool = True,
    lower_bound_flow: bool = True,
    rescue: bool = True,
    blank_per_arm: int = 0,
    tail_fraction: float = 0.0,
    exact_one: Callable[[ConfigProblem], ConfigSolution] | None = None,
    engines: dict[str, str] | None = None,
) -> AllocationResult:
    """Configurations until every reachable target is allocated or nothing more can be.

    ``time_limit_s`` bounds the whole sequence (pending targets then get reason
    ``no_time``); ``config_time_limit_s`` caps each single solve, and with
    ``adaptive_limits`` each solve gets at most twice its share of the remaining time
    (remaining / ceil(pending / arms)), so a few hard configurations cannot starve the
    rest; a solve cut short reports ``feasible`` with its gap.  ``lower_bound_flow`` adds
    ``stats["lower_bound_configurations_flow"]`` (:func:`matching_lower_bound`).  ``max_configurations=1`` is
    the "one configuration" mode.  ``rescue``: targets left as ``conflict`` (reachable only by
    arms that collide with a neighbour's rest location, e.g. a target on another arm's park
    spot) get extra configurations in which idle arms may rest on already observed targets
    (:func:`_rescue_conflicts`).  ``repair``: configurations are emptied by ejection chains
    over the whole sequence (:func:`solvers.repair.absorb_configurations`, no solver calls,
    at most ``repair_time_limit_s`` and half the time left) before the CP-SAT ``repack``.
    Unallocated targets: ``unreachable`` (no enabled arm
    reaches them), ``conflict`` (reachable but no further configuration could take them),
    ``no_time``.  ``exact_one``: the exact single-configuration solve the rescue uses for
    one leftover target at a time (default: CP-SAT); ``engines`` (which engine did which
    part) is returned as ``stats["engines"]``.
    """
    t0 = time.perf_counter()
    timers: dict[str, float] = {}
    n = len(targets)
    n_arms = instrument.n_arms
    x = np.asarray(targets.x_mm, float)
    y = np.asarray(targets.y_mm, float)
    if incompatibility is None:
        incompatibility = incompatibility_for_targets(instrument, x, y, buffer_mm=buffer_mm, fixed=fixed,
                                                      blank_per_arm=blank_per_arm, seed=seed)
    inc = incompatibility
    timers["incompatibility_s"] = time.perf_counter() - t0
    if progress:
        progress(0.05, "incompatibility ready")
    priority = np.asarray(targets.priority, dtype=np.int64)
    unreachable = np.zeros(n, bool)
    unreachable[inc.reachability.unreachable] = True
    pending = ~unreachable
    n_reachable = int(pending.sum())
    n_active = len(_active_arms(inc, n_arms))
    lower_bound = math.ceil(n_reachable / max(n_active, 1)) if n_reachable else 0
    flow_bound = matching_lower_bound(inc, pending) if (n_reachable and lower_bound_flow) else lower_bound
    speeds = joint_speeds(instrument)
    q = instrument.park_configuration.copy() if start_q is None else np.asarray(start_q, float).copy()
    q_start = q.copy()
    proven_bound = crowd_bound = lp_bound = floor_proof = 0
    xy = np.column_stack([x, y])
    tie = hard_to_place(inc, n_arms) if tie_break else None  # crowding term added per configuration
    configs: list[tuple[ConfigProblem, np.ndarray, str, dict]] = []
    t_solve = 0.0
    stop_reason = "complete"
    while pending.any():
        if max_configurations is not None and len(configs) >= max_configurations:
            stop_reason = "max_configurations"
            break
        remaining = time_limit_s - (time.perf_counter() - t0)
        if remaining <= 0.01:
            stop_reason = "no_time"
            break
        # per-configuration limit scaled to the remaining budget: what is left, shared by the
        # configurations still needed at best (ceil(pending / arms)), twice that for slack
        # (the hard ones are few); never above config_time_limit_s
        n_left = max(math.ceil(int(pending.sum()) / max(n_active, 1)), 1)
        # 10 % of the budget is held back for the repacking / rescue passes at the end
        share = max(remaining - 0.1 * time_limit_s, 0.05)
        limit_i = min(config_time_limit_s, remaining, max(2.0 * share / n_left, 0.05)) if adaptive_limits \
            else min(config_time_limit_s, remaining)
        if tie_break and tie_break != "reach":
            tie = hard_to_place(inc, n_arms, xy, pending)
        prob = ConfigProblem(inc, priority, pending.copy(), q, speeds, time_limit_s=limit_i,
                             mip_rel_gap=mip_rel_gap, threads=threads, seed=seed + len(configs),
                             target_xy_mm=xy, tie_break=tie)
        ts = time.perf_counter()
        sol = solve_one(prob)
        dt = time.perf_counter() - ts
        t_solve += dt
        if sol.status in ("timeout", "infeasible") or (sol.chosen < 0).any():
            stop_reason = f"solver_{sol.status}"
            break
        _verify(instrument, prob, sol.chosen)
        tg = prob.assignments.target[sol.chosen]
        tg = tg[tg >= 0]
        if not len(tg):
            stop_reason = "conflict"
            break
        stats = {"solve_s": dt, "status": sol.status, "gap": sol.gap, "longest_move_s": sol.longest_move_s,
                 "time_limit_s": limit_i}
        configs.append((prob, sol.chosen, sol.status, stats))
        pending[tg] = False
        q = prob.assignments.q[sol.chosen]
        if rescue and len(tg) < n_active and 0 < pending.sum() <= tail_fraction * n_reachable:
            # the under-filled tail: what is left is mostly blocked by parked neighbours;
            # finish it where idle arms may rest on observed targets (_rescue_conflicts)
            stop_reason = "tail"
            break
        if progress:
            progress(0.05 + 0.85 * (1 - pending.sum() / max(n_reachable, 1)), f"configuration {len(configs)}")
    timers["sequence_s"] = t_solve
    greedy_count = len(configs)
    # rescue BEFORE the tail repacking: completeness first, the configuration count second
    extra: list[Configuration] = []
    if rescue and stop_reason in ("conflict", "tail") and pending.any() and (max_configurations is None
                                                                   or len(configs) < max_configurations):
        tr = time.perf_counter()
        q_last = configs[-1][0].assignments.q[configs[-1][1]] if configs else q
        extra = _rescue_conflicts(instrument, targets, priority, np.flatnonzero(pending), ~pending & ~unreachable,
                                  q_last, solve_one, fixed, buffer_mm, speeds, len(configs),
                                  t0 + time_limit_s, config_time_limit_s, threads, seed,
                                  None if max_configurations is None else max_configurations - len(configs),
                                  exact_one=exact_one)
        timers["rescue_s"] = time.perf_counter() - tr
        for c in extra:
            pending[_observed(c)] = False
        stop_reason = "complete" if not pending.any() else "conflict"
    if repair and stop_reason in ("complete", "conflict", "tail") and len(configs) + len(extra) > lower_bound:
        # ejection repair first (fast, the whole sequence), then the CP-SAT repacking
        tr = time.perf_counter()
        n0 = len(configs) + len(extra)
        rescued_t = [_observed(c) for c in extra]
        left = time_limit_s - min(0.1 * time_limit_s, 1.0) - (tr - t0)
        new, absorbed_g = absorb_configurations(inc, [ch for _, ch, _, _ in configs], priority,
                                                budget_s=min(0.5 * left, repair_time_limit_s),
                                                loose=rescued_t, min_keep=lower_bound)
        configs = _rebuild(instrument, inc, priority, configs, new, speeds, xy, tie, q_start)
        extra = [c for c, g in zip(extra, absorbed_g, strict=True) if not g]
        timers["repair_s"] = time.perf_counter() - tr
        timers["repair_saved"] = n0 - len(configs) - len(extra)
    if repack and stop_reason in ("complete", "conflict", "tail") and len(configs) + len(extra) > lower_bound:
        tr = time.perf_counter()
        # up to 1 s kept back: building a model and verifying the result are not covered by
        # the solver's own time limit (0.5 s let a 10 s call on 384 targets overrun by 0.8 s)
        budget = min(time_limit_s - min(0.1 * time_limit_s, 1.0) - (tr - t0),
                     max(repack_time_limit_s * 4 * repack_max_window, 0.5 * time_limit_s))
        n0 = len(configs)
        if not extra:
            configs = _repack_bulk(instrument, inc, priority, configs, lower_bound, speeds, xy, tie,
                                   min(0.4 * budget, 3 * repack_time_limit_s), seed, threads)
        timers["repack_bulk_s"] = time.perf_counter() - tr
        timers["repack_bulk_saved"] = n0 - len(configs)
        budget = min(time_limit_s - (time.perf_counter() - t0), budget - (time.perf_counter() - tr))
        rescued = [_observed(c) for c in extra]
        n1 = len(configs) + len(extra)
        if n_reachable <= 400 and budget > 2.0:  # beyond that the disc models cost too much
            tc = time.perf_counter()
            crowd_bound, _ = crowding_lower_bound(inc, xy, ~unreachable, time_limit_s=min(0.5, budget / 20),
                                                  radii_mm=INNER_DISCS_MM)
            timers["crowding_bound_s"] = time.perf_counter() - tc
            floor = max(lower_bound, flow_bound, crowd_bound)
            observed = [_observed_chosen(inc, ch) for _, ch, _, _ in configs]
            if n1 > floor:
                # a packing at the bound is optimal and makes every proof unnecessary: a short
                # tabu search over the whole field first (the one-at-a-time prefix is given up
                # for it; the packed configurations are ordered by total priority)
                ts = time.perf_counter()
                pool = np.concatenate(observed + rescued)
                hint = [ch for _, ch, _, _ in configs]
                tabu_s = min(0.15 * budget, 5.0)
                if floor == math.ceil(len(pool) / max(n_active, 1)) and len(pool) <= MAX_COVER_POOL:
                    # the floor is the count bound alone (no crowding): CP-SAT's max-cover
                    # model finds packings there that the tabu search misses (weak-192
                    # fields into 16: 6-41 s), and its exact-cover model proves the others
                    # infeasible in seconds — worth most of the budget, as a packing here
                    # is optimal, all of it but the LP bound's when the sequence is one above
                    # the floor.  From further above, CP-SAT's best partial packing at the
                    # floor plus its leftovers in one more configuration usually gets one
                    # above (weak 192 at 0.6 of the budget and nothing else: fields 4 and 8
                    # kept 18, the repacking to 17 had too little time left after it)
                    left = budget - (time.perf_counter() - tc)
                    st: dict = {}
                    partial: list = []
                    limit = max(left - 2.0 if n1 == floor + 1 else 0.7 * left, tabu_s)
                    packed = pack_targets(inc, pool, floor, time_limit_s=limit, seed=seed, threads=threads,
                                          hint=hint, status_out=st, tabu_fraction=tabu_s / limit,
                                          proof_fraction=0.25, partial_out=partial)
                    if packed is None and partial and n1 > floor + 1:
                        packed = complete_partial(inc, pool, partial, n1 - 1, time_limit_s=min(
                            5.0, budget - (time.perf_counter() - tc) - 1.0), seed=seed, threads=threads)
                    if st["infeasible"] and (not rescued or len(pool) >= n_active * floor):
                        floor_proof = floor = floor + 1
                else:
                    packed = tabu_pack(inc, pool, floor, seed=seed, time_limit_s=tabu_s, hint=hint)
                if packed is not None:
                    configs = _replace_tail(instrument, inc, priority, configs, len(configs), packed, speeds, xy,
                                            tie, time.perf_counter() - ts, q_start)
                    extra, rescued = [], []
                timers["packing_at_bound_s"] = time.perf_counter() - ts
            lp_s = min(lp_bound_time_limit_s, 0.3 * budget, budget - 1.0 - (time.perf_counter() - tc))
            if len(configs) + len(extra) > floor and lp_s > 0.5:
                # the LP bound finds crowded clusters anywhere (not only about the centre); it
                # stops once it proves the current count, and then nothing is left to repack
                mask = np.zeros(n, bool)
                for o in observed + rescued:
                    mask[o] = True
                lp_bound, _ = configuration_lp_bound(inc, mask, time_limit_s=lp_s,
                                                     columns=observed + rescued, stop_at=n1, seed=seed,
                                                     threads=threads)
            timers["lower_bounds_s"] = time.perf_counter() - tc
            budget -= timers["lower_bounds_s"]
        configs, proven_bound, absorbed = _repack_prefix(
            instrument, inc, priority, configs, max(lower_bound, flow_bound, crowd_bound, lp_bound, floor_proof),
            speeds, xy,
            tie, repack_time_limit_s, budget, seed, threads, q0=q_start, rescued=rescued)
        if absorbed:
            extra = []
        timers["repack_s"] = time.perf_counter() - tr
        timers["repack_saved"] = n1 - len(configs) - len(extra)
    # build outputs
    out = []
    for i, (prob, chosen, status, stats) in enumerate(configs):
        out.append(make_configuration(i, prob, chosen, targets, status, stats))
    for i, c in enumerate(extra):
        out.append(dataclasses.replace(c, index=len(configs) + i))
    allocated = np.zeros(n, bool)
    for c in out:
        for a in c.assignments:
            if a.target_index is not None:
                allocated[a.target_index] = True
    reason_left = "no_time" if stop_reason in ("no_time", "solver_timeout") else "conflict"
    if stop_reason == "max_configurations":  # left for configurations the request did not ask for
        reason_left = "not_scheduled"
    unalloc = []
    for i in np.flatnonzero(~allocated):
        unalloc.append(Unallocated(int(i), targets.ids[i], "unreachable" if unreachable[i] else reason_left))
    total_p = sum(int(p) for p in priority)
    got_p = sum(int(p) for p in priority[allocated])
    timers["total_s"] = time.perf_counter() - t0
    stats = {
        "n_targets": n,
        "n_reachable": n_reachable,
        "n_configurations": len(out),
        "n_configurations_greedy": greedy_count,
        "lower_bound_configurations": lower_bound,
        "lower_bound_configurations_flow": flow_bound,
        # CP-SAT proved the allocated targets cannot be packed into fewer configurations
        "lower_bound_configurations_proven": max(proven_bound, flow_bound, crowd_bound, lp_bound, floor_proof),
        "lower_bound_configurations_crowding": crowd_bound,
        "lower_bound_configurations_lp": lp_bound,
        "field_completeness": float(allocated.sum() / n) if n else 1.0,
        "reachable_completeness": float(allocated.sum() / n_reachable) if n_reachable else 1.0,
        "priority_completeness": got_p / total_p if total_p else 1.0,
        "stop_reason": stop_reason,
        "per_configuration": [{"total_priority": c.total_priority, "arm_yield": c.arm_yield, "status": c.status,
                               "solve_s": c.stats.get("solve_s")} for c in out],
        "timers_s": timers,
        "incompatibility": inc.counts(),
    }
    if engines is not None:
        stats["engines"] = dict(engines)
    if progress:
        progress(1.0, "done")
    return AllocationResult(tuple(out), tuple(unalloc), stats)


def _observed(c: Configuration) -> np.ndarray:
    """Target indices a built configuration observes."""
    return np.array([a.target_index for a in c.assignments if a.target_index is not None], np.int64)


def _observed_chosen(inc: Incompatibility, chosen: np.ndarray) -> np.ndarray:
    """Target indices observed by the (n_arms,) chosen assignment indices."""
    tg = inc.assignments.target[chosen]
    return tg[tg >= 0]


def _active_arms(inc: Incompatibility, n_arms: int) -> list[int]:
    a = inc.assignments
    return [k for k in range(n_arms) if (a.target[a.of_arm(k)] >= 0).any()]


# ------------------------------------------------------------------------------ tail repacking


def pack_targets(inc: Incompatibility, pool: np.ndarray, n_configs: int, *, time_limit_s: float,
                 seed: int = 0, threads: int = 2, hint: list[np.ndarray] | None = None,
                 status_out: dict | None = None, tabu_fraction: float = 0.4,
                 proof_fraction: float = 1.0, partial_out: list | None = None) -> list[np.ndarray] | None:
    """Multi-configuration model: place every pooled target in one of ``n_configs``
    configurations (each obeying eqs. 5.13–5.15).  Returns the chosen assignment indices
    per configuration, or None when no packing was found in time.  Three stages share the
    time: the tabu search of :mod:`solvers.packing` (``tabu_fraction``), then CP-SAT's
    exact-cover model (``proof_fraction`` of what is left; it proves infeasibility fast),
    then, when that is below 1, CP-SAT's max-cover model for the rest (it finds the hard
    perfect packings; the repacking windows keep exact cover alone, which took weak-192
    fields 5 and 8 from 18 to their proven 17 where the split left them at 18) — see
    :mod:`solvers.packing_cpsat`.  ``status_out["infeasible"]`` is set True when CP-SAT
    proves that no packing exists.  ``partial_out`` (optional list) receives the max-cover
    model's best partial packing when there is no packing (valid configurations that leave
    some pooled targets out)."""
    if status_out is not None:
        status_out["infeasible"] = False
    t0 = time.perf_counter()
    partial = None
    if tabu_fraction > 0:
        # the tabu search finds most packings that exist in a fraction of a second
        partial: list = []
        found = tabu_pack(inc, pool, n_configs, time_limit_s=tabu_fraction * time_limit_s, seed=seed, hint=hint,
                          partial_out=partial)
        if found is not None:
            return found
    m = packing_columns(inc, pool)
    if m is None:
        return None
    left = time_limit_s - (time.perf_counter() - t0)
    out = exact_cover(inc, m, pool, n_configs, time_limit_s=proof_fraction * left if proof_fraction < 1 else left,
                      seed=seed, threads=threads, hint=hint)
    if out.packing is None and not out.infeasible and proof_fraction < 1:
        left = time_limit_s - (time.perf_counter() - t0)
        # the tabu search's best partial packing is the better start: CP-SAT's LNS improves on it
        out = max_cover(inc, m, pool, n_configs, time_limit_s=left, seed=seed, threads=threads,
                        hint=partial or hint)
        if out.partial is not None and partial_out is not None:
            partial_out.extend(out.partial)
    if status_out is not None:
        status_out["infeasible"] = out.infeasible
    return out.packing


def complete_partial(inc: Incompatibility, pool: np.ndarray, partial: list[np.ndarray], max_configs: int, *,
                     time_limit_s: float, seed: int = 0, threads: int = 2) -> list[np.ndarray] | None:
    """A packing of ``pool`` into at most ``max_configs`` configurations from a partial one
    (valid configurations that leave some pooled targets out): its configurations that
    observe something, plus the leftover targets packed by CP-SAT's max-cover model into
    as few more as fit.  None when they do not fit in time."""
    a = inc.assignments
    kept = [ch for ch in partial if (a.target[ch] >= 0).any()]
    seen = np.concatenate([a.target[ch] for ch in kept]) if kept else np.zeros(0, np.int64)
    leftover = np.setdiff1d(pool, seen[seen >= 0])
    if not len(leftover):
        return kept if len(kept) <= max_configs else None
    m = packing_columns(inc, leftover)
    if m is None:
        return None
    t0 = time.perf_counter()
    for n in range(1, max_configs - len(kept) + 1):
        left = time_limit_s - (time.perf_counter() - t0)
        if left <= 0.1:
            return None
        out = max_cover(inc, m, leftover, n, time_limit_s=left, seed=seed, threads=threads)
        if out.packing is not None:
            return kept + out.packing
    return None


def _replace_tail(instrument, inc, priority, configs, window, packed, speeds, xy, tie, dt, q0=None):
    """The last ``window`` configurations replaced by the verified ``packed`` ones, highest
    priority first (:func:`_rebuild`; the first starts at ``q0``, default park, when nothing
    is kept)."""
    a = inc.assignments
    packed.sort(key=lambda ch: -sum(int(priority[t]) for t in a.target[ch] if t >= 0))
    head = [ch for _, ch, _, _ in configs[:-window]]
    return _rebuild(instrument, inc, priority, configs, head + packed, speeds, xy, tie,
                    instrument.park_configuration if q0 is None else q0, status="repacked",
                    solve_s=dt / max(len(packed), 1))


def _rebuild(instrument, inc, priority, configs, new_chosen, speeds, xy, tie, q0, status: str = "repaired",
             solve_s: float = 0.0):
    """``configs`` with their chosen assignments replaced by ``new_chosen``: the unchanged
    leading configurations are kept, the rest rebuilt and verified geometrically, each
    starting where the previous one left the arms (the first at ``q0``)."""
    same = 0
    while (same < min(len(configs), len(new_chosen))
           and np.array_equal(configs[same][1], new_chosen[same])):
        same += 1
    if same == len(configs) == len(new_chosen):
        return configs
    a = inc.assignments
    head = configs[:same]
    q = head[-1][0].assignments.q[head[-1][1]] if head else q0
    pending = np.zeros(len(priority), bool)
    for ch in new_chosen[same:]:
        tg = a.target[ch]
        pending[tg[tg >= 0]] = True
    out = list(head)
    for ch in new_chosen[same:]:
        prob = ConfigProblem(inc, priority, pending.copy(), q, speeds, target_xy_mm=xy, tie_break=tie)
        _verify(instrument, prob, ch)
        tg = a.target[ch]
        pending[tg[tg >= 0]] = False
        out.append((prob, ch, "feasible", {"solve_s": solve_s, "status": status,
                                           "longest_move_s": evaluate(prob, ch)[2]}))
        q = a.q[ch]
    return out


def _repack_bulk(instrument, inc, priority, configs, lower_bound, speeds, xy, tie, budget_s, seed, threads):
    """Re-pack the whole under-filled tail at once.

    One-at-a-time sequencing leaves the hard-to-place targets (few arms reach them) for
    the end, where they fill configurations one or two at a time.  The tail is the longest
    suffix whose configurations are not all full (plus the one before it); its targets are
    packed by :func:`pack_targets` into as few configurations as the b-matching bound
    (:func:`matching_lower_bound`) allows, then one more at a time while it fails.
    """
    t0 = time.perf_counter()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    yields = [int((a.target[ch] >= 0).sum()) for _, ch, _, _ in configs]
    full = max(yields, default=0)
    w = 0
    while w < len(configs) and yields[len(configs) - 1 - w] < full:
        w += 1
    window = min(w + 1, len(configs))
    if w < 2:
        return configs
    tail = configs[-window:]
    pool = np.concatenate([_observed_chosen(inc, ch) for _, ch, _, _ in tail])
    mask = np.zeros(inc.reachability.n_targets, bool)
    mask[pool] = True
    need = max(matching_lower_bound(inc, mask), math.ceil(len(pool) / max(n_arms, 1)),
               lower_bound - (len(configs) - window))
    c = need
    while c < window:
        left = budget_s - (time.perf_counter() - t0)
        if left <= 0.5:
            break
        ts = time.perf_counter()
        packed = pack_targets(inc, pool, c, time_limit_s=min(left, max(left / max(window - c, 1), 0.5)),
                              seed=seed + 20_000 + c, threads=threads, hint=[ch for _, ch, _, _ in tail])
        if packed is not None:
            return _replace_tail(instrument, inc, priority, configs, window, packed, speeds, xy, tie,
                                 time.perf_counter() - ts)
        c += 1
    return configs


def _pack_fewest(instrument, inc, priority, configs, extra, lower_bound, speeds, xy, tie, attempt_s,
                 refine_s, budget_s, seed, threads, max_pool, q0):
    """Bottom-up repacking: the longest suffix of at most ``max_pool`` targets (plus the
    rescued ``extra`` ones) is packed into as few configurations as possible, trying
    lower_bound, lower_bound + 1, ... and stopping at the first success; then the longest
    prefix of the original configurations that still allows that count is searched by
    bisection (feasibility is monotone in the prefix length).  Returns None when nothing was
    tried, else (configurations, proven lower bound, packed?)."""
    t0 = time.perf_counter()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    n_active = len(_active_arms(inc, n_arms))
    n_main = len(configs)
    per = [_observed_chosen(inc, ch) for _, ch, _, _ in configs] + list(extra)
    n = len(per)
    sizes = np.array([len(t) for t in per])
    suffix = np.cumsum(sizes[::-1])[::-1]
    ok = np.flatnonzero(suffix[:n_main] <= max_pool)
    if not len(ok) or n <= lower_bound:
        return None
    h0 = int(ok.min())
    proven = lower_bound

    n_attempts = [0]

    def attempt(h: int, count: int, limit: float):
        pool = np.concatenate(per[h:])
        st: dict = {}
        # a seed per attempt: the same pool, count and hint with the same seed would repeat
        # the earlier tabu search step for step
        n_attempts[0] += 1
        packed = pack_targets(inc, pool, count - h, time_limit_s=limit, seed=seed + 101 * n_attempts[0],
                              threads=threads,
                              hint=[ch for _, ch, _, _ in configs[h:]], status_out=st)
        return packed, pool, st["infeasible"]

    best = None
    # bisection on the count (a time-out counts as a failure, so the result is the fewest
    # configurations found, not necessarily the fewest that exist)
    lo, hi = max(lower_bound, h0 + math.ceil(suffix[h0] / n_arms)), n - 1
    while lo <= hi:
        left = budget_s - (time.perf_counter() - t0)
        if left <= 0.5:
            break
        count = (lo + hi) // 2
        ts = time.perf_counter()
        # the attempts the bisection still needs share what is left (at least attempt_s each)
        share = left / max(1, math.ceil(math.log2(hi - lo + 2)))
        packed, pool, infeasible = attempt(h0, count, min(left, max(attempt_s, share)))
        if packed is not None:
            best = (h0, count, packed, pool, time.perf_counter() - ts)
            hi = count - 1
        else:
            lo = count + 1
            # with rescued targets in the pool the model (park rests only) is stricter than
            # the rescue, which may rest idle arms on blank sky — unless the pool fills every
            # active arm of every configuration, when no arm rests at all
            if infeasible and h0 == 0 and (not extra or len(pool) >= n_active * count):
                proven = max(proven, count + 1)
    if best is None:
        return configs, proven, False
    h_lo, count = best[0], best[1]
    fits = np.flatnonzero(suffix[:n_main] <= n_arms * (count - np.arange(n_main)))
    h_hi = int(fits.max()) if len(fits) else h_lo
    while h_lo < h_hi:  # keep as many maximum-priority configurations as the count allows
        left = budget_s - (time.perf_counter() - t0)
        if left <= 0.5:
            break
        mid = (h_lo + h_hi + 1) // 2
        ts = time.perf_counter()
        packed, pool, _ = attempt(mid, count, min(left, refine_s))
        if packed is not None:
            best, h_lo = (mid, count, packed, pool, time.perf_counter() - ts), mid
        else:
            h_hi = mid - 1
    h, count, packed, pool, dt = best
    return _replace_tail(instrument, inc, priority, configs, n_main - h, packed, speeds, xy, tie, dt,
                         q0), proven, True


def _repack_prefix(instrument, inc, priority, configs, lower_bound, speeds, xy, tie, attempt_s, budget_s,
                   seed, threads, max_pool: int = 400, q0=None, bottom_pool: int = 200,
                   rescued: list[np.ndarray] | None = None) -> tuple[list, int, bool]:
    """One configuration fewer at a time, keeping the longest possible prefix of
    one-at-a-time (maximum-priority, thesis 5.5) configurations.

    To go from n to n - 1 configurations, the suffix starting at configuration h is re-packed
    by :func:`pack_targets` into n - 1 - h configurations, for h = the largest index whose
    suffix fits 12 (n - 1 - h) targets, then h - 1, ... 0: feasibility is monotone in h
    (a packing of a suffix plus the configuration before it is a packing of the longer
    suffix), so the first success keeps the longest prefix.  Repeats while it succeeds.

    ``rescued``: the targets of the rescue configurations (:func:`_rescue_conflicts`),
    which come after ``configs``; they join every pool, because in a packing where every
    arm observes a target no arm is parked, so a target on a park spot needs no rescue.
    Returns the configurations, a proven lower bound on their count (when the whole field,
    h = 0, cannot be packed into n - 1, CP-SAT proves n optimal) and whether the rescued
    targets were absorbed into ``configs`` (then the rescue configurations are void).
    """
    t0 = time.perf_counter()
    a = inc.assignments
    n_arms = len(a.arm_start) - 1
    n_active = len(_active_arms(inc, n_arms))
    proven = lower_bound
    extra = list(rescued or [])
    kept = 0  # rescue configurations kept apart after their targets failed to fit any packing
    n_attempts = 0
    # bottom-up first: the fewest configurations the suffix that fits the model can reach
    for use_extra in ((True, False) if extra else (False,)):
        # at most half the budget: when the big model times out, small windows still help
        left = 0.5 * budget_s - (time.perf_counter() - t0)
        res = _pack_fewest(instrument, inc, priority, configs, extra if use_extra else [],
                           max(lower_bound, proven) - (0 if use_extra else len(extra)), speeds, xy, tie,
                           2.5 * attempt_s, attempt_s, left, seed, threads, bottom_pool, q0)
        if res is None:
            continue
        configs, proven_here, packed = res
        proven = max(proven, proven_here)
        if packed:  # the rescue configurations are absorbed, or kept apart
            if not use_extra:
                kept, extra = len(extra), []
            else:
                extra = []
            break
    while len(configs) + len(extra) + kept > max(lower_bound, proven):
        n_main = len(configs)
        n = n_main + len(extra)
        per = [_observed_chosen(inc, ch) for _, ch, _, _ in configs] + extra
        sizes = np.array([len(t) for t in per])
        suffix = np.cumsum(sizes[::-1])[::-1]  # targets in configs[h:] and the rescued ones
        fits = np.flatnonzero(suffix[:n_main] <= n_arms * (n - 1 - np.arange(n_main)))
        if not len(fits):
            if extra:
                kept, extra = len(extra), []
                continue
            break
        found = False
        for h in range(int(fits.max()), -1, -1):
            left = budget_s - (time.perf_counter() - t0)
            if left <= 0.5 or suffix[h] > max_pool:
                return configs, proven, not (extra or kept)
            pool = np.concatenate(per[h:])
            st: dict = {}
            ts = time.perf_counter()
            n_attempts += 1  # a seed per attempt, as in _pack_fewest
            packed = pack_targets(inc, pool, n - 1 - h, time_limit_s=min(left, attempt_s),
                                  seed=seed + 50_000 + 101 * n_attempts, threads=threads,
                                  hint=[ch for _, ch, _, _ in configs[h:]], status_out=st)
            if packed is not None:
                configs = _replace_tail(instrument, inc, priority, configs, n_main - h, packed, speeds, xy, tie,
                                        time.perf_counter() - ts, q0)
                extra, found = [], True
                break
            if h == 0 and st["infeasible"] and (not extra or len(pool) >= n_active * (n - 1)):
                # (with rescued targets in the pool the model is stricter than the rescue,
                # which may rest idle arms on blank sky: no proof then)
                proven = max(proven, n)
        if not found:
            if extra:  # the rescued targets need blank-sky rests: pack the rest without them
                kept, extra = len(extra), []
                continue
            break
    return configs, proven, not (extra or kept)


# ------------------------------------------------------------------------ conflict rescue


def _rescue_conflicts(instrument, targets, priority, left, done, q, solve_one, fixed, buffer_mm, speeds,
                      first_index, deadline, config_time_limit_s, threads, seed, max_configs,
                      n_fill: int = 200, blank_per_arm: int = 16,
                      exact_one: Callable[[ConfigProblem], ConfigSolution] | None = None) -> list[Configuration]:
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
    """
    if exact_one is None:
        from solvers.ilp import solve_ilp_cpsat

        def exact_one(p: ConfigProblem) -> ConfigSolution:
            return solve_ilp_cpsat(p, minimize_move=False, candidates_per_arm=None)

    x = np.asarray(targets.x_mm, float)
    y = np.asarray(targets.y_mm, float)
    fill = np.flatnonzero(done)
    if len(fill):
        d = np.min(np.hypot(x[fill, None] - x[None, left], y[fill, None] - y[None, left]), axis=1)
        fill = fill[np.argsort(d, kind="stable")[:max(n_fill, 2 * len(left))]]
    sub = np.r_[left, fill].astype(np.int64)
    nl = len(left)
    inc = incompatibility_for_targets(instrument, x[sub], y[sub], buffer_mm=buffer_mm, fixed=fixed,
                                      blank_per_arm=blank_per_arm, seed=seed)
    pr = np.r_[priority[left], np.zeros(len(fill), np.int64)]
    pend = np.zeros(len(sub), bool)
    pend[:nl] = True
    pend[:nl] &= inc.reachability.arms_per_target[:nl] > 0
    xy = np.column_stack([x[sub], y[sub]])
    sub_targets = targets.subset(sub)
    out: list[Configuration] = []
    while pend[:nl].any() and (max_configs is None or len(out) < max_configs):
        remaining = deadline - time.perf_counter()
        if remaining <= 0.01:
            break
        avail = pend.copy()
        avail[nl:] = True
        prob = ConfigProblem(inc, pr, avail, q, speeds, time_limit_s=min(config_time_limit_s, remaining),
                             threads=threads, seed=seed + first_index + len(out), target_xy_mm=xy)
        ts = time.perf_counter()
        sol = solve_one(prob)
        dt = time.perf_counter() - ts
        if sol.status in ("timeout", "infeasible") or (sol.chosen < 0).any():
            break
        _verify(instrument, prob, sol.chosen)
        tg = prob.assignments.target[sol.chosen]
        real = tg[(tg >= 0) & (tg < nl)]
        if not len(real):
            # nothing jointly: one leftover target at a time, by an exact ILP engine (a
            # node-limited branch-and-bound wanders in the zero-weight rest placements and
            # may miss it)
            for i in np.flatnonzero(pend[:nl]):
                if deadline - time.perf_counter() <= 0.01:
                    break
                av1 = np.zeros(len(sub), bool)
                av1[i] = True
                av1[nl:] = True
                p1 = dataclasses.replace(prob, available=av1, time_limit_s=min(config_time_limit_s,
                                                                              deadline - time.perf_counter()))
                s1 = exact_one(p1)  # exact, small
                if s1.status in ("optimal", "feasible") and (s1.chosen >= 0).all() and \
                        i in p1.assignments.target[s1.chosen]:
                    prob, sol = p1, s1
                    _verify(instrument, prob, sol.chosen)
                    tg = prob.assignments.target[sol.chosen]
                    real = tg[(tg >= 0) & (tg < nl)]
                    break
            if not len(real):
                break
        pend[real] = False
        c = make_configuration(first_index + len(out), prob, sol.chosen, sub_targets, sol.status,
                               {"solve_s": dt, "status": sol.status, "gap": sol.gap,
                                "longest_move_s": sol.longest_move_s, "rescue": True})
        assigns = []
        for a_ in c.assignments:
            if a_.target_index is not None and a_.target_index >= nl:  # resting on an observed target
                a_ = dataclasses.replace(a_, kind="blank", target_index=None, target_id=None)
            elif a_.target_index is not None:
                a_ = dataclasses.replace(a_, target_index=int(sub[a_.target_index]))
            assigns.append(a_)
        out.append(dataclasses.replace(c, assignments=tuple(assigns), arm_yield=len(real)))
        q = prob.assignments.q[sol.chosen]
    return out
