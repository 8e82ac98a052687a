"""The clock every time budget of the allocator and the motion planner reads.

By default :func:`now` is the wall clock (``time.perf_counter``), and a budget ends when its
seconds have passed, so what a time-limited search finds depends on how busy the machine is.

Inside :func:`effort`, :func:`now` is an *effort clock* instead: it advances only by the
work the code reports, in reference seconds (what that work costs on the reference machine,
two cores of the development host), plus :data:`TICK_S` for every reading. The same call
with the same inputs then stops every search at the same point on any machine and under any
load, so a plan depends only on its request and seed: the same plan whatever the number of
workers.

Work is reported in two ways:

* :func:`charge` adds seconds the caller has priced itself;
* :func:`work` reports ``units`` of a named kind of work, priced by the cost tables the
  layers above register with :func:`register_work_costs` (a kind costs ``per call + per
  unit * units`` seconds). Each layer owns and fits its own costs: this module knows none.
  Inside :func:`effort` a kind nobody registered raises :class:`KeyError`, so a misspelt
  kind cannot make work free; on the wall clock :func:`work` does nothing.

A wall-clock guard keeps the effort clock honest: past ``wall_limit_s`` real seconds, every
reading jumps :data:`PAST_WALL_S` ahead, so that every deadline set until then has passed and
the work stops at its next check. Then, and only then, the answer depends on the machine's
speed again; ``overran`` says whether it happened.

Engines that keep their own clock (CP-SAT, HiGHS) run on their deterministic limits inside
:func:`effort` and charge what they report having done (:mod:`solvers.effort`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

__all__ = [
    "EffortClock", "PAST_WALL_S", "TICK_S", "charge", "effort", "effort_clock", "in_effort", "now",
    "register_work_costs", "work",
]

#: Every reading of the effort clock costs this much (it bounds every loop that only reads
#: the clock, and stands for the bookkeeping between two readings).
TICK_S = 20e-6
#: How far every reading jumps once the wall-clock guard has passed.
PAST_WALL_S = 1e9

# kind of work -> the registered table that prices it (the table itself, so that the kind
# is priced by what the table holds when the work is reported)
_COST_TABLES: dict[str, Mapping[str, tuple[float, float]]] = {}


def register_work_costs(table: Mapping[str, tuple[float, float]]) -> None:
    """Price every kind of :func:`work` named in ``table``, as ``(per call s, per unit s)``
    in reference seconds. Registering the same table again does nothing; a kind another
    table already prices at a different cost raises :class:`ValueError` (two layers cannot
    own one kind)."""
    for kind, cost in table.items():
        per_call_s, per_unit_s = cost  # a pair, or the tuple unpacking fails here, not in work()
        if not (math.isfinite(per_call_s) and math.isfinite(per_unit_s) and per_call_s >= 0 and per_unit_s >= 0):
            raise ValueError(f"work cost of {kind!r} must be two finite seconds >= 0, got {cost!r}")
        owner = _COST_TABLES.get(kind)
        if owner is not None and owner is not table and tuple(owner[kind]) != tuple(cost):
            raise ValueError(f"work kind {kind!r} is already priced at {owner[kind]!r} by another table")
    for kind in table:
        _COST_TABLES[kind] = table


@dataclass
class EffortClock:
    """Reference seconds charged so far (``t_s``); the wall-clock guard ``wall_end`` (a
    ``time.perf_counter`` instant, or None); ``overran`` once the guard has fired."""

    t_s: float = 0.0
    wall_end: float | None = None
    overran: bool = False
    tally: dict[str, tuple[int, float]] | None = None  # calls and units per kind of work
    reads: int = 0

    def read(self) -> float:
        self.reads += 1
        self.t_s += TICK_S
        if self.wall_end is not None and time.perf_counter() > self.wall_end:
            self.overran = True
            self.t_s += PAST_WALL_S
        return self.t_s


_CLOCK: ContextVar[EffortClock | None] = ContextVar("mxs_effort_clock", default=None)


def now() -> float:
    """Seconds on the current clock: the wall clock, or inside :func:`effort` the reference
    seconds of work charged so far. Only differences and comparisons of two readings of the
    same clock mean anything."""
    c = _CLOCK.get()
    return time.perf_counter() if c is None else c.read()


def charge(t_s: float) -> None:
    """Report work just done that costs ``t_s`` reference seconds (no-op on the wall clock)."""
    c = _CLOCK.get()
    if c is not None:
        c.t_s += t_s


def work(kind: str, units: float = 0.0) -> None:
    """Report work of ``kind`` (a kind of a table registered with :func:`register_work_costs`)
    and size ``units``. No-op on the wall clock; inside :func:`effort` an unregistered kind
    raises :class:`KeyError`."""
    c = _CLOCK.get()
    if c is not None:
        try:
            per_call_s, per_unit_s = _COST_TABLES[kind][kind]
        except KeyError:
            raise KeyError(f"no cost registered for the work kind {kind!r} "
                           "(models.clock.register_work_costs)") from None
        c.t_s += per_call_s + per_unit_s * units
        if c.tally is not None:
            n, u = c.tally.get(kind, (0, 0.0))
            c.tally[kind] = (n + 1, u + units)


def in_effort() -> bool:
    """True inside :func:`effort`."""
    return _CLOCK.get() is not None


def effort_clock() -> EffortClock | None:
    """The current effort clock (None on the wall clock)."""
    return _CLOCK.get()


@contextmanager
def effort(wall_limit_s: float | None = None, *, tally: bool = False) -> Iterator[EffortClock]:
    """Run the block on a fresh effort clock, starting at 0; past ``wall_limit_s`` real
    seconds (None: no guard) every deadline of the block has passed. ``tally``: count the
    calls and units of every kind of :func:`work` (for calibration)."""
    end = None if wall_limit_s is None or math.isinf(wall_limit_s) else (
        time.perf_counter() + max(float(wall_limit_s), 0.0))
    clock = EffortClock(0.0, end, tally={} if tally else None)
    token = _CLOCK.set(clock)
    try:
        yield clock
    finally:
        _CLOCK.reset(token)
