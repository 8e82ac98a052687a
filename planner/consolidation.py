"""After the rounds: exposures of a programme's plan emptied into the idle arms of its other
exposures (segmentation mode "fewest-exposures"; docs/programme.md, *Emptied exposures*).

Each pointing is allocated and planned on its own, so a pointing's last exposures observe the
few targets it has left while exposures of the neighbouring pointings keep idle arms over the
same sky. Once every pointing is planned, :func:`regroup` runs the optimiser's pass
(:func:`solvers.programme.consolidate.empty_exposures`: an exposure is given up when each of
its targets fits, as the other exposures stand, on an idle arm of one of them) on the plan's
configurations; when it empties none, it moves each target of an exposure observing two that
an idle arm of a fuller exposure can take there (:func:`solvers.programme.consolidate.thin_moves`: such an
exposure then keeps only targets no fuller exposure can take). The pointings it changes are
planned again with those configurations as their allocation (:attr:`Regrouped.allocation`;
the allocation is not searched again), reusing the legs of their plan where they make the
same moves (:mod:`planner.known_legs`), each on a share of what the rounds left in proportion
to what its new legs cost in them (:func:`replan_costs`, :func:`consolidation_tasks`); when
that does not fit in what is left, the pass runs again giving targets to the exposures whose
legs cost least to plan again, and then the costliest pointing is left out of the pass
(:func:`affordable`). The new plans replace the old ones only when every
one of them is executable, together they observe every target the old ones did and take fewer
exposures, or as many with fewer targets left in exposures observing few (:func:`accepted`,
:func:`few_observed`). A changed pointing whose new plan has a failed leg, or an
exposure its motion planner added for a moved target, is planned again, on another seed, with
what the rounds and the pass's plans left (:func:`retry_tasks`), before the new plans are
judged: a pass is not given up, nor its saving cut, for a leg while the limit has time for
it. Otherwise the plan stays as it was. An accepted pass's new plans move arms, so the pass
runs again on the plan it left, on what the rounds and the earlier passes left, while each
is accepted; a pass refused because some of its new plans failed runs again without those
pointings (:func:`another_pass`, at most :data:`MAX_PASSES`).

The pass reads the plan's outcomes and runs on the plan's effort clock, so the result is the
same on one or many workers.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from models.budget import Budget
from models.instrument import Instrument
from models.types import AllocationResult, ArmAssignment, Configuration
from planner.known_legs import new_legs
from planner.programme import PointingOutcome, RoundTask, best_outcomes, margin_left_s
from planner.shares import SHARES, ProgrammeShares
from solvers.programme.consolidate import (
    LegCosts,
    allocation_of,
    arms_of,
    empty_exposures,
    thin_moves,
)
from solvers.programme.fill import Field
from solvers.programme.spare import FEW_TARGETS

__all__ = ["MAX_PASSES", "MODE", "NEW_LEG_FACTOR", "NO_TIME_REASON", "PLAN_FAILED_REASON", "REUSED_LEG_S", "REPLAN_WALL_MARGIN", "REPLAN_WALL_MARGIN_MIN_S", "PASS_EFFORT_S", "PASS_WALL_GUARD", "PlannedPointing", "Regrouped", "accepted", "affordable", "another_pass", "applies",
           "consolidation_tasks", "costs", "few_observed", "groups_of", "left_s", "no_time", "pass_wall_s", "regroup", "replan_wall_s", "replan_costs", "retry_tasks"]

#: the segmentation mode whose plans are consolidated (the programme optimiser's)
MODE = "fewest-exposures"
#: the pass itself (its placement tests, every run of :func:`affordable`) runs on at most
#: this many effort seconds
PASS_EFFORT_S = 3.0
#: the pass's wall-clock guard is this many times the wall-clock seconds its effort stands for
#: (:func:`pass_wall_s`): a safety net for a machine slower than the effort clock's reference,
#: which ends the pass (its plan then stays as it was); what the pass spends is counted on the
#: effort clock, so the plan is the same on any machine the guard does not stop
PASS_WALL_GUARD = 2.0
#: a leg the pass makes new costs this many times an average leg of its pointing in the rounds
#: (its costliest round's motion seconds over its legs): it goes into or out of an exposure
#: that took a target on an arm its allocation left idle, or joins two exposures no leg joined,
#: a move no search of the rounds made easy (the 25 new legs of cluster-18001's crowded core
#: took 1.6 times its round's average leg: ``python benchmarks/replan_costs.py cluster:18001``)
NEW_LEG_FACTOR = 2.0
#: a leg the pass reuses (:mod:`planner.known_legs`) costs this many wall-clock seconds: it is
#: verified again (0.02-0.08 s per leg measured on pointings of 11-60 legs,
#: ``benchmarks/replan_costs.py``, at motion costs 1.44 times those of :mod:`planner.effort`:
#: 0.014-0.056 s at these; 0.053 s on the 60-target field of tests/test_known_legs.py)
REUSED_LEG_S = 0.07
#: a pass's reason when :func:`no_time` stops it before it searches
NO_TIME_REASON = "no time left to plan a changed pointing"
#: why a target of an exposure observing few stays although another exposure could take it:
#: its pointing or the taker's was planned again by a pass with targets moved, that plan
#: failed (a leg, or a target the motion planner dropped), and the later passes leave the
#: pointing out (:func:`another_pass`)
PLAN_FAILED_REASON = "consolidation_plan_failed"
#: passes at most: a pass runs again on the plan an accepted pass left (its new plans move
#: arms and free others, so another exposure's targets may fit where none did), while each
#: is accepted (:func:`another_pass`)
MAX_PASSES = 4
#: of the wall-clock time the plan has left, what a changed pointing's plan keeps back for the
#: work after its wall-clock guard (its answer built and verified): the consolidation's
#: shares spend the rounds' margin (``consolidation_effort_share``), so on a machine slower
#: than the effort clock's reference its last plan ends at its guard, not at its share
#: (cluster-halo-12007, 300 stars: a second plan of an 18-exposure pointing took 0.3-0.55 s
#: past its guard), at least ``REPLAN_WALL_MARGIN_MIN_S``
REPLAN_WALL_MARGIN = 0.05
REPLAN_WALL_MARGIN_MIN_S = 1.0


def pass_wall_s(effort_s: float = PASS_EFFORT_S, table: ProgrammeShares = SHARES) -> float:
    """The wall-clock seconds ``effort_s`` of the pass stand for, counted as the rounds count
    a pointing's effort (over ``effort_share``)."""
    return effort_s / table.effort_share


def replan_wall_s(wall_left_s: float) -> float:
    """The wall-clock guard of a changed pointing's plan when the plan has ``wall_left_s``
    wall-clock seconds left: that less :data:`REPLAN_WALL_MARGIN` of it, and less at least
    :data:`REPLAN_WALL_MARGIN_MIN_S` (none when that leaves nothing)."""
    return max(wall_left_s - max(REPLAN_WALL_MARGIN * wall_left_s, REPLAN_WALL_MARGIN_MIN_S), 0.0)


def applies(mode: str, keeps_configurations: bool) -> bool:
    """Whether a plan is consolidated: in :data:`MODE`, unless it keeps configurations of a
    previous plan (those stay as they were)."""
    return mode == MODE and not keeps_configurations


@dataclass(frozen=True)
class PlannedPointing:
    """A pointing as the plan observes it: centre (sky, deg), position angle, its
    configurations (each arm's ``target_index``: the target's index in the programme) and its
    members the plan does not observe, with the reason (programme index -> reason)."""

    centre: tuple[float, float]
    pa_deg: float
    configurations: tuple[Configuration, ...]
    unobserved: Mapping[int, str]


@dataclass(frozen=True)
class Regrouped:
    """A pointing the pass changed: its members (programme indices, ascending) and their
    allocation (``target_index`` into ``members``, ``target_id`` the ``str`` of the programme
    index: the form of :attr:`solvers.segmentation.field.Pointing.allocation`) and its
    ``group``: the least index of the pointings it gave targets to or took targets from,
    directly or through others (:func:`groups_of`); a group's new plans are kept or refused
    together, apart from the other groups'."""

    index: int
    members: tuple[int, ...]
    allocation: AllocationResult
    group: int = 0


def groups_of(exchanges: Sequence[frozenset[int]]) -> dict[int, int]:
    """The pointings of ``exchanges`` (each: the pointings that gave or took the targets of
    one exposure) in connected groups: pointing -> the least pointing of its group."""
    parent: dict[int, int] = {}

    def root(j: int) -> int:
        while parent.setdefault(j, j) != j:
            j = parent[j]
        return j

    for ex in exchanges:
        first, *rest = sorted(ex)
        root(first)  # a pointing whose exposure gave its targets to its own other exposures
        for j in rest:
            a, b = sorted((root(first), root(j)))
            parent[b] = a
    return {j: root(j) for j in parent}


def regroup(inst: Instrument, ra_deg: np.ndarray, dec_deg: np.ndarray, priority: np.ndarray,
            pointings: Sequence[PlannedPointing], park_move_limit_s: float | None,
            arm_limits: tuple[int, ...] | None, budget: Budget, *,
            frozen: frozenset[int] = frozenset(),
            per_leg_s: Mapping[int, float] | None = None) -> tuple[int, int, list[Regrouped]]:
    """The exposures the pass gives up, the targets it moves out of exposures observing few
    targets (:func:`solvers.programme.consolidate.thin_moves`, only when it empties none: a
    pass that saves exposures is not made costlier, or riskier, by moves that save nothing)
    and the pointings it changes (module docstring); the pointings ``frozen`` neither give nor
    take a target. ``per_leg_s`` (what planning one leg of each pointing again costs): a
    target goes to the exposure whose legs cost least to plan again, then the fullest
    (:class:`solvers.programme.consolidate.LegCosts`); None: the fullest."""
    f = Field(inst, np.asarray(ra_deg, float), np.asarray(dec_deg, float), np.asarray(priority, np.int64))
    state = {j: arms_of(inst.n_arms, p.centre, p.pa_deg, p.configurations, _programme_index)
             for j, p in enumerate(pointings) if p.configurations and j not in frozen}
    legs = None if per_leg_s is None else LegCosts.of(state, per_leg_s)
    saved, exchanges = empty_exposures(f, state, park_move_limit_s, arm_limits, budget, legs)
    moved = 0
    if not exchanges:  # moves that save nothing never put a saving's plans at risk
        saved, moved, exchanges = thin_moves(f, state, park_move_limit_s, arm_limits, budget, legs=legs)
    group = groups_of(exchanges)
    out = []
    for j in sorted(group):
        members, allocation = allocation_of(f, state[j], pointings[j].configurations, _programme_index,
                                            pointings[j].unobserved, "consolidation")
        out.append(Regrouped(j, members, allocation, group[j]))
    return saved, moved, out


def _programme_index(asg: ArmAssignment) -> int:
    return int(asg.target_index)


def affordable(inst: Instrument, ra_deg: np.ndarray, dec_deg: np.ndarray, priority: np.ndarray,
               pointings: Sequence[PlannedPointing], park_move_limit_s: float | None,
               arm_limits: tuple[int, ...] | None, budget: Budget, costs_s: Mapping[int, float], left_s: float,
               table: ProgrammeShares = SHARES, frozen: frozenset[int] = frozenset(),
               ) -> tuple[int, int, list[Regrouped]]:
    """:func:`regroup` with what planning the changed pointings again costs within ``left_s``
    (the pointings ``frozen`` left out from the start):
    each costs what it spent in the rounds on the legs it plans anew (:func:`replan_costs`;
    at least ``min_pointing_s``). When they do not fit, the pass runs again with each target
    given to the exposure whose legs cost least to plan again (``per_leg_s`` of
    :func:`regroup`); while that does not fit either, the costliest pointing it changes is left
    out of the pass and both run again; (0, 0, []) when nothing that fits changes, at once
    when ``left_s`` holds no pointing's ``min_pointing_s`` (no change could fit)."""
    if no_time(left_s, table):
        return 0, 0, []
    per_leg = {j: costs_s.get(j, 0.0) / (len(p.configurations) + 1) for j, p in enumerate(pointings)}

    def attempt(frozen: frozenset[int]) -> tuple[tuple[int, int, list[Regrouped]] | None, dict[int, float]]:
        """The pass with ``frozen`` left out, the fullest takers first, then (when what that
        changes does not fit) the cheapest legs first: the first whose changes fit (else
        None), and the costs of the last one's changes."""
        need: dict[int, float] = {}
        for thrifty in (None, per_leg):
            saved, moved, changed = regroup(inst, ra_deg, dec_deg, priority, pointings, park_move_limit_s,
                                            arm_limits, budget, frozen=frozen, per_leg_s=thrifty)
            if not changed:
                continue
            need = replan_costs(costs_s, pointings, changed)
            if sum(max(v, table.min_pointing_s) for v in need.values()) <= left_s:
                return (saved, moved, changed), need
        return None, need

    while not budget.expired():
        fit, need = attempt(frozen)
        if fit is not None:
            return fit
        if not need:
            return 0, 0, []
        frozen = frozen | {max(need, key=lambda j: (need[j], j))}
    return 0, 0, []


def no_time(left_s: float, table: ProgrammeShares = SHARES) -> bool:
    """Whether ``left_s`` holds no pointing's least plan (``min_pointing_s``): no change of a
    pass could be planned again (:data:`NO_TIME_REASON`)."""
    return left_s < table.min_pointing_s


def replan_costs(costs_s: Mapping[int, float], pointings: Sequence[PlannedPointing],
                 changed: Sequence[Regrouped]) -> dict[int, float]:
    """What planning each ``changed`` pointing again costs when the legs of its plan are
    reused where its new configurations make the same moves (:mod:`planner.known_legs`):
    :data:`NEW_LEG_FACTOR` times its average leg in the rounds (its cost there, ``costs_s``,
    :func:`costs`, over its legs) for each leg it plans anew
    (:func:`planner.known_legs.new_legs`), and :data:`REUSED_LEG_S` for each leg it reuses; at
    most its cost in the rounds."""
    out = {}
    for r in changed:
        p, cost = pointings[r.index], costs_s[r.index]
        legs = len(r.allocation.configurations) + 1
        fresh = new_legs(p.configurations, r.allocation.configurations)
        per_leg_s = cost / (len(p.configurations) + 1)
        out[r.index] = min(cost, NEW_LEG_FACTOR * per_leg_s * fresh + REUSED_LEG_S * (legs - fresh))
    return out


def costs(history: Sequence[Sequence[PointingOutcome]], table: ProgrammeShares = SHARES) -> dict[int, float]:
    """What planning each pointing again costs, in wall-clock seconds counted as
    :func:`planner.programme.next_round` counts them: the most one of its rounds spent on its
    motion legs (the allocation is not searched again; a round the wall guard stopped counts
    its whole share)."""
    out: dict[int, float] = {}
    for outcomes in history:
        for o in outcomes:
            motion = o.share_s if o.overran else (o.effort_s - o.allocation_effort_s) / table.effort_share
            out[o.index] = max(out.get(o.index, 0.0), motion)
    return out


def left_s(limit_s: float | None, history: Sequence[Sequence[PointingOutcome]], spent_s: float = 0.0,
           table: ProgrammeShares = SHARES) -> float:
    """What the rounds (and ``spent_s`` more) left of the plan's usable limit, counted as
    :func:`planner.programme.next_round` counts it but with each outcome's effort at
    ``consolidation_effort_share`` (:class:`planner.shares.ProgrammeShares`): the plan's last
    step spends the margin the rounds kept."""
    return margin_left_s(limit_s, history, table) - spent_s


def consolidation_tasks(costs_s: Mapping[int, float], left: float, round_: int, changed: Sequence[int],
                        table: ProgrammeShares = SHARES) -> list[RoundTask]:
    """The tasks that plan the ``changed`` pointings again in round ``round_``: ``left``
    seconds split in proportion to their costs (each at least ``min_pointing_s``), so each
    gets at least what it spent in the rounds; none when ``left`` is less than that."""
    need = {i: max(costs_s[i], table.min_pointing_s) for i in changed}
    total = sum(need.values())
    if not changed or total > left:
        return []
    scale = left / total if math.isfinite(left) else 1.0
    return [RoundTask(i, round_, need[i] * scale) for i in sorted(changed)]


def retry_tasks(costs_s: Mapping[int, float], limit_s: float | None, history: Sequence[Sequence[PointingOutcome]],
                spent_s: float, tries: Sequence[Sequence[PointingOutcome]],
                table: ProgrammeShares = SHARES) -> list[RoundTask]:
    """The pass's next plans of its changed pointings, after ``tries`` (the outcomes of each
    of its plans so far, the first :func:`consolidation_tasks`): the pointings whose best plan
    of the pass has a failed leg, or (once) takes an exposure the motion planner added for a
    target it moved (another seed and more time may route the arms without it; the best plan
    is the one with fewer exposures, :func:`planner.programme.rank`), each with what the
    rounds (``history``), the pass (``spent_s``)
    and its plans left, split as :func:`consolidation_tasks` splits it (in proportion to their
    costs, each at least what it spent in the rounds). None when every one is executable, when
    that is not enough for them, or after ``table.rounds`` plans of the pass; the round numbers
    go on from the rounds' (each plan on another seed)."""
    if not tries or len(tries) >= table.rounds:
        return []
    best = best_outcomes(tries)
    tried = Counter(o.index for outcomes in tries for o in outcomes)
    failed = sorted(i for i, o in best.items()
                    if o.attempted and (not o.executable or (o.exposures_added and tried[i] < 2)))
    if not failed:
        return []
    left = left_s(limit_s, [*history, *tries], spent_s, table)
    return consolidation_tasks(costs_s, left, len(history) + len(tries) + 1, failed, table)


def another_pass(accepted_passes: Sequence[bool], max_passes: int = MAX_PASSES,
                 left_out: Sequence[frozenset[int]] = ()) -> bool:
    """Whether the plan runs the pass again after passes whose plans were kept or not
    (``accepted_passes``, in order): while every pass so far was accepted, or refused with
    pointings whose new plans failed that the later passes leave out (``left_out[i]``: those
    pass i adds; none: the pass would only run again as it ran), at most ``max_passes`` in
    all (the time each takes is counted as the first's is)."""
    more = list(left_out) + [frozenset()] * (len(accepted_passes) - len(left_out))
    return len(accepted_passes) < max_passes and all(a or bool(m) for a, m in zip(accepted_passes, more, strict=False))


def few_observed(targets_per_exposure: Sequence[int], few: int = FEW_TARGETS) -> int:
    """The targets observed in exposures observing at most ``few`` (each exposure's count of
    targets in ``targets_per_exposure``): what moving targets out of such exposures lowers."""
    return sum(n for n in targets_per_exposure if n <= few)


def accepted(old_observed: Sequence[set[str]], new_observed: Sequence[set[str]], old_exposures: int,
             new_exposures: int, executable: Sequence[bool], old_few: int = 0, new_few: int = 0) -> bool:
    """Whether the changed pointings' new plans replace their old ones: every one executable,
    together observing every target the old ones did, in fewer exposures, or in as many with
    fewer targets in exposures observing few (``old_few``/``new_few``, :func:`few_observed`)."""
    old_all = set().union(*old_observed)
    new_all = set().union(*new_observed)
    fewer = new_exposures < old_exposures or (new_exposures == old_exposures and new_few < old_few)
    return all(executable) and new_all >= old_all and fewer
