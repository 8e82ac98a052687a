"""Error answers quote at most about 100 characters of any input: a huge string in any
field, as an unknown field's name or a job's kind, a huge array where a number belongs, an
array of 200,000 wrong items, a long path parameter. The answer stays small and still names
the field."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.errors import ECHO_CHARS, MAX_ERRORS, clip, clip_message
from service.settings import Settings

N = 1_000_000  # characters of each hostile string
SLACK = 10  # a clipped echo keeps its quotes and "..."
SOLID = "x" * N
SPACED = "lorem ipsum " * (N // 12)  # a long input with blanks in it


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    db = tmp_path_factory.mktemp("echo") / "j.db"
    app = create_app(Settings(job_db=db, max_body_bytes=50_000_000,
                              max_job_body_bytes=50_000_000, max_segmentation_body_bytes=50_000_000))
    with TestClient(app) as c:
        yield c


def longest_echo(answer: str, filler: str) -> int:
    """The longest stretch of ``answer`` copied from the periodic ``filler``."""
    period = filler[:12] if filler is SPACED else filler[:1]
    runs = re.findall(f"(?:{re.escape(period)})+", answer)
    return max((len(r) for r in runs), default=0)


def sky1(**over: Any) -> dict[str, Any]:
    target = {"id": "a", "ra_deg": 10.0, "dec_deg": 20.0, "priority": 1}
    target.update(over.pop("target", {}))
    return {"targets": [target], **over}


PLANE = [{"id": "a", "x_mm": 0.0, "y_mm": 0.0, "priority": 1}]
Build = Callable[[str], tuple[str, Any, list[Any]]]  # filler -> (path, body, loc prefix)
BODIES: dict[str, Build] = {
    "target id": lambda s: ("/v1/segmentations", sky1(target={"id": s}), ["body", "targets", 0, "id"]),
    "ra_deg as text": lambda s: ("/v1/plans", sky1(target={"ra_deg": s}), ["body", "targets", 0, "ra_deg"]),
    "method": lambda s: ("/v1/allocations", {"targets": PLANE, "method": s}, ["body", "method"]),
    "segmentation mode": lambda s: ("/v1/segmentations", sky1(mode=s), ["body", "mode"]),
    "target_list_id": lambda s: ("/v1/plans", {"target_list_id": s}, ["body", "target_list_id"]),
    "unknown field": lambda s: ("/v1/plans", sky1(**{s: 1}), ["body"]),
    "unknown target field": lambda s: ("/v1/segmentations", sky1(target={s: 1}), ["body", "targets", 0]),
    "job kind": lambda s: ("/v1/jobs", {"kind": s, "request": {}}, ["body"]),
    "job request field": lambda s: ("/v1/jobs", {"kind": "plan", "request": sky1(**{s: 1})},
                                    ["body", "plan", "request"]),
    "arm as text": lambda s: ("/v1/allocations", {"targets": PLANE, "disabled_arms": [
        {"arm": s, "theta1_rad": 0.0, "theta2_rad": 0.0}]}, ["body", "disabled_arms", 0, "arm"]),
}


@pytest.mark.parametrize("filler", [SOLID, SPACED], ids=["solid", "spaced"])
@pytest.mark.parametrize("name", list(BODIES))
def test_a_long_string_is_quoted_clipped(client: TestClient, name: str, filler: str) -> None:
    path, body, loc = BODIES[name](filler)
    r = client.post(path, json=body)
    assert r.status_code == 422, r.text[:500]
    out = r.json()
    assert any(e["loc"][:len(loc)] == loc for e in out["detail"]), out
    assert longest_echo(r.text, filler) <= ECHO_CHARS + SLACK, name
    assert len(r.content) < 8_000


def test_a_huge_array_is_quoted_clipped(client: TestClient) -> None:
    r = client.post("/v1/segmentations", json=sky1(target={"ra_deg": [1.5] * 200_000}))
    assert r.status_code == 422
    (e,) = r.json()["detail"]
    assert e["loc"] == ["body", "targets", 0, "ra_deg"]
    assert isinstance(e["input"], str) and len(e["input"]) < ECHO_CHARS + 30
    assert len(r.content) < 2_000


def test_a_huge_integer_is_described(client: TestClient) -> None:
    r = client.post("/v1/segmentations", json=sky1(target={"priority": int("9" * 4000)}))
    assert r.status_code == 422
    (e,) = r.json()["detail"]
    assert e["loc"] == ["body", "targets", 0, "priority"] and "4000 digits" in e["input"]


def test_many_errors_are_listed_up_to_a_bound(client: TestClient) -> None:
    r = client.post("/v1/segmentations", json={"targets": ["x"] * 200_000})
    assert r.status_code == 422
    out = r.json()
    assert len(out["detail"]) == MAX_ERRORS
    assert [e["loc"] for e in out["detail"][:2]] == [["body", "targets", 0], ["body", "targets", 1]]
    assert f"200000 errors in all, the first {MAX_ERRORS} in detail" in out["message"]
    assert len(r.content) < 20_000


@pytest.mark.parametrize("path", ["/v1/jobs/{}", "/v1/target-lists/{}"])
def test_a_long_path_parameter_is_quoted_clipped(client: TestClient, path: str) -> None:
    r = client.get(path.format("z" * 20_000))
    assert r.status_code == 404
    assert longest_echo(r.json()["detail"], "z") <= ECHO_CHARS
    assert len(r.content) < 1_000


def test_clip_helpers() -> None:
    assert clip("abc") == "abc"
    assert clip("a" * 150) == "a" * ECHO_CHARS + "... (150 characters)"
    # an input's string is clipped once wherever it occurs; other long runs too; the whole bounded
    msg = clip_message(f"tag '{SOLID[:5000]}' and {'y' * 300}", (SOLID[:5000],))
    assert msg == f"tag '{clip(SOLID[:5000])}' and {clip('y' * 300)}"
    assert len(clip_message(SPACED)) < 1_100


def test_a_bad_table_cell_is_quoted_clipped(client: TestClient, tmp_path: Path) -> None:
    """Issue 41: a 40 MB bad RA cell gave an 80 MB 422; a 1 MB one is answered small."""
    csv = "ra,dec\n" + "1" * N + "x,20\n"
    r = client.post("/v1/target-lists", files={"file": ("t.csv", csv.encode())})
    assert r.status_code in (413, 422), r.text[:300]
    assert longest_echo(json.dumps(r.json()), "1") <= ECHO_CHARS
    assert len(r.content) < 4_000


def test_a_failed_job_quotes_its_input_clipped(tmp_path: Path) -> None:
    from service.jobs import JobStore

    store = JobStore(tmp_path / "j.db")
    store.init()
    job_id = store.create("segmentation", {"targets": []})
    store.set_failed(job_id, f"invalid input: no target {SOLID!r}")
    job = store.get(job_id)
    assert job is not None and job["status"] == "failed"
    assert job["error"].startswith("invalid input: no target 'xxx")
    assert longest_echo(job["error"], SOLID) <= ECHO_CHARS + SLACK
