"""keep_configurations (issue 39): c1..ck of a previous plan kept as they were, the rest
planned again from ck's arm states, through the pipeline, the API and the CLI.

The oracles are independent of the keeping code: the previous plan's own JSON (kept
configurations compared field by field), the trajectory verifier re-run on every leg of the
answer from its JSON way-points, the geometry of models.kinematics for tampered
configurations, and the request's targets (each observed at most once, none lost)."""

from __future__ import annotations

import copy
import csv
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.budget import Budget
from models.instrument import default_instrument
from models.kinematics import Links, in_zoa, inverse_fov
from models.sky import focal_mm_to_sky
from models.types import ArmTrajectory, Configuration, MotionPlan
from planner import pointing, programme
from planner.keep import KeptArm, KeptPointing, kept_configurations
from planner.reassign import Placed, new_configuration, try_place
from planner.sequence import SequenceOptions, _Sequencer
from planner.verify import verify_trajectories
from service import pipeline
from service.app import create_app
from service.cli import main
from service.cli_keep import keep_arg, keep_from_plan
from service.schemas import PlanRequest
from service.settings import Settings

INST = default_instrument()
TWO_PI = 2 * math.pi
LIMIT_S = 40.0


def field_targets(n: int = 30, seed: int = 3, centre: tuple[float, float] = (150.0, 20.0)) -> list[dict[str, Any]]:
    """``n`` targets spread over one FOV about ``centre``."""
    rng = np.random.default_rng(seed)
    r, a = 100 * np.sqrt(rng.random(n)), TWO_PI * rng.random(n)
    ra, dec = focal_mm_to_sky(r * np.cos(a), r * np.sin(a), *centre, INST.plate_scale_arcsec_per_mm)
    return [{"id": f"t{seed}_{i}", "ra_deg": float(x), "dec_deg": float(y), "priority": 1 + i % 3}
            for i, (x, y) in enumerate(zip(ra, dec, strict=True))]


TARGETS = field_targets()


def plan(targets: list[dict[str, Any]], seed: int, keep: dict[str, Any] | None = None) -> dict[str, Any]:
    return pipeline.plan(PlanRequest(targets=targets, seed=seed, time_limit_s=LIMIT_S,
                                     keep_configurations=keep), INST)


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """One server for the module's API calls (its request workers start once)."""
    with TestClient(create_app(Settings(job_db=tmp_path_factory.mktemp("keep") / "j.db"))) as c:
        yield c


@pytest.fixture(scope="module")
def base() -> dict[str, Any]:
    out = plan(TARGETS, seed=1)
    assert out["executable"] and len(out["pointings"]) == 1
    assert len(out["pointings"][0]["configurations"]) >= 2
    return out


# ----------------------------------------------------------------------- oracles


def assert_same_configuration(old: dict[str, Any], new: dict[str, Any]) -> None:
    """Same arms, targets and joint angles (exactly), tips to 1e-9 mm."""
    assert [a["arm"] for a in new["assignments"]] == [a["arm"] for a in old["assignments"]]
    for a, b in zip(old["assignments"], new["assignments"], strict=True):
        assert b["target_id"] == a["target_id"]
        assert (b["theta1_rad"], b["theta2_rad"]) == (a["theta1_rad"], a["theta2_rad"])
        assert abs(b["x_mm"] - a["x_mm"]) <= 1e-9 and abs(b["y_mm"] - a["y_mm"]) <= 1e-9


def q_of(config: dict[str, Any]) -> np.ndarray:
    return np.array([[a["theta1_rad"], a["theta2_rad"]] for a in config["assignments"]])


def legs_verified(p: dict[str, Any]) -> None:
    """Every leg park -> c1 -> ... -> park re-verified from its JSON way-points."""
    park = INST.park_configuration
    ends = [park] + [q_of(c) for c in p["configurations"]] + [park]
    assert len(p["motions"]) == len(ends) - 1
    for i, m in enumerate(p["motions"]):
        assert m["status"] == "ok", (i, m["failed_arms"])
        trajs = [ArmTrajectory(t["arm"], np.array([w["t_s"] for w in t["waypoints"]]),
                               np.array([w["theta1_rad"] for w in t["waypoints"]]),
                               np.array([w["theta2_rad"] for w in t["waypoints"]]))
                 for t in m["trajectories"]]
        report = verify_trajectories(INST, trajs, ends[i], ends[i + 1], max_start_stop=None)
        assert report.ok, (i, report.violations[:3])


def observed(p: dict[str, Any], configs: slice = slice(None)) -> list[str]:
    return [a["target_id"] for c in p["configurations"][configs] for a in c["assignments"]
            if a["target_id"] is not None]


# ------------------------------------------------------------------ the pipeline


def test_keep_c1_and_replan_the_rest_from_its_arm_states(base, monkeypatch) -> None:
    calls: list[tuple[tuple[str, ...], Any]] = []
    real = pointing.allocate

    def spy(inst, targets, **kw):
        calls.append((targets.ids, kw.get("start_q")))
        return real(inst, targets, **kw)

    monkeypatch.setattr(pointing, "allocate", spy)
    old = base["pointings"][0]
    new_plan = plan(TARGETS, seed=9, keep=keep_from_plan(base, 1))
    new = new_plan["pointings"][0]
    assert new["id"] == old["id"] and (new["ra_deg"], new["dec_deg"]) == (old["ra_deg"], old["dec_deg"])
    assert_same_configuration(old["configurations"][0], new["configurations"][0])
    c1 = set(observed(old, slice(0, 1)))
    rest = observed(new, slice(1, None))
    assert rest and not c1 & set(rest) and len(rest) == len(set(rest))  # observed once each
    left = {u["target_id"] for u in new["unallocated"]}
    assert c1 | set(rest) | left == set(old["target_ids"])  # none lost without a reason
    # the rest was allocated alone, from c1's arm states
    assert len(calls) == 1
    ids, start_q = calls[0]
    assert set(ids) == set(old["target_ids"]) - c1
    assert np.array_equal(start_q, q_of(old["configurations"][0]))
    assert new_plan["executable"] and new["executable"]
    legs_verified(new)


def test_keeping_every_configuration_reproduces_the_plan(base) -> None:
    old = base["pointings"][0]
    k = len(old["configurations"])
    new = plan(TARGETS, seed=5, keep=keep_from_plan(base, k + 3))["pointings"][0]
    assert len(new["configurations"]) == k
    for a, b in zip(old["configurations"], new["configurations"], strict=True):
        assert_same_configuration(a, b)
    assert new["executable"]
    legs_verified(new)


def test_targets_outside_the_kept_pointings_are_segmented_after_them(base) -> None:
    far = field_targets(6, seed=11, centre=(151.0, 21.0))
    out = plan(TARGETS + far, seed=2, keep=keep_from_plan(base, 1))
    kept, *others = out["pointings"]
    assert kept["id"] == base["pointings"][0]["id"]
    assert_same_configuration(base["pointings"][0]["configurations"][0], kept["configurations"][0])
    assert others and {t for p in others for t in p["target_ids"]} == {t["id"] for t in far}
    assert len({p["id"] for p in out["pointings"]}) == len(out["pointings"])
    assert "exposures_lower_bound" not in out["stats"]


def test_keep_c1_with_an_exclusion_and_a_lock_in_the_rest(base) -> None:
    """The astronomer's re-plan: c1 kept, one target of the rest excluded, another locked to
    the arm that observed it (both honoured; c1 untouched)."""
    old = base["pointings"][0]
    c2 = [a for a in old["configurations"][1]["assignments"] if a["target_id"] is not None]
    gone, held = c2[0]["target_id"], c2[1]
    out = pipeline.plan(PlanRequest(targets=TARGETS, seed=3, time_limit_s=LIMIT_S,
                                    keep_configurations=keep_from_plan(base, 1), excluded_targets=[gone],
                                    locked=[{"target_id": held["target_id"], "arm": held["arm"]}]), INST)
    new = out["pointings"][0]
    assert_same_configuration(old["configurations"][0], new["configurations"][0])
    assert gone not in observed(new) and gone not in new["target_ids"]
    assert {"target_id": gone, "reason": "excluded"} in out["unallocated"]
    arms = [a["arm"] for c in new["configurations"] for a in c["assignments"] if a["target_id"] == held["target_id"]]
    assert arms == [held["arm"]]
    assert out["executable"]
    legs_verified(new)


@pytest.mark.parametrize("how", ["exclude", "lock"])
def test_a_request_that_contradicts_a_kept_configuration_is_a_422(base, how) -> None:
    c1 = base["pointings"][0]["configurations"][0]["assignments"]
    m, a = next((m, a) for m, a in enumerate(c1) if a["target_id"] is not None)
    extra = ({"excluded_targets": [a["target_id"]]} if how == "exclude"
             else {"locked": [{"target_id": a["target_id"], "arm": (a["arm"] + 6) % 12}]})
    req = PlanRequest(targets=TARGETS, seed=1, time_limit_s=LIMIT_S, keep_configurations=keep_from_plan(base, 1),
                      **extra)
    field = r"keep_configurations\.pointings\[0\]\.configurations\[0\]"
    with pytest.raises(ValueError, match=field + (rf"\[{m}\].*excluded" if how == "exclude" else ".*locked to arm")):
        pipeline.plan(req, INST)


# ------------------------------------------------------------------- tampering


def tampered(base: dict[str, Any], how: str) -> dict[str, Any]:
    """c1 of the base plan, kept, with one planted defect."""
    keep = copy.deepcopy(keep_from_plan(base, 1))
    arms = keep["pointings"][0]["configurations"][0]
    observing = [a for a in arms if a["target_id"] is not None]
    if how == "swap":  # two arms' targets swapped: each tip is off its new target
        observing[0]["target_id"], observing[1]["target_id"] = observing[1]["target_id"], observing[0]["target_id"]
    elif how == "collide":  # an idle arm put with its tip on a neighbour's target
        arm_b, angles = colliding_arm(arms)
        arms[arm_b].update(target_id=None, theta1_rad=angles[0], theta2_rad=angles[1])
        arms[arm_b].pop("x_mm"), arms[arm_b].pop("y_mm")
    elif how == "zoa":
        observing[0]["theta1_rad"] = 3.6  # beyond the J1 limit (pi)
    elif how == "member":
        keep["pointings"][0]["target_ids"].append("no-such-target")
    elif how == "xy":
        observing[0]["x_mm"] += 0.5
    return keep


def colliding_arm(arms: list[dict[str, Any]]) -> tuple[int, tuple[float, float]]:
    """An arm b and joint angles that put its tip on arm a's tip (a neighbour observing a
    target), outside the zone of avoidance: the two arms then collide."""
    for a in arms:
        if a["target_id"] is None:
            continue
        for b in ((a["arm"] + 1) % 12, (a["arm"] - 1) % 12):
            ik = inverse_fov(INST, b, a["x_mm"], a["y_mm"])
            for t1, t2, ok in zip(np.ravel(ik.theta1_rad), np.ravel(ik.theta2_rad), np.ravel(ik.valid),
                                  strict=True):
                if ok and not in_zoa(t1, t2, Links.of(INST, b)):
                    return b, (float(t1), float(t2))
    raise AssertionError("no neighbour reaches an observed target")


@pytest.mark.parametrize("how,loc_tail,words", [
    ("swap", ["configurations", 0], "does not reach"),
    ("collide", ["configurations", 0], "collide"),
    ("zoa", ["configurations", 0], "zone of avoidance"),
    ("member", ["target_ids"], "not in the request"),
    ("xy", ["configurations", 0], "not the tip"),
])
def test_a_tampered_kept_configuration_is_a_422_naming_it(base, client, how, loc_tail, words) -> None:
    body = {"targets": TARGETS, "seed": 1, "time_limit_s": LIMIT_S, "keep_configurations": tampered(base, how)}
    r = client.post("/v1/plans", json=body)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"][0]
    assert detail["loc"][:4] == ["body", "keep_configurations", "pointings", 0]
    assert detail["loc"][4:4 + len(loc_tail)] == loc_tail
    assert words in detail["msg"]


def test_kept_configurations_are_checked_in_the_domain() -> None:
    """Without the service: an arm on a target its tip is not on, and a target observed twice."""
    from service.pointing_plans import sky_plane_targets
    from service.schemas import SkyTarget

    members = [SkyTarget(**t) for t in TARGETS[:3]]
    targets = sky_plane_targets(members, 150.0, 20.0, INST)
    park = INST.park_configuration
    idle = [KeptArm(k, None, float(park[k, 0]), float(park[k, 1])) for k in range(12)]
    on_park = KeptPointing("P", 150.0, 20.0, 0.0, tuple(t.id for t in members), (tuple(idle),))
    (c,) = kept_configurations(INST, targets, on_park)
    assert all(a.kind == "park" for a in c.assignments) and c.stats["kept"]
    as_sky = KeptPointing("P", 150.0, 20.0, 0.0, on_park.target_ids,
                          ((KeptArm(0, None, float(park[0, 0]), float(park[0, 1]), kind="sky"), *idle[1:]),))
    assert kept_configurations(INST, targets, as_sky)[0].assignments[0].kind == "blank"  # re-classified
    wrong = list(idle)
    wrong[3] = KeptArm(3, members[0].id, float(park[3, 0]), float(park[3, 1]))  # park is not on it
    with pytest.raises(ValueError, match=r"configurations\[0\]\[3\].*does not reach"):
        kept_configurations(INST, targets, KeptPointing("P", 150.0, 20.0, 0.0, on_park.target_ids, (tuple(wrong),)))


def one_target_configuration(index: int) -> Configuration:
    c = try_place(INST, new_configuration(INST, index), Placed("a", 0, 30.0, 0.0, 1, -1), INST.collision_buffer_mm)
    assert c is not None
    return c


def test_a_moved_target_is_never_put_into_a_kept_configuration() -> None:
    configs = [new_configuration(INST, 0), new_configuration(INST, 1)]
    moved = Placed("b", 1, -30.0, 0.0, 1, -1)
    free = _Sequencer(INST, list(configs), SequenceOptions(), {}, Budget.start(10.0))
    assert free._place(moved, -1, ()) and free.configs[0] != configs[0]  # the first that fits
    kept = _Sequencer(INST, list(configs), SequenceOptions(kept=1), {}, Budget.start(10.0))
    assert kept._place(moved, -1, ())
    assert kept.configs[0] == configs[0] and kept.configs[1] != configs[1]
    with pytest.raises(ValueError, match="kept"):
        SequenceOptions(kept=-1)


def test_a_leg_into_a_kept_configuration_is_never_repaired_by_changing_it() -> None:
    """A leg that cannot be planned into a kept configuration stays failed: without the
    freeze the repair takes its blocking target out."""
    config = one_target_configuration(0)
    failed = MotionPlan("failed", math.nan, (), tuple(range(12)), {"reasons": {}})
    for kept, changed in ((0, True), (1, False)):
        seq = _Sequencer(INST, [config], SequenceOptions(kept=kept), {}, Budget.start(10.0))
        seq.pending = []
        seq.plan = lambda start, goal, *_: failed  # type: ignore[method-assign]
        leg = seq.transition(0, INST.park_configuration)
        assert (seq.configs[:1] != [config]) == changed
        if not changed:
            assert leg is failed and not seq.changes


def test_pointing_options_refuse_anything_but_a_kept_pointing() -> None:
    with pytest.raises(ValueError, match="kept"):
        programme.PointingOptions(kept=object())  # type: ignore[arg-type]


# ------------------------------------------------------------- API and CLI


def test_api_keeps_c1(base, client) -> None:
    body = {"targets": TARGETS, "seed": 4, "time_limit_s": LIMIT_S, "keep_configurations": keep_from_plan(base, 1)}
    r = client.post("/v1/plans", json=body)
    assert r.status_code == 200, r.text
    new = r.json()["pointings"][0]
    assert_same_configuration(base["pointings"][0]["configurations"][0], new["configurations"][0])
    assert r.json()["executable"]


def write_csv(path: Path, targets: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "ra", "dec", "priority"])
        for t in targets:
            w.writerow([t["id"], repr(t["ra_deg"]), repr(t["dec_deg"]), t["priority"]])


def test_cli_keep_plan_json_1(tmp_path, capsys) -> None:
    src = tmp_path / "t.csv"
    write_csv(src, TARGETS)
    common = [str(src), "--quiet", "--time-limit", str(LIMIT_S)]
    assert main(["plan", *common, "--out", str(tmp_path / "a"), "--seed", "1"]) == 0
    first = json.loads((tmp_path / "a" / "plan.json").read_text())
    assert main(["plan", *common, "--out", str(tmp_path / "b"), "--seed", "7",
                 "--keep", f"{tmp_path / 'a' / 'plan.json'}:1"]) == 0
    second = json.loads((tmp_path / "b" / "plan.json").read_text())
    for p, q in zip(first["pointings"], second["pointings"], strict=False):
        if p["configurations"]:
            assert q["id"] == p["id"]
            assert_same_configuration(p["configurations"][0], q["configurations"][0])
    capsys.readouterr()
    assert main(["plan", *common, "--out", str(tmp_path / "c"), "--keep", f"{tmp_path / 'none.json'}:1"]) == 2
    assert "--keep" in capsys.readouterr().err


@pytest.mark.parametrize("text", ["plan.json", "plan.json:0", "plan.json:x", ":2"])
def test_keep_arg_needs_a_file_and_a_count(text) -> None:
    import argparse

    with pytest.raises(argparse.ArgumentTypeError):
        keep_arg(text)
    assert keep_arg("a:b/plan.json:3") == ("a:b/plan.json", 3)
