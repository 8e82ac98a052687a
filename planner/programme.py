"""A whole programme: how one plan's time limit is shared over its pointings. The plan of one
pointing (allocation, then the executable motion sequence park -> c1 -> ... -> park) is
:mod:`planner.pointing`'s, the table of shares :mod:`planner.shares`'; both are imported here
for the programme's callers.

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
   could be given to it. A later round plans a pointing again from its best plan so far
   (:func:`keeps_plan`): its configurations are observed as they are and its verified legs
   reused, so that the round's share goes to the legs that failed, not to a new allocation
   and every leg again on less time than the first round had.
3. **After the rounds** (mode "fewest-exposures"), :mod:`planner.consolidation` empties
   exposures into idle arms of the plan's other exposures and plans the pointings it changed
   again on what the rounds left, keeping their plans only when better.

All shares are in wall-clock seconds; a pointing's searches get :attr:`ProgrammeShares.effort_share`
of its share in effort seconds (``models.clock``), the rest is the margin by which a machine
may be slower than the effort clock's calibration before the wall-clock guard stops them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from planner.exposure_caps import (
    TARGETS_PER_EXPOSURE,
    estimated_exposures,
    exposure_caps,
)
from planner.pointing import (
    PointingOptions,
    PointingPlan,
    allocation_options,
    given_allocation,
    plan_pointing,
    pointing_telescope_time,
)
from planner.shares import ALLOCATION_PART, FIRST_ROUND_DONE, SEGMENTED, SHARES, ProgrammeShares

__all__ = [
    "ALLOCATION_PART", "DEFAULT_LIMIT_S", "DEFAULT_SEGMENTATION_MODE", "FIRST_ROUND_DONE", "SEGMENTED", "SHARES",
    "TARGETS_PER_EXPOSURE", "PointingOptions", "PointingOutcome", "PointingPlan", "allocation_options",
    "pointing_telescope_time",
    "ProgrammeShares", "RoundTask", "best_outcomes", "better", "planned", "estimated_exposures", "given_allocation", "exposure_caps", "first_round_shares",
    "by_expected_share", "expected_share_s", "fitting", "next_round",
    "keeps_plan", "margin_left_s", "margin_round", "optimiser_guard_s", "optimiser_s", "variants_s", "rounds_limit_s", "plan_pointing", "pointing_need", "pointing_seed", "pointing_shares", "plan_progress", "rank", "reserve_s", "wall_reserve_s",
    "run_rounds", "segmentation_mode", "usable_s",
]

Progress = Callable[[float], None]
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


def wall_reserve_s(limit_s: float | None, n_targets: int, table: ProgrammeShares = SHARES) -> float:
    """What the wall clock of a plan of ``n_targets`` limited to ``limit_s`` keeps back after
    its last pointing: :func:`reserve_s` and ``answer_s_per_target`` a target, at most
    ``reserve_fraction`` of the limit."""
    if limit_s is None or math.isinf(limit_s):
        return 0.0
    return min(table.reserve_fraction * limit_s, table.reserve_max_s + table.answer_s_per_target * n_targets)


def usable_s(limit_s: float | None, table: ProgrammeShares = SHARES) -> float:
    """What the pointings of a plan limited to ``limit_s`` may use (inf: no limit)."""
    if limit_s is None or math.isinf(limit_s):
        return math.inf
    return max(limit_s - reserve_s(limit_s, table), 0.0)


def optimiser_s(limit_s: float | None, table: ProgrammeShares = SHARES, n_targets: int | None = None) -> float:
    """The wall-clock seconds the programme optimiser of a plan of ``n_targets`` limited to
    ``limit_s`` may use (its searches get ``effort_share`` of them in effort seconds): its
    share, and :func:`variants_s` for its model's other variants."""
    return _optimiser_share_s(limit_s, table) + variants_s(limit_s, table, n_targets)


def variants_s(limit_s: float | None, table: ProgrammeShares = SHARES, n_targets: int | None = None) -> float:
    """The wall-clock seconds the programme optimiser of a plan of ``n_targets`` limited to
    ``limit_s`` may add for its model's other variants: what the usable time leaves beyond the
    optimiser's share and ``variants_need_factor`` times the typical effort of the targets (in
    wall-clock seconds, a pointing's fixed part counted once: ``fixed_need_targets``), at most
    ``variants_max_s``; none without a limit or a count."""
    if n_targets is None or limit_s is None or math.isinf(limit_s):
        return 0.0
    targets = n_targets + table.fixed_need_targets
    need_s = table.variants_need_factor * table.typical_effort_per_target_s * targets / table.effort_share
    left_s = usable_s(limit_s, table) - _optimiser_share_s(limit_s, table) - need_s
    return min(max(left_s, 0.0), table.variants_max_s)


def optimiser_guard_s(optimiser_s: float, table: ProgrammeShares = SHARES) -> float:
    """The programme optimiser's wall-clock guard for ``optimiser_s`` wall-clock seconds of
    share (``optimiser_guard_factor`` times it): past it the guard, not the optimiser's
    budget, ends the searches."""
    return table.optimiser_guard_factor * optimiser_s


def rounds_limit_s(limit_s: float, n_targets: int, variants_effort_s: float,
                   table: ProgrammeShares = SHARES) -> float:
    """What a plan of ``n_targets`` limited to ``limit_s`` leaves its pointings after the
    programme optimiser: the limit less the optimiser's share and less the wall-clock seconds
    its model's other variants used (``variants_effort_s`` effort seconds over
    ``effort_share``, at most :func:`variants_s`): time the variants did not use goes to the
    rounds."""
    used_s = min(variants_effort_s / table.effort_share, variants_s(limit_s, table, n_targets))
    return limit_s - _optimiser_share_s(limit_s, table) - used_s


def _optimiser_share_s(limit_s: float | None, table: ProgrammeShares) -> float:
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
    #: the effort seconds of ``effort_s`` its allocation took (the rest: its motion legs)
    allocation_effort_s: float = 0.0
    #: the exposures its plan takes, and how many of them the motion planner added for targets
    #: it moved (0: not recorded)
    exposures: int = 0
    exposures_added: int = 0

    def spent_s(self, table: ProgrammeShares = SHARES, effort_share: float | None = None) -> float:
        """The wall-clock share this outcome used up, counted deterministically (its effort
        over ``effort_share``, by default the table's, at most its share)."""
        per = table.effort_share if effort_share is None else effort_share
        if math.isinf(self.share_s):
            return self.effort_s / per
        return self.share_s if self.overran else min(self.effort_s / per, self.share_s)


def planned(o: PointingOutcome) -> bool:
    """Whether the outcome is a plan of the pointing: attempted, and not cut by the wall
    clock with a leg left unplanned (that plan ran out of the limit's time: its pointing is
    not planned for lack of time, as one not attempted is)."""
    return o.attempted and not (o.overran and not o.executable)


def rank(o: PointingOutcome) -> tuple[bool, bool, int, int, int]:
    """How good a pointing's plan is: planned first (:func:`planned`; a pointing not planned
    for lack of time observes nothing, though no leg of it failed), then executable, then
    fewer failed legs, then more targets observed, then fewer exposures."""
    return (planned(o), o.executable, -o.failed_legs, o.observed, -o.exposures)


def better(new: PointingOutcome, old: PointingOutcome) -> bool:
    """Whether a later round's plan replaces the one kept (:func:`rank`; a tie keeps the old)."""
    return rank(new) > rank(old)


def best_outcomes(history: Sequence[Sequence[PointingOutcome]]) -> dict[int, PointingOutcome]:
    """Each pointing's best outcome over the rounds ``history`` (:func:`better`: of equals,
    the earliest)."""
    best: dict[int, PointingOutcome] = {}
    for outcomes in history:
        for o in outcomes:
            if o.index not in best or better(o, best[o.index]):
                best[o.index] = o
    return best


def keeps_plan(best: PointingOutcome | None, round_: int) -> bool:
    """Whether round ``round_`` plans a pointing again from its best plan so far, ``best``
    (its configurations as its allocation, observed as they are, and its verified legs
    reused, :mod:`planner.known_legs`), rather than with a new allocation: in every round
    after the first, when that plan was attempted, observes targets and has a failed leg.
    The failed legs then get the round's whole share; a new allocation would spend half of it
    (``allocation_share``) and plan every leg again, on a share smaller than the first
    round's (docs/programme.md, *Rounds*: two-clump-4006)."""
    return round_ > 1 and best is not None and best.attempted and not best.executable and best.observed > 0


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
    best = best_outcomes(history)
    spent = sum(o.spent_s(table) for outcomes in history for o in outcomes)
    failed = _failed(best)
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


def _failed(best: dict[int, PointingOutcome]) -> list[int]:
    """The pointings whose best plan was attempted and has a failed leg."""
    return [i for i, o in best.items() if o.attempted and not o.executable]


def margin_left_s(limit_s: float | None, history: Sequence[Sequence[PointingOutcome]],
                  table: ProgrammeShares = SHARES) -> float:
    """What the rounds ``history`` left of the plan's usable limit with their effort counted
    at face value (``consolidation_effort_share``): the margin they kept for a slower
    machine included (inf: no limit)."""
    usable = usable_s(limit_s, table)
    if math.isinf(usable):
        return math.inf
    return usable - sum(o.spent_s(table, table.consolidation_effort_share) for outcomes in history for o in outcomes)


def margin_round(needs: Sequence[float], limit_s: float | None,
                 history: Sequence[Sequence[PointingOutcome]],
                 table: ProgrammeShares = SHARES) -> list[RoundTask]:
    """The round after the rounds of a plan that spends their margin (the consolidation's
    plans, :func:`planner.consolidation.applies`): the pointings whose best plan still has a
    failed leg, each with a share (by need, :func:`_by_need`) of what the rounds left with
    their effort counted at face value (``consolidation_effort_share``: the margin they kept
    for a slower machine). A failed leg gets that margin before any pointing is changed to
    save an exposure. Empty when every pointing is executable or less than
    ``min_pointing_s`` is left."""
    left = margin_left_s(limit_s, history, table)
    if math.isinf(left) or not history:
        return []
    failed = _failed(best_outcomes(history))
    if not failed or left < table.min_pointing_s:
        return []
    r = len(history) + 1
    return [RoundTask(i, r, share) for i, share in sorted(_by_need(left, failed, needs, table).items())]


def run_rounds(needs: Sequence[float], limit_s: float | None,
               compute: Callable[[Sequence[RoundTask]], Sequence[PointingOutcome]],
               table: ProgrammeShares = SHARES, *, spend_margin: bool = False) -> list[list[PointingOutcome]]:
    """The one plan loop of a programme: the first round on :func:`first_round_shares`, then
    :func:`next_round` until none is due, then (``spend_margin``) :func:`margin_round`.
    ``compute`` plans a round's tasks (in this process, on a job's runner, on Dask: any order)
    and keeps each pointing's best plan (:func:`better`); it returns their outcomes. Returns
    the outcomes of every round."""
    shares = first_round_shares(limit_s, needs, table)
    tasks = [RoundTask(i, 1, s) for i, s in enumerate(shares)]
    history: list[list[PointingOutcome]] = []
    while tasks:
        history.append(list(compute(tasks)))
        tasks = next_round(needs, limit_s, history, table)
    tasks = margin_round(needs, limit_s, history, table) if spend_margin else []
    if tasks:
        history.append(list(compute(tasks)))
    return history


