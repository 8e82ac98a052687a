"""A later round plans a pointing whose best plan has a failed leg from that plan
(planner.programme.keeps_plan, service.round_tasks): the same configurations, the verified
legs reused, only the failed leg planned again; the new plan passes the independent
verifier. Other rounds and plans keep the fresh task."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from models.instrument import default_instrument
from planner import programme as pp
from planner.programme import PointingOutcome, RoundTask
from service import pipeline, pointing_plans
from service.round_tasks import allocation_in, round_task
from service.schemas import PlanRequest

INST = default_instrument()


@pytest.fixture(scope="module")
def planned():
    """A 30-target pointing (complete linkage keeps it whole) planned once: its request,
    segmentation and PlanPointing dict."""
    rng = np.random.default_rng(5)
    ra = 150.0 + rng.uniform(-0.02, 0.02, 30)
    dec = 20.0 + rng.uniform(-0.02, 0.02, 30)
    targets = [{"id": f"t{i}", "ra_deg": float(r), "dec_deg": float(d), "priority": int(p)}
               for i, (r, d, p) in enumerate(zip(ra, dec, rng.choice([1, 10, 100], 30), strict=True))]
    req = PlanRequest.model_validate({"targets": targets, "seed": 3, "segmentation_mode": "complete-linkage",
                                      "time_limit_s": 30})
    seg, answers, _ = pipeline.plan_pointings(req, INST)
    i = max(range(len(answers)), key=lambda j: len(answers[j]["configurations"]))
    assert answers[i]["executable"] and len(answers[i]["configurations"]) >= 2
    return req, seg, i, answers[i]


def _failed(answer: dict, leg: int) -> dict:
    """``answer`` with leg ``leg`` failed (its verified trajectories dropped), as its round
    records it."""
    out = copy.deepcopy(answer)
    out["motions"][leg] = {**out["motions"][leg], "status": "failed", "trajectories": [], "failed_arms": [0]}
    out["executable"] = False
    out["stats"]["rounds"] = [{**r, "executable": False, "failed_legs": 1} for r in out["stats"]["rounds"]]
    return out


def _targets_by_exposure(answer: dict) -> list[list[tuple[int, str | None, float, float]]]:
    return [[(a["arm"], a["target_id"], a["theta1_rad"], a["theta2_rad"])
             for a in sorted(c["assignments"], key=lambda a: a["arm"]) if a["target_id"] is not None]
            for c in answer["configurations"]]


@pytest.mark.parametrize("where", ["first", "middle", "last"])
def test_a_failed_leg_is_planned_again_from_the_best_plan(planned, where: str) -> None:
    req, seg, i, answer = planned
    legs = len(answer["motions"])
    leg = {"first": 0, "middle": legs // 2, "last": legs - 1}[where]
    best = _failed(answer, leg)
    task = round_task(req, seg, RoundTask(i, 2, 20.0), INST, best)
    assert task.options.allocation_final and task.options.known_legs is not None
    again = pointing_plans.pointing_result(task, INST)
    assert again["executable"], again["reasons"]
    # the same targets on the same arms at the same joint angles, exposure by exposure
    assert _targets_by_exposure(again) == _targets_by_exposure(answer)
    reused = [bool(m["stats"].get("reused")) for m in again["motions"]]
    assert reused == [k != leg for k in range(legs)]
    assert again["stats"]["allocation"]["source"] == "best plan so far"  # no allocation searched


def test_other_rounds_and_plans_get_the_fresh_task(planned) -> None:
    req, seg, i, answer = planned
    fresh = pointing_plans.pointing_task(req, seg, RoundTask(i, 2, 20.0))
    assert fresh.options.known_legs is None
    for task, best in ((RoundTask(i, 1, 20.0), _failed(answer, 0)),  # a first round searches
                       (RoundTask(i, 2, 20.0), answer),  # an executable plan is not planned again from
                       (RoundTask(i, 2, 20.0), None)):
        got = round_task(req, seg, task, INST, best)
        assert got.options.known_legs is None and got.options.allocation_final == fresh.options.allocation_final


def test_keeps_plan_only_for_a_planned_pointing_with_a_failed_leg() -> None:
    def o(**kw) -> PointingOutcome:
        base = {"index": 0, "round": 1, "share_s": 5.0, "effort_s": 4.0, "executable": False, "failed_legs": 1,
                "observed": 10}
        return PointingOutcome(**{**base, **kw})

    assert pp.keeps_plan(o(), 2) and pp.keeps_plan(o(), 8)
    assert not pp.keeps_plan(o(), 1)
    assert not pp.keeps_plan(None, 2)
    assert not pp.keeps_plan(o(executable=True, failed_legs=0), 2)
    assert not pp.keeps_plan(o(attempted=False), 2)  # no share: nothing was allocated
    assert not pp.keeps_plan(o(observed=0), 2)


def test_allocation_in_reads_the_plan_in_the_pointings_member_order(planned) -> None:
    req, seg, i, answer = planned
    members = [req.targets[int(k)].id for k in seg.pointings[i].target_indices]
    got = allocation_in(answer, members)
    assert got is not None and got.stats["n_targets"] == len(members)
    for c, d in zip(got.configurations, answer["configurations"], strict=True):
        for a in c.assignments:
            if a.target_index is not None:
                assert members[a.target_index] == a.target_id
        assert sorted(a.target_id for a in c.assignments if a.target_id) == \
            sorted(a["target_id"] for a in d["assignments"] if a["target_id"])
    assert allocation_in(answer, members[1:]) is None or members[0] not in {
        a["target_id"] for c in answer["configurations"] for a in c["assignments"]}
