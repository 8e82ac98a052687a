"""Plan jobs as whole programmes: one task per pointing, committed as it finishes, on the
local pool or a dask.distributed cluster; resumed after an interruption."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from distributed import LocalCluster
from fastapi.testclient import TestClient

from planner import programme as programme_policy
from planner.plan_file import content_hash
from service import job_run, jobs, pipeline
from service.app import create_app
from service.errors import json_safe
from service.runners import DaskRunner, LocalPoolRunner
from service.schemas import PlanRequest
from service.settings import Settings

INST = pipeline.instrument_from(None)
# three clumps of two targets, 0.2 deg apart: three pointings (the FOV is 5 arcmin wide)
TARGETS = [{"id": f"t{i}", "ra_deg": 150.0 + 0.2 * (i % 3) + 0.0006 * i,
            "dec_deg": 2.0 + 0.0004 * i, "priority": 1 + i % 4} for i in range(6)]
REQUEST = {"targets": TARGETS, "seed": 3, "time_limit_s": 60}


def content(plan: dict[str, Any]) -> Any:
    """A plan without its ``stats`` (compute times differ from run to run) and so without its
    ``content_hash`` (which covers them), as JSON."""
    def strip(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if k not in ("stats", "content_hash")}
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v

    return strip(json.loads(json.dumps(json_safe(plan))))


@pytest.fixture(scope="module")
def reference() -> dict[str, Any]:
    """The synchronous pipeline's plan of REQUEST, as POST /v1/plans computes it (the oracle
    of every job path)."""
    return pipeline.plan(PlanRequest.model_validate(REQUEST), INST, budget_s=120.0)


@pytest.fixture(scope="module")
def cluster() -> Iterator[LocalCluster]:
    """Two single-thread Dask workers in this process, behind a TCP scheduler (so that the
    job pool's processes can reach it)."""
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, protocol="tcp",
                      host="127.0.0.1", dashboard_address=None) as c:
        yield c


def new_job(tmp_path: Path, owner: str = "srv/1") -> tuple[jobs.JobStore, str]:
    store = jobs.JobStore(tmp_path / "j.db")
    store.init()
    job_id = store.create("plan", REQUEST, time_limit_s=10.0, budget_s=3600.0)
    claimed = store.claim(owner, lease_s=60.0)
    assert claimed is not None and claimed.job_id == job_id
    return store, job_id


class Counting(LocalPoolRunner):
    """The local runner, recording the pointings it computes; ``die_after`` simulates a kill
    of its process once that many pointings are committed."""

    def __init__(self, die_after: int | None = None):
        super().__init__()
        self.computed: list[int] = []
        self.die_after = die_after

    def compute(self, task, inst, progress):
        if self.die_after is not None and len(self.computed) == self.die_after:
            raise Killed()
        self.computed.append(task.index)
        return super().compute(task, inst, progress)


class Killed(BaseException):  # noqa: N818 - like SIGKILL: nothing catches it
    pass


def test_reference_has_several_pointings(reference) -> None:
    assert len(reference["pointings"]) == 3
    assert all(p["configurations"] for p in reference["pointings"])


def test_pointing_seeds_are_fixed_per_index() -> None:
    seeds = [programme_policy.pointing_seed(3, i) for i in range(100)]
    assert seeds[0] == 3 and len(set(seeds)) == 100
    assert all(0 <= s < 2**31 for s in seeds)
    assert seeds == [programme_policy.pointing_seed(3, i) for i in range(100)]


def test_pointing_shares_follow_need_and_stay_within_the_limit() -> None:
    assert programme_policy.pointing_shares(None, [1.0, 2.0, 3.0]) == [float("inf")] * 3
    shares = programme_policy.pointing_shares(100.0, [10.0, 10.0, 20.0, 60.0])
    assert shares[0] == shares[1] and shares[2] == pytest.approx(2 * shares[0])
    assert shares[3] == pytest.approx(6 * shares[0])
    assert sum(shares) == pytest.approx(programme_policy.usable_s(100.0)) and sum(shares) <= 100.0
    # a tiny need still gets the minimum, taken from the others
    tiny = programme_policy.pointing_shares(10.0, [1.0, 1000.0])
    assert tiny[0] == programme_policy.SHARES.min_pointing_s and sum(tiny) == pytest.approx(9.5)
    # 1.2 s cannot give 5 pointings 0.5 s each: 2 get it, 3 none
    short = programme_policy.pointing_shares(1.2, [1.0] * 5)
    assert short == [programme_policy.SHARES.min_pointing_s] * 2 + [0.0] * 3


def test_dask_job_over_http_equals_the_synchronous_plan(tmp_path, cluster, reference) -> None:
    """POST /v1/jobs -> a job-pool process -> one Dask task per pointing on two workers;
    the answer equals the synchronous plan (what POST /v1/plans answers) for the same request
    and seed."""
    settings = Settings(job_db=tmp_path / "j.db", workers=1,
                        dask_scheduler=cluster.scheduler_address)
    with TestClient(create_app(settings)) as c:
        r = c.post("/v1/jobs", json={"kind": "plan", "request": REQUEST})
        assert r.status_code == 202, r.text
        job_id = r.json()["job_id"]
        deadline = time.monotonic() + 60
        while (job := c.get(f"/v1/jobs/{job_id}").json())["status"] not in ("done", "failed"):
            assert time.monotonic() < deadline, job
            time.sleep(0.1)
    assert job["status"] == "done", job
    assert (job["pointings_done"], job["pointings_total"], job["progress"]) == (3, 3, 1.0)
    assert job["result"]["stats"]["engine"] == "dask"
    assert content(job["result"]) == content(reference)
    assert job["result"]["content_hash"] == content_hash(job["result"])  # the bytes served hash to it


def test_interrupted_job_resumes_from_its_finished_pointings(tmp_path, reference) -> None:
    """Killed after 2 of 3 pointings, re-queued, resumed by another server: done with the 3
    pointings, the first 2 exactly as committed, and only the third computed again."""
    store, job_id = new_job(tmp_path, owner="old/1")
    first = Counting(die_after=2)
    with pytest.raises(Killed):
        job_run.run_job(str(store.db_path), job_id, "plan", REQUEST, None, 10.0, 3600.0,
                     owner="old/1", runner=first)
    assert first.computed == [0, 1]
    job = store.get(job_id)
    assert job is not None and job["status"] == "running"
    assert (job["pointings_done"], job["pointings_total"]) == (2, 3)
    assert job["progress"] == pytest.approx(0.05 + 0.8 * 2 / 3)  # round 1 counts pointings
    committed = store.pointing_results(job_id)
    assert sorted(committed) == [0, 1]

    assert store.recover(max_attempts=3, owner="old/1").requeued == 1  # its process died
    claimed = store.claim("new/2", lease_s=60.0)
    assert claimed is not None and claimed.job_id == job_id
    second = Counting()
    assert job_run.run_job(str(store.db_path), job_id, "plan", claimed.request, None, 10.0,
                        3600.0, owner="new/2", runner=second) == "done"
    assert second.computed == [2]
    job = store.get(job_id)
    assert job is not None and job["status"] == "done" and job["progress"] == 1.0
    result = job["result"]
    assert [p["id"] for p in result["pointings"]] == [p["id"] for p in reference["pointings"]]
    assert result["pointings"][:2] == [committed[0], committed[1]]  # unchanged, stats included
    assert (result["stats"]["pointings_resumed"], result["stats"]["pointings_computed"]) == (2, 1)
    assert content(result) == content(reference)
    assert result["content_hash"] == content_hash(result)


def test_a_job_that_is_no_longer_ours_stops_and_commits_nothing_more(tmp_path, cluster) -> None:
    """Its lease taken over (or the job cancelled) after the first pointing: the runner stops
    submitting, cancels its Dask tasks and the job is left to its new owner."""
    store, job_id = new_job(tmp_path, owner="old/1")
    commit = store.commit_pointing

    def commit_then_lose(job: str, owner: str, index: int, answer: dict, **kw: Any) -> bool:
        ok = commit(job, owner, index, answer, **kw)
        with jobs._closing(jobs.connect(store.db_path)) as con:
            con.execute("UPDATE jobs SET owner='other/9' WHERE job_id=?", (job,))
        return ok

    store.commit_pointing = commit_then_lose  # type: ignore[method-assign]
    runner = DaskRunner(cluster.scheduler_address, window=1)
    from service import programme
    out = programme.run_plan(store, job_id, "old/1", REQUEST, INST, runner, budget_s=3600.0)
    client = runner.client()
    assert out is None
    job = store.get(job_id)
    assert job is not None and job["status"] == "running" and job["pointings_done"] == 1
    assert len(store.pointing_results(job_id)) == 1
    assert not store.commit_pointing(job_id, "old/1", 2, {"id": "x"})  # refused
    deadline = time.monotonic() + 1.0  # far less than a pointing takes
    while any(client.processing().values()):
        assert time.monotonic() < deadline, "a cancelled pointing task kept running"
        time.sleep(0.05)
    runner.close()


ROOT = Path(__file__).resolve().parents[1]


def test_the_base_install_runs_without_dask() -> None:
    """Without the 'distributed' extra the service imports and uses the local pool, and a
    scheduler address is refused with a message naming the setting and the extra."""
    code = (
        "import sys\n"
        "sys.modules['distributed'] = None; sys.modules['dask'] = None\n"
        "import service.app, service.jobpool\n"
        "from service.runners import make_runner\n"
        "from service.settings import Settings\n"
        "print(make_runner(Settings().dask_scheduler).name)\n"
        "try:\n"
        "    Settings(dask_scheduler='tcp://h:8786')\n"
        "except ValueError as exc:\n"
        "    print(exc)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("MXS_DASK_SCHEDULER", None)
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    first, rest = r.stdout.split("\n", 1)
    assert first == "local"
    assert "MXS_DASK_SCHEDULER" in rest and "[distributed]" in rest


def test_compose_has_an_optional_dask_cluster_from_the_same_image() -> None:
    compose = yaml.safe_load((ROOT / "compose.yaml").read_text())
    services = compose["services"]
    assert "profiles" not in services["api"]  # `docker compose up` starts the API alone
    for name, command in (("scheduler", ["dask", "scheduler"]),
                          ("worker", ["dask", "worker", "tcp://scheduler:8786"])):
        s = services[name]
        assert s["profiles"] == ["dask"] and s["image"] == services["api"]["image"], name
        assert s["command"][:len(command)] == command, name
    assert "MXS_DASK_SCHEDULER" in services["api"]["environment"]
    assert 'pip install ".[${EXTRAS}]"' in (ROOT / "Dockerfile").read_text()


def test_an_unreachable_scheduler_fails_the_job_with_the_reason(tmp_path) -> None:
    store, job_id = new_job(tmp_path)
    runner = DaskRunner(f"tcp://127.0.0.1:{_closed_port()}", connect_timeout_s=1.0)
    assert job_run.run_job(str(store.db_path), job_id, "plan", REQUEST, None, 10.0, 3600.0,
                        owner="srv/1", runner=runner) == "failed"
    job = store.get(job_id)
    assert job is not None and job["status"] == "failed"
    assert "Dask scheduler at tcp://127.0.0.1:" in job["error"] and "did not answer" in job["error"]


def _closed_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_job_finished_elsewhere_stops_the_local_runner_inside_its_pointing(tmp_path) -> None:
    """The job leaves the open states (cancelled, or failed by another server) while its
    second pointing is computed: that pointing stops at its next progress report, nothing
    more is committed and the job is left as it is."""
    from service import programme

    store, job_id = new_job(tmp_path, owner="srv/1")

    class CloseDuringSecond(Counting):
        def __init__(self) -> None:
            super().__init__()
            self.returned: list[int] = []

        def compute(self, task, inst, progress):
            if task.index == 1:
                with jobs._closing(jobs.connect(store.db_path)) as con:
                    con.execute("UPDATE jobs SET status='failed', error='closed elsewhere' "
                                "WHERE job_id=?", (job_id,))
            out = super().compute(task, inst, progress)
            self.returned.append(task.index)
            return out

    runner = CloseDuringSecond()
    runner.poll_s = 0.0
    assert programme.run_plan(store, job_id, "srv/1", REQUEST, INST, runner,
                              budget_s=3600.0) is None
    assert runner.computed == [0, 1] and runner.returned == [0]  # the second one was cut short
    job = store.get(job_id)
    assert job is not None and (job["status"], job["error"]) == ("failed", "closed elsewhere")
    assert sorted(store.pointing_results(job_id)) == [0]


def test_a_cancelled_dask_job_stops_submitting_and_cancels_its_tasks(tmp_path, cluster,
                                                                    monkeypatch) -> None:
    """POST /v1/jobs/{id}/cancel's store call after the first pointing: the job ends
    `cancelled` with no result, its other Dask tasks are cancelled and nothing more is
    committed."""
    store, job_id = new_job(tmp_path, owner="srv/1")
    commit = jobs.JobStore.commit_pointing

    def commit_then_cancel(self, job: str, owner: str, index: int, answer: dict, **kw: Any) -> bool:
        ok = commit(self, job, owner, index, answer, **kw)
        self.cancel(job)
        return ok

    monkeypatch.setattr(jobs.JobStore, "commit_pointing", commit_then_cancel)
    runner = DaskRunner(cluster.scheduler_address, window=1)
    assert job_run.run_job(str(store.db_path), job_id, "plan", REQUEST, None, 10.0, 3600.0,
                        owner="srv/1", runner=runner) == jobs.CANCELLED
    client = runner.client()
    deadline = time.monotonic() + 1.0  # far less than a pointing takes
    while any(client.processing().values()):
        assert time.monotonic() < deadline, "a cancelled pointing task kept running"
        time.sleep(0.05)
    runner.close()
    job = store.get(job_id)
    assert job is not None and (job["status"], job["result"]) == (jobs.CANCELLED, None)
    assert job["pointings_done"] == 1 and sorted(store.pointing_results(job_id)) == [0]
