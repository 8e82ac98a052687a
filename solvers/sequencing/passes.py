"""The named post-passes of a sequence, tried in order after the greedy loop.

Each pass is an object with ``name``, ``applies(state, ctx)`` and ``run(state, ctx)`` over
one :class:`~solvers.sequencing.state.SequenceState`; :data:`POST_PASSES` is the order:

1. :class:`RescuePass` — completeness first: targets left ``conflict`` get configurations in
   which idle arms may rest on observed sky (:mod:`solvers.sequencing.rescue`);
2. :class:`RepairPass` — ejection chains empty configurations over the whole sequence, no
   solver calls (:mod:`solvers.sequencing.repair`);
3. :class:`BulkPackingPass` — the under-filled tail into the b-matching bound (it opens the
   repacking budget that the next two share);
4. :class:`BoundsPass` — the crowding bound, a packing of the whole field at the best cheap
   bound (a packing there is optimal), and the configuration LP bound;
5. :class:`PrefixPackingPass` — bottom-up, then one configuration fewer at a time, never
   below the bounds.

The time each gets is computed by :class:`solvers.sequencing.shares.SequenceShares`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from models import clock
from models.budget import Budget
from solvers.problem import ConfigProblem, ConfigSolution
from solvers.sequencing.bounds import INNER_DISCS_MM, configuration_lp_bound, crowding_lower_bound
from solvers.sequencing.options import SequencingOptions
from solvers.sequencing.packing import complete_partial, pack_targets
from solvers.sequencing.repack import repack_bulk, repack_prefix
from solvers.sequencing.repair import absorb_configurations
from solvers.sequencing.rescue import rescue_conflicts
from solvers.sequencing.shares import SHARES
from solvers.sequencing.state import SequenceState, observed, observed_chosen, rebuild, replace_tail
from solvers.sequencing.tabu import tabu_pack

__all__ = ["POST_PASSES", "BoundsPass", "BulkPackingPass", "PassContext", "PrefixPackingPass", "RepairPass",
           "RescuePass"]


@dataclass(frozen=True)
class PassContext:
    """What the passes read and never change: the options, the call's budget, the engines."""

    options: SequencingOptions
    budget: Budget
    solve_one: Callable[[ConfigProblem], ConfigSolution]
    exact_one: Callable[[ConfigProblem], ConfigSolution] | None
    fixed: dict[int, tuple[float, float]] | None
    buffer_mm: float | None
    #: target index -> (arm, branch or None): the rescue's structure keeps them (models.locks)
    locks: dict[int, tuple[int, int | None]] = field(default_factory=dict)


class RescuePass:
    name = "rescue"

    def applies(self, s: SequenceState, ctx: PassContext) -> bool:
        mc = ctx.options.sequence.max_configurations
        return (ctx.options.rescue.enabled and s.stop_reason in ("conflict", "tail") and bool(s.pending.any())
                and (mc is None or len(s.steps) < mc))

    def run(self, s: SequenceState, ctx: PassContext) -> None:
        tr = clock.now()
        mc = ctx.options.sequence.max_configurations
        q_last = s.steps[-1].problem.assignments.q[s.steps[-1].chosen] if s.steps else s.q
        s.extra = rescue_conflicts(s.instrument, s.targets, s.priority, np.flatnonzero(s.pending),
                                   ~s.pending & ~s.unreachable, q_last, ctx.solve_one, ctx.fixed, ctx.buffer_mm,
                                   s.speeds, len(s.steps), ctx.budget,
                                   ctx.options.sequence.config_time_limit_s, s.threads, s.seed,
                                   None if mc is None else mc - len(s.steps), exact_one=ctx.exact_one,
                                   park_move_limit_s=ctx.options.sequence.park_move_limit_s, locks=ctx.locks)
        for c in s.extra:
            s.pending[observed(c)] = False
        self._locked_again(s, ctx)
        s.timers["rescue_s"] = clock.now() - tr
        s.stop_reason = "complete" if not s.pending.any() else "conflict"

    def _locked_again(self, s: SequenceState, ctx: PassContext) -> None:
        """Locked targets the rescue left: tried again, each alone, with four times the blank-sky
        rests on another sample. A locked target has one arm (and branch), so it cannot go to an
        arm whose neighbours have room: the neighbours must make room, and the rescue's
        sample of rest locations is what decides whether they can."""
        mc = ctx.options.sequence.max_configurations
        for t in [int(t) for t in np.flatnonzero(s.pending) if int(t) in ctx.locks]:
            if mc is not None and s.n_configurations >= mc:
                break
            q_last = s.extra[-1].q if s.extra else (
                s.steps[-1].problem.assignments.q[s.steps[-1].chosen] if s.steps else s.q)
            more = rescue_conflicts(s.instrument, s.targets, s.priority, np.array([t]), ~s.pending & ~s.unreachable,
                                    q_last, ctx.solve_one, ctx.fixed, ctx.buffer_mm, s.speeds, s.n_configurations,
                                    ctx.budget, ctx.options.sequence.config_time_limit_s, s.threads, s.seed + 1, 1,
                                    exact_one=ctx.exact_one, blank_per_arm=4 * SHARES.rescue_blank_per_arm,
                                    park_move_limit_s=ctx.options.sequence.park_move_limit_s, locks=ctx.locks)
            for c in more:
                s.pending[observed(c)] = False
            s.extra += more


class RepairPass:
    name = "repair"

    def applies(self, s: SequenceState, ctx: PassContext) -> bool:
        return ctx.options.repair.enabled and s.finished_normally() and s.n_configurations > s.lower_bound

    def run(self, s: SequenceState, ctx: PassContext) -> None:
        tr = clock.now()
        n0 = s.n_configurations
        rescued_t = [observed(c) for c in s.extra]
        new, absorbed_g = absorb_configurations(s.inc, [st.chosen for st in s.steps], s.priority,
                                                budget_s=SHARES.repair_s(ctx.budget, ctx.options.repair.time_limit_s),
                                                loose=rescued_t, min_keep=s.lower_bound)
        s.steps = rebuild(s.instrument, s.inc, s.priority, s.steps, new, s.speeds, s.xy, s.tie, s.q_start)
        s.extra = [c for c, g in zip(s.extra, absorbed_g, strict=True) if not g]
        s.timers["repair_s"] = clock.now() - tr
        s.timers["repair_saved"] = n0 - s.n_configurations


class BulkPackingPass:
    name = "packing"

    def applies(self, s: SequenceState, ctx: PassContext) -> bool:
        return ctx.options.packing.enabled and s.finished_normally() and s.n_configurations > s.lower_bound

    def run(self, s: SequenceState, ctx: PassContext) -> None:
        tr = clock.now()
        pk = ctx.options.packing
        budget = SHARES.repack_s(ctx.budget, pk.attempt_time_limit_s, pk.max_window)
        n0 = len(s.steps)
        if not s.extra:
            s.steps = repack_bulk(s.instrument, s.inc, s.priority, s.steps, s.lower_bound, s.speeds, s.xy, s.tie,
                                  min(SHARES.bulk_fraction * budget, SHARES.bulk_attempts * pk.attempt_time_limit_s),
                                  s.seed, s.threads)
        s.timers["repack_bulk_s"] = clock.now() - tr
        s.timers["repack_bulk_saved"] = n0 - len(s.steps)
        s.repack_budget_s = min(ctx.budget.left_s(), budget - (clock.now() - tr))
        s.rescued = [observed(c) for c in s.extra]
        s.repack_t0, s.repack_n1 = tr, s.n_configurations


class BoundsPass:
    name = "bounds"

    def applies(self, s: SequenceState, ctx: PassContext) -> bool:
        return (s.repack_t0 is not None and s.n_reachable <= SHARES.bounds_max_targets
                and s.repack_budget_s > SHARES.bounds_min_budget_s)

    def run(self, s: SequenceState, ctx: PassContext) -> None:
        budget = s.repack_budget_s
        n1 = s.repack_n1
        tc = clock.now()
        s.crowd_bound, _ = crowding_lower_bound(s.inc, s.xy, ~s.unreachable,
                                                time_limit_s=min(SHARES.crowding_max_s,
                                                                 budget * SHARES.crowding_fraction),
                                                radii_mm=INNER_DISCS_MM)
        s.timers["crowding_bound_s"] = clock.now() - tc
        floor = max(s.lower_bound, s.flow_bound, s.crowd_bound)
        obs = [observed_chosen(s.inc, st.chosen) for st in s.steps]
        if n1 > floor:
            floor = self._pack_at_floor(s, obs, floor, n1, budget, tc)
        lp_s = min(ctx.options.packing.lp_bound_time_limit_s, SHARES.lp_fraction * budget,
                   budget - SHARES.pass_margin_s - (clock.now() - tc))
        if s.n_configurations > floor and lp_s > SHARES.min_search_s:
            # the LP bound finds crowded clusters anywhere (not only about the centre); it
            # stops once it proves the current count, and then nothing is left to repack
            mask = np.zeros(len(s.priority), bool)
            for o in obs + s.rescued:
                mask[o] = True
            s.lp_bound, _ = configuration_lp_bound(s.inc, mask, time_limit_s=lp_s, columns=obs + s.rescued,
                                                   stop_at=n1, seed=s.seed, threads=s.threads)
        s.timers["lower_bounds_s"] = clock.now() - tc
        s.repack_budget_s -= s.timers["lower_bounds_s"]

    @staticmethod
    def _pack_at_floor(s: SequenceState, obs: list[np.ndarray], floor: int, n1: int, budget: float,
                       tc: float) -> int:
        """A packing at the bound is optimal and makes every proof unnecessary: a short tabu
        search over the whole field first (the one-at-a-time prefix is given up for it; the
        packed configurations are ordered by total priority).  Returns the floor, one higher
        when CP-SAT proves the floor infeasible."""
        ts = clock.now()
        pool = np.concatenate(obs + s.rescued)
        hint = [st.chosen for st in s.steps]
        tabu_s = min(SHARES.tabu_fraction * budget, SHARES.tabu_max_s)
        if floor == math.ceil(len(pool) / max(s.n_active, 1)) and len(pool) <= SHARES.max_cover_pool:
            # the floor is the count bound alone (no crowding): CP-SAT's max-cover model finds
            # packings there that the tabu search misses (weak-192 fields into 16: 6-41 s),
            # and its exact-cover model proves the others infeasible in seconds — worth most
            # of the budget, as a packing here is optimal, all of it but the LP bound's when
            # the sequence is one above the floor.  From further above, CP-SAT's best partial
            # packing at the floor plus its leftovers in one more configuration usually gets
            # one above (weak 192 at 0.6 of the budget and nothing else: fields 4 and 8 kept
            # 18, the repacking to 17 had too little time left after it)
            left = budget - (clock.now() - tc)
            st: dict = {}
            partial: list = []
            limit = max(left - SHARES.cover_margin_s if n1 == floor + 1 else SHARES.cover_fraction * left, tabu_s)
            packed = pack_targets(s.inc, pool, floor, time_limit_s=limit, seed=s.seed, threads=s.threads,
                                  hint=hint, status_out=st, tabu_fraction=tabu_s / limit,
                                  proof_fraction=SHARES.cover_proof_fraction, partial_out=partial)
            if packed is None and partial and n1 > floor + 1:
                packed = complete_partial(s.inc, pool, partial, n1 - 1, time_limit_s=min(
                    SHARES.complete_partial_max_s,
                    budget - (clock.now() - tc) - SHARES.pass_margin_s),
                    seed=s.seed, threads=s.threads)
            if st["infeasible"] and (not s.rescued or len(pool) >= s.n_active * floor):
                s.floor_proof = floor = floor + 1
        else:
            packed = tabu_pack(s.inc, pool, floor, seed=s.seed, time_limit_s=tabu_s, hint=hint)
        if packed is not None:
            s.steps = replace_tail(s.instrument, s.inc, s.priority, s.steps, len(s.steps), packed, s.speeds, s.xy,
                                   s.tie, clock.now() - ts, s.q_start)
            s.extra, s.rescued = [], []
        s.timers["packing_at_bound_s"] = clock.now() - ts
        return floor


class PrefixPackingPass:
    name = "repack"

    def applies(self, s: SequenceState, ctx: PassContext) -> bool:
        return s.repack_t0 is not None

    def run(self, s: SequenceState, ctx: PassContext) -> None:
        bound = max(s.lower_bound, s.flow_bound, s.crowd_bound, s.lp_bound, s.floor_proof)
        s.steps, s.proven_bound, absorbed = repack_prefix(
            s.instrument, s.inc, s.priority, s.steps, bound, s.speeds, s.xy, s.tie,
            ctx.options.packing.attempt_time_limit_s, s.repack_budget_s, s.seed, s.threads, q0=s.q_start,
            rescued=s.rescued)
        if absorbed:
            s.extra = []
        s.timers["repack_s"] = clock.now() - s.repack_t0
        s.timers["repack_saved"] = s.repack_n1 - s.n_configurations


POST_PASSES = (RescuePass(), RepairPass(), BulkPackingPass(), BoundsPass(), PrefixPackingPass())
