"""Where the pointings of a plan job are computed: the engine behind one small interface.

A :class:`PointingRunner` takes the :class:`~service.pointing_plans.PointingTask` s still to do and
calls ``on_done(index, answer)`` as each pointing finishes (in any order); ``on_done`` commits
it and returns False when the job must stop (it was cancelled or is no longer this server's),
and so does ``keep_going()``, which the runner polls while pointings run. A runner that sees
a pointing's own progress reports it as ``partial(fraction)`` (the local one does). :func:`make_runner`
chooses the engine once from the settings:

- :class:`LocalPoolRunner` (the embedded default, no ``MXS_DASK_SCHEDULER``): the job's own
  process of the server's job pool computes its pointings one after the other. It is the
  lighter choice on one machine: it starts no process and holds no memory beyond the pool
  (``MXS_WORKERS`` processes, whose compiled planner kernels are already loaded), needs no
  extra package, and the pool already keeps the cores busy with ``MXS_WORKERS`` jobs at a time.
  A local Dask cluster would add a scheduler, a nanny and worker processes (each a Python
  process of its own, with the domain and its kernels loaded again) on top of the pool, to
  compete for the same cores.
- :class:`DaskRunner` (``MXS_DASK_SCHEDULER=tcp://host:8786``): one ``dask.distributed``
  task per pointing on that cluster, at most ``window`` in flight (so that a job stopping
  leaves little to cancel), the others submitted as these finish. The workers need the same
  package (the service image); ``dask worker --nthreads 1`` suits this CPU-bound Python work.
  A worker that dies mid-task has its pointing re-run by the scheduler on another worker.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from models.instrument import Instrument
from service import pointing_plans
from service.pointing_plans import PointingTask

OnDone = Callable[[int, dict[str, Any]], bool]
KeepGoing = Callable[[], bool]
Partial = Callable[[float], None]


def _no_partial(_: float) -> None:
    pass


class RunnerError(Exception):
    """The engine could not compute the job's pointings: the job fails with this reason."""


class PointingFailed(RunnerError):
    """The computation of one pointing raised: the job fails with the pointing named."""

    def __init__(self, index: int, exc: BaseException):
        super().__init__(f"pointing {index}: {type(exc).__name__}: {exc}")
        self.index = index


class _Stop(BaseException):  # noqa: N818 - unwinds a pointing whose job must stop
    pass


class PointingRunner(Protocol):
    name: str

    def run(self, tasks: Sequence[PointingTask], inst: Instrument, on_done: OnDone,
            keep_going: KeepGoing, partial: Partial = _no_partial) -> bool:
        """Compute ``tasks``, handing each answer to ``on_done``; True when all were handed
        over, False when the job stopped (``on_done`` or ``keep_going`` said so)."""
        ...

    def close(self) -> None: ...


class LocalPoolRunner:
    """The pointings one after the other, in this process (see the module docstring)."""

    name = "local"

    def __init__(self, poll_s: float = 0.5):
        self.poll_s = poll_s

    def compute(self, task: PointingTask, inst: Instrument,
                progress: pointing_plans.Progress) -> dict[str, Any]:
        return pointing_plans.pointing_result(task, inst, progress)

    def run(self, tasks: Sequence[PointingTask], inst: Instrument, on_done: OnDone,
            keep_going: KeepGoing, partial: Partial = _no_partial) -> bool:
        last = [time.monotonic()]

        def progress(fraction: float) -> None:  # a job that must stop stops inside its pointing
            partial(fraction)
            now = time.monotonic()
            if now - last[0] >= self.poll_s:
                last[0] = now
                if not keep_going():
                    raise _Stop()

        for task in tasks:
            if not keep_going():
                return False
            try:
                answer = self.compute(task, inst, progress)
            except _Stop:
                return False
            except Exception as exc:
                raise PointingFailed(task.index, exc) from exc
            if not on_done(task.index, answer):
                return False
        return True

    def close(self) -> None:
        pass


class DaskRunner:
    """One ``dask.distributed`` task per pointing on the cluster at ``address``."""

    name = "dask"

    def __init__(self, address: str, window: int | None = None, poll_s: float = 0.5,
                 connect_timeout_s: float = 30.0):
        self.address = address
        self.window = window
        self.poll_s = poll_s
        self.connect_timeout_s = connect_timeout_s
        self._client: Any = None

    def client(self) -> Any:
        """The (lazily connected, then kept) client of the cluster."""
        if self._client is not None and self._client.status not in ("running", "connecting"):
            self.close()
        if self._client is None:
            from distributed import Client

            try:
                self._client = Client(self.address, timeout=self.connect_timeout_s,
                                      set_as_default=False)
            except (OSError, TimeoutError) as exc:
                raise RunnerError(f"the Dask scheduler at {self.address} did not answer within "
                                  f"{self.connect_timeout_s:g} s ({type(exc).__name__}: {exc})"
                                  ) from exc
        return self._client

    def run(self, tasks: Sequence[PointingTask], inst: Instrument, on_done: OnDone,
            keep_going: KeepGoing, partial: Partial = _no_partial) -> bool:
        from distributed import wait

        client = self.client()
        window = self.window or max(2 * sum(client.nthreads().values()), 2)
        todo = iter(tasks)
        running: dict[Any, int] = {}
        try:
            while True:
                while len(running) < window and (task := next(todo, None)) is not None:
                    running[client.submit(pointing_plans.pointing_result, task, inst, pure=False,
                                          key=f"mxs-pointing-{task.index}-{time.time_ns()}")] = task.index
                if not running:
                    return True
                with contextlib.suppress(Exception):  # a timeout; a cancelled task raises below
                    wait(list(running), timeout=self.poll_s, return_when="FIRST_COMPLETED")
                if not keep_going():
                    return False
                for fut in [f for f in running if f.done()]:
                    index = running.pop(fut)
                    try:
                        answer = fut.result()
                    except (Exception, asyncio.CancelledError) as exc:  # a cancelled task too
                        raise PointingFailed(index, exc) from exc
                    if not on_done(index, answer):
                        return False
        finally:
            if running:
                client.cancel(list(running))

    def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(Exception):
                client.close()


def make_runner(dask_scheduler: str | None) -> PointingRunner:
    """The engine the settings choose: Dask with a scheduler address, else the local pool."""
    if dask_scheduler:
        return DaskRunner(dask_scheduler)
    return LocalPoolRunner()
