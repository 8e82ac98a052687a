"""The programme model's HiGHS run stops on the work it did, not on the wall clock: on the
effort clock its solution is the same on a slower machine (docs/programme.md, "The fewest
exposures"). A slower machine is played by sleeping in every HiGHS callback, which adds wall
time and no work; a run limited by wall seconds (a multiple of its budget) stops earlier in
its search and keeps another solution."""

from __future__ import annotations

import time
from functools import cache
from pathlib import Path

import numpy as np

from models import clock
from models.budget import Budget
from models.instrument import load_instrument
from service.tables import read_target_table
from solvers import effort
from solvers.programme import optimiser
from solvers.programme.bound import RADIUS_SLACK
from solvers.programme.candidates import maximal_sets
from solvers.programme.crowding import crowding_cells, exclusion_distance_mm
from solvers.programme.fill import Field
from solvers.programme.optimiser import VARIANTS, OptimiserOptions, _model, _Space
from solvers.programme.reach import entry_masks
from solvers.segmentation.field import field_plane

CASE = Path(__file__).parent / "data" / "m67-like-150-vizier.csv"
INST = load_instrument()
#: the model's first budget in a plan at the default limit (0.8 x 8 % of 119.5 s x 0.15)
BUDGET_S = 1.15
#: wall seconds each HiGHS callback sleeps in the "slow machine" run
SLEEP_S = 0.15


@cache
def first_model_inputs():
    rows = read_target_table(str(CASE)).rows()
    ra = np.array([r["ra_deg"] for r in rows])
    dec = np.array([r["dec_deg"] for r in rows])
    R, scale = float(INST.fov_radius_mm), float(INST.plate_scale_arcsec_per_mm)
    ra, dec, _, tangent, xy = field_plane(ra, dec, threshold_mm=None, tangent_point=None, fov_radius_mm=R,
                                          plate_scale_arcsec_per_mm=scale)
    cand = maximal_sets(xy, R * (1.0 + RADIUS_SLACK) + 1e-9)  # as the optimiser
    opts = OptimiserOptions()
    masks = entry_masks(INST, cand, xy, opts.fill.position_angle_deg, opts.fill.park_move_limit_s)
    f = Field(INST, ra, dec, np.ones(len(ra), np.int64))
    space = _Space(f, cand, masks, crowding_cells(xy, exclusion_distance_mm(INST)), tangent)
    return space, len(ra), opts


def solve(slow: bool):
    """The plan's first programme model on the M67-like case, on the effort clock; ``slow``:
    every HiGHS callback sleeps :data:`SLEEP_S` first. Returns the point where the run
    stopped (the callbacks it took) with its solution, the run's wall seconds and the seconds
    it slept. The model is searched whatever its size: the M67-like case's first model holds
    more entries than the plan searches (:data:`optimiser.SEARCH_MAX_ENTRIES`), and the
    property is that of HiGHS's run on the effort clock."""
    space, n, opts = first_model_inputs()
    real, size = effort.HighsMeter.on_callback, optimiser.SEARCH_MAX_ENTRIES
    calls = [0]

    def counted(self, callback_type, data_out):
        if slow:
            time.sleep(SLEEP_S)
        calls[0] += 1
        real(self, callback_type, data_out)

    effort.HighsMeter.on_callback = counted
    optimiser.SEARCH_MAX_ENTRIES = len(space.cand.index)
    try:
        t0 = time.perf_counter()
        with clock.effort(wall_limit_s=120.0):
            cover, _ = _model(space, np.ones(n, bool), opts, VARIANTS[0], Budget.start(BUDGET_S))
        wall_s = time.perf_counter() - t0
    finally:
        effort.HighsMeter.on_callback, optimiser.SEARCH_MAX_ENTRIES = real, size
    key = (calls[0], cover.status, cover.nodes, round(cover.objective, 9), tuple(cover.exposures),
           tuple(cover.owner))
    return key, wall_s, calls[0] * SLEEP_S if slow else 0.0


def test_the_model_keeps_its_solution_on_a_slower_machine() -> None:
    fast, _, _ = solve(slow=False)
    slow, slow_s, slept_s = solve(slow=True)
    assert slow == fast  # the run stopped at the same point of its search, with the same solution ...
    # ... on a machine made slower by its whole budget: the slow run's wall time holds its
    # sleeps, more than the budget, so a run limited by wall seconds would have stopped earlier
    assert slow_s >= slept_s >= BUDGET_S


def _segmentation(optimiser_s: float):
    from service import pipeline
    from service.schemas import SegmentationRequest

    rows = read_target_table(str(CASE)).rows()[:14]
    req = SegmentationRequest.model_validate({"targets": rows, "mode": "fewest-exposures", "seed": 1})
    return pipeline.segment(req, INST, None, optimiser_s)


def test_the_segmentation_says_whether_the_wall_clock_ended_the_optimiser() -> None:
    """Within its budget the optimiser reports the effort seconds it spent; past its
    wall-clock guard (a limit no machine meets), ``overran`` and no effort figure (the
    readings past the guard are not seconds of work)."""
    ample = _segmentation(600.0).stats["optimiser"]
    assert ample["overran"] is False and 0.0 < ample["effort_s"] < 0.8 * 600.0
    cut = _segmentation(1e-6).stats["optimiser"]
    assert cut["overran"] is True and cut["effort_s"] is None
