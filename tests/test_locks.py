"""Locks and exclusions (issue 39 item 3) through the API and the CLI: every lock that cannot be
honoured is a 422 naming ``locked[i]`` with why (the oracle of "cannot": ``models.kinematics``
and FCL, directly); honoured locks end on their arm, excluded targets are reported 'excluded';
the post-passes and the motion planner's changes keep a locked target on its arm.

The random-programme property test over every engine is tests/test_locks_property.py."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from models.budget import Budget
from models.collision import fcl_clearance_mm
from models.errors import InputError
from models.instrument import CONFIGURATION_TIME_GOAL_S, default_instrument
from models.kinematics import inverse_fov, positive_turn_move_time_s
from models.locks import TargetLock
from models.types import PlaneTargets
from planner.reassign import Placed, new_configuration
from planner.sequence import SequenceOptions as MotionSequenceOptions
from planner.sequence import _Sequencer
from service.cli import EXIT_INVALID_INPUT, lock_arg, main
from solvers.allocation import allocate
from solvers.allocation.options import AllocationOptions
from solvers.sequencing.options import SequenceOptions

INST = default_instrument()
ARMS = np.arange(INST.n_arms)


def ik_valid(x_mm: float, y_mm: float) -> np.ndarray:
    """(n_arms, 4): which IK branch of which arm reaches (x, y)."""
    return inverse_fov(INST, ARMS[:, None], np.array([[x_mm]]), np.array([[y_mm]])).valid[:, 0, :]


def plane(points: dict[str, tuple[float, float]]) -> list[dict[str, Any]]:
    return [{"id": t, "x_mm": x, "y_mm": y, "priority": 10} for t, (x, y) in points.items()]


POINTS = {"c": (0.0, 0.0), "edge": (120.0, 0.0), "mid": (40.0, 30.0), "far": (-60.0, 50.0)}


def post_allocation(url: str, body: dict[str, Any]) -> httpx.Response:
    base = {"targets": plane(POINTS), "method": "ilp", "solver": "bnb", "configurations": "all",
            "time_limit_s": 10}
    return httpx.post(url + "/v1/allocations", json={**base, **body}, timeout=60)


def loc_and_msg(r: httpx.Response) -> tuple[list[Any], str]:
    assert r.status_code == 422, r.text
    err = r.json()["detail"][0]
    return err["loc"], err["msg"]


def test_an_arm_that_cannot_reach_is_a_422_naming_the_lock(live_server) -> None:
    assert not ik_valid(*POINTS["edge"])[6].any()  # the oracle: arm 6 cannot reach (120, 0)
    loc, msg = loc_and_msg(post_allocation(live_server.url, {
        "locked": [{"target_id": "c", "arm": 2}, {"target_id": "edge", "arm": 6}]}))
    assert loc == ["body", "locked", 1] and "cannot reach" in msg and "arm 6" in msg


def test_a_branch_that_cannot_reach_is_a_422_naming_the_lock(live_server) -> None:
    valid = ik_valid(*POINTS["mid"])
    arm = next(k for k in ARMS if valid[k].any() and not valid[k].all())
    branch = int(np.flatnonzero(~valid[arm])[0])
    loc, msg = loc_and_msg(post_allocation(live_server.url, {
        "locked": [{"target_id": "mid", "arm": int(arm), "branch": branch}]}))
    assert loc == ["body", "locked", 0] and f"not branch {branch}" in msg


@pytest.mark.parametrize("body,where,words", [
    ({"locked": [{"target_id": "nope", "arm": 1}]}, ["locked", 0, "target_id"], "unknown target"),
    ({"locked": [{"target_id": "c", "arm": 1}, {"target_id": "c", "arm": 2}]}, ["locked", 1], "locked twice"),
    ({"locked": [{"target_id": "c", "arm": 1}], "excluded_targets": ["c"]}, ["locked", 0], "both locked and excluded"),
    ({"locked": [{"target_id": "c", "arm": 3}],
      "disabled_arms": [{"arm": 3, "theta1_rad": math.pi, "theta2_rad": 0.0}]}, ["locked", 0], "disabled"),
    ({"locked": [{"target_id": "c", "arm": 12}]}, ["locked", 0, "arm"], ""),
    ({"locked": [{"target_id": "c", "arm": 1, "branch": 4}]}, ["locked", 0, "branch"], ""),
    ({"excluded_targets": ["zz"]}, ["excluded_targets", 0], "unknown target"),
    ({"excluded_targets": ["c", "far", "c"]}, ["excluded_targets", 2], "excluded twice"),
])
def test_each_lock_or_exclusion_that_cannot_be_honoured_is_a_422(live_server, body, where, words) -> None:
    loc, msg = loc_and_msg(post_allocation(live_server.url, body))
    assert loc == ["body", *where] and words in msg


def test_a_lock_onto_a_disabled_arms_body_is_a_422(live_server) -> None:
    """Arm 0 out of service through the FOV centre (theta1 = theta2 = 0, its tip at x = -32 mm):
    arm 6 on a target next to the centre touches it on every branch (FCL says so), so that lock
    is refused."""
    q0 = (0.0, 0.0)
    ik = inverse_fov(INST, 6, np.array([-1.0]), np.array([0.0]))
    qs = [(float(ik.theta1_rad[0, b]), float(ik.theta2_rad[0, b])) for b in np.flatnonzero(ik.valid[0])]
    assert qs and all(fcl_clearance_mm(INST, 6, q, 0, q0) < INST.collision_buffer_mm for q in qs)
    loc, msg = loc_and_msg(post_allocation(live_server.url, {
        "targets": plane({"a": (-1.0, 0.0)}), "locked": [{"target_id": "a", "arm": 6}],
        "disabled_arms": [{"arm": 0, "theta1_rad": 0.0, "theta2_rad": 0.0}]}))
    assert loc == ["body", "locked", 0] and "disabled arm 0" in msg


def beyond_park_limit_point(k: int = 0) -> tuple[float, float, int]:
    """A point arm ``k`` reaches, but only by a move from park longer than T_p (the oracle: IK
    and the positive-turn move time, directly, on a grid of the FOV's rim)."""
    r, a = np.meshgrid(np.arange(118.0, 125.0, 0.1), np.radians(np.arange(0.0, 360.0, 0.25)))
    x, y = (r * np.cos(a)).ravel(), (r * np.sin(a)).ravel()
    ik = inverse_fov(INST, k, x, y)
    t_s = positive_turn_move_time_s(INST.park_configuration[k], np.stack([ik.theta1_rad, ik.theta2_rad], -1),
                                    INST.arms[k].joint1_speed_rad_s, INST.arms[k].joint2_speed_rad_s)
    beyond = np.flatnonzero(ik.valid.any(-1) & ~(ik.valid & (t_s <= CONFIGURATION_TIME_GOAL_S)).any(-1))
    assert len(beyond)
    return float(x[beyond[0]]), float(y[beyond[0]]), k


def test_a_lock_beyond_the_park_move_limit_is_refused() -> None:
    x, y, k = beyond_park_limit_point()
    targets = PlaneTargets.from_lists(["a", "b"], [x, 0.0], [y, 0.0], [1, 1])
    options = AllocationOptions(sequence=SequenceOptions(park_move_limit_s=CONFIGURATION_TIME_GOAL_S))
    with pytest.raises(InputError, match="park move limit") as exc:
        allocate(INST, targets, locked=[TargetLock("b", 0), TargetLock("a", k)], options=options)
    assert exc.value.field == "locked[1]"


def test_locks_and_exclusions_over_the_allocation_api(live_server) -> None:
    """The locked targets end on their arms (each of them one that the allocator does not pick
    unlocked), the excluded one is reported 'excluded' and observed by none."""
    free = post_allocation(live_server.url, {}).json()
    arm_of = {a["target_id"]: a["arm"] for c in free["configurations"] for a in c["assignments"] if a["target_id"]}
    locks = []
    for t in ("c", "mid"):
        other = next(int(k) for k in ARMS if ik_valid(*POINTS[t])[k].any() and k != arm_of[t])
        locks.append({"target_id": t, "arm": other, "branch": None})
    r = post_allocation(live_server.url, {"locked": locks, "excluded_targets": ["far"]})
    assert r.status_code == 200, r.text
    out = r.json()
    got = {a["target_id"]: a["arm"] for c in out["configurations"] for a in c["assignments"] if a["target_id"]}
    assert {lk["target_id"]: got[lk["target_id"]] for lk in locks} == {lk["target_id"]: lk["arm"] for lk in locks}
    assert "far" not in got and {"target_id": "far", "reason": "excluded"} in out["unallocated"]


def test_the_post_passes_keep_locked_targets_on_their_arms() -> None:
    """A dense field to completeness with every post-pass on (rescue, repair, repacking): each
    locked target, put on an arm the unlocked sequence does not use for it, stays there."""
    rng = np.random.default_rng(7)
    n = 40
    xy = rng.normal(0.0, 45.0, (n, 2))
    xy = xy[np.hypot(xy[:, 0], xy[:, 1]) < 110]
    ids = [f"t{i}" for i in range(len(xy))]
    targets = PlaneTargets.from_lists(ids, xy[:, 0], xy[:, 1], rng.choice([500, 100, 10, 1], len(xy)))
    free = allocate(INST, targets, configurations="all", time_limit_s=8.0, seed=1)
    arm_of = {a.target_id: a.arm for c in free.configurations for a in c.assignments if a.target_id}
    locks = []
    for i in range(0, len(ids), 5):
        others = [int(k) for k in ARMS if ik_valid(*xy[i])[k].any() and k != arm_of.get(ids[i])]
        if others:
            locks.append(TargetLock(ids[i], others[len(others) // 2]))
    assert len(locks) >= 5
    r = allocate(INST, targets, configurations="all", time_limit_s=8.0, seed=1, locked=locks)
    got = {a.target_id: a.arm for c in r.configurations for a in c.assignments if a.target_id}
    reasons = {u.target_id: u.reason for u in r.unallocated}
    for lk in locks:
        assert got.get(lk.target_id, lk.arm) == lk.arm
        assert lk.target_id in got or reasons[lk.target_id].startswith("locked_")
    assert sum(lk.target_id in got for lk in locks) >= len(locks) - 1


def test_the_motion_planners_move_keeps_a_locked_target_on_its_arm() -> None:
    """A target the motion planner takes out of a configuration goes to another configuration
    on another arm than the one it left (planner.sequence.place_pending); locked, it goes back
    to its own arm."""
    x, y = 30.0, 20.0
    reach = [int(k) for k in ARMS if ik_valid(x, y)[k].any()]
    lock_arm = reach[0]
    placed = Placed("a", 0, x, y, 10, from_arm=lock_arm)

    def place(locked: tuple[tuple[str, int, int | None], ...]) -> int:
        seq = _Sequencer(INST, [new_configuration(INST, 0)], MotionSequenceOptions(locked=locked), {"a": 10},
                         Budget.start(30.0))
        seq.pending = [placed]
        seq.place_pending(-1)
        return next(a.arm for c in seq.configs for a in c.assignments if a.target_id == "a")

    assert place(()) != lock_arm  # unlocked: moved to another arm
    assert place((("a", lock_arm, None),)) == lock_arm


def test_lock_arguments() -> None:
    assert lock_arg("s1:4") == {"target_id": "s1", "arm": 4, "branch": None}
    assert lock_arg("s1:4:2") == {"target_id": "s1", "arm": 4, "branch": 2}
    assert lock_arg("NGC:869:4") == {"target_id": "NGC", "arm": 869, "branch": 4}  # arm 869 -> 422 later
    assert lock_arg("a:b:4") == {"target_id": "a:b", "arm": 4, "branch": None}
    with pytest.raises(Exception, match="TARGET:ARM"):
        lock_arg("s1")


def sky_rows() -> list[dict[str, Any]]:
    rng = np.random.default_rng(3)
    n = 12
    ra = 10 + rng.uniform(-1.2, 1.2, n) / 60 / math.cos(math.radians(30))
    dec = -30 + rng.uniform(-1.2, 1.2, n) / 60
    return [{"id": f"s{i}", "ra_deg": float(ra[i]), "dec_deg": float(dec[i]), "priority": int(p)}
            for i, p in enumerate(rng.choice([500, 100, 10, 1], n))]


def focal_reach() -> dict[str, np.ndarray]:
    """Each target's IK reach in its pointing, as the plan projects it (its segmentation is
    deterministic for the request)."""
    from planner.programme import RoundTask
    from service import pipeline, pointing_plans
    from service.schemas import PlanRequest

    req = PlanRequest(targets=sky_rows(), time_limit_s=30, seed=1)
    seg = pipeline.segment_plan(req, INST, 30)
    out = {}
    for i in range(len(seg.pointings)):
        task = pointing_plans.pointing_task(req, seg, RoundTask(i, 1, 0.0))
        p = task.pointing
        tg = pointing_plans.sky_plane_targets(task.members, p.ra_deg % 360, p.dec_deg, INST, task.position_angle_deg)
        for t, x, y in zip(tg.ids, tg.x_mm, tg.y_mm, strict=True):
            out[t] = ik_valid(float(x), float(y))
    return out


def test_a_plan_honours_locks_and_exclusions_and_refuses_an_unreachable_lock(live_server) -> None:
    reach = focal_reach()
    locks = [{"target_id": t, "arm": int(np.flatnonzero(reach[t].any(axis=1))[-1]), "branch": None}
             for t in ("s0", "s1", "s2")]
    body = {"targets": sky_rows(), "time_limit_s": 30, "seed": 1, "locked": locks, "excluded_targets": ["s5"]}
    r = httpx.post(live_server.url + "/v1/plans", json=body, timeout=120)
    assert r.status_code == 200, r.text
    plan = r.json()
    for p in plan["pointings"]:
        for c in p["configurations"]:
            for a in c["assignments"]:
                assert a["target_id"] != "s5"
                for lk in locks:
                    if a["target_id"] == lk["target_id"]:
                        assert a["arm"] == lk["arm"]
        for u in p["unallocated"]:
            assert u["target_id"] not in {lk["target_id"] for lk in locks} or u["reason"].startswith("locked_")
    assert plan["unallocated"] == [{"target_id": "s5", "reason": "excluded"}]
    assert plan["stats"]["unallocated_by_reason"]["excluded"] == 1 and plan["stats"]["targets"] == 12
    far = next(t for t in reach if not reach[t][0].any() and t not in ("s0", "s1", "s2", "s5"))
    bad = {**body, "locked": [*locks, {"target_id": far, "arm": 0}]}
    loc, msg = loc_and_msg(httpx.post(live_server.url + "/v1/plans", json=bad, timeout=120))
    assert loc == ["body", "locked", 3] and "arm 0 cannot reach" in msg


def test_cli_lock_and_exclude_flags(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    reach = focal_reach()
    csv = tmp_path / "t.csv"
    csv.write_text("id,ra_deg,dec_deg,priority\n" + "".join(
        f"{r['id']},{r['ra_deg']!r},{r['dec_deg']!r},{r['priority']}\n" for r in sky_rows()))
    arm = int(np.flatnonzero(reach["s1"].any(axis=1))[0])
    out = tmp_path / "out"
    code = main(["plan", str(csv), "--out", str(out), "--time-limit", "10", "--seed", "1", "--quiet",
                 "--lock", f"s1:{arm}", "--exclude", "s5", "--exclude", "s6"])
    assert code in (0, 4), capsys.readouterr().err
    plan = json.loads((out / "plan.json").read_text())
    arms = {a["target_id"]: a["arm"] for p in plan["pointings"] for c in p["configurations"]
            for a in c["assignments"] if a["target_id"]}
    assert arms["s1"] == arm and "s5" not in arms and "s6" not in arms
    assert {u["target_id"] for u in plan["unallocated"]} == {"s5", "s6"}
    # a target arm 0 cannot reach from the field's own pointing: the segmentation places its
    # pointing where arm 0 reaches it (tests/test_locks_segmentation.py)
    far = next(t for t in reach if not reach[t][0].any())
    code = main(["plan", str(csv), "--out", str(tmp_path / "far"), "--time-limit", "10", "--seed", "1",
                 "--quiet", "--lock", f"{far}:0"])
    assert code in (0, 4), capsys.readouterr().err
    plan = json.loads((tmp_path / "far" / "plan.json").read_text())
    assert {a["arm"] for p in plan["pointings"] for c in p["configurations"] for a in c["assignments"]
            if a["target_id"] == far} == {0}
    code = main(["plan", str(csv), "--out", str(tmp_path / "bad"), "--time-limit", "30", "--quiet",
                 "--lock", "nobody:0"])
    assert code == EXIT_INVALID_INPUT
    assert "locked[0]" in capsys.readouterr().err


def test_a_plan_job_with_a_bad_exclusion_or_lock_is_refused_at_submission(live_server) -> None:
    for request, where in (({"excluded_targets": ["s0", "zz"]}, ["excluded_targets", 1]),
                           ({"locked": [{"target_id": "s0", "arm": 1}, {"target_id": "s0", "arm": 2}]},
                            ["locked", 1]),
                           ({"excluded_targets": [r["id"] for r in sky_rows()]}, ["excluded_targets"])):
        r = httpx.post(live_server.url + "/v1/jobs", json={"kind": "plan", "request": {
            "targets": sky_rows(), **request}}, timeout=60)
        loc, _ = loc_and_msg(r)
        assert loc[-len(where):] == where and "request" in loc


@pytest.mark.parametrize("method,solver", [("ilp", "highs"), ("ilp", "cpsat"), ("ilp", "bnb"), ("semigreedy", "bnb")])
def test_a_locked_target_takes_precedence_over_a_higher_priority_one(method: str, solver: str) -> None:
    """Two targets 1 mm apart (no two arms fit on them at once): one configuration observes
    the priority-500 one, unless the priority-1 one is locked (it then weighs 1 + 500)."""
    targets = PlaneTargets.from_lists(["low", "high"], [0.0, 1.0], [0.0, 0.0], [1, 500])
    assert ik_valid(0.0, 0.0)[3].any()
    free = allocate(INST, targets, method=method, solver=solver, time_limit_s=5.0)
    locked = allocate(INST, targets, method=method, solver=solver, time_limit_s=5.0, locked=[TargetLock("low", 3)])
    observed = [{a.target_id: a.arm for a in r.configurations[0].assignments if a.target_id} for r in (free, locked)]
    assert list(observed[0]) == ["high"]
    assert observed[1] == {"low": 3}
    assert locked.configurations[0].total_priority == 1  # reported with its own priority


def test_an_allocation_job_with_a_lock_that_cannot_be_honoured_is_refused_at_submission(live_server) -> None:
    body = {"targets": plane(POINTS), "configurations": "all", "locked": [{"target_id": "edge", "arm": 6}]}
    loc, msg = loc_and_msg(httpx.post(live_server.url + "/v1/jobs", json={"kind": "allocation", "request": body},
                                      timeout=60))
    assert loc[-2:] == ["locked", 0] and "request" in loc and "cannot reach" in msg
