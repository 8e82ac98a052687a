"""Plain domain types passed between stages (serialisable, never solver objects).

Angles in radians, lengths in millimetres, times in seconds; units are in the names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from models.errors import InputError

MAX_PRIORITY = 2**32 - 1  # priorities are 32-bit unsigned integers (thesis 5.1)

AssignmentKind = Literal["target", "park", "blank", "fixed"]
# why a target is in no configuration: no arm reaches it; it conflicts with the chosen
# assignments whatever the sequence; the time ran out; the request asked for fewer
# configurations ("one", ``max_configurations``) than observing it needs; in a plan, its arm
# reaches it only by a move from park beyond the limit, the programme's ``max_exposures`` left
# no exposure for it, or the exposure that would observe it is below the request's
# ``min_priority_per_exposure`` / ``min_targets_per_exposure``
UnallocatedReason = Literal["unreachable", "conflict", "no_time", "not_scheduled", "beyond_park_move_limit",
                            "beyond_max_exposures", "below_exposure_threshold"]


@dataclass(frozen=True)
class PlaneTargets:
    """Targets of one pointing in the FOV frame. ``priority`` is int64 in [1, 2^32 - 1]."""

    ids: tuple[str, ...]
    x_mm: np.ndarray
    y_mm: np.ndarray
    priority: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.ids)
        for name in ("x_mm", "y_mm", "priority"):
            v = getattr(self, name)
            if np.shape(v) != (n,):
                raise InputError(f"targets.{name}", f"expected {n} values, got shape {np.shape(v)}")
        for name in ("x_mm", "y_mm"):
            bad = np.flatnonzero(~np.isfinite(np.asarray(getattr(self, name), float)))
            if len(bad):
                raise InputError(f"targets[{bad[0]}].{name}", "must be a finite number")
        p = np.asarray(self.priority)
        if n and (p.dtype.kind not in "iu"):
            raise InputError("targets.priority", "must be integers")
        bad = np.flatnonzero((p < 1) | (p > MAX_PRIORITY)) if n else []
        if len(bad):
            raise InputError(f"targets[{bad[0]}].priority", f"must be an integer in 1..{MAX_PRIORITY}")
        seen: set[str] = set()
        for i, t in enumerate(self.ids):
            if t in seen:
                raise InputError(f"targets[{i}].id", f"duplicate target id {t!r}")
            seen.add(t)

    @staticmethod
    def from_lists(ids, x_mm, y_mm, priority) -> PlaneTargets:
        return PlaneTargets(tuple(str(i) for i in ids), np.asarray(x_mm, float), np.asarray(y_mm, float),
                            np.asarray(priority, dtype=np.int64))

    def __len__(self) -> int:
        return len(self.ids)

    def subset(self, index: np.ndarray) -> PlaneTargets:
        index = np.asarray(index, dtype=int)
        return PlaneTargets(tuple(self.ids[i] for i in index), self.x_mm[index], self.y_mm[index],
                            self.priority[index])


@dataclass(frozen=True)
class ArmAssignment:
    """Where one arm is in one configuration. ``target_index`` indexes the PlaneTargets given
    to the allocator; it is None for park / blank sky / fixed (out of service) locations."""

    arm: int
    kind: AssignmentKind
    theta1_rad: float
    theta2_rad: float
    x_mm: float
    y_mm: float
    target_index: int | None = None
    target_id: str | None = None


@dataclass(frozen=True)
class Configuration:
    """One observational configuration: exactly one entry per arm, sorted by arm."""

    index: int
    assignments: tuple[ArmAssignment, ...]
    total_priority: int
    arm_yield: int
    status: Literal["optimal", "feasible"]
    stats: dict = field(default_factory=dict, compare=False)

    @property
    def q(self) -> np.ndarray:
        """(n_arms, 2) joint angles of the configuration."""
        return np.array([[a.theta1_rad, a.theta2_rad] for a in self.assignments])


@dataclass(frozen=True)
class Unallocated:
    target_index: int
    target_id: str
    reason: UnallocatedReason


@dataclass(frozen=True)
class AllocationResult:
    configurations: tuple[Configuration, ...]
    unallocated: tuple[Unallocated, ...]
    stats: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class ControllerCommand:
    """One MCC2 move: starts and ends at rest (thesis 3.5.1.2)."""

    joint: Literal[1, 2]
    t_start_s: float
    from_rad: float
    to_rad: float
    speed_rad_s: float


@dataclass(frozen=True)
class ArmTrajectory:
    """Timed way-points of one arm; joint motion is linear between consecutive way-points
    and theta2 is continuous (not wrapped), so the interpolation is unambiguous."""

    arm: int
    t_s: np.ndarray
    theta1_rad: np.ndarray
    theta2_rad: np.ndarray
    commands: tuple[ControllerCommand, ...] = ()


@dataclass(frozen=True)
class MotionPlan:
    status: Literal["ok", "failed"]
    makespan_s: float
    trajectories: tuple[ArmTrajectory, ...]
    failed_arms: tuple[int, ...] = ()
    stats: dict = field(default_factory=dict, compare=False)
