"""The strategy interface: a leg, a budget, and what a strategy answers (thesis 6.3).

A *leg* moves every arm from a start to a goal configuration. The driver
(:mod:`planner.driver`) builds one :class:`Leg` per request and tries strategies in
order; each strategy's :meth:`Strategy.plan` answers a :class:`Candidate` (trajectories,
not yet verified: the driver verifies every candidate once) or a :class:`Refusal` (the arms
it could not plan and why). Strategies never call each other through the driver: what one
strategy learns that another can use (the delay CSP's straight-move problem, the cluster
strategy's removal sets, roadmap paths) goes into the leg's :class:`LegCache`, which the
driver owns.

A strategy plans within a :class:`models.budget.Budget`: the leg's, or the part of it
:func:`stage_budget` gives. Its ``hard_deadline_s`` is the whole leg's deadline, which a
strategy's share never extends: a strategy may finish work it cannot do without (such as the
straight-move tables the later strategies start from) up to it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

from models import clock
from models.budget import Budget
from models.collision import colliding_arm_pairs
from models.errors import InputError
from models.instrument import Instrument
from models.kinematics import direct_move_time_s
from models.types import ArmTrajectory
from planner.geometry import ArmGeom
from planner.options import MotionOptions

TWO_PI = 2.0 * np.pi


@dataclass
class LegCache:
    """What strategies share within one leg (owned by the driver, one per :class:`Leg`).

    ``delay_search`` the departure-delay CSP's state (:class:`planner.delays.DelaySearch`):
    its straight-move problem when every straight option failed, resumed by the detour
    rounds; ``delay_deadline`` the delay stage's deadline; ``removal_sets`` /
    ``removal_complete`` the cluster strategy's removal sets (None: it did not run) and
    whether their search was exhaustive; ``cluster_s`` the time the cluster strategy took;
    ``paths`` roadmap paths per direction ("forward", "reverse").
    """

    delay_search: Any = None
    delay_deadline: float | None = None
    removal_sets: list[list[int]] | None = None
    removal_complete: bool = False
    cluster_s: float | None = None
    paths: dict[str, list] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Leg:
    """One planning problem: every arm from ``start_q`` to ``goal_q`` (both (n_arms, 2), rad).

    ``start_q``'s theta2 may be unwrapped (continuing a previous trajectory); ``goal_q``'s
    counts modulo 2 pi. ``lower_bound_s`` is the longest direct move at full speed
    (thesis eq. 6.23), a lower bound of the makespan.
    """

    instrument: Instrument
    start_q: np.ndarray
    goal_q: np.ndarray
    options: MotionOptions
    buffer_mm: float
    geoms: tuple[ArmGeom, ...]
    enabled: tuple[int, ...]
    lower_bound_s: float
    cache: LegCache = field(default_factory=LegCache)

    @staticmethod
    def build(instrument: Instrument, start_q, goal_q, options: MotionOptions,
              geoms: Sequence[ArmGeom] | None = None) -> Leg:
        """Checks the shapes (:class:`~models.errors.InputError` naming the field) and resolves
        the buffer, the arm geometry and the lower bound once."""
        start = check_configuration(instrument, start_q, "start_q")
        goal = check_configuration(instrument, goal_q, "goal_q")
        if geoms is None:
            geoms = [ArmGeom.of(instrument, k) for k in range(instrument.n_arms)]
        b = options.collision_buffer_mm
        buffer_mm = instrument.collision_buffer_mm if b is None else float(b)
        v1 = instrument.arm_array("joint1_speed_rad_s")
        v2 = instrument.arm_array("joint2_speed_rad_s")
        lb = float(np.max(direct_move_time_s(start, goal, v1, v2), initial=0.0))
        return Leg(instrument, start, goal, options, buffer_mm, tuple(geoms),
                   tuple(int(k) for k in instrument.enabled_arms), lb)

    def with_ends(self, start_q: np.ndarray, goal_q: np.ndarray, options: MotionOptions | None = None) -> Leg:
        """Another leg of the same instrument (fresh cache, lower bound recomputed)."""
        return Leg.build(self.instrument, start_q, goal_q, options or self.options, self.geoms)

    @property
    def n_arms(self) -> int:
        return self.instrument.n_arms

    @property
    def disabled(self) -> list[int]:
        en = set(self.enabled)
        return [k for k in range(self.n_arms) if k not in en]


@dataclass(frozen=True, eq=False)
class Candidate:
    """Trajectories of every arm for the leg (one :class:`~models.types.ArmTrajectory` per arm,
    from t = 0), not yet verified. ``stats`` are merged into the plan's stats by the driver."""

    trajectories: tuple[ArmTrajectory, ...]
    makespan_s: float
    strategy: str
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Refusal:
    """No plan: ``arms`` the arms the strategy could not plan (may be empty when it has no
    opinion), ``reasons`` per arm. ``final`` means no later strategy can do better (the
    driver stops)."""

    arms: tuple[int, ...] = ()
    reasons: dict[int, str] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    final: bool = False


@runtime_checkable
class Strategy(Protocol):
    """A way of planning a leg. ``plan`` must honour ``budget`` (it may overrun by one
    indivisible step) and never raise for an unplannable leg."""

    name: str

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal: ...




def check_configuration(instrument: Instrument, q, name: str) -> np.ndarray:
    a = np.asarray(q, dtype=float)
    if a.shape != (instrument.n_arms, 2):
        raise InputError(name, f"expected shape ({instrument.n_arms}, 2), got {a.shape}")
    bad = np.argwhere(~np.isfinite(a))
    if len(bad):
        raise InputError(f"{name}[{bad[0][0]}]", "joint angles must be finite")
    return a


def same_angle(a: float, b: float, tol: float = 1e-9) -> bool:
    return abs((a - b + np.pi) % TWO_PI - np.pi) <= tol


def same_configuration(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal theta1 and equal theta2 modulo 2 pi for every arm."""
    return bool(np.all(np.abs(a[:, 0] - b[:, 0]) <= 1e-9)
                and all(same_angle(x, y) for x, y in zip(a[:, 1], b[:, 1], strict=True)))


def unplannable(leg: Leg) -> dict[int, str]:
    """Reasons why arms of ``leg`` cannot be planned at all (thesis 6.3.1 assumes feasible ends)."""
    return ends_unplannable(leg.instrument, leg.geoms, leg.start_q, leg.goal_q, leg.buffer_mm)


def ends_unplannable(instrument: Instrument, geoms: Sequence[ArmGeom], start_q: np.ndarray,
                     goal_q: np.ndarray, buffer_mm: float) -> dict[int, str]:
    """Ends in the ZoA or beyond the joint limits, a disabled arm asked to move, colliding ends."""
    reasons: dict[int, str] = {}
    enabled = set(instrument.enabled_arms)
    for k, g in enumerate(geoms):
        if g.in_zoa(start_q[k, 0], start_q[k, 1]):
            reasons[k] = "start in zone of avoidance or beyond joint limits"
        elif g.in_zoa(goal_q[k, 0], goal_q[k, 1]):
            reasons[k] = "goal in zone of avoidance or beyond joint limits"
        elif k not in enabled and not (abs(start_q[k, 0] - goal_q[k, 0]) <= 1e-9
                                       and same_angle(start_q[k, 1], goal_q[k, 1])):
            reasons[k] = "arm is disabled but its goal differs from its start"
    for name, q in (("goal", goal_q), ("start", start_q)):
        for a, b in colliding_arm_pairs(instrument, q, buffer_mm):
            for x, y in ((a, b), (b, a)):
                reasons.setdefault(x, f"{name} configuration collides with arm {y}")
    return reasons


def stage_budget(name: str, leg: Leg, budget: Budget) -> Budget:
    """The part of ``budget`` a strategy gets (:data:`planner.options.SHARES`)."""
    from planner.options import SHARES as sh

    o = leg.options
    if name in ("delays", "cluster", "evasion", "sequenced"):
        return sh.share(budget, getattr(sh, name))
    if name == "detours":
        d = leg.cache.delay_deadline if leg.cache.delay_deadline is not None else budget.deadline_s
        if leg.cache.cluster_s is not None:  # the cluster's time is its own, not the delay stage's
            f = sh.detours_after_cluster
            d = min(d + leg.cache.cluster_s, clock.now() + min(f * budget.total_s, sh.cap_s(f)))
        return replace(budget, deadline_s=d)
    if name == "prioritized" and o.via is not None and o.max_start_stop >= 1:
        f = sh.via_reserve
        return budget.keep(min(f * budget.total_s, sh.cap_s(f)))
    return budget


class FirstOf:
    """Strategies tried in order on the same leg, each with its :func:`stage_budget`; the first
    candidate is the answer (unverified: the caller verifies), else the last refusal naming
    arms. Stats of every step are merged (:func:`merge_stats`)."""

    def __init__(self, name: str, strategies: Sequence[Strategy]) -> None:
        self.name = name
        self.strategies = tuple(strategies)

    def plan(self, leg: Leg, budget: Budget) -> Candidate | Refusal:
        stats: dict = {}
        refusal = Refusal()
        for s in self.strategies:
            out = s.plan(leg, stage_budget(s.name, leg, budget))
            merge_stats(stats, out.stats)
            if isinstance(out, Candidate):
                return Candidate(out.trajectories, out.makespan_s, out.strategy, stats)
            if out.arms or not refusal.arms:
                refusal = out
            if out.final:
                break
        return Refusal(refusal.arms, refusal.reasons, stats, refusal.final)


COUNTERS = ("collision_checks", "states_explored", "paths_explored")


def merge_stats(into: dict, new: dict) -> dict:
    """Counters add up, ``attempt_log`` entries append, other keys are replaced."""
    for key, v in new.items():
        if key in COUNTERS:
            into[key] = into.get(key, 0) + v
        elif key == "attempt_log":
            into.setdefault("attempt_log", []).extend(v)
        else:
            into[key] = v
    return into
