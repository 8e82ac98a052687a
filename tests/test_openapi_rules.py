"""The OpenAPI document states the requests' cross-field rules exactly: for bodies built to
sit on either side of each rule (one of `targets` / `target_list_id`, each arm at most once,
`pointing` with sky targets, at least one target, the server's time-limit and threshold
bounds), a JSON Schema 2020-12 validator of the document (jsonschema-rs, independent of
pydantic) accepts a body exactly when the server's checks do. So a client, or a fuzzer,
generating from the document sends what the server accepts, and the server refuses what
the document refuses."""

from __future__ import annotations

import math
from typing import Any

import jsonschema_rs
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from models.instrument import default_instrument
from service.errors import FieldError
from service.export_openapi import openapi_document
from service.limits import check_request
from service.schemas import REQUEST_TYPES
from service.settings import Settings

DOC = openapi_document()
SETTINGS = Settings(_env_file=None)
INST = default_instrument()
COMPONENT = {"segmentation": "SegmentationRequest", "allocation": "AllocationRequest",
             "motion-plan": "MotionPlanRequest", "plan": "PlanRequest"}
VALIDATORS = {kind: jsonschema_rs.Draft202012Validator(
    {"$ref": f"#/components/schemas/{name}", "components": DOC["components"]})
    for kind, name in COMPONENT.items()}


def server_accepts(kind: str, body: dict[str, Any]) -> bool:
    """The request schema's validation, then this server's limits (a stored list is taken
    to exist: whether it does is not the document's to say)."""
    try:
        req = REQUEST_TYPES[kind].model_validate(body)
        check_request(req, SETTINGS, INST)
    except (ValidationError, FieldError):
        return False
    return True


def document_accepts(kind: str, body: dict[str, Any]) -> bool:
    return VALIDATORS[kind].is_valid(body)


SKY = [{"id": "a", "ra_deg": 10.0, "dec_deg": 20.0, "priority": 1},
       {"id": "b", "ra_deg": 10.01, "dec_deg": 20.0, "priority": 2}]
PLANE = [{"id": "a", "x_mm": 0.0, "y_mm": 0.0, "priority": 1}]
POINTING = {"ra_deg": 10.0, "dec_deg": 20.0}


def arm(k: int, t1: float = math.pi, t2: float = 0.0) -> dict[str, Any]:
    return {"arm": k, "theta1_rad": t1, "theta2_rad": t2}


ALL_ARMS = [arm(k) for k in range(12)]
CASES: list[tuple[str, dict[str, Any]]] = [
    ("segmentation", {"targets": SKY}),
    ("segmentation", {"target_list_id": "abc"}),
    ("segmentation", {"targets": SKY, "target_list_id": "abc"}),
    ("segmentation", {}),
    ("segmentation", {"targets": None, "target_list_id": "abc"}),
    ("segmentation", {"targets": SKY, "target_list_id": None}),
    ("segmentation", {"targets": None, "target_list_id": None}),
    ("segmentation", {"targets": []}),
    ("segmentation", {"targets": SKY, "threshold_mm": 250.0}),
    ("segmentation", {"targets": SKY, "threshold_mm": 250.5}),
    ("plan", {"targets": SKY, "target_list_id": "abc"}),
    ("plan", {"target_list_id": "abc", "time_limit_s": 600}),
    ("plan", {"target_list_id": "abc", "time_limit_s": 600.5}),
    ("plan", {"targets": SKY, "threshold_mm": 251}),
    ("allocation", {"targets": PLANE}),
    ("allocation", {"targets": []}),
    ("allocation", {"targets": SKY}),
    ("allocation", {"targets": SKY, "pointing": None}),
    ("allocation", {"targets": SKY, "pointing": POINTING}),
    ("allocation", {"targets": PLANE, "pointing": POINTING}),
    ("allocation", {"targets": PLANE, "disabled_arms": [arm(0), arm(0, 1.0)]}),
    ("allocation", {"targets": PLANE, "disabled_arms": [arm(0), arm(0)]}),
    ("allocation", {"targets": PLANE, "disabled_arms": [arm(0), arm(6)]}),
    ("allocation", {"targets": PLANE, "start": [arm(3), arm(4), {"arm": 3.0, "theta1_rad": 1.0,
                                                                 "theta2_rad": 0.0}]}),
    ("allocation", {"targets": PLANE, "start": ALL_ARMS}),
    ("allocation", {"targets": PLANE, "time_limit_s": 601}),
    ("motion-plan", {"start": ALL_ARMS, "goal": ALL_ARMS}),
    ("motion-plan", {"start": ALL_ARMS[:11] + [arm(0, 1.0)], "goal": ALL_ARMS}),
    ("motion-plan", {"start": ALL_ARMS, "goal": ALL_ARMS[::-1]}),
    ("motion-plan", {"start": ALL_ARMS, "goal": ALL_ARMS[1:] + [arm(5, 2.0)]}),
]


@pytest.mark.parametrize("kind,body", CASES, ids=[f"{k}-{i}" for i, (k, _) in enumerate(CASES)])
def test_the_document_accepts_what_the_server_accepts(kind: str, body: dict[str, Any]) -> None:
    assert document_accepts(kind, body) == server_accepts(kind, body)


def test_the_cases_cover_both_sides_of_every_rule() -> None:
    verdicts = [server_accepts(k, b) for k, b in CASES]
    assert 8 <= sum(verdicts) <= len(CASES) - 8


ARMS = st.lists(st.builds(arm, st.integers(0, 11), st.sampled_from([math.pi, 1.0])), max_size=12)
TARGETS = st.sampled_from([None, [], SKY, PLANE, SKY[:1]])


@st.composite
def allocation_bodies(draw: st.DrawFn) -> dict[str, Any]:
    body: dict[str, Any] = {"targets": draw(st.sampled_from([[], SKY, PLANE]))}
    for name, values in (("pointing", st.sampled_from([None, POINTING])), ("start", ARMS),
                         ("disabled_arms", ARMS), ("time_limit_s", st.sampled_from([1, 600, 900]))):
        if draw(st.booleans()):
            body[name] = draw(values)
    return body


@st.composite
def source_bodies(draw: st.DrawFn) -> dict[str, Any]:
    body: dict[str, Any] = {}
    for name, values in (("targets", TARGETS), ("target_list_id", st.sampled_from([None, "L1"])),
                         ("threshold_mm", st.sampled_from([10.0, 250.0, 300.0]))):
        if draw(st.booleans()):
            body[name] = draw(values)
    return body


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.one_of(st.tuples(st.just("allocation"), allocation_bodies()),
                 st.tuples(st.sampled_from(["segmentation", "plan"]), source_bodies()),
                 st.tuples(st.just("motion-plan"), st.fixed_dictionaries(
                     {"start": st.permutations(ALL_ARMS), "goal": ARMS}))))
def test_the_document_and_the_server_agree_on_random_bodies(case: tuple[str, dict[str, Any]]) -> None:
    kind, body = case
    assert document_accepts(kind, body) == server_accepts(kind, body), body
