"""The one time budget of the project: a span of the current clock.

Every time limit of the allocator, the sequencing driver and the motion planner (a call's,
a configuration's share, a leg's, a strategy's share, a whole sequence's) is a
:class:`Budget`. It reads :func:`models.clock.now`, so it counts effort seconds inside
:func:`models.clock.effort` (the work charged) and wall seconds outside it.

Inside :func:`models.clock.effort` every reading of the clock costs
:data:`models.clock.TICK_S`, so a method reads the clock at most once, and only when its
answer depends on it: the same calls then charge the same ticks and stop every search at the
same point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from models import clock

__all__ = ["Budget"]


@dataclass(frozen=True)
class Budget:
    """The one budget type of the project: a span of the current clock,
    :func:`models.clock.now`, from ``start_s`` to ``deadline_s`` (``math.inf``: no limit),
    so it counts effort seconds inside :func:`models.clock.effort` and wall seconds outside.

    ``total_s`` is the seconds that :meth:`share` takes fractions of: the whole budget a
    caller was given, which a sub-budget keeps so that every stage's share is a fraction of
    the same whole. ``hard_deadline_s`` is an enclosing deadline that no share extends (a
    stage may finish work it cannot do without up to it); it defaults to ``deadline_s``.
    """

    start_s: float
    deadline_s: float
    total_s: float
    hard_deadline_s: float | None = None

    def __post_init__(self) -> None:
        hard_s = self.deadline_s if self.hard_deadline_s is None else self.hard_deadline_s
        for name, value in (("start_s", self.start_s), ("deadline_s", self.deadline_s),
                            ("total_s", self.total_s), ("hard_deadline_s", hard_s)):
            object.__setattr__(self, name, float(value))

    @staticmethod
    def start(limit_s: float | None) -> Budget:
        """A budget of ``limit_s`` from now (None or ``math.inf``: unlimited); shares are
        fractions of ``limit_s``."""
        t_s = clock.now()
        if limit_s is None or limit_s == math.inf:
            return Budget(t_s, math.inf, math.inf)
        return Budget(t_s, t_s + limit_s, limit_s)

    @staticmethod
    def ending_at(deadline_s: float | None) -> Budget:
        """A budget that ends at the clock instant ``deadline_s`` (None or ``math.inf``:
        unlimited), for a caller that holds only that instant; it does not read the clock. Its
        start is unknown (``-math.inf``) and its ``total_s`` is ``math.inf``, so a
        :meth:`share` of it is all of what is left."""
        end_s = math.inf if deadline_s is None else deadline_s
        return Budget(-math.inf, end_s, math.inf)

    @property
    def limit_s(self) -> float:
        """The seconds from the start to the deadline (``math.inf``: unlimited)."""
        return self.deadline_s - self.start_s

    @property
    def unlimited(self) -> bool:
        """True when the deadline is ``math.inf``."""
        return self.deadline_s == math.inf

    def left_s(self) -> float:
        """Seconds until the deadline (negative once it has passed). An unlimited budget
        answers ``math.inf`` without reading the clock."""
        if self.unlimited:
            return math.inf
        return self.deadline_s - clock.now()

    def elapsed_s(self) -> float:
        """Seconds since the start."""
        return clock.now() - self.start_s

    def expired(self) -> bool:
        """True once the clock is past the deadline; an unlimited budget never expires and
        does not read the clock."""
        if self.unlimited:
            return False
        return clock.now() > self.deadline_s

    def past_deadline(self) -> bool:
        """True once the clock is past the deadline. It reads the clock on every call, also
        when the budget is unlimited (where :meth:`expired` does not): a search loop that polls
        it charges one tick per poll whatever its limit."""
        return clock.now() > self.deadline_s

    def part(self, fraction: float) -> Budget:
        """The first ``fraction`` of this budget counted from its start: the same start, the
        deadline ``start_s + fraction * total_s`` (never past this budget's deadline), the same
        ``total_s`` and ``hard_deadline_s``. It does not read the clock."""
        return replace(self, deadline_s=min(self.start_s + fraction * self.total_s, self.deadline_s))

    def share(self, fraction: float, cap_s: float = math.inf) -> Budget:
        """A sub-budget of ``min(fraction * total_s, cap_s)`` from now, never past this
        budget's deadline; it keeps ``total_s`` and ``hard_deadline_s``, so that the next
        share is a fraction of the same whole."""
        t_s = clock.now()
        deadline_s = min(t_s + min(fraction * self.total_s, cap_s), self.deadline_s)
        return replace(self, start_s=t_s, deadline_s=deadline_s)

    def keep(self, seconds: float) -> Budget:
        """This budget with ``seconds`` kept back at its end (for a later stage); the same
        start, ``total_s`` and ``hard_deadline_s``."""
        return replace(self, deadline_s=self.deadline_s - seconds)

    def child(self, limit_s: float) -> Budget:
        """A budget of its own of ``limit_s`` from now, within this one (never past its
        deadline): its shares are fractions of its own length and its deadline is its hard
        deadline, as for a budget :meth:`start` gives."""
        t_s = clock.now()
        deadline_s = min(t_s + limit_s, self.deadline_s)
        return Budget(t_s, deadline_s, deadline_s - t_s)
