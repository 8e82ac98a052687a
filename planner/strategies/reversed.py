"""Time reversal of a whole leg (SDSS-V / kaiju, Sayres et al. 2021).

Collisions, the zone of avoidance, joint speed limits and stop counts are all symmetric in
time: a valid plan of goal -> start played backwards (t -> T - t) is a valid plan of
start -> goal. :class:`Reversed` solves the reversed leg with an inner strategy and plays
the answer backwards, so a leg to park is the reversal of a leg from park, where arms
leave a crowded configuration instead of converging onto it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from models.budget import Budget
from models.types import ArmTrajectory
from planner.commands import arm_trajectory
from planner.strategy import Candidate, Leg, Refusal, Strategy

TWO_PI = 2.0 * np.pi


def reverse_trajectories(trajectories: Sequence[ArmTrajectory], start_q: np.ndarray,
                         makespan_s: float | None = None) -> tuple[ArmTrajectory, ...]:
    """Trajectories played backwards about ``makespan_s`` (default: the latest way-point).

    ``trajectories`` go from some configuration to ``start_q`` modulo 2 pi (a plan of the
    reversed leg); the result goes from ``start_q`` back to where they started. Each arm
    waits at ``start_q`` until ``makespan_s`` minus its own duration, then retraces its
    way-points; theta2 is shifted by whole turns so that the result starts exactly at
    ``start_q`` (which may be unwrapped); when ``start_q`` is the reversed plan's real end,
    the result ends exactly where the reversed plan started.
    """
    start_q = np.asarray(start_q, float)
    T = max(float(tr.t_s[-1]) for tr in trajectories) if makespan_s is None else float(makespan_s)
    out = []
    for tr in sorted(trajectories, key=lambda tr: tr.arm):
        t = T - np.asarray(tr.t_s, float)[::-1]
        q = np.column_stack([np.asarray(tr.theta1_rad, float)[::-1], np.asarray(tr.theta2_rad, float)[::-1]])
        q[:, 1] += TWO_PI * np.round((start_q[tr.arm, 1] - q[0, 1]) / TWO_PI)
        if np.all(np.abs(q[0] - start_q[tr.arm]) <= 1e-9):  # exactly where the arm is (no rounding)
            q[0] = start_q[tr.arm]
        if len(t) == 1:
            t = np.zeros(1)
        elif t[0] > 1e-12:  # at rest at the start until the retrace begins
            t = np.concatenate([[0.0], t])
            q = np.concatenate([q[:1], q])
        else:
            t[0] = 0.0
        out.append(arm_trajectory(tr.arm, t, q))
    return tuple(out)


class Reversed:
    """``inner`` on the time-reversed leg (goal -> start), played backwards."""

    def __init__(self, inner: Strategy, name: str | None = None) -> None:
        self.inner = inner
        self.name = name or f"reversed-{inner.name}"

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        rev = leg.with_ends(leg.goal_q, leg.start_q)
        out = self.inner.plan(rev, budget)
        if isinstance(out, Refusal):
            return out
        trajs = reverse_trajectories(out.trajectories, leg.start_q, out.makespan_s)
        return Candidate(trajs, out.makespan_s, "reversed", {**out.stats, "reversed": out.strategy})
