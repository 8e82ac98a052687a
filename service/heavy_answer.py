"""The answer of a stage request that takes a heavy slot: ``POST /v1/segmentations``,
``/v1/allocations``, ``/v1/motion-plans``, ``/v1/plans`` and ``/v1/validations`` compute in a
slot of the bounded executor (503 with ``Retry-After`` when every slot is taken), in a worker
process of :mod:`service.sync_workers` unless ``MXS_HEAVY_PROCESSES`` is false, and stop when
the client leaves."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol

from fastapi import Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel

from models.instrument import Instrument
from service.executor import HeavyExecutor, Ticket, run_heavy
from service.settings import Settings
from service.sync_workers import StageCall, WorkerPool

__all__ = ["MIN_LIMIT_S", "HeavyState", "Stage", "answer_heavy", "cancelling"]

#: the least time limit a request that waited for a worker is given, s
MIN_LIMIT_S = 0.1
#: a stage: ``fn(request, instrument, progress, **{limit keyword: seconds})`` -> its answer
Stage = Callable[..., dict[str, Any]]


class HeavyState(Protocol):
    """What a heavy answer needs of the service's state (:class:`service.app.ServiceState`)."""

    settings: Settings
    instrument: Instrument

    @property
    def heavy(self) -> HeavyExecutor: ...

    @property
    def workers(self) -> WorkerPool | None: ...


def cancelling(ticket: Ticket) -> Callable[[float], None]:
    """A progress callback that stops the computation once its request is cancelled."""

    def progress(_: float) -> None:
        ticket.check()

    return progress


async def answer_heavy(request: Request, st: HeavyState, model: type[BaseModel], fn: Stage,
                       req: Any, limit: tuple[str, float] | None = None) -> Response:
    """Answer ``fn(req, instrument, progress, **{name: seconds})`` in a slot of the bounded
    executor (503 + Retry-After when full), validated against ``model`` and encoded off the
    event loop; stop it if the client leaves. ``limit`` = (``fn``'s keyword, time limit):
    what remains of the limit after the wait for a worker is passed; without one the work is
    bounded by ``MXS_MAX_TIME_LIMIT_S``. With ``MXS_HEAVY_PROCESSES`` (the default) ``fn``
    runs in a worker process (:mod:`service.sync_workers`), else in the heavy thread."""

    def stage_call(ticket: Ticket) -> StageCall:
        if limit is None:
            return StageCall(fn, req, model, st.settings.max_time_limit_s)
        name, limit_s = limit
        left_s = max(limit_s - (time.monotonic() - ticket.admitted_at), MIN_LIMIT_S)
        return StageCall(fn, req, model, left_s, {name: left_s})

    def work(ticket: Ticket) -> Response:
        pool = st.workers
        if pool is not None:
            with pool.slot() as slot:
                body = slot.call(lambda: stage_call(ticket), ticket.cancel)
            return Response(body, media_type="application/json")
        call = stage_call(ticket)
        result = call.fn(call.request, st.instrument, cancelling(ticket), **call.kwargs)
        return JSONResponse(model.model_validate(result).model_dump(mode="json", by_alias=True))

    return await run_heavy(st.heavy, work, request.is_disconnected, st.settings.retry_after_s)
