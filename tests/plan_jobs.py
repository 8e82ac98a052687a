"""A plan job run to its end in a fresh store, for tests that compare it with the synchronous
plan of the same request."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def plan_job_result(tmp_path: Path, request: dict[str, Any], time_limit_s: float) -> dict[str, Any]:
    """The result of a plan job of ``request`` (limit ``time_limit_s``) on the local pool."""
    from service import job_run, jobs
    from service.runners import LocalPoolRunner

    store = jobs.JobStore(tmp_path / "j.db")
    store.init()
    job_id = store.create("plan", request, time_limit_s=time_limit_s, budget_s=3600.0)
    assert store.claim("srv/1", lease_s=60.0) is not None
    assert job_run.run_job(str(store.db_path), job_id, "plan", request, None, time_limit_s, 3600.0,
                        owner="srv/1", runner=LocalPoolRunner()) == "done"
    return store.get(job_id)["result"]  # type: ignore[index]
