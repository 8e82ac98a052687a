"""Step 6 of the programme optimiser: two pointings one FOV holds become one.

The commits (:mod:`.fill`) place the pointings one at a time, and each hands on the targets of
its weak exposures; the last pointings collect those few targets, often beside (or over) an
earlier pointing. Two pointings whose members one FOV holds (about the smallest circle
enclosing them all, by :data:`solvers.programme.fill.RIM_MARGIN_MM`) become one when the
allocation of their members together, at the position angle a commit would give that
pointing, observes every one of them in no more exposures than the two take apart: the
programme then takes one acquisition fewer, and an exposure fewer whenever the arms of one
fill what the two left idle.

Pairs are tried smallest first (fewest members together, then in the order of the
pointings); a merge replaces the first of the two and the scan starts again, so a merged
pointing may merge again. A pair whose allocation does not qualify is not tried twice. Each
allocation is the commits' (:func:`solvers.programme.fill.allocate_pointing`), on the
caller's budget (the optimiser gives the merges a tenth of a search's); one cut short observes
fewer targets and is not taken.
"""

from __future__ import annotations

import numpy as np

from models.budget import Budget
from models.sky import tangent_radius_mm
from solvers.programme.fill import (
    Field,
    FillOptions,
    Pointing,
    observed_members,
    pointing_angle,
    recentre,
    timed_allocation,
    within,
    witness,
)

__all__ = ["merge_pointings"]


def merge_pointings(f: Field, pts: list[Pointing], opts: FillOptions, budget: Budget) -> int:
    """Merge pairs of ``pts`` in place (module docstring); returns the pointings merged away."""
    merged, failed = 0, set()
    while (found := _next_merge(f, pts, opts, budget, failed)) is not None:
        j, k, one = found
        pts[j] = one
        del pts[k]
        merged += 1
    return merged


def _next_merge(f: Field, pts: list[Pointing], opts: FillOptions, budget: Budget, failed: set,
                ) -> tuple[int, int, Pointing] | None:
    """The first pair (j, k) of :func:`_pairs` not in ``failed`` that merges, with its merged
    pointing; None when none does or the budget is spent. Pairs that do not merge join
    ``failed`` (keyed by their members)."""
    for j, k in _pairs(f, pts):
        key = (tuple(pts[j].members), tuple(pts[k].members))
        if key in failed:
            continue
        if budget.expired():
            return None
        one = _merged(f, pts[j], pts[k], opts, budget)
        if one is not None:
            return j, k, one
        failed.add(key)
    return None


def _pairs(f: Field, pts: list[Pointing]) -> list[tuple[int, int]]:
    """Pairs (j < k) of allocated pointings whose centres are within a FOV diameter, fewest
    members together first."""
    live = [j for j, p in enumerate(pts) if _allocated(p)]
    ra = np.array([pts[j].centre[0] for j in live])
    dec = np.array([pts[j].centre[1] for j in live])
    out = []
    for a, j in enumerate(live[:-1]):
        d = tangent_radius_mm(ra[a + 1:], dec[a + 1:], ra[a], dec[a], f.scale)
        out += [(j, k) for k, near in zip(live[a + 1:], d <= 2.0 * f.radius_mm, strict=True) if near]
    return sorted(out, key=lambda jk: (len(pts[jk[0]].members) + len(pts[jk[1]].members), jk))


def _allocated(p: Pointing) -> bool:
    return len(p.members) > 0 and p.exposures is not None and p.allocation is not None


def _merged(f: Field, a: Pointing, b: Pointing, opts: FillOptions, budget: Budget) -> Pointing | None:
    """``a`` and ``b`` as one pointing, or None when one FOV does not hold them or their
    allocation together does not observe every target they observe in at most their
    exposures (a member neither observes stays unobserved for a reason of the geometry, as
    :func:`solvers.programme.fill.witness` requires)."""
    members = np.union1d(a.members, b.members)
    start = a.centre if len(a.members) >= len(b.members) else b.centre
    centre = recentre(f, members, start)
    if not within(f, members, centre).all():
        return None
    pa, search = pointing_angle(f, members, centre, opts)
    one = Pointing(centre, pa, members, pa_search=search)
    result, one.allocation_s = timed_allocation(f, one, f.priority, opts, budget)
    before = observed_members(a.members, a.allocation) | observed_members(b.members, b.allocation)
    if not before <= observed_members(members, result) or len(result.configurations) > a.exposures + b.exposures:
        return None
    one.exposures = len(result.configurations)
    one.allocation = witness(result, members, members, one.exposures, f.priority)
    return one if one.allocation is not None else None
