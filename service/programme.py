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
from dataclasses import dataclass, field
from typing import Any

from models.instrument import Instrument
from planner import stages
from planner.programme import PointingOutcome, RoundTask, plan_progress
from service import adapters, pipeline, plan_locks, pointing_plans
from service.jobs import JobStore
from service.round_tasks import round_task
from service.runners import PointingRunner
from service.schemas import PlanRequest
from solvers.segmentation import Segmentation


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
    job = _JobRounds(store, job_id, owner, inst, req, runner, progress, stage, cancelled)
    try:
        planned = pipeline.plan_programme(req, inst, limit, stage, job.rounds_for,
                                          lambda: limit - (time.monotonic() - t0), None)
    except _Stopped:
        return None
    if planned is None:
        return None
    seg, pointings, stats = planned
    return pipeline.plan_answer(req, inst, seg, pointings, {
        **stats, "budget_s": budget_s, "elapsed_s": time.monotonic() - t0, "engine": runner.name,
        "pointings_resumed": job.resumed, "pointings_computed": job.computed, **epoch, **excluded})


@dataclass
class _JobRounds:
    """A plan job's rounds (:class:`service.pipeline.PlanRounds`): its pointings computed on
    ``runner``, each answer committed to the job's table as it comes; a pointing committed by
    an earlier attempt of the job (the same id and targets) is resumed, and a round whose
    outcome a committed answer records is not computed again."""

    store: JobStore
    job_id: str
    owner: str
    inst: Instrument
    req: PlanRequest
    runner: PointingRunner
    progress: pointing_plans.Progress
    stage: pipeline.Stages
    cancelled: threading.Event | None
    answers: dict[int, dict[str, Any]] = field(default_factory=dict)
    resumed: int = 0
    computed: int = 0
    committed: int = 0

    def rounds_for(self, seg: Segmentation) -> pipeline.PlanRounds | None:
        """The job's rounds of ``seg``, its committed answers taken back (None: the job is no
        longer ``owner``'s)."""
        n = len(seg.pointings)
        if not self.store.start_pointings(self.job_id, self.owner, n):
            return None
        ids = [t.id for t in self.req.targets]
        expected = [adapters.pointing_out(p, ids) for p in seg.pointings]
        done = self.store.pointing_results(self.job_id)
        stale = [i for i, a in done.items() if i >= n or not _matches(a, expected[i])]
        if stale:
            self.store.drop_pointings(self.job_id, stale)
        self.answers.update({i: a for i, a in done.items() if i not in stale})
        self.resumed = self.committed = len(self.answers)
        return pipeline.PlanRounds(lambda tasks: self._compute(seg, tasks), self.answers)

    def _recorded(self, task: RoundTask) -> PointingOutcome | None:
        old = self.answers.get(task.index)
        rounds = [] if old is None else pointing_plans.outcomes_of(old, task.index)
        return next((o for o in rounds if o.round == task.round), None)

    def _on_done(self, index: int, answer: dict[str, Any]) -> bool:
        rounds = pointing_plans.outcomes_of(answer, index)
        old = self.answers.get(index)
        if old is not None and rounds and any(
                o.round == rounds[-1].round for o in pointing_plans.outcomes_of(old, index)):
            return True  # the same round computed twice (a re-run task): keep the first
        kept = pointing_plans.keep_better(old, answer, index)
        if not self.store.commit_pointing(self.job_id, self.owner, index, kept, replace=old is not None):
            return False
        self.answers[index] = kept
        if old is None:
            self.committed += 1
        return True

    def _keep_going(self) -> bool:
        return (not (self.cancelled is not None and self.cancelled.is_set())
                and self.store.owns(self.job_id, self.owner))

    def _compute(self, seg: Segmentation, tasks: Sequence[RoundTask]) -> list[PointingOutcome]:
        todo = [round_task(self.req, seg, t, self.inst, self.answers.get(t.index))
                for t in tasks if self._recorded(t) is None]
        self.computed += len(todo)
        first = tasks[0].round == 1  # the first round counts every pointing, resumed ones too
        count = _RoundProgress(self.progress, self.stage, tasks[0].round, len(seg.pointings) if first else len(tasks),
                               self.committed if first else len(tasks) - len(todo))

        def done(index: int, answer: dict[str, Any]) -> bool:
            ok = self._on_done(index, answer)
            count.done += ok
            count.part(0.0)
            return ok

        if not self.runner.run(todo, self.inst, done, self._keep_going, count.part):
            raise _Stopped()
        missing = [t.index for t in tasks if self._recorded(t) is None]
        if missing:  # pragma: no cover - the runner handed every task over
            raise RuntimeError(f"pointings {missing} have no committed answer")
        return [self._recorded(t) for t in tasks]  # type: ignore[misc]


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
