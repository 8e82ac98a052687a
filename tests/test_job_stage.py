"""Progress names the stage and the pointing (issue 40): the synchronous plan's ``on_stage``
callback, a plan job's persisted ``stage`` (service.jobs), typed in its status schema."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from planner import stages
from planner.programme import ALLOCATION_PART
from service import job_run, jobs, pipeline
from service.job_schemas import JOB_STATUS
from service.schemas import PlanRequest

INST = pipeline.instrument_from(None)
# three clumps of two targets, 0.2 deg apart: three pointings (the FOV is 5 arcmin wide)
TARGETS = [{"id": f"t{i}", "ra_deg": 150.0 + 0.2 * (i % 3) + 0.0006 * i,
            "dec_deg": 2.0 + 0.0004 * i, "priority": 1 + i % 4} for i in range(6)]
REQUEST = {"targets": TARGETS, "seed": 3, "time_limit_s": 60}
POINTING = re.compile(r"^(?:round (\d+): )?(allocating pointing|planning motion, pointing) (\d+) of (\d+)$")


def test_a_stage_names_the_pointing_and_what_is_done_to_it() -> None:
    assert stages.plan_stage(1, 0.0, 3) == "0 of 3 pointings done"
    assert stages.plan_stage(1, 1.0 + 0.5 * ALLOCATION_PART, 3) == "allocating pointing 2 of 3"
    assert stages.plan_stage(1, 2.0 + ALLOCATION_PART, 3) == "planning motion, pointing 3 of 3"
    assert stages.plan_stage(2, 0.9, 1) == "round 2: planning motion, pointing 1 of 1"
    assert stages.plan_stage(1, 3.0, 3) == "3 of 3 pointings done"
    assert stages.segmentation_stage("fewest-exposures") == stages.OPTIMISING
    assert stages.segmentation_stage("complete-linkage") == stages.SEGMENTING


def final_pointings(body: dict) -> set[int]:
    """The pointings (1, 2, ...) of the plan of ``body`` whose allocation from the programme
    optimiser is final: the plan plans their motion without allocating them."""
    req = PlanRequest.model_validate(body)
    seg = pipeline.segment_plan(req, INST, pipeline.plan_limit_s(req, None))
    return {k + 1 for k, p in enumerate(seg.pointings) if p.allocation_final}


def check_plan_stages(seen: list[str], mode_stage: str, n: int, final: set[int] = frozenset()) -> None:
    """``seen``: a plan's stages in order. It segments first and assembles last; between, the
    first round takes pointing 1 .. n in order, each allocated before its motion is planned
    (the pointings given a share and planned; the others are only counted done), except the
    pointings ``final`` (their allocation from the optimiser is final: motion only)."""
    assert seen[0] == mode_stage and seen[-1] == stages.ASSEMBLING
    assert all(a != b for a, b in zip(seen, seen[1:], strict=False))  # each stage once as it begins
    first = [(m.group(2), int(m.group(3)), int(m.group(4))) for s in seen[1:-1]
             if (m := POINTING.match(s)) and m.group(1) is None]
    assert {total for *_, total in first} == {n}
    order = [(k, what != "allocating pointing") for what, k, _ in first]
    assert order == sorted(order)  # pointing by pointing, allocation before motion
    assert {k for k, _ in order} == set(range(1, n + 1))
    assert all(((k, False) in order) == (k not in final) and (k, True) in order for k, _ in order)
    assert f"{n} of {n} pointings done" in seen


@pytest.mark.parametrize("mode", [None, "complete-linkage"])
def test_the_synchronous_plan_names_its_stages(mode) -> None:
    body = REQUEST if mode is None else {**REQUEST, "segmentation_mode": mode}
    seen: list[str] = []
    heard: list[float] = []
    out = pipeline.plan(PlanRequest.model_validate(body), INST, heard.append, budget_s=120.0,
                        on_stage=seen.append)
    n = len(out["pointings"])
    assert n == 3 and out["executable"]
    final = final_pointings(body) if mode is None else set()
    check_plan_stages(seen, stages.OPTIMISING if mode is None else stages.SEGMENTING, n, final)
    assert heard == sorted(heard)  # the fractions are still reported, as before


def test_a_plan_job_persists_its_stages(tmp_path: Path, monkeypatch) -> None:
    """A plan job run by a job-pool worker (service.job_run.run_job, the local runner): its
    ``stage`` passes queued -> the segmentation -> pointing by pointing -> assembling -> done,
    each stage stored as it begins; the status schema types it."""
    store = jobs.JobStore(tmp_path / "j.db")
    store.init()
    job_id = store.create("plan", REQUEST, time_limit_s=60.0, budget_s=3600.0)
    assert store.get(job_id)["stage"] == stages.QUEUED
    assert JOB_STATUS.validate_python(store.get(job_id)).stage == stages.QUEUED
    claimed = store.claim("srv/1", lease_s=60.0)
    assert claimed is not None
    stored: list[str] = []
    real = jobs.JobStore.set_stage

    def recording(self, jid, stage):
        real(self, jid, stage)
        stored.append(self.get(jid)["stage"])  # as a poll of the job would read it

    monkeypatch.setattr(jobs.JobStore, "set_stage", recording)
    assert job_run.run_job(str(store.db_path), job_id, "plan", REQUEST, None, 60.0, 3600.0,
                        owner="srv/1") == "done"
    job = store.get(job_id)
    assert job["status"] == "done" and job["stage"] == stages.DONE
    assert JOB_STATUS.validate_python(job).stage == stages.DONE
    check_plan_stages(stored, stages.OPTIMISING, job["pointings_total"], final_pointings(REQUEST))


def test_other_jobs_name_their_stage_and_a_requeued_job_is_queued_again(tmp_path: Path,
                                                                        monkeypatch) -> None:
    store = jobs.JobStore(tmp_path / "j.db")
    store.init()
    seg = {"targets": TARGETS[:3]}
    job_id = store.create("segmentation", seg)
    store.claim("srv/1", lease_s=60.0)
    seen: list[str] = []
    real = jobs.JobStore.set_stage
    monkeypatch.setattr(jobs.JobStore, "set_stage",
                        lambda self, jid, s: (seen.append(s), real(self, jid, s))[1])
    assert job_run.run_job(str(store.db_path), job_id, "segmentation", seg, None, 10.0,
                        owner="srv/1") == "done"
    assert seen == [stages.SEGMENTING] and store.get(job_id)["stage"] == stages.DONE
    # a running job handed back to the queue reads 'queued' again
    other = store.create("segmentation", seg)
    store.claim("srv/2", lease_s=60.0)
    store.set_stage(other, stages.SEGMENTING)
    assert store.get(other)["stage"] == stages.SEGMENTING
    assert store.release("srv") == 1 and store.get(other)["stage"] == stages.QUEUED
