"""Running one claimed job (:mod:`service.jobs`): its stage, on the job's instrument and
limits, with its progress, stage and outcome committed to the job table. A plan job runs its
pointings through :func:`service.programme.run_plan`, which commits each pointing as it is
computed."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from models.instrument import InstrumentError
from service import pipeline, programme
from service.errors import ServiceError
from service.executor import Cancelled
from service.jobs import CANCELLED, KIND_STAGES, JobStore
from service.runners import LocalPoolRunner, PointingRunner, RunnerError

__all__ = ["run_job"]

log = logging.getLogger("service.jobs")


def run_job(db_path: str, job_id: str, kind: str, request: dict[str, Any],
            instrument_file: str | None, time_limit_s: float,
            budget_s: float | None = None, cancelled: threading.Event | None = None, *,
            owner: str = "", runner: PointingRunner | None = None) -> str:
    """Run one claimed job's stage and persist its outcome. Never raises an ``Exception``.

    Once ``cancelled`` is set (the job was cancelled), the stage stops at its next progress
    report (:class:`~service.executor.Cancelled`) and ``"cancelled"`` is returned. A plan
    job's pointings run on ``runner`` (default: here, one after the other); it stops as soon
    as it is cancelled, or returns "stopped" once it is no longer ``owner``'s."""
    store = JobStore(db_path)
    try:
        last = [0.0, time.monotonic()]

        def progress(p: float) -> None:
            if cancelled is not None and cancelled.is_set():
                raise Cancelled()
            now = time.monotonic()
            if p >= 1.0 or p - last[0] >= 0.01 and now - last[1] >= 0.2:
                last[:] = [p, now]
                store.set_progress(job_id, p)

        def stage(words: str) -> None:
            if cancelled is not None and cancelled.is_set():
                raise Cancelled()
            store.set_stage(job_id, words)

        inst = pipeline.instrument_from(instrument_file)
        if kind == "plan":
            result = programme.run_plan(store, job_id, owner, request, inst,
                                        runner or LocalPoolRunner(),
                                        budget_s=budget_s, progress=progress,
                                        cancelled=cancelled, on_stage=stage)
            if result is None:
                return CANCELLED if store.status(job_id) == CANCELLED else "stopped"
        else:
            stage(KIND_STAGES.get(kind, kind))
            result = pipeline.run(kind, request, inst, progress, time_limit_s=time_limit_s,
                                  budget_s=budget_s)
        store.set_done(job_id, result)
        return "done"
    except Cancelled:
        return CANCELLED
    except (ServiceError, InstrumentError, RunnerError) as exc:
        store.set_failed(job_id, str(exc))
    except ValueError as exc:  # domain input errors (InputError) and pydantic ValidationError
        store.set_failed(job_id, f"invalid input: {exc}")
    except Exception as exc:  # noqa: BLE001 - a job must end, whatever happens
        log.exception("job %s (%s) crashed", job_id, kind)
        store.set_failed(job_id, f"internal error: {type(exc).__name__}: {exc}")
    return "failed"
