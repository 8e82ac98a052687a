"""A ``plan`` job as a whole programme: segmentation, then one task per pointing, each
committed as soon as it is computed, then the answer assembled in pointing order.

The pointings run on a :class:`~service.runners.PointingRunner` (this process, or a Dask
cluster). Each pointing's plan depends only on the request, the pointing and its index:
its seed is :func:`service.pipeline.pointing_seed` of the job's seed, and its wall-clock share
is fixed before any pointing runs (:func:`service.pipeline.pointing_shares`), so the plan is the same whatever the
number of workers, their order or the attempt that computed a pointing, and equal to the
synchronous ``POST /v1/plans`` answer whenever no time limit cuts a computation short.

A job re-queued after an interruption (its server or worker killed) segments again (cheap,
and deterministic for the request and its seed) and computes only the pointings that have no
committed answer; a committed answer that does not match its pointing any more (the same
index, other targets) is dropped and recomputed.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from models.instrument import Instrument
from service import adapters, pipeline
from service.jobs import JobStore, pointing_progress
from service.runners import PointingRunner
from service.schemas import PlanRequest


def _matches(answer: dict[str, Any], expected: dict[str, Any]) -> bool:
    return answer.get("id") == expected["id"] and answer.get("target_ids") == expected["target_ids"]


def run_plan(store: JobStore, job_id: str, owner: str, request: Any, inst: Instrument,
             runner: PointingRunner, *, time_limit_s: float, budget_s: float | None = None,
             progress: pipeline.Progress = lambda _: None,
             cancelled: threading.Event | None = None) -> dict[str, Any] | None:
    """Run (or resume) plan job ``job_id`` owned by ``owner`` on ``runner``; its
    PlanResponse dict, or None when it stopped before its end: ``cancelled`` was set, or the
    job is no longer open and ``owner``'s (cancelled, finished elsewhere, or taken over after
    a lost lease). ``progress`` hears :func:`~service.jobs.pointing_progress` of the pointings
    committed plus the part done of the one being computed, when the runner sees it."""
    t0 = time.monotonic()
    req = request if isinstance(request, PlanRequest) else PlanRequest.model_validate(request)
    limit = pipeline.plan_limit_s(req, budget_s)
    seg = pipeline.segment_plan(req, inst)
    n = len(seg.pointings)
    if not store.start_pointings(job_id, owner, n):
        return None
    ids = [t.id for t in req.targets]
    expected = [adapters.pointing_out(p, ids) for p in seg.pointings]
    done = store.pointing_results(job_id)
    stale = [i for i, a in done.items() if i >= n or not _matches(a, expected[i])]
    if stale:
        store.drop_pointings(job_id, stale)
    resumed = len(done) - len(stale)
    shares = pipeline.pointing_shares(limit, n)
    todo = [pipeline.pointing_task(req, seg, i, shares[i], time_limit_s)
            for i in range(n) if i not in done or i in stale]
    committed = [resumed]

    def on_done(index: int, answer: dict[str, Any]) -> bool:
        if not store.commit_pointing(job_id, owner, index, answer):
            return False
        committed[0] += 1
        return True

    def keep_going() -> bool:
        return not (cancelled is not None and cancelled.is_set()) and store.owns(job_id, owner)

    finished = runner.run(todo, inst, on_done, keep_going,
                          lambda f: progress(pointing_progress(committed[0] + f, n)))
    if not finished:
        return None
    answers = store.pointing_results(job_id)
    missing = [i for i in range(n) if i not in answers]
    if missing:  # pragma: no cover - the runner handed every task over
        raise RuntimeError(f"pointings {missing} have no committed answer")
    return pipeline.plan_out(seg, [answers[i] for i in range(n)], req.targets, {
        "time_limit_s": time_limit_s, "budget_s": budget_s, "deadline_s": limit,
        "elapsed_s": time.monotonic() - t0, "engine": runner.name,
        "pointings_resumed": resumed, "pointings_computed": len(todo)})
