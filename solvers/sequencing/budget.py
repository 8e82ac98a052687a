"""The time budget of a sequence: every constant of the driver and its post-passes, named once.

:class:`SequenceBudget` holds the constants (fractions of the call's limit, caps and margins
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

__all__ = ["BUDGET", "SequenceBudget"]


@dataclass(frozen=True)
class SequenceBudget:
    """The driver's constants.  Seconds end in ``_s``; fractions are of the call's limit
    unless named otherwise."""

    # --- the greedy loop
    min_solve_s: float = 0.01  # less than this left: stop (no_time)
    min_share_s: float = 0.05  # the least one configuration's solve is given
    share_slack: float = 2.0  # a solve gets up to this many times its share (the hard ones are few)
    # --- post-passes: a keep-back for model building and verification (0.5 s let a 10 s
    # call on 384 targets overrun by 0.8 s)
    keep_back_fraction: float = 0.1
    keep_back_max_s: float = 1.0
    # --- repair (ejection chains)
    repair_left_fraction: float = 0.5  # at most this fraction of what is left
    # --- repacking
    repack_window_attempts: float = 4.0  # the repacking budget: attempt limit x this x window ...
    repack_call_fraction: float = 0.5  # ... or this fraction of the call, whichever is more
    bulk_fraction: float = 0.4  # of the repacking budget, for the bulk tail repacking ...
    bulk_attempts: float = 3.0  # ... at most this many attempt limits
    fewest_fraction: float = 0.5  # of the repacking budget, for the bottom-up repacking
    fewest_attempt_factor: float = 2.5  # a bottom-up attempt: this many attempt limits
    min_attempt_s: float = 0.5  # less than this left: no further packing attempt
    bottom_pool: int = 200  # the bottom-up repacking packs suffixes of at most this many targets
    prefix_max_pool: int = 400  # the one-fewer repacking, at most this many
    # --- lower bounds and the packing at the bound
    bounds_max_targets: int = 400  # beyond that the disc models cost too much
    bounds_min_budget_s: float = 2.0
    crowding_max_s: float = 0.5
    crowding_fraction: float = 1 / 20  # of the repacking budget
    tabu_fraction: float = 0.15  # of the repacking budget, the whole-field tabu search ...
    tabu_max_s: float = 5.0  # ... at most this
    # the whole-field CP-SAT packing at the floor pays up to this pool size: on weak 192 it
    # found the perfect packings; on weak 384 (32.1 with the tabu search alone, 32.3 with it)
    # it took the budget the prefix repacking needed to go from 33 to 32
    max_cover_pool: int = 250
    cover_margin_s: float = 2.0  # one above the floor: all but this (the LP bound's) ...
    cover_fraction: float = 0.7  # ... else this fraction of what is left
    cover_proof_fraction: float = 0.25  # of a packing call, CP-SAT's exact-cover proof
    complete_partial_max_s: float = 5.0
    complete_partial_margin_s: float = 1.0
    lp_fraction: float = 0.3  # of the repacking budget, the configuration LP bound ...
    lp_margin_s: float = 1.0  # ... leaving this ...
    lp_min_s: float = 0.5  # ... and only when it gets at least this
    # --- the conflict rescue
    rescue_fill_targets: int = 200  # observed targets offered as rests
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


BUDGET = SequenceBudget()
