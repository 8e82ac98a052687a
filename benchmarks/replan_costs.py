"""What planning a consolidated pointing again costs, against its estimate
(``planner.consolidation.replan_costs``); prints JSON to stdout, progress to stderr.

    python benchmarks/replan_costs.py cluster-halo:4007 two-clump:4006

Each ``shape:seed`` is a programme of ``benchmarks/programme_time.py`` (the same generator and
the same call, ``service.pipeline.plan`` at the server's default budget, mode
"fewest-exposures"), planned without its consolidation (the rounds' plan). On that plan the
consolidation's first pass (``planner.consolidation.regroup``) runs with time to spare; each
pointing it changes is then planned again alone, as a pass plans it
(``service.plan_consolidation.changed_segmentation``: its new allocation final; the legs of
its plan known, ``planner.known_legs``) but without the sky pass and on a share of 60 s, so
that the effort measured is that of its legs. Per changed pointing: its legs, the legs it
plans anew (``planner.known_legs.new_legs``) and reuses, its cost in the rounds
(``planner.consolidation.costs``: its costliest round's motion seconds), the estimate, the
measured motion seconds (effort over ``effort_share``, as the estimate counts them) and the
measured seconds per new leg (the reused legs' checks included) over the rounds' average leg
(what ``NEW_LEG_FACTOR`` bounds).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def measured(shape: str, seed: int) -> list[dict[str, Any]]:
    """The changed pointings of the programme ``shape``/``seed`` (module docstring)."""
    from benchmarks import programme_time as PT
    from models.budget import Budget
    from planner.consolidation import costs, regroup, replan_costs
    from planner.known_legs import new_legs
    from planner.programme import RoundTask
    from planner.shares import SHARES
    from service import adapters, pipeline, plan_consolidation, pointing_plans
    from service.plan_consolidation import _planned
    from service.schemas import PlanRequest
    from service.settings import Settings

    prog = PT.generated([(shape, seed)])[0]
    unchanged = plan_consolidation.consolidated
    plan_consolidation.consolidated = lambda req, inst, seg, answers, *_: (seg, answers, {})  # the rounds' plan
    try:
        plan, _ = PT.plan_programme(prog["targets"], seed, "fewest-exposures", None)
    finally:
        plan_consolidation.consolidated = unchanged
    inst = pipeline.instrument_from(None)
    req = PlanRequest.model_validate({"targets": prog["targets"], "seed": seed,
                                      "segmentation_mode": "fewest-exposures"})
    index = {t.id: i for i, t in enumerate(req.targets)}
    answers = plan["pointings"]
    planned = [_planned(p, index) for p in answers]
    history = [[o for j, p in enumerate(answers) for o in pointing_plans.outcomes_of(p, j)]]
    cost = costs(history)
    _, _, changed = regroup(inst, np.array([t.ra_deg for t in req.targets]), np.array([t.dec_deg for t in req.targets]),
                            np.array([int(t.priority) for t in req.targets]), planned, req.park_move_limit_s, None,
                            Budget.start(30.0))
    estimate = replan_costs(cost, planned, changed)
    seg = pipeline.segment_plan(req, inst, pipeline.plan_limit_s(req, Settings().plan_budget_s))
    seg = plan_consolidation.changed_segmentation(req, inst, seg, changed)
    out = []
    for r in changed:
        old, new = planned[r.index].configurations, r.allocation.configurations
        task = pointing_plans.pointing_task(req, seg, RoundTask(r.index, len(history) + 1, 60.0),
                                      adapters.known_legs_in(inst, answers[r.index]))
        task = dataclasses.replace(task, sky=None)  # the legs alone: no sky pass
        answer = pointing_plans.pointing_result(task, inst)
        o = answer["stats"]["rounds"][-1]
        motion_s = (o["effort_s"] - o["allocation_effort_s"]) / SHARES.effort_share
        fresh, legs = new_legs(old, new), len(new) + 1
        per_leg_s = cost[r.index] / (len(old) + 1)
        out.append({"programme": f"{shape}-{seed}", "pointing": answers[r.index]["id"], "legs": legs,
                    "new_legs": fresh, "reused_legs": answer["stats"]["sequence"]["reused_legs"],
                    "round_cost_s": round(cost[r.index], 3), "estimate_s": round(estimate[r.index], 3),
                    "measured_s": round(motion_s, 3), "executable": answer["executable"],
                    "new_leg_over_average": None if not fresh else round(motion_s / fresh / per_leg_s, 3)})
        print(json.dumps(out[-1]), file=sys.stderr)
    return out


def main(argv: list[str]) -> None:
    rows = []
    for arg in argv or ["cluster-halo:4007", "two-clump:4006"]:
        shape, seed = arg.rsplit(":", 1)
        rows += measured(shape, int(seed))
    print(json.dumps({"changed_pointings": rows}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
