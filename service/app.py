"""The FastAPI application: routes translate HTTP to :mod:`service.pipeline` calls.

``service.app:app`` is built from the environment (``MXS_*``); tests and the CLI build
their own with :func:`create_app`.
"""

from __future__ import annotations

import logging
import secrets
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib.metadata import PackageNotFoundError, version
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from models.instrument import Instrument
from service import pipeline
from service.errors import (
    BodyLimitMiddleware,
    CatchAllMiddleware,
    FieldError,
    NotFound,
    ServiceError,
    install_error_handlers,
)
from service.jobs import JobManager
from service.schemas import (
    AllocationRequest,
    AllocationResponse,
    ErrorResponse,
    Health,
    InstrumentInfo,
    JobCreated,
    JobRequest,
    JobStatus,
    MotionPlanRequest,
    MotionPlanResponse,
    PlanRequest,
    PlanResponse,
    SegmentationRequest,
    SegmentationResponse,
)
from service.settings import Settings
from service.web import install_web

log = logging.getLogger("service")

try:
    VERSION = version("mxs-planner")
except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
    VERSION = "0.0.0"

_bearer = HTTPBearer(auto_error=False, description="Required on POST when MXS_API_TOKEN is set.")

ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": ErrorResponse, "description": "Missing or wrong bearer token."},
    413: {"model": ErrorResponse, "description": "Request body too large."},
    501: {"model": ErrorResponse, "description": "This stage is not available in this build."},
    503: {"model": ErrorResponse, "description": "Temporary failure; retry."},
}


class ServiceState:
    """Per-app state: settings, the loaded instrument and (lazily) the job manager."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self.instrument: Instrument = pipeline.instrument_from(
            str(settings.instrument_file) if settings.instrument_file else None
        )
        self._jobs: JobManager | None = None
        self._lock = threading.Lock()

    @property
    def jobs(self) -> JobManager:
        with self._lock:
            if self._jobs is None:
                s = self.settings
                self._jobs = JobManager(
                    s.job_db, s.workers, str(s.instrument_file) if s.instrument_file else None
                )
            return self._jobs

    def close(self) -> None:
        with self._lock:
            if self._jobs is not None:
                self._jobs.shutdown()
                self._jobs = None


def _state(request: Request) -> ServiceState:
    return request.app.state.mxs


StateDep = Annotated[ServiceState, Depends(_state)]


def _authorize(
    request: Request,
    creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    token = _state(request).settings.api_token
    if token is None:
        return
    if creds is None or not secrets.compare_digest(creds.credentials.encode(), token.encode()):
        raise ServiceError("a valid 'Authorization: Bearer <token>' header is required",
                           status_code=401, code="unauthorized")


Auth = Depends(_authorize)


def _check_limits(req: Any, settings: Settings, prefix: tuple[str | int, ...] = ("body",)) -> float:
    """Deployment limits the schema cannot know; returns the time limit to use."""
    targets = getattr(req, "targets", None)
    if targets is not None and len(targets) > settings.max_targets:
        raise FieldError((*prefix, "targets"),
                         f"at most {settings.max_targets} targets per request, got {len(targets)}",
                         "too_long")
    limit = getattr(req, "time_limit_s", None)
    if limit is not None and limit > settings.max_time_limit_s:
        raise FieldError((*prefix, "time_limit_s"),
                         f"must be <= {settings.max_time_limit_s} s on this server",
                         "less_than_equal")
    return float(limit if limit is not None else settings.default_time_limit_s)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    state = ServiceState(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        _ = state.jobs  # open the job database now: fails interrupted jobs at start-up
        yield
        state.close()

    app = FastAPI(
        title="MXS planner",
        version=VERSION,
        summary="Pointings, probe-arm allocations and collision-free motion plans for MIRADAS.",
        lifespan=lifespan,
        docs_url=None,  # served offline by install_web
        redoc_url=None,
        responses={422: {"description": "Invalid input; `detail[].loc` names the field."}},
    )
    app.state.mxs = state
    install_error_handlers(app)
    if settings.cors_origin_list:
        app.add_middleware(
            CORSMiddleware, allow_origins=settings.cors_origin_list, allow_methods=["GET", "POST"],
            allow_headers=["Authorization", "Content-Type"],
        )
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_body_bytes)
    app.add_middleware(CatchAllMiddleware)

    install_web(app, max_targets=settings.max_targets, auth=Auth, responses=ERRORS)

    @app.get("/v1/health", operation_id="health", response_model=Health, tags=["service"], responses=ERRORS)
    def health() -> dict[str, Any]:
        return {"status": "ok", "version": VERSION}

    @app.get("/v1/instrument", operation_id="get_instrument", response_model=InstrumentInfo, tags=["service"], responses=ERRORS)
    def instrument(st: StateDep) -> dict[str, Any]:
        return pipeline.instrument_info(st.instrument)

    # Stage endpoints are plain ``def``: FastAPI runs them in its thread pool, never on the
    # event loop. Long work belongs in /v1/jobs (process pool).

    @app.post("/v1/segmentations", operation_id="create_segmentation", response_model=SegmentationResponse, tags=["stages"],
              dependencies=[Auth], responses=ERRORS)
    def segmentations(req: SegmentationRequest, st: StateDep) -> dict[str, Any]:
        _check_limits(req, st.settings)
        return pipeline.segmentation(req, st.instrument)

    @app.post("/v1/allocations", operation_id="create_allocation", response_model=AllocationResponse, tags=["stages"],
              dependencies=[Auth], responses=ERRORS)
    def allocations(req: AllocationRequest, st: StateDep) -> dict[str, Any]:
        limit = _check_limits(req, st.settings)
        return pipeline.allocation(req, st.instrument, time_limit_s=limit)

    @app.post("/v1/motion-plans", operation_id="create_motion_plan", response_model=MotionPlanResponse, tags=["stages"],
              dependencies=[Auth], responses=ERRORS)
    def motion_plans(req: MotionPlanRequest, st: StateDep) -> dict[str, Any]:
        limit = _check_limits(req, st.settings)
        return pipeline.motion_plan(req, st.instrument, time_limit_s=limit)

    @app.post("/v1/plans", operation_id="create_plan", response_model=PlanResponse, tags=["stages"],
              dependencies=[Auth], responses=ERRORS)
    def plans(req: PlanRequest, st: StateDep) -> dict[str, Any]:
        """The whole pipeline: segmentation, then per pointing allocation (all
        configurations) and the motion sequence park -> c1 -> ... -> park, whose planner may
        change the configurations (a leg through park, targets moved to other or new
        configurations) so that every leg can be executed; the changes are listed per pointing.

        The request is bounded as a whole by the server's plan budget (`MXS_PLAN_BUDGET_S`,
        default 120 s): pointings reached after it ran out report their targets `no_time`.
        Plan big fields with `POST /v1/jobs` (`kind: "plan"`, budget `MXS_JOB_BUDGET_S`,
        default 1 h). A motion leg that still cannot be planned is returned with status "failed",
        and the plan says `executable: false` with the `reasons`.
        """
        limit = _check_limits(req, st.settings)
        return pipeline.plan(req, st.instrument, time_limit_s=limit,
                             budget_s=st.settings.plan_budget_s)

    @app.post("/v1/jobs", operation_id="create_job", response_model=JobCreated, status_code=202, tags=["jobs"],
              dependencies=[Auth], responses=ERRORS)
    def create_job(job: JobRequest, st: StateDep) -> JSONResponse:
        limit = _check_limits(job.request, st.settings, ("body", job.kind, "request"))
        pipeline.require_stage(job.kind)  # 501 now rather than a job that must fail
        request = job.request.model_dump(mode="json", exclude_none=True)
        job_id = st.jobs.submit(job.kind, request, limit, st.settings.job_budget_s)
        return JSONResponse(status_code=202, content={"job_id": job_id, "status": "queued"})

    @app.get("/v1/jobs/{job_id}", operation_id="get_job", response_model=JobStatus, tags=["jobs"],
             responses={404: {"model": ErrorResponse, "description": "No such job."}, **ERRORS})
    def get_job(job_id: str, st: StateDep) -> dict[str, Any]:
        job = st.jobs.get(job_id)
        if job is None:
            raise NotFound(f"job {job_id!r} not found")
        return job

    return app


app = create_app()
