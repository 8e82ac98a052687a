"""What limit a programme needs, and what to tell the astronomer when theirs was too short.

A plan's limit is shared over its pointings by need (:mod:`planner.programme`). A pointing
is expected to be planned in :func:`planner.programme.expected_share_s` (its targets times
``ProgrammeShares.enough_effort_per_target_s`` effort seconds, the effort clock's reference
seconds: :mod:`planner.effort`, :mod:`solvers.effort`, over the effort share); the limit a
programme needs is the least one whose pointings' part (the limit less the programme
optimiser's share and the answer's reserve) holds every pointing's expected share
(:func:`needed_limit_s`). After the rounds, :func:`time_advice` estimates it again from what
the pointings spent, and says which pointings the limit left unplanned.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from planner.programme import (
    SHARES,
    PointingOutcome,
    ProgrammeShares,
    best_outcomes,
    expected_share_s,
    optimiser_s,
    usable_s,
)

__all__ = ["TimeAdvice", "needed_limit_s", "pointings_part_s", "time_advice"]


def pointings_part_s(limit_s: float, optimiser: bool, table: ProgrammeShares = SHARES,
                     n_targets: int | None = None) -> float:
    """What the pointings of a plan limited to ``limit_s`` share (the rounds' usable time):
    the limit less the programme optimiser's part (``optimiser``: segmentation mode
    "fewest-exposures", for a programme of ``n_targets``: :func:`planner.programme.optimiser_s`)
    and less the answer's reserve."""
    rounds_s = limit_s - optimiser_s(limit_s, table, n_targets) if optimiser else limit_s
    return usable_s(max(rounds_s, 0.0), table)


def needed_limit_s(pointings_s: float, optimiser: bool, table: ProgrammeShares = SHARES,
                   n_targets: int | None = None) -> float:
    """The least limit, in whole seconds, whose :func:`pointings_part_s` holds
    ``pointings_s`` (the part grows with the limit, so a bisection finds it)."""
    if pointings_s <= 0:
        return 0.0
    lo, hi = 0.0, max(2.0 * pointings_s, 1.0)
    while pointings_part_s(hi, optimiser, table, n_targets) < pointings_s:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pointings_part_s(mid, optimiser, table, n_targets) < pointings_s else (lo, mid)
    return float(math.ceil(hi - 1e-9))


@dataclass(frozen=True)
class TimeAdvice:
    """A plan whose limit left some pointing unplanned: the limit it had, the limit the
    programme is estimated to need, and the pointings (indices) not attempted for lack of
    time and those left with a failed leg when the limit ran out."""

    time_limit_s: float
    needed_limit_s: float
    not_attempted: tuple[int, ...]
    failed: tuple[int, ...]


def time_advice(limit_s: float | None, needs: Sequence[float],
                history: Sequence[Sequence[PointingOutcome]], optimiser: bool,
                table: ProgrammeShares = SHARES, n_targets: int | None = None) -> TimeAdvice | None:
    """The advice of a plan limited to ``limit_s`` whose rounds gave ``history``; None when
    every pointing with a need was planned, or when no limit bound it (a failed leg is then
    not for lack of time), or when the rounds ended with time left (their number, not the
    limit, stopped them).

    The estimate of each pointing: what its executable plan spent (effort over
    ``effort_share``); for one with a failed leg, or not planned because the wall clock cut
    its plan (:func:`planner.programme.planned`), ``failed_growth`` times the largest share it
    had (at least its expected share); for one not attempted, its expected share
    (:func:`planner.programme.expected_share_s`). A limit at least that of the estimate but too
    short all the same is estimated at ``failed_growth`` times itself."""
    if limit_s is None or math.isinf(limit_s):
        return None
    best = best_outcomes(history)
    waiting = tuple(sorted(i for i, o in best.items() if needs[i] > 0 and not o.attempted))
    failed = tuple(sorted(i for i, o in best.items() if needs[i] > 0 and o.attempted and not o.executable))
    usable = pointings_part_s(limit_s, optimiser, table, n_targets)
    spent = sum(o.spent_s(table) for outcomes in history for o in outcomes)
    if not waiting and (not failed or usable - spent >= table.min_pointing_s):
        return None
    tried = {o.index for r in history for o in r if o.attempted}
    cut = [i for i in waiting if i in tried]  # not planned: the wall clock cut every plan of it
    largest = {i: max(o.share_s for r in history for o in r if o.index == i) for i in (*failed, *cut)}
    estimate = 0.0
    for i, o in best.items():
        if i in largest:
            estimate += max(table.failed_growth * largest[i], expected_share_s(needs[i], table))
        elif o.attempted:
            estimate += o.spent_s(table)
        else:
            estimate += expected_share_s(needs[i], table)
    needed = needed_limit_s(estimate, optimiser, table, n_targets)
    if needed <= limit_s:
        needed = float(math.ceil(table.failed_growth * limit_s))
    return TimeAdvice(float(limit_s), needed, waiting, failed)
