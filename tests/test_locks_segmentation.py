"""Locks reach the programme's segmentation: a locked target's pointing and position angle
are ones where its own arm reaches it within the park move limit.

The oracle is the kinematics alone: every IK branch of the locked arm
(:func:`models.kinematics.inverse_fov`) and its move time from park turning J2 the positive
way (:func:`models.kinematics.positive_turn_move_time_s`), on the target projected about the
pointing the segmentation returns (:func:`models.sky.sky_to_focal_mm`)."""

from __future__ import annotations

import numpy as np
import pytest

from models.instrument import CONFIGURATION_TIME_GOAL_S, default_instrument
from models.kinematics import inverse_fov, positive_turn_move_time_s
from models.locks import TargetLock, arm_limits
from models.sky import sky_to_focal_mm
from solvers.programme.angle import AngleSearch
from solvers.programme.fill import FillOptions
from solvers.programme.segment import segment_programme

INST = default_instrument()
RNG = np.random.default_rng(3)
N = 30
RA = 150.0 + RNG.normal(0.0, 0.6 / 60.0, N)  # a cluster of 0.6' (about 30 mm) rms
DEC = 20.0 + RNG.normal(0.0, 0.6 / 60.0, N)
PRIORITY = np.array([500] * 3 + [100] * 12 + [10] * 12 + [1] * 3)
IDS = [f"t{i}" for i in range(N)]


def arm_reaches(arm: int, x_mm: float, y_mm: float) -> bool:
    """Arm ``arm`` reaches (x, y) on some IK branch within the park move limit."""
    ik = inverse_fov(INST, arm, np.array([x_mm]), np.array([y_mm]))
    park = np.asarray(INST.park_configuration[arm], float)
    speed = INST.max_joint_speed_rad_s
    for b in np.flatnonzero(ik.valid[0]):
        q = np.array([ik.theta1_rad[0, b], ik.theta2_rad[0, b]])
        if float(positive_turn_move_time_s(park, q, speed, speed)) <= CONFIGURATION_TIME_GOAL_S + 1e-9:
            return True
    return False


def located(seg, j: int) -> tuple[float, float]:
    """Target ``j`` on the focal plane of its pointing in ``seg``, at that pointing's angle."""
    p = next(p for p in seg.pointings if j in p.target_indices)
    x, y = sky_to_focal_mm(RA[j:j + 1], DEC[j:j + 1], p.ra_deg, p.dec_deg,
                           float(INST.plate_scale_arcsec_per_mm), p.position_angle_deg or 0.0)
    return float(x[0]), float(y[0])


@pytest.fixture(scope="module")
def unlocked():
    return segment_programme(INST, RA, DEC, PRIORITY, mode="fewest-exposures", fill=FillOptions())


@pytest.mark.parametrize("search", [None, AngleSearch()], ids=["requested-angle", "auto"])
@pytest.mark.parametrize("target, arm", [(1, 3), (1, 0), (0, 6)])
def test_a_locked_targets_pointing_lets_its_arm_reach_it(unlocked, target, arm, search) -> None:
    # without the lock the segmentation puts the target where that arm cannot reach it
    assert not arm_reaches(arm, *located(unlocked, target))
    limits = arm_limits(IDS, [TargetLock(IDS[target], arm)], INST.n_arms)
    seg = segment_programme(INST, RA, DEC, PRIORITY, mode="fewest-exposures",
                            fill=FillOptions(arm_limits=limits, angle_search=search))
    assert sorted(i for p in seg.pointings for i in p.target_indices) == list(range(N))
    assert arm_reaches(arm, *located(seg, target))


def test_arm_limits_are_the_locked_arms_bit_or_every_arm() -> None:
    assert arm_limits(IDS[:3], None, 12) is None
    assert arm_limits(IDS[:3], [TargetLock("t1", 4), TargetLock("elsewhere", 2)], 12) == (4095, 1 << 4, 4095)
