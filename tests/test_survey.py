"""Survey-size work through the API: per-stage limits named in their 422/413, stored target
lists (upload once, reference by ``target_list_id``), 100,000-row uploads and a 20,000-target
segmentation over HTTP, and a synchronous plan that stays within its budget without blocking
the event loop."""

from __future__ import annotations

import io
import json
import sqlite3
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from astropy.table import Table
from fastapi.testclient import TestClient

from models.instrument import default_instrument
from service.app import create_app
from service.settings import Settings
from tests.test_service_reliability import serve, until

FOV_RADIUS_MM = default_instrument().fov_radius_mm
SURVEY_ROWS = 100_000  # the survey size; the 10 s goal is measured by benchmarks/survey.py


def field(n: int, side_deg: float, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``n`` uniform random positions in a ``side_deg`` x ``side_deg`` box at (150, 2) deg."""
    rng = np.random.default_rng(seed)
    half = side_deg / 2
    return 150 + rng.uniform(-half, half, n), 2 + rng.uniform(-half, half, n)


def sky(n: int, side_deg: float = 0.05, seed: int = 1) -> list[dict[str, Any]]:
    ra, dec = field(n, side_deg, seed)
    return [{"id": f"t{i}", "ra_deg": float(ra[i]), "dec_deg": float(dec[i]),
             "priority": 1 + i % 7} for i in range(n)]


def csv_bytes(targets: list[dict[str, Any]]) -> bytes:
    rows = "".join(f"{t['id']},{t['ra_deg']!r},{t['dec_deg']!r},{t['priority']}\n" for t in targets)
    return ("id,ra_deg,dec_deg,priority\n" + rows).encode()


def upload(c: TestClient, name: str, data: bytes, **params: Any) -> dict[str, Any]:
    r = c.post("/v1/target-lists", files={"file": (name, data)}, params=params)
    assert r.status_code == 200, r.text
    return r.json()


def check_partition(seg: dict[str, Any], ids: list[str]) -> None:
    """Every target in exactly one pointing, each pointing inside the FOV."""
    members = [t for p in seg["pointings"] for t in p["target_ids"]]
    assert len(members) == len(ids) and set(members) == set(ids)
    assert max(p["radius_mm"] for p in seg["pointings"]) <= FOV_RADIUS_MM + 1e-6


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(Settings(job_db=tmp_path / "jobs.sqlite3"))) as c:
        yield c


# ------------------------------------------------------------- survey-size uploads


def test_100k_row_csv_upload_then_segmentation_by_id(client: TestClient) -> None:
    targets = sky(SURVEY_ROWS, side_deg=2.0)  # 4 deg2
    listed = upload(client, "survey.csv", csv_bytes(targets), include_targets="false")
    assert listed["n_targets"] == SURVEY_ROWS and listed["targets"] == []
    assert listed["expires_at"] > listed["created_at"]
    r = client.post("/v1/segmentations", json={"target_list_id": listed["target_list_id"]})
    assert r.status_code == 200, r.text[:500]
    check_partition(r.json(), [t["id"] for t in targets])


def test_100k_row_fits_upload_is_stored_as_written(client: TestClient) -> None:
    n = SURVEY_ROWS
    ra, dec = field(n, 2.0, seed=2)
    t = Table({"source_id": np.arange(10**9, 10**9 + n, dtype=np.int64), "RAJ2000": ra,
               "DEJ2000": dec, "prio": 1 + np.arange(n) % 5})
    buf = io.BytesIO()
    t.write(buf, format="fits")
    listed = upload(client, "survey.fits", buf.getvalue(), include_targets="false")
    assert listed["n_targets"] == n and listed["columns"]["id"] == "source_id"
    r = client.get(f"/v1/target-lists/{listed['target_list_id']}")
    assert r.status_code == 200
    got = r.json()["targets"]
    assert [g["id"] for g in got] == [str(i) for i in t["source_id"]]
    np.testing.assert_array_equal([g["ra_deg"] for g in got], ra)
    np.testing.assert_array_equal([g["dec_deg"] for g in got], dec)
    assert [g["priority"] for g in got] == list(t["prio"])
    assert [g["row"] for g in got[:3]] == [1, 2, 3]


def test_20k_segmentation_over_http_inline_equals_by_id(client: TestClient) -> None:
    targets = sky(20_000, side_deg=1.0, seed=3)
    inline = client.post("/v1/segmentations", json={"targets": targets, "seed": 4})
    assert inline.status_code == 200, inline.text[:500]
    check_partition(inline.json(), [t["id"] for t in targets])
    listed = upload(client, "s.csv", csv_bytes(targets))
    assert [{k: x[k] for k in targets[0]} for x in listed["targets"]] == targets
    by_id = client.post("/v1/segmentations",
                        json={"target_list_id": listed["target_list_id"], "seed": 4})
    assert by_id.status_code == 200
    a, b = inline.json(), by_id.json()
    assert a["pointings"] == b["pointings"] and a["tangent_point"] == b["tangent_point"]


# ---------------------------------------------------------------- per-stage limits


def limited(tmp_path: Path, **kw: Any) -> TestClient:
    return TestClient(create_app(Settings(job_db=tmp_path / "j.sqlite3", **kw)))


def message(r: httpx.Response) -> str:
    body = r.json()
    return body.get("message") or body.get("detail")


def test_each_stage_has_its_own_target_limit_named_in_the_422(tmp_path: Path) -> None:
    with limited(tmp_path, max_segmentation_targets=30, max_allocation_targets=5,
                 max_plan_targets=4, max_plan_job_targets=6) as c:
        assert c.post("/v1/segmentations", json={"targets": sky(30)}).status_code == 200
        cases = [
            ("/v1/segmentations", {"targets": sky(31)}, "MXS_MAX_SEGMENTATION_TARGETS=30",
             ["body", "targets"]),
            ("/v1/allocations", {"targets": sky(6), "pointing": {"ra_deg": 150, "dec_deg": 2}},
             "MXS_MAX_ALLOCATION_TARGETS=5", ["body", "targets"]),
            ("/v1/plans", {"targets": sky(5)}, "MXS_MAX_PLAN_TARGETS=4", ["body", "targets"]),
            ("/v1/jobs", {"kind": "plan", "request": {"targets": sky(7)}},
             "MXS_MAX_PLAN_JOB_TARGETS=6", ["body", "plan", "request", "targets"]),
            ("/v1/jobs", {"kind": "segmentation", "request": {"targets": sky(31)}},
             "MXS_MAX_SEGMENTATION_TARGETS=30", ["body", "segmentation", "request", "targets"]),
        ]
        for path, body, setting, loc in cases:
            r = c.post(path, json=body)
            assert r.status_code == 422, (path, r.text)
            assert setting in message(r) and r.json()["detail"][0]["loc"] == loc, (path, r.text)
        # a plan job may be bigger than a synchronous plan
        assert c.post("/v1/jobs", json={"kind": "plan", "request": {"targets": sky(6)}}
                      ).status_code == 202
        # a stored list over the stage's limit: the 422 names target_list_id
        lid = upload(c, "l.csv", csv_bytes(sky(31)))["target_list_id"]
        r = c.post("/v1/segmentations", json={"target_list_id": lid})
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "target_list_id"]
        assert "MXS_MAX_SEGMENTATION_TARGETS=30" in message(r) and lid in message(r)
    with limited(tmp_path, max_targets=3) as c:  # the global cap names itself
        r = c.post("/v1/segmentations", json={"targets": sky(4)})
        assert r.status_code == 422 and "MXS_MAX_TARGETS=3" in message(r)


def test_each_route_has_its_own_body_limit_named_in_the_413(tmp_path: Path) -> None:
    with limited(tmp_path, max_body_bytes=4000, max_segmentation_body_bytes=20_000,
                 max_job_body_bytes=8000, max_upload_bytes=6000) as c:
        body = {"targets": sky(100)}  # about 9 kB of JSON
        assert c.post("/v1/segmentations", json=body).status_code == 200
        for path, payload, setting in (
                ("/v1/plans", body, "MXS_MAX_BODY_BYTES=4000"),
                ("/v1/segmentations", {"targets": sky(300)}, "MXS_MAX_SEGMENTATION_BODY_BYTES=20000"),
                ("/v1/jobs", {"kind": "segmentation", "request": body}, "MXS_MAX_JOB_BODY_BYTES=8000")):
            r = c.post(path, json=payload)
            assert r.status_code == 413 and setting in r.json()["detail"], (path, r.text)
        r = c.post("/v1/target-lists", files={"file": ("t.csv", csv_bytes(sky(200)))})
        assert r.status_code == 413 and "MXS_MAX_UPLOAD_BYTES=6000" in r.json()["detail"]


# ------------------------------------------------------- referencing a stored list


def test_targets_and_target_list_id_exactly_one(client: TestClient) -> None:
    lid = upload(client, "t.csv", csv_bytes(sky(3)))["target_list_id"]
    for extra, why in (({"targets": sky(3), "target_list_id": lid}, "not both"),
                       ({}, "give targets")):
        for path, body, loc in (
                ("/v1/segmentations", extra, ["body", "target_list_id"]),
                ("/v1/plans", extra, ["body", "target_list_id"]),
                ("/v1/jobs", {"kind": "plan", "request": extra},
                 ["body", "plan", "request", "target_list_id"])):
            r = client.post(path, json=body)
            assert r.status_code == 422, (path, r.text)
            (err,) = r.json()["detail"]
            assert err["loc"] == loc and why in err["msg"], (path, err)


def test_unknown_target_list_id_is_not_found(client: TestClient) -> None:
    """A `target_list_id` naming no stored list is a missing resource: 404 `not_found`
    naming the field and the id, from every route that resolves one and as a job."""
    for path, body, where in (
            ("/v1/segmentations", {"target_list_id": "nosuchlist"}, "body.target_list_id"),
            ("/v1/plans", {"target_list_id": "nosuchlist"}, "body.target_list_id"),
            ("/v1/jobs", {"kind": "segmentation", "request": {"target_list_id": "nosuchlist"}},
             "body.segmentation.request.target_list_id"),
            ("/v1/jobs", {"kind": "plan", "request": {"target_list_id": "nosuchlist"}},
             "body.plan.request.target_list_id")):
        r = client.post(path, json=body)
        assert r.status_code == 404, (path, r.text)
        out = r.json()
        assert out["error"] == "not_found", (path, out)
        assert out["detail"].startswith(f"{where}: no stored target list 'nosuchlist'"), out
    r = client.get("/v1/target-lists/nosuchlist")
    assert r.status_code == 404 and "nosuchlist" in r.json()["detail"]


def test_an_error_in_a_stored_list_names_its_row(client: TestClient) -> None:
    lid = upload(client, "far.csv", b"id,ra,dec\na,0,0\nb,179,0\nc,90,0\n")["target_list_id"]
    body = {"tangent_point": {"ra_deg": 0, "dec_deg": 0}}
    inline = client.post("/v1/segmentations", json={**body, "targets": [
        {"id": i, "ra_deg": ra, "dec_deg": 0, "priority": 1}
        for i, ra in (("a", 0.0), ("b", 179.0), ("c", 90.0))]})
    assert inline.status_code == 422
    assert inline.json()["detail"][0]["loc"] == ["body", "targets", 1, "dec_deg"]
    r = client.post("/v1/segmentations", json={**body, "target_list_id": lid})
    assert r.status_code == 422
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "target_list_id"] and f"{lid!r} row 2 (dec_deg)" in err["msg"]


def test_retention_deletes_the_oldest_lists(tmp_path: Path) -> None:
    with limited(tmp_path, target_list_retention_count=2) as c:
        ids = [upload(c, f"{k}.csv", csv_bytes(sky(2, seed=k)))["target_list_id"]
               for k in range(3)]
        assert c.get(f"/v1/target-lists/{ids[0]}").status_code == 404
        assert [c.get(f"/v1/target-lists/{i}").status_code for i in ids[1:]] == [200, 200]
        r = c.post("/v1/segmentations", json={"target_list_id": ids[0]})
        assert r.status_code == 404 and "at most the newest 2" in r.json()["detail"]


def test_a_job_by_list_id_carries_the_targets(tmp_path: Path) -> None:
    """The job's stored request holds the list's targets, so a list deleted later cannot
    break it; its result equals the endpoint's."""
    targets = sky(40, side_deg=0.3)
    with limited(tmp_path, workers=1) as c:
        lid = upload(c, "t.csv", csv_bytes(targets))["target_list_id"]
        r = c.post("/v1/jobs", json={"kind": "segmentation", "request": {"target_list_id": lid}})
        assert r.status_code == 202, r.text
        job_id = r.json()["job_id"]
        job = until(lambda: (j := c.get(f"/v1/jobs/{job_id}").json())["status"] in
                    ("done", "failed") and j, 60, "the job")
        assert job["status"] == "done", job
        direct = c.post("/v1/segmentations", json={"targets": targets}).json()
        assert job["result"]["pointings"] == direct["pointings"]
    con = sqlite3.connect(tmp_path / "j.sqlite3")
    (request,) = con.execute("SELECT request FROM jobs WHERE job_id = ?", (job_id,)).fetchone()
    con.close()
    assert json.loads(request)["targets"] == targets and "target_list_id" not in json.loads(request)


# ------------------------------------------- a synchronous plan and the event loop


def _warm_workers(url: str, n: int) -> None:
    """``n`` concurrent small requests, so that every heavy worker process has warmed up
    (a request waits for its worker's warm-up before its time limit starts counting)."""
    small = {"targets": sky(3, side_deg=0.01, seed=1)}
    posts = [threading.Thread(target=lambda: httpx.post(url + "/v1/segmentations", json=small,
                                                         timeout=120)) for _ in range(n)]
    for t in posts:
        t.start()
    for t in posts:
        t.join()


def test_synchronous_plan_keeps_its_budget_and_the_event_loop_free(tmp_path: Path) -> None:
    """A many-pointing POST /v1/plans takes one heavy slot, answers within its time limit
    + 1 s (pointings past it are `no_time`), and /v1/health answers promptly meanwhile."""
    targets = sky(240, side_deg=0.6, seed=5)
    limit_s = 2.0
    # niceness 0: the budget is under test here, against the test run's other processes
    # (the niced workers are tested in tests/test_sync_workers.py)
    app = create_app(Settings(job_db=tmp_path / "j.sqlite3", heavy_threads=2, heavy_nice=0))
    with serve(app) as url:
        _warm_workers(url, n=2)
        out: dict[str, Any] = {}

        def post() -> None:
            t0 = time.monotonic()
            r = httpx.post(url + "/v1/plans", json={"targets": targets, "seed": 1,
                                                     "time_limit_s": limit_s}, timeout=60)
            out.update(status=r.status_code, body=r.json(), wall_s=time.monotonic() - t0)

        poster = threading.Thread(target=post)
        poster.start()
        until(lambda: app.state.mxs.heavy.in_use == 1, 10, "the plan to start")
        health_s, in_use = [], []
        while poster.is_alive():
            t0 = time.monotonic()
            assert httpx.get(url + "/v1/health", timeout=5).status_code == 200
            health_s.append(time.monotonic() - t0)
            in_use.append(app.state.mxs.heavy.in_use)
            time.sleep(0.05)
        poster.join()
    assert out["status"] == 200, out
    body = out["body"]
    assert len(body["pointings"]) >= 5, "the field must need several pointings"
    # documented: within the limit + 1 s; one more second of slack for a loaded machine (the
    # whole field, unbounded, takes far longer: its last pointings are `no_time` below)
    assert out["wall_s"] <= limit_s + 2.0, out["wall_s"]
    reasons = {u["reason"] for p in body["pointings"] for u in p["unallocated"]}
    assert "no_time" in reasons, "the budget must have cut the plan short"
    # a blocked loop would hold /v1/health for the whole plan (>= the 2 s limit); a loaded
    # 2-core machine has delayed one answer by just over 1 s
    assert len(health_s) >= 5 and max(health_s) < 1.5, health_s
    assert float(np.median(health_s)) < 0.2, health_s
    assert max(in_use) == 1  # one request, one slot, whatever it does per pointing
