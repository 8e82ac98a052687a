"""The job worker processes of one server and the thread that supervises them.

:class:`JobManager` (one per server process) owns ``MXS_WORKERS`` spawned worker processes.
Each worker loops: claim the oldest queued job of the shared table (:class:`JobStore`) under a
lease, renew the lease from a heartbeat thread while the job runs, record the outcome.
Workers die with their server: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux (the workers are
started by the long-lived supervisor thread, whose exit is what the kernel watches), plus a
watchdog thread that exits as soon as the parent pid changes (any platform, and the race
before ``prctl`` took effect).

The supervisor thread starts the workers (on the first submission, or at once when jobs
wait), restarts a worker that died and re-queues its job, kills a worker that has not
stopped a cancelled job within :data:`CANCEL_GRACE_S`, renews the leases of its live
workers' jobs (a second heartbeat, independent of the worker's own), sweeps expired leases of
any server and applies the retention rules. :meth:`JobManager.shutdown` stops the workers within a
couple of seconds and hands this server's running jobs back to the queue.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

from service.executor import Overloaded, QueueLimit
from service.job_run import run_job
from service.jobs import CANCELLED, JobStore, QueueFull
from service.parent_death import kill_with_parent

log = logging.getLogger("service.jobs")



@dataclass(frozen=True)
class PoolOptions:
    """How one server runs jobs (see :class:`service.settings.Settings` for each knob)."""

    workers: int = 2
    instrument_file: str | None = None
    lease_s: float = 30.0
    max_attempts: int = 3
    max_queued: int = 100
    retention_s: float = 7 * 86400.0
    retention_count: int = 1000
    retry_after_s: int = 5
    poll_s: float = 0.2
    dask_scheduler: str | None = None
    #: niceness added to the job workers: the same as the heavy request workers', so that
    #: the two share the CPU evenly and the server's event loop wins it over both
    nice: int = 0

    def __post_init__(self) -> None:
        if self.workers < 1 or self.lease_s <= 0 or self.max_attempts < 1:
            raise ValueError("workers, lease_s and max_attempts must be positive")
        if self.max_queued < 1 or self.retention_s <= 0 or self.retention_count < 1:
            raise ValueError("max_queued, retention_s and retention_count must be positive")


# ------------------------------------------------------------------- worker process


def die_with_parent(parent_pid: int) -> None:
    """Make this process exit when ``parent_pid`` does (SIGKILL from the kernel on Linux,
    and a watchdog thread polling the parent pid everywhere)."""
    kill_with_parent()
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(0)

    def watch() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent_pid:
                os._exit(0)

    threading.Thread(target=watch, name="mxs-parent-watchdog", daemon=True).start()


CANCEL_POLL_S = 0.25  # how often the worker of a running job reads whether it was cancelled
CANCEL_GRACE_S = 2.0  # then a job that has not stopped at a progress report is killed


@contextlib.contextmanager
def _watch(store: JobStore, job_id: str, owner: str, lease_s: float,
           cancelled: threading.Event) -> Iterator[None]:
    """While a job runs: renew its lease every third of it, and read its status every
    :data:`CANCEL_POLL_S`; once it is ``cancelled``, set ``cancelled`` (the job then stops at
    its next progress report)."""
    stop = threading.Event()

    def beat() -> None:
        next_renewal = time.monotonic() + lease_s / 3
        while not cancelled.is_set() and not stop.wait(CANCEL_POLL_S):
            try:
                if store.status(job_id) == CANCELLED:
                    cancelled.set()
                elif time.monotonic() >= next_renewal:
                    store.renew(job_id, owner, lease_s)
                    next_renewal = time.monotonic() + lease_s / 3
            except Exception:  # noqa: BLE001 - a missed beat is retried; the lease is long
                log.exception("lease renewal of job %s failed", job_id)

    t = threading.Thread(target=beat, name="mxs-lease", daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join(timeout=5)
        # also when the job ended before its cancellation was seen: the server must not
        # take this worker, busy with its next job, for one that did not stop
        store.stopped(job_id, owner)


def worker_main(db_path: str, instance: str, parent_pid: int, instrument_file: str | None,
                lease_s: float, poll_s: float, dask_scheduler: str | None = None,
                nice: int = 0) -> None:
    """A worker process: claim, run, record; forever (until its server stops it). The
    pointings of its plan jobs run on the engine the settings chose (:func:`make_runner`)."""
    die_with_parent(parent_pid)
    if nice > 0:
        os.nice(nice)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's to handle
    from service import pipeline  # import the domain and its compiled kernels before the first job
    from service.runners import make_runner
    pipeline.warm_up()
    runner = make_runner(dask_scheduler)
    owner = f"{instance}/{os.getpid()}"
    store = JobStore(db_path)
    while True:
        try:
            job = store.claim(owner, lease_s)
        except Exception:  # noqa: BLE001 - e.g. the database is locked: try again
            log.exception("could not claim a job")
            job = None
        if job is None:
            time.sleep(poll_s)
            continue
        cancelled = threading.Event()
        with _watch(store, job.job_id, owner, lease_s, cancelled):
            run_job(db_path, job.job_id, job.kind, job.request, instrument_file,
                    job.time_limit_s, job.budget_s, cancelled, owner=owner,
                    runner=runner)


# --------------------------------------------------------------------- server side


class JobManager:
    """The job store, the worker processes and their supervisor thread of one server."""

    def __init__(self, db_path: str | Path, options: PoolOptions):
        self.options = options
        self.store = JobStore(db_path)
        self.store.init()
        self.instance = uuid.uuid4().hex[:16]
        rec = self.store.recover(options.max_attempts)
        if rec.requeued or rec.failed:
            log.warning("jobs with an expired lease: %d re-queued, %d failed", rec.requeued,
                        rec.failed)
        self.recovered = rec
        self._procs: list[BaseProcess] = []
        self._want = threading.Event()
        self._stop = threading.Event()
        if self.store.count("queued"):
            self._want.set()
        self._supervisor = threading.Thread(target=self._supervise, name="mxs-job-supervisor",
                                            daemon=True)
        self._supervisor.start()

    def submit(self, kind: str, request: dict[str, Any], time_limit_s: float,
               budget_s: float | None = None) -> str:
        """Queue a job; ``time_limit_s`` bounds each solver call, ``budget_s`` a whole plan.
        Raises :class:`~service.executor.QueueLimit` (429 + Retry-After) when the queue is full."""
        if self._stop.is_set():
            raise Overloaded("the server is shutting down; retry", self.options.retry_after_s)
        try:
            job_id = self.store.create(kind, request, time_limit_s, budget_s,
                                       max_queued=self.options.max_queued)
        except QueueFull as exc:
            raise QueueLimit(f"the job queue is full ({exc.queued} jobs waiting, at most "
                             f"{self.options.max_queued}); retry later",
                             self.options.retry_after_s) from exc
        self._want.set()
        return job_id

    def get(self, job_id: str) -> dict[str, Any] | None:
        return self.store.get(job_id)

    def cancel(self, job_id: str) -> str | None:
        """Cancel an open job (its worker stops within :data:`CANCEL_GRACE_S` and about a
        second); the status it had before, None when there is no such job."""
        return self.store.cancel(job_id, CANCEL_GRACE_S)

    def worker_pids(self) -> list[int]:
        return [p.pid for p in list(self._procs) if p.pid is not None and p.is_alive()]

    def ready(self) -> tuple[bool, str]:
        """Whether this server can take jobs: the database answers, the workers run."""
        if self._stop.is_set():
            return False, "shutting down"
        try:
            queued = self.store.count("queued")
        except Exception as exc:  # noqa: BLE001
            return False, f"job database unavailable: {type(exc).__name__}"
        if self._want.is_set() and not self.worker_pids():
            return False, "no job worker is running"
        return True, f"{queued} jobs queued"

    # ------------------------------------------------------------ supervisor thread

    def _spawn(self) -> BaseProcess:
        ctx = multiprocessing.get_context("spawn")
        o = self.options
        p = ctx.Process(target=worker_main, name="mxs-job-worker", daemon=True, args=(
            str(self.store.db_path), self.instance, os.getpid(), o.instrument_file, o.lease_s,
            o.poll_s, o.dask_scheduler, o.nice))
        p.start()
        return p

    def _supervise(self) -> None:
        next_sweep = 0.0
        while not self._stop.is_set():
            try:
                if self._want.is_set():
                    self._kill_cancelled()
                    self._keep_workers()
                if time.monotonic() >= next_sweep:
                    self._sweep()
                    next_sweep = time.monotonic() + min(self.options.lease_s / 3, 60.0)
            except Exception:  # noqa: BLE001 - the supervisor must survive a bad moment
                log.exception("job supervisor")
            self._stop.wait(0.25)
        self._stop_workers()

    def _keep_workers(self) -> None:
        alive = []
        for p in self._procs:
            if p.is_alive():
                alive.append(p)
                continue
            rec = self.store.recover(self.options.max_attempts, owner=f"{self.instance}/{p.pid}",
                                     reason=f"its worker process died (exit code {p.exitcode})")
            log.warning("job worker %s died (exit code %s); its job: %s", p.pid, p.exitcode, rec)
        while len(alive) < self.options.workers and not self._stop.is_set():
            alive.append(self._spawn())
        self._procs = alive

    def _kill_cancelled(self) -> None:
        """Kill the workers still running a job cancelled more than the grace period ago (a
        long solver call reports no progress); :meth:`_keep_workers` starts new ones."""
        for job_id, owner in self.store.overdue_cancelled(self.instance):
            for p in self._procs:
                if f"{self.instance}/{p.pid}" == owner and p.is_alive():
                    log.warning("job %s was cancelled and did not stop: killing its worker %s",
                                job_id, p.pid)
                    p.kill()
                    p.join(timeout=2.0)

    def _sweep(self) -> None:
        o = self.options
        # leases are renewed here too, for every live worker: a job whose worker's own
        # heartbeat is held up (e.g. a long call that keeps the GIL) is not taken for dead
        self.store.renew_owners([f"{self.instance}/{pid}" for pid in self.worker_pids()],
                                o.lease_s)
        rec = self.store.recover(o.max_attempts)
        if rec.requeued or rec.failed:
            log.warning("jobs with an expired lease: %d re-queued, %d failed", rec.requeued,
                        rec.failed)
        self.store.expire(o.retention_s, o.retention_count)

    def _stop_workers(self) -> None:
        procs, self._procs = self._procs, []
        for p in procs:
            p.terminate()
        deadline = time.monotonic() + 2.0
        for p in procs:
            p.join(timeout=max(deadline - time.monotonic(), 0.0))
            if p.is_alive():
                p.kill()
                p.join(timeout=1.0)
        n = self.store.release(self.instance)
        if n:
            log.info("%d running job(s) handed back to the queue", n)

    def shutdown(self, timeout_s: float = 4.0) -> None:
        """Stop the workers and re-queue this server's running jobs (bounded wait)."""
        self._stop.set()
        self._supervisor.join(timeout=timeout_s)
