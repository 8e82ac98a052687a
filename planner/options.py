"""Planning options of one leg (thesis table 6.1) and the budget shares of the strategies.

:class:`MotionOptions` holds every option of :func:`planner.driver.plan_motion` except the
time budget; it is validated once, when built, and shared read-only by the driver and
the strategies. :class:`LegShares` (:data:`SHARES`) is the only place where the strategies'
parts of a leg's time budget are set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.budget import Budget
from models.errors import InputError
from models.instrument import CONFIGURATION_TIME_GOAL_S
from planner.registry import STRATEGIES

#: A leg is never given less than this (a leg of a sequence, and each leg of the "via"
#: fallback): a short budget still has every leg tried rather than failed unplanned.
MIN_LEG_S = 0.5


@dataclass(frozen=True)
class LegShares:
    """The motion driver's one table of time shares: the part of a leg's budget each stage of
    :func:`planner.driver.plan_leg` gets (:func:`planner.strategy.stage_budget`).

    Each share is a fraction of the leg's budget, capped at the same fraction of
    ``cap_leg_s``: a leg given more than that (a leg of a sequence with time to spare) does
    not spend the excess on one strategy's search, which rarely succeeds later where it
    failed early; it goes to the strategies after it and to the sequence's repair loop."""

    #: The leg budget at which every share reaches its cap.
    cap_leg_s: float = 10.0
    #: The departure-delay CSP's straight moves and detour rounds together: the first and
    #: cheapest strategy, which plans most legs; the share keeps the hard legs' strategies
    #: their time.
    delays: float = 0.15
    #: The cluster strategy, counted from when it starts.
    cluster: float = 0.25
    #: The detour rounds after a cluster strategy that found nothing: they rarely succeed
    #: where it failed, so the rest goes to the prioritized strategy.
    detours_after_cluster: float = 0.1
    #: The evasion strategy (clear detours and step-aside moves in the delay CSP).
    evasion: float = 0.15
    #: The sequenced strategy (arm-by-arm moves on a time grid): the strategy of the deep,
    #: crowded legs, so the largest share.
    sequenced: float = 0.8
    #: Kept back for the two-leg "via" fallback: the prioritized strategy stops its attempts
    #: before it, so that a leg it cannot plan can still go through park.
    via_reserve: float = 0.15
    #: Each search for a shorter plan after a long verified one: a plan is kept, so this
    #: only buys a shorter configuration time.
    shorter_search: float = 0.3
    #: A shorter plan is searched for only while this much of the leg's budget is left: a
    #: search on less rarely finds one, and the sequence's later legs need the time.
    shorter_search_min_left_s: float = 1.0

    def cap_s(self, fraction: float) -> float:
        """The cap of a share of ``fraction``."""
        return fraction * self.cap_leg_s

    def share(self, budget: Budget, fraction: float, cap_s: float = math.inf) -> Budget:
        """``fraction`` of ``budget`` from now, at most its cap and ``cap_s``."""
        return budget.share(fraction, min(self.cap_s(fraction), cap_s))


SHARES = LegShares()

# a plan longer than CLUSTER_MAKESPAN_RATIO x the lower bound from one of these strategies lets
# the driver run the prioritized strategy (at most SHORTER_SEARCH_ATTEMPTS attempts, this share
# of the budget, if at least SHORTER_SEARCH_MIN_LEFT_S is left) and keep the shorter verified plan
SHORTER_SEARCH_AFTER = ("cluster", "evasion", "sequenced")
# the same with the sequenced strategy, which tries plans longer than this ratio from these
SEQUENCED_SHORTER_AFTER = ("delays", "cluster", "evasion")
SEQUENCED_SHORTER_RATIO = 1.25
# plans longer than this (the thesis' configuration time goal, 6.4.2) are searched for a
# shorter one whatever their ratio to the lower bound
MAKESPAN_GOAL_S = CONFIGURATION_TIME_GOAL_S
CLUSTER_MAKESPAN_RATIO = 1.25
# a plan of the straight departure delays longer than MAKESPAN_GOAL_S is first searched again
# with departures on this finer step (the CSP's delays are multiples of dt_s, 6 s by default:
# one step on an arm near the goal takes the plan over it)
FINE_DELAY_STEP_S = 2.0
SHORTER_SEARCH_ATTEMPTS = 2  # prioritized attempts of a shorter-plan search
# a plan from park at most this longer than its positive-turn bound (the longest move turning theta2 the
# positive way) is not searched for a shorter one (planner.driver.at_positive_turn_bound)
POSITIVE_BOUND_TOL_S = 1.0

# Bounds on the sampling, so that no request can exhaust memory or time (defaults: 6 s, 0.1 s,
# 220 s: 8.1e4 samples per pair table; the thesis' smallest step, 0.6 s at 0.1 s, 8.1e5)
MIN_DT_S = 0.1
MIN_DT_COL_S = 0.01
MAX_DELAY_SAMPLES = 1e6

DEFAULT_STRATEGIES = ("delays", "sequenced", "evasion", "cluster", "forward", "reverse")
# names with a fixed place in the order (planner.driver.strategy_sequence); others are looked up
# in the registry (planner.registry.STRATEGIES)
BUILTIN_NAMES = ("delays", "cluster", "evasion", "sequenced", "forward", "reverse", "via")


@dataclass(frozen=True, eq=False)
class MotionOptions:
    """Every planning option of a leg (thesis table 6.1 and the strategy settings).

    ``dt_s`` the motion-action step, ``dt_col_s`` the collision-check step (a sub-multiple of
    ``dt_s``), ``max_start_stop`` the stops allowed per arm, ``horizon_s`` T_f,
    ``collision_buffer_mm`` the clearance (None: the instrument's), ``max_attempts`` the
    prioritized planning attempts, ``grid`` the roadmap grid (thesis fig. 6.8),
    ``strategies`` the strategy names in order, ``rpp`` revised prioritized planning with
    ``rpp_max_paths`` roadmap paths, ``turn_sense`` / ``turn_bias_s`` the roadmap's preferred
    theta2 sense, ``via`` the configuration of the two-leg fallback ("park", an
    (n_arms, 2) array or None). Same options and ``seed`` -> same plan.
    """

    dt_s: float = 6.0
    dt_col_s: float = 0.1
    max_start_stop: int = 1
    collision_buffer_mm: float | None = None
    seed: int = 0
    horizon_s: float = 220.0
    max_attempts: int = 10
    grid: tuple[int, int] = (8, 6)
    strategies: tuple[str, ...] = DEFAULT_STRATEGIES
    rpp: bool = False
    rpp_max_paths: int = 8
    turn_sense: int = 1
    turn_bias_s: float = 0.0
    via: np.ndarray | str | None = "park"

    def __post_init__(self) -> None:
        dt, dtc = self.dt_s, self.dt_col_s
        if not (_real(dt) and _real(dtc) and dt > 0 and dtc > 0 and math.isfinite(dt) and math.isfinite(dtc)):
            raise InputError("dt_s", "dt_s and dt_col_s must be positive")
        if dt < MIN_DT_S:
            raise InputError("dt_s", f"must be >= {MIN_DT_S} s")
        if dtc < MIN_DT_COL_S:
            raise InputError("dt_col_s", f"must be >= {MIN_DT_COL_S} s")
        m = max(1, int(round(dt / dtc)))
        if abs(m * dtc - dt) > 1e-6 * dt:
            raise InputError("dt_col_s", "must divide dt_s into a whole number of collision steps")
        self._int("max_start_stop", 0, "must be >= 0")
        b = self.collision_buffer_mm
        if b is not None and not (_real(b) and math.isfinite(b) and b >= 0):
            raise InputError("collision_buffer_mm", "must be a finite number >= 0 (or None)")
        self._int("seed", None, "must be an integer")
        if not (_real(self.horizon_s) and math.isfinite(self.horizon_s) and self.horizon_s > 0):
            raise InputError("horizon_s", "must be a positive number of seconds")
        work = (self.horizon_s / dt) * (self.horizon_s / dtc)
        if work > MAX_DELAY_SAMPLES:
            raise InputError("dt_col_s", f"horizon_s / dt_s x horizon_s / dt_col_s = {work:.3g} is above "
                             f"{MAX_DELAY_SAMPLES:.0e} (the samples of one pair table): use larger steps")
        self._int("max_attempts", 0, "must be an integer >= 0")
        grid = tuple(self.grid) if isinstance(self.grid, (tuple, list)) else ()
        if len(grid) != 2 or not all(_integer(g) and g >= 1 for g in grid):
            raise InputError("grid", "must be two positive integers (theta1, theta2 vertices)")
        object.__setattr__(self, "grid", (int(grid[0]), int(grid[1])))
        self._check_strategies()
        self._int("rpp_max_paths", 1, "must be an integer >= 1")
        if self.turn_sense not in (1, -1):
            raise InputError("turn_sense", "must be 1 or -1")
        if not (_real(self.turn_bias_s) and math.isfinite(self.turn_bias_s)):
            raise InputError("turn_bias_s", "must be a finite number of seconds")
        self._check_via()

    def _int(self, name: str, minimum: int | None, message: str) -> None:
        v = getattr(self, name)
        if not (_integer(v) or (_real(v) and math.isfinite(v) and float(v).is_integer())):
            raise InputError(name, message)
        if minimum is not None and v < minimum:
            raise InputError(name, message)
        object.__setattr__(self, name, int(v))

    def _check_strategies(self) -> None:
        s = self.strategies
        if isinstance(s, str) or not all(isinstance(x, str) for x in s):
            raise InputError("strategies", "must be a sequence of strategy names")
        s = tuple(s)
        bad = [x for x in s if x not in BUILTIN_NAMES and x not in STRATEGIES]
        if bad:
            raise InputError("strategies", f"unknown strategy {bad[0]!r}")
        object.__setattr__(self, "strategies", s)

    def _check_via(self) -> None:
        v = self.via
        if v is None or (isinstance(v, str) and v == "park"):
            return
        if isinstance(v, str):
            raise InputError("via", "must be 'park', a configuration or None")
        a = np.asarray(v, dtype=float)
        if a.ndim != 2 or a.shape[1] != 2 or not np.all(np.isfinite(a)):
            raise InputError("via", "must be a finite (n_arms, 2) configuration")
        object.__setattr__(self, "via", a)

    @property
    def collision_steps(self) -> int:
        """dt_col samples per motion step (m = dt / dt_col)."""
        return max(1, int(round(self.dt_s / self.dt_col_s)))

    @property
    def horizon_steps(self) -> int:
        return max(1, math.ceil(self.horizon_s / self.dt_s - 1e-9))


def _real(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)


def _integer(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)
