"""Step 4 of the programme optimiser: pointings committed one at a time, each allocated as
the plan allocates it, at a position angle that loses no target to reach.

:func:`commit` takes a pointing of the programme model's solution (:mod:`.model`):
re-centred on the smallest circle enclosing the targets the model gives it, rotated
(:func:`position_angle`), and allocated (:func:`solvers.allocation.allocate`, to completeness,
without the repacking post-pass, which costs seconds) on every target still to observe inside
its FOV. Its exposures are kept while they observe at least ``fill_min`` targets, or a target
no other pointing of the model's solution holds (those are allocated first: their priority is
raised by :data:`ONLY_HERE_BOOST` for this allocation). The targets of the exposures dropped
stay for the later pointings, where an arm is spare. So an exposure observing few targets is
kept only for targets no other pointing holds. The exposures kept go to the plan as a witness
(:func:`witness`), which the plan observes as it is when no allocation can take fewer
exposures, and keeps unless its own allocation is better otherwise.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from models.budget import Budget
from models.instrument import Instrument
from models.sky import sky_to_focal_mm, tangent_radius_mm
from models.types import AllocationResult, PlaneTargets, Unallocated
from solvers.allocation import allocate
from solvers.allocation.options import DEFAULT_SOLVER, AllocationOptions, PackingOptions
from solvers.programme.angle import AngleChoice, AngleSearch, choose_angle, refined_angles
from solvers.programme.crowding import crowding_cells, exclusion_distance_mm
from solvers.programme.reach import arm_masks, reach_least
from solvers.segmentation.field import local_fit
from solvers.sequencing.options import SequenceOptions

__all__ = ["GEOMETRIC", "ONLY_HERE_BOOST", "POSITION_ANGLES_DEG", "RIM_MARGIN_MM", "Field", "FillOptions", "Pointing",
           "allocate_pointing", "commit", "least_exposures", "observed_members", "pointing_angle", "position_angle",
           "recentre", "timed_allocation", "within"]

#: the position angles a pointing may take (the instrument allows any): every 5 deg (finer
#: than the arms' pitch, 30 deg on the default instrument, so that a turn moves a rim target
#: between the arms' reaches)
POSITION_ANGLES_DEG = tuple(float(a) for a in range(0, 360, 5))
#: members are kept inside the FOV by this margin (mm), so rounding never puts one outside
RIM_MARGIN_MM = 0.5
#: added to the priority of a target no other pointing holds, for the feedback allocation
ONLY_HERE_BOOST = 1_000_000
#: the reasons a member stays unobserved at any allocation of its pointing's placement
GEOMETRIC = frozenset({"unreachable", "beyond_park_move_limit"})
#: the reasons a target stays unobserved that no more time would change
SETTLED = GEOMETRIC | {"conflict"}


@dataclass(frozen=True)
class FillOptions:
    """How the plan allocates a pointing (the feedback allocates the same way), the angle the
    plan asks for (kept unless another loses fewer targets) and ``fill_min``: an exposure is
    kept when it observes at least this many targets (or one no other pointing holds).
    ``angle_search`` (the request's "auto"): every pointing takes the best angle of that
    search (:func:`solvers.programme.angle.choose_angle`) instead of the requested one."""

    method: str = "ilp"
    solver: str = DEFAULT_SOLVER
    seed: int = 0
    park_move_limit_s: float | None = 120.0
    position_angle_deg: float = 0.0
    search_position_angle: bool = True
    fill_min: int = 8
    angle_search: AngleSearch | None = None
    arm_limits: tuple[int, ...] | None = None

    def limited(self, masks: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """``masks`` (arms reaching each of ``targets``, programme indices) less the arms their
        locks forbid: ``arm_limits`` holds, per target of the programme, the bit mask of the
        arms it may use (a locked target: its arm only; None: every arm)."""
        if self.arm_limits is None:
            return masks
        return masks & np.asarray(self.arm_limits, np.int64)[np.asarray(targets, np.int64)]


@dataclass(frozen=True)
class Field:
    """The programme's targets: sky positions, priorities, the instrument."""

    inst: Instrument
    ra_deg: np.ndarray
    dec_deg: np.ndarray
    priority: np.ndarray

    @property
    def scale(self) -> float:
        return float(self.inst.plate_scale_arcsec_per_mm)

    @property
    def radius_mm(self) -> float:
        return float(self.inst.fov_radius_mm)


@dataclass
class Pointing:
    """A committed pointing: centre (sky), position angle, members, the exposures its
    allocation kept (None: not allocated) and the members no other pointing held."""

    centre: tuple[float, float]
    pa_deg: float
    members: np.ndarray
    exposures: int | None = None
    only_here: np.ndarray | None = None  # set once every pointing is known (mark_only_here)
    allocation: AllocationResult | None = None  # of ``members`` (ascending), its exposures kept
    pa_search: AngleChoice | None = None  # how ``pa_deg`` was chosen (None: not searched)
    #: when its allocation kept no exposure: the exposures of that allocation observing its
    #: members (at least 1), what the plan's own allocation of them is expected to take
    estimate: int | None = None
    #: wall seconds of the allocation ``allocation`` was taken from (0: none)
    allocation_s: float = 0.0


def within(f: Field, idx: np.ndarray, centre: tuple[float, float], margin_mm: float = RIM_MARGIN_MM) -> np.ndarray:
    """Which targets ``idx`` lie inside the FOV about ``centre`` (on its own plane), by
    ``margin_mm`` inside the rim."""
    r = tangent_radius_mm(f.ra_deg[idx], f.dec_deg[idx], centre[0], centre[1], f.scale)
    return r <= f.radius_mm - margin_mm


def recentre(f: Field, members: np.ndarray, start: tuple[float, float]) -> tuple[float, float]:
    """The centre (sky) of the smallest circle enclosing ``members`` on the plane about
    ``start``, fitted twice to absorb the change of plane
    (:func:`solvers.segmentation.field.local_fit`)."""
    rc, dc = start
    for _ in range(2):
        rc, dc = local_fit(members, f.ra_deg, f.dec_deg, rc, dc, f.scale)
    return rc, dc


def position_angle(f: Field, members: np.ndarray, centre: tuple[float, float], opts: FillOptions,
                   ) -> tuple[float, dict[float, int]]:
    """The angle of :data:`POSITION_ANGLES_DEG` (and the requested one) at which the fewest
    members are out of every arm's reach within the park move limit (thesis 7.3: FOV
    rotation); the requested angle, then the nearest to it, on ties. When every grid angle
    loses members, every 0.5 deg within one grid step of the best of them is tried too
    (:func:`solvers.programme.angle.refined_angles`). Returns the angle and
    the members lost at each angle tried (the search stops at the first angle losing none)."""
    want = float(opts.position_angle_deg) % 360.0
    if not opts.search_position_angle or len(members) == 0:
        return want, {}

    def distance(a: float) -> float:
        d = abs(a - want) % 360.0
        return min(d, 360.0 - d)

    angles = sorted({want, *POSITION_ANGLES_DEG}, key=lambda a: (distance(a), a))
    lost: dict[float, int] = {}

    def tried(order: list[float]) -> bool:
        for a in order:
            x, y = sky_to_focal_mm(f.ra_deg[members], f.dec_deg[members], centre[0], centre[1], f.scale, a)
            lost[a] = int(np.count_nonzero(opts.limited(arm_masks(f.inst, x, y, opts.park_move_limit_s), members) == 0))
            if lost[a] == 0:
                return True
        return False

    if not tried(angles):  # a narrow arc between the grid's angles may reach every member
        least = min(lost.values())
        step = POSITION_ANGLES_DEG[1] - POSITION_ANGLES_DEG[0]
        extra = refined_angles([a for a in angles if lost[a] == least], step, -math.inf, math.inf, angles)
        angles += sorted((a % 360.0 for a in extra), key=lambda a: (distance(a), a))
        tried(angles[len(lost):])
    return min(lost, key=lambda a: (lost[a], angles.index(a))), lost


def pointing_angle(f: Field, members: np.ndarray, centre: tuple[float, float], opts: FillOptions,
                   ) -> tuple[float, AngleChoice | None]:
    """The pointing's angle and how it was chosen: the best of ``opts.angle_search`` when the
    request asked for "auto", else :func:`position_angle` about the requested angle (None
    when it searched nothing)."""
    if opts.angle_search is not None and len(members):
        c = choose_angle(f.inst, f.ra_deg[members], f.dec_deg[members], f.priority[members], centre,
                         opts.angle_search, opts.park_move_limit_s,
                         None if opts.arm_limits is None else np.asarray(opts.arm_limits, np.int64)[members])
        return c.chosen_deg, c
    pa, lost = position_angle(f, members, centre, opts)
    if not lost:
        return pa, None
    want = float(opts.position_angle_deg) % 360.0
    objective = (f"{pa:g} deg: {lost[pa]} of {len(members)} targets lost to arm reach. Objective: the "
                 f"requested angle ({want:g} deg), else the angle nearest it, every "
                 f"{POSITION_ANGLES_DEG[1] - POSITION_ANGLES_DEG[0]:g} deg, that loses the fewest "
                 "targets to arm reach within the park move limit (tried nearest first, up to the "
                 "first that loses none).")
    return pa, AngleChoice(pa, tuple(lost), (), objective)


def timed_allocation(f: Field, p: Pointing, priority: np.ndarray, opts: FillOptions, budget: Budget,
                     ) -> tuple[AllocationResult, float]:
    """:func:`allocate_pointing` and its wall seconds (the plan reports how much of the
    optimiser's time went into allocations it observes as they are)."""
    t0 = time.perf_counter()
    result = allocate_pointing(f, p, priority, opts, budget)
    return result, time.perf_counter() - t0


def allocate_pointing(f: Field, p: Pointing, priority: np.ndarray, opts: FillOptions, budget: Budget,
                      ) -> AllocationResult:
    """``p``'s members allocated as the plan allocates a pointing (at ``priority``), to
    completeness, without the repacking post-pass, within what is left of ``budget`` (a
    pointing's allocation ends when its last exposure is proven, well before that on most)."""
    m = p.members
    x, y = sky_to_focal_mm(f.ra_deg[m], f.dec_deg[m], p.centre[0], p.centre[1], f.scale, p.pa_deg)
    targets = PlaneTargets.from_lists([str(int(i)) for i in m], np.asarray(x, float), np.asarray(y, float),
                                      priority[m].astype(np.int64))
    options = AllocationOptions(sequence=SequenceOptions(park_move_limit_s=opts.park_move_limit_s,
                                                         lower_bound_flow=False),
                                packing=PackingOptions(enabled=False))
    return allocate(f.inst, targets, method=opts.method, solver=opts.solver, configurations="all",
                    seed=opts.seed, budget=budget, options=options)


def commit(f: Field, todo: np.ndarray, given: np.ndarray, start: tuple[float, float], elsewhere: np.ndarray,
           opts: FillOptions, budget: Budget) -> Pointing:
    """One step (module docstring): the pointing the model gives ``given`` (target indices)
    about ``start`` (sky), taking every target of the bool mask ``todo`` inside its FOV;
    ``elsewhere``: bool mask of the targets another pointing of the model's solution holds.
    The pointing keeps at least ``given``'s targets when its allocation keeps nothing."""
    centre = recentre(f, given, start)
    inside = np.flatnonzero(todo)
    inside = inside[within(f, inside, centre)]
    members = np.union1d(inside, given)
    pa, search = pointing_angle(f, members, centre, opts)
    p = Pointing(centre, pa, members, pa_search=search)
    only = ~elsewhere[members]
    if budget.expired():
        return p
    raised = f.priority.astype(np.int64).copy()
    raised[members[only]] += ONLY_HERE_BOOST
    result, p.allocation_s = timed_allocation(f, p, raised, opts, budget)
    keep, p.exposures = _kept(result, members, only, opts.fill_min)
    if keep.size == 0:  # nothing worth an exposure: the model's targets, so that steps end
        keep = np.asarray(given, dtype=np.int64)
        p.exposures = None
        mine = set(int(t) for t in keep)
        p.estimate = max(1, sum(any(a.target_index is not None and int(members[a.target_index]) in mine
                                    for a in c.assignments) for c in result.configurations))
    else:
        p.allocation = witness(result, members, keep, p.exposures, f.priority)
    p.members = keep
    return p


def least_exposures(f: Field, p: Pointing, opts: FillOptions) -> int:
    """The fewest exposures in which any allocation at ``p``'s centre and angle can observe
    the members its witness observes: at least one per ``arms`` of them; by arm reach, the
    b-matching bound of :func:`solvers.programme.reach.reach_least` over the arms that reach
    each (within the park move limit and its lock, and the arm the witness gives it); by
    crowding, the most of them in one crowding cell (:mod:`.crowding`: targets closer than
    the exclusion distance never share an exposure). Each holds for every allocation, so a
    witness that takes this many exposures is as short as any (the plan observes it as it is)."""
    if p.allocation is None:
        return 0
    arm_of = {int(p.members[a.target_index]): a.arm for c in p.allocation.configurations[:p.exposures]
              for a in c.assignments if a.target_index is not None}
    seen = np.array(sorted(arm_of), dtype=np.int64)
    if seen.size == 0:
        return 0
    x, y = sky_to_focal_mm(f.ra_deg[seen], f.dec_deg[seen], p.centre[0], p.centre[1], f.scale, p.pa_deg)
    masks = opts.limited(arm_masks(f.inst, x, y, opts.park_move_limit_s), seen)
    masks |= np.left_shift(1, np.array([arm_of[int(t)] for t in seen], np.int64))
    cells = crowding_cells(np.column_stack([x, y]), exclusion_distance_mm(f.inst))
    return max(-(-len(seen) // f.inst.n_arms), reach_least(masks, f.inst.n_arms), int(cells.size.max()))


def observed_members(members: np.ndarray, result: AllocationResult) -> set[int]:
    """The targets (programme indices) that ``result``, an allocation of ``members``, observes."""
    return {int(members[a.target_index]) for c in result.configurations for a in c.assignments
            if a.target_index is not None}


def witness(result: AllocationResult, members: np.ndarray, keep: np.ndarray, exposures: int,
            priority: np.ndarray) -> AllocationResult | None:
    """The feedback allocation as an allocation of ``keep`` (ascending target indices, ids
    their ``str``): its first ``exposures`` configurations, re-indexed, their priority the
    true one; None when a kept target is not observed there for a reason of the geometry
    (:data:`SETTLED`; a search the budget cut: the plan then allocates the pointing itself)."""
    pos = {int(g): i for i, g in enumerate(keep)}
    configs, seen = [], set()
    for c in result.configurations[:exposures]:
        arms = []
        for a in c.assignments:
            if a.target_index is None:
                arms.append(a)
                continue
            g = int(members[a.target_index])
            seen.add(g)
            arms.append(replace(a, target_index=pos[g], target_id=str(g)))
        total = sum(int(priority[int(keep[a.target_index])]) for a in arms if a.target_index is not None)
        configs.append(replace(c, index=len(configs), assignments=tuple(arms), total_priority=total))
    why = {int(members[u.target_index]): u.reason for u in result.unallocated}
    missing = [g for g in keep if int(g) not in seen]
    if any(why.get(int(g)) not in SETTLED for g in missing):
        return None
    unallocated = tuple(Unallocated(pos[int(g)], str(int(g)), why[int(g)]) for g in missing)
    observed = len(seen)
    stats = {"source": "programme optimiser", "n_targets": len(keep), "n_configurations": len(configs),
             "n_allocated": observed, "field_completeness": observed / len(keep) if len(keep) else 1.0,
             "unallocated_by_reason": {r: sum(u.reason == r for u in unallocated)
                                       for r in sorted({u.reason for u in unallocated})}}
    return AllocationResult(tuple(configs), unallocated, stats)


def _kept(result: AllocationResult, members: np.ndarray, only: np.ndarray, fill_min: int,
          ) -> tuple[np.ndarray, int]:
    """The targets of the exposures kept (module docstring) and their number; every target
    only this pointing holds is kept, observed or not (the plan reports why not)."""
    seen = [[int(a.target_index) for a in c.assignments if a.target_index is not None]
            for c in result.configurations]
    last = -1
    for c, idx in enumerate(seen):
        if len(idx) >= fill_min or any(only[i] for i in idx):
            last = c
    keep = {int(members[i]) for c in seen[:last + 1] for i in c}
    keep |= {int(t) for t in members[only]}
    return np.array(sorted(keep), dtype=np.int64), last + 1


def mark_only_here(f: Field, pts: list[Pointing]) -> None:
    """Each pointing's ``only_here``: its targets no other pointing's FOV holds."""
    for j, p in enumerate(pts):
        elsewhere = np.zeros(len(p.members), bool)
        for k, q in enumerate(pts):
            if k != j and len(q.members):
                elsewhere |= within(f, p.members, q.centre)
        p.only_here = p.members[~elsewhere]
