"""Service settings, read from ``MXS_*`` environment variables (pydantic-settings)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Every knob of the service. ``MXS_<NAME>`` sets ``<name>`` (case-insensitive)."""

    model_config = SettingsConfigDict(env_prefix="MXS_", extra="ignore")

    instrument_file: Path | None = Field(
        None, description="Instrument TOML file; unset = the packaged default geometry."
    )
    workers: int = Field(2, ge=1, le=64, description="Processes in the job pool.")
    job_db: Path = Field(Path("data/mxs-jobs.sqlite3"), description="SQLite file holding "
                         "jobs; its directory is created (the default `data/` is git-ignored).")
    cors_origins: str = Field(
        "", description="Comma-separated origins allowed by CORS ('*' for any); empty = none."
    )
    api_token: str | None = Field(
        None, description="When set, POST endpoints, GET /v1/jobs/{job_id} and GET "
        "/v1/target-lists/{target_list_id} require 'Authorization: Bearer <token>'. Empty "
        "counts as unset (logged as a warning)."
    )
    max_segmentation_targets: int = Field(
        100_000, ge=1, description="Most targets of one segmentation (POST /v1/segmentations "
        "and segmentation jobs): the cheap stage, survey-size lists.")
    max_allocation_targets: int = Field(
        5000, ge=1, description="Most targets of one allocation (POST /v1/allocations and "
        "allocation jobs): one pointing, an exact solve.")
    max_plan_targets: int = Field(
        5000, ge=1, description="Most targets of one synchronous POST /v1/plans (bounded by "
        "MXS_PLAN_BUDGET_S); bigger fields go to plan jobs.")
    max_plan_job_targets: int = Field(
        10_000, ge=1, description="Most targets of one plan job (bounded by MXS_JOB_BUDGET_S; "
        "its result holds every pointing's trajectories).")
    max_target_list_targets: int = Field(
        100_000, ge=1, description="Most targets of one stored target list "
        "(POST /v1/target-lists).")
    max_targets: int | None = Field(
        None, ge=1, description="When set, a cap on every per-stage target limit above (the "
        "lower wins).")
    max_body_bytes: int = Field(
        10_000_000, ge=1024, description="Largest request body of every route not named below.")
    max_segmentation_body_bytes: int = Field(
        50_000_000, ge=1024, description="Largest body of POST /v1/segmentations.")
    max_job_body_bytes: int = Field(
        50_000_000, ge=1024, description="Largest body of POST /v1/jobs.")
    max_upload_bytes: int = Field(
        50_000_000, ge=1024, description="Largest body of POST /v1/target-lists (the uploaded "
        "file and its multipart framing).")
    max_upload_decompressed_bytes: int = Field(
        100_000_000, ge=1024, description="Most bytes a compressed upload (gzip, bzip2, xz) "
        "of POST /v1/target-lists may decompress to; 422 beyond.")
    upload_parse_time_s: float = Field(
        10.0, gt=0, description="Wall-clock limit of reading one uploaded table (POST "
        "/v1/target-lists), in a process of its own that is stopped past it; 422. A "
        "100,000-row table of sexagesimal cells takes about 7 s on one core.")
    upload_parse_memory_bytes: int = Field(
        500_000_000, ge=16_000_000, description="Address space the process reading one "
        "uploaded table may take beyond what it starts with (RLIMIT_AS); reading stops past "
        "it with a 413. A 100,000-row CSV takes less than 70 MB.")
    default_time_limit_s: float = Field(
        30.0, gt=0, description="Time limit of a stage request (allocation, motion plan) that "
        "gives none; a plan's limit is plan_budget_s / job_budget_s."
    )
    max_time_limit_s: float = Field(600.0, gt=0, description="Largest time limit a request may ask.")
    plan_budget_s: float = Field(
        120.0, gt=0, description="Wall-clock budget of one synchronous POST /v1/plans (the "
        "whole pipeline); plan big fields as jobs."
    )
    job_budget_s: float = Field(
        3600.0, gt=0, description="Wall-clock budget of one 'plan' job (the whole pipeline)."
    )

    heavy_threads: int = Field(
        2, ge=1, le=64, description="Synchronous stage requests (segmentations, allocations, "
        "motion plans, plans) computed at once: one heavy thread each, and with "
        "heavy_processes one worker process each."
    )
    heavy_processes: bool = Field(
        True, description="Compute synchronous stage requests in worker processes (one per "
        "heavy thread, started with the server and replaced when one dies), so that the "
        "server's event loop never waits for a computation; false: in the heavy threads of "
        "the server process."
    )
    heavy_nice: int = Field(
        10, ge=0, le=19, description="Niceness added to the heavy request workers and the job "
        "workers alike, so that the two share a busy CPU evenly and the server's event loop "
        "(health checks, cheap routes) wins it over both."
    )
    heavy_kill_grace_s: float = Field(
        5.0, gt=0, description="Seconds a heavy worker process may run past its request's "
        "time limit (a segmentation's: max_time_limit_s), or after its request was "
        "cancelled, before it is killed and replaced; the request is then answered as out "
        "of time (422 naming time_limit_s)."
    )
    heavy_queue: int = Field(
        2, ge=0, le=1000, description="Stage requests that may wait for a heavy thread (the "
        "wait is taken off their time limit); beyond threads + queue a request is refused at "
        "once with 503 and Retry-After."
    )
    retry_after_s: int = Field(5, ge=1, le=3600, description="Retry-After of a 503 or 429 refusal.")
    body_timeout_s: float = Field(
        20.0, gt=0, description="Time a client has to send its whole request body (else 408)."
    )
    max_body_buffer_bytes: int = Field(
        200_000_000, ge=1024, description="Request bodies being received at once may hold at "
        "most this together; beyond, 503 with Retry-After."
    )
    shutdown_grace_s: int = Field(
        2, ge=1, le=600, description="On SIGTERM, seconds open requests get to finish before "
        "they are cancelled (mxs-planner serve)."
    )
    job_lease_s: float = Field(
        30.0, ge=1, description="Lease of a running job; its worker renews it every third. A "
        "job whose lease expired (server killed) is re-queued by any server on the database."
    )
    job_max_attempts: int = Field(
        3, ge=1, description="Interruptions after which a job is failed instead of re-queued "
        "(counted per job; a re-queued plan job resumes from its committed pointings)."
    )
    dask_scheduler: str | None = Field(
        None, description="Address of a dask.distributed scheduler (tcp://host:8786): the "
        "pointings of plan jobs run there, one task each (needs the 'distributed' extra). "
        "Unset: each plan job computes its pointings in its own job-pool process."
    )
    max_queued_jobs: int = Field(
        100, ge=1, description="Jobs that may wait in the queue; more are refused with 429."
    )
    job_retention_s: float = Field(
        7 * 86400.0, gt=0, description="Finished jobs older than this answer 410 Gone."
    )
    job_retention_count: int = Field(
        1000, ge=1, description="Finished jobs kept at most (the newest); older answer 410."
    )
    target_list_retention_s: float = Field(
        7 * 86400.0, gt=0, description="Stored target lists older than this are deleted.")
    target_list_retention_count: int = Field(
        100, ge=1, description="Stored target lists kept at most (the newest); older ones are "
        "deleted.")

    def target_limit(self, stage: str) -> tuple[int, str]:
        """The most targets ``stage`` accepts here and the setting that says so (``stage``: a
        job kind, ``plan-job``, or ``target-list``)."""
        name = _TARGET_LIMITS[stage]
        value = getattr(self, name)
        if self.max_targets is not None and self.max_targets < value:
            value, name = self.max_targets, "max_targets"
        return value, env_name(name)

    @field_validator("dask_scheduler")
    @classmethod
    def _dask_installed(cls, v: str | None) -> str | None:
        if not v:
            return None
        if importlib.util.find_spec("distributed") is None:
            raise ValueError("MXS_DASK_SCHEDULER is set but dask.distributed is not installed "
                             "(pip install 'mxs-planner[distributed]')")
        return v

    @property
    def cors_origin_list(self) -> list[str]:
        return [o.strip() for o in self.cors_origins.split(",") if o.strip()]


_TARGET_LIMITS = {
    "segmentation": "max_segmentation_targets",
    "allocation": "max_allocation_targets",
    "plan": "max_plan_targets",
    "plan-job": "max_plan_job_targets",
    "target-list": "max_target_list_targets",
}


def env_name(field: str) -> str:
    """The environment variable of a setting (``max_body_bytes`` -> ``MXS_MAX_BODY_BYTES``)."""
    return "MXS_" + field.upper()
