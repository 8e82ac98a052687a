"""A committed pointing (solvers.programme.fill.commit) is centred on the smallest circle
enclosing the model's targets, unless some of them are then out of every arm's reach and the
model's own centre reaches more: checked with the arms' reach recomputed here
(solvers.programme.reach.arm_masks on focal-plane positions from models.sky)."""

from __future__ import annotations

import numpy as np
import pytest

from models.budget import Budget
from models.instrument import load_instrument
from models.sky import focal_mm_to_sky, sky_to_focal_mm
from solvers.programme import FillOptions, fill
from solvers.programme.reach import arm_masks

INST = load_instrument()
SCALE = float(INST.plate_scale_arcsec_per_mm)
RA0, DEC0 = 150.0, 20.0


def _field(xy_mm: np.ndarray) -> fill.Field:
    ra, dec = focal_mm_to_sky(xy_mm[:, 0], xy_mm[:, 1], RA0, DEC0, SCALE, 0.0)
    return fill.Field(INST, np.asarray(ra, float), np.asarray(dec, float), np.full(len(xy_mm), 10, np.int64))


def _lost(f: fill.Field, idx: np.ndarray, centre: tuple[float, float], pa_deg: float) -> int:
    x, y = sky_to_focal_mm(f.ra_deg[idx], f.dec_deg[idx], centre[0], centre[1], SCALE, pa_deg)
    return int(np.count_nonzero(arm_masks(INST, x, y, 120.0) == 0))


@pytest.mark.parametrize("shift_mm, falls_back", [(0.0, False), (30.0, False), (160.0, True)])
def test_the_pointing_is_about_the_models_centre_when_the_recentred_one_loses_targets(monkeypatch, shift_mm,
                                                                                      falls_back) -> None:
    rng = np.random.default_rng(1)
    xy = rng.uniform(-25.0, 25.0, (10, 2))
    f = _field(xy)
    given = np.arange(10)
    start = (RA0, DEC0)
    moved = focal_mm_to_sky(np.array([shift_mm]), np.array([0.0]), RA0, DEC0, SCALE, 0.0)
    off = (float(moved[0][0]), float(moved[1][0]))
    # the smallest enclosing circle's centre replaced by one ``shift_mm`` away
    monkeypatch.setattr(fill, "recentre", lambda *_: off)
    opts = FillOptions(allocation_cap_s=0.2)
    p = fill.commit(f, np.zeros(10, bool), given, start, np.zeros(10, bool), opts, Budget.start(0.0))
    lost_off = min(_lost(f, given, off, a) for a in fill.POSITION_ANGLES_DEG)
    assert _lost(f, given, start, 0.0) == 0  # the model's centre reaches every target
    assert (lost_off > 0) == falls_back
    if lost_off == 0:  # the recentred centre reaches them at some angle: it is kept
        assert p.centre == off
    else:
        assert p.centre == start and _lost(f, given, p.centre, p.pa_deg) == 0
    assert set(given) <= set(int(i) for i in p.members)
