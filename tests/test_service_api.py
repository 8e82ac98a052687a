"""End-to-end tests of the HTTP API over a real socket (uvicorn), plus in-process edge cases."""

from __future__ import annotations

import json
import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.collision import colliding_arm_pairs
from models.instrument import default_instrument
from models.kinematics import tip_fov
from models.sky import sky_to_focal_mm
from service import pipeline
from service.app import create_app
from service.response_schemas import AllocationResponse, MotionPlanResponse, PlanResponse
from service.settings import Settings

EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "requests"


def example(name: str) -> dict[str, Any]:
    return json.loads((EXAMPLES / f"{name}.json").read_text())


def sky(n: int = 3, **over: Any) -> list[dict[str, Any]]:
    base = [{"id": f"t{i}", "ra_deg": 34.75 + 0.001 * i, "dec_deg": 57.13, "priority": 10}
            for i in range(n)]
    for k, v in over.items():
        base[0][k] = v
    return base


def park() -> list[dict[str, Any]]:
    return [{"arm": a.index, "theta1_rad": a.park_theta1_rad, "theta2_rad": a.park_theta2_rad}
            for a in default_instrument().arms]


def test_every_stage_is_imported_statically() -> None:
    """The pipeline calls the domain functions themselves (no dynamic look-up, no 501)."""
    import inspect

    from planner import plan_motion, pointing, programme
    from planner.sequence import plan_sequence
    from solvers.allocation import allocate
    from solvers.segmentation import segment_field

    assert pipeline.segment_field is segment_field and pipeline.allocate is allocate
    assert pipeline.plan_motion is plan_motion
    assert pointing.allocate is allocate and pointing.plan_sequence is plan_sequence
    for module in (pipeline, programme, pointing):
        src = inspect.getsource(module)
        assert "import_module" not in src and "inspect.signature" not in src


TIP_TOL_MM = 0.01


def check_allocation(out: dict[str, Any], targets: dict[str, tuple[float, float, int]], *,
                     buffer_mm: float | None = None, fixed: dict[int, tuple[float, float]] | None = None
                     ) -> set[str]:
    """Full checks of an allocation answer against ``targets`` {id: (x_mm, y_mm, priority)}
    in the FOV frame. Returns the allocated ids."""
    AllocationResponse.model_validate(out)
    inst = default_instrument()
    seen: set[str] = set()
    for i, c in enumerate(out["configurations"]):
        assert c["index"] == i
        assert c["status"] in ("optimal", "feasible")
        a = c["assignments"]
        assert [e["arm"] for e in a] == list(range(12)), "one entry per arm, sorted"
        th1 = np.array([e["theta1_rad"] for e in a])
        th2 = np.array([e["theta2_rad"] for e in a])
        tips = tip_fov(inst, np.arange(12), th1, th2)  # (12, 2), recomputed from the angles
        got = []
        for e, tip in zip(a, tips, strict=True):
            # the reported position is where the tip really is, for every kind of entry
            assert math.hypot(tip[0] - e["x_mm"], tip[1] - e["y_mm"]) < TIP_TOL_MM, e
            if e["target_id"] is None:
                assert e["kind"] in ("park", "sky", "blank", "fixed"), e
                assert (e.get("sky_ra_deg") is not None) == (e["kind"] == "sky"), e
                continue
            assert e["kind"] == "target", e
            x, y, _ = targets[e["target_id"]]
            assert math.hypot(tip[0] - x, tip[1] - y) < TIP_TOL_MM, (e, x, y)
            got.append(e["target_id"])
        for k, (t1, t2) in (fixed or {}).items():
            assert a[k]["kind"] == "fixed" and a[k]["target_id"] is None
            assert (a[k]["theta1_rad"], a[k]["theta2_rad"]) == pytest.approx((t1, t2), abs=1e-9)
        assert colliding_arm_pairs(inst, np.column_stack([th1, th2]), buffer_mm) == []
        assert len(got) == len(set(got)) == c["arm_yield"]
        assert not seen & set(got), "a target observed twice"
        seen |= set(got)
        total = sum(targets[t][2] for t in got)
        assert type(c["total_priority"]) is int and c["total_priority"] == total
    left = {u["target_id"] for u in out["unallocated"]}
    assert not seen & left
    assert seen | left == set(targets)
    assert all(u["reason"] in ("unreachable", "conflict", "no_time", "not_scheduled") for u in out["unallocated"])
    assert isinstance(out["stats"], dict) and out["stats"]
    return seen


# ------------------------------------------------------------------ GET endpoints


def test_health(live_server) -> None:
    r = httpx.get(live_server.url + "/v1/health")
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ok" and body["version"]


def test_instrument(live_server) -> None:
    r = httpx.get(live_server.url + "/v1/instrument")
    assert r.status_code == 200
    body = r.json()
    inst = default_instrument()
    assert body["fov_diameter_mm"] == inst.fov_diameter_mm == 250.0
    assert body["plate_scale_arcsec_per_mm"] == 1.2
    assert body["collision_buffer_mm"] == 5.0
    assert body["joint_speed_rad_s"] == pytest.approx(0.031416)
    assert [a["arm"] for a in body["arms"]] == list(range(12))
    a5 = body["arms"][5]
    assert a5["enabled"] is True
    assert math.hypot(a5["base_x_mm"], a5["base_y_mm"]) == pytest.approx(350.0)
    assert (a5["d12_mm"], a5["d13_mm"], a5["d24_mm"], a5["d3tip_mm"]) == (186, 77, 50, 305)
    assert (a5["stop_min_mm"], a5["stop_max_mm"]) == (183, 350)
    assert a5["park"] == {"theta1_rad": pytest.approx(math.pi), "theta2_rad": 0.0}
    assert [b["name"] for b in a5["bodies"]] == ["L1", "L2", "L3"]


def test_web_form(live_server) -> None:
    r = httpx.get(live_server.url + "/")
    assert r.status_code == 200 and 'src="static/app.js"' in r.text
    js = httpx.get(live_server.url + "/static/app.js")
    assert js.status_code == 200 and "v1/jobs" in js.text and "v1/target-lists" in js.text


def test_unknown_job_is_404(live_server) -> None:
    r = httpx.get(live_server.url + "/v1/jobs/nope")
    assert r.status_code == 404 and r.json()["error"] == "not_found"


def test_twenty_concurrent_requests(live_server) -> None:
    def call(i: int) -> tuple[int, int, Any]:
        with httpx.Client(base_url=live_server.url, timeout=30) as c:
            if i % 3 == 0:
                r = c.get("/v1/health")
            elif i % 3 == 1:
                r = c.get("/v1/instrument")
            else:  # invalid on purpose: the field must be named in every answer
                r = c.post("/v1/segmentations", json={"targets": sky(2, dec_deg=90 + i)})
            return i, r.status_code, r.json()

    with ThreadPoolExecutor(20) as pool:
        results = list(pool.map(call, range(20)))
    for i, status, body in results:
        if i % 3 == 0:
            assert (status, body["status"]) == (200, "ok")
        elif i % 3 == 1:
            assert status == 200 and len(body["arms"]) == 12
        else:
            assert status == 422
            assert body["detail"][0]["loc"] == ["body", "targets", 0, "dec_deg"]
            assert body["detail"][0]["input"] == 90 + i


# ---------------------------------------------------------------- stage endpoints


def test_segmentation_endpoint(live_server) -> None:
    body = example("segmentation")
    r = httpx.post(live_server.url + "/v1/segmentations", json=body, timeout=60)
    assert r.status_code == 200, r.text
    out = r.json()
    ids = [t for p in out["pointings"] for t in p["target_ids"]]
    assert sorted(ids) == sorted(t["id"] for t in body["targets"])
    fov_r = default_instrument().fov_radius_mm
    assert all(p["radius_mm"] <= fov_r + 1e-9 for p in out["pointings"])
    assert set(out["tangent_point"]) >= {"ra_deg", "dec_deg"}


def plane(body: dict[str, Any]) -> dict[str, tuple[float, float, int]]:
    return {t["id"]: (t["x_mm"], t["y_mm"], t["priority"]) for t in body["targets"]}


def test_allocation_then_motion_plan(live_server) -> None:
    body = example("allocation")  # 24 focal-plane targets, configurations "all"
    r = httpx.post(live_server.url + "/v1/allocations", json=body, timeout=120)
    assert r.status_code == 200, r.text
    out = r.json()
    done = check_allocation(out, plane(body))
    assert len(done) == len(body["targets"])  # all reachable: every one gets a configuration
    assert out["stats"]["n_configurations"] == len(out["configurations"]) >= 2
    goal = [{k: a[k] for k in ("arm", "theta1_rad", "theta2_rad")}
            for a in out["configurations"][0]["assignments"]]
    r = httpx.post(live_server.url + "/v1/motion-plans",
                   json={"start": park(), "goal": goal, "seed": 1, "time_limit_s": 5}, timeout=120)
    assert r.status_code == 200, r.text
    check_motion(r.json(), park(), goal)


def check_motion(plan: dict[str, Any], start: list[dict[str, Any]], goal: list[dict[str, Any]]) -> None:
    """A motion plan is either "ok" (every arm goes from start to goal) or "failed" naming arms."""
    MotionPlanResponse.model_validate(plan)
    assert plan["status"] in ("ok", "failed")
    if plan["status"] == "failed":
        assert plan["failed_arms"]
        return
    assert plan["failed_arms"] == []
    assert sorted(t["arm"] for t in plan["trajectories"]) == list(range(12))
    for tr in plan["trajectories"]:
        first, end = tr["waypoints"][0], tr["waypoints"][-1]
        s, g = start[tr["arm"]], goal[tr["arm"]]
        assert first["theta1_rad"] == pytest.approx(s["theta1_rad"], abs=1e-6)
        assert math.remainder(first["theta2_rad"] - s["theta2_rad"], 2 * math.pi) == pytest.approx(0, abs=1e-6)
        assert end["theta1_rad"] == pytest.approx(g["theta1_rad"], abs=1e-6)
        assert math.remainder(end["theta2_rad"] - g["theta2_rad"],
                              2 * math.pi) == pytest.approx(0, abs=1e-6)
        assert end["t_s"] <= plan["makespan_s"] + 1e-9


def test_allocation_unreachable_priorities_start_and_disabled_arms(live_server) -> None:
    top = 2**32 - 1
    body = {
        "targets": [
            {"id": "far", "x_mm": 400.0, "y_mm": 0.0, "priority": top},  # outside every arm's reach
            {"id": "c", "x_mm": 0.0, "y_mm": 0.0, "priority": top},
            {"id": "d", "x_mm": 60.0, "y_mm": 30.0, "priority": top - 1},
            {"id": "e", "x_mm": -50.0, "y_mm": -60.0, "priority": top - 2},
        ],
        "configurations": "all", "solver": "cpsat", "seed": 3, "time_limit_s": 10,
        "collision_buffer_mm": 6.0,
        "start": [{"arm": 2, "theta1_rad": 3.0, "theta2_rad": 0.2}],
        "disabled_arms": [{"arm": 5, "theta1_rad": 3.0, "theta2_rad": 0.1}],
    }
    r = httpx.post(live_server.url + "/v1/allocations", json=body, timeout=120)
    assert r.status_code == 200, r.text
    out = r.json()
    done = check_allocation(out, plane(body), buffer_mm=6.0, fixed={5: (3.0, 0.1)})
    assert done == {"c", "d", "e"}
    assert out["unallocated"] == [{"target_id": "far", "reason": "unreachable"}]
    # priorities near 2^32 survive exactly (no float rounding on the way)
    totals = sorted(c["total_priority"] for c in out["configurations"])
    assert sum(totals) == 3 * top - 3
    assert all(a["arm"] != 5 for c in out["configurations"] for a in c["assignments"]
               if a["target_id"])


def test_allocation_sky_targets(live_server) -> None:
    body = example("allocation_sky")  # semigreedy, one configuration
    r = httpx.post(live_server.url + "/v1/allocations", json=body, timeout=120)
    assert r.status_code == 200, r.text
    out = r.json()
    p = body["pointing"]
    inst = default_instrument()
    x, y = sky_to_focal_mm(np.array([t["ra_deg"] for t in body["targets"]]),
                           np.array([t["dec_deg"] for t in body["targets"]]),
                           p["ra_deg"], p["dec_deg"], inst.plate_scale_arcsec_per_mm,
                           p["position_angle_deg"])
    targets = {t["id"]: (float(xi), float(yi), t["priority"])
               for t, xi, yi in zip(body["targets"], x, y, strict=True)}
    done = check_allocation(out, targets)
    assert len(out["configurations"]) == 1 and len(done) >= 8


def test_allocation_sky_target_behind_the_pointing_is_422(live_server) -> None:
    body = {"targets": sky(2, ra_deg=214.75, dec_deg=-57.13),
            "pointing": {"ra_deg": 34.75, "dec_deg": 57.13}}
    r = httpx.post(live_server.url + "/v1/allocations", json=body, timeout=30)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "targets", 0, "dec_deg"]


def test_motion_plan_endpoint(live_server) -> None:
    body = example("motion_plan")
    r = httpx.post(live_server.url + "/v1/motion-plans", json=body, timeout=120)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["status"] == "ok"
    check_motion(out, body["start"], body["goal"])


def test_motion_plan_sampling_is_bounded(live_server) -> None:
    """dt_col_s = 1e-4 s took the server past 6 GB; it is refused at once, naming the field."""
    for extra, field in (({"dt_col_s": 1e-4}, "dt_col_s"), ({"dt_s": 0.6, "dt_col_s": 0.01}, "dt_col_s")):
        body = {**example("motion_plan"), **extra}
        r = httpx.post(live_server.url + "/v1/motion-plans", json=body, timeout=30)
        assert r.status_code == 422, r.text
        assert field in r.text


def test_plan_endpoint(live_server) -> None:
    """The whole pipeline on the small example field (12 M13 stars, one pointing)."""
    body = example("plan")
    r = httpx.post(live_server.url + "/v1/plans", json=body, timeout=300)
    assert r.status_code == 200, r.text
    out = r.json()
    PlanResponse.model_validate(out)
    inst = default_instrument()
    by_id = {t["id"]: t for t in body["targets"]}
    assert sorted(t for p in out["pointings"] for t in p["target_ids"]) == sorted(by_id)
    n_ok = 0
    for p in out["pointings"]:
        # members projected onto the pointing's own tangent plane
        members = [by_id[t] for t in p["target_ids"]]
        x, y = sky_to_focal_mm(np.array([t["ra_deg"] for t in members]),
                               np.array([t["dec_deg"] for t in members]), p["ra_deg"], p["dec_deg"],
                               inst.plate_scale_arcsec_per_mm, body.get("position_angle_deg", 0.0))
        targets = {t["id"]: (float(xi), float(yi), t["priority"])
                   for t, xi, yi in zip(members, x, y, strict=True)}
        check_allocation({"configurations": p["configurations"], "unallocated": p["unallocated"],
                          "stats": p["stats"]["allocation"]}, targets)
        # motions: park -> c1 -> ... -> park
        assert len(p["motions"]) == len(p["configurations"]) + 1
        states = [park()] + [
            [{k: a[k] for k in ("arm", "theta1_rad", "theta2_rad")} for a in c["assignments"]]
            for c in p["configurations"]
        ] + [park()]
        for leg, m in enumerate(p["motions"]):
            if leg and p["motions"][leg - 1]["status"] == "ok":
                prev = p["motions"][leg - 1]["trajectories"]
                start = [{"arm": t["arm"], **{k: t["waypoints"][-1][k] for k in ("theta1_rad", "theta2_rad")}}
                         for t in prev]
            else:
                start = states[leg]
            check_motion(m, start, states[leg + 1])
            n_ok += m["status"] == "ok"
    s = out["stats"]
    assert s["pointings"] == len(out["pointings"]) and s["targets"] == len(by_id)
    assert s["allocated_targets"] == len(by_id)  # a one-pointing field within the FOV
    observed = {a["target_id"] for p in out["pointings"] for c in p["configurations"]
                for a in c["assignments"] if a["target_id"] is not None}
    assert s["field_completeness"] == pytest.approx(len(observed) / len(by_id))
    assert s["priority_completeness"] == pytest.approx(
        sum(by_id[t]["priority"] for t in observed) / sum(t["priority"] for t in by_id.values()))
    assert s["motion_plans"] == sum(len(p["motions"]) for p in out["pointings"])
    assert s["motion_plans_failed"] == s["motion_plans"] - n_ok
    assert n_ok >= 1
    assert out["executable"] == (s["motion_plans_failed"] == 0)
    assert out["executable"] == (out["reasons"] == [])


# --------------------------------------------------------------------- bad input


BAD: list[tuple[str, str, Any, list[Any]]] = [
    # (name, path, body, expected loc prefix)
    ("wrong type ra", "/v1/segmentations", {"targets": sky(2, ra_deg="east")},
     ["body", "targets", 0, "ra_deg"]),
    ("wrong type targets", "/v1/segmentations", {"targets": "all of them"}, ["body", "targets"]),
    ("NaN", "/v1/segmentations", '{"targets": [{"id": "a", "ra_deg": NaN, "dec_deg": 1, '
     '"priority": 1}]}', ["body", "targets", 0, "ra_deg"]),
    ("Infinity", "/v1/plans", '{"targets": [{"id": "a", "ra_deg": 1, "dec_deg": Infinity, '
     '"priority": 1}]}', ["body", "targets", 0, "dec_deg"]),
    ("Dec 95", "/v1/plans", {"targets": sky(2, dec_deg=95)}, ["body", "targets", 0, "dec_deg"]),
    ("RA 360", "/v1/plans", {"targets": sky(2, ra_deg=360)}, ["body", "targets", 0, "ra_deg"]),
    ("priority 0", "/v1/segmentations", {"targets": sky(2, priority=0)},
     ["body", "targets", 0, "priority"]),
    ("priority 2^40", "/v1/segmentations", {"targets": sky(2, priority=2**40)},
     ["body", "targets", 0, "priority"]),
    ("priority 1.5", "/v1/segmentations", {"targets": sky(2, priority=1.5)},
     ["body", "targets", 0, "priority"]),
    ("13 arms", "/v1/motion-plans",
     {"start": park() + [{"arm": 0, "theta1_rad": 0, "theta2_rad": 0}], "goal": park()},
     ["body", "start"]),
    ("arm 12", "/v1/motion-plans",
     {"start": park()[:11] + [{"arm": 12, "theta1_rad": 0, "theta2_rad": 0}], "goal": park()},
     ["body", "start", 11, "arm"]),
    ("arm twice", "/v1/motion-plans",
     {"start": park()[:11] + [{"arm": 0, "theta1_rad": 0, "theta2_rad": 0}], "goal": park()},
     ["body", "start"]),
    ("unknown method", "/v1/allocations",
     {"targets": [{"id": "a", "x_mm": 0, "y_mm": 0, "priority": 1}], "method": "magic"},
     ["body", "method"]),
    ("unknown solver", "/v1/plans", {"targets": sky(1), "solver": "cplex"}, ["body", "solver"]),
    ("duplicate id", "/v1/segmentations", {"targets": sky(2, id="t1")}, ["body", "targets"]),
    ("empty list", "/v1/segmentations", {"targets": []}, ["body", "targets"]),
    ("missing pointing", "/v1/allocations", {"targets": sky(2)}, ["body"]),
    ("unknown field", "/v1/plans", {"targets": sky(1), "thresold_mm": 3}, ["body", "thresold_mm"]),
    ("negative time limit", "/v1/plans", {"targets": sky(1), "time_limit_s": -1},
     ["body", "time_limit_s"]),
    ("too long time limit", "/v1/plans", {"targets": sky(1), "time_limit_s": 86000},
     ["body", "time_limit_s"]),
    ("too many targets", "/v1/segmentations", {"targets": sky(501)}, ["body", "targets"]),
    ("unknown job kind", "/v1/jobs", {"kind": "coffee", "request": {}}, ["body"]),
    ("bad job request", "/v1/jobs", {"kind": "plan", "request": {"targets": sky(2, dec_deg=95)}},
     ["body", "plan", "request", "targets", 0, "dec_deg"]),
    ("not json", "/v1/plans", "{targets", ["body"]),
]
POINTING = {"ra_deg": 10.0, "dec_deg": 20.0}


@pytest.mark.parametrize("path,body,loc", [
    ("/v1/allocations", {"targets": [{"id": "a", "ra_deg": 10.0, "dec_deg": 20.0, "priority": 1},
                                     {"id": "b", "ra_deg": 10.0, "dec_deg": 95.0, "priority": 1}],
                         "pointing": POINTING}, ["body", "targets", 1, "dec_deg"]),
    ("/v1/allocations", {"targets": [{"id": "a", "x_mm": 0.0, "y_mm": "far", "priority": 1}]},
     ["body", "targets", 0, "y_mm"]),
    ("/v1/jobs", {"kind": "allocation", "request": {"targets": [
        {"id": "a", "ra_deg": 10.0, "dec_deg": 95.0, "priority": 1}], "pointing": POINTING}},
     ["body", "allocation", "request", "targets", 0, "dec_deg"]),
], ids=["sky", "plane", "job"])
def test_allocation_targets_422_names_only_the_kind_given(live_server, path, body, loc) -> None:
    """Sky or focal-plane targets: the answer is about the kind of target given, not the
    other branch of the union (no 'x_mm: Field required' for a sky target)."""
    r = httpx.post(live_server.url + path, json=body, timeout=30)
    assert r.status_code == 422, r.text
    out = r.json()
    assert [e["loc"] for e in out["detail"]] == [loc]
    assert "SkyTarget" not in out["message"] and "PlaneTarget" not in out["message"]


@pytest.mark.parametrize("name,path,body,loc", BAD, ids=[b[0] for b in BAD])
def test_bad_input_is_422_naming_the_field(live_server, name, path, body, loc) -> None:
    kw: dict[str, Any] = (
        {"content": body, "headers": {"content-type": "application/json"}}
        if isinstance(body, str) else {"json": body}
    )
    r = httpx.post(live_server.url + path, timeout=30, **kw)
    assert r.status_code == 422, r.text
    out = r.json()
    locs = [e["loc"] for e in out["detail"]]
    assert any(lc[: len(loc)] == loc for lc in locs), locs
    assert out["message"]
    if name == "missing pointing":
        assert "pointing" in out["message"]
    if name == "duplicate id":
        assert "targets[1].id" in out["message"]


def test_body_limit_is_413(live_server) -> None:
    r = httpx.post(live_server.url + "/v1/plans", content=b"x" * 300_000,
                   headers={"content-type": "application/json"})
    assert r.status_code == 413 and r.json()["error"] == "too_large"

    def chunks():  # no Content-Length: the limit still holds
        for _ in range(30):
            yield b" " * 10_000

    r = httpx.post(live_server.url + "/v1/plans", content=chunks(),
                   headers={"content-type": "application/json"})
    assert r.status_code == 413


# ------------------------------------------------------------- in-process edge cases


def test_bearer_token_required_on_post(tmp_path) -> None:
    app = create_app(Settings(job_db=tmp_path / "j.db", api_token="s3cret"))
    with TestClient(app) as c:
        assert c.get("/v1/health").status_code == 200  # GET stays open
        body = {"targets": sky(1)}
        for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": "Basic s3cret"}):
            r = c.post("/v1/plans", json=body, headers=headers)
            assert r.status_code == 401, r.text
            assert r.json()["error"] == "unauthorized"
        r = c.post("/v1/plans", json={"targets": sky(1, dec_deg=95)},
                   headers={"Authorization": "Bearer s3cret"})
        assert r.status_code == 422


def test_cors_origins(tmp_path) -> None:
    app = create_app(Settings(job_db=tmp_path / "j.db", cors_origins="https://form.example"))
    with TestClient(app) as c:
        r = c.options("/v1/plans", headers={"Origin": "https://form.example",
                                            "Access-Control-Request-Method": "POST"})
        assert r.headers["access-control-allow-origin"] == "https://form.example"


def test_unexpected_error_is_never_500(tmp_path, monkeypatch) -> None:
    app = create_app(Settings(job_db=tmp_path / "j.db"))

    def boom(_: Any) -> Any:
        raise RuntimeError("a bug")

    monkeypatch.setattr(pipeline, "instrument_info", boom)
    with TestClient(app, raise_server_exceptions=False) as c:
        r = c.get("/v1/instrument")
        assert r.status_code == 503
        assert r.json()["error"] == "internal_error"


def _bad_segmentation(*_: Any, **__: Any) -> Any:
    """Module-level, so that a heavy worker process can import it by name."""
    from models.errors import InputError

    raise InputError("targets[3].dec_deg", "too close to the pole")


def _slow_segmentation(*_: Any, **__: Any) -> Any:
    from models.errors import TimeLimitExceeded

    raise TimeLimitExceeded("segmentation", 0.5)


def test_domain_input_error_is_422(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _bad_segmentation)
    app = create_app(Settings(job_db=tmp_path / "j.db"))
    with TestClient(app) as c:
        r = c.post("/v1/segmentations", json={"targets": sky(4)})
        assert r.status_code == 422
        assert r.json()["detail"][0]["loc"] == ["body", "targets", 3, "dec_deg"]


def test_stage_out_of_time_is_422_on_time_limit(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _slow_segmentation)
    app = create_app(Settings(job_db=tmp_path / "j.db"))
    with TestClient(app) as c:
        r = c.post("/v1/segmentations", json={"targets": sky(4)})
        assert r.status_code == 422
        assert r.json()["detail"][0]["loc"] == ["body", "time_limit_s"]
        assert "segmentation" in r.json()["detail"][0]["msg"]


def test_example_requests_are_valid() -> None:
    from service.job_schemas import JobStatus  # noqa: F401
    from service.schemas import REQUEST_TYPES

    names = {"segmentation": "segmentation", "allocation": "allocation",
             "allocation_sky": "allocation", "motion_plan": "motion-plan", "plan": "plan"}
    for name, kind in names.items():
        REQUEST_TYPES[kind].model_validate(example(name))


def test_lone_surrogate_is_422_not_5xx(live_server) -> None:
    """JSON may carry a lone surrogate ("\\ud800"); the 422 that echoes it must still encode."""
    for path in ("/v1/segmentations", "/v1/allocations", "/v1/plans"):
        r = httpx.post(live_server.url + path, content=b'{"targets":"\\ud800"}',
                       headers={"Content-Type": "application/json"}, timeout=30)
        assert r.status_code == 422, (path, r.status_code, r.text)
        assert "targets" in r.json()["message"]


def test_completeness_counts_unreachable_targets_as_not_observed(live_server) -> None:
    """A target out of every arm's reach: completeness over every target stays below 1 and
    the counts say why (denominators: all targets; n_allocated from the configurations)."""
    targets = [{"id": f"t{i}", "x_mm": 20.0 * i - 40, "y_mm": 5.0 * i, "priority": 1 + i}
               for i in range(5)] + [{"id": "far", "x_mm": 1000.0, "y_mm": 0.0, "priority": 7}]
    r = httpx.post(live_server.url + "/v1/allocations", timeout=60, json={
        "targets": targets, "configurations": "all", "time_limit_s": 5, "seed": 1})
    assert r.status_code == 200, r.text
    out = r.json()
    observed = {a["target_id"] for c in out["configurations"] for a in c["assignments"]
                if a["target_id"] is not None}
    assert "far" not in observed and {"target_id": "far", "reason": "unreachable"} in out["unallocated"]
    s = out["stats"]
    assert "reachable_completeness" not in s
    assert (s["n_targets"], s["n_unreachable"], s["n_reachable"]) == (6, 1, 5)
    assert s["n_allocated"] == len(observed)
    assert s["field_completeness"] == pytest.approx(len(observed) / 6) and s["field_completeness"] < 1
    prio = {t["id"]: t["priority"] for t in targets}
    assert s["priority_completeness"] == pytest.approx(
        sum(prio[t] for t in observed) / sum(prio.values()))
