"""The position angle search refines between its grid angles when they all lose members
(solvers.programme.angle.refined_angles): several rim members can leave an arc of angles that
reaches them all narrower than the grid step.

Oracle: benchmarks/pa_rim.py's reach (IK of every arm and branch, the move from park within
the limit), independent of the planner's reach tables, scanned every 0.5 deg."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import pa_rim
from benchmarks.motion_fields import thesis_field
from models.instrument import default_instrument
from models.sky import focal_mm_to_sky, sky_to_focal_mm
from solvers.programme import angle as angle_mod
from solvers.programme.angle import AngleSearch, choose_angle, refined_angles
from solvers.programme.fill import Field, FillOptions, position_angle

INST = default_instrument()
CENTRE = (150.0, 2.0)
#: thesis fields (100 targets, seed 1) whose 5 deg grid loses a rim member at every angle while
#: an angle between two grid angles reaches every member
NARROW = (11, 16, 24)


def _field(i: int):
    _, t = thesis_field(100, 1, i)
    ra, dec = focal_mm_to_sky(t.x_mm, t.y_mm, CENTRE[0], CENTRE[1], 1.2)
    return t, ra, dec


def _lost(ra, dec, pa: float) -> int:
    x, y = sky_to_focal_mm(ra, dec, CENTRE[0], CENTRE[1], 1.2, pa)
    return int((~pa_rim.reached(INST, x, y)).sum())


@pytest.mark.parametrize("i", NARROW)
def test_auto_finds_the_narrow_arc_the_grid_misses(i: int, monkeypatch) -> None:
    t, ra, dec = _field(i)
    assert all(_lost(ra, dec, a) >= 1 for a in AngleSearch().angles())  # every grid angle loses one
    assert pa_rim.fewest_lost(INST, t.x_mm, t.y_mm) == 0  # some angle loses none
    c = choose_angle(INST, ra, dec, t.priority, CENTRE, AngleSearch(), pa_rim.LIMIT_S)
    assert 0.0 <= c.chosen_deg < 360.0 and _lost(ra, dec, c.chosen_deg) == 0
    assert len(c.tried_deg) > len(AngleSearch().angles())
    monkeypatch.setattr(angle_mod, "refined_angles", lambda *a, **k: ())
    plain = choose_angle(INST, ra, dec, t.priority, CENTRE, AngleSearch(), pa_rim.LIMIT_S)
    assert _lost(ra, dec, plain.chosen_deg) == 1


@pytest.mark.parametrize("i", NARROW)
def test_the_requested_angle_turns_into_the_narrow_arc_too(i: int) -> None:
    t, ra, dec = _field(i)
    f = Field(INST, np.asarray(ra), np.asarray(dec), t.priority)
    pa, lost = position_angle(f, np.arange(len(ra)), CENTRE, FillOptions())
    assert lost[pa] == 0 and _lost(ra, dec, pa) == 0


def test_refined_angles_stay_in_the_range_and_skip_what_was_tried() -> None:
    got = refined_angles([10.0, 12.5], 5.0, 8.0, 13.0, (10.0, 15.0))
    assert got == (8.0, 8.5, 9.0, 9.5, 10.5, 11.0, 11.5, 12.0, 12.5, 13.0)
    assert all(8.0 <= a <= 13.0 for a in got) and 10.0 not in got
