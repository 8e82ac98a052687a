"""Out-of-service (disabled) arms: the semi-greedy and the exact allocator agree on what they
refuse (the same unreachable targets; when the disabled arms clash with each other, every
target, as a conflict), whatever the layout of the disabled arms, symmetric and degenerate
ones included; over HTTP and as a job the answer is a 200 with reasons.

The oracle is independent of both allocators: FCL's clearance between the disabled arms
(the allocators and their verifier use the vectorised capsule model)."""

from __future__ import annotations

import itertools
import math
import time
from typing import Any

import httpx
import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from models.collision import colliding_arm_pairs, fcl_clearance_mm
from models.instrument import default_instrument
from models.types import AllocationResult, PlaneTargets
from solvers.allocation import allocate

INST = default_instrument()
BUFFER_MM = INST.collision_buffer_mm
NEAR_MM = 1e-3  # clearances this close to the buffer are left to either model's rounding
PARK = (math.pi, 0.0)
# degenerate joint angles: the stops, the zone of avoidance (theta1 = theta2 = 0), park
ANGLES = st.one_of(
    st.sampled_from([(0.0, 0.0), PARK, (math.pi / 2, math.pi), (0.0, math.pi), (math.pi, math.pi),
                     (1.0, 0.5), (2.5, 5.5)]),
    st.tuples(st.floats(0.0, math.pi), st.floats(0.0, 2 * math.pi)),
)
POINTS = st.one_of(st.sampled_from([(0.0, 0.0), (1.0, 0.0), (60.0, 30.0), (-50.0, -60.0),
                                    (120.0, 0.0), (400.0, 0.0)]),
                   st.tuples(st.floats(-130.0, 130.0), st.floats(-130.0, 130.0)))


@st.composite
def layouts(draw: st.DrawFn) -> dict[int, tuple[float, float]]:
    """Disabled arms: a random set at random angles, or symmetric ones (opposite or
    neighbouring arms at the same angles)."""
    kind = draw(st.sampled_from(["random", "opposite", "neighbours"]))
    if kind == "random":
        arms = draw(st.lists(st.integers(0, 11), min_size=1, max_size=6, unique=True))
        return {k: draw(ANGLES) for k in arms}
    k = draw(st.integers(0, 11))
    q = draw(ANGLES)
    return {k: q, (k + (6 if kind == "opposite" else 1)) % 12: q}


def targets_of(points: list[tuple[float, float]]) -> PlaneTargets:
    xy = np.array(points, float).reshape(-1, 2)
    return PlaneTargets.from_lists([f"t{i}" for i in range(len(points))], xy[:, 0], xy[:, 1],
                                   np.arange(1, len(points) + 1, dtype=np.int64))


def clearances(fixed: dict[int, tuple[float, float]]) -> list[float]:
    return [fcl_clearance_mm(INST, a, fixed[a], b, fixed[b])
            for a, b in itertools.combinations(sorted(fixed), 2)]


def reasons(r: AllocationResult) -> dict[str, str]:
    return {u.target_id: u.reason for u in r.unallocated}


def check_configurations(r: AllocationResult, fixed: dict[int, tuple[float, float]]) -> None:
    """Every configuration keeps the disabled arms where they are and collides nowhere."""
    for c in r.configurations:
        q = np.array([(a.theta1_rad, a.theta2_rad) for a in c.assignments])
        assert colliding_arm_pairs(INST, q) == []
        for k, qk in fixed.items():
            assert c.assignments[k].kind == "fixed" and c.assignments[k].target_id is None
            assert tuple(q[k]) == qk


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(layouts(), st.lists(POINTS, min_size=1, max_size=4))
@example({0: (0.0, 0.0), 6: (0.0, 0.0)}, [(1.0, 0.0)])  # issue 41: opposite arms through the centre
@example({3: PARK, 4: PARK}, [(0.0, 0.0)])
@example({0: (2.0, 0.0), 6: (2.0, 0.0)}, [(0.0, 0.0)])  # parks of 1 and 7 blocked: blank sky
def test_both_methods_refuse_the_same_targets(fixed: dict[int, tuple[float, float]],
                                              points: list[tuple[float, float]]) -> None:
    targets = targets_of(points)
    out = {m: allocate(INST, targets, method=m, fixed=fixed, time_limit_s=10.0, seed=1)
           for m in ("ilp", "semigreedy")}
    for r in out.values():
        check_configurations(r, fixed)
    exact, heuristic = out["ilp"], out["semigreedy"]
    unreachable = {t for t, why in reasons(exact).items() if why == "unreachable"}
    assert {t for t, why in reasons(heuristic).items() if why == "unreachable"} == unreachable
    # the semi-greedy locations include the exact model's (plus blank-sky rest locations for
    # idle arms, where a disabled arm may block a neighbour's park): where the exact
    # allocator finds a configuration, so does it
    if exact.configurations:
        assert heuristic.configurations, (exact, heuristic)
    for r in out.values():
        if not r.configurations:
            assert set(reasons(r).values()) <= {"unreachable", "conflict"}
    gaps = clearances(fixed)
    if any(g < BUFFER_MM - NEAR_MM for g in gaps):
        # disabled arms closer than the buffer: nothing can be verified, every reachable
        # target is refused as a conflict, by both
        for r in out.values():
            assert r.configurations == ()
            assert reasons(r) == {t: "unreachable" if t in unreachable else "conflict"
                                  for t in targets.ids}


ISSUE_BODY: dict[str, Any] = {
    "targets": [{"id": "a", "x_mm": 1, "y_mm": 0, "priority": 1}], "method": "semigreedy",
    "disabled_arms": [{"arm": 0, "theta1_rad": 0, "theta2_rad": 0},
                      {"arm": 6, "theta1_rad": 0, "theta2_rad": 0}]}


def test_clashing_disabled_arms_over_http_and_as_a_job(live_server) -> None:
    """Issue 41: the body answered 503 with semigreedy; both methods answer 200 with the
    same reasons, and the job ends done with the endpoint's answer."""
    answers = {}
    for method in ("ilp", "semigreedy"):
        body = {**ISSUE_BODY, "method": method}
        r = httpx.post(live_server.url + "/v1/allocations", json=body, timeout=60)
        assert r.status_code == 200, r.text
        answers[method] = r.json()
        assert answers[method]["configurations"] == []
        assert answers[method]["unallocated"] == [{"target_id": "a", "reason": "conflict"}]
    r = httpx.post(live_server.url + "/v1/jobs", json={"kind": "allocation", "request": ISSUE_BODY},
                   timeout=60)
    assert r.status_code == 202, r.text
    job_id = r.json()["job_id"]
    deadline = time.monotonic() + 60
    while True:
        job = httpx.get(f"{live_server.url}/v1/jobs/{job_id}", timeout=10).json()
        if job["status"] not in ("queued", "running") or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert job["status"] == "done", job
    assert job["result"]["unallocated"] == answers["semigreedy"]["unallocated"]
