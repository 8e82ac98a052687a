"""The bounded executor of the synchronous heavy endpoints, with admission control.

Segmentations, allocations, motion plans, plans and uploads take one of a fixed set of daemon
threads (``MXS_HEAVY_THREADS``), never the event loop nor the thread pool that serves cheap
routes. A stage request's thread hands the computation to its worker process
(:mod:`service.sync_workers`) and only waits on a pipe, so ``/v1/health`` answers whatever
the load. At most ``MXS_HEAVY_QUEUE`` more requests may wait for a thread (the time they wait
is taken off their time limit); beyond that :meth:`HeavyExecutor.submit` refuses at once with
:class:`Overloaded` (HTTP 503 with ``Retry-After``) instead of queueing without end, and
:class:`RefuseWhenFull` gives the same answer before the request's body is even read.

Every admitted request carries a :class:`Ticket`. Its ``cancel`` event is set when the
client disconnects or the server shuts down: a request still waiting is dropped before it
starts, and a running one stops at its next progress report (the ``progress`` callback the
pipeline calls raises :class:`Cancelled`). The domain call's own ``time_limit_s`` is the
hard deadline in between. The threads are daemons, so a stuck computation never holds up
the process exit.
"""

from __future__ import annotations

import asyncio
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from service.errors import ServiceError, error_body

log = logging.getLogger("service.executor")


class Cancelled(BaseException):  # noqa: N818 - like asyncio.CancelledError, not an Exception
    """Raised inside a heavy computation whose client left or whose server is stopping.

    A ``BaseException`` so that the domain's ``except Exception`` safety nets let it through.
    """


class Overloaded(ServiceError):
    """Every heavy slot is taken: HTTP 503 with a ``Retry-After`` header."""

    status_code = 503
    code = "overloaded"

    def __init__(self, message: str, retry_after_s: int):
        super().__init__(message)
        self.retry_after_s = max(int(retry_after_s), 1)


class QueueLimit(Overloaded):
    """The job queue holds its configured maximum: HTTP 429 with a ``Retry-After`` header (a
    quota on queued work, not a server fault)."""

    status_code = 429
    code = "queue_full"


@dataclass(eq=False)
class Ticket:
    """One admitted request: its cancellation flag and the future of its answer."""

    cancel: threading.Event = field(default_factory=threading.Event)
    future: asyncio.Future[Any] | None = None
    admitted_at: float = field(default_factory=time.monotonic)
    started_at: float | None = None
    loop: asyncio.AbstractEventLoop | None = None

    @property
    def waited_s(self) -> float:
        """Seconds between admission and the start of the computation (so far)."""
        return (self.started_at or time.monotonic()) - self.admitted_at

    def check(self) -> None:
        """Raise :class:`Cancelled` when the request should stop."""
        if self.cancel.is_set():
            raise Cancelled()


@dataclass(frozen=True)
class _Work:
    ticket: Ticket
    fn: Callable[[Ticket], Any]
    loop: asyncio.AbstractEventLoop


class HeavyExecutor:
    """``threads`` daemon workers behind an admission limit of ``threads + queue`` requests."""

    def __init__(self, threads: int, queue_size: int, retry_after_s: int = 5):
        self.threads = threads
        self.capacity = threads + queue_size
        self.retry_after_s = retry_after_s
        self._queue: queue.SimpleQueue[_Work | None] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._admitted: set[Ticket] = set()
        self._closed = False
        self._workers = [
            threading.Thread(target=self._loop, name=f"mxs-heavy-{i}", daemon=True)
            for i in range(threads)
        ]
        for t in self._workers:
            t.start()

    @property
    def in_use(self) -> int:
        with self._lock:
            return len(self._admitted)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called (the server is stopping)."""
        return self._closed

    def has_room(self) -> bool:
        with self._lock:
            return not self._closed and len(self._admitted) < self.capacity

    def submit(self, fn: Callable[[Ticket], Any]) -> Ticket:
        """Admit ``fn(ticket)`` or raise :class:`Overloaded`. Call from the event loop."""
        loop = asyncio.get_running_loop()
        ticket = Ticket()
        with self._lock:
            if self._closed:
                raise Overloaded("the server is shutting down; retry on another instance",
                                 self.retry_after_s)
            if len(self._admitted) >= self.capacity:
                raise Overloaded(_full_message(self.capacity), self.retry_after_s)
            self._admitted.add(ticket)
        ticket.future, ticket.loop = loop.create_future(), loop
        self._queue.put(_Work(ticket, fn, loop))
        return ticket

    def cancel(self, ticket: Ticket) -> None:
        """Stop ``ticket``'s work; a request still waiting gives its slot back at once."""
        ticket.cancel.set()
        with self._lock:
            if ticket.started_at is None:
                self._admitted.discard(ticket)

    def _loop(self) -> None:
        while True:
            work = self._queue.get()
            if work is None:
                return
            self._run(work)

    def _run(self, work: _Work) -> None:
        outcome: tuple[bool, Any]
        with self._lock:
            work.ticket.started_at = time.monotonic()
        try:
            work.ticket.check()
            outcome = (True, work.fn(work.ticket))
        except Cancelled:
            outcome = (False, Cancelled())
        except Exception as exc:  # noqa: BLE001 - handed to the awaiting request
            outcome = (False, exc)
        finally:
            with self._lock:
                self._admitted.discard(work.ticket)
        try:
            work.loop.call_soon_threadsafe(_resolve, work.ticket, outcome)
        except RuntimeError:  # the event loop is closed: nobody waits any more
            pass

    def close(self) -> None:
        """Refuse new work, cancel every admitted request and answer each at once (its
        awaiting request raises :class:`Cancelled`); the threads finish in the background.
        Safe to call from a signal handler or any thread."""
        with self._lock:
            self._closed = True
            tickets = list(self._admitted)
        for t in tickets:
            t.cancel.set()
            if t.loop is not None:
                try:
                    t.loop.call_soon_threadsafe(_resolve, t, (False, Cancelled()))
                except RuntimeError:  # the loop is closed
                    pass

    def shutdown(self) -> None:
        """:meth:`close`, and let the threads exit; never waits for a thread."""
        self.close()
        for _ in self._workers:
            self._queue.put(None)


def _resolve(ticket: Ticket, outcome: tuple[bool, Any]) -> None:
    fut = ticket.future
    if fut is None or fut.done():
        return
    ok, value = outcome
    if ok:
        fut.set_result(value)
    else:
        fut.set_exception(value)
        if isinstance(value, Cancelled):
            fut.exception()  # maybe nobody awaits it any more (the client left): not an error


class RefuseWhenFull:
    """ASGI middleware: a ``POST`` to one of ``paths`` while every heavy slot is taken is
    refused (503 + ``Retry-After``, as :meth:`HeavyExecutor.submit` would) before its body is
    read, parsed and checked. A client that retries at once, ignoring ``Retry-After``, then
    costs the event loop a header's worth of work instead of a request's, so health checks
    and cheap routes keep their latency. (A request refused here is not validated: when the
    server is full, a malformed one is answered 503, and 422 once it is retried.)"""

    def __init__(self, app: ASGIApp, executor: Callable[[], HeavyExecutor],
                 paths: frozenset[str]):
        self.app = app
        self.executor = executor
        self.paths = paths

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (scope["type"] == "http" and scope["method"] == "POST"
                and scope["path"] in self.paths):
            heavy = self.executor()
            if not heavy.has_room():
                why = ("the server is shutting down; retry on another instance" if heavy.closed
                       else _full_message(heavy.capacity))
                exc = Overloaded(why, heavy.retry_after_s)
                answer = JSONResponse(error_body(exc.code, exc.message), status_code=503,
                                      headers={"Retry-After": str(exc.retry_after_s)})
                await answer(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _full_message(capacity: int) -> str:
    return (f"all {capacity} heavy-request slots are in use; retry later or submit the work "
            "as a job (POST /v1/jobs)")


async def wait_or_cancel(executor: HeavyExecutor, ticket: Ticket,
                         disconnected: Callable[[], Any], poll_s: float = 0.25) -> Any:
    """Await ``ticket``'s answer; cancel it as soon as ``disconnected()`` (an awaitable
    returning bool) says the client has gone, or when this task is cancelled."""
    assert ticket.future is not None
    try:
        while True:
            done, _ = await asyncio.wait({ticket.future}, timeout=poll_s)
            if done:
                return ticket.future.result()
            if await disconnected():
                executor.cancel(ticket)
                log.info("client disconnected: heavy request cancelled")
                raise Cancelled()
    except asyncio.CancelledError:
        executor.cancel(ticket)
        raise


async def run_heavy(executor: HeavyExecutor, work: Callable[[Ticket], Any],
                    disconnected: Callable[[], Any], retry_after_s: int,
                    what: str = "request") -> Any:
    """``work`` run in a heavy slot and awaited (:func:`wait_or_cancel`); a cancelled ``what``
    (the client gone, or the server shutting down) is answered 503 with ``Retry-After``."""
    ticket = executor.submit(work)
    try:
        return await wait_or_cancel(executor, ticket, disconnected)
    except Cancelled:
        raise Overloaded(f"the {what} was cancelled (client gone or server shutting down)",
                         retry_after_s) from None
