"""The typed state of one sequence and the helpers every pass shares.

:class:`Step` is one configuration of the main structure (its problem, the chosen
assignment per arm, status and stats); :class:`SequenceState` is what the greedy loop
builds and the post-passes (:mod:`solvers.sequencing.passes`) transform: the steps, the
rescue configurations, the pending targets, the lower bounds, the timers.  Every
configuration, however it was made, is re-checked geometrically (:func:`verify`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from models import clock
from models.incompatibility import Incompatibility
from models.instrument import Instrument
from models.types import ArmAssignment, Configuration, PlaneTargets
from solvers.effort import CONFIGURATION_BUILD_S, VERIFY_CONFIGURATION_S
from solvers.problem import ConfigProblem, check_solution, evaluate

__all__ = ["SequenceState", "Step", "UnverifiedConfigurationError", "active_arms", "hard_to_place", "joint_speeds",
           "make_configuration", "observed", "observed_chosen", "rebuild", "replace_tail", "verify"]

CROWDING_RADIUS_MM = 15.0  # near the FOV centre only one arm at a time fits in a disc this size


class UnverifiedConfigurationError(RuntimeError):
    """A back-end returned a configuration that fails the independent geometric re-check."""


class Step(NamedTuple):
    """One configuration of the main structure."""

    problem: ConfigProblem
    chosen: np.ndarray  # (n_arms,) assignment index per arm
    status: str
    stats: dict


@dataclass
class SequenceState:
    """One sequence in the making (see the module docstring)."""

    instrument: Instrument
    targets: PlaneTargets
    inc: Incompatibility
    priority: np.ndarray  # (n_targets,) int64
    unreachable: np.ndarray  # (n_targets,) bool
    pending: np.ndarray  # (n_targets,) bool: reachable, not yet observed
    n_reachable: int
    n_active: int  # arms that reach some target
    lower_bound: int  # ceil(reachable / active arms)
    flow_bound: int  # the b-matching bound (or lower_bound)
    speeds: np.ndarray
    xy: np.ndarray  # (n_targets, 2) mm
    tie: np.ndarray | None  # the tie-break weights of the last configuration
    q: np.ndarray  # the arms' positions after the last configuration
    q_start: np.ndarray
    seed: int
    threads: int
    steps: list[Step] = field(default_factory=list)
    extra: list[Configuration] = field(default_factory=list)  # rescue configurations, after the steps
    stop_reason: str = "complete"
    greedy_count: int = 0
    timers: dict[str, float] = field(default_factory=dict)
    proven_bound: int = 0  # CP-SAT proved the count cannot be lower
    crowd_bound: int = 0
    lp_bound: int = 0
    floor_proof: int = 0
    repack_budget_s: float = 0.0  # shared by the packing passes
    repack_t0: float | None = None  # when the packing passes began (None: they do not run)
    repack_n1: int = 0  # the count when they began
    rescued: list[np.ndarray] = field(default_factory=list)  # targets of the rescue configurations

    @property
    def n_configurations(self) -> int:
        return len(self.steps) + len(self.extra)

    @property
    def n_arms(self) -> int:
        return self.instrument.n_arms

    def finished_normally(self) -> bool:
        """The loop stopped because it was done, not because the time or a solver ran out."""
        return self.stop_reason in ("complete", "conflict", "tail")


def joint_speeds(instrument: Instrument) -> np.ndarray:
    return np.column_stack([instrument.arm_array("joint1_speed_rad_s"), instrument.arm_array("joint2_speed_rad_s")])


def hard_to_place(incompatibility: Incompatibility, n_arms: int, xy_mm: np.ndarray | None = None,
                  pending: np.ndarray | None = None, crowding_radius_mm: float = CROWDING_RADIUS_MM) -> np.ndarray:
    """(n_targets,) tie-break weight: n_arms - (arms reaching the target), plus, with
    ``xy_mm``, the number of other still ``pending`` (default: reachable) targets within
    ``crowding_radius_mm`` — near the FOV centre arms converging on one spot collide, so a
    crowded neighbourhood can only be observed about one target per configuration and must
    be started early (see solvers.sequencing.bounds.crowding_lower_bound); 0 if unreachable."""
    apt = incompatibility.reachability.arms_per_target
    h = np.where(apt > 0, n_arms - apt, 0).astype(np.int64)
    if xy_mm is not None and len(h):
        from scipy.spatial import cKDTree

        live = np.flatnonzero((apt > 0) if pending is None else (pending & (apt > 0)))
        if len(live):
            near = cKDTree(xy_mm[live]).query_ball_point(xy_mm[live], crowding_radius_mm, return_length=True)
            h[live] += np.asarray(near, np.int64) - 1
    return h


def make_configuration(index: int, problem: ConfigProblem, chosen: np.ndarray, targets: PlaneTargets,
                       status: str, stats: dict) -> Configuration:
    """One :class:`Configuration` with one ArmAssignment per arm (kind target/park/fixed)."""
    a = problem.assignments
    out = []
    for k, c in enumerate(np.asarray(chosen, int)):
        t = int(a.target[c])
        kind = "target" if t >= 0 else {-1: "park", -2: "fixed", -3: "blank"}.get(t, "fixed")
        out.append(ArmAssignment(k, kind, float(a.theta1_rad[c]), float(a.theta2_rad[c]), float(a.x_mm[c]),
                                 float(a.y_mm[c]), t if t >= 0 else None, targets.ids[t] if t >= 0 else None))
    total, yld, _ = evaluate(problem, chosen)
    clock.charge(CONFIGURATION_BUILD_S)
    return Configuration(index, tuple(out), total, yld, "optimal" if status == "optimal" else "feasible", stats)


def verify(instrument: Instrument, problem: ConfigProblem, chosen: np.ndarray) -> None:
    errors = check_solution(instrument, problem, chosen)
    clock.charge(VERIFY_CONFIGURATION_S)
    if errors:
        raise UnverifiedConfigurationError("; ".join(errors))


def observed(c: Configuration) -> np.ndarray:
    """Target indices a built configuration observes."""
    return np.array([a.target_index for a in c.assignments if a.target_index is not None], np.int64)


def observed_chosen(inc: Incompatibility, chosen: np.ndarray) -> np.ndarray:
    """Target indices observed by the (n_arms,) chosen assignment indices."""
    tg = inc.assignments.target[chosen]
    return tg[tg >= 0]


def active_arms(inc: Incompatibility, n_arms: int) -> list[int]:
    a = inc.assignments
    return [k for k in range(n_arms) if (a.target[a.of_arm(k)] >= 0).any()]


def replace_tail(instrument, inc, priority, configs, window, packed, speeds, xy, tie, dt, q0=None):
    """The last ``window`` configurations replaced by the verified ``packed`` ones, highest
    priority first (:func:`rebuild`; the first starts at ``q0``, default park, when nothing
    is kept)."""
    a = inc.assignments
    packed.sort(key=lambda ch: -sum(int(priority[t]) for t in a.target[ch] if t >= 0))
    head = [ch for _, ch, _, _ in configs[:-window]]
    return rebuild(instrument, inc, priority, configs, head + packed, speeds, xy, tie,
                    instrument.park_configuration if q0 is None else q0, status="repacked",
                    solve_s=dt / max(len(packed), 1))


def rebuild(instrument, inc, priority, configs, new_chosen, speeds, xy, tie, q0, status: str = "repaired",
             solve_s: float = 0.0):
    """``configs`` with their chosen assignments replaced by ``new_chosen``: the unchanged
    leading configurations are kept, the rest rebuilt and verified geometrically, each
    starting where the previous one left the arms (the first at ``q0``)."""
    same = 0
    while (same < min(len(configs), len(new_chosen))
           and np.array_equal(configs[same][1], new_chosen[same])):
        same += 1
    if same == len(configs) == len(new_chosen):
        return configs
    a = inc.assignments
    head = configs[:same]
    q = head[-1][0].assignments.q[head[-1][1]] if head else q0
    pending = np.zeros(len(priority), bool)
    for ch in new_chosen[same:]:
        tg = a.target[ch]
        pending[tg[tg >= 0]] = True
    out = list(head)
    for ch in new_chosen[same:]:
        prob = ConfigProblem(inc, priority, pending.copy(), q, speeds, target_xy_mm=xy, tie_break=tie)
        verify(instrument, prob, ch)
        tg = a.target[ch]
        pending[tg[tg >= 0]] = False
        out.append(Step(prob, ch, "feasible", {"solve_s": solve_s, "status": status,
                                               "longest_move_s": evaluate(prob, ch)[2]}))
        q = a.q[ch]
    return out
