"""Timed way-points, MCC2 controller commands and motor-step conversion (thesis 3.5.1.2, 6.4.1.1).

Motion model (the contract of :class:`models.types.ArmTrajectory`): both joints move
linearly in time between consecutive way-points, so every way-point where the joint
velocity changes is a stop of the arm. The real MCC2 executes each move as a trapezoidal
(LSPB) profile that starts and ends at rest (thesis 3.5.1, fig. 3.12) and cannot blend
way-points (3.5.1.2): one command per joint per moving segment, given as (start time, from,
to, cruise speed). The ramps make the real motion lag the linear model slightly; the
collision buffer (thesis 6.3.2) covers that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.instrument import Instrument
from models.kinematics import tip_fov
from models.types import ArmTrajectory, ControllerCommand

_EPS_RAD = 1e-12
TIP_TOLERANCE_MM = 0.5  # coarse positioning accuracy needed before acquisition (thesis 6.4.1.1)


def compress_waypoints(t_s: np.ndarray, q: np.ndarray, tol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Drop way-points where the velocity does not change (they are not stops)."""
    t_s = np.asarray(t_s, float)
    q = np.asarray(q, float)
    if len(t_s) <= 2:
        return t_s, q
    v = np.diff(q, axis=0) / np.diff(t_s)[:, None]
    change = np.any(np.abs(v[1:] - v[:-1]) > tol, axis=1)
    keep = np.concatenate([[True], change, [True]])
    return t_s[keep], q[keep]


def controller_commands(t_s: np.ndarray, theta1_rad: np.ndarray, theta2_rad: np.ndarray) -> tuple[ControllerCommand, ...]:
    """One command per joint per moving segment: moves that start and end at rest (3.5.1.2)."""
    out: list[ControllerCommand] = []
    for i in range(len(t_s) - 1):
        dur = float(t_s[i + 1] - t_s[i])
        for joint, th in ((1, theta1_rad), (2, theta2_rad)):
            a, b = float(th[i]), float(th[i + 1])
            if abs(b - a) > _EPS_RAD:
                out.append(ControllerCommand(joint, float(t_s[i]), a, b, abs(b - a) / dur))
    return tuple(out)


def trajectory_from_steps(arm: int, q_steps: np.ndarray, dt_s: float) -> ArmTrajectory:
    """Timed way-points + commands from the arm position at every dt step (t = k dt)."""
    t = np.arange(len(q_steps)) * dt_s
    t, q = compress_waypoints(t, q_steps)
    return ArmTrajectory(arm, t, q[:, 0].copy(), q[:, 1].copy(), controller_commands(t, q[:, 0], q[:, 1]))


def arm_trajectory(arm: int, t_s: np.ndarray, q: np.ndarray) -> ArmTrajectory:
    """Timed way-points (t, (theta1, theta2)) as an :class:`ArmTrajectory` with commands,
    way-points without a velocity change dropped."""
    t, q = compress_waypoints(t_s, q)
    return ArmTrajectory(arm, t, q[:, 0].copy(), q[:, 1].copy(), controller_commands(t, q[:, 0], q[:, 1]))


def stop_count(t_s: np.ndarray, theta1_rad: np.ndarray, theta2_rad: np.ndarray, tol: float = 1e-12) -> int:
    """Start-stop cycles (thesis 6.3.4.4): moving segments of constant velocity, minus one.

    Rests between moves and direction changes both count; waiting before the first move
    or after the last does not.
    """
    t_s = np.asarray(t_s, float)
    if len(t_s) < 2:
        return 0
    q = np.column_stack([theta1_rad, theta2_rad])
    v = np.diff(q, axis=0) / np.diff(t_s)[:, None]
    moving = np.any(np.abs(np.diff(q, axis=0)) > _EPS_RAD, axis=1)
    n_moves = 0
    prev = None
    for vi, mv in zip(v, moving, strict=True):
        if not mv:
            prev = None
            continue
        if prev is None or np.any(np.abs(vi - prev) > tol):
            n_moves += 1
        prev = vi
    return max(n_moves - 1, 0)


# ---------------------------------------------------------------------- motor steps


@dataclass(frozen=True)
class MotorCommand:
    """A controller command in motor steps (integer positions, step rate in steps/s)."""

    joint: int
    t_start_s: float
    from_steps: int
    to_steps: int
    speed_steps_s: float


@dataclass(frozen=True)
class MotorSteps:
    arm: int
    commands: tuple[MotorCommand, ...]
    goal_steps: tuple[int, int]
    tip_error_mm: float  # tip distance between the rounded and the planned goal

    @property
    def within_tolerance(self) -> bool:
        return self.tip_error_mm <= TIP_TOLERANCE_MM


def to_motor_steps(instrument: Instrument, trajectory: ArmTrajectory,
                   steps_per_rad: float | tuple[float, float]) -> MotorSteps:
    """Convert a trajectory to motor steps and check the tip error of the rounding (6.4.1.1).

    Way-point angles are rounded to whole steps (steppers cannot do fractions, 6.3.4.4);
    the step rate of each move keeps its duration, so timing, and thus the verified
    clearances, are unchanged up to the rounding. The thesis requires the pick-off mirror
    to end within 0.5 mm of its target after this conversion.
    """
    r1, r2 = (steps_per_rad, steps_per_rad) if np.isscalar(steps_per_rad) else steps_per_rad
    s1 = np.rint(np.asarray(trajectory.theta1_rad) * r1).astype(np.int64)
    s2 = np.rint(np.asarray(trajectory.theta2_rad) * r2).astype(np.int64)
    t = np.asarray(trajectory.t_s, float)
    cmds: list[MotorCommand] = []
    for i in range(len(t) - 1):
        dur = float(t[i + 1] - t[i])
        for joint, s in ((1, s1), (2, s2)):
            if s[i + 1] != s[i]:
                cmds.append(MotorCommand(joint, float(t[i]), int(s[i]), int(s[i + 1]), abs(int(s[i + 1] - s[i])) / dur))
    arm = trajectory.arm
    planned = tip_fov(instrument, arm, trajectory.theta1_rad[-1], trajectory.theta2_rad[-1])
    rounded = tip_fov(instrument, arm, s1[-1] / r1, s2[-1] / r2)
    err = float(np.hypot(*(np.asarray(planned) - np.asarray(rounded))))
    return MotorSteps(arm, tuple(cmds), (int(s1[-1]), int(s2[-1])), err)
