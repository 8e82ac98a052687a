"""Two zero-stop legs through another configuration: start -> via -> goal (e.g. park).

Each leg has no intermediate stop, so an arm that moves in both legs stops once (at
``via``) and the whole respects ``max_start_stop`` >= 1 (thesis 3.5.1.2). Each leg is
planned by the departure-delay strategies (:mod:`planner.strategies.delays`) on a leg
of its own; the second starts where the first really ended (theta2 unwrapped). The
concatenation is one candidate, which the driver verifies as a whole. Time reversal
would give the same first leg (a verified via -> start plan played backwards has the same
clearances, speeds and stops); the delay CSP plans start -> via directly just as well.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from models.budget import Budget
from planner.commands import arm_trajectory
from planner.options import MIN_LEG_S, MotionOptions
from planner.strategies.delays import Delays, Detours
from planner.strategy import (
    Candidate,
    FirstOf,
    Leg,
    Refusal,
    check_configuration,
    ends_unplannable,
    same_configuration,
)

ZERO_STOP = FirstOf("delays", (Delays(), Detours()))


def via_configuration(leg: Leg) -> np.ndarray | None:
    """The leg's via configuration (``options.via``: "park", a configuration or None)."""
    v = leg.options.via
    if v is None:
        return None
    if isinstance(v, str):
        return leg.instrument.park_configuration
    return check_configuration(leg.instrument, v, "via")


def concatenate(first: Candidate, second: Candidate, n_arms: int):
    """Per-arm way-points of two consecutive legs, the junction point once."""
    T1 = first.makespan_s
    out = []
    for k in range(n_arms):
        a, b = first.trajectories[k], second.trajectories[k]
        t = np.concatenate([a.t_s, b.t_s + T1])
        q = np.column_stack([np.concatenate([a.theta1_rad, b.theta1_rad]),
                             np.concatenate([a.theta2_rad, b.theta2_rad])])
        keep = np.concatenate([np.diff(t) > 1e-12, [True]])  # drop the duplicated junction point
        out.append(arm_trajectory(k, t[keep], q[keep]))
    return tuple(out)


class Via:
    """start -> via -> goal as two zero-stop legs (stats strategy "via")."""

    name = "via"

    def __init__(self, legs=ZERO_STOP) -> None:
        self.legs = legs  # the strategy planning each zero-stop leg

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        o = leg.options
        via_q = via_configuration(leg)
        if (via_q is None or o.max_start_stop < 1 or same_configuration(via_q, leg.start_q)
                or same_configuration(via_q, leg.goal_q)
                or ends_unplannable(leg.instrument, leg.geoms, via_q, via_q, leg.buffer_mm)):
            return Refusal()
        if budget.expired():
            return Refusal()
        each_s = max(MIN_LEG_S, budget.left_s())
        sub = MotionOptions(dt_s=o.dt_s, dt_col_s=o.dt_col_s, max_start_stop=0, collision_buffer_mm=leg.buffer_mm,
                            seed=o.seed, horizon_s=o.horizon_s, grid=o.grid, strategies=("delays",), via=None)
        parts: list[Candidate] = []
        cur = leg.start_q
        for target in (via_q, leg.goal_q):
            out = self.legs.plan(leg.with_ends(cur, target, sub), replace(budget, total_s=each_s))
            if not isinstance(out, Candidate):
                failed = list(out.arms) or list(leg.enabled)
                return Refusal((), {}, {"attempt_log": [{"direction": "via", "failed_arms": failed}]})
            parts.append(out)
            cur = np.array([[tr.theta1_rad[-1], tr.theta2_rad[-1]] for tr in out.trajectories])
        stats = {key: sum(p.stats.get(key, 0) for p in parts) for key in ("collision_checks", "states_explored")}
        stats["attempt_log"] = [{"direction": "via"}]
        return Candidate(concatenate(parts[0], parts[1], leg.n_arms), float(parts[0].makespan_s + parts[1].makespan_s),
                         "via", stats)
