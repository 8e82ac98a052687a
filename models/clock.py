"""The clock every time budget of the allocator and the motion planner reads.

By default :func:`now` is the wall clock (``time.perf_counter``), and a budget ends when its
seconds have passed, so what a time-limited search finds depends on how busy the machine was.

Inside :func:`effort`, :func:`now` is an *effort clock* instead: it advances only by the
work the code reports through :func:`charge`, in reference seconds (what that work costs on
the reference machine, two cores of the development host; the costs are the constants
below, measured once), plus :data:`TICK_S` for every reading. The same call with the same
inputs then stops every search at the same point on any machine and under any load, so a
plan depends only on its request and seed: the same plan whatever the number of workers.

A wall-clock guard keeps the effort clock honest: past ``wall_limit_s`` real seconds, every
reading jumps :data:`PAST_WALL_S` ahead, so that every deadline set before it has passed and
the work stops at its next check. Then, and only then, the answer depends on the machine's
speed again; ``overran()`` says whether it happened.

Engines that keep their own clock (CP-SAT, HiGHS) read :func:`effort_limits` to run on their
deterministic limits instead of seconds, and :func:`charge` what they report having done.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

__all__ = [
    "EffortClock", "PAST_WALL_S", "PLANNER_WORK_S", "TICK_S", "charge", "effort", "effort_clock", "in_effort",
    "now", "work",
]

#: Every reading of the effort clock costs this much (it bounds every loop that only reads
#: the clock, and stands for the bookkeeping between two readings).
TICK_S = 20e-6
#: How far every reading jumps once the wall-clock guard has passed.
PAST_WALL_S = 1e9

# ------------------------------------------------------------------ costs of the planner
# (reference seconds per unit of work, charged by planner/)

#: Reference seconds of each kind of planner work, as (per call, per unit), reported through
#: :func:`work`; fitted by ``python benchmarks/effort_motion.py`` (least squares of the CPU seconds
#: of real legs on the counts of each kind).
PLANNER_WORK_S: dict[str, tuple[float, float]] = {
    "departure": (0.0, 1.1e-06),  # planner.timeline: one earliest departure; unit: move samples
    "free_after": (0.0, 0.0),  # planner.timeline: a rest check; unit: poses
    "move_samples": (0.0, 0.0),  # planner.timeline: a straight move sampled; unit: samples
    "clearance_rows": (0.0, 3.9e-08),  # planner.clearance: unit: rows of body pairs
    "clearance_to_arms": (9.7e-05, 0.0),  # planner.clearance: unit: arm x sample clearances
    "walk": (0.0, 1.1e-06),  # planner.clearance: delay-table walks; unit: exact clearances
    "segments": (7.6e-05, 5.8e-07),  # planner.geometry: forward kinematics; unit: poses
    "zoa_edges": (0.0, 1.9e-06),  # planner.geometry: ZoA test of straight edges; unit: edges
    "csp_nodes": (3.2e-05, 0.0),  # planner.delays: unit: search nodes
    "verify": (0.0, 6.8e-06),  # planner.verify: unit: pair samples computed
}

# ---------------------------------------------------------------- costs of the allocator
# (reference seconds per unit of work, charged by solvers/ and models/incompatibility.py;
# measured with ``python -m benchmarks.effort``, which compares the effort seconds of whole
# allocate calls with the CPU seconds they used on the thesis fields)
# bitset branch-and-bound (solvers.allocation.bitset)
BNB_NODE_S = 24e-6  # one node of the depth-first search
BNB_TABLE_BIT_S = 1.1e-9  # one bit of the per-arm conflict bitsets built for the search
BNB_TABLE_ROW_S = 1.6e-6  # one (location, arm) bitset turned into a Python int
PRUNE_PROBE_S = 6e-6  # one column probed by the exact column pruning
# the exact model (solvers.model, solvers.allocation.cliques, solvers.allocation.exact)
MODEL_NONZERO_S = 0.04e-6  # one non-zero of the model arrays built
MODEL_COLUMN_S = 0.5e-6  # one column of the model arrays built
CLIQUE_STEP_S = 8e-6  # one column added to a greedy clique
CLIQUE_DISC_S = 10e-6  # one seed disc of the clique rows
CLIQUE_CELL_S = 2e-9  # one cell of the dense exclusion matrix read or built
# OR-Tools CP-SAT (every model of solvers/)
CPSAT_LITERAL_S = 0.8e-6  # one literal added to a model from Python
CPSAT_DETERMINISTIC_S = 0.6  # one unit of CP-SAT's deterministic time
CPSAT_SOLVE_S = 5e-3  # the fixed cost of one solve (setup, presolve bookkeeping)
# HiGHS (solvers.allocation.highs, exact.relaxation_bound)
HIGHS_RUN_S = 1e-3  # the fixed cost of one run
HIGHS_NONZERO_S = 0.2e-6  # one non-zero of the matrix passed to HiGHS
HIGHS_SIMPLEX_ITERATION_S = 20e-6  # one simplex iteration (LP or inside the MIP)
HIGHS_MIP_NODE_S = 1e-3  # one branch-and-bound node
HIGHS_CALLBACK_NONZERO_S = 1.8e-6  # per non-zero of the matrix, the MIP work between two callbacks
# semi-greedy heuristic (solvers.allocation.semigreedy)
SEMIGREEDY_PREPARE_COLUMN_S = 0.7e-6  # one assignment in the per-configuration preparation
SEMIGREEDY_ITERATION_S = 1.3e-3  # one construction + padding
SEMIGREEDY_PASS_S = 0.28e-3  # one local-search pass
# sequencing post-passes (solvers.sequencing)
TABU_MOVE_S = 60e-6  # one move of the packing tabu search
TABU_CELL_S = 5e-9  # one cell of the cost arrays a move reads or updates
REPAIR_STEP_S = 180e-6  # one frontier target expanded by an ejection chain
LP_SOLVE_S = 2e-3  # one master LP of the column generation (scipy HiGHS) ...
LP_CELL_S = 50e-9  # ... and per cell of its dense matrix
VERIFY_CONFIGURATION_S = 2e-3  # one configuration checked on the geometry
CONFIGURATION_BUILD_S = 0.6e-3  # one configuration turned into its result record
# incompatibility structure (models.incompatibility)
INCOMPATIBILITY_PAIR_S = 0.06e-6  # one candidate pair of locations checked
INCOMPATIBILITY_ASSIGNMENT_S = 60e-6  # one reachable location built
INCOMPATIBILITY_FOUND_PAIR_S = 0.15e-6  # one incompatible pair stored (CSR assembly)
INCOMPATIBILITY_BLANK_S = 1.3e-3  # one blank-sky pose sampled for an arm

# ------------------------------------------------------------------------------------------


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
    """Report planner work of ``kind`` (a key of :data:`PLANNER_WORK_S`) and size ``units``."""
    c = _CLOCK.get()
    if c is not None:
        per_call_s, per_unit_s = PLANNER_WORK_S[kind]
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
