"""Synchronous stage requests computed in worker processes (service.sync_workers): where the
work runs, that the answers are the server's own, and what a hung, crashed or abandoned
worker gives the client (never a 500).

The stand-in stages are module-level functions: a worker process imports them by name, as it
imports ``service.pipeline``'s own."""

from __future__ import annotations

import json
import multiprocessing
import os
import pickle
import signal
import socket
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from models.errors import InputError, TimeLimitExceeded
from service import pipeline
from service.app import create_app
from service.errors import FieldError
from service.settings import Settings
from service.sync_workers import RemoteError
from tests.test_service_reliability import alive, serve, until

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples" / "requests"
SEG = {"targets": [{"id": f"s{i}", "ra_deg": 34.75 + 0.002 * i, "dec_deg": 57.13, "priority": 1}
                   for i in range(5)]}
EMPTY_SEGMENTATION = {"tangent_point": {"ra_deg": 0.0, "dec_deg": 0.0}, "pointings": []}


def _where(req: Any, inst: Any, progress: Any, **_: Any) -> dict[str, Any]:
    """A segmentation answering where it was computed: pid and niceness."""
    progress(0.5)
    return {**EMPTY_SEGMENTATION, "stats": {"pid": os.getpid(), "nice": os.nice(0)}}


def _hang(req: Any, inst: Any, progress: Any, **_: Any) -> dict[str, Any]:
    """A computation stuck where it reports no progress (a long call in compiled code)."""
    time.sleep(120)
    raise AssertionError("never woken")


def _crash(req: Any, inst: Any, progress: Any, **_: Any) -> dict[str, Any]:
    """A worker that dies mid-request (as by a segfault or the OOM killer)."""
    if multiprocessing.parent_process() is None:  # never the test's own process
        raise RuntimeError("not in a worker process")
    os.kill(os.getpid(), signal.SIGKILL)
    raise AssertionError("killed")


def _spin(req: Any, inst: Any, progress: Any, **_: Any) -> dict[str, Any]:
    """Reports progress every 50 ms for up to 20 s; writes how it ended to the file named by
    the first target's id."""
    marker = Path(req.targets[0].id)
    _write_whole(marker, "started")
    outcome = "cancelled"
    try:
        for _ in range(400):
            progress(0.5)
            time.sleep(0.05)
        outcome = "ran out"
        return {**EMPTY_SEGMENTATION, "stats": {}}
    finally:
        _write_whole(marker, f"{outcome} {os.getpid()}")


def _write_whole(path: Path, text: str) -> None:
    """``text`` into ``path`` at once (a rename): a reader never sees it empty or half written."""
    part = path.with_name(path.name + ".part")
    part.write_text(text)
    part.replace(path)


def _input_error(*_: Any, **__: Any) -> dict[str, Any]:
    raise InputError("targets[3].dec_deg", "too close to the pole")


def _field_error(*_: Any, **__: Any) -> dict[str, Any]:
    raise FieldError(("body", "threshold_mm"), "too wide for this field", "less_than_equal")


def _out_of_time(*_: Any, **__: Any) -> dict[str, Any]:
    raise TimeLimitExceeded("segmentation", 0.5)


def _bug(*_: Any, **__: Any) -> dict[str, Any]:
    raise KeyError("a bug")


def _refuse_in_worker() -> Any:
    if multiprocessing.parent_process() is not None:
        raise ImportError("this stage cannot be imported here")
    return _where


class _Unreadable:
    """A stage that pickles in the server and cannot be unpickled in a worker."""

    def __reduce__(self) -> Any:
        return (_refuse_in_worker, ())


def _app(tmp_path: Path, **settings: Any) -> Any:
    return create_app(Settings(job_db=tmp_path / "j.db", heavy_threads=1, **settings))


def test_stage_work_runs_in_a_niced_worker_process(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _where)
    app = _app(tmp_path)
    with TestClient(app) as c:
        r = c.post("/v1/segmentations", json=SEG)
        assert r.status_code == 200, r.text
        stats = r.json()["stats"]
        assert stats["pid"] != os.getpid()
        assert app.state.mxs.workers.pids() == [stats["pid"]]
        assert stats["nice"] == min(os.nice(0) + 10, 19)
        again = c.post("/v1/segmentations", json=SEG).json()["stats"]
        assert again["pid"] == stats["pid"]  # the worker is kept, not started per request
    assert not alive(stats["pid"])  # and stops with the server


def test_in_thread_mode_computes_in_the_server_process(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _where)
    app = _app(tmp_path, heavy_processes=False)
    with TestClient(app) as c:
        r = c.post("/v1/segmentations", json=SEG)
        assert r.status_code == 200, r.text
        assert r.json()["stats"]["pid"] == os.getpid()
        assert app.state.mxs.workers is None


@pytest.mark.parametrize("name", ["segmentation", "motion_plan"])
def test_a_worker_answers_what_the_server_would(tmp_path, name) -> None:
    """The same example request, computed in a worker and in the server's thread: the same
    answer but for the solve times."""
    path = {"segmentation": "/v1/segmentations", "motion_plan": "/v1/motion-plans"}[name]
    req = json.loads((EXAMPLES / f"{name}.json").read_text())
    answers = []
    for processes in (True, False):
        with TestClient(_app(tmp_path, heavy_processes=processes)) as c:
            r = c.post(path, json=req)
            assert r.status_code == 200, r.text
            assert r.headers["content-type"] == "application/json"
            answers.append(_without_times(r.json()))
    assert answers[0] == answers[1]


TIMINGS = ("time_s", "compute_s", "wall_s", "elapsed_s")


def _without_times(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _without_times(v) for k, v in x.items() if not k.endswith(TIMINGS)}
    if isinstance(x, list):
        return [_without_times(v) for v in x]
    return x


@pytest.mark.parametrize(("fn", "status", "loc"), [
    (_input_error, 422, ["body", "targets", 3, "dec_deg"]),
    (_field_error, 422, ["body", "threshold_mm"]),
    (_out_of_time, 422, ["body", "time_limit_s"]),
])
def test_errors_raised_in_a_worker_are_answered_as_in_the_server(tmp_path, monkeypatch, fn,
                                                                 status, loc) -> None:
    monkeypatch.setattr(pipeline, "segmentation", fn)
    with TestClient(_app(tmp_path)) as c:
        r = c.post("/v1/segmentations", json=SEG)
        assert r.status_code == status, r.text
        assert r.json()["detail"][0]["loc"] == loc


def test_a_bug_in_a_worker_is_503_not_500(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _bug)
    with TestClient(_app(tmp_path), raise_server_exceptions=False) as c:
        r = c.post("/v1/segmentations", json=SEG)
        assert r.status_code == 503, r.text
        assert r.json()["error"] == "internal_error"


def test_a_call_a_worker_cannot_read_is_503_and_the_worker_goes_on(tmp_path,
                                                                  monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _where)
    app = _app(tmp_path)
    with TestClient(app, raise_server_exceptions=False) as c:
        pid = c.post("/v1/segmentations", json=SEG).json()["stats"]["pid"]
        monkeypatch.setattr(pipeline, "segmentation", _Unreadable())
        r = c.post("/v1/segmentations", json=SEG)
        assert r.status_code == 503, r.text
        assert r.json()["error"] == "internal_error"
        assert app.state.mxs.workers.pids() == [pid]


def test_a_hung_worker_is_killed_past_the_time_limit_and_replaced(tmp_path,
                                                                  monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "allocation", _hang)
    monkeypatch.setattr(pipeline, "segmentation", _where)
    req = json.loads((EXAMPLES / "allocation.json").read_text())
    req["time_limit_s"] = 1.0
    app = _app(tmp_path, heavy_kill_grace_s=0.5)
    with TestClient(app) as c:
        first = c.post("/v1/segmentations", json=SEG).json()["stats"]["pid"]
        t0 = time.monotonic()
        r = c.post("/v1/allocations", json=req)
        took_s = time.monotonic() - t0
        assert r.status_code == 422, r.text
        assert r.json()["detail"][0]["loc"] == ["body", "time_limit_s"]
        assert 1.0 <= took_s < 20.0  # limit + grace, far from the stand-in's 120 s
        assert not alive(first)
        after = c.post("/v1/segmentations", json=SEG)  # the slot has a fresh worker
        assert after.status_code == 200, after.text
        assert after.json()["stats"]["pid"] not in (first, os.getpid())


def test_a_worker_that_dies_is_503_with_retry_after_and_replaced(tmp_path,
                                                                 monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _crash)
    app = _app(tmp_path, retry_after_s=9)
    with TestClient(app) as c:
        r = c.post("/v1/segmentations", json=SEG)
        assert r.status_code == 503, r.text
        assert r.headers["retry-after"] == "9"
        assert r.json()["error"] == "worker_lost"
        assert "died" in r.json()["detail"]
        monkeypatch.setattr(pipeline, "segmentation", _where)
        after = c.post("/v1/segmentations", json=SEG)
        assert after.status_code == 200, after.text
        assert after.json()["stats"]["pid"] != os.getpid()


def test_a_client_that_leaves_stops_its_worker_computation(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(pipeline, "segmentation", _spin)
    marker = tmp_path / "marker"
    req = {"targets": [{**SEG["targets"][0], "id": str(marker)}]}
    app = _app(tmp_path)
    body = json.dumps(req).encode()
    with serve(app) as url:
        port = int(url.rsplit(":", 1)[1])
        with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
            s.sendall(b"POST /v1/segmentations HTTP/1.1\r\nHost: x\r\nContent-Type: "
                      b"application/json\r\nContent-Length: " + str(len(body)).encode()
                      + b"\r\n\r\n" + body)
            until(marker.exists, 30, "the computation to start in its worker")
        # the client has left while its computation runs
        until(lambda: marker.read_text() != "started", 10, "the abandoned computation to stop")
        outcome, pid = marker.read_text().split()
        assert outcome == "cancelled"
        assert app.state.mxs.workers.pids() == [int(pid)]  # stopped, not killed
        until(lambda: app.state.mxs.heavy.in_use == 0, 5, "the slot to be free")


def test_remote_errors_keep_their_type_and_fields() -> None:
    for exc in (InputError("targets[2].ra_deg", "out of range"),
                FieldError(("body", "goal", 1, "arm"), "no such arm", "value_error"),
                TimeLimitExceeded("allocation", 2.0)):
        back = pickle.loads(pickle.dumps(RemoteError.of(exc))).rebuild()
        assert type(back) is type(exc)
        assert vars(back) == vars(exc) and str(back) == str(exc)

    class Local(Exception):  # not importable by name: cannot cross the pipe
        pass

    back = RemoteError.of(Local("x")).rebuild()
    assert type(back) is RuntimeError and "Local: x" in str(back)


def test_a_full_server_refuses_before_reading_the_body(tmp_path, monkeypatch) -> None:
    """Every slot taken: a heavy POST whose body never comes is answered 503 + Retry-After
    from its headers alone (a greedy client costs the event loop no parsing)."""
    monkeypatch.setattr(pipeline, "segmentation", _spin)
    marker = tmp_path / "marker"
    req = {"targets": [{**SEG["targets"][0], "id": str(marker)}]}
    app = create_app(Settings(job_db=tmp_path / "j.db", heavy_threads=1, heavy_queue=0,
                              retry_after_s=6))
    with serve(app) as url:
        busy = threading.Thread(target=lambda: _ignore(lambda: httpx.post(
            url + "/v1/segmentations", json=req, timeout=30)), daemon=True)
        busy.start()
        until(lambda: marker.exists(), 20, "the slot to be taken")
        port = int(url.rsplit(":", 1)[1])
        for path in (b"/v1/motion-plans", b"/v1/target-lists"):
            with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
                s.sendall(b"POST " + path + b" HTTP/1.1\r\nHost: x\r\nContent-Type: "
                          b"application/json\r\nContent-Length: 100000\r\n\r\n")
                answer = b""
                while b"}" not in answer and (chunk := s.recv(4096)):
                    answer += chunk
            assert answer.startswith(b"HTTP/1.1 503"), answer
            assert b"retry-after: 6" in answer.lower() and b"overloaded" in answer
        ok = httpx.get(url + "/v1/instrument", timeout=5)  # cheap routes are not refused
        assert ok.status_code == 200
        app.state.mxs.heavy.close()  # stops the busy request
        busy.join(timeout=15)


def _ignore(fn: Any) -> None:
    try:
        fn()
    except httpx.HTTPError:
        pass


def test_job_workers_are_niced_as_the_request_workers(tmp_path) -> None:
    """Jobs and heavy requests share a busy CPU evenly: both worker kinds run at the server's
    niceness + MXS_HEAVY_NICE (read from the kernel, not from the worker)."""
    app = create_app(Settings(job_db=tmp_path / "j.db", heavy_threads=1, workers=1, heavy_nice=7))
    with TestClient(app) as c:
        assert c.post("/v1/jobs", json={"kind": "segmentation", "request": SEG}).status_code == 202
        want = min(os.nice(0) + 7, 19)
        deadline = time.monotonic() + 60
        while True:
            pids = app.state.mxs.jobs.worker_pids()
            if pids and os.getpriority(os.PRIO_PROCESS, pids[0]) == want:
                break
            assert time.monotonic() < deadline, (pids, [os.getpriority(os.PRIO_PROCESS, p) for p in pids])
            time.sleep(0.1)
