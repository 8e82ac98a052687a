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
5. **Emptied exposures** (:mod:`.consolidate`): an exposure whose every target an idle arm
   of another exposure (of any pointing holding it) can take as it stands is given up.
6. **Merged pointings** (:mod:`.merge`): two pointings one FOV holds become one when the
   allocation of their members together takes no more exposures than the two apart.

The allocation each pointing keeps (its witness) goes to the plan, which observes it as it is
when no allocation at its placement takes fewer exposures (``allocation_final``: the pointing is
allocated once) and otherwise keeps it when its own allocation of the pointing is not better:
the plan has no more exposures than the optimiser counted before its motion planner's changes.

The searches run on the caller's clock (a plan's effort clock), so the result depends on the
programme, the options and the budget only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from models import clock
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
    GEOMETRIC,
    Field,
    FillOptions,
    Pointing,
    commit,
    least_exposures,
    mark_only_here,
    recentre,
)
from solvers.programme.merge import merge_pointings
from solvers.programme.model import CoverSolution, greedy_solution, solve_cover
from solvers.programme.reach import entry_masks, reach_rows, shortlist

__all__ = ["VARIANTS", "ModelVariant", "OptimisedPointing", "OptimiserOptions", "ProgrammeResult", "optimise"]


#: the bound solves the model over every candidate only up to this many (set, member) entries
BOUND_MODEL_MAX_ENTRIES = 8_000
#: the model's search runs on shortlists of at most this many (set, member) entries; a larger
#: model takes its greedy start (:func:`solvers.programme.model.greedy_solution`): HiGHS's root
#: LP of such a model takes the search's whole share, what it finds there beyond the start
#: (on first models of clustered programmes) the plans' exposures do not follow, and the
#: plans take as many exposures in less time without it (docs/programme.md, *Model*)
SEARCH_MAX_ENTRIES = 3_000


@dataclass(frozen=True)
class ModelVariant:
    """One way to set the programme model: a pointing's cost in exposures (its acquisition
    against an exposure and its reconfiguration) and whether the crowding rows are in it."""

    pointing_cost: float = 0.3
    crowding: bool = False


#: The model's variants, searched in turn while the budget allows (the first always): each is
#: a whole search (model, commits, emptied exposures, merges), and the search whose real
#: allocations take the least telescope time is kept. The model leaves out what the
#: allocations meet (the other links' collisions, and crowding in the first variant), so
#: which variant's pointings allocate best differs from programme to programme
#: (docs/programme.md).
VARIANTS = (ModelVariant(), ModelVariant(crowding=True), ModelVariant(pointing_cost=0.6))


@dataclass(frozen=True)
class OptimiserOptions:
    """The allocation the feedback runs (as the plan's), the model's variants and the
    optimiser's one table of shares of its budget."""

    fill: FillOptions = FillOptions()
    #: of the optimiser's budget: the bound (its cutting planes, then the model without reach
    #: rows), the model's first search, then each later step's; the allocations the rest
    bound_share: float = 0.1
    model_share: float = 0.15
    step_share: float = 0.03
    #: of a search's budget, at most: its merges (step 6), which allocate pairs that may not
    #: merge, so that they never take the time of the model's other variants
    merge_share: float = 0.1
    #: the cost of a pointing (its acquisition) in exposures (an exposure and its
    #: reconfiguration): the searches are compared on telescope time
    pointing_cost: float = 0.3
    #: candidates the model chooses among (:func:`solvers.programme.reach.shortlist`)
    max_candidates: int = 150
    variants: tuple[ModelVariant, ...] = VARIANTS
    #: step 6: merge pairs of pointings one FOV holds (:mod:`.merge`), within ``merge_share``
    merge: bool = True


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
    #: the plan observes ``allocation`` as it is: it takes the fewest exposures any allocation
    #: of what it observes can take here (:func:`solvers.programme.fill.least_exposures`)
    allocation_final: bool = False
    #: wall seconds of the allocation ``allocation`` was taken from
    allocation_s: float = 0.0


@dataclass(frozen=True)
class ProgrammeResult:
    pointings: tuple[OptimisedPointing, ...]
    bound: ExposureBound
    stats: dict = field(default_factory=dict)


def optimise(inst: Instrument, ra_deg, dec_deg, priority, tangent: tuple[float, float],
             xy_mm: np.ndarray, options: OptimiserOptions, budget: Budget, variants_s: float = 0.0,
             ) -> ProgrammeResult:
    """The programme's pointings with the fewest exposures (module docstring), within
    ``budget``, of which the last ``variants_s`` (effort seconds) are for the model's other
    variants. ``xy_mm``: the targets on the programme's tangent plane about ``tangent``."""
    first = budget if variants_s <= 0 else budget.child(max(budget.left_s() - variants_s, 0.0))
    f = Field(inst, np.asarray(ra_deg, float), np.asarray(dec_deg, float), np.asarray(priority, np.int64))
    arms, R = inst.n_arms, f.radius_mm
    cand = maximal_sets(xy_mm, R * (1.0 + RADIUS_SLACK) + 1e-9)  # every FOV set: a bound holds
    masks = options.fill.limited(entry_masks(inst, cand, xy_mm, options.fill.position_angle_deg,
                                             options.fill.park_move_limit_s), cand.index)
    cells = crowding_cells(xy_mm, exclusion_distance_mm(inst))
    bound = _bound(xy_mm, R, arms, cand, first.share(options.bound_share), options.fill.seed, cells)
    space = _Space(f, cand, masks, cells, tangent)
    t0 = clock.now()
    best = _search(space, options, options.variants[0], first)
    cost_s, length_s = clock.now() - t0, first.total_s
    tried, t1 = [best], clock.now()
    for variant in options.variants[1:] if variants_s > 0 else ():
        if budget.left_s() < cost_s or not best.complete:
            break
        tried.append(_search(space, options, variant, budget.child(min(budget.left_s(), length_s))))
        if tried[-1].complete and tried[-1].key(options.pointing_cost) < best.key(options.pointing_cost):
            best = tried[-1]
    variants_effort_s = clock.now() - t1 if len(tried) > 1 else 0.0
    pts = best.pointings
    mark_only_here(f, pts)
    out = tuple(_optimised(f, p, options.fill) for p in pts)
    stats = {"candidates": len(cand), "candidates_complete": cand.complete, "steps": best.steps,
             "model_status": best.cover.status, "model_exposures": int(best.cover.exposures.sum()),
             "model_pointings": int(np.count_nonzero(best.cover.exposures)),
             "exposures_estimate": best.exposures,
             "allocated_pointings": sum(p.exposures is not None for p in pts),
             "exposures_emptied": best.emptied, "pointings_merged": best.merged,
             "model_variants": [{"pointing_cost": s.variant.pointing_cost, "crowding": s.variant.crowding,
                                 "exposures": s.exposures, "pointings": len(s.pointings), "complete": s.complete,
                                 "chosen": s is best} for s in tried],
             "variants_effort_s": variants_effort_s}
    return ProgrammeResult(out, bound, stats)


@dataclass(frozen=True)
class _Space:
    """What every search of :func:`optimise` shares: the programme, its candidates, their
    members' arm masks, the crowding cells and the tangent point."""

    f: Field
    cand: Candidates
    masks: np.ndarray
    cells: CrowdingCells
    tangent: tuple[float, float]


@dataclass(frozen=True)
class _Searched:
    """One search's pointings (those with members, after steps 5-6), the model's first
    solution, its steps and what steps 5-6 saved."""

    variant: ModelVariant
    pointings: list[Pointing]
    cover: CoverSolution
    steps: int
    emptied: int
    merged: int

    @property
    def complete(self) -> bool:
        """Every pointing got its allocation feedback: it keeps it as its witness, or its
        allocation kept no exposure and estimates what the plan's will take (a pointing whose
        allocation was cut short, or that the budget left unallocated, has neither, and then
        the search's exposures are not all counted)."""
        return all(_counted(p) is not None for p in self.pointings if len(p.members))

    @property
    def exposures(self) -> int:
        return sum(_counted(p) or 0 for p in self.pointings)

    def key(self, pointing_cost: float) -> tuple[float, int]:
        """Telescope time in exposures (each pointing its acquisition), then exposures."""
        used = sum(1 for p in self.pointings if len(p.members))
        return self.exposures + pointing_cost * used, self.exposures


def _optimised(f: Field, p: Pointing, opts: FillOptions) -> OptimisedPointing:
    """``p`` as the optimiser returns it. Its witness says, in its stats, the fewest
    exposures any allocation at its placement can observe what it observes in
    (``lower_bound_configurations_proven``, :func:`solvers.programme.fill.least_exposures`),
    and the plan observes it as it is (``allocation_final``) when it takes no more and every
    member it leaves unobserved no arm reaches (within the park move limit): the plan's own
    allocation could not be better (the plan keeps a witness unless its own observes more
    targets or as many in fewer exposures), so the pointing's share goes to its motion legs."""
    allocation, final = p.allocation, False
    if allocation is not None and p.exposures is not None:
        least = least_exposures(f, p, opts)
        allocation = replace(allocation, stats={**allocation.stats, "lower_bound_configurations_proven": least})
        final = p.exposures <= least and all(u.reason in GEOMETRIC for u in allocation.unallocated)
    return OptimisedPointing(p.centre[0] % 360.0, p.centre[1], p.pa_deg % 360.0, tuple(int(i) for i in p.members),
                             p.exposures, tuple(int(i) for i in p.only_here), allocation, p.pa_search, final,
                             p.allocation_s)


def _counted(p: Pointing) -> int | None:
    """A pointing's exposures as a search counts them: its witness's, else its estimate."""
    if p.exposures is not None and p.allocation is not None:
        return p.exposures
    return p.estimate


def _search(space: _Space, options: OptimiserOptions, variant: ModelVariant, budget: Budget) -> _Searched:
    """Steps 3-6 of the module docstring with the model set as ``variant``, within ``budget``."""
    f, todo = space.f, np.ones(len(space.f.ra_deg), bool)
    pts: list[Pointing] = []
    first: CoverSolution | None = None
    cover, sub, done = None, None, set()
    while todo.any():
        if cover is None or any(int(cover.owner[i]) in done or cover.owner[i] < 0 for i in np.flatnonzero(todo)):
            share = options.model_share if first is None else options.step_share
            cover, sub = _model(space, todo, options, variant, budget.share(share))
            first, done = (cover if first is None else first), set()
        used = np.bincount(cover.owner[todo], minlength=len(sub))
        if budget.expired():  # no time for the feedback: the model's pointings as they are
            pts += [_unallocated(f, np.flatnonzero(todo & (cover.owner == j)), sub.centres_mm[j], space.tangent)
                    for j in np.flatnonzero(used)]
            break
        j = int(np.argmax(used))  # the model's largest pointing
        given = np.flatnonzero(todo & (cover.owner == j))
        elsewhere = np.zeros(len(todo), bool)
        for k in np.flatnonzero(used):
            if k != j:
                elsewhere[sub.of(k)] = True
        p = commit(f, todo, given, _sky(sub.centres_mm[j], space.tangent, f.scale), elsewhere, options.fill,
                   budget)
        todo[p.members] = False
        done.add(j)
        pts.append(p)
    steps = len(pts)
    emptied = consolidate(f, pts, options.fill, budget)
    pts = [p for p in pts if len(p.members)]
    merged = merge_pointings(f, pts, options.fill, budget.share(options.merge_share)) if options.merge else 0
    return _Searched(variant, pts, first, steps, emptied, merged)


def _model(space: _Space, todo: np.ndarray, options: OptimiserOptions, variant: ModelVariant,
           budget: Budget) -> tuple[CoverSolution, Candidates]:
    """The programme model on the targets ``todo`` (bool mask), over its shortlist, with the
    rows of arm reach, the dominant crowding rows (a cell holding more of a candidate's
    members than they need exposures over the arms: :func:`.crowding.crowding_rows`) and
    every crowding row when ``variant`` says so: the feedback allocations see crowding as it
    is, and the other rows steer the model to pointings that take more exposures on some
    programmes, fewer on others (docs/programme.md)."""
    n, arms = len(todo), space.f.inst.n_arms
    sub, entries = space.cand.restrict(todo)
    keep = shortlist(sub, n, space.masks[entries], arms, options.max_candidates)
    sub, within_sub = sub.subset(keep)
    entries = entries[within_sub]
    allowed, rows = reach_rows(sub, space.masks[entries], arms)
    rows = with_crowding(rows, sub, space.cells, None if variant.crowding else arms)
    if len(sub.index) > SEARCH_MAX_ENTRIES:
        cover = greedy_solution(sub, n, arms=arms, reach=rows, allowed=allowed, pointing_cost=variant.pointing_cost)
    else:
        cover = solve_cover(sub, n, budget, arms=arms, seed=options.fill.seed, reach=rows, allowed=allowed,
                            pointing_cost=variant.pointing_cost)
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
