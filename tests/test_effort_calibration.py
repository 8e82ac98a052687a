"""The effort clock's calibration: an effort second is about a CPU second.

Inside :func:`models.clock.effort` (every pointing of a plan runs there) a budget is
counted in reference seconds of the work the code reports, at costs each layer owns:
:data:`planner.effort.PLANNER_WORK_S` for the motion planner, the constants of
:mod:`solvers.effort` for the allocator and the incompatibility structure. They are fitted
so that an effort second is a CPU second of the reference machine (2 cores, nothing else
running). When the code gets faster or slower, or its work is counted differently, the
costs drift and every effort budget means more or less real time than it says.

This test plans fixed motion legs and runs fixed allocations on the effort clock, sums the
effort seconds and the CPU seconds (``time.process_time``: the load of other processes
hardly moves it) per layer, and fails when their ratio leaves :data:`RATIO_RANGE` (wide,
since CPU seconds still vary with the machine and its load).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from benchmarks.effort_allocation import DISTRIBUTIONS, measure, thesis_field
from models import clock
from models.instrument import default_instrument
from planner import plan_motion
from planner.kernels import compile_kernels
from solvers.allocation import allocate

INST = default_instrument()
LEGS = json.loads((Path(__file__).parent / "data" / "motion_legs.json").read_text())["legs"]
#: wide: the machines the suite runs on differ from the one the costs were fitted on, and not
#: alike for every layer. Measured on the regression legs: 0.96-1.09 where the costs were
#: fitted, 0.69 on a slower machine, 1.30-1.40 on a faster one (also at the fit's own commit,
#: so the machine, not the code; the allocator's calls 1.08 there). The range catches a
#: halving or doubling of what the code's work costs.
RATIO_RANGE = (0.5, 2.0)
LEG_BUDGET_S = 3.0
ALLOCATION_LIMIT_S = 5.0
# (method, targets, distribution): seeded fields of benchmarks/effort_allocation.py
ALLOCATIONS = [(method, n, dist) for method in ("bnb", "semigreedy") for dist in ("uniform", "gauss40")
               for n in (40, 150)]
REFIT = {
    "motion legs": ("planner/effort.py (PLANNER_WORK_S)",
                    "python benchmarks/effort_motion.py --fields 2 --seed 5"),
    "allocations": ("solvers/effort.py (the allocator's costs)",
                    "python -m benchmarks.effort_allocation --sizes 40 100 400 --limit 5 --methods bnb semigreedy"),
}


@pytest.fixture(scope="module", autouse=True)
def _warm() -> None:
    """Compiled kernels, imports and caches: the first calls' extra CPU seconds are not work."""
    compile_kernels()
    with clock.effort():
        plan_motion(INST, np.array(LEGS[0]["start_q"]), np.array(LEGS[0]["goal_q"]), seed=0, time_budget_s=0.5)
        allocate(INST, thesis_field(50, None, 0), time_limit_s=2.0)


def _assert_calibrated(layer: str, effort_s: float, cpu_s: float) -> None:
    where, command = REFIT[layer]
    ratio = effort_s / max(cpu_s, 1e-9)
    lo, hi = RATIO_RANGE
    assert lo <= ratio <= hi, (
        f"{layer}: effort / CPU seconds is {ratio:.2f} ({effort_s:.2f} effort s over {cpu_s:.2f} CPU s), "
        f"outside {lo}-{hi}: the work costs no longer match what this code costs on this machine. "
        f"If the machine was not busy, re-fit the costs in {where}: run `{command}` (2 cores, nothing "
        "else running), scale the costs so that its median effort/CPU is about 1, and record the "
        "measured medians where the costs and docs quote them.")


def test_motion_legs_cost_about_their_cpu_seconds() -> None:
    effort_s = cpu_s = 0.0
    for leg in LEGS:
        with clock.effort(wall_limit_s=60.0) as c:
            t0 = time.process_time()
            plan_motion(INST, np.array(leg["start_q"]), np.array(leg["goal_q"]), seed=0,
                        time_budget_s=LEG_BUDGET_S)
            cpu_s += time.process_time() - t0
        assert not c.overran, f"{leg['name']}: the wall-clock guard stopped the leg"
        effort_s += c.t_s
    _assert_calibrated("motion legs", effort_s, cpu_s)


def test_allocations_cost_about_their_cpu_seconds() -> None:
    effort_s = cpu_s = 0.0
    for method, n, dist in ALLOCATIONS:
        row = measure(method, thesis_field(n, DISTRIBUTIONS[dist], seed=n), "all", ALLOCATION_LIMIT_S)
        assert not row["overran"], f"{method} on {n} {dist} targets: the wall-clock guard stopped the call"
        effort_s += row["effort_s"]
        cpu_s += row["cpu_s"]
    _assert_calibrated("allocations", effort_s, cpu_s)
