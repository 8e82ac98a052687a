"""A programme's exposure rules: its ``max_exposures`` split over its pointings
(:func:`exposure_caps`, on the pointings' estimated exposures, :func:`estimated_exposures`;
:mod:`planner.programme` re-exports both), and a pointing's allocation under its cap and the
request's exposure thresholds (:func:`apply_exposure_rules`, :func:`split_by_thresholds`)."""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from models.errors import InputError
from models.types import (
    AllocationResult,
    Configuration,
    PlaneTargets,
    Unallocated,
    UnallocatedReason,
)
from planner.telescope_time import ObservingRules

__all__ = ["TARGETS_PER_EXPOSURE", "apply_exposure_rules", "estimated_exposures", "exposure_caps",
           "split_by_thresholds"]

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


def _observed(config: Configuration, priority_of: dict[str, int]) -> tuple[str, ...]:
    return tuple(a.target_id for a in config.assignments if a.kind == "target" and a.target_id is not None
                 and a.target_id in priority_of)


def split_by_thresholds(configs: Sequence[Configuration], targets: PlaneTargets, rules: ObservingRules,
           reason: UnallocatedReason = "below_exposure_threshold",
           ) -> tuple[tuple[Configuration, ...], tuple[Unallocated, ...]]:
    """The configurations that meet ``rules``' thresholds (renumbered from 0, in order) and
    the targets of the others, each ``reason``. An exposure's targets and summed priority are
    counted from its own assignments."""
    priority_of = {t: int(p) for t, p in zip(targets.ids, targets.priority, strict=True)}
    index_of = {t: i for i, t in enumerate(targets.ids)}
    kept: list[Configuration] = []
    out: list[Unallocated] = []
    for c in configs:
        ids = _observed(c, priority_of)
        if rules.keeps(len(ids), sum(priority_of[t] for t in ids)):
            kept.append(replace(c, index=len(kept)) if c.index != len(kept) else c)
        else:
            out.extend(Unallocated(index_of[t], t, reason) for t in ids)
    return tuple(kept), tuple(out)


def apply_exposure_rules(result: AllocationResult, targets: PlaneTargets, max_configurations: int | None,
                         rules: ObservingRules) -> tuple[AllocationResult, dict]:
    """The allocation under the request's rules: the targets the cap left out are
    ``beyond_max_exposures`` (the allocator's ``not_scheduled``), and the exposures below a
    threshold are not opened (the greedy sequence puts the weakest last), their targets
    ``below_exposure_threshold``. ``max_configurations``: the pointing's cap (None: none).
    Returns the allocation and what was dropped."""
    capped = max_configurations is not None
    unallocated = tuple(replace(u, reason="beyond_max_exposures") if capped and u.reason == "not_scheduled"
                        else u for u in result.unallocated)
    kept, below = split_by_thresholds(result.configurations, targets, rules)
    stats = {"max_configurations": max_configurations,
             "dropped_configurations": len(result.configurations) - len(kept),
             "below_exposure_threshold": len(below),
             "beyond_max_exposures": sum(u.reason == "beyond_max_exposures" for u in unallocated)}
    if not below and unallocated == result.unallocated:
        return result, stats  # the rules changed nothing: the allocator's own result
    return AllocationResult(kept, unallocated + below, result.stats), stats
