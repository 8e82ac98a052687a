"""Executable whole-field plans: `executable`, `reasons` and `changes` of POST /v1/plans, of a
plan job's result and of `mxs-planner plan` (exit code 4 when a leg could not be planned).

The fast tests replace ``planner.pointing.plan_sequence`` with a fake that returns a
``SequencePlan`` of real domain objects (segmentation and allocation run for real); the last
test runs the whole pipeline unchanged on a tiny field."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.budget import Budget
from models.instrument import default_instrument
from models.sky import focal_mm_to_sky
from models.types import ArmTrajectory, Configuration, MotionPlan, PlaneTargets
from planner import pointing, programme
from planner.sequence import PlanChange, SequenceOptions, SequencePlan
from service import job_run, jobs
from service.app import create_app
from service.cli import EXIT_NOT_EXECUTABLE, build_parser, main
from service.job_schemas import PlanJobStatus
from service.response_schemas import PlanResponse
from service.settings import Settings

TOKEN = "t0ken"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
FAILED_ARMS = (3, 4)
ARM_REASONS = {3: "blocked by arm 4", 4: "no path found within the leg budget"}


TARGETS = [{"id": f"s{i}", "ra_deg": 34.75 + 0.002 * i, "dec_deg": 57.13 - 0.001 * i,
            "priority": 1 + i} for i in range(3)]  # three stars in one pointing


def targets() -> list[dict[str, Any]]:
    return [dict(t) for t in TARGETS]


def _leg(start: np.ndarray, goal: np.ndarray, ok: bool) -> MotionPlan:
    if not ok:
        return MotionPlan("failed", math.nan, (), FAILED_ARMS, {"reasons": dict(ARM_REASONS)})
    trajs = tuple(ArmTrajectory(k, np.array([0.0, 1.0]), np.array([start[k, 0], goal[k, 0]]),
                                np.array([start[k, 1], goal[k, 1]])) for k in range(len(start)))
    return MotionPlan("ok", 1.0, trajs, (), {"compute_s": 0.0})


def fake_plan_sequence(fail: bool):
    """A stand-in for planner.sequence.plan_sequence: the configurations unchanged, one
    via-park and one moved-target change, and (``fail``) the last leg failed."""
    calls: list[SequenceOptions] = []

    def plan_sequence(inst: Any, configurations: Any, options: SequenceOptions, *,
                      targets: PlaneTargets, progress: Any, budget: Budget, known: Any = None) -> SequencePlan:
        assert isinstance(options, SequenceOptions) and options.leg_time_limit_s > 0
        progress(1.0)
        assert isinstance(targets, PlaneTargets) and len(targets.ids) == len(TARGETS)
        configs = tuple(configurations)
        assert configs and all(isinstance(c, Configuration) for c in configs)
        calls.append(options)
        park = inst.park_configuration
        qs = [park] + [c.q for c in configs] + [park]
        legs = tuple(_leg(qs[i], qs[i + 1], ok=not (fail and i == len(qs) - 2))
                     for i in range(len(qs) - 1))
        moved = next(a for a in configs[0].assignments if a.target_id is not None)
        changes = (
            PlanChange("via_park", 0, 0, (), (), "leg 0 planned through park"),
            PlanChange("moved_target", 1, 0, (moved.arm,), (moved.target_id,),
                       f"arm {moved.arm} blocked the leg"),
        )
        return SequencePlan(configs, legs, changes, (), {"fake": True})

    plan_sequence.calls = calls  # type: ignore[attr-defined]
    return plan_sequence


def check_failed(out: dict[str, Any]) -> None:
    PlanResponse.model_validate(out)
    assert out["executable"] is False
    (p,) = out["pointings"]
    assert p["executable"] is False
    n = len(p["configurations"])
    assert len(p["motions"]) == n + 1
    assert [m["status"] for m in p["motions"]] == ["ok"] * n + ["failed"]
    assert p["motions"][-1]["failed_arms"] == list(FAILED_ARMS)
    (reason,) = p["reasons"]
    # legs counted from 1, like the configurations: leg n + 1 goes cn -> park (motions[n])
    assert reason.startswith(f"leg {n + 1} (c{n} -> park): arms 3, 4 not planned")
    assert "arm 3: blocked by arm 4" in reason
    assert out["reasons"] == [f"pointing {p['id']}: {reason}"]
    assert [c["kind"] for c in p["changes"]] == ["via_park", "moved_target"]
    moved = p["changes"][1]
    assert set(moved) == {"kind", "leg", "configuration", "arms", "target_ids", "reason"}
    assert moved["leg"] == 1 and moved["configuration"] == 0 and len(moved["arms"]) == 1
    assert moved["target_ids"][0] in {t["id"] for t in targets()}
    m = p["stats"]["motion"]
    assert (m["legs"], m["failed_legs"]) == (n + 1, 1)
    assert (m["targets_moved"], m["legs_via_park"], m["configurations_added"],
            m["targets_dropped"]) == (1, 1, 0, 0)
    s = out["stats"]
    assert (s["targets_moved"], s["legs_via_park"], s["motion_plans_failed"]) == (1, 1, 1)


# ------------------------------------------------------------------------ HTTP


@pytest.mark.parametrize("fail", [True, False])
def test_plan_endpoint_says_whether_executable(tmp_path: Path, monkeypatch, fail: bool) -> None:
    fake = fake_plan_sequence(fail)
    monkeypatch.setattr(pointing, "plan_sequence", fake)
    # heavy_processes=False: the plan computes in this process, where the fake applies
    app = create_app(Settings(job_db=tmp_path / "j.db", api_token=TOKEN, heavy_processes=False))
    with TestClient(app) as c:
        r = c.post("/v1/plans", json={"targets": targets(), "seed": 1, "time_limit_s": 10},
                   headers=AUTH)
    assert r.status_code == 200, r.text
    out = r.json()
    assert fake.calls[0].seed == 1
    if fail:  # the pointing is planned again, on other seeds, while the limit has time left:
        # every round, then (the default mode spends the rounds' margin) the margin round. The
        # first round plans the legs with the spare arms on sky, then (they failed) without;
        # the later rounds start from its plan, whose legs end at the plain configurations,
        # and plan those first (planner.pointing._sequence_with_sky)
        rounds = programme.SHARES.rounds + 1
        assert len(fake.calls) == rounds + 1
        assert fake.calls[1].seed == fake.calls[0].seed
        assert len({o.seed for o in fake.calls[1:]}) == rounds
        assert [r["round"] for r in out["pointings"][0]["stats"]["rounds"]] == list(range(1, rounds + 1))
        check_failed(out)
        return
    # the legs with the spare arms on sky, kept: every leg planned, no target dropped
    # (planner.pointing._sequence_with_sky)
    assert [o.seed for o in fake.calls] == [1]
    assert sum(a["kind"] == "sky" for c in out["pointings"][0]["configurations"] for a in c["assignments"]) > 0
    PlanResponse.model_validate(out)
    assert out["executable"] is True and out["reasons"] == []
    (p,) = out["pointings"]
    assert p["executable"] is True and p["reasons"] == []
    assert all(m["status"] == "ok" for m in p["motions"])
    assert [c["kind"] for c in p["changes"]] == ["via_park", "moved_target"]
    assert p["stats"]["motion"]["failed_legs"] == 0
    assert p["stats"]["sequence"] == {"fake": True}


def test_planner_error_is_a_failed_plan_not_a_5xx(tmp_path: Path, monkeypatch) -> None:
    def broken(*_: Any, **__: Any) -> Any:
        raise RuntimeError("a bug")

    monkeypatch.setattr(pointing, "plan_sequence", broken)
    app = create_app(Settings(job_db=tmp_path / "j.db", heavy_processes=False))
    with TestClient(app) as c:
        r = c.post("/v1/plans", json={"targets": targets(), "seed": 1, "time_limit_s": 10})
    assert r.status_code == 200, r.text
    out = r.json()
    PlanResponse.model_validate(out)
    assert out["executable"] is False
    (p,) = out["pointings"]
    assert all(m["status"] == "failed" for m in p["motions"])
    assert p["reasons"] == ["planner error: RuntimeError: a bug"]
    assert out["reasons"] == [f"pointing {p['id']}: planner error: RuntimeError: a bug"]


def test_plan_job_result_carries_executable(tmp_path: Path, monkeypatch) -> None:
    """The worker's own function, run here so the fake applies; read back with GET /v1/jobs."""
    monkeypatch.setattr(pointing, "plan_sequence", fake_plan_sequence(fail=True))
    db = tmp_path / "j.db"
    app = create_app(Settings(job_db=db))
    with TestClient(app) as c:
        request = {"targets": targets(), "seed": 1, "time_limit_s": 10}
        job_id = jobs.JobStore(db).create("plan", request)
        assert job_run.run_job(str(db), job_id, "plan", request, None, 3.0, 60.0) == "done"
        r = c.get(f"/v1/jobs/{job_id}")
    assert r.status_code == 200, r.text
    job = PlanJobStatus.model_validate(r.json())
    assert job.status == "done" and isinstance(job.result, PlanResponse)
    check_failed(r.json()["result"])


# ------------------------------------------------------------------------- CLI


def _target_file(tmp_path: Path) -> Path:
    src = tmp_path / "t.csv"
    src.write_text("id,ra_deg,dec_deg,priority\n" + "".join(
        f"{t['id']},{t['ra_deg']},{t['dec_deg']},{t['priority']}\n" for t in targets()))
    return src


def test_cli_exit_code_4_when_not_executable(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(pointing, "plan_sequence", fake_plan_sequence(fail=True))
    code = main(["plan", str(_target_file(tmp_path)), "--out", str(tmp_path / "o"),
                 "--seed", "1", "--time-limit", "10", "--quiet"])
    cap = capsys.readouterr()
    assert code == EXIT_NOT_EXECUTABLE == 4, cap.err
    assert "not executable" in cap.err
    # legs counted from 1, like the configurations: the last leg n + 1 goes cn -> park
    assert re.search(r"error: pointing \S+: motion leg (\d+) \(c(\d+) -> park\) not planned",
                     cap.err), cap.err
    m = re.search(r"error: pointing \S+: leg (\d+) \(c(\d+) -> park\): arms 3, 4 not planned "
                  r"\(arm 3: blocked by arm 4; arm 4: no path found", cap.err)
    assert m and int(m.group(1)) == int(m.group(2)) + 1, cap.err
    assert "1 target moved to another configuration, 1 leg through park" in cap.out
    assert (tmp_path / "o" / "plan.json").is_file()  # the plan is still written


def test_cli_exit_code_0_when_executable(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(pointing, "plan_sequence", fake_plan_sequence(fail=False))
    code = main(["plan", str(_target_file(tmp_path)), "--out", str(tmp_path / "o"),
                 "--seed", "1", "--time-limit", "10", "--quiet"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "not executable" not in cap.err and "not planned" not in cap.err


def test_cli_help_documents_exit_codes() -> None:
    sub = build_parser()._subparsers._group_actions[0].choices["plan"]  # type: ignore[union-attr]
    for text in (build_parser().format_help(), sub.format_help()):
        assert "4  plan not executable" in text and "2  invalid input" in text


# ----------------------------------------------------------------- integration


def test_tiny_field_is_executable_without_fakes(tmp_path: Path) -> None:
    """Four stars toward arms 0, 3, 6 and 9, one pointing: every leg is planned."""
    inst = default_instrument()
    x = np.array([80.0, 0.0, -80.0, 0.0])
    y = np.array([0.0, 80.0, 0.0, -80.0])
    ra, dec = focal_mm_to_sky(x, y, 150.0, 20.0, inst.plate_scale_arcsec_per_mm)
    body = {"targets": [{"id": f"d{i}", "ra_deg": float(a), "dec_deg": float(d), "priority": 5}
                        for i, (a, d) in enumerate(zip(ra, dec, strict=True))],
            "seed": 1, "time_limit_s": 30}  # the whole plan; two legs of ~2.5 s each
    app = create_app(Settings(job_db=tmp_path / "j.db"))
    with TestClient(app) as c:
        r = c.post("/v1/plans", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    PlanResponse.model_validate(out)
    assert out["executable"] is True, out["reasons"]
    assert out["reasons"] == []
    assert out["stats"]["allocated_targets"] == 4
    for p in out["pointings"]:
        assert p["executable"] is True
        assert len(p["motions"]) == len(p["configurations"]) + 1
        assert all(m["status"] == "ok" for m in p["motions"])
