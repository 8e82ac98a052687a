"""The plan of one pointing of a programme: its allocation (thesis ch. 5; the exposure rules,
locks, kept configurations and sky placement applied), then the executable motion sequence
park -> c1 -> ... -> park (ch. 6), within the pointing's share on the effort clock, with its
telescope time. The rounds that share a plan's limit over its pointings are
:mod:`planner.programme`'s."""

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
    apply_exposure_rules,
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
from planner.known_legs import KnownLegs
from planner.locks import honours, member_locks, motion_locks, plain_reasons, with_lock_reasons
from planner.sequence import MIN_LEG_S, SequenceOptions, SequencePlan, plan_sequence
from planner.shares import ALLOCATION_PART, SHARES, ProgrammeShares
from planner.sky import SkyField, place_sky
from planner.telescope_time import ObservingRules, TelescopeTime, pointing_time
from solvers.allocation import allocate
from solvers.allocation.options import DEFAULT_SOLVER, AllocationOptions
from solvers.sequencing.options import SequenceOptions as AllocationSequenceOptions

__all__ = ["PointingOptions", "PointingPlan", "allocation_options", "given_allocation", "plan_pointing",
           "pointing_telescope_time"]

Progress = Callable[[float], None]
log = logging.getLogger("planner")


def _noop(_: float) -> None:
    pass


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
    #: ``allocation`` is observed as it is, without a search of the plan's own (a pointing the
    #: plan's consolidation changed, :mod:`planner.consolidation`)
    allocation_final: bool = False
    #: the pointing's sky (:class:`planner.sky.SkyField`): its spare arms are placed on sky after
    #: the allocation (:func:`planner.sky.place_sky`); None: they rest where the allocator left them
    sky: SkyField | None = field(default=None, compare=False, repr=False)
    #: a previous plan's pointing whose configurations c1..ck are kept as they were
    #: (:mod:`planner.keep`): the plan allocates the members they leave from ck's arm states
    kept: KeptPointing | None = field(default=None, compare=False, repr=False)
    #: the locks of the pointing's members (:mod:`models.locks`): the allocation keeps each on
    #: its arm (and branch), and so do the motion planner's changes (:mod:`planner.locks`)
    locked: tuple[TargetLock, ...] = ()
    #: an earlier plan's verified legs (:mod:`planner.known_legs`): the motion planner reuses
    #: them where this plan makes the same moves (a pointing the plan's consolidation changed)
    known_legs: KnownLegs | None = field(default=None, compare=False, repr=False)

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
    #: the effort seconds of ``effort_s`` its allocation took (the rest went to the motion legs)
    allocation_effort_s: float = 0.0

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
                        plan.stats, effort.t_s, effort.overran or cut, pointing_telescope_time(plan, options.rules),
                        plan.allocation_effort_s)


def _plan_pointing(inst: Instrument, targets: PlaneTargets, options: PointingOptions,
                   share_s: float, progress: Progress, table: ProgrammeShares) -> PointingPlan:
    if options.max_configurations == 0 or share_s < table.min_pointing_s:
        return _not_attempted(inst, targets, options)
    budget = Budget.start(table.effort_share * share_s)  # the pointing's effort seconds
    kept = () if options.kept is None else kept_configurations(inst, targets, options.kept)
    given = given_allocation(options, targets)
    if given is not None and options.allocation_final and not kept and honours(inst, given, options.locked):
        result = given
    else:
        result = _allocate(inst, targets, options, kept, budget.share(table.allocation_share), progress)
        if given is not None and _allocation_rank(given) > _allocation_rank(result) and \
                honours(inst, given, options.locked):
            result = given
    result, below = apply_exposure_rules(plain_reasons(result), targets, options.max_configurations,
                                         options.rules)
    skyed = None if options.sky is None else with_kept(replace(result, configurations=place_sky(
        inst, result.configurations, options.sky, options.park_move_limit_s)), kept)
    progress(ALLOCATION_PART)
    result = with_kept(result, kept)
    allocation_s = budget.elapsed_s()
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
    return PointingPlan(targets, result, seq, err, stats, allocation_effort_s=allocation_s)


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
    """The legs of ``skyed`` (the spare arms on sky, :func:`planner.sky.place_sky`), kept when
    every one is planned and the motion planner dropped no target; else the legs of ``plain``
    (the spare arms where the allocator left them) on what is left, and the sky legs kept only
    when they are executable and drop no more targets. Returns the allocation whose legs were
    kept.

    The sky legs come first because a spare arm resting on sky near the field moves less
    between exposures than one sent back to park: on cluster-18005's 35-exposure pointing the
    legs took 40 s each on sky against 105 s plain (docs/allocation.md, *Sky positions (spare arms)*),
    and planning them first spends the pointing's motion time once. A pointing planned again
    from an earlier plan (known legs, :mod:`planner.known_legs`: a later round's retry of a
    failed leg, the consolidation) plans the plain legs first (:func:`_plain_first`): its legs
    come before its sky, and a failed sky attempt could take the time they need."""
    if skyed is None or skyed.configurations == plain.configurations:
        seq, err = _sequence(inst, plain.configurations, targets, options, budget, progress)
        return plain, seq, err
    if options.known_legs is not None:
        return _plain_first(inst, plain, skyed, targets, options, budget, progress, table)
    sky_seq, sky_err = _sequence(inst, skyed.configurations, targets, options, budget, progress)
    if sky_err is None and sky_seq.executable and not sky_seq.dropped:
        return skyed, sky_seq, None
    seq, err = _sequence(inst, plain.configurations, targets, options, budget, _noop)
    return (skyed, sky_seq, None) if _sky_kept(sky_seq, sky_err, seq, err) else (plain, seq, err)


def _sky_kept(sky_seq: SequencePlan, sky_err: str | None, seq: SequencePlan, err: str | None) -> bool:
    """Whether the sky legs ``sky_seq`` are kept over the plain ones ``seq`` (``*_err``: why a
    sequence was not planned): they are executable, and the plain ones are not or drop no
    fewer targets."""
    if sky_err is not None or not sky_seq.executable:
        return False
    return err is not None or not seq.executable or len(sky_seq.dropped) <= len(seq.dropped)


def _plain_first(inst: Instrument, plain: AllocationResult, skyed: AllocationResult,
                 targets: PlaneTargets, options: PointingOptions, budget: Budget, progress: Progress,
                 table: ProgrammeShares) -> tuple[AllocationResult, SequencePlan, str | None]:
    """The legs of ``plain``; then, when they are all planned and the motion time left is at
    least ``table.sky_motion_factor`` times what they took, the legs of ``skyed``, kept when
    all of them are planned and they drop no more targets."""
    left_s = budget.left_s()
    seq, err = _sequence(inst, plain.configurations, targets, options, budget, progress)
    if err is not None or not seq.executable:
        return plain, seq, err
    took_s = left_s - budget.left_s()
    if budget.left_s() < table.sky_motion_factor * took_s:
        log.info("no time to rest the spare arms on sky (%.2f s left, the legs took %.2f s)",
                 budget.left_s(), took_s)
        return plain, seq, err
    # the pointing's progress has reached the end of its legs: the sky pass does not move it back
    sky_seq, sky_err = _sequence(inst, skyed.configurations, targets, options, budget, _noop)
    return (skyed, sky_seq, None) if _sky_kept(sky_seq, sky_err, seq, err) else (plain, seq, err)


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
                             budget=budget, known=options.known_legs), None
    except Exception as exc:  # noqa: BLE001 - reported as failed legs, never a 5xx
        log.exception("motion sequence planning failed")
        return SequencePlan(configs, ()), f"planner error: {type(exc).__name__}: {exc}"
