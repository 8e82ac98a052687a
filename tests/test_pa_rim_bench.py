"""benchmarks/pa_rim.py: its reach oracle and one small run (the full run is the README's)."""

from __future__ import annotations

import json

import numpy as np

from benchmarks import pa_rim
from models.instrument import default_instrument
from solvers.programme.reach import arm_masks

INST = default_instrument()


def test_the_oracle_agrees_with_the_planners_reach_and_the_scan_contains_it() -> None:
    rng = np.random.default_rng(2)
    r = 124.0 * np.sqrt(rng.random(300))
    a = 2 * np.pi * rng.random(300)
    x, y = r * np.cos(a), r * np.sin(a)
    mine = pa_rim.reached(INST, x, y)
    assert np.array_equal(mine, arm_masks(INST, x, y, pa_rim.LIMIT_S) != 0)
    assert 0 < mine.sum() < len(mine)  # the rim holds points no arm reaches at this angle
    anywhere = pa_rim.reached_at_some_angle(INST, x[~mine], y[~mine])
    assert anywhere.any()  # a turn brings some of them within reach


def test_a_small_run_loses_no_target_some_angle_reaches(capsys) -> None:
    assert pa_rim.main(["--fields", "1", "--targets", "40"]) == 0
    out = json.loads(capsys.readouterr().out)
    auto = out["modes"]["auto"]
    assert auto["members"] == 40 and auto["lost_but_reachable"] == 0 and auto["lost_beyond_best_angle"] == 0
    assert set(out["modes"]) == {"auto", "fixed_0"}
