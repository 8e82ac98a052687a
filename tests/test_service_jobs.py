"""Jobs: process pool, SQLite persistence, restart semantics."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx
from fastapi.testclient import TestClient

from service.app import create_app
from service.jobs import INTERRUPTED, JobStore
from service.settings import Settings

SEG_REQUEST = {"targets": [
    {"id": f"s{i}", "ra_deg": 34.75 + 0.002 * i, "dec_deg": 57.13 - 0.001 * i, "priority": 1 + i}
    for i in range(8)
]}


def wait_terminal(get, job_id: str, timeout: float = 60.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = get(job_id)
        assert 0.0 <= job["progress"] <= 1.0
        if job["status"] in ("done", "failed"):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not finish: {job}")


def test_job_over_http(live_server) -> None:
    r = httpx.post(live_server.url + "/v1/jobs",
                   json={"kind": "segmentation", "request": SEG_REQUEST})
    assert r.status_code == 202, r.text
    created = r.json()
    assert created["status"] == "queued"
    job = wait_terminal(lambda j: httpx.get(f"{live_server.url}/v1/jobs/{j}").json(),
                        created["job_id"])
    assert job["status"] == "done", job
    assert job["kind"] == "segmentation" and job["progress"] == 1.0
    ids = sorted(t for p in job["result"]["pointings"] for t in p["target_ids"])
    assert ids == sorted(t["id"] for t in SEG_REQUEST["targets"])


def test_job_survives_server_restart(tmp_path: Path) -> None:
    db = tmp_path / "jobs.sqlite3"
    settings = Settings(job_db=db, workers=1, job_max_attempts=1)

    # first server: one job runs to its end in a worker process; another is left "running"
    # with a lease that has already expired (as after a kill -9), a third is finished
    app1 = create_app(settings)
    with TestClient(app1) as c:
        jobs = app1.state.mxs.jobs
        finished = jobs.submit("segmentation", SEG_REQUEST, 10.0)
        before = wait_terminal(lambda j: c.get(f"/v1/jobs/{j}").json(), finished)
        assert before["status"] == "done" and before["result"]["pointings"]
        store = JobStore(db)
        fake_done = store.create("allocation", {"targets": []})
        store.set_done(fake_done, {"configurations": [], "unallocated": [], "stats": {"x": 1}})
    in_flight = store.create("plan", {"targets": []})
    store.set_running(in_flight, owner="dead-server/1", lease_s=-1.0)
    store.set_progress(in_flight, 0.4)

    # second server on the same database file: the expired job has had its one attempt
    app2 = create_app(settings)
    with TestClient(app2) as c:
        after = c.get(f"/v1/jobs/{finished}").json()
        assert after == before
        lost = c.get(f"/v1/jobs/{in_flight}").json()
        assert lost["status"] == "failed" and lost["error"].startswith(INTERRUPTED)
        assert "lease expired" in lost["error"]
        assert lost["progress"] == 0.4
        kept = c.get(f"/v1/jobs/{fake_done}").json()
        assert kept["status"] == "done" and kept["result"]["stats"] == {"x": 1}


def test_store_never_reopens_a_finished_job(tmp_path: Path) -> None:
    store = JobStore(tmp_path / "j.db")
    store.init()
    j = store.create("plan", {})
    store.set_done(j, {"ok": True})
    store.set_failed(j, "late failure")
    store.set_progress(j, 0.1)
    job = store.get(j)
    assert job is not None
    assert (job["status"], job["result"], job["error"], job["progress"]) == (
        "done", {"ok": True}, None, 1.0)
    assert store.recover(max_attempts=3).requeued == 0  # nothing to interrupt


def test_invalid_job_request_fails_cleanly_in_worker(tmp_path: Path) -> None:
    """A request that slips past the HTTP layer still ends as a failed job, never a hang."""
    app = create_app(Settings(job_db=tmp_path / "j.db", workers=1))
    with TestClient(app) as c:
        jobs = app.state.mxs.jobs
        j = jobs.submit("segmentation", {"targets": [{"id": "a", "ra_deg": 400}]}, 10.0)
        job = wait_terminal(lambda k: c.get(f"/v1/jobs/{k}").json(), j)
        assert job["status"] == "failed"
        assert "ra_deg" in job["error"]


def test_allocation_and_plan_jobs_over_http(live_server) -> None:
    """The allocation and whole-pipeline stages run in the process pool with progress."""
    alloc = {"targets": [{"id": f"a{i}", "x_mm": 40.0 * i - 60, "y_mm": 10.0 * i, "priority": 2**32 - 1 - i}
                         for i in range(4)], "configurations": "all", "seed": 2, "time_limit_s": 5}
    plan = {"targets": SEG_REQUEST["targets"][:3], "seed": 1, "time_limit_s": 3}
    ids = {}
    for kind, req in (("allocation", alloc), ("plan", plan)):
        r = httpx.post(live_server.url + "/v1/jobs", json={"kind": kind, "request": req})
        assert r.status_code == 202, r.text
        ids[kind] = r.json()["job_id"]
    get = lambda j: httpx.get(f"{live_server.url}/v1/jobs/{j}").json()  # noqa: E731
    a = wait_terminal(get, ids["allocation"], timeout=120)
    assert a["status"] == "done", a
    assert a["progress"] == 1.0
    res = a["result"]
    assert {x["target_id"] for c in res["configurations"] for x in c["assignments"]
            if x["target_id"]} | {u["target_id"] for u in res["unallocated"]} == {t["id"] for t in alloc["targets"]}
    assert all(type(c["total_priority"]) is int for c in res["configurations"])
    p = wait_terminal(get, ids["plan"], timeout=120)
    assert p["status"] == "done", p
    out = p["result"]
    assert sorted(t for q in out["pointings"] for t in q["target_ids"]) == sorted(
        t["id"] for t in plan["targets"])
    for q in out["pointings"]:
        assert len(q["motions"]) == len(q["configurations"]) + 1
        assert q["executable"] == all(m["status"] == "ok" for m in q["motions"])
    assert out["executable"] == all(q["executable"] for q in out["pointings"])


def test_default_job_database_is_under_an_ignored_data_directory(tmp_path: Path,
                                                                  monkeypatch) -> None:
    monkeypatch.delenv("MXS_JOB_DB", raising=False)
    default = Settings().job_db
    assert not default.is_absolute() and default.parts[0] == "data"
    ignored = (Path(__file__).resolve().parents[1] / ".gitignore").read_text().splitlines()
    assert "/data/" in ignored
    monkeypatch.chdir(tmp_path)
    JobStore(default).init()  # the directory is created
    assert (tmp_path / default).is_file()


def test_a_result_stored_under_an_older_schema_is_answered_as_stored(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    store = JobStore(db)
    store.init()
    old = store.create("segmentation", SEG_REQUEST)
    store.set_done(old, {"clusters": [[0, 1]]})  # not a SegmentationResponse
    with TestClient(create_app(Settings(job_db=db))) as c:
        r = c.get(f"/v1/jobs/{old}")
    assert r.status_code == 200, r.text
    assert (r.json()["status"], r.json()["result"]) == ("done", {"clusters": [[0, 1]]})
