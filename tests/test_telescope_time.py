"""Telescope time as a plan's output and the astronomer's stop rules as its inputs: the time
recomputed from each plan's own legs, the exposure thresholds and caps checked on the plans
returned, the caps' split against a brute-force restatement, and invalid rules named (422
over HTTP, exit code 2 on the CLI)."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st

from models.budget import Budget
from models.errors import InputError
from models.instrument import default_instrument
from models.types import AllocationResult, ArmAssignment, Configuration, MotionPlan, PlaneTargets
from planner import pointing, programme
from planner.reassign import Placed, new_configuration
from planner.sequence import SequenceOptions, SequencePlan, _Sequencer
from planner.telescope_time import ObservingRules, TelescopeTime, pointing_time, total
from service import pipeline
from service.app import create_app
from service.cli import main
from service.response_schemas import PlanResponse
from service.schemas import PlanRequest
from service.settings import Settings
from service.tables import read_targets
from tests.plan_jobs import plan_job_result

ROOT = Path(__file__).resolve().parents[1]
INST = pipeline.instrument_from(None)
M13 = read_targets(ROOT / "examples" / "m13_targets.csv")[:20]  # one pointing, two exposures
# three clumps of two targets, 0.2 deg apart: three pointings
CLUMPS = [{"id": f"t{i}", "ra_deg": 150.0 + 0.2 * (i % 3) + 0.0006 * i,
           "dec_deg": 2.0 + 0.0004 * i, "priority": 1 + i % 4} for i in range(6)]


def plan(targets: list[dict[str, Any]], **rules: Any) -> dict[str, Any]:
    out = pipeline.plan(PlanRequest(targets=targets, seed=1, time_limit_s=30, **rules), INST)
    PlanResponse.model_validate(out)
    return out


# ------------------------------------------------------------------- the oracles


def leg_duration_s(motion: dict[str, Any]) -> float | None:
    """A planned leg's duration from its own way-points (the last arm to arrive); None when
    it was not planned."""
    if motion["status"] != "ok":
        return None
    return max((t["waypoints"][-1]["t_s"] for t in motion["trajectories"]), default=0.0)


def expected_time(p: dict[str, Any], exposure_time_s: float, acquisition_s: float) -> dict[str, float]:
    n = len(p["configurations"])
    if n == 0:
        return {"exposures": 0, "acquisitions": 0, "exposure_s": 0.0, "acquisition_s": 0.0,
                "reconfiguration_s": 0.0, "unplanned_legs": 0, "total_s": 0.0}
    legs = [leg_duration_s(m) for m in p["motions"]]
    assert len(legs) == n + 1
    reconf = sum(t for t in legs if t is not None)
    return {"exposures": n, "acquisitions": 1, "exposure_s": n * exposure_time_s,
            "acquisition_s": acquisition_s, "reconfiguration_s": reconf,
            "unplanned_legs": sum(t is None for t in legs),
            "total_s": n * exposure_time_s + acquisition_s + reconf}


def check_time(out: dict[str, Any], exposure_time_s: float = 900.0, acquisition_s: float = 300.0) -> None:
    """Every pointing's stats.telescope_time and the plan's are what its own legs give."""
    whole = dict.fromkeys(expected_time({"configurations": []}, 1.0, 0.0), 0.0)
    for p in out["pointings"]:
        want = expected_time(p, exposure_time_s, acquisition_s)
        assert p["stats"]["telescope_time"] == pytest.approx(want, rel=1e-9, abs=1e-6)
        for k, v in want.items():
            whole[k] += v
    assert out["stats"]["telescope_time"] == pytest.approx(whole, rel=1e-9, abs=1e-6)
    assert out["stats"]["telescope_time"]["exposures"] == out["stats"]["configurations"]


def observed(out: dict[str, Any]) -> list[str]:
    return [a["target_id"] for p in out["pointings"] for c in p["configurations"]
            for a in c["assignments"] if a["target_id"] is not None]


def reasons(out: dict[str, Any]) -> dict[str, str]:
    return {u["target_id"]: u["reason"] for p in out["pointings"] for u in p["unallocated"]}


def check_accounted(out: dict[str, Any], targets: list[dict[str, Any]]) -> None:
    """Every target of the request observed exactly once or reported once with a reason."""
    seen = observed(out)
    assert len(seen) == len(set(seen))
    why = [u["target_id"] for p in out["pointings"] for u in p["unallocated"]]
    assert len(why) == len(set(why)) and not set(why) & set(seen)
    assert set(seen) | set(why) == {t["id"] for t in targets}


# ------------------------------------------------------------------- real plans


@pytest.fixture(scope="module")
def default_plan() -> dict[str, Any]:
    return plan(M13, exposure_time_s=600.0, acquisition_s=120.0)


def test_telescope_time_is_what_the_plans_own_legs_give(default_plan) -> None:
    out = default_plan
    check_time(out, 600.0, 120.0)
    t = out["stats"]["telescope_time"]
    assert t["exposures"] >= 2 and t["reconfiguration_s"] > 0 and t["acquisitions"] == 1
    check_accounted(out, M13)
    assert not reasons(out)  # the default: full completeness


def test_min_targets_per_exposure_keeps_only_full_exposures() -> None:
    # 20 targets: at most one exposure of 12, so at least 8 are below the threshold
    out = plan(M13, min_targets_per_exposure=12)
    check_time(out)
    check_accounted(out, M13)
    for p in out["pointings"]:
        for c in p["configurations"]:
            assert sum(a["target_id"] is not None for a in c["assignments"]) >= 12
    below = [t for t, r in reasons(out).items() if r == "below_exposure_threshold"]
    assert len(below) >= len(M13) - 12
    assert out["stats"]["unallocated_by_reason"]["below_exposure_threshold"] == len(below)


def test_min_priority_per_exposure_keeps_only_rich_exposures() -> None:
    # more than half the summed priority: two such exposures cannot both exist
    prio = {t["id"]: t["priority"] for t in M13}
    threshold = sum(prio.values()) // 2 + 1
    out = plan(M13, min_priority_per_exposure=threshold)
    check_time(out)
    check_accounted(out, M13)
    configs = [c for p in out["pointings"] for c in p["configurations"]]
    assert len(configs) <= 1
    for c in configs:
        assert sum(prio[a["target_id"]] for a in c["assignments"] if a["target_id"]) >= threshold
    assert "below_exposure_threshold" in set(reasons(out).values())


def test_max_exposures_caps_the_plan() -> None:
    out = plan(M13, max_exposures=1)
    check_time(out)
    check_accounted(out, M13)
    assert out["stats"]["configurations"] <= 1
    assert len(observed(out)) <= 12
    assert "beyond_max_exposures" in set(reasons(out).values())
    p = out["pointings"][0]
    assert p["stats"]["exposure_rules"]["max_configurations"] == 1


def test_max_exposures_below_the_pointings_leaves_one_unattempted() -> None:
    out = plan(CLUMPS, max_exposures=2)
    check_time(out)
    check_accounted(out, CLUMPS)
    assert len(out["pointings"]) == 3 and out["stats"]["configurations"] <= 2
    empty = [p for p in out["pointings"] if not p["configurations"]]
    assert len(empty) == 1
    assert {u["reason"] for u in empty[0]["unallocated"]} == {"beyond_max_exposures"}
    assert {u["target_id"] for u in empty[0]["unallocated"]} == set(empty[0]["target_ids"])
    assert empty[0]["stats"]["telescope_time"]["total_s"] == 0.0
    assert out["executable"]


def test_a_plan_job_applies_the_same_rules(tmp_path) -> None:
    """A plan job goes through the same functions: the same plan and telescope time as the
    synchronous plan of the same request."""
    request = {"targets": CLUMPS, "seed": 1, "time_limit_s": 30, "max_exposures": 2,
               "exposure_time_s": 60.0, "acquisition_s": 30.0}
    sync = pipeline.plan(PlanRequest.model_validate(request), INST)
    result = plan_job_result(tmp_path, request, 30.0)
    check_time(result, 60.0, 30.0)
    assert result["stats"]["telescope_time"] == pytest.approx(sync["stats"]["telescope_time"])
    assert [len(p["configurations"]) for p in result["pointings"]] == \
        [len(p["configurations"]) for p in sync["pointings"]]
    assert reasons(result) == reasons(sync)


# ------------------------------------------------------ rules on a pointing's plan


def _targets(n: int, priority: list[int]) -> PlaneTargets:
    return PlaneTargets.from_lists([f"t{i}" for i in range(n)], np.zeros(n), np.zeros(n), priority)


def _config(index: int, observed_ids: list[int], targets: PlaneTargets) -> Configuration:
    """A configuration observing ``observed_ids`` on arms 0.. (angles do not matter here)."""
    park = INST.park_configuration
    asg = []
    for k in range(INST.n_arms):
        if k < len(observed_ids):
            i = observed_ids[k]
            asg.append(ArmAssignment(k, "target", 1.0, 1.0, 0.0, 0.0, i, targets.ids[i]))
        else:
            asg.append(ArmAssignment(k, "park", float(park[k, 0]), float(park[k, 1]), 0.0, 0.0))
    prio = int(sum(int(targets.priority[i]) for i in observed_ids))
    return Configuration(index, tuple(asg), prio, len(observed_ids), "feasible")


class Stages:
    """Fakes of allocate and plan_sequence: the allocation gives ``configs``; the first
    motion plan moves target 0 out of c1 into an added exposure (as the motion planner does
    when an arm blocks a leg), later ones keep their configurations."""

    def __init__(self, targets: PlaneTargets, configs: list[list[int]]) -> None:
        self.targets = targets
        self.configs = configs
        self.sequence_calls: list[int | None] = []

    def allocate(self, inst: Any, targets: PlaneTargets, **_: Any) -> AllocationResult:
        return AllocationResult(tuple(_config(i, ids, targets) for i, ids in enumerate(self.configs)), ())

    def plan_sequence(self, inst: Any, configurations: Any, options: SequenceOptions, **_: Any) -> SequencePlan:
        self.sequence_calls.append(options.max_configurations)
        configs = list(configurations)
        if len(self.sequence_calls) == 1 and configs:
            first = [a.target_index for a in configs[0].assignments if a.kind == "target"]
            configs[0] = _config(0, first[1:], self.targets)
            configs.append(_config(len(configs), first[:1], self.targets))
        legs = tuple(MotionPlan("ok", 10.0, ()) for _ in range(len(configs) + 1))
        return SequencePlan(tuple(configs), legs)


def test_thresholds_hold_after_the_motion_planners_changes(monkeypatch) -> None:
    targets = _targets(8, [5, 1, 1, 1, 1, 1, 1, 1])
    fake = Stages(targets, [[0, 1, 2, 3], [4, 5, 6], [7]])
    monkeypatch.setattr(pointing, "allocate", fake.allocate)
    monkeypatch.setattr(pointing, "plan_sequence", fake.plan_sequence)
    options = programme.PointingOptions(rules=ObservingRules(min_targets_per_exposure=3, exposure_time_s=100.0,
                                                             acquisition_s=7.0))
    pp = programme.plan_pointing(INST, targets, options, share_s=30.0)
    # the allocation's c3 (1 target) is not opened; the motion planner's added exposure (1
    # target) is dropped and the legs planned again without adding any
    yields = [c.arm_yield for c in pp.sequence.configurations]
    assert yields == [3, 3] and all(y >= 3 for y in yields)
    assert fake.sequence_calls == [None, 2]
    why = {u.target_id: u.reason for u in pp.allocation.unallocated}  # type: ignore[union-attr]
    assert why == {"t7": "below_exposure_threshold", "t0": "below_exposure_threshold"}
    assert pp.telescope_time == TelescopeTime(2, 1, 200.0, 7.0, 30.0, 0)
    assert pp.executable


def test_a_pointing_given_no_exposure_is_not_attempted(monkeypatch) -> None:
    targets = _targets(3, [1, 2, 3])
    fake = Stages(targets, [[0, 1, 2]])
    monkeypatch.setattr(pointing, "allocate", fake.allocate)
    pp = programme.plan_pointing(INST, targets, programme.PointingOptions(max_configurations=0), share_s=30.0)
    assert pp.sequence.configurations == () and pp.executable
    assert {u.reason for u in pp.allocation.unallocated} == {"beyond_max_exposures"}  # type: ignore[union-attr]
    assert len(pp.allocation.unallocated) == 3  # type: ignore[union-attr]
    assert pp.telescope_time == TelescopeTime()


def test_the_motion_planner_adds_no_exposure_beyond_its_cap() -> None:
    """A target moved out of a configuration that only a new configuration can take: added
    without a cap, dropped as beyond_max_exposures at the cap."""
    inst = default_instrument()
    one = new_configuration(inst, 0)
    target = Placed("t0", 0, 0.0, 0.0, 1, 0)
    for cap, configs, reason in ((None, 2, None), (1, 1, "beyond_max_exposures"), (2, 2, None)):
        seq = _Sequencer(inst, [one], SequenceOptions(max_configurations=cap), {"t0": 1}, Budget.start(10.0))
        seq.pending = [target]
        seq.place_pending(0)
        assert len(seq.configs) == configs
        assert [u.reason for u in seq.dropped] == ([] if reason is None else [reason])


# ------------------------------------------------------------------- the domain


def test_pointing_time_and_sums() -> None:
    t = pointing_time(2, [100.0, 50.0, float("nan")], 900.0, 300.0)
    assert t == TelescopeTime(2, 1, 1800.0, 300.0, 150.0, 1)
    assert t.total_s == 2250.0
    assert pointing_time(0, [0.0], 900.0, 300.0) == TelescopeTime()
    both = total([t, pointing_time(1, [10.0, None], 900.0, 300.0)])
    assert both == TelescopeTime(3, 2, 2700.0, 600.0, 160.0, 2) and both.total_s == 3460.0
    assert t + TelescopeTime() == t and total([]) == TelescopeTime()
    with pytest.raises(InputError) as e:
        pointing_time(2, [1.0, 2.0], 900.0, 300.0)
    assert e.value.field == "leg_makespans_s"


@pytest.mark.parametrize("field,value", [
    ("exposure_time_s", 0.0), ("exposure_time_s", math.inf), ("acquisition_s", -1.0),
    ("max_exposures", 0), ("max_exposures", 1.5), ("min_priority_per_exposure", 0),
    ("min_targets_per_exposure", True),
])
def test_rules_are_validated_once_naming_the_field(field: str, value: Any) -> None:
    with pytest.raises(InputError) as e:
        ObservingRules(**{field: value})
    assert e.value.field == field
    assert ObservingRules() == ObservingRules(900.0, 300.0, None, None, None)


def brute_caps_objective(m: int, estimates: list[int]) -> tuple[int, set[tuple[int, ...]]]:
    """The least squared distance to the shares over every split of ``m`` that gives
    min(m, n) pointings an exposure (in units of 1 / sum(e)^2), and the splits reaching it."""
    n = len(estimates)
    w = estimates if any(estimates) else [1] * n
    tot = sum(w)
    best, argbest = None, set()
    for c in itertools.product(range(m + 1), repeat=n):
        if sum(c) != m or sum(x > 0 for x in c) != min(m, n):
            continue
        obj = sum((ci * tot - m * wi) ** 2 for ci, wi in zip(c, w, strict=True))
        if best is None or obj < best:
            best, argbest = obj, {c}
        elif obj == best:
            argbest.add(c)
    assert best is not None
    return best, argbest


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 9), st.lists(st.integers(0, 6), min_size=1, max_size=4))
def test_exposure_caps_match_a_brute_force_restatement(m: int, estimates: list[int]) -> None:
    caps = programme.exposure_caps(m, estimates)
    assert sum(caps) == m and len(caps) == len(estimates)
    assert sum(c > 0 for c in caps) == min(m, len(estimates))
    _, best = brute_caps_objective(m, estimates)
    assert tuple(caps) in best
    assert caps == programme.exposure_caps(m, list(estimates))  # deterministic


def test_exposure_caps_examples_and_errors() -> None:
    assert programme.exposure_caps(5, [3, 1, 1]) == [3, 1, 1]
    assert programme.exposure_caps(2, [1, 3, 2]) == [0, 1, 1]
    assert programme.exposure_caps(4, [2, 2]) == [2, 2]
    assert programme.exposure_caps(3, []) == []
    with pytest.raises(InputError) as e:
        programme.exposure_caps(-1, [1])
    assert e.value.field == "max_exposures"
    with pytest.raises(InputError) as e:
        programme.exposure_caps(2, [1, -1])
    assert e.value.field == "estimates[1]"


def test_estimated_exposures_prefers_the_segmentations_own() -> None:
    class P:
        target_indices = tuple(range(25))

    class Q(P):
        exposures = 2

    assert programme.estimated_exposures(P()) == 3
    assert programme.estimated_exposures(Q()) == 2


# ------------------------------------------------------------------- the edges


@pytest.mark.parametrize("field,value", [
    ("exposure_time_s", 0), ("acquisition_s", -5), ("max_exposures", 0), ("max_exposures", 2.5),
    ("min_priority_per_exposure", 0), ("min_targets_per_exposure", 13), ("min_targets_per_exposure", "3"),
])
def test_invalid_rules_are_422_naming_the_field(tmp_path, field: str, value: Any) -> None:
    with TestClient(create_app(Settings(job_db=tmp_path / "j.db"))) as c:
        r = c.post("/v1/plans", json={"targets": CLUMPS, field: value})
        assert r.status_code == 422, r.text
        assert [e["loc"] for e in r.json()["detail"]] == [["body", field]]
        r = c.post("/v1/jobs", json={"kind": "plan", "request": {"targets": CLUMPS, field: value}})
        assert r.status_code == 422, r.text
        assert r.json()["detail"][0]["loc"][-1] == field


@pytest.mark.parametrize("flag,value,field", [
    ("--exposure-time", "0", "exposure_time_s"), ("--acquisition", "-1", "acquisition_s"),
    ("--max-exposures", "0", "max_exposures"), ("--min-priority-per-exposure", "0", "min_priority_per_exposure"),
    ("--min-targets-per-exposure", "13", "min_targets_per_exposure"),
])
def test_cli_invalid_rules_exit_2_naming_the_field(tmp_path, capsys, flag: str, value: str, field: str) -> None:
    src = tmp_path / "t.csv"
    src.write_text("id,ra_deg,dec_deg,priority\n" + "".join(
        f"{t['id']},{t['ra_deg']},{t['dec_deg']},{t['priority']}\n" for t in CLUMPS))
    assert main(["plan", str(src), "--out", str(tmp_path / "o"), "--quiet", flag, value]) == 2
    assert f"error: {field}:" in capsys.readouterr().err


def test_cli_prints_exposures_and_telescope_time(tmp_path, capsys) -> None:
    src = tmp_path / "t.csv"
    src.write_text("id,ra_deg,dec_deg,priority\n" + "".join(
        f"{t['id']},{t['ra_deg']},{t['dec_deg']},{t['priority']}\n" for t in CLUMPS))
    out = tmp_path / "o"
    code = main(["plan", str(src), "--out", str(out), "--quiet", "--seed", "1", "--time-limit", "30",
                 "--exposure-time", "1200", "--acquisition", "600", "--max-exposures", "2"])
    assert code == 0, capsys.readouterr().err
    result = json.loads((out / "plan.json").read_text())
    check_time(result, 1200.0, 600.0)
    t = result["stats"]["telescope_time"]
    assert t["exposures"] <= 2
    text = capsys.readouterr()
    h, m = divmod(round(t["total_s"] / 60), 60)
    assert f"{t['exposures']} exposures, telescope time {h}:{m:02d} (h:mm) = exposures " in text.out
    assert "+ 2 acquisitions 0:20 + reconfiguration" in text.out
    assert "targets not allocated (beyond_max_exposures)" in text.err
