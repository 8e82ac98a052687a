"""The programme optimiser: the pointings, position angles and members of a whole programme
with the fewest exposures (segmentation mode "fewest-exposures"). The formulation, the bound
and the measured figures are in docs/programme.md.

:func:`optimise` runs, within one budget:

1. **Candidates**: the maximal sets of targets one FOV can hold (:mod:`.candidates`).
2. **Bound**: the proven lower bound on the programme's exposures (:mod:`.bound`; on thin
   fields also the model's dual bound without the reach rows, which depend on where a
   pointing is placed).
3. **Model**: choose pointings and give each target to one of them, fewest exposures and
   acquisitions (telescope time), each pointing's exposures bounded below by its targets
   over the arms and by arm reach (:mod:`.model`, :mod:`.reach`; HiGHS, started from a
   greedy cover).
4. **Commit** (:mod:`.fill`): the model's largest pointing, re-centred on the smallest circle
   enclosing its targets and turned to the position angle that loses none to reach (thesis
   7.3), is allocated as the plan allocates it on every target still to observe inside its
   FOV; its weak exposures hand their targets on. The model is solved again on what is left
   when a commit gives back targets it had placed; then the next pointing is committed.
5. **Spare arms** (:func:`.fill.spare_arms`): a pointing's last exposure is given up when
   other pointings take its targets in the exposures they already have.
6. **Emptied exposures** (:mod:`.consolidate`): an exposure whose every target an idle arm
   of another exposure (of any pointing holding it) can take as it stands is given up.

The allocation each pointing keeps (its witness) goes to the plan, which keeps it when its own
allocation of the pointing is not better: the plan has no more exposures than the optimiser
counted.

The searches run on the caller's clock (a plan's effort clock), so the result depends on the
programme, the options and the budget only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from models.budget import Budget
from models.instrument import Instrument
from models.sky import focal_mm_to_sky
from models.types import AllocationResult
from solvers.programme.angle import AngleChoice
from solvers.programme.bound import RADIUS_SLACK, ExposureBound, lower_bound
from solvers.programme.candidates import Candidates, maximal_sets
from solvers.programme.consolidate import consolidate
from solvers.programme.crowding import (
    CrowdingCells,
    crowding_cells,
    exclusion_distance_mm,
    with_crowding,
)
from solvers.programme.fill import (
    Field,
    FillOptions,
    Pointing,
    commit,
    mark_only_here,
    recentre,
    spare_arms,
)
from solvers.programme.model import CoverSolution, solve_cover
from solvers.programme.reach import entry_masks, reach_rows, shortlist

__all__ = ["OptimisedPointing", "OptimiserOptions", "ProgrammeResult", "optimise"]


#: the bound solves the model over every candidate only up to this many (set, member) entries
BOUND_MODEL_MAX_ENTRIES = 8_000


@dataclass(frozen=True)
class OptimiserOptions:
    """The allocation the feedback runs (as the plan's), and the optimiser's one table of
    shares of its budget."""

    fill: FillOptions = FillOptions()
    #: of the optimiser's budget: the bound (its cutting planes, then the model without reach
    #: rows), the model's first search, then each later step's; the allocations the rest
    bound_share: float = 0.1
    model_share: float = 0.15
    step_share: float = 0.03
    #: the cost of a pointing (its acquisition) in exposures (an exposure and its
    #: reconfiguration): the plan's model minimises telescope time
    pointing_cost: float = 0.3
    #: candidates the model chooses among (:func:`solvers.programme.reach.shortlist`)
    max_candidates: int = 150


@dataclass(frozen=True)
class OptimisedPointing:
    """A pointing: centre (sky), position angle, members (indices into the programme), the
    exposures its feedback allocation kept (None: not allocated) and the members no other
    pointing holds."""

    ra_deg: float
    dec_deg: float
    position_angle_deg: float
    members: tuple[int, ...]
    exposures: int | None
    only_here: tuple[int, ...] = ()
    allocation: AllocationResult | None = field(default=None, compare=False, repr=False)
    position_angle_search: AngleChoice | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class ProgrammeResult:
    pointings: tuple[OptimisedPointing, ...]
    bound: ExposureBound
    stats: dict = field(default_factory=dict)


def optimise(inst: Instrument, ra_deg, dec_deg, priority, tangent: tuple[float, float],
             xy_mm: np.ndarray, options: OptimiserOptions, budget: Budget) -> ProgrammeResult:
    """The programme's pointings with the fewest exposures (module docstring), within
    ``budget``. ``xy_mm``: the targets on the programme's tangent plane about ``tangent``."""
    f = Field(inst, np.asarray(ra_deg, float), np.asarray(dec_deg, float), np.asarray(priority, np.int64))
    n, arms, R = len(f.ra_deg), inst.n_arms, f.radius_mm
    cand = maximal_sets(xy_mm, R * (1.0 + RADIUS_SLACK) + 1e-9)  # every FOV set: a bound holds
    masks = options.fill.limited(entry_masks(inst, cand, xy_mm, options.fill.position_angle_deg,
                                             options.fill.park_move_limit_s), cand.index)
    cells = crowding_cells(xy_mm, exclusion_distance_mm(inst))
    bound = _bound(xy_mm, R, arms, cand, budget.share(options.bound_share), options.fill.seed, cells)
    todo = np.ones(n, bool)
    pts: list[Pointing] = []
    first: CoverSolution | None = None
    cover, sub, done = None, None, set()
    while todo.any():
        if cover is None or any(int(cover.owner[i]) in done or cover.owner[i] < 0 for i in np.flatnonzero(todo)):
            share = options.model_share if first is None else options.step_share
            cover, sub = _model(cand, masks, todo, arms, options, budget.share(share))
            first, done = (cover if first is None else first), set()
        used = np.bincount(cover.owner[todo], minlength=len(sub))
        if budget.expired():  # no time for the feedback: the model's pointings as they are
            pts += [_unallocated(f, np.flatnonzero(todo & (cover.owner == j)), sub.centres_mm[j], tangent)
                    for j in np.flatnonzero(used)]
            break
        j = int(np.argmax(used))  # the model's largest pointing
        given = np.flatnonzero(todo & (cover.owner == j))
        elsewhere = np.zeros(n, bool)
        for k in np.flatnonzero(used):
            if k != j:
                elsewhere[sub.of(k)] = True
        p = commit(f, todo, given, _sky(sub.centres_mm[j], tangent, f.scale), elsewhere, options.fill, budget)
        todo[p.members] = False
        done.add(j)
        pts.append(p)
    saved = spare_arms(f, pts, options.fill, budget)
    emptied = consolidate(f, pts, options.fill, budget)
    pts = [p for p in pts if len(p.members)]
    mark_only_here(f, pts)
    out = tuple(OptimisedPointing(p.centre[0] % 360.0, p.centre[1], p.pa_deg % 360.0,
                                  tuple(int(i) for i in p.members), p.exposures,
                                  tuple(int(i) for i in p.only_here),
                                  p.allocation, p.pa_search)
                for p in pts)
    stats = {"candidates": len(cand), "candidates_complete": cand.complete, "steps": len(pts),
             "model_status": first.status, "model_exposures": int(first.exposures.sum()),
             "model_pointings": int(np.count_nonzero(first.exposures)),
             "exposures_estimate": sum(p.exposures or 0 for p in pts),
             "allocated_pointings": sum(p.exposures is not None for p in pts), "spare_arm_moves": saved,
             "exposures_emptied": emptied}
    return ProgrammeResult(out, bound, stats)


def _model(cand: Candidates, masks: np.ndarray, todo: np.ndarray, arms: int, options: OptimiserOptions,
           budget: Budget) -> tuple[CoverSolution, Candidates]:
    """The programme model on the targets ``todo`` (bool mask), over its shortlist, with the
    rows of arm reach. The crowding rows are left out of it: the feedback allocations see
    crowding as it is, and the rows steer the model to pointings that take more exposures
    (docs/programme.md)."""
    n = len(todo)
    sub, entries = cand.restrict(todo)
    keep = shortlist(sub, n, masks[entries], arms, options.max_candidates)
    sub, within_sub = sub.subset(keep)
    entries = entries[within_sub]
    allowed, rows = reach_rows(sub, masks[entries], arms)
    cover = solve_cover(sub, n, budget, arms=arms, seed=options.fill.seed, reach=rows, allowed=allowed,
                        pointing_cost=options.pointing_cost)
    if cover.status == "timeout":  # the greedy start is a solution; a guard only
        raise RuntimeError("the programme model found no solution within its budget")
    return cover, sub


def _unallocated(f: Field, members: np.ndarray, centre_mm: np.ndarray, tangent) -> Pointing:
    centre = recentre(f, members, _sky(centre_mm, tangent, f.scale))
    return Pointing(centre, 0.0, members)


def _bound(xy, R, arms, cand: Candidates, budget: Budget, seed: int, cells: CrowdingCells) -> ExposureBound:
    """The cutting-plane bound, or the model's dual bound (complete candidates, the crowding
    rows but no reach rows, a model of at most :data:`BOUND_MODEL_MAX_ENTRIES` entries: thin
    sets, where the per-set rounding the LP misses matters) when it is higher. Both count
    the crowding cells (:mod:`.crowding`): it holds wherever a pointing is placed."""
    cut = lower_bound(xy, R, arms, budget=budget.share(0.5), cell=cells.cell)
    if not cand.complete or budget.expired() or len(cand.index) > BOUND_MODEL_MAX_ENTRIES:
        return cut
    model = solve_cover(cand, len(xy), budget, arms=arms, seed=seed, reach=with_crowding(None, cand, cells))
    if model.exposures_bound > cut.exposures:
        return ExposureBound(model.exposures_bound, cut.trivial, cut.components, cut.weight, "model", cut.rounds)
    return cut


def _sky(c_mm: np.ndarray, tangent: tuple[float, float], scale: float) -> tuple[float, float]:
    r, d = focal_mm_to_sky(np.array([c_mm[0]]), np.array([c_mm[1]]), tangent[0], tangent[1], scale)
    return float(r[0]), float(d[0])
