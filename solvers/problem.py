"""The single-configuration allocation problem shared by every allocator back-end.

Exact (Pyomo/HiGHS, CP-SAT) and semi-greedy allocators all take a :class:`ConfigProblem`
built on the precomputed incompatibility structure and return a :class:`ConfigSolution`
choosing one assignment per arm; the sequencing driver turns solutions into
:class:`~models.types.Configuration` objects after re-checking them geometrically.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from models.collision import colliding_arm_pairs
from models.incompatibility import Incompatibility
from models.instrument import Instrument
from models.kinematics import direct_move_time_s

SolveStatus = Literal["optimal", "feasible", "timeout", "infeasible"]


@dataclass(frozen=True)
class ConfigProblem:
    """One configuration to allocate (thesis 5.4, eqs. 5.13–5.18).

    ``available[t]`` marks targets still to observe; assignments on other targets are not
    allowed. ``start_q`` (n_arms, 2) is where the arms are now: the longest-move criterion
    (eq. 5.16) is measured from there.
    """

    incompatibility: Incompatibility
    priority: np.ndarray  # (n_targets,) int64 in [1, 2^32 - 1]
    available: np.ndarray  # (n_targets,) bool
    start_q: np.ndarray  # (n_arms, 2)
    joint_speed_rad_s: np.ndarray  # (n_arms, 2)
    time_limit_s: float = 10.0
    mip_rel_gap: float = 0.0
    threads: int = 2
    seed: int = 0
    target_xy_mm: np.ndarray | None = None  # (n_targets, 2), for the independent tip re-check
    # optional (n_targets,) small non-negative ints: a tie-break among equal-priority,
    # equal-yield solutions (e.g. "hard to place"); exact back-ends use it with weights that
    # cannot trade away priority or yield (solvers.model.safe_weights); others may ignore it
    tie_break: np.ndarray | None = None

    @property
    def assignments(self):
        return self.incompatibility.assignments

    def allowed(self) -> np.ndarray:
        """(n_assignments,) bool: park/fixed locations and assignments on available targets."""
        t = self.assignments.target
        ok = t < 0
        real = ~ok
        ok[real] = self.available[t[real]]
        return ok

    def assignment_priority(self) -> np.ndarray:
        """(n_assignments,) int64 priority of each assignment (0 for park/fixed)."""
        t = self.assignments.target
        p = np.zeros(len(t), dtype=np.int64)
        real = t >= 0
        p[real] = self.priority[t[real]]
        return p

    def move_time_s(self) -> np.ndarray:
        """(n_assignments,) direct-move time from the arm's start configuration (eq. 5.1)."""
        a = self.assignments
        v = self.joint_speed_rad_s[a.arm]
        return direct_move_time_s(self.start_q[a.arm], a.q, v[:, 0], v[:, 1])


@dataclass(frozen=True)
class ConfigSolution:
    """One assignment index per arm (into ``problem.assignments``) plus honest status."""

    chosen: np.ndarray  # (n_arms,) int
    status: SolveStatus
    total_priority: int
    arm_yield: int
    longest_move_s: float
    gap: float | None = None
    stats: dict = field(default_factory=dict, compare=False)


def evaluate(problem: ConfigProblem, chosen: np.ndarray) -> tuple[int, int, float]:
    """(total priority, arm yield, longest move s) of a choice — exact Python integers."""
    a = problem.assignments
    chosen = np.asarray(chosen, dtype=int)
    t = a.target[chosen]
    real = t >= 0
    total = sum(int(problem.priority[i]) for i in t[real])
    longest = float(problem.move_time_s()[chosen].max()) if len(chosen) else 0.0
    return total, int(real.sum()), longest


def check_solution(instrument: Instrument, problem: ConfigProblem, chosen: np.ndarray,
                   tip_tol_mm: float = 0.01) -> list[str]:
    """Independent re-check of a solution; returns a list of problems (empty when valid).

    One location per arm, each target at most once and only if available, no two arms
    closer than the buffer (re-computed from geometry, not from the incompatibility
    table), every target assignment's tip within ``tip_tol_mm`` of its target.
    """
    from models.kinematics import tip_fov  # local: keep this module light to import

    errors: list[str] = []
    a = problem.assignments
    chosen = np.asarray(chosen, dtype=int)
    if chosen.shape != (instrument.n_arms,):
        return [f"expected one location per arm ({instrument.n_arms}), got shape {chosen.shape}"]
    arms = a.arm[chosen]
    if not np.array_equal(arms, np.arange(instrument.n_arms)):
        errors.append(f"assignment arms {arms.tolist()} are not 0..{instrument.n_arms - 1} in order")
    t = a.target[chosen]
    real = t[t >= 0]
    if len(np.unique(real)) != len(real):
        errors.append("a target is assigned to two arms")
    if len(real) and not problem.available[real].all():
        errors.append("an unavailable target is assigned")
    pairs = colliding_arm_pairs(instrument, a.q[chosen], problem.incompatibility.buffer_mm)
    if pairs:
        errors.append(f"arms closer than the buffer: {pairs}")
    tips = tip_fov(instrument, arms, a.theta1_rad[chosen], a.theta2_rad[chosen])
    goal = np.column_stack([a.x_mm[chosen], a.y_mm[chosen]])
    if problem.target_xy_mm is not None:
        on_target = t >= 0
        goal[on_target] = problem.target_xy_mm[t[on_target]]
    tip_err = np.hypot(tips[:, 0] - goal[:, 0], tips[:, 1] - goal[:, 1])
    if (tip_err > tip_tol_mm).any():
        errors.append(f"tip off its location by {tip_err.max():.3g} mm")
    return errors
