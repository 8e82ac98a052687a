"""A programme's ``max_exposures`` split over its pointings (:func:`exposure_caps`), on the
pointings' estimated exposures (:func:`estimated_exposures`); :mod:`planner.programme`
re-exports both."""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from typing import Any

from models.errors import InputError

__all__ = ["TARGETS_PER_EXPOSURE", "estimated_exposures", "exposure_caps"]

#: Targets one exposure observes at most (the arms of MIRADAS): a pointing's exposures are
#: estimated as ceil(members / this) when the segmentation gives no estimate of its own.
TARGETS_PER_EXPOSURE = 12


def estimated_exposures(pointing: Any) -> int:
    """A pointing's estimated exposures (``solvers.segmentation.Pointing``): its own
    ``exposures`` when the segmentation gives one, else ceil(members / 12), the fewest that
    can observe them all."""
    e = getattr(pointing, "exposures", None)
    if e is not None:
        return int(e)
    return math.ceil(len(pointing.target_indices) / TARGETS_PER_EXPOSURE)


def exposure_caps(max_exposures: int, estimates: Sequence[int]) -> list[int]:
    """A programme's ``max_exposures`` split over its pointings in proportion to their
    ``estimates`` of exposures, deterministically: caps summing to ``max_exposures``.

    With ``M = max_exposures``, ``n`` pointings and shares ``q_i = M e_i / sum(e)`` (equal
    shares when every estimate is 0):

    - ``M >= n``: every pointing gets at least 1, and the caps are the integers closest to
      the shares in least squares, ``min sum (c_i - q_i)^2`` subject to ``c_i >= 1`` and
      ``sum c_i = M``. The objective is separable and convex, so giving the ``M - n``
      exposures beyond the first one at a time to the pointing furthest below its share
      (:math:`q_i - c_i` largest; ties: the larger estimate, then the lower index) is optimal.
    - ``M < n``: the ``M`` pointings with the largest estimates (ties: the lower index) get 1,
      the others 0 (not attempted: their targets ``beyond_max_exposures``); the first
      exposure of a pointing observes the most, so this spreads them where they observe most.
    """
    if isinstance(max_exposures, bool) or not isinstance(max_exposures, int) or max_exposures < 0:
        raise InputError("max_exposures", f"must be an integer >= 0, got {max_exposures!r}")
    for i, e in enumerate(estimates):
        if isinstance(e, bool) or not isinstance(e, int) or e < 0:
            raise InputError(f"estimates[{i}]", f"must be an integer >= 0, got {e!r}")
    n, m = len(estimates), int(max_exposures)
    if n == 0:
        return []
    w = [int(e) for e in estimates] if any(estimates) else [1] * n
    if m < n:
        first = set(sorted(range(n), key=lambda i: (-w[i], i))[:m])
        return [1 if i in first else 0 for i in range(n)]
    total = sum(w)
    caps = [1] * n
    # q_i - c_i in units of 1 / total, exactly: m * w_i - c_i * total
    heap = [(-(m * w[i] - total), -w[i], i) for i in range(n)]
    heapq.heapify(heap)
    for _ in range(m - n):
        _, neg_w, i = heapq.heappop(heap)
        caps[i] += 1
        heapq.heappush(heap, (-(m * w[i] - caps[i] * total), neg_w, i))
    return caps
