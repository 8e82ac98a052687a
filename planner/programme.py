"""A whole programme: how one plan's time limit is shared over its pointings, and the plan of
one pointing (allocation, then the executable motion sequence park -> c1 -> ... -> park).

The synchronous plan (``POST /v1/plans``, ``mxs-planner plan``), a plan job (its local pool or
Dask) and the benchmarks all run :func:`run_rounds` with their own way of computing a round's
pointings; the policy is here, once:

1. **Shares by need.** Each pointing's wall-clock share of the plan's limit follows its need
   (:func:`pointing_need`: its targets, plus a fixed part for the legs every pointing has),
   fixed before any pointing runs (:func:`pointing_shares`), so the plan is the same on one or
   many workers, in any order.
2. **Rounds.** A pointing's searches run on the effort clock (:func:`plan_pointing`), so what
   it spends is a function of its task alone. Time the first round does not use is not lost:
   the pointings whose plan has a failed leg are planned again, each with a share of what the
   earlier rounds left (:func:`next_round`), which depends only on the earlier rounds'
   outcomes: the same on any number of workers. A round's plan replaces an earlier one only
   when it is better (:func:`better`). Rounds go on while a failed pointing can be given more
   than it had; so no pointing reports a failed leg while the plan's limit has time that
   could be given to it.

All shares are in wall-clock seconds; a pointing's searches get :attr:`ProgrammeShares.effort_share`
of its share in effort seconds (``models.clock``), the rest is the margin by which a machine
may be slower than the effort clock's calibration before the wall-clock guard stops them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from models import clock
from models.budget import Budget
from models.errors import InputError
from models.instrument import CONFIGURATION_TIME_GOAL_S, Instrument
from models.locks import TargetLock
from models.types import (
    AllocationResult,
    Configuration,
    PlaneTargets,
    Unallocated,
)
from planner.exposure_caps import (
    TARGETS_PER_EXPOSURE,
    apply_exposure_rules,
    estimated_exposures,
    exposure_caps,
    split_by_thresholds,
)
from planner.keep import (
    KeptPointing,
    allocate_rest,
    kept_configurations,
    kept_count,
    split_rest,
    with_kept,
)
from planner.locks import honours, member_locks, motion_locks, plain_reasons, with_lock_reasons
from planner.sequence import MIN_LEG_S, SequenceOptions, SequencePlan, plan_sequence
from planner.sky import SkyField, place_sky
from planner.telescope_time import ObservingRules, TelescopeTime, pointing_time
from solvers.allocation import allocate
from solvers.allocation.options import DEFAULT_SOLVER, AllocationOptions
from solvers.sequencing.options import SequenceOptions as AllocationSequenceOptions

__all__ = [
    "ALLOCATION_PART", "DEFAULT_LIMIT_S", "DEFAULT_SEGMENTATION_MODE", "SHARES", "TARGETS_PER_EXPOSURE", "PointingOptions", "PointingOutcome", "PointingPlan",
    "ProgrammeShares", "RoundTask", "better", "estimated_exposures", "given_allocation", "exposure_caps", "first_round_shares",
    "by_expected_share", "expected_share_s", "fitting", "next_round",
    "optimiser_s", "plan_pointing", "pointing_need", "pointing_seed", "pointing_shares", "plan_progress", "rank", "reserve_s",
    "run_rounds", "segmentation_mode", "usable_s",
]

Progress = Callable[[float], None]
log = logging.getLogger("planner")


def _noop(_: float) -> None:
    pass


@dataclass(frozen=True)
class ProgrammeShares:
    """The driver's one table of shares; each entry says what it protects."""

    #: Of the plan's limit, kept back (at most ``reserve_max_s``) to build and send the answer
    #: after the last pointing: it keeps the answer within the request's limit.
    reserve_fraction: float = 0.05
    reserve_max_s: float = 0.5
    #: Effort seconds a pointing's searches get per wall-clock second of its share. Below 1 by
    #: the margin a machine may be slower than the effort clock's calibration before the
    #: wall-clock guard, not the work, ends the searches (the plan then depends on the load).
    effort_share: float = 0.8
    #: Of a pointing's effort, what its allocation may use; the motion legs and the
    #: allocation <-> motion loop get the rest (and whatever the allocation left).
    allocation_share: float = 0.5
    #: The legs with the spare arms on sky are planned once the plain legs are, when the
    #: motion time left is at least this many times what the plain legs took
    #: (:func:`_sequence_with_sky`), and kept when every one of them is planned.
    sky_motion_factor: float = 1.5
    #: A pointing whose share is below this is not attempted (its targets ``no_time``): less
    #: cannot allocate and plan even one leg.
    min_pointing_s: float = 0.5
    #: Every pointing's need counts this many targets on top of its own: the legs from and
    #: back to park, which even a one-target pointing plans.
    fixed_need_targets: int = 12
    #: Rounds at most (the first included): each plans again the pointings with a failed leg
    #: on what the earlier rounds left (a round is due only while one fails, and only while
    #: enough is left for it: so many that a failed leg is given all the limit has).
    rounds: int = 8
    #: Of the plan's limit, what the programme optimiser (segmentation mode
    #: "fewest-exposures") may use, at most ``optimiser_max_s``: the pointings get the rest.
    optimiser_share: float = 0.08
    optimiser_max_s: float = 12.0
    #: Effort seconds a pointing's plan takes per target, measured by ``python
    #: benchmarks/time_need.py`` (docs/programme.md: 93 pointings of ten programmes of 63-181
    #: stars and the M67-like case; a pointing's effort follows its targets more closely than
    #: its need): the median, a typical pointing's, and the 95th percentile, enough for all but
    #: one in twenty (a limit asked too long costs nothing: a plan ends when it is done). A
    #: first round whose limit cannot hold every pointing's typical share plans only the
    #: neediest pointings whose shares of enough fit (:func:`first_round_shares`), and the
    #: plan's answer says which limit its field needs from the shares of enough
    #: (:func:`planner.time_advice.needed_limit_s`).
    typical_effort_per_target_s: float = 0.18
    enough_effort_per_target_s: float = 0.56
    #: The least share a pointing is expected to be planned whole in: its legs need
    #: ``MIN_LEG_S`` effort seconds (0.625 s of share at ``effort_share``) after its allocation.
    least_planned_s: float = 0.75
    #: A pointing whose plan failed on a share is estimated to need at least this many times
    #: that share (the estimate behind :func:`planner.time_advice.time_advice`).
    failed_growth: float = 2.0


SHARES = ProgrammeShares()
#: A plan's progress once its field is segmented.
SEGMENTED = 0.05
#: A plan's progress once every pointing has its first-round plan; the later rounds (those
#: that plan again the pointings with a failed leg) share the rest equally.
FIRST_ROUND_DONE = 0.85
#: Of a pointing's progress, the part its allocation reports (its motion legs the rest): a
#: progress below it is the allocation's (:func:`planner.stages.plan_stage`).
ALLOCATION_PART = 0.5
#: How a plan splits its field into pointings when the caller does not say
#: (:data:`solvers.segmentation.field.MODES`): the programme optimiser, which takes fewer
#: exposures than complete linkage on the programme benchmark (docs/programme.md).
DEFAULT_SEGMENTATION_MODE = "fewest-exposures"


def segmentation_mode(requested: str | None, n_targets: int) -> str:
    """A plan's segmentation mode: the one requested, else :data:`DEFAULT_SEGMENTATION_MODE`
    for a programme the optimiser plans (at most
    :data:`solvers.programme.segment.MAX_TARGETS` targets) and complete linkage beyond."""
    from solvers.programme.segment import MAX_TARGETS

    if requested is not None:
        return requested
    return DEFAULT_SEGMENTATION_MODE if n_targets <= MAX_TARGETS else "complete-linkage"
#: The limit of a whole plan when the caller gives none: the instrument's configuration time
#: goal, and the default of ``POST /v1/plans`` and ``mxs-planner plan``.
DEFAULT_LIMIT_S = 120.0


def plan_progress(round_: int, done: float, total: int, table: ProgrammeShares = SHARES) -> float:
    """A plan's progress with ``done`` of the ``total`` tasks of round ``round_`` computed (a
    fraction for the part done of one being computed): :data:`SEGMENTED`, then round 1 to
    :data:`FIRST_ROUND_DONE` in proportion to its pointings, then each later round an equal
    part of the rest. It never decreases from one round to the next, and a plan ends at 1
    whichever round it stops after."""
    part = min(max(done / max(total, 1), 0.0), 1.0)
    if round_ <= 1:
        return SEGMENTED + (FIRST_ROUND_DONE - SEGMENTED) * part
    step = (1.0 - FIRST_ROUND_DONE) / max(table.rounds - 1, 1)
    return min(FIRST_ROUND_DONE + step * (round_ - 2 + part), 1.0)


# ------------------------------------------------------------------------ shares


def reserve_s(limit_s: float | None, table: ProgrammeShares = SHARES) -> float:
    """What a plan limited to ``limit_s`` keeps back to build its answer."""
    if limit_s is None or math.isinf(limit_s):
        return 0.0
    return min(table.reserve_fraction * limit_s, table.reserve_max_s)


def usable_s(limit_s: float | None, table: ProgrammeShares = SHARES) -> float:
    """What the pointings of a plan limited to ``limit_s`` may use (inf: no limit)."""
    if limit_s is None or math.isinf(limit_s):
        return math.inf
    return max(limit_s - reserve_s(limit_s, table), 0.0)


def optimiser_s(limit_s: float | None, table: ProgrammeShares = SHARES) -> float:
    """The wall-clock seconds the programme optimiser of a plan limited to ``limit_s`` may
    use (its searches get ``effort_share`` of them in effort seconds)."""
    if limit_s is None or math.isinf(limit_s):
        return table.optimiser_max_s
    return min(table.optimiser_share * usable_s(limit_s, table), table.optimiser_max_s)


def pointing_need(n_targets: int, table: ProgrammeShares = SHARES, *,
                  max_configurations: int | None = None) -> float:
    """A pointing's need: its targets plus the fixed part every pointing has; none for a
    pointing given no exposure (``max_configurations`` 0: it is not attempted)."""
    if max_configurations == 0:
        return 0.0
    return float(n_targets + table.fixed_need_targets)


def pointing_shares(limit_s: float | None, needs: Sequence[float],
                    table: ProgrammeShares = SHARES) -> list[float]:
    """The usable limit split in proportion to ``needs``, fixed in advance. A share below
    ``min_pointing_s`` is raised to it, taken from the largest shares; when the limit cannot
    give every pointing that minimum, the first pointings get it and the others none (their
    targets ``no_time``)."""
    return _split_usable(usable_s(limit_s, table), needs, table)


def expected_share_s(need: float, table: ProgrammeShares = SHARES, *, typical: bool = False) -> float:
    """The wall-clock share a pointing of need ``need`` (:func:`pointing_need`: its targets
    plus ``fixed_need_targets``) is expected to be planned in: its targets (at least one) times
    ``enough_effort_per_target_s`` (``typical``: ``typical_effort_per_target_s``) in effort
    seconds, over ``effort_share``, at least ``least_planned_s``; none for a pointing of no
    need (it is not attempted)."""
    if need <= 0:
        return 0.0
    per_target_s = table.typical_effort_per_target_s if typical else table.enough_effort_per_target_s
    targets = max(need - table.fixed_need_targets, 1.0)
    return max(targets * per_target_s / table.effort_share, table.least_planned_s)


def fitting(usable: float, indices: Sequence[int], needs: Sequence[float],
            table: ProgrammeShares = SHARES, *, at_least_one: bool = True) -> list[int]:
    """Of ``indices``, the pointings a plan with ``usable`` seconds plans: the neediest first
    (ties: the lower index), each taken when its :func:`expected_share_s` (enough) still fits
    in what the ones taken before left, so that every pointing taken can be planned whole
    rather than every pointing started on too little. When none fits and ``at_least_one``,
    the least needy alone (ties: the lower index; while ``usable`` reaches
    ``min_pointing_s``): the one most likely to be planned in all there is. Sorted by index."""
    left, chosen = usable, []
    wanted = sorted((i for i in indices if needs[i] > 0), key=lambda i: (-needs[i], i))
    for i in wanted:
        if expected_share_s(needs[i], table) <= left:
            chosen.append(i)
            left -= expected_share_s(needs[i], table)
    if at_least_one and not chosen and wanted and usable >= table.min_pointing_s:
        chosen = [min(wanted, key=lambda i: (needs[i], i))]
    return sorted(chosen)


def by_expected_share(usable: float, chosen: Sequence[int], needs: Sequence[float],
                      table: ProgrammeShares = SHARES) -> list[float]:
    """``usable`` seconds split over the ``chosen`` pointings in proportion to their
    :func:`expected_share_s` (enough): each gets at least it when they fit together."""
    weights = [expected_share_s(needs[i], table) for i in chosen]
    total = sum(weights)
    return [usable * w / total for w in weights] if total > 0 else [0.0] * len(chosen)


def first_round_shares(limit_s: float | None, needs: Sequence[float],
                       table: ProgrammeShares = SHARES) -> list[float]:
    """The first round's wall-clock share of each pointing. When the usable limit holds
    every pointing's typical :func:`expected_share_s`, it is :func:`pointing_shares` (split
    by need; the rounds give what the quick ones leave to the slow ones). When it does not,
    the limit cannot plan them all: only the pointings that :func:`fitting` takes are
    planned, the usable limit split over them by :func:`by_expected_share`; the others get
    none (their targets ``no_time``) and wait for what the rounds leave (:func:`next_round`)."""
    usable = usable_s(limit_s, table)
    if math.isinf(usable) or sum(expected_share_s(w, table, typical=True) for w in needs) <= usable:
        return pointing_shares(limit_s, needs, table)
    chosen = fitting(usable, range(len(needs)), needs, table)
    given = dict(zip(chosen, by_expected_share(usable, chosen, needs, table), strict=True))
    return [given.get(i, 0.0) for i in range(len(needs))]


def _split_usable(usable: float, needs: Sequence[float], table: ProgrammeShares) -> list[float]:
    """``usable`` seconds split by need (:func:`pointing_shares`)."""
    n = len(needs)
    if math.isinf(usable):
        return [math.inf] * n
    if usable < n * table.min_pointing_s:
        fit = int(usable // table.min_pointing_s)
        return [table.min_pointing_s if i < fit else 0.0 for i in range(n)]
    total = float(sum(needs)) or 1.0
    shares = [usable * w / total for w in needs]
    short = [i for i, s in enumerate(shares) if s < table.min_pointing_s]
    if short:
        floor = table.min_pointing_s * len(short)
        rest = [i for i in range(n) if i not in short]
        rest_total = sum(needs[i] for i in rest) or 1.0
        for i in short:
            shares[i] = table.min_pointing_s
        for i in rest:
            shares[i] = (usable - floor) * needs[i] / rest_total
    return shares


def pointing_seed(seed: int, index: int, round_: int = 1) -> int:
    """The seed of pointing ``index`` of a plan seeded ``seed`` in round ``round_``: a fixed
    function of the three (pointing 0 keeps ``seed`` in the first round), so a pointing's plan
    does not depend on which worker computes it or in which order the pointings run; a later
    round searches with another seed (its share may be smaller than the first round's, and
    the same search on less time could not do better)."""
    return (int(seed) + 2_654_435_761 * int(index) + 40_503 * (int(round_) - 1)) % 2**31


# ------------------------------------------------------------------------ rounds


@dataclass(frozen=True)
class RoundTask:
    """Pointing ``index`` planned in round ``round`` (1 = the first) within ``share_s``."""

    index: int
    round: int
    share_s: float


@dataclass(frozen=True)
class PointingOutcome:
    """What the next round needs of one pointing's plan: its share, the effort seconds its
    searches spent (a function of the task alone, unless the wall guard fired), whether
    every leg was planned, and how many legs failed and targets it observes."""

    index: int
    round: int
    share_s: float
    effort_s: float
    executable: bool
    failed_legs: int
    observed: int
    overran: bool = False
    #: False when the pointing was not attempted for lack of time (no share, or a deadline
    #: with less than the least share left): its plan observes nothing and plans no leg.
    attempted: bool = True

    def spent_s(self, table: ProgrammeShares = SHARES) -> float:
        """The wall-clock share this outcome used up, counted deterministically (its effort
        over ``effort_share``, at most its share)."""
        if math.isinf(self.share_s):
            return self.effort_s / table.effort_share
        return self.share_s if self.overran else min(self.effort_s / table.effort_share, self.share_s)


def rank(o: PointingOutcome) -> tuple[bool, bool, int, int]:
    """How good a pointing's plan is: attempted first (a plan not attempted for lack of time
    observes nothing, though no leg of it failed), then executable, then fewer failed legs,
    then more targets observed."""
    return (o.attempted, o.executable, -o.failed_legs, o.observed)


def better(new: PointingOutcome, old: PointingOutcome) -> bool:
    """Whether a later round's plan replaces the one kept (:func:`rank`; a tie keeps the old)."""
    return rank(new) > rank(old)


def next_round(needs: Sequence[float], limit_s: float | None,
               history: Sequence[Sequence[PointingOutcome]],
               table: ProgrammeShares = SHARES) -> list[RoundTask]:
    """The tasks of the round after ``history`` (the outcomes of each earlier round): the
    pointings whose best plan so far has a failed leg, each with a share of what the earlier
    rounds left in proportion to its need (:func:`_by_need`: at least ``min_pointing_s``, the
    least needy left out when there is not enough for all; its search runs on another seed,
    :func:`pointing_seed`). When none has a failed leg, the pointings not attempted yet (a
    short limit's first round left them out) whose expected shares fit in what is left
    (:func:`fitting`; none when none fits), split by :func:`by_expected_share`. Empty when no round is due: every pointing is executable, ``rounds`` are
    done, or less than ``min_pointing_s`` is left."""
    r = len(history) + 1
    if r > table.rounds or not history:
        return []
    usable = usable_s(limit_s, table)
    if math.isinf(usable):
        return []  # without a limit every pointing already had all the time it asked for
    best: dict[int, PointingOutcome] = {}
    spent = 0.0
    for outcomes in history:
        for o in outcomes:
            spent += o.spent_s(table)
            if o.index not in best or better(o, best[o.index]):
                best[o.index] = o
    failed = [i for i, o in best.items() if o.attempted and not o.executable]
    left = usable - spent
    if left < table.min_pointing_s:
        return []
    if failed:
        return [RoundTask(i, r, share) for i, share in sorted(_by_need(left, failed, needs, table).items())]
    waiting = fitting(left, sorted(i for i, o in best.items() if not o.attempted), needs, table,
                      at_least_one=False)
    shares = by_expected_share(left, waiting, needs, table)
    return [RoundTask(i, r, share) for i, share in zip(waiting, shares, strict=True)]


def _by_need(left_s: float, indices: Sequence[int], needs: Sequence[float],
             table: ProgrammeShares) -> dict[int, float]:
    """``left_s`` split by need over the neediest of ``indices`` that each get at least
    ``min_pointing_s`` (the least needy are left out, one at a time, until every share
    reaches it): a round spends all that is left on as many pointings as it can."""
    chosen = sorted(indices, key=lambda i: (-needs[i], i))
    while chosen:
        total = sum(needs[i] for i in chosen) or 1.0
        shares = {i: left_s * needs[i] / total for i in chosen}
        if min(shares.values()) >= table.min_pointing_s:
            return shares
        chosen.pop()
    return {}


def run_rounds(needs: Sequence[float], limit_s: float | None,
               compute: Callable[[Sequence[RoundTask]], Sequence[PointingOutcome]],
               table: ProgrammeShares = SHARES) -> list[list[PointingOutcome]]:
    """The one plan loop of a programme: the first round on :func:`first_round_shares`, then
    :func:`next_round` until none is due. ``compute`` plans a round's tasks (in this process,
    on a job's runner, on Dask: any order) and keeps each pointing's best plan
    (:func:`better`); it returns their outcomes. Returns the outcomes of every round."""
    shares = first_round_shares(limit_s, needs, table)
    tasks = [RoundTask(i, 1, s) for i, s in enumerate(shares)]
    history: list[list[PointingOutcome]] = []
    while tasks:
        history.append(list(compute(tasks)))
        tasks = next_round(needs, limit_s, history, table)
    return history


# --------------------------------------------------------------- one pointing


@dataclass(frozen=True)
class PointingOptions:
    """A pointing's plan options: the allocation's method and solver, its seed
    (:func:`pointing_seed`), the allocation's park move limit (None: none), the most
    exposures (configurations) it may take (None: as many as completeness needs; 0: the
    pointing is not attempted, its targets ``beyond_max_exposures``; the programme's
    ``max_exposures`` split by :func:`exposure_caps`) and the request's
    :class:`~planner.telescope_time.ObservingRules` (its exposure thresholds and the times its
    telescope time is counted with)."""

    method: str = "ilp"
    solver: str = DEFAULT_SOLVER
    seed: int = 0
    park_move_limit_s: float | None = CONFIGURATION_TIME_GOAL_S
    max_configurations: int | None = None
    rules: ObservingRules = field(default_factory=ObservingRules)
    #: an allocation of the pointing's targets, kept instead of the one the plan computes when
    #: it observes more targets or as many in fewer exposures (the programme optimiser's,
    #: :attr:`solvers.segmentation.Pointing.allocation`; target ids are replaced by the
    #: pointing's own, by index)
    allocation: AllocationResult | None = field(default=None, compare=False, repr=False)
    #: the pointing's sky (:class:`planner.sky.SkyField`): its spare arms are placed on sky after
    #: the allocation (:func:`planner.sky.place_sky`); None: they rest where the allocator left them
    sky: SkyField | None = field(default=None, compare=False, repr=False)
    #: a previous plan's pointing whose configurations c1..ck are kept as they were
    #: (:mod:`planner.keep`): the plan allocates the members they leave from ck's arm states
    kept: KeptPointing | None = field(default=None, compare=False, repr=False)
    #: the locks of the pointing's members (:mod:`models.locks`): the allocation keeps each on
    #: its arm (and branch), and so do the motion planner's changes (:mod:`planner.locks`)
    locked: tuple[TargetLock, ...] = ()

    def __post_init__(self) -> None:
        cap = self.max_configurations
        if cap is not None and (isinstance(cap, bool) or not isinstance(cap, int) or cap < 0):
            raise InputError("max_configurations", f"must be an integer >= 0 or None, got {cap!r}")
        if not isinstance(self.rules, ObservingRules):
            raise InputError("rules", "must be an ObservingRules")
        if self.kept is not None and not isinstance(self.kept, KeptPointing):
            raise InputError("kept", f"must be a KeptPointing or None, got {type(self.kept).__name__}")


@dataclass(frozen=True)
class PointingPlan:
    """One pointing's plan on domain types. ``allocation`` is None when the pointing was not
    attempted for lack of time (its share below ``min_pointing_s``: its targets ``no_time``);
    its ``unallocated`` include the targets the exposure rules left out
    (``beyond_max_exposures``, ``below_exposure_threshold``). ``unplanned_reason`` says why
    its legs were not planned (a planner failure, or no time left): every leg is then
    reported failed. ``telescope_time``: what the plan as returned costs
    (:func:`planner.telescope_time.pointing_time`; set by :func:`plan_pointing`)."""

    targets: PlaneTargets
    allocation: AllocationResult | None
    sequence: SequencePlan
    unplanned_reason: str | None = None
    stats: dict = field(default_factory=dict)
    effort_s: float = 0.0
    overran: bool = False
    telescope_time: TelescopeTime | None = None

    @property
    def executable(self) -> bool:
        """Whether every leg was planned and verified (never when ``unplanned_reason`` is set)."""
        return self.unplanned_reason is None and self.sequence.executable


def allocation_options(park_move_limit_s: float | None,
                       max_configurations: int | None = None) -> AllocationOptions:
    """The allocation options of a plan: every location within its park move limit, at most
    ``max_configurations`` configurations (None: to completeness)."""
    return AllocationOptions(sequence=AllocationSequenceOptions(park_move_limit_s=park_move_limit_s,
                                                                max_configurations=max_configurations))


def pointing_telescope_time(plan: PointingPlan, rules: ObservingRules) -> TelescopeTime:
    """The telescope time of ``plan`` as returned: its configurations, and the makespans of
    its legs park -> c1 -> ... -> park (a leg not planned counts in ``unplanned_legs``)."""
    seq = plan.sequence
    n = len(seq.configurations)
    if plan.unplanned_reason is None and len(seq.legs) == n + 1:
        makespans = [leg.makespan_s if leg.status == "ok" else None for leg in seq.legs]
    else:
        makespans = [None] * (n + 1)
    return pointing_time(n, makespans, rules.exposure_time_s, rules.acquisition_s)


def plan_pointing(inst: Instrument, targets: PlaneTargets, options: PointingOptions,
                  share_s: float, progress: Progress = _noop,
                  table: ProgrammeShares | None = None, *,
                  wall_limit_s: float | None = None) -> PointingPlan:
    """Allocation (all configurations, at most ``options.max_configurations``; the exposure
    thresholds of ``options.rules`` applied) then the executable motion sequence of one
    pointing, within ``share_s`` wall-clock seconds (thesis ch. 5 and 6), with its telescope
    time.

    Every budget inside runs on the effort clock (:func:`models.clock.effort`) and the
    searches get ``effort_share`` of the share in effort seconds: the plan then depends only
    on its arguments (the same on any machine, under any load, on any worker). ``share_s``
    stays the wall-clock limit (or ``wall_limit_s``, when the plan's deadline has less left:
    the budget is still counted from ``share_s``, so that the plan does not depend on how
    long other pointings took): a machine so slow that it is reached stops the searches
    there, and the plan's ``overran`` says so (as it does when the deadline had less than
    the least share left: the pointing is then not attempted)."""
    table = SHARES if table is None else table  # read at call time
    wall_s = share_s if wall_limit_s is None else min(wall_limit_s, share_s)
    cut = share_s >= table.min_pointing_s > wall_s  # the deadline, not the share, rules it out
    with clock.effort(wall_limit_s=wall_s) as effort:
        plan = _plan_pointing(inst, targets, options, 0.0 if cut else share_s, progress, table)
    return PointingPlan(plan.targets, plan.allocation, plan.sequence, plan.unplanned_reason,
                        plan.stats, effort.t_s, effort.overran or cut, pointing_telescope_time(plan, options.rules))


def _plan_pointing(inst: Instrument, targets: PlaneTargets, options: PointingOptions,
                   share_s: float, progress: Progress, table: ProgrammeShares) -> PointingPlan:
    if options.max_configurations == 0 or share_s < table.min_pointing_s:
        return _not_attempted(inst, targets, options)
    budget = Budget.start(table.effort_share * share_s)  # the pointing's effort seconds
    kept = () if options.kept is None else kept_configurations(inst, targets, options.kept)
    result = _allocate(inst, targets, options, kept, budget.share(table.allocation_share), progress)
    given = given_allocation(options, targets)
    if given is not None and _allocation_rank(given) > _allocation_rank(result) and \
            honours(inst, given, options.locked):
        result = given
    result, below = apply_exposure_rules(plain_reasons(result), targets, options.max_configurations,
                                         options.rules)
    skyed = None if options.sky is None else with_kept(replace(result, configurations=place_sky(
        inst, result.configurations, options.sky, options.park_move_limit_s)), kept)
    progress(ALLOCATION_PART)
    result = with_kept(result, kept)
    motion_s = budget.left_s()
    legs = len(result.configurations) + 1
    if motion_s < MIN_LEG_S:
        seq, err = SequencePlan(tuple(result.configurations), ()), (
            f"no time left for motion planning ({max(motion_s, 0.0):.2f} s of the pointing's "
            "share for its legs)")
    else:
        motion_progress = lambda f: progress(ALLOCATION_PART + (1.0 - ALLOCATION_PART) * f)  # noqa: E731
        result, seq, err = _sequence_with_sky(inst, result, skyed, targets, options, budget, motion_progress,
                                              table)
        if err is None:
            seq, err, weak = _thresholds_after_motion(inst, seq, targets, options, budget, motion_progress)
            if weak:  # exposures the motion planner's changes left below a threshold
                result = replace(result, unallocated=result.unallocated + weak)
                below["dropped_after_motion"] = len(weak)
    stats = {"allocation": result.stats,
             "motion": {"legs": len(seq.legs) if err is None else legs, "budget_s": motion_s},
             "exposure_rules": below}
    if options.locked:  # a locked target left out says so (after the rules read its reason)
        result = replace(result, unallocated=with_lock_reasons(result.unallocated, options.locked))
        seq = replace(seq, dropped=with_lock_reasons(seq.dropped, options.locked))
    return PointingPlan(targets, result, seq, err, stats)


def _allocate(inst: Instrument, targets: PlaneTargets, options: PointingOptions,
              kept: Sequence[Configuration], budget: Budget, progress: Progress) -> AllocationResult:
    """The pointing's allocation (all configurations, at most ``options.max_configurations``)
    within ``budget``; with ``kept`` configurations, of the members they leave, from the last
    one's arm states (:func:`planner.keep.allocate_rest`; the kept ones are put in front after
    the exposure rules, :func:`planner.keep.with_kept`)."""
    def run(tg: PlaneTargets, start_q: np.ndarray | None, cap: int | None) -> AllocationResult:
        return allocate(inst, tg, method=options.method, solver=options.solver, configurations="all",
                        seed=options.seed, budget=budget, start_q=start_q,
                        locked=member_locks(options.locked, tg.ids),
                        progress=lambda p, _m="": progress(ALLOCATION_PART * min(max(float(p), 0.0), 1.0)),
                        options=allocation_options(options.park_move_limit_s, cap))

    if not kept:
        return run(targets, None, options.max_configurations)
    return allocate_rest(targets, kept, options.max_configurations, run)


def _allocation_rank(result: AllocationResult) -> tuple[int, int]:
    """How good an allocation of a pointing is: more targets observed, then fewer exposures."""
    observed = {a.target_index for c in result.configurations for a in c.assignments if a.target_index is not None}
    return len(observed), -len(result.configurations)


def given_allocation(options: PointingOptions, targets: PlaneTargets) -> AllocationResult | None:
    """``options.allocation`` relabelled with ``targets``' ids and cut to the pointing's cap;
    None when there is none or it is not an allocation of these targets (another count, or a
    tip more than 1 micron from its target: the plan then allocates the pointing itself)."""
    given = options.allocation
    if given is None or given.stats.get("n_targets") != len(targets.ids):
        return None
    configs = []
    for c in given.configurations[:options.max_configurations]:
        arms = []
        for a in c.assignments:
            if a.target_index is not None:
                i = int(a.target_index)
                if not (0 <= i < len(targets.ids)) or math.hypot(a.x_mm - float(targets.x_mm[i]),
                                                                 a.y_mm - float(targets.y_mm[i])) > 1e-3:
                    return None
                a = replace(a, target_id=targets.ids[i])
            arms.append(a)
        configs.append(replace(c, assignments=tuple(arms)))
    observed = {a.target_index for c in configs for a in c.assignments if a.target_index is not None}
    cut = tuple(Unallocated(i, targets.ids[i], "beyond_max_exposures")
                for c in given.configurations[len(configs):] for a in c.assignments
                if (i := a.target_index) is not None and i not in observed)
    unallocated = tuple(replace(u, target_id=targets.ids[u.target_index]) for u in given.unallocated) + cut
    return AllocationResult(tuple(configs), unallocated, dict(given.stats))


def _not_attempted(inst: Instrument, targets: PlaneTargets, options: PointingOptions) -> PointingPlan:
    """A pointing not attempted: no exposure left for it (``max_configurations`` 0: its targets
    ``beyond_max_exposures``) or no time (allocation None: its targets ``no_time``)."""
    seq = plan_sequence(inst, (), SequenceOptions(seed=options.seed))
    motion = {"legs": len(seq.legs), "budget_s": 0.0}
    if options.max_configurations == 0:
        unallocated = tuple(Unallocated(i, t, "beyond_max_exposures") for i, t in enumerate(targets.ids))
        skipped = "max_exposures leaves no exposure for this pointing"
        return PointingPlan(targets, AllocationResult((), unallocated, {"skipped": skipped}), seq, stats={
            "allocation": {"skipped": skipped}, "motion": motion,
            "exposure_rules": {"max_configurations": 0}})
    return PointingPlan(targets, None, seq, stats={
        "allocation": {"skipped": "the plan's time limit left this pointing no share"}, "motion": motion})


def _thresholds_after_motion(inst: Instrument, seq: SequencePlan, targets: PlaneTargets,
                             options: PointingOptions, budget: Budget, progress: Progress,
                             ) -> tuple[SequencePlan, str | None, tuple[Unallocated, ...]]:
    """The motion planner's changes (a target moved out of an exposure, one added for it) can
    leave an exposure below a threshold: drop those and plan the legs of the others again,
    adding none (so every pass has fewer exposures, and this ends). A target the new plan
    can place only in an added exposure is ``below_exposure_threshold`` too (or
    ``beyond_max_exposures`` when the pointing's cap is what forbids it). Returns the plan,
    the reason its legs were not planned (None: planned) and the targets dropped."""
    weak_all: list[Unallocated] = []
    cap = options.max_configurations
    while True:
        kept, weak = split_rest(seq.configurations, lambda cs: split_by_thresholds(cs, targets, options.rules))
        if not weak:
            return seq, None, tuple(weak_all)
        weak_all.extend(weak)
        if not kept:
            empty = plan_sequence(inst, (), SequenceOptions(seed=options.seed))
            return replace(empty, dropped=seq.dropped), None, tuple(weak_all)
        if budget.left_s() < MIN_LEG_S:
            return SequencePlan(kept, (), dropped=seq.dropped), (
                f"no time left to plan the legs again without the exposures below the threshold "
                f"({max(budget.left_s(), 0.0):.2f} s of the pointing's share left)"), tuple(weak_all)
        again, err = _sequence(inst, kept, targets, replace(options, max_configurations=len(kept)),
                               budget, progress)
        cap_binds = cap is not None and len(kept) >= cap
        dropped = tuple(u if cap_binds or u.reason != "beyond_max_exposures"
                        else replace(u, reason="below_exposure_threshold") for u in again.dropped)
        seq = replace(again, dropped=seq.dropped + dropped)
        if err is not None:
            return seq, err, tuple(weak_all)


def _sequence_with_sky(inst: Instrument, plain: AllocationResult, skyed: AllocationResult | None,
                       targets: PlaneTargets, options: PointingOptions, budget: Budget, progress: Progress,
                       table: ProgrammeShares) -> tuple[AllocationResult, SequencePlan, str | None]:
    """The legs of ``plain`` (the spare arms where the allocator left them); then, when they
    are all planned and the motion time left is at least ``table.sky_motion_factor`` times
    what they took, the legs of ``skyed`` (the spare arms on sky, :func:`planner.sky.place_sky`),
    kept when all of them are planned and they observe no fewer targets. Resting arms on sky
    never costs the plan a leg, nor the time its legs need. Returns the allocation whose legs
    were kept."""
    left_s = budget.left_s()
    seq, err = _sequence(inst, plain.configurations, targets, options, budget, progress)
    if skyed is None or skyed.configurations == plain.configurations or err is not None or not seq.executable:
        return plain, seq, err
    took_s = left_s - budget.left_s()
    if budget.left_s() < table.sky_motion_factor * took_s:
        log.info("no time to rest the spare arms on sky (%.2f s left, the legs took %.2f s)",
                 budget.left_s(), took_s)
        return plain, seq, err
    # the pointing's progress has reached the end of its legs: the sky pass does not move it back
    sky_seq, sky_err = _sequence(inst, skyed.configurations, targets, options, budget, _noop)
    if sky_err is None and sky_seq.executable and len(sky_seq.dropped) <= len(seq.dropped):
        return skyed, sky_seq, None
    return plain, seq, err


def _sequence(inst: Instrument, configs: Sequence[Configuration], targets: PlaneTargets,
              options: PointingOptions, budget: Budget,
              progress: Progress) -> tuple[SequencePlan, str | None]:
    """``planner.sequence.plan_sequence`` on one pointing's configurations within what
    ``budget`` (the pointing's) has left, adding none beyond ``options.max_configurations``;
    never raises: a planner failure comes back as the unchanged configurations with its
    reason."""
    configs = tuple(configs)
    # a leg may use all the motion time left (the sequence shares it over the legs still
    # to plan); an unlimited pointing gives each leg the library's minute
    leg_s = budget.limit_s if math.isfinite(budget.limit_s) else 60.0
    seq_options = SequenceOptions(seed=options.seed, leg_time_limit_s=float(leg_s),
                                  park_move_limit_s=options.park_move_limit_s,
                                  max_configurations=options.max_configurations,
                                  locked=motion_locks(options.locked),
                                  kept=kept_count(configs))
    try:
        return plan_sequence(inst, configs, seq_options, targets=targets, progress=progress,
                             budget=budget), None
    except Exception as exc:  # noqa: BLE001 - reported as failed legs, never a 5xx
        log.exception("motion sequence planning failed")
        return SequencePlan(configs, ()), f"planner error: {type(exc).__name__}: {exc}"
