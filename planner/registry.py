"""The motion strategies by name: :mod:`planner.strategies` registers the built-in ones, a
caller may register its own, and :class:`planner.options.MotionOptions` accepts the names
registered here (besides the built-in names that have a fixed place in the driver's order)."""

from __future__ import annotations

from typing import Any, Protocol, TypeVar

__all__ = ["STRATEGIES", "register"]


class _Named(Protocol):
    name: str


S = TypeVar("S", bound=_Named)

#: every registered strategy (a :class:`planner.strategy.Strategy`) under its name
STRATEGIES: dict[str, Any] = {}


def register(strategy: S) -> S:
    """Make ``strategy`` available to the driver under ``strategy.name``."""
    STRATEGIES[strategy.name] = strategy
    return strategy
