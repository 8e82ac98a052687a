"""A plan file anyone can re-check (issue 39 item 5): the content hash, planner.validate on
real plans and on a corpus of tampered ones, POST /v1/validations and `mxs-planner validate`."""

from __future__ import annotations

import copy
import hashlib
import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from benchmarks.programme_time import SMOKE, generated
from models.instrument import default_instrument
from models.kinematics import tip_fov
from planner.options import MotionOptions
from planner.plan_file import content_hash
from planner.validate import DT_CHECK_S, validate_plan
from service import pipeline
from service.app import create_app
from service.cli import main
from service.schemas import PlanRequest
from service.settings import Settings
from tests.tampered_plans import TAMPERS, tampered

#: the module's tests share its module-scoped plans: one pytest-xdist worker runs them all
pytestmark = pytest.mark.xdist_group("test_validate")

INST = default_instrument()


def _plan(targets: list[dict[str, Any]], seed: int) -> dict[str, Any]:
    req = PlanRequest.model_validate({"targets": targets, "seed": seed, "time_limit_s": 15.0})
    return pipeline.plan(req, INST)


@pytest.fixture(scope="module")
def plans() -> list[dict[str, Any]]:
    """Plans the service makes of two small multi-pointing programmes (the programme
    benchmark's smoke programmes)."""
    progs = generated(SMOKE["programmes"], n_range=SMOKE["n_range"])
    return [_plan(p["targets"], p["seed"]) for p in progs]


@pytest.fixture(scope="module")
def base(plans: list[dict[str, Any]]) -> dict[str, Any]:
    """A plan with a pointing of two or more configurations whose legs are all planned."""
    for plan in plans:
        for p in plan["pointings"]:
            if len(p["configurations"]) >= 2 and all(m["status"] == "ok" for m in p["motions"]):
                return plan
    pytest.fail("no plan has an executable pointing with two configurations")


def _whole_as_int(text: str) -> float | int:
    v = float(text)
    return int(v) if v.is_integer() else v


def _oracle_hash(plan: dict[str, Any]) -> str:
    body = {k: v for k, v in plan.items() if k != "content_hash"}
    # re-read with every whole float as an integer (JSON does not tell 900 from 900.0)
    body = json.loads(json.dumps(body), parse_float=_whole_as_int)
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return "sha256:" + hashlib.sha256(text.encode("utf-8")).hexdigest()


# ------------------------------------------------------------------------------ hash


def test_every_plan_carries_the_hash_of_its_canonical_json(plans: list[dict[str, Any]]) -> None:
    for plan in plans:
        assert plan["content_hash"] == _oracle_hash(plan)
        # written and read back as the CLI and the service write it: the same hash
        assert content_hash(json.loads(json.dumps(plan, indent=1))) == plan["content_hash"]


def test_the_hash_changes_with_any_number() -> None:
    plan = {"a": [1.0, 2.5], "b": {"c": 3}}
    h = content_hash(plan)
    assert h == _oracle_hash(plan)
    assert content_hash({"b": {"c": 3}, "a": [1.0, 2.5]}) == h  # key order does not matter
    assert content_hash({**plan, "content_hash": "sha256:00"}) == h  # the field itself is left out
    assert content_hash({"a": [1.0, 2.5000000000000004], "b": {"c": 3}}) != h
    assert content_hash({"a": [1.0, 2.5], "b": {"c": 4}}) != h
    # a writer that drops a whole float's fraction (JavaScript's JSON.stringify) hashes the same
    assert content_hash(json.loads('{"a": [1, 2.5], "b": {"c": 3.0}}')) == h
    assert content_hash({"a": [1.0, 2.5], "b": {"c": 3.5}}) != h


# ------------------------------------------------------------------------ real plans


def test_every_plan_the_service_makes_is_valid(plans: list[dict[str, Any]]) -> None:
    assert sum(len(p["pointings"]) for p in plans) >= 3  # multi-pointing programmes
    for plan in plans:
        r = validate_plan(INST, plan)
        assert r.violations == () and r.valid and r.hash_ok
        assert r.executable == plan["executable"]
        legs = sum(len(p["motions"]) for p in plan["pointings"])
        assert r.checked["legs"] == legs
        assert r.checked["configurations"] == sum(len(p["configurations"]) for p in plan["pointings"])
        assert r.checked["legs_failed"] == sum(m["status"] != "ok" for p in plan["pointings"] for m in p["motions"])
        # clearance re-simulated at least every DT_CHECK_S, finer than the planner's step
        assert DT_CHECK_S < MotionOptions().dt_col_s
        span_s = sum(m["makespan_s"] for p in plan["pointings"] for m in p["motions"] if m["status"] == "ok")
        assert r.checked["samples"] >= span_s / DT_CHECK_S


def test_plan_targets_are_where_the_tips_are(plans: list[dict[str, Any]]) -> None:
    """The new PlanPointing.targets: each observed target's listed position is its arm's tip
    (forward kinematics, independently of the validator)."""
    n = 0
    for plan in plans:
        for p in plan["pointings"]:
            where = {t["id"]: (t["x_mm"], t["y_mm"]) for t in p["targets"]}
            assert set(where) == set(p["target_ids"])
            for c in p["configurations"]:
                for a in c["assignments"]:
                    if a["target_id"] is not None:
                        tip = tip_fov(INST, a["arm"], a["theta1_rad"], a["theta2_rad"])
                        assert np.hypot(*(tip - where[a["target_id"]])) < 1e-6
                        n += 1
    assert n > 10


# -------------------------------------------------------------------------- corpus


def test_the_corpus_is_large_enough() -> None:
    assert len(TAMPERS) >= 20
    assert len({t.name for t in TAMPERS}) == len(TAMPERS)


@pytest.mark.parametrize("tamper", TAMPERS, ids=[t.name for t in TAMPERS])
def test_every_tampered_plan_is_caught_with_its_kind(base: dict[str, Any], tamper: Any) -> None:
    bad = tampered(base, INST, tamper)
    assert bad != base
    r = validate_plan(INST, bad)
    kinds = Counter(v.kind for v in r.violations)
    assert not r.valid and tamper.kind in kinds, (tamper.name, kinds)
    assert r.hash_ok == tamper.rehash  # the rehashed ones are caught by the content checks alone
    assert r.violations_total >= len(r.violations) > 0


def test_a_violation_names_pointing_leg_and_arm(base: dict[str, Any]) -> None:
    t = next(t for t in TAMPERS if t.name == "too_fast")
    r = validate_plan(INST, tampered(base, INST, t))
    v = next(v for v in r.violations if v.kind == "speed")
    assert v.pointing is not None and v.leg is not None and v.arm is not None


def test_a_plan_not_executable_is_checked_and_says_so(base: dict[str, Any]) -> None:
    """A failed leg (as the planner writes one: arms resting at the start), the pointing and
    the plan saying executable: false, hash recomputed: valid, not executable."""
    plan = copy.deepcopy(base)
    p = next(p for p in plan["pointings"] if len(p["motions"]) >= 2)
    m = p["motions"][-1]
    m.update(status="failed", makespan_s=None, failed_arms=[0])
    for tr in m["trajectories"]:
        tr["waypoints"] = tr["waypoints"][:1]
        tr["commands"] = []
    p["executable"] = plan["executable"] = False
    plan["content_hash"] = content_hash(plan)
    r = validate_plan(INST, plan)
    assert r.valid and not r.executable and r.checked["legs_failed"] >= 1


# --------------------------------------------------------------------------- shapes


@pytest.mark.parametrize(("edit", "field"), [
    (lambda p: p.pop("pointings"), "pointings"),
    (lambda p: p.update(executable="yes"), "executable"),
    (lambda p: p["pointings"][0].update(configurations=3), "pointings[0].configurations"),
    (lambda p: p["pointings"][0]["motions"][0]["trajectories"][2]["waypoints"][0].update(t_s="0"),
     "pointings[0].motions[0].trajectories[2].waypoints[0].t_s"),
    (lambda p: p["pointings"][0]["motions"][0].update(status="maybe"), "pointings[0].motions[0].status"),
    (lambda p: p["pointings"][0]["configurations"][0]["assignments"][0].update(arm=True),
     "pointings[0].configurations[0].assignments[0].arm"),
])
def test_a_wrong_shape_names_the_field(base: dict[str, Any], edit: Any, field: str) -> None:
    from models.errors import InputError

    plan = copy.deepcopy(base)
    edit(plan)
    with pytest.raises(InputError) as exc:
        validate_plan(INST, plan)
    assert exc.value.field == field


# ------------------------------------------------------------------------------ API


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Any:
    db = tmp_path_factory.mktemp("validate") / "j.db"
    with TestClient(create_app(Settings(job_db=db, heavy_processes=False))) as c:
        yield c


def test_api_valid_and_tampered(client: Any, base: dict[str, Any]) -> None:
    r = client.post("/v1/validations", json=base)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["valid"] and out["hash_ok"] and out["violations"] == []
    assert out["executable"] == base["executable"] and out["checked"]["legs"] > 0
    for name in ("swap_arms", "hash_edited", "waypoint_moved", "target_ra"):
        t = next(t for t in TAMPERS if t.name == name)
        out = client.post("/v1/validations", json=tampered(base, INST, t)).json()
        assert not out["valid"] and t.kind in {v["kind"] for v in out["violations"]}
        assert set(out["violations"][0]) == {"pointing", "configuration", "leg", "arm", "kind", "message"}


def test_api_bad_bodies_are_422_naming_the_field(client: Any, base: dict[str, Any]) -> None:
    r = client.post("/v1/validations", content=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status_code == 422
    r = client.post("/v1/validations", json=[1, 2])
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][0] == "body"
    plan = copy.deepcopy(base)
    plan["pointings"][0]["motions"][0]["trajectories"][1]["waypoints"][0]["theta1_rad"] = "pi"
    r = client.post("/v1/validations", json=plan)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "pointings", 0, "motions", 0, "trajectories", 1,
                                            "waypoints", 0, "theta1_rad"]


def test_api_never_5xx_on_mangled_plans(client: Any, base: dict[str, Any]) -> None:
    """Random deletions and replacements anywhere in a plan: 200 or 422, never 5xx."""
    rng = np.random.default_rng(7)
    small = copy.deepcopy(base)
    small["pointings"] = small["pointings"][:1]
    for _ in range(25):
        plan = copy.deepcopy(small)
        node: Any = plan
        for _depth in range(int(rng.integers(1, 7))):
            keys = list(node) if isinstance(node, dict) else list(range(len(node)))
            if not keys:
                break
            k = keys[int(rng.integers(len(keys)))]
            if not isinstance(node[k], (dict, list)) or rng.random() < 0.3:
                node[k] = [None, "x", -1, 1e308, {}, [], True][int(rng.integers(7))]
                break
            node = node[k]
        r = client.post("/v1/validations", json=plan)
        assert r.status_code in (200, 422), r.text


# ------------------------------------------------------------------------------ CLI


def test_cli_exit_codes(tmp_path: Path, base: dict[str, Any], capsys: Any) -> None:
    good = tmp_path / "plan.json"
    good.write_text(json.dumps(base, indent=1))
    assert main(["validate", str(good)]) == (0 if base["executable"] else 4)
    t = next(t for t in TAMPERS if t.name == "too_fast")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(tampered(base, INST, t)))
    capsys.readouterr()
    assert main(["validate", str(bad)]) == 5
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if ": speed: " in x)
    assert line.startswith("violation: pointing ") and ", leg " in line and ", arm " in line
    junk = tmp_path / "junk.json"
    junk.write_text("{ not json")
    assert main(["validate", str(junk)]) == 2
    assert main(["validate", str(tmp_path / "missing.json")]) == 2
    shape = tmp_path / "shape.json"
    shape.write_text(json.dumps({"pointings": "none", "executable": True}))
    capsys.readouterr()
    assert main(["validate", str(shape)]) == 2
    assert "pointings" in capsys.readouterr().err


def test_cli_plan_json_is_valid(tmp_path: Path) -> None:
    """`mxs-planner plan` writes a plan.json that `mxs-planner validate` accepts."""
    src = tmp_path / "t.csv"
    rows = ["id,ra_deg,dec_deg,priority"] + [f"s{i},{150 + 0.0004 * i:.6f},{2 + 0.0003 * (i % 5):.6f},{1 + i}"
                                              for i in range(6)]
    src.write_text("\n".join(rows) + "\n")
    out = tmp_path / "o"
    code = main(["plan", str(src), "--out", str(out), "--seed", "1", "--time-limit", "15", "--quiet"])
    assert code in (0, 4)
    plan = json.loads((out / "plan.json").read_text())
    assert plan["content_hash"] == _oracle_hash(plan)
    assert main(["validate", str(out / "plan.json")]) == code


def test_api_in_a_worker_process_and_plan_answers_carry_their_hash(tmp_path: Path, base: dict[str, Any]) -> None:
    """With the default worker processes: a validation computed in a worker, and the bytes of a
    POST /v1/plans answer hash to the content_hash they carry."""
    with TestClient(create_app(Settings(job_db=tmp_path / "j.db"))) as c:
        out = c.post("/v1/validations", json=base).json()
        assert out["valid"] and out["hash_ok"]
        targets = [{"id": f"s{i}", "ra_deg": 150 + 0.0004 * i, "dec_deg": 2.0 + 0.0003 * (i % 5),
                    "priority": 1 + i} for i in range(5)]
        r = c.post("/v1/plans", json={"targets": targets, "seed": 1, "time_limit_s": 15.0})
        assert r.status_code == 200, r.text
        plan = json.loads(r.content)
        assert plan["content_hash"] == _oracle_hash(plan)
        out = c.post("/v1/validations", json=plan).json()
        assert out["valid"] and out["executable"] == plan["executable"]
