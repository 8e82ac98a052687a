"""Reliability of the service: admission and cancellation of heavy requests, liveness under
saturation, job leases across servers, worker processes that die with their server, the job
queue bound, result retention, submission checks, and slow request bodies."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from service import pipeline
from service.app import create_app
from service.jobpool import JobManager, PoolOptions
from service.jobs import INTERRUPTED, JobStore
from service.settings import Settings
from tests.conftest import free_port

ROOT = Path(__file__).resolve().parent.parent
SEG = {"targets": [{"id": f"s{i}", "ra_deg": 34.75 + 0.002 * i, "dec_deg": 57.13, "priority": 1}
                   for i in range(5)]}


@contextmanager
def serve(app: FastAPI) -> Iterator[str]:
    """``app`` under uvicorn in a thread of this process (so monkeypatches apply)."""
    import uvicorn

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    until(lambda: _answers(url), 20, "server start")
    try:
        yield url
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def _answers(url: str) -> bool:
    try:
        return httpx.get(url + "/v1/health", timeout=1).status_code == 200
    except httpx.HTTPError:
        return False


def until(cond: Callable[[], Any], timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = cond()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state not in ("Z", "X")


class SlowStage:
    """A stand-in segmentation that runs until told to stop or cancelled via progress, in the
    server's heavy threads (``heavy_processes=False``: its events live in this process)."""

    def __init__(self) -> None:
        self.started = threading.Semaphore(0)
        self.release = threading.Event()
        self.stopped: list[str] = []

    def __call__(self, req: Any, inst: Any, progress: Callable[[float], None]) -> dict[str, Any]:
        self.started.release()
        outcome = "cancelled"
        try:
            for _ in range(400):  # at most 20 s
                progress(0.5)
                if self.release.wait(0.05):
                    outcome = "finished"
                    return {"tangent_point": {"ra_deg": 0.0, "dec_deg": 0.0}, "pointings": [],
                            "stats": {}}
            outcome = "ran out"
            raise RuntimeError("never released")
        finally:
            self.stopped.append(outcome)


# ----------------------------------------------------------------- heavy requests


def test_saturated_executor_refuses_at_once_and_health_answers(tmp_path, monkeypatch) -> None:
    slow = SlowStage()
    monkeypatch.setattr(pipeline, "segmentation", slow)
    app = create_app(Settings(job_db=tmp_path / "j.db", heavy_threads=1, heavy_queue=1,
                              retry_after_s=7, heavy_processes=False))
    with serve(app) as url:
        results: list[int] = []

        def post() -> None:
            results.append(httpx.post(url + "/v1/segmentations", json=SEG, timeout=30).status_code)

        posters = [threading.Thread(target=post) for _ in range(2)]
        posters[0].start()
        assert slow.started.acquire(timeout=10)  # one computing
        posters[1].start()
        until(lambda: app.state.mxs.heavy.in_use == 2, 10, "the second request queued")
        # full: a third is refused at once with Retry-After, documented in the contract
        t0 = time.monotonic()
        r = httpx.post(url + "/v1/segmentations", json=SEG, timeout=10)
        assert r.status_code == 503 and r.headers["retry-after"] == "7", r.text
        assert r.json()["error"] == "overloaded"
        assert time.monotonic() - t0 < 5
        # liveness answers, readiness says not ready (with Retry-After)
        for _ in range(20):
            h = httpx.get(url + "/v1/health", timeout=2)
            assert h.status_code == 200 and h.json()["status"] == "ok"
        assert httpx.get(url + "/v1/health/live", timeout=2).status_code == 200
        ready = httpx.get(url + "/v1/health/ready", timeout=5)
        assert ready.status_code == 503 and ready.headers["retry-after"] == "7"
        assert ready.json()["heavy_in_use"] == 2 == ready.json()["heavy_capacity"]
        assert httpx.get(url + "/v1/instrument", timeout=2).status_code == 200
        slow.release.set()
        for t in posters:
            t.join(timeout=30)
        assert sorted(results) == [200, 200]
        assert httpx.get(url + "/v1/health/ready", timeout=5).status_code == 200
    spec = app.openapi()["paths"]["/v1/segmentations"]["post"]["responses"]["503"]
    assert "Retry-After" in spec["headers"]


def test_work_of_a_client_that_left_stops(tmp_path, monkeypatch) -> None:
    slow = SlowStage()
    monkeypatch.setattr(pipeline, "segmentation", slow)
    app = create_app(Settings(job_db=tmp_path / "j.db", heavy_threads=1, heavy_queue=0,
                              heavy_processes=False))
    with serve(app) as url:
        with pytest.raises(httpx.ReadTimeout):
            httpx.post(url + "/v1/segmentations", json=SEG, timeout=1.0)  # gives up after 1 s
        until(lambda: slow.stopped, 10, "the abandoned computation to stop")
        assert slow.stopped == ["cancelled"]
        until(lambda: app.state.mxs.heavy.in_use == 0, 5, "the slot to be free")


# --------------------------------------------------------------------------- jobs


def test_job_submission_is_checked_like_the_endpoint(tmp_path) -> None:
    app = create_app(Settings(job_db=tmp_path / "j.db", max_targets=6))
    bad = {**SEG, "threshold_mm": 9999}
    with TestClient(app) as c:
        direct = c.post("/v1/segmentations", json=bad)
        job = c.post("/v1/jobs", json={"kind": "segmentation", "request": bad})
        assert direct.status_code == job.status_code == 422
        assert direct.json()["detail"][0]["loc"] == ["body", "threshold_mm"]
        assert job.json()["detail"][0]["loc"] == ["body", "segmentation", "request", "threshold_mm"]
        assert job.json()["detail"][0]["msg"] == direct.json()["detail"][0]["msg"]
        many = {"targets": SEG["targets"] + [dict(t, id=f"x{i}") for i, t in
                                             enumerate(SEG["targets"])]}
        assert c.post("/v1/plans", json=many).status_code == 422
        assert c.post("/v1/jobs", json={"kind": "plan", "request": many}).status_code == 422
        behind = {"targets": [{"id": "a", "ra_deg": 214.75, "dec_deg": -57.13, "priority": 1}],
                  "pointing": {"ra_deg": 34.75, "dec_deg": 57.13}}  # the antipode of the pointing
        direct = c.post("/v1/allocations", json=behind)
        job = c.post("/v1/jobs", json={"kind": "allocation", "request": behind})
        assert direct.status_code == job.status_code == 422, job.text
        assert job.json()["detail"][0]["loc"] == ["body", "allocation", "request", *direct.json()["detail"][0]["loc"][1:]]
        assert JobStore(tmp_path / "j.db").count("queued") == 0


def test_job_queue_is_bounded(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(JobManager, "_keep_workers", lambda self: None)  # nothing consumes
    app = create_app(Settings(job_db=tmp_path / "j.db", max_queued_jobs=3, retry_after_s=9))
    with TestClient(app) as c:
        codes = [c.post("/v1/jobs", json={"kind": "segmentation", "request": SEG}).status_code
                 for _ in range(3)]
        assert codes == [202, 202, 202]
        r = c.post("/v1/jobs", json={"kind": "segmentation", "request": SEG})
        assert r.status_code == 429 and r.headers["retry-after"] == "9", r.text
        assert "queue is full" in r.json()["detail"]
        assert "429" in app.openapi()["paths"]["/v1/jobs"]["post"]["responses"]
    assert JobStore(tmp_path / "j.db").count("queued") == 3


def test_finished_results_expire_with_410(tmp_path) -> None:
    db = tmp_path / "j.db"
    store = JobStore(db)
    store.init()
    ids = []
    for i in range(4):
        j = store.create("segmentation", SEG)
        store.set_done(j, {"tangent_point": {"ra_deg": 0.0, "dec_deg": 0.0}, "pointings": [],
                           "stats": {"n": i}})
        ids.append(j)
        time.sleep(0.01)
    live = store.create("segmentation", SEG)  # an open job is never expired
    assert store.expire(retention_s=3600, retention_count=2) == 2
    app = create_app(Settings(job_db=db, job_retention_count=2))
    with TestClient(app) as c:
        for j in ids[:2]:
            r = c.get(f"/v1/jobs/{j}")
            assert r.status_code == 410 and "expired" in r.json()["detail"], r.text
        assert [c.get(f"/v1/jobs/{j}").json()["result"]["stats"] for j in ids[2:]] == [
            {"n": 2}, {"n": 3}]
        assert c.get(f"/v1/jobs/{live}").status_code == 200
        gone = c.get("/v1/jobs/0123456789abcdef")
        assert gone.status_code == 404 and "kept for" in gone.json()["detail"]
    assert store.expire(retention_s=1e-6, retention_count=100) == 2  # the age rule
    assert store.get(ids[3])["status"] == "expired"


BIG_PLAN: dict[str, Any] = {"targets": [{"id": f"t{i}", "ra_deg": 34.7 + 0.01 * (i % 20),
                         "dec_deg": 57.1 + 0.01 * (i // 20), "priority": 1 + i % 7}
                        for i in range(400)], "time_limit_s": 60}


def test_second_manager_requeues_only_expired_leases(tmp_path) -> None:
    """Two real managers on one database: the job of a dead server, whose lease expired, is
    re-queued (by B's start-up recovery, or by A's lease sweep when it comes first) and run,
    but A's running job is left alone, also in B's later lease sweeps; when A stops, A's job goes back to the queue and B takes it."""
    db = tmp_path / "j.db"
    a = JobManager(db, PoolOptions(workers=1, lease_s=1.5))
    b = None
    try:
        j = a.submit("plan", BIG_PLAN, 60.0, 600.0)
        until(lambda: a.store.get(j)["status"] == "running", 60, "A to run the job")
        orphan = a.store.create("segmentation", SEG, time_limit_s=10.0)
        a.store.set_running(orphan, owner="dead-server/1", lease_s=-1)
        b = JobManager(db, PoolOptions(workers=1, lease_s=1.5))
        # B's start-up recovery re-queues it, unless A's lease sweep (every 0.5 s) came first
        assert b.recovered.failed == 0 and b.recovered.requeued <= 1
        done = until(lambda: (o := b.store.get(orphan))["status"] == "done" and o, 60,
                     "B to run the re-queued job")
        assert {t for p in done["result"]["pointings"] for t in p["target_ids"]} == {
            t["id"] for t in SEG["targets"]}
        time.sleep(2.0)  # longer than a lease: A's heartbeat must have kept it
        job = a.store.get(j)
        assert job["status"] == "running" and job["error"] is None
        a.shutdown()
        assert a.worker_pids() == []
        until(lambda: b.store.get(j)["status"] == "running", 60, "B to take the job over")
    finally:
        a.shutdown()
        if b is not None:
            b.shutdown()


def test_a_job_interrupted_too_often_fails_with_the_reason(tmp_path) -> None:
    store = JobStore(tmp_path / "j.db")
    store.init()
    j = store.create("plan", {})
    for attempt in range(3):
        assert store.claim(f"s{attempt}/1", lease_s=-1) is not None
        rec = store.recover(max_attempts=3)
        assert (rec.requeued, rec.failed) == ((1, 0) if attempt < 2 else (0, 1))
    job = store.get(j)
    assert job["status"] == "failed" and job["error"].startswith(INTERRUPTED)
    assert store.claim("s9/1", lease_s=30) is None


_MANAGER_SCRIPT = """
import sys, time
from service.jobpool import JobManager, PoolOptions
m = JobManager(sys.argv[1], PoolOptions(workers=2))
m.submit("segmentation", {"targets": [{"id": "a", "ra_deg": 1.0, "dec_deg": 2.0}]}, 5.0)
deadline = time.monotonic() + 60
while len(m.worker_pids()) < 2 and time.monotonic() < deadline:
    time.sleep(0.05)
print(*m.worker_pids(), flush=True)
time.sleep(600)
"""


def test_workers_die_when_their_server_is_killed(tmp_path) -> None:
    proc = subprocess.Popen([sys.executable, "-c", _MANAGER_SCRIPT, str(tmp_path / "j.db")],
                            cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        pids = [int(p) for p in proc.stdout.readline().split()]
        assert len(pids) == 2 and all(alive(p) for p in pids)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        until(lambda: not any(alive(p) for p in pids), 5, "orphan workers to exit")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        _kill_alive(pids if "pids" in locals() else [])


def _kill_alive(pids: list[int]) -> None:
    for p in pids:
        if alive(p):
            os.kill(p, signal.SIGKILL)


def children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError, IndexError):
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


@pytest.mark.parametrize("command", [
    ["-m", "uvicorn", "service.app:app"],  # plain uvicorn: no graceful-shutdown timeout
    ["-m", "service.cli", "serve"],
], ids=["uvicorn", "mxs-planner-serve"])
def test_sigterm_on_a_busy_server_is_prompt_and_hands_jobs_back(tmp_path, command) -> None:
    port = free_port()
    env = {**os.environ, "MXS_JOB_DB": str(tmp_path / "j.db"), "MXS_WORKERS": "1",
           "MXS_HEAVY_THREADS": "1", "MXS_RETRY_AFTER_S": "4"}
    proc = subprocess.Popen([sys.executable, *command, "--port", str(port),
                             "--log-level", "warning"], cwd=ROOT, env=env)
    url = f"http://127.0.0.1:{port}"
    answers: list[httpx.Response] = []
    try:
        until(lambda: _answers(url), 30, "server start")
        job = httpx.post(url + "/v1/jobs", json={"kind": "plan", "request": BIG_PLAN}, timeout=10)
        assert job.status_code == 202, job.text
        job_id = job.json()["job_id"]
        client = threading.Thread(target=lambda: answers.append(httpx.post(
            url + "/v1/plans", json=BIG_PLAN, timeout=60)), daemon=True)
        client.start()
        store = JobStore(tmp_path / "j.db")
        until(lambda: store.get(job_id)["status"] == "running", 30, "the job to run")
        until(lambda: httpx.get(url + "/v1/health/ready", timeout=5).json()["heavy_in_use"] == 1,
              30, "the synchronous plan to compute")
        workers = children(proc.pid)
        assert workers
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=15)
        assert time.monotonic() - t0 <= 5.0
        assert store.get(job_id)["status"] == "queued"  # handed back for the next server
        until(lambda: not any(alive(p) for p in workers), 5, "no orphan process")
        client.join(timeout=10)
        (answer,) = answers  # the client in flight is told to retry elsewhere
        assert answer.status_code == 503 and answer.headers["retry-after"] == "4", answer.text
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        _kill_alive(workers if "workers" in locals() else [])


def _ignore(fn: Callable[[], Any]) -> None:
    try:
        fn()
    except httpx.HTTPError:
        pass


# ------------------------------------------------------------------ request bodies


def test_slow_body_is_408(tmp_path) -> None:
    app = create_app(Settings(job_db=tmp_path / "j.db", body_timeout_s=1.0))
    with serve(app) as url:
        port = int(url.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.sendall(b"POST /v1/segmentations HTTP/1.1\r\nHost: x\r\n"
                      b"Content-Type: application/json\r\nContent-Length: 100000\r\n\r\n"
                      b'{"targets": [')
            t0 = time.monotonic()
            answer = b""
            while b"\r\n\r\n" not in answer:
                chunk = s.recv(4096)
                if not chunk:
                    break
                answer += chunk
            assert answer.startswith(b"HTTP/1.1 408"), answer
            assert time.monotonic() - t0 < 8
        assert httpx.get(url + "/v1/health", timeout=2).status_code == 200
        ok = httpx.post(url + "/v1/segmentations", json=SEG, timeout=30)  # normal bodies pass
        assert ok.status_code == 200, ok.text


def test_bodies_in_flight_share_a_memory_budget(tmp_path) -> None:
    app = create_app(Settings(job_db=tmp_path / "j.db", max_body_buffer_bytes=4096,
                              retry_after_s=3))
    with serve(app) as url:
        port = int(url.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.sendall(b"POST /v1/segmentations HTTP/1.1\r\nHost: x\r\n"
                      b"Content-Type: application/json\r\nContent-Length: 100000\r\n\r\n")
            s.sendall(b" " * 8192)
            answer = s.recv(4096)
        assert answer.startswith(b"HTTP/1.1 503") and b"retry-after: 3" in answer.lower(), answer
        # the budget is released with the refused body: a normal request passes
        ok = httpx.post(url + "/v1/segmentations", json=SEG, timeout=30)
        assert ok.status_code == 200, ok.text


def test_a_server_renews_the_leases_of_its_live_workers(tmp_path) -> None:
    store = JobStore(tmp_path / "j.db")
    store.init()
    mine, theirs = store.create("plan", {}), store.create("plan", {})
    assert store.claim("me/1", lease_s=0.2).job_id == mine
    assert store.claim("dead/2", lease_s=0.2).job_id == theirs
    assert store.renew_owners(["me/1"], lease_s=60) == 1
    time.sleep(0.3)
    assert store.recover(max_attempts=3).requeued == 1
    assert (store.get(mine)["status"], store.get(theirs)["status"]) == ("running", "queued")


def test_a_waiting_request_whose_client_left_frees_its_slot_and_never_runs(tmp_path,
                                                                           monkeypatch) -> None:
    slow = SlowStage()
    monkeypatch.setattr(pipeline, "segmentation", slow)
    app = create_app(Settings(job_db=tmp_path / "j.db", heavy_threads=1, heavy_queue=1,
                              heavy_processes=False))
    with serve(app) as url:
        codes: list[int] = []

        def post() -> None:
            codes.append(httpx.post(url + "/v1/segmentations", json=SEG, timeout=30).status_code)

        first = threading.Thread(target=post)
        first.start()
        assert slow.started.acquire(timeout=10)
        with pytest.raises(httpx.ReadTimeout):  # waits for the busy thread, then gives up
            httpx.post(url + "/v1/segmentations", json=SEG, timeout=1.0)
        until(lambda: app.state.mxs.heavy.in_use == 1, 5, "the waiting slot to be freed")
        third = threading.Thread(target=post)
        third.start()
        until(lambda: app.state.mxs.heavy.in_use == 2, 5, "the third request admitted")
        slow.release.set()
        first.join(timeout=30)
        third.join(timeout=30)
        assert codes == [200, 200]
        assert slow.stopped == ["finished", "finished"]  # the abandoned one never started
