"""The OpenAPI contract: committed document in sync and a generated client. Schemathesis
fuzzes every endpoint of the document, with every check, in tests/test_service_contract.py."""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from service.export_openapi import DEFAULT_PATH, openapi_document, render
from solvers.allocation.options import DEFAULT_SOLVER

ROOT = Path(__file__).resolve().parents[1]


def test_committed_openapi_matches_app() -> None:
    committed = DEFAULT_PATH.read_text()
    current = render(openapi_document())
    assert committed == current, (
        "openapi/openapi.json is stale: run `python -m service.export_openapi`"
    )


def test_contract_names() -> None:
    doc = openapi_document()
    paths = doc["paths"]
    for p in ("/v1/health", "/v1/instrument", "/v1/segmentations", "/v1/allocations",
              "/v1/motion-plans", "/v1/plans", "/v1/jobs", "/v1/jobs/{job_id}", "/v1/validations"):
        assert p in paths
    s = doc["components"]["schemas"]
    alloc = s["AllocationRequest"]["properties"]
    assert alloc["method"]["default"] == "ilp"
    assert alloc["solver"]["default"] == DEFAULT_SOLVER
    assert alloc["configurations"]["default"] == "one"
    assert set(s["SkyTarget"]["properties"]) == {"id", "ra_deg", "dec_deg", "priority", "pmra_mas_yr",
                                                 "pmdec_mas_yr", "parallax_mas", "radial_velocity_km_s",
                                                 "ref_epoch_yr"}
    plan = s["PlanRequest"]["properties"]
    assert {"obs_date", "position_angle_range_deg", "position_angle_step_deg", "locked", "excluded_targets",
            "keep_configurations", "sky_positions", "sky_radius_arcsec"} <= set(plan)
    assert {"content_hash", "epoch", "unallocated"} <= set(s["PlanResponse"]["properties"])
    assert s["SkyTarget"]["properties"]["priority"]["maximum"] == 2**32 - 1
    assert set(s["ArmState"]["properties"]) == {"arm", "theta1_rad", "theta2_rad"}
    assert s["MotionPlanRequest"]["properties"]["start"]["maxItems"] == 12
    assert "202" in paths["/v1/jobs"]["post"]["responses"]


# --------------------------------------------------------------- generated client


def readme_client_command() -> list[str]:
    """The client generation command of the README, as a user would copy it."""
    lines = [ln.strip() for ln in (ROOT / "README.md").read_text().splitlines()
             if ln.strip().startswith("openapi-python-client generate")]
    assert len(lines) == 1, lines
    return shlex.split(lines[0])


def test_generated_client_round_trip(tmp_path: Path, live_server) -> None:
    """The README's command on a copy of the committed document, then the client it writes
    against a live server: stages, a typed job result, the typed 409 and 422 bodies."""
    command = readme_client_command()
    assert shutil.which(command[0]), "openapi-python-client (dev extra) is not installed"
    (tmp_path / "openapi").mkdir()
    shutil.copy(DEFAULT_PATH, tmp_path / "openapi" / "openapi.json")
    subprocess.run(command, cwd=tmp_path, check=True, capture_output=True, timeout=120)
    out = tmp_path / command[command.index("--output-path") + 1]
    assert (out / "__init__.py").exists()
    code = CLIENT_SCRIPT.format(pkg=out.name, url=live_server.url)
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    report = json.loads(r.stdout.strip().splitlines()[-1])
    report["kinds"] = set(report["kinds"])
    assert report["health"] == "ok"
    assert report["arms"] == 12
    assert report["allocation"] == "ok"
    assert report["allocated"] >= 1 and report["kinds"] <= {"target", "park", "blank", "sky", "fixed"}
    assert report["motion"] in ("ok", "failed")
    assert report["job"] == ["SegmentationJobStatus", "SegmentationResponse", "done"]
    assert report["job_targets"] == ["s0", "s1", "s2"]
    assert report["cancel_done"] == [409, "ErrorResponse", "conflict"]
    assert report["bad"] == [422, "ValidationErrorResponse", ["body", "targets", 0, "dec_deg"]]
    assert report["plan"] == ["EpochOut", True, True, ["excluded"], True, True]
    assert report["validation"] == [200, "ValidationResponse", True, True]


CLIENT_SCRIPT = r'''
import datetime, json, math, time
from {pkg} import Client
from {pkg}.api.stages import create_plan
from {pkg}.api.validation import create_validation
from {pkg}.api.service import get_instrument, health
from {pkg}.api.jobs import cancel_job, create_job, get_job
from {pkg}.api.stages import create_allocation, create_motion_plan, create_segmentation
from {pkg}.models import (AllocationRequest, ArmState, MotionPlanRequest, PlaneTarget,
                          SegmentationJob, SegmentationRequest, SkyTarget, PlanRequest, SkyPoint,
                          TargetLockIn, CreateValidationPlan)

client = Client(base_url="{url}", raise_on_unexpected_status=False, timeout=120)
report = {{}}
report["health"] = health.sync(client=client).status
inst = get_instrument.sync(client=client)
report["arms"] = len(inst.arms)
targets = [PlaneTarget(id=f"t{{i}}", x_mm=60 * math.cos(i), y_mm=60 * math.sin(i), priority=i + 1)
           for i in range(10)]
resp = create_allocation.sync_detailed(
    client=client, body=AllocationRequest(targets=targets, time_limit_s=10, seed=1))
assert resp.status_code == 200, (resp.status_code, resp.content)
alloc = resp.parsed
report["allocation"] = "ok"
cfg = alloc.configurations[0]
assert [a.arm for a in cfg.assignments] == list(range(12))
xy = {{t.id: (t.x_mm, t.y_mm) for t in targets}}
for a in cfg.assignments:
    if isinstance(a.target_id, str):  # the tip sits on its target
        assert math.hypot(a.x_mm - xy[a.target_id][0], a.y_mm - xy[a.target_id][1]) < 0.01
report["allocated"] = sum(isinstance(a.target_id, str) for a in cfg.assignments)
report["kinds"] = sorted({{str(getattr(a.kind, "value", a.kind)) for a in cfg.assignments}})
goal = [ArmState(arm=a.arm, theta1_rad=a.theta1_rad, theta2_rad=a.theta2_rad)
        for a in cfg.assignments]
start = [ArmState(arm=a.arm, theta1_rad=a.park.theta1_rad, theta2_rad=a.park.theta2_rad)
         for a in inst.arms]
m = create_motion_plan.sync_detailed(
    client=client, body=MotionPlanRequest(start=start, goal=goal, seed=1, time_limit_s=5))
assert m.status_code == 200, (m.status_code, m.content)
report["motion"] = m.parsed.status.value if hasattr(m.parsed.status, "value") else str(m.parsed.status)
assert len(m.parsed.trajectories) == (12 if report["motion"] == "ok" else len(m.parsed.trajectories))
sky = [SkyTarget(id=f"s{{i}}", ra_deg=34.75 + 0.002 * i, dec_deg=57.13, priority=1) for i in range(3)]
created = create_job.sync(client=client, body=SegmentationJob(
    kind="segmentation", request=SegmentationRequest(targets=sky)))
for _ in range(600):
    job = get_job.sync(client=client, job_id=created.job_id)
    if str(getattr(job.status, "value", job.status)) in ("done", "failed"):
        break
    time.sleep(0.1)
status = str(getattr(job.status, "value", job.status))
report["job"] = [type(job).__name__, type(job.result).__name__, status]
report["job_targets"] = sorted(t for p in job.result.pointings for t in p.target_ids)
c = cancel_job.sync_detailed(client=client, job_id=created.job_id)
report["cancel_done"] = [c.status_code, type(c.parsed).__name__, c.parsed.error]
bad = create_segmentation.sync_detailed(client=client, body=SegmentationRequest(
    targets=[SkyTarget(id="x", ra_deg=10.0, dec_deg=95.0, priority=1)]))
report["bad"] = [bad.status_code, type(bad.parsed).__name__, bad.parsed.detail[0].loc]
# issue 39's controls, typed by the generated models: epochs, an angle search, a lock, an
# exclusion, sky; then the plan's own bytes re-checked through POST /v1/validations
stars = [SkyTarget(id="m", ra_deg=34.75, dec_deg=57.13, priority=10, pmra_mas_yr=500.0, pmdec_mas_yr=-300.0,
                   ref_epoch_yr=2016.0),
         SkyTarget(id="n", ra_deg=34.752, dec_deg=57.131, priority=100),
         SkyTarget(id="x", ra_deg=34.749, dec_deg=57.129, priority=1)]
ask = PlanRequest(targets=stars, obs_date=datetime.date(2027, 1, 1), position_angle_deg="auto",
                  position_angle_range_deg=[0.0, 90.0], excluded_targets=["x"], sky_radius_arcsec=10.0,
                  sky_positions=[SkyPoint(ra_deg=34.76, dec_deg=57.14)], time_limit_s=60, seed=1)
first = create_plan.sync_detailed(client=client, body=ask)
assert first.status_code == 200, (first.status_code, first.content)
pt = next(p for p in first.parsed.pointings if "n" in p.target_ids)
arm = next(a.arm for c in pt.configurations for a in c.assignments if a.target_id == "n")
ask.locked = [TargetLockIn(target_id="n", arm=arm)]
r = create_plan.sync_detailed(client=client, body=ask)
assert r.status_code == 200, (r.status_code, r.content)
plan = r.parsed
report["plan"] = [type(plan.epoch).__name__, plan.epoch.obs_date == "2027-01-01" or str(plan.epoch.obs_date),
                  plan.content_hash.startswith("sha256:"),
                  sorted(str(getattr(u.reason, "value", u.reason)) for u in plan.unallocated),
                  sorted({{a.arm for p in plan.pointings for c in p.configurations for a in c.assignments
                           if a.target_id == "n"}}) == [arm],
                  all(p.position_angle_search is not None for p in plan.pointings if p.configurations)]
v = create_validation.sync_detailed(client=client, body=CreateValidationPlan.from_dict(json.loads(r.content)))
report["validation"] = [v.status_code, type(v.parsed).__name__, v.parsed.valid, v.parsed.hash_ok]
print(json.dumps(report))
'''
