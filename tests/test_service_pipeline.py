"""The service pipeline calls the domain with typed arguments and splits one deadline.

Spies built with ``create_autospec`` keep the domain functions' real signatures (a keyword
the function does not take is a TypeError, as it is for the real call) and record what the
pipeline passes; the deadline tests replace the slow stages with fakes that use all the time
they are given, so the split is checked without depending on the machine's speed."""

from __future__ import annotations

import math
import time
from typing import Any
from unittest import mock

import numpy as np
import pytest

from models import clock
from models.budget import Budget
from models.instrument import default_instrument
from models.sky import focal_mm_to_sky
from models.types import AllocationResult, ArmAssignment, Configuration, MotionPlan, PlaneTargets
from planner import plan_motion, pointing, programme
from planner.options import MotionOptions
from planner.sequence import SequenceOptions, SequencePlan
from service import pipeline
from service.schemas import AllocationRequest, MotionPlanRequest, PlanRequest, SegmentationRequest
from solvers.allocation import allocate
from solvers.segmentation import segment_field

INST = default_instrument()


def spy(monkeypatch: pytest.MonkeyPatch, name: str, real: Any) -> mock.MagicMock:
    m = mock.create_autospec(real, side_effect=real)
    monkeypatch.setattr(pipeline, name, m)
    return m


def sky_targets(n: int, spread_mm: float = 60.0) -> list[dict[str, Any]]:
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ra, dec = focal_mm_to_sky(spread_mm * np.cos(ang), spread_mm * np.sin(ang), 150.0, 20.0,
                              INST.plate_scale_arcsec_per_mm)
    return [{"id": f"s{i}", "ra_deg": float(a), "dec_deg": float(d), "priority": 1 + i}
            for i, (a, d) in enumerate(zip(ra, dec, strict=True))]


def test_segmentation_options_reach_the_domain(monkeypatch) -> None:
    seg = spy(monkeypatch, "segment_field", segment_field)
    req = SegmentationRequest(targets=sky_targets(4), threshold_mm=100.0, mode="balanced", seed=7,
                              tangent_point={"ra_deg": 150.0, "dec_deg": 20.0})
    out = pipeline.segmentation(req, INST)
    kw = seg.call_args.kwargs
    assert (kw["threshold_mm"], kw["mode"], kw["seed"]) == (100.0, "balanced", 7)
    assert kw["tangent_point"] == (150.0, 20.0)
    assert kw["fov_radius_mm"] == INST.fov_radius_mm
    assert kw["plate_scale_arcsec_per_mm"] == INST.plate_scale_arcsec_per_mm
    assert out["stats"]["mode"] == "balanced"


def test_allocation_options_reach_the_domain(monkeypatch) -> None:
    alloc = spy(monkeypatch, "allocate", allocate)
    req = AllocationRequest.model_validate({
        "targets": [{"id": "a", "x_mm": 30.0, "y_mm": 0.0, "priority": 3}],
        "method": "ilp", "solver": "bnb", "configurations": "all", "seed": 5,
        "collision_buffer_mm": 6.0,
        "start": [{"arm": 1, "theta1_rad": 3.0, "theta2_rad": 0.1}],
        "disabled_arms": [{"arm": 4, "theta1_rad": 3.1, "theta2_rad": 0.0}]})
    pipeline.allocation(req, INST, time_limit_s=2.0)
    (inst, targets), kw = alloc.call_args
    assert inst is INST and isinstance(targets, PlaneTargets) and targets.ids == ("a",)
    assert (kw["method"], kw["solver"], kw["configurations"]) == ("ilp", "bnb", "all")
    assert (kw["seed"], kw["collision_buffer_mm"], kw["time_limit_s"]) == (5, 6.0, 2.0)
    assert kw["fixed"] == {4: (3.1, 0.0)}
    assert tuple(kw["start_q"][1]) == (3.0, 0.1) and tuple(kw["start_q"][4]) == (3.1, 0.0)


def test_motion_options_reach_the_domain(monkeypatch) -> None:
    motion = spy(monkeypatch, "plan_motion", plan_motion)
    park = [{"arm": a.index, "theta1_rad": a.park_theta1_rad, "theta2_rad": a.park_theta2_rad}
            for a in INST.arms]
    req = MotionPlanRequest.model_validate({"start": park, "goal": park, "dt_s": 3.0,
                                            "dt_col_s": 0.05, "max_start_stop": 2,
                                            "collision_buffer_mm": 4.0, "seed": 9})
    out = pipeline.motion_plan(req, INST, time_limit_s=1.5)
    kw = motion.call_args.kwargs
    o = kw["options"]
    assert isinstance(o, MotionOptions)
    assert (o.dt_s, o.dt_col_s, o.max_start_stop, o.collision_buffer_mm, o.seed) == (3.0, 0.05, 2, 4.0, 9)
    assert kw["time_budget_s"] == 1.5
    assert out["status"] in ("ok", "failed")
    # defaults are the planner's own, not a copy in the service
    d = pipeline.motion_options(MotionPlanRequest.model_validate({"start": park, "goal": park}))
    assert (d.dt_s, d.dt_col_s, d.max_start_stop) == (MotionOptions().dt_s, MotionOptions().dt_col_s,
                                                      MotionOptions().max_start_stop)


def test_a_misspelt_keyword_is_an_error_not_dropped() -> None:
    """What the old signature-filtering call let through: an unknown keyword must fail."""
    with pytest.raises(TypeError):
        segment_field(np.array([1.0]), np.array([1.0]), instrument=INST)  # type: ignore[call-arg]
    with pytest.raises(TypeError):
        MotionOptions(dt_col=0.1)  # type: ignore[call-arg]


# ----------------------------------------------------------------- the deadline


def _configuration(index: int, targets: PlaneTargets) -> Configuration:
    park = INST.park_configuration
    assignments = tuple(ArmAssignment(k, "park", float(park[k, 0]), float(park[k, 1]), 0.0, 0.0)
                        for k in range(INST.n_arms))
    return Configuration(index, assignments, 0, 0, "feasible")


def _use(budget_s: float) -> None:
    clock.charge(budget_s)
    time.sleep(budget_s / programme.SHARES.effort_share)


class SlowStages:
    """allocate / plan_sequence fakes that use their whole budget (as a solver that does not
    stop early would) on a machine as slow as the effort clock's margin allows: every
    effort second they are given takes 1 / EFFORT_SHARE wall seconds. They record what they
    were given."""

    def __init__(self) -> None:
        self.allocation_limits: list[float] = []
        self.sequence_limits: list[tuple[float, float | None]] = []

    def allocate(self, inst: Any, targets: PlaneTargets, *, budget: Budget, **_: Any
                 ) -> AllocationResult:
        self.allocation_limits.append(budget.limit_s)
        _use(budget.left_s())
        return AllocationResult((_configuration(0, targets), _configuration(1, targets)), ())

    def plan_sequence(self, inst: Any, configurations: Any, options: SequenceOptions, *,
                      targets: Any = None, progress: Any = None, budget: Budget | None = None,
                      known: Any = None) -> SequencePlan:
        left_s = 0.0 if budget is None else max(budget.left_s(), 0.0)  # None: no configurations
        self.sequence_limits.append((options.leg_time_limit_s, left_s))
        _use(left_s)
        legs = tuple(MotionPlan("ok", 0.0, ()) for _ in range(len(configurations) + 1))
        return SequencePlan(tuple(configurations), legs)


@pytest.mark.parametrize("limit_s,spread_deg", [(3.0, 0.0), (7.0, 0.2)])
def test_the_whole_plan_honours_the_request_time_limit(monkeypatch, limit_s, spread_deg) -> None:
    fake = SlowStages()
    monkeypatch.setattr(pointing, "allocate", fake.allocate)
    monkeypatch.setattr(pointing, "plan_sequence", fake.plan_sequence)
    targets = sky_targets(6)
    for i, t in enumerate(targets):  # spread_deg > 0: several pointings
        t["dec_deg"] += spread_deg * (i % 3)
    req = PlanRequest(targets=targets, time_limit_s=limit_s, seed=1)
    t0 = time.monotonic()
    out = pipeline.plan(req, INST, budget_s=120.0)
    wall = time.monotonic() - t0
    assert wall <= limit_s + 0.3, wall  # fakes use all they get: the split itself is checked
    n = out["stats"]["pointings"]
    assert n == (1 if spread_deg == 0 else 3)
    given = sum(fake.allocation_limits) + sum(s for _, s in fake.sequence_limits if s is not None)
    assert given <= limit_s
    assert fake.sequence_limits, "motion planning was given time"
    assert out["stats"]["time_limit_s"] == limit_s


def test_the_server_budget_caps_the_request_limit(monkeypatch) -> None:
    fake = SlowStages()
    monkeypatch.setattr(pointing, "allocate", fake.allocate)
    monkeypatch.setattr(pointing, "plan_sequence", fake.plan_sequence)
    req = PlanRequest(targets=sky_targets(3), time_limit_s=60.0, seed=1, segmentation_mode="complete-linkage")
    t0 = time.monotonic()
    out = pipeline.plan(req, INST, budget_s=2.0)
    assert time.monotonic() - t0 <= 2.3
    assert out["stats"]["time_limit_s"] == 2.0
    # no request limit: the budget alone, the one limit of the whole plan (no solver cap:
    # the allocation gets its share of the pointing's effort)
    fake2 = SlowStages()
    monkeypatch.setattr(pointing, "allocate", fake2.allocate)
    monkeypatch.setattr(pointing, "plan_sequence", fake2.plan_sequence)
    out = pipeline.plan(PlanRequest(targets=sky_targets(3), seed=1, segmentation_mode="complete-linkage"), INST,
                        budget_s=2.0)
    usable = programme.usable_s(2.0)
    t = programme.SHARES
    assert fake2.allocation_limits == [pytest.approx(t.allocation_share * t.effort_share * usable)]
    assert out["stats"]["time_limit_s"] == 2.0


def test_a_pointing_reached_after_the_deadline_is_no_time(monkeypatch) -> None:
    fake = SlowStages()
    monkeypatch.setattr(pointing, "allocate", fake.allocate)
    monkeypatch.setattr(pointing, "plan_sequence", fake.plan_sequence)
    targets = sky_targets(6)
    for i, t in enumerate(targets):
        t["dec_deg"] += 0.2 * (i % 3)
    out = pipeline.plan(PlanRequest(targets=targets, time_limit_s=1.0, seed=1), INST,
                        budget_s=None)
    reasons = {u["reason"] for p in out["pointings"] for u in p["unallocated"]}
    assert "no_time" in reasons
    skipped = [p for p in out["pointings"] if "skipped" in p["stats"]["allocation"]]
    assert skipped and all(len(p["motions"]) == 1 and p["configurations"] == [] for p in skipped)
    assert math.isclose(out["stats"]["time_limit_s"], 1.0)
