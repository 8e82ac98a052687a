"""The programme driver's one table of shares (:class:`ProgrammeShares`) and the progress
marks of a plan: read by the rounds (:mod:`planner.programme`) and by each pointing's plan
(:mod:`planner.pointing`)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ALLOCATION_PART", "FIRST_ROUND_DONE", "SEGMENTED", "SHARES", "ProgrammeShares"]


@dataclass(frozen=True)
class ProgrammeShares:
    """The driver's one table of shares; each entry says what it protects."""

    #: Of the plan's limit, kept back (at most ``reserve_max_s``) to build and send the answer
    #: after the last pointing: it keeps the answer within the request's limit.
    reserve_fraction: float = 0.05
    reserve_max_s: float = 0.5
    #: Wall-clock seconds per target the plan's wall clock also keeps back (within
    #: ``reserve_fraction`` of the limit) for the answer's account of its exposures observing
    #: few targets (:func:`service.plan_output.few_target_exposures`, run on the finished plan):
    #: twice the 2.1 ms a target it takes on cluster-18001 (247 stars, 69 such exposures,
    #: 0.53 s), so that a plan whose last step runs to its wall-clock guard on a busy machine
    #: still answers within its limit. Only the wall-clock guards read it: on the effort clock
    #: the plan is the same.
    answer_s_per_target: float = 0.004
    #: Effort seconds a pointing's searches get per wall-clock second of its share. Below 1 by
    #: the margin a machine may be slower than the effort clock's calibration before the
    #: wall-clock guard, not the work, ends the searches (the plan then depends on the load).
    effort_share: float = 0.8
    #: The consolidation after the rounds (:mod:`planner.consolidation`), the plan's last
    #: step, counts what the rounds and its own plans spent as their effort over this (1: at
    #: face value), not over ``effort_share``: it spends the margin the rounds kept for a
    #: slower machine. Its plans keep their own margin (their searches get ``effort_share`` of
    #: their shares) and the plan's wall-clock guard holds the limit: a plan the guard cuts
    #: fails, and its group keeps the rounds' plans.
    consolidation_effort_share: float = 1.0
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
    #: The programme optimiser may add up to ``variants_max_s`` for its model's other variants
    #: (:data:`solvers.programme.optimiser.VARIANTS`: each a whole search, the one with the
    #: fewest exposures kept) out of what the usable time leaves beyond its share and
    #: ``variants_need_factor`` times the typical effort its targets need: only time the rounds
    #: are not expected to use (none on a programme of 250 stars or more at 120 s).
    variants_max_s: float = 12.0
    variants_need_factor: float = 2.0
    #: The programme optimiser's wall-clock guard, in wall-clock seconds per second of its
    #: share: its work is charged below its CPU time (its model's HiGHS solves at about half,
    #: its allocations at about 0.75: 15 effort seconds for 22 s on the M67-like case), so
    #: at the pointings' margin (1 / ``effort_share``) the guard, not its budget, would end
    #: its searches and its pointings would depend on the machine's speed
    #: (``stats.segmentation.optimiser.overran`` says when the guard fires).
    optimiser_guard_factor: float = 1.6
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
