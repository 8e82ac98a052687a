"""Spare arms (solvers.programme.spare): whether a target fits into an exposure as it is, and
the plan's `only_here` on exposures observing few targets.

Oracle: a brute force over every idle arm and every IK branch (models.kinematics.inverse_fov),
the move from park within the limit (positive_turn_move_time_s) and FCL clearances against
every other arm of the configuration, on configurations a real allocation built."""

from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.collision import fcl_clearance_mm
from models.instrument import default_instrument
from models.kinematics import inverse_fov, positive_turn_move_time_s, tip_fov
from models.types import PlaneTargets
from service.app import create_app
from service.settings import Settings
from solvers.allocation import allocate
from solvers.programme.spare import (
    NO_SPARE_ARM,
    NOWHERE_ELSE,
    OUTSIDE_OTHER_FIELDS,
    TAKERS_OBSERVE_FEWER,
    Exposure,
    explained,
    only_here,
    spare_arm_for,
    takers,
)

INST = default_instrument()
LIMIT_S = 120.0
V1 = INST.arm_array("joint1_speed_rad_s")
V2 = INST.arm_array("joint2_speed_rad_s")
#: capsule and FCL clearances agree to far less; a point this close to the buffer is not judged
EDGE_MM = 1e-6


@functools.cache
def _configurations(seed: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    xy = rng.normal(0.0, 45.0, (40, 2))
    targets = PlaneTargets(tuple(f"t{i}" for i in range(40)), xy[:, 0], xy[:, 1], np.ones(40, np.int64))
    result = allocate(INST, targets, configurations="all", time_limit_s=20.0, seed=seed)
    qs, idles = [], []
    for c in result.configurations:
        arms = sorted(c.assignments, key=lambda a: a.arm)
        qs.append(np.array([[a.theta1_rad, a.theta2_rad] for a in arms]))
        idles.append(np.array([a.kind in ("park", "blank") for a in arms]))
    return qs, idles


def _brute_force(q: np.ndarray, idle: np.ndarray, x: float, y: float) -> tuple[bool, bool]:
    """(fits, on the edge): some idle arm and branch reaches (x, y) within the limit with every
    FCL clearance at least the buffer; on the edge when the deciding clearance is within EDGE_MM."""
    fits, edge = False, False
    for k in np.flatnonzero(idle):
        ik = inverse_fov(INST, int(k), np.array([x]), np.array([y]))
        for b in range(4):
            if not ik.valid[0, b]:
                continue
            pose = (float(ik.theta1_rad[0, b]), float(ik.theta2_rad[0, b]))
            assert np.allclose(tip_fov(INST, int(k), *pose), (x, y), atol=1e-6)
            if positive_turn_move_time_s(INST.park_configuration[k], np.array(pose), V1[k], V2[k]) > LIMIT_S:
                continue
            worst = min(fcl_clearance_mm(INST, int(k), pose, j, tuple(q[j])) for j in range(INST.n_arms) if j != k)
            edge |= abs(worst - INST.collision_buffer_mm) < EDGE_MM
            fits |= worst >= INST.collision_buffer_mm
    return fits, edge


@pytest.mark.parametrize("seed", [3, 4])
def test_spare_arm_for_agrees_with_a_brute_force_with_fcl(seed: int) -> None:
    qs, idles = _configurations(seed)
    rng = np.random.default_rng(100 + seed)
    fits = 0
    checked = 0
    for q, idle in zip(qs, idles, strict=True):
        for _ in range(6):
            r, a = 110.0 * math.sqrt(rng.random()), 2 * math.pi * rng.random()
            x, y = r * math.cos(a), r * math.sin(a)
            want, edge = _brute_force(q, idle, x, y)
            if edge:
                continue
            got = spare_arm_for(INST, q, idle, x, y, LIMIT_S)
            assert (got is not None) == want, (x, y)
            if got is not None:
                k, t1, t2 = got
                assert idle[k] and np.allclose(tip_fov(INST, k, t1, t2), (x, y), atol=1e-6)
                assert min(fcl_clearance_mm(INST, k, (t1, t2), j, tuple(q[j]))
                           for j in range(INST.n_arms) if j != k) >= INST.collision_buffer_mm
            fits += want
            checked += 1
    assert checked >= 20 and 0 < fits < checked  # both answers occur


def test_takers_is_spare_arm_for_on_every_configuration_at_once() -> None:
    qs, idles = _configurations(5)
    q, idle = np.stack(qs), np.stack(idles)
    for x, y in [(0.0, 0.0), (60.0, -20.0), (-90.0, 40.0), (15.0, 100.0)]:
        one = np.array([spare_arm_for(INST, qq, ii, x, y, LIMIT_S) is not None for qq, ii in zip(qs, idles, strict=True)])
        assert np.array_equal(takers(INST, q, idle, x, y, LIMIT_S), one)


def test_only_here_gives_the_reasons_it_can_prove() -> None:
    """Three exposures at one pointing and one far away: the far exposure's target is outside
    every other field; a target whose other exposures have no idle arm has no spare arm; a
    target another exposure can take is not listed."""
    park = INST.park_configuration
    scale = INST.plate_scale_arcsec_per_mm / 3600.0  # deg per mm
    ra = np.array([10.0, 10.0 + 20 * scale, 11.0])
    dec = np.array([20.0, 20.0, 20.0])
    all_idle, none_idle = np.ones(INST.n_arms, bool), np.zeros(INST.n_arms, bool)
    e = [Exposure(10.0, 20.0, 0.0, park, all_idle, (0,)),
         Exposure(10.0, 20.0, 0.0, park, all_idle, (1,)),
         Exposure(11.0, 20.0, 0.0, park, all_idle, (2,))]
    got = only_here(INST, ra, dec, e, LIMIT_S)
    assert got == {2: {2: OUTSIDE_OTHER_FIELDS}}  # targets 0 and 1 fit in each other's exposure
    assert explained(INST, ra, dec, e, LIMIT_S) == (got, {0: {0: 1}, 1: {1: 0}})  # and where
    e[1] = Exposure(10.0, 20.0, 0.0, park, none_idle, (1,))
    got = only_here(INST, ra, dec, e, LIMIT_S)
    assert got == {0: {0: NO_SPARE_ARM}, 2: {2: OUTSIDE_OTHER_FIELDS}}
    assert explained(INST, ra, dec, e, LIMIT_S) == (got, {1: {1: 0}})


def test_only_here_says_when_only_exposures_of_fewer_targets_can_take_one() -> None:
    """An exposure of two targets that only an exposure observing one can take (moving one
    there leaves as many exposures of few targets): both listed as such; once that exposure
    observes two, neither is listed (it could take them)."""
    park = INST.park_configuration
    scale = INST.plate_scale_arcsec_per_mm / 3600.0  # deg per mm
    ra = np.array([10.0, 10.0 + 20 * scale, 10.0 - 30 * scale, 12.0, 10.0 + 50 * scale])
    dec = np.full(5, 20.0)
    all_idle, none_idle = np.ones(INST.n_arms, bool), np.zeros(INST.n_arms, bool)
    e = [Exposure(10.0, 20.0, 0.0, park, none_idle, (0, 1)),
         Exposure(10.0, 20.0, 0.0, park, all_idle, (2,)),
         Exposure(12.0, 20.0, 0.0, park, all_idle, (3,))]
    got = only_here(INST, ra, dec, e, LIMIT_S)
    assert got == {0: {0: TAKERS_OBSERVE_FEWER, 1: TAKERS_OBSERVE_FEWER}, 1: {2: NO_SPARE_ARM},
                   2: {3: OUTSIDE_OTHER_FIELDS}}
    assert explained(INST, ra, dec, e, LIMIT_S)[1] == {}  # every target is listed
    e[1] = Exposure(10.0, 20.0, 0.0, park, all_idle, (2, 4))  # observes two
    got = only_here(INST, ra, dec, e, LIMIT_S)
    assert 0 not in got and got[1] == {2: NO_SPARE_ARM, 4: NO_SPARE_ARM}
    assert explained(INST, ra, dec, e, LIMIT_S)[1] == {0: {0: 1, 1: 1}}  # exposure 1 could take them
    assert NOWHERE_ELSE == {OUTSIDE_OTHER_FIELDS, NO_SPARE_ARM}


def test_a_plan_says_which_targets_of_a_small_exposure_no_other_can_take(tmp_path) -> None:
    """A lone star 1 deg from a small group: its pointing's one exposure observes it alone, and
    the plan says that no other exposure's field holds it."""
    targets = [{"id": f"g{i}", "ra_deg": 150.0 + 0.004 * i, "dec_deg": 2.0, "priority": 10} for i in range(5)]
    targets.append({"id": "lone", "ra_deg": 151.0, "dec_deg": 2.0, "priority": 10})
    c = TestClient(create_app(Settings(job_db=tmp_path / "j.sqlite3")))
    r = c.post("/v1/plans", json={"targets": targets, "seed": 1, "time_limit_s": 30})
    assert r.status_code == 200, r.text
    plan = r.json()
    few = {(f["pointing_id"], f["configuration"]): f for f in plan["few_target_exposures"]}
    lone = [(p["id"], cfg["index"]) for p in plan["pointings"] for cfg in p["configurations"]
            if any(a["target_id"] == "lone" for a in cfg["assignments"])]
    assert len(lone) == 1 and few[lone[0]]["only_here"] == [{"target_id": "lone", "reason": "outside_other_fields"}]
    expected = {}
    for p in plan["pointings"]:
        for cfg in p["configurations"]:
            observed = [a["target_id"] for a in cfg["assignments"] if a["target_id"] is not None]
            if 0 < len(observed) <= 2:
                expected[(p["id"], cfg["index"])] = observed
    assert {k: f["target_ids"] for k, f in few.items()} == expected
    assert all({o["target_id"] for o in f["only_here"]} <= set(f["target_ids"]) for f in few.values())


def test_the_plan_and_the_cli_count_the_exposures_observing_few_targets(tmp_path, capsys) -> None:
    """The plan's stats count its exposures observing at most 2 targets and those explained by
    `only_here`; the CLI prints them beside the proven bound."""
    from service.cli import main

    rows = ["id,ra_deg,dec_deg,priority"] + [f"g{i},{150.0 + 0.004 * i},2.0,10" for i in range(5)]
    rows.append("lone,151.0,2.0,10")
    src = tmp_path / "few.csv"
    src.write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    assert main(["plan", str(src), "--out", str(out), "--seed", "1", "--time-limit", "30", "--quiet"]) == 0
    printed = capsys.readouterr().out
    plan = json.loads((out / "plan.json").read_text())
    s = plan["stats"]
    few = plan["few_target_exposures"]
    explained = [f for f in few if {o["target_id"] for o in f["only_here"]} >= set(f["target_ids"])]
    nowhere = [f for f in few
               if {o["target_id"] for o in f["only_here"] if o["reason"] in NOWHERE_ELSE} >= set(f["target_ids"])]
    assert s["few_target_exposures"] == len(few) >= 1
    assert s["few_target_exposures_only_here"] == len(nowhere) >= 1
    assert s["few_target_exposures_explained"] == len(explained) >= len(nowhere)
    assert (f"proven lower bound {s['exposures_lower_bound']}" in printed
            and f"{len(few)} exposure" in printed and f"{len(nowhere)} of them only for" in printed)


@pytest.mark.parametrize("seed", [5])
def test_the_clearance_prefilter_keeps_the_capsule_answer(seed: int) -> None:
    """Which configurations an idle arm's pose clears (the capsule test computed only for the
    body pairs whose midpoint bound is below the buffer) is the full capsule test's
    (:func:`models.collision.arm_pair_clearance_mm` on every other arm), with the bodies
    given or not."""
    from models.collision import arm_pair_clearance_mm
    from solvers.programme.spare import _options, bodies_of

    rng = np.random.default_rng(400 + seed)
    qs, idles = _configurations(seed)
    q, idle = np.stack(qs), np.stack(idles)
    checked, refused = 0, 0
    for _ in range(16):
        x, y = rng.normal(0.0, 45.0, 2)
        given = list(_options(INST, q, idle, x, y, None, None, bodies_of(INST, q)))
        plain = list(_options(INST, q, idle, x, y, None, None))
        assert len(given) == len(plain)
        for (k, pose, ok), (k2, pose2, ok2) in zip(plain, given, strict=True):
            others = np.array([j for j in range(INST.n_arms) if j != k])
            full = np.array([np.all(arm_pair_clearance_mm(INST, np.full(len(others), k), np.broadcast_to(pose, (len(others), 2)),
                                                          others, q[e, others]) >= INST.collision_buffer_mm)
                             for e in range(len(q))])
            assert np.array_equal(ok, idle[:, k] & full)
            assert k2 == k and np.array_equal(ok2, ok) and np.array_equal(pose2, pose)
            checked += int(idle[:, k].sum())
            refused += int((idle[:, k] & ~full).sum())
    assert checked > 0 and 0 < refused < checked  # both answers occur
