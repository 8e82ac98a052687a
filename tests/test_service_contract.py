"""The HTTP contract holds for any input: schemathesis with every check, with and without a
bearer token, plus the hand-made bodies the generators rarely produce (not UTF-8, nested
10,000 deep, a 5,001-digit integer, malformed JSON), authentication before parsing, CORS on
every answer, and integral floats for integer fields."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from schemathesis.config import CoveragePhaseConfig, PositiveDataAcceptanceConfig
from schemathesis.config._checks import NegativeDataRejectionConfig

from service.app import create_app
from service.auth import warn_if_open
from service.settings import Settings

TOKEN = "c0ntract-t0ken"
ORIGIN = "https://form.example"
JSON = {"content-type": "application/json"}


def _settings(db: Path, token: str | None) -> Settings:
    # tiny limits: every stage runs for real, each call kept short; the job queue bound (a
    # deployment quota, tested in test_service_reliability.py) out of the fuzzer's reach
    return Settings(job_db=db, workers=1, max_targets=8, default_time_limit_s=0.15, max_queued_jobs=100_000,
                    max_time_limit_s=0.25, plan_budget_s=0.2, job_budget_s=0.2,
                    api_token=token, cors_origins=ORIGIN, max_body_bytes=100_000)


# ------------------------------------------------------------------- schemathesis


@pytest.fixture(scope="module", params=["open", "token-sent", "token-missing"])
def contract_schema(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    mode = request.param
    db = tmp_path_factory.mktemp(f"contract-{mode}") / "jobs.sqlite3"
    app = create_app(_settings(db, None if mode == "open" else TOKEN))
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    # Schema-valid is not always meaningful: a target 90 deg from the tangent point, a
    # threshold wider than the FOV, more targets than this server takes. Those are the
    # documented 422 naming the field, so 422 counts as a right answer to positive data.
    schema.config.checks.positive_data_acceptance = PositiveDataAcceptanceConfig(
        expected_statuses=["2xx", 401, 404, 422])
    # A list one longer than its maxItems (100,000 locked targets, say) is larger than the
    # server's body limit: it is refused by that limit, 413, before it is read; a refusal too.
    schema.config.checks.negative_data_rejection = NegativeDataRejectionConfig(
        expected_statuses=[400, 401, 403, 404, 405, 406, 409, 413, 415, 422, 428, 429])
    if mode == "token-sent":
        schema.config.update(headers={"Authorization": f"Bearer {TOKEN}"})
    if mode != "open":
        # the coverage phase's few thousand boundary cases run once, on the open server; with
        # a token the fuzzing phase (and its auth probes) checks the same contract
        schema.config.phases.coverage = CoveragePhaseConfig(enabled=False)
    yield schema
    app.state.mxs.close()


contract = schemathesis.pytest.from_fixture("contract_schema")


@contract.parametrize()
@settings(max_examples=5, deadline=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
def test_schemathesis_every_check(case: Any) -> None:
    """0 answers >= 500, 0 schema violations, 0 undocumented status codes (every check)."""
    response = case.call()
    assert response.status_code < 500, (response.status_code, response.text)
    case.validate_response(response)


# ------------------------------------------------------------ bodies and headers


UNPARSABLE = {
    "not UTF-8": (b'{"targets": "\xff\xfe\xfa"}', "UTF-8"),
    "nested 10,000 deep": (b"[" * 10_000 + b"]" * 10_000, "nested too deeply"),
    "objects nested 5,000 deep": (b'{"a":' * 5_000 + b"1" + b"}" * 5_000, "nested too deeply"),
    "5,001-digit integer": (b'{"targets": [{"id": "a", "ra_deg": 1, "dec_deg": 1, "priority": '
                            + b"7" * 5_001 + b"}]}", "digits"),
    "malformed JSON": (b"{targets", "not valid JSON"),
}


@pytest.fixture(scope="module")
def clients(tmp_path_factory: pytest.TempPathFactory):
    out = {}
    for name, token in (("open", None), ("token", TOKEN)):
        app = create_app(_settings(tmp_path_factory.mktemp(name) / "j.db", token))
        out[name] = TestClient(app, raise_server_exceptions=False).__enter__()
    yield out
    for c in out.values():
        c.__exit__(None, None, None)


@pytest.mark.parametrize("name", list(UNPARSABLE))
def test_unparsable_body_is_422_naming_body(clients, name: str) -> None:
    body, why = UNPARSABLE[name]
    for path in ("/v1/segmentations", "/v1/plans", "/v1/jobs"):
        r = clients["open"].post(path, content=body, headers={**JSON, "Origin": ORIGIN})
        assert r.status_code == 422, (path, r.status_code, r.text)
        out = r.json()
        assert out["detail"][0]["loc"] == ["body"] and why in out["message"], out
        assert out["message"].startswith("body: ")
        assert r.headers["access-control-allow-origin"] == ORIGIN


@pytest.mark.parametrize("content_type,body", [
    ("multipart/form-data", b"xx"),
    ("multipart/form-data; boundary=abc", b"garbage"),
    ("multipart/form-data; boundary=abc", b"--abc\r\nContent-Disposition: form-data\r\n\r\nx\r\n--abc--\r\n"),
])
def test_unreadable_upload_is_422_naming_body(clients, content_type: str, body: bytes) -> None:
    r = clients["open"].post("/v1/target-lists", content=body, headers={"content-type": content_type})
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body"] and r.json()["message"].startswith("body: ")


@pytest.mark.parametrize("name", list(UNPARSABLE))
def test_token_is_checked_before_the_body(clients, name: str) -> None:
    body, _ = UNPARSABLE[name]
    c = clients["token"]
    for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": f"Basic {TOKEN}"}):
        r = c.post("/v1/plans", content=body, headers={**JSON, **headers, "Origin": ORIGIN})
        assert r.status_code == 401, r.text
        assert r.json()["error"] == "unauthorized"
        assert r.headers["www-authenticate"] == "Bearer"
        assert r.headers["access-control-allow-origin"] == ORIGIN
    r = c.post("/v1/plans", content=body, headers={**JSON, "Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 422, r.text


def test_job_status_requires_the_token(clients) -> None:
    c = clients["token"]
    auth = {"Authorization": f"Bearer {TOKEN}"}
    body = {"kind": "segmentation", "request": {"targets": [
        {"id": "a", "ra_deg": 10.0, "dec_deg": 20.0, "priority": 1}]}}
    r = c.post("/v1/jobs", json=body, headers=auth)
    assert r.status_code == 202, r.text
    job = r.json()["job_id"]
    for headers in ({}, {"Authorization": "Bearer wrong"}):
        r = c.get(f"/v1/jobs/{job}", headers=headers)
        assert r.status_code == 401 and "result" not in r.json()
    assert c.get(f"/v1/jobs/{job}", headers=auth).status_code == 200
    assert c.get("/v1/jobs/nope", headers={}).status_code == 401  # no probing for ids either
    for open_path in ("/v1/health", "/v1/instrument", "/openapi.json", "/"):
        assert c.get(open_path).status_code == 200, open_path


def test_cors_headers_on_every_error(clients, monkeypatch) -> None:
    c = clients["token"]
    auth = {"Authorization": f"Bearer {TOKEN}", "Origin": ORIGIN}
    r = c.post("/v1/plans", content=b" " * 200_000, headers={**JSON, **auth})
    assert r.status_code == 413 and r.headers["access-control-allow-origin"] == ORIGIN
    r = c.post("/v1/plans", json={"targets": []}, headers=auth)
    assert r.status_code == 422 and r.headers["access-control-allow-origin"] == ORIGIN
    r = c.get("/v1/jobs/nope", headers=auth)
    assert r.status_code == 404 and r.headers["access-control-allow-origin"] == ORIGIN
    from service import pipeline

    def boom(_: Any) -> Any:
        raise RuntimeError("a bug")

    monkeypatch.setattr(pipeline, "instrument_info", boom)
    r = c.get("/v1/instrument", headers={"Origin": ORIGIN})
    assert r.status_code == 503 and r.headers["access-control-allow-origin"] == ORIGIN
    r = c.get("/v1/instrument", headers={"Origin": "https://elsewhere.example"})
    assert "access-control-allow-origin" not in r.headers


def _sky(priority: Any) -> dict[str, Any]:
    return {"targets": [{"id": "a", "ra_deg": 10.0, "dec_deg": 20.0, "priority": priority}]}


def test_integer_fields_take_integral_floats(clients) -> None:
    c = clients["open"]
    r = c.post("/v1/segmentations", json={**_sky(3.0), "seed": 1e1})
    assert r.status_code == 200, r.text
    for bad, field in ((_sky(1.5), ["body", "targets", 0, "priority"]),
                       ({**_sky(1), "seed": 0.5}, ["body", "seed"]),
                       (_sky("2"), ["body", "targets", 0, "priority"]),
                       (_sky(True), ["body", "targets", 0, "priority"])):
        r = c.post("/v1/segmentations", json=bad)
        assert r.status_code == 422, r.text
        assert r.json()["detail"][0]["loc"] == field, r.json()
    park = [{"arm": float(k), "theta1_rad": 3.14159, "theta2_rad": 0.0} for k in range(12)]
    r = c.post("/v1/motion-plans", json={"start": park, "goal": park, "max_start_stop": 1.0})
    assert r.status_code == 200, r.text


def test_misspelt_options_are_errors(clients) -> None:
    c = clients["open"]
    park = [{"arm": k, "theta1_rad": 3.14159, "theta2_rad": 0.0} for k in range(12)]
    for path, body, field in (
        ("/v1/motion-plans", {"start": park, "goal": park, "dt_col": 0.1}, "dt_col"),
        ("/v1/plans", {**_sky(1), "segmentaton_mode": "balanced"}, "segmentaton_mode"),
        ("/v1/allocations", {"targets": [{"id": "a", "x_mm": 0, "y_mm": 0, "priority": 1}],
                             "solvr": "bnb"}, "solvr"),
    ):
        r = c.post(path, json=body)
        assert r.status_code == 422, r.text
        assert r.json()["detail"][0]["loc"] == ["body", field]


def test_array_lengths_are_item_counts() -> None:
    """Every array constraint in the document is minItems/maxItems (minLength is for strings)."""
    from service.export_openapi import openapi_document

    def walk(node: Any, path: str) -> None:
        if isinstance(node, dict):
            if node.get("type") == "array":
                assert not {"minLength", "maxLength"} & set(node), path
            if {"minLength", "maxLength"} & set(node):
                assert node.get("type") == "string", path
            for k, v in node.items():
                walk(v, f"{path}.{k}")
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{path}[{i}]")

    doc = openapi_document()
    walk(doc, "$")
    targets = doc["components"]["schemas"]["AllocationRequest"]["properties"]["targets"]
    assert [b["minItems"] for b in targets["anyOf"]] == [1, 1]


def test_empty_token_is_unset_with_a_warning(tmp_path: Path, caplog) -> None:
    with caplog.at_level(logging.WARNING, logger="service"):
        app = create_app(_settings(tmp_path / "j.db", "  "))
    assert "authentication is DISABLED" in caplog.text
    with TestClient(app) as c:
        assert c.post("/v1/segmentations", json=_sky(1)).status_code == 200
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="service"):
        warn_if_open("0.0.0.0", Settings(api_token=None))
        assert "without MXS_API_TOKEN" in caplog.text
        caplog.clear()
        for quiet in (("127.0.0.1", None), ("::1", None), ("localhost", None),
                      ("0.0.0.0", TOKEN)):
            warn_if_open(quiet[0], Settings(api_token=quiet[1]))
        assert caplog.text == ""


def test_compose_requires_a_token() -> None:
    compose = (Path(__file__).resolve().parent.parent / "compose.yaml").read_text()
    line = next(ln for ln in compose.splitlines() if "MXS_API_TOKEN:" in ln)
    assert "${MXS_API_TOKEN:?" in line, line  # compose refuses to start without one
