"""Cancelling jobs: POST /v1/jobs/{job_id}/cancel stops a queued or running job for good."""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from service.app import create_app
from service.job_run import run_job
from service.jobpool import JobManager, PoolOptions
from service.jobs import CANCELLED, JobStore
from service.settings import Settings
from tests.test_service_jobs import SEG_REQUEST, wait_terminal


def _cpu_s(pid: int) -> float:
    """User + system CPU time of a process so far, s (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _dense_plan(n: int = 600) -> dict:
    """A crowded single-pointing field: dozens of configurations and motion legs (minutes),
    segmented by complete linkage (the job is past its segmentation within a second or two)."""
    rng = np.random.default_rng(7)
    ra, dec = 250.42 + rng.normal(0, 0.006, n), 36.46 + rng.normal(0, 0.006, n)
    return {"targets": [{"id": f"t{i}", "ra_deg": float(ra[i]), "dec_deg": float(dec[i]),
                         "priority": int(1 + i % 5)} for i in range(n)],
            "seed": 1, "time_limit_s": 600, "segmentation_mode": "complete-linkage"}


def test_cancel_a_queued_job_it_never_runs(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    app = create_app(Settings(job_db=db, workers=1))
    with TestClient(app) as c:
        # inserted behind the server's back: no worker is woken for it
        queued = JobStore(db).create("segmentation", SEG_REQUEST)
        r = c.post(f"/v1/jobs/{queued}/cancel")
        assert r.status_code == 200, r.text
        assert (r.json()["status"], r.json()["kind"], r.json()["result"]) == (
            CANCELLED, "segmentation", None)
        # a later job is worked off; the cancelled one is never claimed
        later = c.post("/v1/jobs", json={"kind": "segmentation", "request": SEG_REQUEST})
        done = wait_terminal(lambda j: c.get(f"/v1/jobs/{j}").json(), later.json()["job_id"])
        assert done["status"] == "done"
        job = c.get(f"/v1/jobs/{queued}").json()
        assert (job["status"], job["progress"], job["result"]) == (CANCELLED, 0.0, None)
        assert "cancelled" in job["error"]


def test_cancel_a_running_job_its_worker_stops(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    app = create_app(Settings(job_db=db, workers=1, job_budget_s=600))
    with TestClient(app) as c:
        long = c.post("/v1/jobs", json={"kind": "plan", "request": _dense_plan()}).json()["job_id"]
        deadline = time.monotonic() + 60
        while c.get(f"/v1/jobs/{long}").json()["progress"] < 0.06:  # past the segmentation
            assert time.monotonic() < deadline, c.get(f"/v1/jobs/{long}").json()
            time.sleep(0.1)
        (pid,) = app.state.mxs.jobs.worker_pids()
        t_cancel = time.monotonic()
        r = c.post(f"/v1/jobs/{long}/cancel")
        assert r.status_code == 200 and r.json()["status"] == CANCELLED, r.text
        # the one worker is free again: a small job queued behind the plan is done at once
        quick = c.post("/v1/jobs", json={"kind": "segmentation", "request": SEG_REQUEST})
        done = wait_terminal(lambda j: c.get(f"/v1/jobs/{j}").json(), quick.json()["job_id"])
        assert done["status"] == "done"
        assert time.monotonic() - t_cancel < 30
        # ... and no longer computes the plan (idle, or replaced by a fresh worker)
        if pid in app.state.mxs.jobs.worker_pids():
            before = _cpu_s(pid)
            time.sleep(1.0)
            assert _cpu_s(pid) - before < 0.3
        job = c.get(f"/v1/jobs/{long}").json()
        assert (job["status"], job["result"]) == (CANCELLED, None)
        assert job["progress"] < 1.0


def test_cancel_a_finished_or_unknown_job(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    app = create_app(Settings(job_db=db, workers=1))
    with TestClient(app) as c:
        store = JobStore(db)
        done = store.create("allocation", {"targets": []})
        store.set_done(done, {"configurations": [], "unallocated": [], "stats": {"x": 1}})
        failed = store.create("plan", {"targets": []})
        store.set_failed(failed, "no luck")
        for job_id, status in ((done, "done"), (failed, "failed")):
            r = c.post(f"/v1/jobs/{job_id}/cancel")
            assert r.status_code == 409, r.text
            assert status in r.json()["detail"]
            assert c.get(f"/v1/jobs/{job_id}").json()["status"] == status  # unchanged
        assert c.get(f"/v1/jobs/{done}").json()["result"]["stats"] == {"x": 1}
        queued = store.create("segmentation", SEG_REQUEST)
        assert c.post(f"/v1/jobs/{queued}/cancel").status_code == 200
        assert c.post(f"/v1/jobs/{queued}/cancel").status_code == 409  # cancelled is finished
        r = c.post("/v1/jobs/nope/cancel")
        assert r.status_code == 404 and r.json()["error"] == "not_found"


def _sleep() -> None:
    time.sleep(60)


def test_a_worker_that_does_not_stop_is_killed(tmp_path: Path) -> None:
    """A job in a long call that reports no progress: its server kills the worker once the
    grace period is over."""
    mgr = JobManager(tmp_path / "j.db", PoolOptions(workers=1))
    sleeper = multiprocessing.get_context("spawn").Process(target=_sleep, daemon=True)
    sleeper.start()
    try:
        mgr._procs = [sleeper]
        job = mgr.store.create("plan", {"targets": []})
        assert mgr.store.claim(f"{mgr.instance}/{sleeper.pid}", 30.0) is not None
        assert mgr.store.cancel(job, grace_s=0.5) == "running"
        mgr._kill_cancelled()  # within the grace period: left alone
        assert sleeper.is_alive()
        time.sleep(0.6)
        mgr._kill_cancelled()
        assert not sleeper.is_alive()
        assert mgr.store.overdue_cancelled(mgr.instance) == []  # handed over once
        assert mgr.store.get(job)["status"] == CANCELLED
    finally:
        mgr.shutdown()
        if sleeper.is_alive():
            sleeper.kill()


def test_a_cancelled_stage_stops_at_its_next_progress_report(tmp_path: Path) -> None:
    """The worker's own function: once the flag is up, the stage ends at its next report and
    nothing it computed is recorded."""
    db = tmp_path / "j.db"
    store = JobStore(db)
    store.init()
    job = store.create("segmentation", SEG_REQUEST)
    assert store.claim("me/1", 30.0) is not None
    assert store.cancel(job) == "running"
    flag = threading.Event()
    flag.set()
    assert run_job(str(db), job, "segmentation", SEG_REQUEST, None, 10.0, cancelled=flag) == CANCELLED
    after = store.get(job)
    assert (after["status"], after["result"], after["progress"]) == (CANCELLED, None, 0.0)
    # the same job without the flag runs to its end, but a cancelled job is never reopened
    assert run_job(str(db), job, "segmentation", SEG_REQUEST, None, 10.0) == "done"
    assert store.get(job)["status"] == CANCELLED and store.get(job)["result"] is None


def test_a_job_cancelled_as_it_ends_does_not_get_its_worker_killed(tmp_path: Path) -> None:
    """The worker finished before it saw the cancellation: it says it stopped, so the server
    never kills it later (it may be running its next job by then)."""
    from service.jobpool import _watch

    store = JobStore(tmp_path / "j.db")
    store.init()
    job = store.create("plan", {"targets": []})
    assert store.claim("srv/42", 30.0) is not None
    flag = threading.Event()
    with _watch(store, job, "srv/42", 30.0, flag):
        assert store.cancel(job, grace_s=0.0) == "running"  # the job ends at once
    time.sleep(0.01)
    assert store.overdue_cancelled("srv") == []
