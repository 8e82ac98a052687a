"""Legs a pointing's earlier plan verified, reused where its new plan makes the same move.

A pointing planned again with an allocation that changes only some of its configurations
(the plan's consolidation, :mod:`planner.consolidation`) makes the same moves between the
configurations it keeps in the same order: park -> c1 when c1 is unchanged, c_i -> c_(i+1)
when both are. :class:`KnownLegs` holds the earlier plan's verified legs by where they start
and end; the sequencer (:mod:`planner.sequence`) takes a leg from it before it plans one, so
planning a changed pointing costs only the legs next to its changed configurations
(:func:`new_legs` counts them).

A known leg is reused only for the same move: it starts where the arms are (theta1 exactly,
theta2 whole turns apart: the trajectory is shifted onto the start) and ends at the same
configuration (its joint angles, byte for byte). It is verified again, as a whole, on the
instrument it is reused on (:func:`planner.driver.verified_plan`), so a reused leg is as
verified as a planned one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from models.instrument import Instrument
from models.types import ArmTrajectory, Configuration, MotionPlan
from planner.commands import controller_commands
from planner.driver import verified_plan

__all__ = ["ANGLE_TOL_RAD", "KnownLegs", "goal_key", "new_legs"]

#: a known leg's start and the arms' place agree within this (theta2 modulo whole turns)
ANGLE_TOL_RAD = 1e-9


def goal_key(q: np.ndarray) -> bytes:
    """A configuration's joint angles (n_arms, 2) as the key of the legs that end there."""
    return np.ascontiguousarray(q, dtype=float).tobytes()


@dataclass(frozen=True)
class KnownLegs:
    """Verified legs by the configuration they end at (:func:`goal_key`): each with the joint
    angles (n_arms, 2) it starts from."""

    by_goal: Mapping[bytes, tuple[tuple[np.ndarray, MotionPlan], ...]] = field(default_factory=dict)

    @classmethod
    def of_plan(cls, park_q: np.ndarray, configurations: Sequence[np.ndarray],
                legs: Sequence[MotionPlan]) -> KnownLegs:
        """The verified legs of a plan park -> c1 -> ... -> park (``configurations``: each
        configuration's joint angles; ``legs``: len(configurations) + 1, failed ones skipped)."""
        goals = [*configurations, park_q]
        out: dict[bytes, list[tuple[np.ndarray, MotionPlan]]] = {}
        for goal, leg in zip(goals, legs, strict=True):
            arms = [tr.arm for tr in leg.trajectories]
            if leg.status == "ok" and arms == list(range(len(park_q))):  # one trajectory per arm, in order
                start = np.array([[tr.theta1_rad[0], tr.theta2_rad[0]] for tr in leg.trajectories])
                out.setdefault(goal_key(np.asarray(goal, float)), []).append((start, leg))
        return cls({k: tuple(v) for k, v in out.items()})

    def leg(self, instrument: Instrument, start_q: np.ndarray, goal_q: np.ndarray) -> MotionPlan | None:
        """A known leg from ``start_q`` to ``goal_q``, shifted onto ``start_q`` and verified
        again; None when none makes that move (or the verifier rejects it)."""
        start_q = np.asarray(start_q, float)
        for start, leg in self.by_goal.get(goal_key(np.asarray(goal_q, float)), ()):
            turns = _turns(start, start_q)
            if turns is None:
                continue
            trajs = tuple(_shifted(tr, float(start_q[tr.arm, 1] - start[tr.arm, 1])) if turns[tr.arm] else tr
                          for tr in leg.trajectories)
            stats = {**leg.stats, "reused": True, "compute_s": 0.0, "attempts": 0}
            again = verified_plan(instrument, trajs, start_q, goal_q, max_start_stop=None, stats=stats)
            if again is not None:
                return again
        return None


def _turns(start: np.ndarray, start_q: np.ndarray) -> np.ndarray | None:
    """Per arm, whether theta2 of ``start_q`` lies whole turns (not zero) from ``start``'s;
    None when an arm is elsewhere."""
    if start.shape != start_q.shape or np.any(np.abs(start[:, 0] - start_q[:, 0]) > ANGLE_TOL_RAD):
        return None
    d = start_q[:, 1] - start[:, 1]
    turns = np.round(d / (2 * np.pi))
    if np.any(np.abs(d - 2 * np.pi * turns) > ANGLE_TOL_RAD):
        return None
    return turns != 0


def _shifted(tr: ArmTrajectory, d_rad: float) -> ArmTrajectory:
    """``tr`` with theta2 ``d_rad`` (whole turns) further: the same motion."""
    theta2 = tr.theta2_rad + d_rad
    return ArmTrajectory(tr.arm, tr.t_s, tr.theta1_rad, theta2, controller_commands(tr.t_s, tr.theta1_rad, theta2))


def new_legs(old: Sequence[Configuration], new: Sequence[Configuration]) -> int:
    """The legs of the plan park -> new[0] -> ... -> park that the plan park -> old[0] -> ...
    -> park does not make (the same two configurations, by their joint angles, one after the
    other): what planning ``new`` costs when the legs of ``old`` are known."""
    def moves(cs: Sequence[Configuration]) -> list[tuple[bytes | None, bytes | None]]:
        keys: list[bytes | None] = [None, *(goal_key(c.q) for c in cs), None]  # None: park
        return list(zip(keys[:-1], keys[1:], strict=True))

    made = set(moves(old))
    return sum(m not in made for m in moves(new))
