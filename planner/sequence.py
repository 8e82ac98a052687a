"""Whole-field motion plans that the instrument can execute: park -> c1 -> ... -> park.

:func:`plan_sequence` plans every leg of an allocation's sequence of configurations and,
when a leg cannot be planned, changes the plan instead of handing the failure over
(thesis 2.2.1.1, "Off-line operations": problematic targets are temporarily discarded and a
new assignment plan computed):

1. the leg goes through park: c_i -> park is the time reversal of a verified park -> c_i
   plan (collisions, the zone of avoidance and speed limits are symmetric in time), then
   park -> c_(i+1);
2. the arms that block the leg are sent to their park in that configuration and their
   targets move to another configuration that can take them (another arm or IK branch there),
   or to a new configuration at the end of the sequence;
3. then the changed legs are re-planned and re-verified.

Only when every option is exhausted does a leg stay failed; the plan then says
``executable = False`` with the reasons. Every leg in the result is a
:class:`~models.types.MotionPlan` from :func:`planner.plan_motion` (verified there) or a
time reversal / concatenation of verified plans, verified again as a whole.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from models.types import Configuration, MotionPlan, Unallocated

ChangeKind = Literal["via_park", "moved_target", "new_configuration", "dropped_target"]


@dataclass(frozen=True)
class PlanChange:
    """One change to the allocation's plan made so that every leg can be executed.

    ``leg`` indexes the legs of the final plan (leg i goes to configuration i + 1; leg 0 starts
    at park, the last leg ends there); ``configuration`` indexes the final configurations.
    """

    kind: ChangeKind
    leg: int
    configuration: int | None
    arms: tuple[int, ...]
    target_ids: tuple[str, ...]
    reason: str


@dataclass(frozen=True)
class SequencePlan:
    """The executable plan of one pointing: (possibly changed) configurations and their legs."""

    configurations: tuple[Configuration, ...]
    legs: tuple[MotionPlan, ...]  # len(configurations) + 1: park -> c1, ..., c_n -> park
    changes: tuple[PlanChange, ...] = ()
    dropped: tuple[Unallocated, ...] = ()  # targets no configuration could take without a failed leg
    stats: dict = field(default_factory=dict)

    @property
    def failed_legs(self) -> tuple[int, ...]:
        return tuple(i for i, leg in enumerate(self.legs) if leg.status != "ok")

    @property
    def executable(self) -> bool:
        return not self.failed_legs

    @property
    def reasons(self) -> tuple[str, ...]:
        """One line per failed leg: which leg, which arms, why."""
        out = []
        n = len(self.legs)
        for i in self.failed_legs:
            leg = self.legs[i]
            src = "park" if i == 0 else f"c{i}"
            dst = "park" if i == n - 1 else f"c{i + 1}"
            why = "; ".join(f"arm {a}: {r}" for a, r in sorted(leg.stats.get("reasons", {}).items()))
            arms = ", ".join(str(a) for a in leg.failed_arms)
            out.append(f"leg {i} ({src} -> {dst}): arms {arms} not planned" + (f" ({why})" if why else ""))
        return tuple(out)


@dataclass(frozen=True)
class SequenceOptions:
    """Options of :func:`plan_sequence`, validated once."""

    seed: int = 0
    leg_time_limit_s: float = 10.0  # each plan_motion call
    time_limit_s: float | None = None  # the whole sequence (None: no limit beyond the legs')
    max_changes: int = 24  # allocation changes tried before a leg is left failed
