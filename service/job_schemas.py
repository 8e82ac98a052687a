"""Job schemas of the v1 HTTP contract: a job request wraps one stage request, a job status
carries the stage's response as ``result``, typed per ``kind`` (one schema per job kind,
discriminated by ``kind``, so a generated client gets the stage's own response type)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, TypeAdapter

from service.response_schemas import (
    AllocationResponse,
    MotionPlanResponse,
    PlanResponse,
    SegmentationResponse,
)
from service.schemas import (
    AllocationRequest,
    MotionPlanRequest,
    PlanRequest,
    Request,
    Response,
    SegmentationRequest,
)


class SegmentationJob(Request):
    kind: Literal["segmentation"]
    request: SegmentationRequest


class AllocationJob(Request):
    kind: Literal["allocation"]
    request: AllocationRequest


class MotionPlanJob(Request):
    kind: Literal["motion-plan"]
    request: MotionPlanRequest


class PlanJob(Request):
    kind: Literal["plan"]
    request: PlanRequest


JobRequest = Annotated[
    SegmentationJob | AllocationJob | MotionPlanJob | PlanJob, Field(discriminator="kind")
]
JobKind = Literal["segmentation", "allocation", "motion-plan", "plan"]
JobState = Literal["queued", "running", "done", "failed", "cancelled"]


class JobCreated(Response):
    job_id: str
    status: JobState


class JobStatusBase(Response):
    job_id: str
    kind: JobKind
    status: JobState = Field(description="'queued', 'running', then 'done' (with `result`), "
                             "'failed' (with `error`) or 'cancelled' (POST "
                             "/v1/jobs/{job_id}/cancel).")
    progress: float = Field(ge=0.0, le=1.0)
    result: Response | None = None
    error: str | None = Field(None, description="Why the job failed or was cancelled.")
    created_at: float = Field(description="Unix time the job was accepted.")
    updated_at: float = Field(description="Unix time of the last state change.")
    pointings_done: int | None = Field(None, ge=0, description="A plan job: pointings whose "
                                       "plan is computed and stored. `progress` is 0.05 once "
                                       "the field is segmented, then 0.05 + 0.80 * "
                                       "pointings_done / pointings_total in the first round "
                                       "(plus the part done of a pointing being computed in "
                                       "the job pool); each later round, which plans again the "
                                       "pointings with a failed leg, takes an equal part of "
                                       "the last 0.15.")
    pointings_total: int | None = Field(None, ge=0, description="A plan job: its pointings "
                                        "(known once the field is segmented).")
    stage: str | None = Field(None, description="What the job is doing, in words: 'queued'; "
                              "a plan job then 'optimising pointings' (segmentation mode "
                              "'fewest-exposures') or 'segmenting the field', 'allocating "
                              "pointing k of n', 'planning motion, pointing k of n', 'k of n "
                              "pointings done' (later rounds prefixed 'round r: '), 'assembling "
                              "the plan'; other kinds 'segmenting the field', 'allocating' or "
                              "'planning motion'; 'done' once done. A failed or cancelled job "
                              "keeps the stage it was in.")


class SegmentationJobStatus(JobStatusBase):
    kind: Literal["segmentation"]
    result: SegmentationResponse | None = Field(None, description="Set when `status` is 'done'.")


class AllocationJobStatus(JobStatusBase):
    kind: Literal["allocation"]
    result: AllocationResponse | None = Field(None, description="Set when `status` is 'done'.")


class MotionPlanJobStatus(JobStatusBase):
    kind: Literal["motion-plan"]
    result: MotionPlanResponse | None = Field(None, description="Set when `status` is 'done'.")


class PlanJobStatus(JobStatusBase):
    kind: Literal["plan"]
    result: PlanResponse | None = Field(None, description="Set when `status` is 'done'.")


JobStatus = Annotated[
    SegmentationJobStatus | AllocationJobStatus | MotionPlanJobStatus | PlanJobStatus,
    Field(discriminator="kind"),
]
JOB_STATUS: TypeAdapter[Any] = TypeAdapter(JobStatus)
