"""Every stage endpoint and its job refuse the same requests with the same 422: each
endpoint's corpus of bad bodies (the ones the other tests send, plus issue 41's) goes to the
endpoint and, wrapped, to ``POST /v1/jobs``; both answers name the same fields (the job's
under ``body.<kind>.request``) with the same messages, and no such job is queued."""

from __future__ import annotations

import json
from typing import Any

import httpx
import pytest
from test_service_api import BAD, POINTING, example, park, sky

KINDS = {"/v1/segmentations": "segmentation", "/v1/allocations": "allocation",
         "/v1/motion-plans": "motion-plan", "/v1/plans": "plan"}
ARM0 = {"arm": 0, "theta1_rad": 3.14159, "theta2_rad": 0.0}
PLANE = [{"id": "a", "x_mm": 0.0, "y_mm": 0.0, "priority": 1}]
# targets with no centre on the sphere, or one >= 90 deg from the field's centre (issue 41)
SPREAD = [{"id": "a", "ra_deg": 0.0, "dec_deg": 0.0, "priority": 1},
          {"id": "b", "ra_deg": 180.0, "dec_deg": 0.0, "priority": 1}]
BEHIND = [{"id": f"n{i}", "ra_deg": 0.0, "dec_deg": 0.0, "priority": 1} for i in range(3)] + [
    {"id": "s", "ra_deg": 180.0, "dec_deg": 0.0, "priority": 1}]


def _sky1(**over: Any) -> dict[str, Any]:
    return {"targets": [{"id": "a", "ra_deg": 10.0, "dec_deg": 20.0, "priority": 1}], **over}


def _motion(**over: Any) -> dict[str, Any]:
    return {**example("motion_plan"), **over}


EXTRA: list[tuple[str, str, Any]] = [
    # issue 41: refused by the endpoints, once accepted as jobs and failed
    ("spread over the sphere", "/v1/segmentations", {"targets": SPREAD}),
    ("spread over the sphere", "/v1/plans", {"targets": SPREAD}),
    ("a target 180 deg from the centre", "/v1/segmentations", {"targets": BEHIND}),
    ("a target 180 deg from the centre", "/v1/plans", {"targets": BEHIND}),
    ("target behind the tangent point", "/v1/segmentations",
     {"targets": sky(2), "tangent_point": {"ra_deg": 214.75, "dec_deg": -57.13}}),
    # issue 41: the cross-field rules
    ("arm twice in disabled_arms", "/v1/allocations",
     {"targets": PLANE, "disabled_arms": [ARM0, ARM0]}),
    ("arm twice in start", "/v1/allocations", {"targets": PLANE, "start": [ARM0, ARM0]}),
    ("arm twice in goal", "/v1/motion-plans", _motion(goal=park()[:11] + [park()[0]])),
    ("targets and target_list_id", "/v1/segmentations",
     {"targets": sky(2), "target_list_id": "abc"}),
    ("targets and target_list_id", "/v1/plans", {"targets": sky(2), "target_list_id": "abc"}),
    ("neither targets nor target_list_id", "/v1/plans", {}),
    ("empty allocation targets", "/v1/allocations", {"targets": []}),
    # tests/test_service_api.py
    ("sky target behind the pointing", "/v1/allocations",
     {"targets": sky(2, ra_deg=214.75, dec_deg=-57.13), "pointing": {"ra_deg": 34.75, "dec_deg": 57.13}}),
    ("sky target Dec 95", "/v1/allocations",
     {"targets": [{"id": "a", "ra_deg": 10.0, "dec_deg": 20.0, "priority": 1},
                  {"id": "b", "ra_deg": 10.0, "dec_deg": 95.0, "priority": 1}], "pointing": POINTING}),
    ("plane target y_mm text", "/v1/allocations",
     {"targets": [{"id": "a", "x_mm": 0.0, "y_mm": "far", "priority": 1}]}),
    ("dt_col_s too small", "/v1/motion-plans", _motion(dt_col_s=1e-4)),
    ("too many collision samples", "/v1/motion-plans", _motion(dt_s=0.6, dt_col_s=0.01)),
    ("dt_col_s does not divide dt_s", "/v1/motion-plans", _motion(dt_s=1.0, dt_col_s=0.3)),
    # tests/test_service_reliability.py
    ("threshold over the FOV diameter", "/v1/segmentations", {"targets": sky(3), "threshold_mm": 9999}),
    ("threshold over the FOV diameter", "/v1/plans", {"targets": sky(3), "threshold_mm": 9999}),
    # tests/test_service_contract.py
    ("priority 1.5", "/v1/plans", _sky1(targets=[{"id": "a", "ra_deg": 1.0, "dec_deg": 2.0, "priority": 1.5}])),
    ("seed 0.5", "/v1/segmentations", _sky1(seed=0.5)),
    ("priority as text", "/v1/segmentations",
     _sky1(targets=[{"id": "a", "ra_deg": 1.0, "dec_deg": 2.0, "priority": "2"}])),
    ("misspelt dt_col", "/v1/motion-plans", _motion(dt_col=0.1)),
    ("misspelt segmentation_mode", "/v1/plans", _sky1(segmentaton_mode="balanced")),
    ("misspelt solver", "/v1/allocations", {"targets": PLANE, "solvr": "bnb"}),
    # tests/test_park_move_limit.py
    ("negative park_move_limit_s", "/v1/plans", _sky1(park_move_limit_s=-5)),
    ("park_move_limit_s as text", "/v1/plans", _sky1(park_move_limit_s="abc")),
]
CORPUS = [(name, path, body) for name, path, body, _ in BAD
          if path in KINDS and name != "not json"] + EXTRA


def _post(url: str, body: Any) -> httpx.Response:
    if isinstance(body, str):  # JSON a client cannot build from Python values (NaN)
        return httpx.post(url, content=body, headers={"content-type": "application/json"},
                          timeout=60)
    return httpx.post(url, json=body, timeout=60)


def _job(kind: str, body: Any) -> Any:
    if isinstance(body, str):
        return f'{{"kind": {json.dumps(kind)}, "request": {body}}}'
    return {"kind": kind, "request": body}


def _errors(r: httpx.Response, prefix: list[Any]) -> list[tuple[list[Any], str]]:
    assert r.status_code == 422, (r.status_code, r.text)
    detail = r.json()["detail"]
    assert all(e["loc"][:len(prefix)] == prefix for e in detail), detail
    return [(e["loc"][len(prefix):], e["msg"]) for e in detail]


@pytest.mark.parametrize("name,path,body", CORPUS, ids=[f"{c[1]} {c[0]}" for c in CORPUS])
def test_a_job_is_refused_as_its_endpoint_refuses(live_server, name: str, path: str,
                                                  body: Any) -> None:
    kind = KINDS[path]
    direct = _errors(_post(live_server.url + path, body), ["body"])
    job = _errors(_post(live_server.url + "/v1/jobs", _job(kind, body)), ["body", kind, "request"])
    assert job == direct


def test_a_stored_list_is_refused_as_its_endpoint_refuses(live_server) -> None:
    """A stored list whose targets have no centre: the 422 names ``target_list_id`` at the
    endpoints and in the job alike."""
    csv = "id,ra_deg,dec_deg\n" + "".join(f"{t['id']},{t['ra_deg']},{t['dec_deg']}\n" for t in SPREAD)
    r = httpx.post(live_server.url + "/v1/target-lists", files={"file": ("s.csv", csv.encode())},
                   timeout=60)
    assert r.status_code in (200, 201), r.text
    body = {"target_list_id": r.json()["target_list_id"]}
    for path in ("/v1/segmentations", "/v1/plans"):
        kind = KINDS[path]
        direct = _errors(_post(live_server.url + path, body), ["body"])
        assert direct[0][0] == ["target_list_id"] and "spread over the whole sphere" in direct[0][1]
        job = _errors(_post(live_server.url + "/v1/jobs", _job(kind, body)), ["body", kind, "request"])
        assert job == direct
