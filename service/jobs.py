"""Background jobs: a SQLite job table shared by every server, worked off under leases.

A job is inserted ``queued`` (refused with 429 + ``Retry-After`` when ``MXS_MAX_QUEUED_JOBS``
are already waiting). Worker processes (:mod:`service.worker`) of any server on the same
database claim the oldest queued job atomically, marking it ``running`` with an owner
(``<server instance>/<pid>``) and a lease (``MXS_JOB_LEASE_S``) that a heartbeat renews while
the job runs; progress, then ``done`` with the result or ``failed`` with the reason, are each
committed in their own transaction (WAL, synchronous=FULL), so a finished result survives any
later crash and is never overwritten (only open jobs are updated).

A ``plan`` job commits each pointing's answer to ``job_pointings`` as soon as it is computed
(:mod:`service.programme`): progress counts committed pointings, and a job that is re-queued
after an interruption resumes from them, so no finished pointing is lost or computed again.
``MXS_JOB_MAX_ATTEMPTS`` counts interruptions of the whole job (each attempt only computes the
pointings still missing); a commit is accepted only from the job's current owner.

Recovery never touches a live job: only a ``running`` job whose lease has expired (its server
was killed, its worker died) is re-queued for any server to pick up, and failed with the
reason once it has been interrupted ``MXS_JOB_MAX_ATTEMPTS`` times. A server that stops
normally hands its own running jobs back to the queue at once; queued jobs stay in the shared
table for the next server. Finished jobs are kept for ``MXS_JOB_RETENTION_S`` and at most the
newest ``MXS_JOB_RETENTION_COUNT``; older ones are reduced to a tombstone that answers 410.

Cancelling (:meth:`JobStore.cancel`) finishes an open job at once as ``cancelled``: a queued job
is never claimed; the worker of a running one sees the status change within a fraction of a
second and stops at the stage's next progress report, or is ended by its server after a grace
period (:mod:`service.jobpool`). Whatever it computes after the cancellation is never
recorded, since only open jobs are updated.
"""

from __future__ import annotations

import json
import logging
import sqlite3
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner import stages
from planner.programme import SEGMENTED, plan_progress
from service.errors import clip_message, json_safe

log = logging.getLogger("service.jobs")

INTERRUPTED = "interrupted by server restart"
EXPIRED = "expired"
CANCELLED = "cancelled"
CANCELLED_ERROR = "cancelled by request"
OPEN = "('queued', 'running')"
FINISHED = "('done', 'failed', 'cancelled')"
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
_POINTINGS = """
CREATE TABLE IF NOT EXISTS job_pointings (
    job_id     TEXT NOT NULL,
    idx        INTEGER NOT NULL,
    result     TEXT NOT NULL,
    created_at REAL NOT NULL,
    PRIMARY KEY (job_id, idx)
)
"""
# columns added to the first table layout (a database from an older server is migrated)
_COLUMNS = {
    "owner": "TEXT",
    "lease_until": "REAL",
    "attempts": "INTEGER NOT NULL DEFAULT 0",
    "time_limit_s": "REAL",
    "budget_s": "REAL",
    "pointings_done": "INTEGER",
    "pointings_total": "INTEGER",
    "stage": "TEXT",
}
_PUBLIC = ("job_id", "kind", "status", "progress", "result", "error", "created_at", "updated_at",
           "pointings_done", "pointings_total", "stage")
#: What a job of each kind other than "plan" is doing while it runs (a plan names its own
#: stages: :mod:`planner.stages`).
KIND_STAGES = {"segmentation": stages.SEGMENTING, "allocation": "allocating",
               "motion-plan": "planning motion"}
# the job may take a commit: open, and (when an owner is named) still that owner's
_OURS = f"job_id = ? AND status IN {OPEN} AND (? = '' OR owner = ?)"


def pointing_progress(done: float, total: int) -> float:
    """The progress of a plan job with ``done`` of its ``total`` pointings planned in its
    first round (:func:`planner.programme.plan_progress`, as the synchronous plan reports it)."""
    return plan_progress(1, done, total)


def connect(db_path: str | Path) -> sqlite3.Connection:
    con = sqlite3.connect(str(db_path), timeout=30.0, isolation_level=None)
    con.execute("PRAGMA busy_timeout = 30000")
    con.execute("PRAGMA synchronous = FULL")
    return con


@dataclass(frozen=True)
class ClaimedJob:
    """What a worker needs to run one job it has claimed."""

    job_id: str
    kind: str
    request: dict[str, Any]
    time_limit_s: float
    budget_s: float | None


@dataclass(frozen=True)
class Recovery:
    """Outcome of one lease sweep: jobs handed back to the queue, jobs failed for good."""

    requeued: int
    failed: int


class QueueFull(Exception):  # noqa: N818 - a condition, answered 429 by the app
    def __init__(self, queued: int):
        super().__init__(f"{queued} jobs are already queued")
        self.queued = queued


class JobStore:
    """All SQL of the job table. Cheap to create; one short-lived connection per call."""

    def __init__(self, db_path: str | Path):
        self.db_path = Path(db_path)

    def init(self) -> None:
        """Create (or migrate) the table, WAL mode. Touches no job."""
        if self.db_path.parent and not self.db_path.parent.exists():
            self.db_path.parent.mkdir(parents=True, exist_ok=True)
        with _closing(connect(self.db_path)) as con:
            con.execute("PRAGMA journal_mode = WAL")
            con.execute(_SCHEMA)
            con.execute(_POINTINGS)
            have = {row[1] for row in con.execute("PRAGMA table_info(jobs)")}
            for name, decl in _COLUMNS.items():
                if name not in have:
                    con.execute(f"ALTER TABLE jobs ADD COLUMN {name} {decl}")
            con.execute("CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status, created_at)")

    # ---------------------------------------------------------------- submission side

    def create(self, kind: str, request: dict[str, Any], time_limit_s: float = 30.0,
               budget_s: float | None = None, max_queued: int | None = None) -> str:
        """Insert a queued job; :class:`QueueFull` when ``max_queued`` already wait."""
        job_id = uuid.uuid4().hex
        now = time.time()
        blob = json.dumps(json_safe(request))
        with _closing(connect(self.db_path)) as con:
            con.execute("BEGIN IMMEDIATE")
            try:
                if max_queued is not None:
                    (n,) = con.execute("SELECT COUNT(*) FROM jobs WHERE status='queued'").fetchone()
                    if n >= max_queued:
                        raise QueueFull(n)
                con.execute(
                    "INSERT INTO jobs (job_id, kind, status, progress, request, created_at, "
                    "updated_at, time_limit_s, budget_s, stage) "
                    "VALUES (?, ?, 'queued', 0, ?, ?, ?, ?, ?, ?)",
                    (job_id, kind, blob, now, now, float(time_limit_s), budget_s, stages.QUEUED),
                )
                con.execute("COMMIT")
            except BaseException:
                con.execute("ROLLBACK")
                raise
        return job_id

    def get(self, job_id: str) -> dict[str, Any] | None:
        """The public fields of a job (``status`` may be ``expired``), or None."""
        with _closing(connect(self.db_path)) as con:
            row = con.execute(f"SELECT {', '.join(_PUBLIC)} FROM jobs WHERE job_id = ?",
                              (job_id,)).fetchone()
        if row is None:
            return None
        job = dict(zip(_PUBLIC, row, strict=True))
        job["result"] = json.loads(job["result"]) if job["result"] else None
        return job

    def status(self, job_id: str) -> str | None:
        """A job's status only (a cheap read, polled by the worker running it), or None."""
        with _closing(connect(self.db_path)) as con:
            row = con.execute("SELECT status FROM jobs WHERE job_id = ?", (job_id,)).fetchone()
        return None if row is None else str(row[0])

    def cancel(self, job_id: str, grace_s: float = 2.0) -> str | None:
        """Finish an open job as ``cancelled``; returns the status it had before (None: no
        such job). A finished (or expired) job is left as it is. A running job keeps its
        owner until the worker says it stopped (:meth:`stopped`); one that has not within
        ``grace_s`` is listed by :meth:`overdue_cancelled`."""
        with _closing(connect(self.db_path)) as con:
            con.execute("BEGIN IMMEDIATE")
            try:
                row = con.execute("SELECT status FROM jobs WHERE job_id = ?", (job_id,)).fetchone()
                now = time.time()
                con.execute(
                    f"UPDATE jobs SET status='{CANCELLED}', error=?, lease_until=?, updated_at=? "
                    f"WHERE job_id = ? AND status IN {OPEN}",
                    (CANCELLED_ERROR, now + grace_s, now, job_id))
                con.execute("COMMIT")
            except BaseException:
                con.execute("ROLLBACK")
                raise
        return None if row is None else str(row[0])

    def stopped(self, job_id: str, owner: str) -> None:
        """``owner`` has stopped working on ``job_id`` (a no-op unless it was cancelled)."""
        with _closing(connect(self.db_path)) as con:
            con.execute(f"UPDATE jobs SET owner=NULL, lease_until=NULL WHERE job_id=? AND "
                        f"status='{CANCELLED}' AND owner=?", (job_id, owner))

    def overdue_cancelled(self, instance: str) -> list[tuple[str, str]]:
        """(job id, owner) of the cancelled jobs that workers of server ``instance`` have not
        stopped within the grace period; each is handed over (its owner cleared)."""
        query = (f"SELECT job_id, owner FROM jobs WHERE status='{CANCELLED}' AND owner LIKE ? "
                 "AND lease_until < ?")
        args = (f"{instance}/%", time.time())
        with _closing(connect(self.db_path)) as con:
            if not con.execute(query, args).fetchone():
                return []  # the common case: no write lock taken
            con.execute("BEGIN IMMEDIATE")
            try:
                rows = con.execute(query, args).fetchall()
                con.executemany("UPDATE jobs SET owner=NULL, lease_until=NULL WHERE job_id=?",
                                [(r[0],) for r in rows])
                con.execute("COMMIT")
            except BaseException:
                con.execute("ROLLBACK")
                raise
        return [(str(r[0]), str(r[1])) for r in rows]

    def count(self, status: str) -> int:
        with _closing(connect(self.db_path)) as con:
            (n,) = con.execute("SELECT COUNT(*) FROM jobs WHERE status = ?", (status,)).fetchone()
        return int(n)

    # -------------------------------------------------------------------- worker side

    def claim(self, owner: str, lease_s: float) -> ClaimedJob | None:
        """Atomically take the oldest queued job for ``owner`` under a fresh lease."""
        now = time.time()
        with _closing(connect(self.db_path)) as con:
            if con.execute("SELECT 1 FROM jobs WHERE status='queued' LIMIT 1").fetchone() is None:
                return None  # the common idle case: no write lock taken
            con.execute("BEGIN IMMEDIATE")
            try:
                row = con.execute(
                    "SELECT job_id, kind, request, time_limit_s, budget_s FROM jobs "
                    "WHERE status='queued' ORDER BY created_at LIMIT 1").fetchone()
                if row is not None:
                    con.execute(
                        "UPDATE jobs SET status='running', owner=?, lease_until=?, updated_at=? "
                        "WHERE job_id=?", (owner, now + lease_s, now, row[0]))
                con.execute("COMMIT")
            except BaseException:
                con.execute("ROLLBACK")
                raise
        if row is None:
            return None
        return ClaimedJob(row[0], row[1], json.loads(row[2]),
                          float(row[3]) if row[3] is not None else 30.0, row[4])

    def renew(self, job_id: str, owner: str, lease_s: float) -> bool:
        """Extend ``owner``'s lease on a running job; False when it is no longer theirs."""
        with _closing(connect(self.db_path)) as con:
            cur = con.execute("UPDATE jobs SET lease_until=? WHERE job_id=? AND owner=? "
                              "AND status='running'", (time.time() + lease_s, job_id, owner))
        return cur.rowcount == 1

    def renew_owners(self, owners: list[str], lease_s: float) -> int:
        """Extend the leases of every running job of ``owners`` (a server renewing for its
        live worker processes)."""
        if not owners:
            return 0
        marks = ", ".join("?" * len(owners))
        with _closing(connect(self.db_path)) as con:
            return con.execute(f"UPDATE jobs SET lease_until=? WHERE status='running' AND "
                               f"owner IN ({marks})", (time.time() + lease_s, *owners)).rowcount

    def set_running(self, job_id: str, owner: str = "", lease_s: float = 30.0) -> None:
        self._update(job_id, "status='running', owner=?, lease_until=?",
                     (owner, time.time() + lease_s))

    def set_progress(self, job_id: str, progress: float) -> None:
        p = min(max(float(progress), 0.0), 1.0)
        self._update(job_id, "progress=MAX(progress, ?)", (p,))

    def set_stage(self, job_id: str, stage: str) -> None:
        """What the open job is doing now (:mod:`planner.stages`), in words."""
        self._update(job_id, "stage=?", (str(stage),))

    def set_done(self, job_id: str, result: dict[str, Any]) -> None:
        self._update(job_id, "status='done', progress=1, result=?, owner=NULL, lease_until=NULL, "
                     "stage=?", (json.dumps(json_safe(result)), stages.DONE))

    def set_failed(self, job_id: str, error: str) -> None:
        """Fail an open job with ``error``, quoting at most ~100 characters of any input."""
        self._update(job_id, "status='failed', error=?, owner=NULL, lease_until=NULL",
                     (clip_message(error),))

    # ------------------------------------------------------- per-pointing plan jobs

    def start_pointings(self, job_id: str, owner: str, total: int) -> bool:
        """Record that the job's field is segmented into ``total`` pointings (progress
        :data:`planner.programme.SEGMENTED`, then :func:`pointing_progress`); False when the
        job is no longer ``owner``'s (``owner`` '' : any open job)."""
        with _closing(connect(self.db_path)) as con:
            return con.execute(
                "UPDATE jobs SET pointings_total=?, pointings_done=(SELECT COUNT(*) FROM "
                "job_pointings WHERE job_id=?), progress=MAX(progress, ?), updated_at=? "
                "WHERE " + _OURS,
                (int(total), job_id, SEGMENTED, time.time(), job_id, owner, owner)).rowcount == 1

    def commit_pointing(self, job_id: str, owner: str, index: int, result: dict[str, Any],
                        *, replace: bool = False) -> bool:
        """Commit pointing ``index``'s answer and the job's progress in one transaction, if
        the job is still ``owner``'s (else nothing is written and False is returned). A
        pointing already committed keeps its first answer, unless ``replace`` (a later
        round's answer, which records the earlier rounds)."""
        blob = json.dumps(json_safe(result))
        with _closing(connect(self.db_path)) as con:
            con.execute("BEGIN IMMEDIATE")
            try:
                if con.execute("SELECT 1 FROM jobs WHERE " + _OURS,
                               (job_id, owner, owner)).fetchone() is None:
                    con.execute("ROLLBACK")
                    return False
                now = time.time()
                verb = "INSERT OR REPLACE" if replace else "INSERT OR IGNORE"
                con.execute(f"{verb} INTO job_pointings (job_id, idx, result, created_at) "
                            "VALUES (?, ?, ?, ?)", (job_id, int(index), blob, now))
                (done,) = con.execute("SELECT COUNT(*) FROM job_pointings WHERE job_id=?",
                                      (job_id,)).fetchone()
                (total,) = con.execute("SELECT COALESCE(pointings_total, ?) FROM jobs "
                                       "WHERE job_id=?", (done, job_id)).fetchone()
                con.execute("UPDATE jobs SET pointings_done=?, progress=MAX(progress, ?), "
                            "updated_at=? WHERE job_id=?",
                            (done, pointing_progress(done, int(total)), now, job_id))
                con.execute("COMMIT")
            except BaseException:
                con.execute("ROLLBACK")
                raise
        return True

    def pointing_results(self, job_id: str) -> dict[int, dict[str, Any]]:
        """The committed pointing answers of a job, by pointing index."""
        with _closing(connect(self.db_path)) as con:
            rows = con.execute("SELECT idx, result FROM job_pointings WHERE job_id=?",
                               (job_id,)).fetchall()
        return {int(i): json.loads(r) for i, r in rows}

    def drop_pointings(self, job_id: str, indices: list[int]) -> None:
        """Forget committed pointings (answers that no longer match the job's segmentation)."""
        with _closing(connect(self.db_path)) as con:
            con.executemany("DELETE FROM job_pointings WHERE job_id=? AND idx=?",
                            [(job_id, int(i)) for i in indices])

    def owns(self, job_id: str, owner: str) -> bool:
        """Whether the job is open and (``owner`` non-empty) still ``owner``'s."""
        with _closing(connect(self.db_path)) as con:
            return con.execute("SELECT 1 FROM jobs WHERE " + _OURS,
                               (job_id, owner, owner)).fetchone() is not None

    def _update(self, job_id: str, assignments: str, args: tuple[Any, ...]) -> None:
        """Change an open job only: a finished result is never overwritten."""
        with _closing(connect(self.db_path)) as con:
            con.execute(f"UPDATE jobs SET {assignments}, updated_at=? "
                        f"WHERE job_id = ? AND status IN {OPEN}", (*args, time.time(), job_id))

    # ------------------------------------------------------------------ recovery side

    def recover(self, max_attempts: int, owner: str | None = None,
                reason: str = "its lease expired") -> Recovery:
        """Re-queue running jobs whose lease has expired (or all of ``owner``'s), counting
        an attempt; a job interrupted ``max_attempts`` times is failed with ``reason``."""
        now = time.time()
        if owner is None:
            where, args = "status='running' AND (lease_until IS NULL OR lease_until < ?)", (now,)
        else:
            where, args = "status='running' AND owner = ?", (owner,)
        with _closing(connect(self.db_path)) as con:
            con.execute("BEGIN IMMEDIATE")
            failed = con.execute(
                f"UPDATE jobs SET status='failed', owner=NULL, lease_until=NULL, updated_at=?, "
                f"attempts=attempts+1, error=? WHERE {where} AND attempts+1 >= ?",
                (now, f"{INTERRUPTED}: {reason}, {max_attempts} times", *args, max_attempts),
            ).rowcount
            requeued = con.execute(
                f"UPDATE jobs SET status='queued', owner=NULL, lease_until=NULL, updated_at=?, "
                f"attempts=attempts+1, stage=? WHERE {where}", (now, stages.QUEUED, *args),
            ).rowcount
            con.execute("COMMIT")
        return Recovery(requeued, failed)

    def release(self, instance: str) -> int:
        """Hand every running job of server ``instance`` back to the queue (a normal
        shutdown: not counted as an attempt)."""
        with _closing(connect(self.db_path)) as con:
            return con.execute(
                "UPDATE jobs SET status='queued', owner=NULL, lease_until=NULL, updated_at=?, "
                "stage=? WHERE status='running' AND owner LIKE ?",
                (time.time(), stages.QUEUED, f"{instance}/%"),
            ).rowcount

    def expire(self, retention_s: float, retention_count: int) -> int:
        """Reduce finished jobs older than ``retention_s`` or beyond the newest
        ``retention_count`` to tombstones (status ``expired``, no request, no result); drop
        tombstones ten retention periods old."""
        now = time.time()
        with _closing(connect(self.db_path)) as con:
            con.execute("BEGIN IMMEDIATE")
            n = con.execute(
                f"UPDATE jobs SET status='{EXPIRED}', request='', result=NULL, updated_at=? "
                f"WHERE status IN {FINISHED} AND (updated_at < ? OR job_id NOT IN ("
                f"SELECT job_id FROM jobs WHERE status IN {FINISHED} "
                "ORDER BY updated_at DESC LIMIT ?))",
                (now, now - retention_s, retention_count),
            ).rowcount
            con.execute(f"DELETE FROM jobs WHERE status='{EXPIRED}' AND updated_at < ?",
                        (now - 10 * retention_s,))
            # the pointings of a finished job live on in its result (or are of no more use)
            con.execute("DELETE FROM job_pointings WHERE job_id NOT IN "
                        f"(SELECT job_id FROM jobs WHERE status IN {OPEN})")
            con.execute("COMMIT")
        return n


class _closing:
    def __init__(self, con: sqlite3.Connection):
        self.con = con

    def __enter__(self) -> sqlite3.Connection:
        return self.con

    def __exit__(self, *exc: object) -> None:
        self.con.close()
