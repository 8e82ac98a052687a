"""Background jobs: SQLite-persisted state, work done in a process pool.

The parent process inserts a job as ``queued`` and hands it to a
:class:`~concurrent.futures.ProcessPoolExecutor`; the worker process itself records
``running``, progress, and finally ``done`` with the result or ``failed`` with the reason,
each in its own committed transaction (WAL, synchronous=FULL), so a finished result
survives any later crash. On start-up, jobs left ``queued``/``running`` by a previous
server are marked ``failed`` ("interrupted by server restart").
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import sqlite3
import threading
import time
import uuid
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import Any

from service.errors import ServiceError, json_safe

log = logging.getLogger("service.jobs")

INTERRUPTED = "interrupted by server restart"
_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    job_id     TEXT PRIMARY KEY,
    kind       TEXT NOT NULL,
    status     TEXT NOT NULL,
    progress   REAL NOT NULL DEFAULT 0,
    request    TEXT NOT NULL,
    result     TEXT,
    error      TEXT,
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL
)
"""


def connect(db_path: str | Path) -> sqlite3.Connection:
    con = sqlite3.connect(str(db_path), timeout=30.0, isolation_level=None)
    con.execute("PRAGMA busy_timeout = 30000")
    con.execute("PRAGMA synchronous = FULL")
    return con


class JobStore:
    """All SQL of the job table. Cheap to create; one short-lived connection per call."""

    def __init__(self, db_path: str | Path):
        self.db_path = Path(db_path)

    def init(self) -> int:
        """Create the table (WAL mode) and fail jobs a previous server left unfinished."""
        if self.db_path.parent and not self.db_path.parent.exists():
            self.db_path.parent.mkdir(parents=True, exist_ok=True)
        with _closing(connect(self.db_path)) as con:
            con.execute("PRAGMA journal_mode = WAL")
            con.execute(_SCHEMA)
            cur = con.execute(
                "UPDATE jobs SET status='failed', error=?, updated_at=? "
                "WHERE status IN ('queued', 'running')",
                (INTERRUPTED, time.time()),
            )
            return cur.rowcount

    def create(self, kind: str, request: dict[str, Any]) -> str:
        job_id = uuid.uuid4().hex
        now = time.time()
        with _closing(connect(self.db_path)) as con:
            con.execute(
                "INSERT INTO jobs (job_id, kind, status, progress, request, created_at, updated_at)"
                " VALUES (?, ?, 'queued', 0, ?, ?, ?)",
                (job_id, kind, json.dumps(json_safe(request)), now, now),
            )
        return job_id

    def get(self, job_id: str) -> dict[str, Any] | None:
        with _closing(connect(self.db_path)) as con:
            row = con.execute(
                "SELECT job_id, kind, status, progress, result, error, created_at, updated_at "
                "FROM jobs WHERE job_id = ?", (job_id,),
            ).fetchone()
        if row is None:
            return None
        keys = ("job_id", "kind", "status", "progress", "result", "error", "created_at",
                "updated_at")
        job = dict(zip(keys, row, strict=True))
        job["result"] = json.loads(job["result"]) if job["result"] else None
        return job

    def set_running(self, job_id: str) -> None:
        self._update(job_id, "status='running'", (), only_open=True)

    def set_progress(self, job_id: str, progress: float) -> None:
        p = min(max(float(progress), 0.0), 1.0)
        self._update(job_id, "progress=MAX(progress, ?)", (p,), only_open=True)

    def set_done(self, job_id: str, result: dict[str, Any]) -> None:
        self._update(job_id, "status='done', progress=1, result=?",
                     (json.dumps(json_safe(result)),), only_open=True)

    def set_failed(self, job_id: str, error: str) -> None:
        self._update(job_id, "status='failed', error=?", (error,), only_open=True)

    def _update(self, job_id: str, assignments: str, args: tuple[Any, ...], *,
                only_open: bool) -> None:
        where = "job_id = ?" + (" AND status IN ('queued', 'running')" if only_open else "")
        with _closing(connect(self.db_path)) as con:
            con.execute(f"UPDATE jobs SET {assignments}, updated_at=? WHERE {where}",
                        (*args, time.time(), job_id))


class _closing:
    def __init__(self, con: sqlite3.Connection):
        self.con = con

    def __enter__(self) -> sqlite3.Connection:
        return self.con

    def __exit__(self, *exc: object) -> None:
        self.con.close()


# --------------------------------------------------------------------- worker side


def run_job(db_path: str, job_id: str, kind: str, request: dict[str, Any],
            instrument_file: str | None, time_limit_s: float,
            budget_s: float | None = None) -> str:
    """Executed in a pool process: run the stage, persist the outcome. Never raises."""
    from models.instrument import InstrumentError
    from service import pipeline

    store = JobStore(db_path)
    try:
        store.set_running(job_id)
        last = [0.0, time.monotonic()]

        def progress(p: float) -> None:
            now = time.monotonic()
            if p >= 1.0 or p - last[0] >= 0.01 and now - last[1] >= 0.2:
                last[:] = [p, now]
                store.set_progress(job_id, p)

        inst = pipeline.instrument_from(instrument_file)
        result = pipeline.run(kind, request, inst, progress, time_limit_s=time_limit_s,
                              budget_s=budget_s)
        store.set_done(job_id, result)
        return "done"
    except (ServiceError, InstrumentError) as exc:
        store.set_failed(job_id, str(exc))
    except ValueError as exc:  # domain input errors (InputError) and pydantic ValidationError
        store.set_failed(job_id, f"invalid input: {exc}")
    except Exception as exc:  # noqa: BLE001 - a job must end, whatever happens
        log.exception("job %s (%s) crashed", job_id, kind)
        store.set_failed(job_id, f"internal error: {type(exc).__name__}: {exc}")
    return "failed"


# --------------------------------------------------------------------- parent side


class JobManager:
    """Owns the store and the process pool of one server process."""

    def __init__(self, db_path: str | Path, workers: int, instrument_file: str | None):
        self.store = JobStore(db_path)
        self.workers = workers
        self.instrument_file = instrument_file
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self.interrupted = self.store.init()
        if self.interrupted:
            log.warning("%d job(s) marked failed: %s", self.interrupted, INTERRUPTED)

    def _executor(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(
                    max_workers=self.workers, mp_context=multiprocessing.get_context("spawn")
                )
            return self._pool

    def submit(self, kind: str, request: dict[str, Any], time_limit_s: float,
               budget_s: float | None = None) -> str:
        """Queue a job; ``time_limit_s`` bounds each solver call, ``budget_s`` a whole plan."""
        job_id = self.store.create(kind, request)
        try:
            fut = self._executor().submit(
                run_job, str(self.store.db_path), job_id, kind, request,
                self.instrument_file, time_limit_s, budget_s,
            )
        except Exception as exc:  # broken pool: start a fresh one next time
            log.exception("could not submit job %s", job_id)
            with self._lock:
                self._pool = None
            self.store.set_failed(job_id, f"could not start the job: {exc}")
            raise ServiceError("the job pool is unavailable; retry", status_code=503,
                               code="unavailable") from exc
        fut.add_done_callback(lambda f: self._finished(job_id, f))
        return job_id

    def _finished(self, job_id: str, fut: Future[str]) -> None:
        exc = fut.exception() if not fut.cancelled() else None
        if fut.cancelled() or exc is not None:
            # the worker died (or the pool shut down) before it could record an outcome
            reason = "cancelled at server shutdown" if fut.cancelled() else (
                f"worker process failed: {type(exc).__name__}: {exc}")
            try:
                self.store.set_failed(job_id, reason)
            except Exception:  # noqa: BLE001
                log.exception("could not record the failure of job %s", job_id)
            if exc is not None:
                with self._lock:
                    self._pool = None

    def get(self, job_id: str) -> dict[str, Any] | None:
        return self.store.get(job_id)

    def shutdown(self, wait: bool = False) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=wait, cancel_futures=True)
