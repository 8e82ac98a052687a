"""A leg through park (planner.sequence.via_park_leg) is two legs, start -> park and
park -> goal, each with the planner's stops, and one more rest at park: the validator allows
exactly that (planner.validate.allowed_stops), so a plan the planner verified is valid.

The leg is one the planner made (tests/data/via_park_leg.json: a crowded two-clump programme
at the plan defaults): the planner's verifier accepts it, and the validator's own stop counter
(a rest or a change of velocity is a stop) finds an arm stopping in each half and at park."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from models.instrument import default_instrument
from models.types import ArmTrajectory
from planner.validate import MAX_STOPS, _stop_count, allowed_stops
from planner.verify import verify_trajectories

INST = default_instrument()
LEG = json.loads((Path(__file__).parent / "data" / "via_park_leg.json").read_text())


def _trajectories() -> list[ArmTrajectory]:
    out = []
    for tr in LEG["trajectories"]:
        w = tr["waypoints"]
        out.append(ArmTrajectory(int(tr["arm"]), np.array([p["t_s"] for p in w]),
                                 np.array([p["theta1_rad"] for p in w]), np.array([p["theta2_rad"] for p in w])))
    return out


def test_a_leg_through_park_stops_in_each_half_and_at_park_and_is_valid() -> None:
    trajs = _trajectories()
    report = verify_trajectories(INST, trajs, np.array(LEG["start_q"]), np.array(LEG["goal_q"]), max_start_stop=None)
    assert not report.violations  # the planner's verifier accepts the leg
    stops = [_stop_count(t.t_s, np.column_stack([t.theta1_rad, t.theta2_rad])) for t in trajs]
    assert max(stops) == 2 * MAX_STOPS + 1
    assert max(stops) > allowed_stops(via_park=False) + 1  # more than a direct leg and a rest at park
    assert all(s <= allowed_stops(via_park=True) for s in stops)
