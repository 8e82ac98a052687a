"""The time shares of a sequence: every constant of the driver and its post-passes, named once.

:class:`SequenceShares` holds the constants (fractions of the call's limit, caps and margins
in seconds, model sizes, seed offsets) and computes each stage's allowance from the call's
:class:`models.budget.Budget` (started with the call's limit, so its ``total_s`` is that
limit).  The greedy loop shares what is left between the configurations still needed; the
post-passes (rescue, repair, packing, bounds) get what the loop left, minus a reserve for
building models and verifying results, which no solver's own limit covers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from models.budget import Budget

__all__ = ["SHARES", "SequenceShares"]


@dataclass(frozen=True)
class SequenceShares:
    """The driver's constants, each with what it protects.  Seconds end in ``_s``; fractions
    are of the call's limit unless named otherwise."""

    # --- the greedy loop
    #: Less than this left: the loop stops (pending targets ``no_time``) instead of starting
    #: a solve that cannot finish.
    min_solve_s: float = 0.01
    #: The least one configuration's solve is given, so that a long sequence's last
    #: configurations still get a real solve.
    min_share_s: float = 0.05
    #: A solve gets up to this many times its share of what is left: the hard configurations
    #: are few, and the easy ones leave them their time.
    share_slack: float = 2.0
    # --- the post-passes
    #: Kept back at the end of the call (at most ``keep_back_max_s``) for building models and
    #: verifying results, which no solver's own limit covers: it keeps the call within its
    #: limit (0.5 s let a 10 s call on 384 targets overrun by 0.8 s).
    keep_back_fraction: float = 0.1
    keep_back_max_s: float = 1.0
    #: The repair pass (ejection chains) gets at most this fraction of what is left, so the
    #: repacking passes after it keep theirs.
    repair_left_fraction: float = 0.5
    #: The repacking budget: this many attempt limits per window configuration, or
    #: ``repack_call_fraction`` of the call, whichever is more; it bounds the passes that
    #: only save configurations, so the loop's allocation is never starved for them.
    repack_window_attempts: float = 4.0
    repack_call_fraction: float = 0.5
    #: Of the repacking budget, the bulk tail repacking's part (at most ``bulk_attempts``
    #: attempt limits): the rest goes to the bottom-up and one-fewer repackings.
    bulk_fraction: float = 0.4
    bulk_attempts: float = 3.0
    #: Of the repacking budget, the bottom-up repacking's part, each of its attempts at most
    #: ``fewest_attempt_factor`` attempt limits: the one-fewer repacking keeps the rest.
    fewest_fraction: float = 0.5
    fewest_attempt_factor: float = 2.5
    #: A packing attempt or the LP bound is started only with at least this left: less
    #: rarely improves a packing and still pays for building its model.
    min_search_s: float = 0.5
    #: A bound or completion pass ends this long before the repacking budget, which leaves
    #: the passes after it and the keep-back their time.
    pass_margin_s: float = 1.0
    #: The bottom-up repacking packs suffixes of at most this many targets, and the
    #: one-fewer repacking at most ``prefix_max_pool``: bigger packing models cost more than
    #: the attempts have.
    bottom_pool: int = 200
    prefix_max_pool: int = 400
    # --- lower bounds and the packing at the bound
    #: The bounds are computed for at most this many reachable targets (beyond, the disc
    #: models cost too much) and a repacking budget above ``bounds_min_budget_s``.
    bounds_max_targets: int = 400
    bounds_min_budget_s: float = 2.0
    #: The crowding bound: this fraction of the repacking budget, at most ``crowding_max_s``
    #: (a cheap bound; it must not eat the LP's time).
    crowding_max_s: float = 0.5
    crowding_fraction: float = 1 / 20
    #: The whole-field tabu search for a packing at the floor: this fraction of the
    #: repacking budget, at most ``tabu_max_s`` (also its part of a CP-SAT packing call), so
    #: a packing at the floor is tried without taking the LP bound's and the repackings' time.
    tabu_fraction: float = 0.15
    tabu_max_s: float = 5.0
    #: The whole-field CP-SAT packing at the floor pays up to this pool size: on weak 192 it
    #: found the perfect packings; on weak 384 it took the budget the prefix repacking needed
    #: to go from 33 to 32 configurations.
    max_cover_pool: int = 250
    #: One above the floor, the packing gets all but ``cover_margin_s`` (the LP bound's
    #: time); else ``cover_fraction`` of what is left, so the other passes keep the rest.
    cover_margin_s: float = 2.0
    cover_fraction: float = 0.7
    #: Of a packing call, CP-SAT's exact-cover proof: the rest finds the packing itself.
    cover_proof_fraction: float = 0.25
    #: Completing a partial packing gets at most this: a partial packing rarely completes.
    complete_partial_max_s: float = 5.0
    #: The configuration LP bound: this fraction of the repacking budget; it proves the
    #: floor, so it gets a real share but not the packings' time.
    lp_fraction: float = 0.3
    # --- the conflict rescue
    #: Observed targets offered as rests, and blank locations per arm, in the rescue's
    #: models: enough to free an arm, small enough for a fast exact solve.
    rescue_fill_targets: int = 200
    rescue_blank_per_arm: int = 16
    # --- seed offsets of the packing attempts (a distinct seed per attempt)
    bulk_seed_offset: int = 20_000
    prefix_seed_offset: int = 50_000
    attempt_seed_stride: int = 101

    def config_limit_s(self, remaining_s: float, budget: Budget, n_pending: int, n_active: int, cap_s: float,
                       adaptive: bool, reserve_fraction: float) -> float:
        """One configuration's solve limit: at most ``cap_s`` and ``remaining_s``; with
        ``adaptive``, at most ``share_slack`` times its share of what is left after the
        reserve (``reserve_fraction`` of the call's limit, ``budget.total_s``, held back for
        the post-passes), shared by the configurations still needed at best (ceil(pending / arms))."""
        remaining = remaining_s
        if not adaptive:
            return min(cap_s, remaining)
        n_left = max(math.ceil(n_pending / max(n_active, 1)), 1)
        share = max(remaining - reserve_fraction * budget.total_s, self.min_share_s)
        return min(cap_s, remaining, max(self.share_slack * share / n_left, self.min_share_s))

    def keep_back_s(self, budget: Budget) -> float:
        """The seconds kept back at the end of the call for model building and verification."""
        return min(self.keep_back_fraction * budget.total_s, self.keep_back_max_s)

    def repair_s(self, budget: Budget, cap_s: float) -> float:
        """The repair pass's seconds: a fraction of what is left before the keep-back, at most ``cap_s``."""
        left = budget.total_s - self.keep_back_s(budget) - budget.elapsed_s()
        return min(self.repair_left_fraction * left, cap_s)

    def repack_s(self, budget: Budget, attempt_s: float, max_window: int) -> float:
        """The repacking passes' seconds: what is left before the keep-back, at most the
        larger of the attempts' allowance and a fraction of the call's limit."""
        return min(budget.total_s - self.keep_back_s(budget) - budget.elapsed_s(),
                   max(attempt_s * self.repack_window_attempts * max_window, self.repack_call_fraction * budget.total_s))


SHARES = SequenceShares()
