"""The FastAPI application: routes translate HTTP to :mod:`service.pipeline` calls.

``service.app:app`` is built from the environment (``MXS_*``); tests and the CLI build
their own with :func:`create_app`.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from importlib.metadata import PackageNotFoundError, version
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool

from models.errors import InputError
from models.instrument import Instrument
from service import finding_charts, pipeline, validations
from service.admission import check_stage
from service.auth import Auth, AuthMiddleware, describe_security, effective_token, warn_if_empty
from service.errors import (
    BodyLimitMiddleware,
    CatchAllMiddleware,
    FieldError,
    NotFound,
    ServiceError,
    error_body,
    install_error_handlers,
    parse_loc,
)
from service.executor import (
    HeavyExecutor,
    Overloaded,
    RefuseWhenFull,
)
from service.heavy_answer import answer_heavy
from service.job_schemas import JOB_STATUS, JobCreated, JobRequest, JobStatus
from service.jobpool import JobManager, PoolOptions
from service.jobs import CANCELLED, EXPIRED
from service.limits import check_request
from service.middleware import BodyTimeoutMiddleware
from service.response_schemas import (
    AllocationResponse,
    ErrorResponse,
    Health,
    InstrumentInfo,
    MotionPlanResponse,
    PlanResponse,
    Readiness,
    SegmentationResponse,
    ValidationErrorResponse,
)
from service.schema_rules import describe_limits
from service.schemas import AllocationRequest, MotionPlanRequest, PlanRequest, SegmentationRequest
from service.settings import Settings, env_name
from service.sync_workers import WorkerOptions, WorkerPool
from service.target_lists import TargetListStore, install_target_lists, resolve
from service.uploads import start_fork_server
from service.web import install_web

log = logging.getLogger("service")

try:
    VERSION = version("mxs-planner")
except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
    VERSION = "0.0.0"

RETRY_AFTER = {"Retry-After": {"description": "Seconds to wait before retrying.",
                               "schema": {"type": "integer", "minimum": 1}}}
ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorResponse, "description": "Missing or wrong bearer token."},
    408: {"model": ErrorResponse,
          "description": "The request body did not arrive within the server's body timeout."},
    413: {"model": ErrorResponse, "description": "Request body too large."},
    422: {"model": ValidationErrorResponse,
          "description": "Invalid input (also a body that is not UTF-8 JSON, nested too deeply "
                         "or with a number of more than 4300 digits); `detail[].loc` names the "
                         "field."},
    503: {"model": ErrorResponse, "headers": RETRY_AFTER,
          "description": "Overloaded (every heavy-request slot is taken), "
          "shutting down, or a temporary failure: retry after `Retry-After` seconds."},
}
#: a request naming a stored target list that does not exist (never uploaded, or deleted)
LIST_NOT_FOUND: dict[str, Any] = {
    "model": ErrorResponse,
    "description": "`target_list_id` names no stored target list (never uploaded, or deleted by "
                   "the retention); `detail` names the field and the id."}
#: the routes whose work takes a heavy slot (refused before their body is read when all are taken)
HEAVY_PATHS = frozenset({"/v1/segmentations", "/v1/allocations", "/v1/motion-plans", "/v1/plans",
                         "/v1/target-lists", "/v1/finding-charts", "/v1/validations"})
QUEUE_FULL: dict[str, Any] = {"model": ErrorResponse, "headers": RETRY_AFTER,
                              "description": "The job queue is full (`MXS_MAX_QUEUED_JOBS`): retry after "
                                             "`Retry-After` seconds."}


class ServiceState:
    """Per-app state: settings, the loaded instrument and (lazily) the heavy executor and the
    job manager."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self.instrument: Instrument = pipeline.instrument_from(
            str(settings.instrument_file) if settings.instrument_file else None
        )
        self._jobs: JobManager | None = None
        self._heavy: HeavyExecutor | None = None
        self._workers: WorkerPool | None = None
        self._lists: TargetListStore | None = None
        self._lock = threading.Lock()

    @property
    def lists(self) -> TargetListStore:
        """The stored target lists (a table of the job database)."""
        with self._lock:
            if self._lists is None:
                s = self.settings
                store = TargetListStore(s.job_db, s.target_list_retention_s,
                                        s.target_list_retention_count)
                store.init()
                self._lists = store
            return self._lists

    @property
    def jobs(self) -> JobManager:
        with self._lock:
            if self._jobs is None:
                s = self.settings
                self._jobs = JobManager(s.job_db, PoolOptions(
                    workers=s.workers,
                    instrument_file=str(s.instrument_file) if s.instrument_file else None,
                    lease_s=s.job_lease_s, max_attempts=s.job_max_attempts,
                    max_queued=s.max_queued_jobs, retention_s=s.job_retention_s,
                    retention_count=s.job_retention_count, retry_after_s=s.retry_after_s,
                    dask_scheduler=s.dask_scheduler, nice=s.heavy_nice,
                ))
            return self._jobs

    @property
    def heavy(self) -> HeavyExecutor:
        with self._lock:
            if self._heavy is None:
                s = self.settings
                self._heavy = HeavyExecutor(s.heavy_threads, s.heavy_queue, s.retry_after_s)
            return self._heavy

    @property
    def workers(self) -> WorkerPool | None:
        """The worker processes of the heavy threads (None: the threads compute themselves,
        ``MXS_HEAVY_PROCESSES=false``)."""
        s = self.settings
        if not s.heavy_processes:
            return None
        with self._lock:
            if self._workers is None:
                self._workers = WorkerPool(WorkerOptions(
                    size=s.heavy_threads,
                    instrument_file=str(s.instrument_file) if s.instrument_file else None,
                    nice=s.heavy_nice, kill_grace_s=s.heavy_kill_grace_s,
                    retry_after_s=s.retry_after_s))
            return self._workers

    def close(self) -> None:
        with self._lock:
            heavy, self._heavy = self._heavy, None
            jobs, self._jobs = self._jobs, None
            workers, self._workers = self._workers, None
        if heavy is not None:
            heavy.shutdown()
        if workers is not None:
            workers.close()
        if jobs is not None:
            jobs.shutdown()


def _state(request: Request) -> ServiceState:
    return request.app.state.mxs


def _lists_of(request: Request) -> TargetListStore:
    return _state(request).lists


def _heavy_of(request: Request) -> HeavyExecutor:
    return _state(request).heavy


async def _admit(req: Any, st: ServiceState, prefix: tuple[str | int, ...] = ("body",), *,
                 job: bool = False) -> tuple[Any, float]:
    """The request with a stored list's targets in place of its ``target_list_id`` (loaded
    off the event loop), checked against this server's limits and by the stage's domain
    (:func:`service.admission.check_stage`, off the event loop): the one check of a stage
    request, at its endpoint and as a job. Returns it and the solver time limit. An error
    a stored list's targets cause is a 422 naming ``target_list_id``."""
    list_id = getattr(req, "target_list_id", None)
    if list_id is not None:
        req = await run_in_threadpool(resolve, req, st.lists, prefix)
    try:
        limit = check_request(req, st.settings, st.instrument, prefix, job=job)
        await run_in_threadpool(check_stage, req, st.instrument, prefix)
    except FieldError as exc:
        if list_id is None:
            raise
        raise _in_list(exc, list_id, prefix) from exc
    return req, limit


def _in_list(exc: FieldError | InputError, list_id: str,
             prefix: tuple[str | int, ...] = ("body",)) -> Exception:
    """An error naming ``targets[i]`` of a request whose targets came from a stored list, as
    a 422 naming ``target_list_id`` and the list's row (``exc`` itself when it names another
    field)."""
    if isinstance(exc, InputError):
        loc: tuple[Any, ...] = (*prefix, *parse_loc(str(exc.field)))
        bare, type_ = exc.message, "value_error"
    else:
        loc, bare, type_ = exc.loc, exc.bare, exc.type
    if loc[:len(prefix) + 1] != (*prefix, "targets"):
        return exc
    rest = loc[len(prefix) + 1:]
    where = f" row {rest[0] + 1}" if rest and isinstance(rest[0], int) else ""
    what = f" ({rest[1]})" if len(rest) > 1 else ""
    return FieldError((*prefix, "target_list_id"), f"target list {list_id!r}{where}{what}: "
                      f"{bare}", type_)


async def _from_list(list_id: str | None, answer: Awaitable[JSONResponse]) -> JSONResponse:
    """Await ``answer``; errors naming ``targets[i]`` name the stored list's row instead."""
    try:
        return await answer
    except (FieldError, InputError) as exc:
        if list_id is None:
            raise
        raise _in_list(exc, list_id) from exc


async def _state_dep(request: Request) -> ServiceState:  # async: resolved on the event loop
    return _state(request)


StateDep = Annotated[ServiceState, Depends(_state_dep)]


async def _on_overloaded(_: Request, exc: Overloaded) -> JSONResponse:
    return JSONResponse(status_code=exc.status_code, content=error_body(exc.code, exc.message),
                        headers={"Retry-After": str(exc.retry_after_s)})


def _on_sigterm(action: Callable[[], None]) -> Callable[[], None]:
    """Run ``action`` first when the server (uvicorn) handling SIGTERM receives it: stage
    requests in flight are answered 503 at once, so the server's graceful shutdown, which
    waits for open requests, is not held up by long computations. Returns the undo."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None  # not the process's server (tests, embedded use)
    previous = signal.getsignal(signal.SIGTERM)
    if not callable(previous):
        return lambda: None  # nobody handles SIGTERM: the default action ends the process

    def handler(signum: int, frame: Any) -> None:
        try:
            action()
        finally:
            previous(signum, frame)

    signal.signal(signal.SIGTERM, handler)

    def restore() -> None:
        signal.signal(signal.SIGTERM, previous)

    return restore


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    state = ServiceState(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        _ = state.jobs  # open the job database now: re-queues jobs whose lease expired
        _ = state.lists
        await run_in_threadpool(pipeline.warm_up)  # the planner's compiled kernels, before the first request
        start_fork_server()  # the upload readers' (in the background)
        if state.workers is not None:
            state.workers.start()  # the heavy workers warm up in the background
        heavy = state.heavy
        restore = _on_sigterm(heavy.close)
        yield
        restore()
        state.close()

    app = FastAPI(
        title="MXS planner",
        version=VERSION,
        summary="Pointings, probe-arm allocations and collision-free motion plans for MIRADAS.",
        lifespan=lifespan,
        docs_url=None,  # served offline by install_web
        redoc_url=None,
    )
    app.state.mxs = state
    install_error_handlers(app)
    app.add_exception_handler(Overloaded, _on_overloaded)  # type: ignore[arg-type]
    warn_if_empty(settings)
    describe_security(app, required=effective_token(settings) is not None)
    describe_limits(app, settings.max_time_limit_s, 2.0 * state.instrument.fov_radius_mm)
    # outermost last: CORS headers on every answer (401, 413, 503 included); the token is
    # checked before the body is read, and so is whether a heavy slot is free
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes,
                       setting=env_name("max_body_bytes"), routes=_body_limits(settings))
    app.add_middleware(BodyTimeoutMiddleware, timeout_s=settings.body_timeout_s,
                       buffer_bytes=settings.max_body_buffer_bytes,
                       retry_after_s=settings.retry_after_s)
    app.add_middleware(RefuseWhenFull, executor=lambda: state.heavy, paths=HEAVY_PATHS)
    app.add_middleware(AuthMiddleware, token=effective_token(settings))
    app.add_middleware(CatchAllMiddleware)
    if settings.cors_origin_list:
        app.add_middleware(
            CORSMiddleware, allow_origins=settings.cors_origin_list, allow_methods=["GET", "POST"],
            allow_headers=["Authorization", "Content-Type"],
        )
    install_web(app)
    install_target_lists(app, _lists_of, _heavy_of, settings, auth=Auth,
                         responses=ERRORS)
    _service_routes(app)
    _stage_routes(app)
    _job_routes(app)
    app.include_router(finding_charts.router)
    app.include_router(validations.router, responses=ERRORS)
    return app


def _body_limits(settings: Settings) -> dict[str, tuple[int, str]]:
    """Routes whose body limit is not ``MXS_MAX_BODY_BYTES``: survey-size work."""
    return {path: (getattr(settings, name), env_name(name)) for path, name in (
        ("/v1/segmentations", "max_segmentation_body_bytes"),
        ("/v1/jobs", "max_job_body_bytes"),
        ("/v1/validations", "max_job_body_bytes"),
        ("/v1/target-lists", "max_upload_bytes"))}


# Cheap routes are ``async``: they run on the event loop, never behind heavy work (which
# runs in the bounded HeavyExecutor's worker processes, never in the thread pool the page and
# files use).


def _service_routes(app: FastAPI) -> None:

    @app.get("/v1/health", operation_id="health", response_model=Health, tags=["service"],
             responses=ERRORS)
    async def health() -> dict[str, Any]:
        """Liveness: the process serves requests (no database, no computation)."""
        return {"status": "ok", "version": VERSION}

    @app.get("/v1/health/live", operation_id="health_live", response_model=Health,
             tags=["service"], responses=ERRORS)
    async def health_live() -> dict[str, Any]:
        """Liveness, as `/v1/health`: what a container health check should probe."""
        return {"status": "ok", "version": VERSION}

    @app.get("/v1/health/ready", operation_id="health_ready", response_model=Readiness,
             tags=["service"], responses=ERRORS)
    async def health_ready(st: StateDep) -> JSONResponse:
        """Readiness: the job database answers, the job workers run and a heavy-request slot
        is free. 503 (with `Retry-After`) otherwise: route new work to another instance."""
        jobs_ok, jobs_reason = await run_in_threadpool(st.jobs.ready)
        heavy = st.heavy
        room = heavy.has_room()
        ready = jobs_ok and room
        body = {"status": "ready" if ready else "not_ready", "version": VERSION,
                "jobs": jobs_reason, "heavy_in_use": heavy.in_use,
                "heavy_capacity": heavy.capacity}
        headers = None if ready else {"Retry-After": str(st.settings.retry_after_s)}
        return JSONResponse(Readiness.model_validate(body).model_dump(mode="json"),
                            status_code=200 if ready else 503, headers=headers)

    @app.get("/v1/instrument", operation_id="get_instrument", response_model=InstrumentInfo,
             tags=["service"], responses=ERRORS)
    async def instrument(st: StateDep) -> dict[str, Any]:
        return pipeline.instrument_info(st.instrument)


def _stage_routes(app: FastAPI) -> None:
    @app.post("/v1/segmentations", operation_id="create_segmentation", response_model=SegmentationResponse, tags=["stages"],
              dependencies=[Auth], responses={**ERRORS, 404: LIST_NOT_FOUND})
    async def segmentations(req: SegmentationRequest, st: StateDep, request: Request) -> JSONResponse:
        """Pointings covering the targets (thesis ch. 4): the cheap stage, up to
        `MXS_MAX_SEGMENTATION_TARGETS` targets (default 100,000), inline or as a stored
        `target_list_id`.

        The schema states exactly one of `targets` and `target_list_id`, at least one target,
        and this server's `threshold_mm` bound (the FOV diameter). Also a 422 naming the field:
        duplicate target ids; targets with no centre on the sky (spread over the whole sphere)
        or one 90 deg or more from the centre (or from `tangent_point`). A `target_list_id`
        that names no stored list is a 404."""
        list_id = req.target_list_id
        req, _ = await _admit(req, st)
        return await _from_list(list_id, answer_heavy(
            request, st, SegmentationResponse, pipeline.segmentation, req))

    @app.post("/v1/allocations", operation_id="create_allocation", response_model=AllocationResponse, tags=["stages"],
              dependencies=[Auth], responses=ERRORS)
    async def allocations(req: AllocationRequest, st: StateDep, request: Request) -> JSONResponse:
        """The arms' allocation to the targets (thesis ch. 5): one configuration, or all of
        them to completeness (`configurations: "all"`).

        The schema states at least one target, `pointing` with sky targets, each arm at most
        once in `start` and in `disabled_arms`, and this server's `time_limit_s` bound
        (`MXS_MAX_TIME_LIMIT_S`). Also a 422 naming the field: duplicate target ids, a sky
        target 90 deg or more from the pointing, an arm the instrument does not have. A valid
        request that cannot be satisfied answers 200 with `unallocated[].reason`."""
        req, limit = await _admit(req, st)
        return await answer_heavy(request, st, AllocationResponse, pipeline.allocation, req,
                            ("time_limit_s", limit))

    @app.post("/v1/motion-plans", operation_id="create_motion_plan", response_model=MotionPlanResponse, tags=["stages"],
              dependencies=[Auth], responses=ERRORS)
    async def motion_plans(req: MotionPlanRequest, st: StateDep, request: Request) -> JSONResponse:
        """Collision-free trajectories of the 12 arms from `start` to `goal` (thesis ch. 6).

        The schema states that `start` and `goal` each name every arm once, and this server's
        `time_limit_s` bound. Also a 422 naming the field: `dt_col_s` must divide `dt_s` into
        a whole number of collision steps (the default `dt_col_s` is 0.1 s, so a `dt_s`
        alone must be a multiple of 0.1 s), and (220 s / dt_s) x (220 s / dt_col_s) may not
        exceed 1e6. A plan that cannot be found answers 200 with `status: "failed"`."""
        req, limit = await _admit(req, st)
        return await answer_heavy(request, st, MotionPlanResponse, pipeline.motion_plan, req,
                            ("time_limit_s", limit))

    @app.post("/v1/plans", operation_id="create_plan", response_model=PlanResponse, tags=["stages"],
              dependencies=[Auth], responses={**ERRORS, 404: LIST_NOT_FOUND})
    async def plans(req: PlanRequest, st: StateDep, request: Request) -> JSONResponse:
        """The whole pipeline: segmentation, then per pointing allocation (all
        configurations) and the motion sequence park -> c1 -> ... -> park, whose planner may
        change the configurations (a leg through park, targets moved to other or new
        configurations) so that every leg can be executed; the changes are listed per pointing.

        The request's `time_limit_s` bounds the whole plan, answered within it + 1 s (default
        and cap: the server's plan budget `MXS_PLAN_BUDGET_S`, default 120 s): pointings
        reached after it ran out report their targets `no_time`.
        At most `MXS_MAX_PLAN_TARGETS` targets (inline or a stored `target_list_id`). Plan big
        fields with `POST /v1/jobs` (`kind: "plan"`, budget `MXS_JOB_BUDGET_S`, default 1 h). A motion leg that still cannot be planned is returned with status "failed",
        and the plan says `executable: false` with the `reasons`.

        The schema states exactly one of `targets` and `target_list_id`, at least one target,
        and this server's `time_limit_s` and `threshold_mm` bounds. Also a 422 naming the
        field: duplicate target ids, targets with no centre on the sky or one 90 deg or more
        from it. A `target_list_id` that names no stored list is a 404.
        """
        list_id = req.target_list_id
        req, _ = await _admit(req, st)
        return await _from_list(list_id, answer_heavy(
            request, st, PlanResponse, pipeline.plan, req,
            ("budget_s", st.settings.plan_budget_s)))


def _job_routes(app: FastAPI) -> None:
    @app.post("/v1/jobs", operation_id="create_job", response_model=JobCreated, status_code=202, tags=["jobs"],
              dependencies=[Auth], responses={**ERRORS, 404: LIST_NOT_FOUND, 429: QUEUE_FULL})
    async def create_job(job: JobRequest, st: StateDep) -> JSONResponse:
        """Queue a stage request as a job: validated now exactly as its endpoint validates it,
        by the same code (the rules in each stage's description; 422 naming
        `body.<kind>.request.<field>`; a plan job may hold up to
        `MXS_MAX_PLAN_JOB_TARGETS` targets), refused with 429 + `Retry-After` when the queue is
        full (`MXS_MAX_QUEUED_JOBS`). A segmentation or plan request may name a stored list
        (`target_list_id`): its targets are copied into the job when it is queued; an id that
        names no stored list is a 404 naming `body.<kind>.request.target_list_id`."""
        req, limit = await _admit(job.request, st, ("body", job.kind, "request"), job=True)

        def submit() -> str:  # off the event loop: a big request is dumped and stored here
            request = req.model_dump(mode="json", exclude_none=True)
            return st.jobs.submit(job.kind, request, limit, st.settings.job_budget_s)

        job_id = await run_in_threadpool(submit)
        return JSONResponse(status_code=202, content={"job_id": job_id, "status": "queued"})

    @app.get("/v1/jobs/{job_id}", operation_id="get_job", response_model=JobStatus, tags=["jobs"],
             dependencies=[Auth], responses={404: {"model": ErrorResponse, "description": "No such job."},
                        410: {"model": ErrorResponse, "description": "The job finished longer "
                              "ago than the server keeps results (MXS_JOB_RETENTION_S / "
                              "MXS_JOB_RETENTION_COUNT)."},
                        **ERRORS})
    async def get_job(job_id: str, st: StateDep) -> JSONResponse:
        return await run_in_threadpool(_job_answer, st, job_id)

    @app.post("/v1/jobs/{job_id}/cancel", operation_id="cancel_job", response_model=JobStatus,
              tags=["jobs"], dependencies=[Auth], responses={
                  404: {"model": ErrorResponse, "description": "No such job."},
                  409: {"model": ErrorResponse, "description": "The job has already finished "
                        "(done, failed or cancelled); it is left as it is."},
                  410: {"model": ErrorResponse, "description": "The job has expired."},
                  **ERRORS})
    async def cancel_job(job_id: str, st: StateDep) -> JSONResponse:
        """Cancel a queued or running job: it ends at once with status `cancelled` (a queued
        job is never started; the worker of a running one stops within a couple of seconds
        and its result is never recorded). Answers the job's new state. The job stays
        readable with `GET /v1/jobs/{job_id}`, so cancelling is a state change (POST), not a
        deletion."""
        return await run_in_threadpool(_cancel_answer, st, job_id)


def _cancel_answer(st: ServiceState, job_id: str) -> JSONResponse:
    before = st.jobs.cancel(job_id)
    if before in ("done", "failed", CANCELLED):
        raise ServiceError(f"job {job_id!r} has already finished ({before}); only queued or "
                           "running jobs can be cancelled", status_code=409, code="conflict")
    return _job_answer(st, job_id)


def _job_answer(st: ServiceState, job_id: str) -> JSONResponse:
    """A job's state, read, validated and rendered in a thread (results can be large)."""
    job = st.jobs.get(job_id)
    kept = (f"finished jobs are kept for {st.settings.job_retention_s:g} s, at most the newest "
            f"{st.settings.job_retention_count}")
    if job is None:
        raise NotFound(f"job {job_id!r} not found ({kept})")
    if job["status"] == EXPIRED:
        raise ServiceError(f"job {job_id!r} has expired and its result was deleted ({kept})",
                           status_code=410, code="gone")
    try:
        typed = JOB_STATUS.validate_python(job)
    except ValidationError as exc:  # a result stored under an older schema: answered as stored
        log.warning("job %s: stored result does not fit the %s schema (%d errors); answered "
                    "as stored", job_id, job["kind"], exc.error_count())
        return JSONResponse(job)
    return JSONResponse(JOB_STATUS.dump_python(typed, mode="json", by_alias=True))


app = create_app()
