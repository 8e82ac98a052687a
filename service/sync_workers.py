"""Worker processes that compute the synchronous stage requests off the server's process.

Segmentations, allocations, motion plans and plans are CPU work in Python and numpy. In a
thread of the server they would share its interpreter lock with the event loop, and every
``GET /v1/health`` would wait for the computation to let go of it. :class:`WorkerPool`
therefore keeps one spawned process per heavy thread of :class:`service.executor.HeavyExecutor`
(``MXS_HEAVY_THREADS``). Each worker has the domain imported and its compiled kernels loaded
before its first request, runs at a lower CPU priority (``MXS_HEAVY_NICE``) so that the event
loop wins a busy CPU, and dies with its server (the kernel's parent-death signal and a
watchdog, as the job workers).

A heavy thread takes a :class:`WorkerSlot`, sends it one :class:`StageCall` through a pipe and
waits on the pipe, which holds no interpreter lock. The worker runs the stage, validates its
answer against the response model and encodes the JSON itself, so the server only forwards
bytes. The slot enforces what the request was promised:

- cancellation (client gone, server stopping): a shared event that the worker's progress
  callback reads, raising :class:`~service.executor.Cancelled` at the next progress report;
- time: a worker still computing ``kill_grace_s`` after the call's time limit is killed, and
  the request is answered as out of time (:class:`~models.errors.TimeLimitExceeded`: a 422
  naming ``time_limit_s``, as a stage that runs out of time);
- a worker that dies on its own (a crash, the kernel's OOM killer) answers
  :class:`WorkerLost` (503 with ``Retry-After``): a server fault, not the client's input.

Whatever happened, the slot starts a fresh worker for the next request. Errors the stage
raises travel back with their type and attributes (:class:`RemoteError`), so the server
answers them exactly as it answers the same error raised in its own process.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import pickle
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any

from fastapi.responses import JSONResponse
from pydantic import BaseModel

from models.errors import InputError, TimeLimitExceeded
from models.instrument import InstrumentError
from service.errors import ServiceError
from service.executor import Cancelled, Overloaded

log = logging.getLogger("service.sync_workers")

POLL_S = 0.05  # how often a waiting heavy thread looks at its ticket and its worker
START_TIMEOUT_S = 120.0  # a worker that is not ready by then is taken for broken


class WorkerLost(Overloaded):
    """The worker computing a request died without answering: HTTP 503 with Retry-After."""

    code = "worker_lost"


@dataclass(frozen=True)
class StageCall:
    """One stage computation: ``fn(request, instrument, progress, **kwargs)`` answering a
    dict that ``model`` validates, within ``limit_s`` (the worker is killed ``kill_grace_s``
    later). ``fn`` is a module-level function (pickled by name)."""

    fn: Callable[..., dict[str, Any]]
    request: Any
    model: type[BaseModel]
    limit_s: float
    kwargs: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RemoteError:
    """An exception raised in a worker, carried by type, ``args`` and attributes: exception
    classes whose ``__init__`` takes other arguments than their ``args`` (``InputError``,
    ``FieldError``) cannot be pickled and rebuilt by their constructor."""

    cls: type[BaseException]
    args: tuple[Any, ...]
    state: dict[str, Any]

    def rebuild(self) -> BaseException:
        exc = self.cls.__new__(self.cls)
        exc.args = self.args
        exc.__dict__.update(self.state)
        return exc

    @classmethod
    def of(cls, exc: BaseException) -> RemoteError:
        """``exc`` as a RemoteError that survives the pipe, else a ``RuntimeError`` naming it."""
        try:
            remote = cls(type(exc), exc.args, dict(vars(exc)))
            pickle.loads(pickle.dumps(remote)).rebuild()
            return remote
        except Exception:  # noqa: BLE001 - an exotic exception: its name and message survive
            return cls(RuntimeError, (f"{type(exc).__name__}: {exc}",), {})


# ------------------------------------------------------------------- worker process


_EXPECTED = (InputError, InstrumentError, TimeLimitExceeded, ServiceError)


def worker_main(conn: Connection, cancel: Any, parent_pid: int, instrument_file: str | None,
                nice: int) -> None:
    """A worker process: load the domain, say ``ready``, then answer calls until the pipe
    closes or the server dies."""
    from service.jobpool import die_with_parent

    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's to handle
    if nice > 0:
        os.nice(nice)
    from service import pipeline

    pipeline.warm_up()
    inst = pipeline.instrument_from(instrument_file)
    conn.send(("ready", os.getpid()))
    while True:
        try:
            raw = conn.recv_bytes()
        except (EOFError, OSError):
            return
        try:
            call = pickle.loads(raw)  # the stage function is imported here, by name
        except Exception as exc:  # noqa: BLE001 - answered, the worker goes on
            log.exception("a call could not be read in a worker")
            conn.send(("error", RemoteError.of(exc)))
            continue
        conn.send(_answer(call, inst, cancel))


def _answer(call: StageCall, inst: Any, cancel: Any) -> tuple[str, Any]:
    """``("ok", JSON bytes)``, ``("cancelled", None)`` or ``("error", RemoteError)``."""

    def progress(_: float) -> None:
        if cancel.is_set():
            raise Cancelled()

    try:
        result = call.fn(call.request, inst, progress, **call.kwargs)
        content = call.model.model_validate(result).model_dump(mode="json", by_alias=True)
        return "ok", JSONResponse(content).body
    except Cancelled:
        return "cancelled", None
    except Exception as exc:  # noqa: BLE001 - answered by the server's error handlers
        if not isinstance(exc, _EXPECTED):
            log.exception("stage %s failed in a worker", getattr(call.fn, "__name__", call.fn))
        return "error", RemoteError.of(exc)


# --------------------------------------------------------------------- server side


@dataclass(frozen=True)
class WorkerOptions:
    """How the workers run (see :class:`service.settings.Settings` for each knob)."""

    size: int = 2
    instrument_file: str | None = None
    nice: int = 10
    kill_grace_s: float = 5.0
    retry_after_s: int = 5


class WorkerSlot:
    """One worker process, used by one heavy thread at a time."""

    def __init__(self, options: WorkerOptions):
        self.options = options
        self._ctx = multiprocessing.get_context("spawn")
        self._proc: BaseProcess | None = None
        self._conn: Connection | None = None
        self._cancel = self._ctx.Event()
        self._ready = False
        self._closed = False
        self._lock = threading.Lock()  # start, stop and close come from two threads

    @property
    def pid(self) -> int | None:
        """The worker's pid while it runs (None before it is started or after it died)."""
        p = self._proc
        return p.pid if p is not None and p.is_alive() else None

    def start(self) -> None:
        """Start the worker unless it runs or the slot is closed (it warms up in the
        background)."""
        with self._lock:
            if self._closed or (self._proc is not None and self._proc.is_alive()):
                return
            self._stop()
            mine, theirs = self._ctx.Pipe()
            self._proc = self._ctx.Process(
                target=worker_main, name="mxs-heavy-worker", daemon=True,
                args=(theirs, self._cancel, os.getpid(), self.options.instrument_file,
                      self.options.nice))
            self._proc.start()
            theirs.close()
            self._conn, self._ready = mine, False

    def call(self, work: Callable[[], StageCall], cancel: threading.Event) -> bytes:
        """The JSON answer of the call ``work()`` builds once the worker is ready (so that
        its time limit counts from then), computed in the worker within its ``limit_s`` +
        the kill grace. Raises the stage's error, :class:`Cancelled` (``cancel`` was set),
        :class:`TimeLimitExceeded` or :class:`WorkerLost`."""
        conn, proc = self._wait_ready(cancel)
        self._cancel.clear()
        stage = work()
        limit_s = stage.limit_s
        try:
            conn.send(stage)
        except OSError:  # the worker died since it said ready
            raise self._lost("before its request", cancel) from None
        deadline = time.monotonic() + limit_s + self.options.kill_grace_s
        cancelled_at: float | None = None
        while not self._poll(conn, POLL_S, cancel):
            now = time.monotonic()
            if not proc.is_alive() and not self._poll(conn, 0, cancel):
                raise self._lost("while computing", cancel)
            if cancel.is_set() and cancelled_at is None:
                self._cancel.set()  # the worker stops at its next progress report
                cancelled_at = now
            if cancelled_at is not None and now - cancelled_at > self.options.kill_grace_s:
                self._replace("it did not stop after its request was cancelled")
                raise Cancelled()
            if now > deadline:
                self._replace(f"it was still computing {self.options.kill_grace_s:g} s past "
                              f"its time limit of {limit_s:g} s")
                raise TimeLimitExceeded("request", limit_s)
        return self._result(conn, cancel)

    @staticmethod
    def _poll(conn: Connection, timeout_s: float, cancel: threading.Event) -> bool:
        """Whether ``conn`` has an answer; a pipe closed under the call (the pool is
        closing) ends it as cancelled."""
        try:
            return conn.poll(timeout_s)
        except (OSError, ValueError):
            raise Cancelled() from None

    def _result(self, conn: Connection, cancel: threading.Event) -> bytes:
        try:
            kind, value = conn.recv()
        except (EOFError, OSError):
            raise self._lost("while answering", cancel) from None
        if kind == "ok":
            return value
        if kind == "cancelled":
            raise Cancelled()
        raise value.rebuild()

    def _wait_ready(self, cancel: threading.Event) -> tuple[Connection, BaseProcess]:
        """The worker's pipe and process once it said ``ready`` (started when needed)."""
        if self._proc is None or not self._proc.is_alive():
            self.start()
        conn, proc = self._conn, self._proc
        if conn is None or proc is None:
            raise Cancelled()  # the slot is closed: the server is stopping
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self._ready:
            if self._poll(conn, POLL_S, cancel):
                try:
                    kind, _ = conn.recv()
                except (EOFError, OSError):
                    raise self._lost("while starting", cancel) from None
                self._ready = kind == "ready"
            elif not proc.is_alive():
                raise self._lost("while starting", cancel)
            elif cancel.is_set():
                raise Cancelled()
            elif time.monotonic() > deadline:
                self._replace(f"it was not ready after {START_TIMEOUT_S:g} s")
                raise WorkerLost("no worker process could be started; retry later",
                                 self.options.retry_after_s)
        return conn, proc

    def _lost(self, when: str, cancel: threading.Event) -> BaseException:
        """The error of a request whose worker died: :class:`WorkerLost`, or
        :class:`Cancelled` when the request was cancelled (the server is stopping its
        workers). A fresh worker is started either way."""
        p = self._proc
        code = p.exitcode if p is not None else None
        if cancel.is_set():
            self._replace(None)
            return Cancelled()
        log.error("heavy worker %s died %s (exit code %s); starting another",
                  p.pid if p else None, when, code)
        self._replace(None)
        return WorkerLost(f"the worker process computing this request died {when} (exit "
                          f"code {code}); retry, or submit the work as a job (POST /v1/jobs)",
                          self.options.retry_after_s)

    def _replace(self, why: str | None) -> None:
        """Kill the worker (when ``why`` says why) and start a fresh one."""
        if why is not None:
            log.warning("killing heavy worker %s: %s", self.pid, why)
        with self._lock:
            self._stop()
        self.start()

    def _stop(self) -> None:
        """Kill the worker and close its pipe (the caller holds the lock)."""
        p, conn = self._proc, self._conn
        self._proc, self._conn, self._ready = None, None, False
        if conn is not None:
            conn.close()
        if p is not None:
            if p.is_alive():
                p.kill()
            p.join(timeout=5.0)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._stop()


class WorkerPool:
    """``size`` worker slots; a heavy thread holds one for the length of a request."""

    def __init__(self, options: WorkerOptions):
        self.options = options
        self._slots = [WorkerSlot(options) for _ in range(options.size)]
        self._free: queue.SimpleQueue[WorkerSlot] = queue.SimpleQueue()
        for s in self._slots:
            self._free.put(s)

    def start(self) -> None:
        """Start every worker now (each warms up in the background)."""
        for s in self._slots:
            s.start()

    def pids(self) -> list[int]:
        """The running workers' pids (for the readiness answer and tests)."""
        return [pid for s in self._slots if (pid := s.pid) is not None]

    @contextlib.contextmanager
    def slot(self) -> Iterator[WorkerSlot]:
        """A free slot, held while the block runs. There are as many slots as heavy threads,
        so a heavy thread never waits here."""
        s = self._free.get()
        try:
            yield s
        finally:
            self._free.put(s)

    def close(self) -> None:
        """Kill every worker (the heavy threads have been told to stop)."""
        for s in self._slots:
            s.close()
