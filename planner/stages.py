"""What a plan is doing, in words: the stage its progress reports name (a plan job's
``stage``, the synchronous plan's ``on_stage`` callback).

A plan segments its field (or, in segmentation mode "fewest-exposures", the programme
optimiser chooses its pointings), then plans its pointings in rounds
(:func:`planner.programme.run_rounds`), each pointing its allocation then its motion legs
(the allocation reports the first :data:`planner.programme.ALLOCATION_PART` of a pointing's
progress), then the answer is assembled. :func:`plan_stage` names the stage from the same
counts as :func:`planner.programme.plan_progress`.
"""

from __future__ import annotations

import math

from planner.programme import ALLOCATION_PART

__all__ = ["ASSEMBLING", "DONE", "OPTIMISING", "QUEUED", "SEGMENTING", "plan_stage", "segmentation_stage"]

QUEUED = "queued"
SEGMENTING = "segmenting the field"
OPTIMISING = "optimising pointings"
ASSEMBLING = "assembling the plan"
DONE = "done"


def segmentation_stage(mode: str) -> str:
    """The stage of a plan's segmentation in ``mode``: the programme optimiser's
    ("fewest-exposures") or the clustering's."""
    return OPTIMISING if mode == "fewest-exposures" else SEGMENTING


def plan_stage(round_: int, done: float, total: int) -> str:
    """The stage of round ``round_`` with ``done`` of its ``total`` pointings planned: a whole
    number names the pointings planned; a fraction is the pointing being planned (the
    ``done + 1``-th), allocating below :data:`ALLOCATION_PART` of it, planning its motion
    legs from there. Later rounds (pointings planned again, or planned on the time the first
    round left) say their round."""
    total = max(int(total), 1)
    whole = min(max(int(math.floor(done)), 0), total)
    part = done - math.floor(done)
    prefix = "" if round_ <= 1 else f"round {int(round_)}: "
    if whole >= total or part <= 0.0:
        return f"{prefix}{whole} of {total} pointings done"
    what = "allocating pointing" if part < ALLOCATION_PART else "planning motion, pointing"
    return f"{prefix}{what} {whole + 1} of {total}"
