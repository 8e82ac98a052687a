"""A ``plan`` job as a whole programme: segmentation, then one task per pointing, each
committed as soon as it is computed, then the answer assembled in pointing order.

The pointings run on a :class:`~service.runners.PointingRunner` (this process, or a Dask
cluster). Each pointing's plan depends only on the request, the pointing and its index:
its seed is :func:`planner.programme.pointing_seed` of the job's seed, and its wall-clock
share is fixed before any pointing runs, then later rounds share what the earlier ones left
(:func:`planner.programme.run_rounds`), so the plan is the same whatever the number of
workers, their order or the attempt that computed a pointing, and equal to the synchronous
``POST /v1/plans`` answer whenever the wall-clock guard cuts no computation short.

A job re-queued after an interruption (its server or worker killed) segments again (cheap,
and deterministic for the request and its seed) and computes only the pointings that have no
committed answer; a committed answer that does not match its pointing any more (the same
index, other targets) is dropped and recomputed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from models.instrument import Instrument
from planner import stages
from planner.programme import PointingOutcome, RoundTask, plan_progress, run_rounds
from service import adapters, pipeline, plan_locks, pointing_plans
from service.jobs import JobStore
from service.plan_consolidation import consolidated
from service.round_tasks import round_task
from service.runners import PointingRunner
from service.schemas import PlanRequest


def _matches(answer: dict[str, Any], expected: dict[str, Any]) -> bool:
    """A committed answer is the pointing's: the same id and targets, and a telescope time."""
    return (answer.get("id") == expected["id"] and answer.get("target_ids") == expected["target_ids"]
            and "telescope_time" in answer.get("stats", {}))


def run_plan(store: JobStore, job_id: str, owner: str, request: Any, inst: Instrument,
             runner: PointingRunner, *, budget_s: float | None = None,
             progress: pointing_plans.Progress = lambda _: None,
             cancelled: threading.Event | None = None,
             on_stage: pipeline.Stage = lambda _: None) -> dict[str, Any] | None:
    """Run (or resume) plan job ``job_id`` owned by ``owner`` on ``runner``; its
    PlanResponse dict, or None when it stopped before its end: ``cancelled`` was set, or the
    job is no longer open and ``owner``'s (cancelled, finished elsewhere, or taken over after
    a lost lease). ``progress`` hears :func:`planner.programme.plan_progress` of the round's
    tasks done plus the part done of the one being computed, when the runner sees it;
    ``on_stage`` hears each stage as it begins (:func:`planner.stages.plan_stage`, on the same
    counts).

    The rounds are :func:`planner.programme.run_rounds`', as in the synchronous plan; a round
    whose outcome a committed answer already records (``stats.rounds``) is not computed
    again."""
    t0 = time.monotonic()
    req = request if isinstance(request, PlanRequest) else PlanRequest.model_validate(request)
    req, epoch = pipeline.at_epoch(req)
    req, excluded = plan_locks.without_excluded(req, inst)
    limit = pipeline.plan_limit_s(req, budget_s)
    stage = pipeline.Stages(on_stage)
    stage(stages.segmentation_stage(pointing_plans.plan_mode(req)))
    seg = pipeline.segment_plan(req, inst, limit)
    pointing_plans.check_pointing_locks(req, seg, inst)
    n = len(seg.pointings)
    if not store.start_pointings(job_id, owner, n):
        return None
    ids = [t.id for t in req.targets]
    expected = [adapters.pointing_out(p, ids) for p in seg.pointings]
    done = store.pointing_results(job_id)
    stale = [i for i, a in done.items() if i >= n or not _matches(a, expected[i])]
    if stale:
        store.drop_pointings(job_id, stale)
    answers = {i: a for i, a in done.items() if i not in stale}
    resumed = len(answers)
    computed = [0]
    committed = [resumed]

    def recorded(task: RoundTask) -> PointingOutcome | None:
        old = answers.get(task.index)
        rounds = [] if old is None else pointing_plans.outcomes_of(old, task.index)
        return next((o for o in rounds if o.round == task.round), None)

    def on_done(index: int, answer: dict[str, Any]) -> bool:
        rounds = pointing_plans.outcomes_of(answer, index)
        old = answers.get(index)
        if old is not None and rounds and any(
                o.round == rounds[-1].round for o in pointing_plans.outcomes_of(old, index)):
            return True  # the same round computed twice (a re-run task): keep the first
        kept = pointing_plans.keep_better(old, answer, index)
        if not store.commit_pointing(job_id, owner, index, kept, replace=old is not None):
            return False
        answers[index] = kept
        if old is None:
            committed[0] += 1
        return True

    def keep_going() -> bool:
        return not (cancelled is not None and cancelled.is_set()) and store.owns(job_id, owner)

    def compute(tasks: Sequence[RoundTask]) -> list[PointingOutcome]:
        todo = [round_task(req, seg, t, inst, answers.get(t.index)) for t in tasks if recorded(t) is None]
        computed[0] += len(todo)
        first = tasks[0].round == 1  # the first round counts every pointing, resumed ones too
        count = _RoundProgress(progress, stage, tasks[0].round, n if first else len(tasks),
                               committed[0] if first else len(tasks) - len(todo))

        def done(index: int, answer: dict[str, Any]) -> bool:
            ok = on_done(index, answer)
            count.done += ok
            count.part(0.0)
            return ok

        if not runner.run(todo, inst, done, keep_going, count.part):
            raise _Stopped()
        missing = [t.index for t in tasks if recorded(t) is None]
        if missing:  # pragma: no cover - the runner handed every task over
            raise RuntimeError(f"pointings {missing} have no committed answer")
        return [recorded(t) for t in tasks]  # type: ignore[misc]

    try:
        history = run_rounds(pointing_plans.pointing_needs(seg, req), pipeline.rounds_limit_s(req, limit, seg), compute,
                             spend_margin=pipeline.spends_margin(req))
    except _Stopped:
        return None
    pointings = [answers[i] for i in range(n)]
    advice = pipeline.limit_advice(req, seg, pointings, history, limit, None)
    seg, pointings, consolidation = consolidated(req, inst, seg, pointings, history,
                                                 pipeline.rounds_limit_s(req, limit, seg),
                                                 lambda: limit - (time.monotonic() - t0))
    stage(stages.ASSEMBLING)
    few = pipeline.few_target_exposures(pointings, req.targets, inst, req.park_move_limit_s,
                                        pipeline.left_out_of(consolidation))
    return adapters.with_content_hash(pipeline.plan_out(seg, pointings, req.targets, {
        "time_limit_s": limit, "budget_s": budget_s, "rounds": len(history),
        "elapsed_s": time.monotonic() - t0, "engine": runner.name,
        "pointings_resumed": resumed, "pointings_computed": computed[0], **epoch, **excluded, **consolidation,
        **({} if advice is None else {"time_limit_advice": advice})}, few))


@dataclass
class _RoundProgress:
    """A plan job's progress while a round runs (:func:`planner.programme.plan_progress`)
    and its stage (:func:`planner.stages.plan_stage`): ``done`` of the round's ``total``
    tasks, plus the part done of the one being computed."""

    progress: pointing_plans.Progress
    stage: pipeline.Stage
    round_: int
    total: int
    done: int

    def part(self, fraction: float) -> None:
        self.progress(plan_progress(self.round_, self.done + fraction, self.total))
        self.stage(stages.plan_stage(self.round_, self.done + fraction, self.total))


class _Stopped(Exception):
    """The runner stopped: the job was cancelled or is no longer this server's."""
