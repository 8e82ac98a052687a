"""Steps 4-5 of the programme optimiser: pointings committed one at a time, each allocated as
the plan allocates it, at a position angle that loses no target to reach.

Each step solves the programme model on the targets still to observe (:mod:`.model`) and
commits its largest pointing: re-centred on the smallest circle enclosing the targets the model
gives it, rotated (:func:`position_angle`), and allocated (:func:`solvers.allocation.allocate`,
to completeness, without the post-passes that only shorten the sequence) on every target
still to observe inside its FOV. Its exposures are kept while they observe at least
``fill_min`` targets, or a target no other pointing of the model's solution holds (those
are allocated first: their priority is raised by :data:`ONLY_HERE_BOOST` for this
allocation). The targets of the exposures dropped stay for the next steps, where a pointing
with a spare arm takes them. So an exposure observing few targets is kept only for targets
no other pointing holds, and the model of each step knows what the real allocation of the
steps before achieved.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.budget import Budget
from models.instrument import Instrument
from models.sky import focal_mm_to_sky, sky_to_focal_mm, tangent_radius_mm
from models.types import AllocationResult, PlaneTargets
from solvers.allocation import allocate
from solvers.allocation.options import AllocationOptions, PackingOptions
from solvers.programme.reach import arm_masks
from solvers.segmentation.enclosing_circle import smallest_enclosing_circle
from solvers.sequencing.options import SequenceOptions

__all__ = ["ONLY_HERE_BOOST", "POSITION_ANGLES_DEG", "RIM_MARGIN_MM", "Field", "FillOptions", "Pointing",
           "commit", "position_angle", "recentre", "within"]

#: the position angles a pointing may take (the instrument allows any): every 30 deg
POSITION_ANGLES_DEG = tuple(float(a) for a in range(0, 360, 30))
#: members are kept inside the FOV by this margin (mm), so rounding never puts one outside
RIM_MARGIN_MM = 0.5
#: added to the priority of a target no other pointing holds, for the feedback allocation
ONLY_HERE_BOOST = 1_000_000


@dataclass(frozen=True)
class FillOptions:
    """How the plan allocates a pointing (the feedback allocates the same way), the angle the
    plan asks for (kept unless another loses fewer targets) and ``fill_min``: an exposure is
    kept when it observes at least this many targets (or one no other pointing holds)."""

    method: str = "ilp"
    solver: str = "bnb"
    seed: int = 0
    park_move_limit_s: float | None = 120.0
    position_angle_deg: float = 0.0
    search_position_angle: bool = True
    fill_min: int = 8
    allocation_cap_s: float = 1.0


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
    only_here: np.ndarray | None = None


def within(f: Field, idx: np.ndarray, centre: tuple[float, float], margin_mm: float = RIM_MARGIN_MM) -> np.ndarray:
    """Which targets ``idx`` lie inside the FOV about ``centre`` (on its own plane), by
    ``margin_mm`` inside the rim."""
    r = tangent_radius_mm(f.ra_deg[idx], f.dec_deg[idx], centre[0], centre[1], f.scale)
    return r <= f.radius_mm - margin_mm


def recentre(f: Field, members: np.ndarray, start: tuple[float, float]) -> tuple[float, float]:
    """The centre (sky) of the smallest circle enclosing ``members`` on the plane about
    ``start``, projected twice to absorb the change of plane."""
    rc, dc = start
    for _ in range(2):
        x, y = sky_to_focal_mm(f.ra_deg[members], f.dec_deg[members], rc, dc, f.scale)
        cx, cy, _ = smallest_enclosing_circle(np.column_stack([x, y]), seed=0)
        r2, d2 = focal_mm_to_sky(np.array([cx]), np.array([cy]), rc, dc, f.scale)
        rc, dc = float(r2[0]), float(d2[0])
    return rc, dc


def position_angle(f: Field, members: np.ndarray, centre: tuple[float, float], opts: FillOptions,
                   ) -> tuple[float, dict[float, int]]:
    """The angle of :data:`POSITION_ANGLES_DEG` (and the requested one) at which the fewest
    members are out of every arm's reach within the park move limit (thesis 7.3: FOV
    rotation); the requested angle, then the nearest to it, on ties. Returns the angle and
    the members lost at each angle tried (the search stops at the first angle losing none)."""
    want = float(opts.position_angle_deg) % 360.0
    if not opts.search_position_angle or len(members) == 0:
        return want, {}

    def distance(a: float) -> float:
        d = abs(a - want) % 360.0
        return min(d, 360.0 - d)

    angles = sorted({want, *POSITION_ANGLES_DEG}, key=lambda a: (distance(a), a))
    lost: dict[float, int] = {}
    for a in angles:
        x, y = sky_to_focal_mm(f.ra_deg[members], f.dec_deg[members], centre[0], centre[1], f.scale, a)
        lost[a] = int(np.count_nonzero(arm_masks(f.inst, x, y, opts.park_move_limit_s) == 0))
        if lost[a] == 0:
            break
    return min(lost, key=lambda a: (lost[a], angles.index(a))), lost


def _allocate(f: Field, p: Pointing, priority: np.ndarray, opts: FillOptions, budget: Budget) -> AllocationResult:
    m = p.members
    x, y = sky_to_focal_mm(f.ra_deg[m], f.dec_deg[m], p.centre[0], p.centre[1], f.scale, p.pa_deg)
    targets = PlaneTargets.from_lists([str(int(i)) for i in m], np.asarray(x, float), np.asarray(y, float),
                                      priority[m].astype(np.int64))
    options = AllocationOptions(sequence=SequenceOptions(park_move_limit_s=opts.park_move_limit_s,
                                                         lower_bound_flow=False),
                                packing=PackingOptions(enabled=False))
    call = budget.part(min(opts.allocation_cap_s, max(budget.left_s(), 1e-3)))
    return allocate(f.inst, targets, method=opts.method, solver=opts.solver, configurations="all",
                    seed=opts.seed, budget=call, options=options)


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
    pa, _ = position_angle(f, members, centre, opts)
    p = Pointing(centre, pa, members)
    only = ~elsewhere[members]
    if budget.expired():
        p.only_here = members[only]
        return p
    raised = f.priority.astype(np.int64).copy()
    raised[members[only]] += ONLY_HERE_BOOST
    keep, p.exposures = _kept(_allocate(f, p, raised, opts, budget), members, only, opts.fill_min)
    if keep.size == 0:  # nothing worth an exposure: the model's targets, so that steps end
        keep = np.asarray(given, dtype=np.int64)
        p.exposures = None
    p.members = keep
    p.only_here = np.intersect1d(keep, members[only])
    return p


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
