"""The park move limit: every location an arm may take is reached from park within the limit,
turning theta2 the positive way (models.incompatibility.build_assignments), through the
allocators, plan changes, the plan pipeline, the API and the CLI."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.errors import InputError
from models.incompatibility import BLANK, FIXED, PARK, build_assignments
from models.instrument import CONFIGURATION_TIME_GOAL_S, default_instrument
from models.kinematics import tip_fov
from models.sky import focal_mm_to_sky
from models.types import PlaneTargets
from planner.reassign import other_branches, take_out, try_place
from service import pointing_plans
from service.app import create_app
from service.cli import EXIT_INVALID_INPUT, build_parser, main
from service.schemas import PlanRequest
from service.settings import Settings
from solvers.allocation import allocate
from solvers.allocation.options import AllocationOptions
from solvers.sequencing.options import SequenceOptions

INS = default_instrument()
LIMIT_S = CONFIGURATION_TIME_GOAL_S
# three targets 0.5 mm inside the FOV edge, 120 degrees apart, where the 12-fold ring of arms
# reaches the rim only by turning J2 more than 216 degrees the positive way from park
RIM_DEG = (90.0, 210.0, 330.0)
RIM_R_MM = 124.5


def oracle_park_move_s(arm: int, theta1_rad: float, theta2_rad: float) -> float:
    """Independent restatement: time of the straight move from park, J2 counterclockwise."""
    a = INS.arms[arm]
    d1 = abs(theta1_rad - a.park_theta1_rad)
    d2 = math.fmod(theta2_rad - a.park_theta2_rad, 2 * math.pi)
    if d2 < 0:
        d2 += 2 * math.pi
    return max(d1 / a.joint1_speed_rad_s, d2 / a.joint2_speed_rad_s)


def field_xy(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Random points plus degenerate ones: the centre, the axes, mirror pairs, the rim."""
    r = 125.0 * np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    ring = np.radians(np.arange(0.0, 360.0, 15.0))
    x = np.r_[r * np.cos(a), 0.0, 124.9, -124.9, 0.0, 0.0, 123.0 * np.cos(ring), -123.0 * np.cos(ring)]
    y = np.r_[r * np.sin(a), 0.0, 0.0, 0.0, 124.9, -124.9, 123.0 * np.sin(ring), -123.0 * np.sin(ring)]
    return x, y


@pytest.mark.parametrize("limit_s", [LIMIT_S, 60.0])
def test_limit_keeps_exactly_the_locations_within_it(limit_s: float) -> None:
    x, y = field_xy(np.random.default_rng(5), 150)
    full = build_assignments(INS, x, y, blank_per_arm=6, seed=2)
    cut = build_assignments(INS, x, y, blank_per_arm=6, seed=2, park_move_limit_s=limit_s)
    a, b = full.assignments, cut.assignments
    t_s = np.array([oracle_park_move_s(int(k), t1, t2)
                    for k, t1, t2 in zip(a.arm, a.theta1_rad, a.theta2_rad, strict=True)])
    want = (a.target == PARK) | (a.target == FIXED) | (t_s <= limit_s)
    assert 0 < want.sum() < len(a)  # the limit removes some locations, keeps others
    keys = {(int(k), int(t), int(br), round(float(q1), 9), round(float(q2), 9))
            for k, t, br, q1, q2 in zip(b.arm, b.target, b.branch, b.theta1_rad, b.theta2_rad, strict=True)}
    want_keys = {(int(k), int(t), int(br), round(float(q1), 9), round(float(q2), 9))
                 for k, t, br, q1, q2, w in zip(a.arm, a.target, a.branch, a.theta1_rad, a.theta2_rad, want,
                                                strict=True) if w}
    assert keys == want_keys
    assert (np.diff(b.arm) >= 0).all() and b.arm_start[-1] == len(b)
    assert set(b.target[b.target == BLANK]) <= {BLANK}
    # the kept target locations still put the tip on their target
    real = b.target >= 0
    tips = tip_fov(INS, b.arm[real], b.theta1_rad[real], b.theta2_rad[real])
    np.testing.assert_allclose(tips, np.column_stack([x[b.target[real]], y[b.target[real]]]), atol=1e-6)
    # beyond the limit: reached without it, by no location within it
    reach_any = {int(t) for t in a.target[a.target >= 0]}
    reach_cut = {int(t) for t in b.target[b.target >= 0]}
    assert set(cut.beyond_limit.tolist()) == reach_any - reach_cut
    assert set(cut.unreachable.tolist()) == set(range(len(x))) - reach_cut
    assert full.beyond_limit.size == 0 and full.beyond_park_move_limit is None


def test_only_the_outer_rim_is_beyond_the_configuration_time() -> None:
    """With T_p = 120 s the targets lost are within 3 mm of the 125 mm FOV edge."""
    g = np.arange(-125.0, 125.01, 1.0)
    gx, gy = np.meshgrid(g, g)
    inside = np.hypot(gx, gy) <= 124.9
    x, y = gx[inside], gy[inside]
    cut = build_assignments(INS, x, y, park_move_limit_s=LIMIT_S)
    beyond = cut.beyond_limit
    assert beyond.size > 0
    assert np.hypot(x[beyond], y[beyond]).min() > 122.0
    assert build_assignments(INS, x, y).unreachable.size == 0


def rim_targets(centre: bool = True) -> PlaneTargets:
    a = np.radians(RIM_DEG)
    x, y = RIM_R_MM * np.cos(a), RIM_R_MM * np.sin(a)
    if centre:
        x, y = np.r_[x, 0.0], np.r_[y, 0.0]
    ids = [f"t{i}" for i in range(len(x))]
    return PlaneTargets(ids, x, y, np.full(len(x), 100, np.int64))


@pytest.mark.parametrize(("method", "solver"), [("ilp", "bnb"), ("ilp", "cpsat"), ("semigreedy", "bnb")])
def test_allocators_respect_the_limit_and_report_the_rim(method: str, solver: str) -> None:
    rng = np.random.default_rng(11)
    x, y = field_xy(rng, 60)
    rim = rim_targets(centre=False)
    targets = PlaneTargets([f"f{i}" for i in range(len(x))] + list(rim.ids), np.r_[x, rim.x_mm],
                           np.r_[y, rim.y_mm], np.r_[rng.choice([500, 100, 10, 1], len(x)), rim.priority])
    opts = AllocationOptions(sequence=SequenceOptions(park_move_limit_s=LIMIT_S))
    res = allocate(INS, targets, method=method, solver=solver, configurations="all", time_limit_s=20.0,
                   seed=3, options=opts)
    for c in res.configurations:
        for a in c.assignments:
            if a.kind != "park":
                assert oracle_park_move_s(a.arm, a.theta1_rad, a.theta2_rad) <= LIMIT_S + 1e-9, (c.index, a)
    beyond = {u.target_id for u in res.unallocated if u.reason == "beyond_park_move_limit"}
    want = {targets.ids[i] for i in build_assignments(INS, targets.x_mm, targets.y_mm,
                                                      park_move_limit_s=LIMIT_S).beyond_limit}
    assert set(rim.ids) <= beyond == want
    assert res.stats["n_beyond_park_move_limit"] == len(want)
    unlimited = allocate(INS, targets, method=method, solver=solver, configurations="all", time_limit_s=20.0,
                         seed=3)
    placed = {a.target_id for c in unlimited.configurations for a in c.assignments if a.kind == "target"}
    assert set(rim.ids) <= placed  # reachable without the limit


def test_plan_changes_keep_to_the_limit() -> None:
    """A target moved by plan_sequence goes only to an IK branch within the limit, and so does
    another branch of a blocking arm's target."""
    rng = np.random.default_rng(4)
    x, y = field_xy(rng, 40)
    rim = rim_targets(centre=False)
    targets = PlaneTargets([f"f{i}" for i in range(len(x))] + list(rim.ids), np.r_[x, rim.x_mm],
                           np.r_[y, rim.y_mm], np.full(len(x) + 3, 10, np.int64))
    res = allocate(INS, targets, method="semigreedy", configurations="all", time_limit_s=20.0, seed=1)
    where = {a.target_id: (c, a.arm) for c in res.configurations for a in c.assignments if a.kind == "target"}
    c, arm = where[rim.ids[0]]
    emptied, (placed,) = take_out(INS, c, [arm], {rim.ids[0]: 100})
    assert try_place(INS, emptied, placed, INS.collision_buffer_mm) is not None
    assert try_place(INS, emptied, placed, INS.collision_buffer_mm, park_move_limit_s=LIMIT_S) is None
    checked = 0
    for c in res.configurations:
        for a in c.assignments:
            if a.kind != "target":
                continue
            free = other_branches(INS, c, a.arm, INS.collision_buffer_mm)
            kept = other_branches(INS, c, a.arm, INS.collision_buffer_mm, park_move_limit_s=60.0)
            q = [(x.assignments[a.arm].theta1_rad, x.assignments[a.arm].theta2_rad) for x in free]
            want = [qq for qq in q if oracle_park_move_s(a.arm, *qq) <= 60.0]
            assert [(x.assignments[a.arm].theta1_rad, x.assignments[a.arm].theta2_rad) for x in kept] == want
            checked += len(q) > len(want)
    assert checked > 0  # some other branch was beyond the limit


def test_sequence_option_is_checked() -> None:
    with pytest.raises(InputError) as e:
        SequenceOptions(park_move_limit_s=-1.0)
    assert e.value.field == "park_move_limit_s"


def sky_body(limit: object = "default", mode: str = "complete-linkage") -> dict:
    """The rim targets as a plan request; complete linkage keeps the requested angle (0), where
    the park move limit leaves them out."""
    t = rim_targets()
    ra, dec = focal_mm_to_sky(t.x_mm, t.y_mm, 150.0, 20.0, INS.plate_scale_arcsec_per_mm)
    body = {"targets": [{"id": i, "ra_deg": float(a), "dec_deg": float(d), "priority": 100}
                        for i, a, d in zip(t.ids, ra, dec, strict=True)],
            "seed": 1, "time_limit_s": 20, "segmentation_mode": mode}
    if limit != "default":
        body["park_move_limit_s"] = limit
    return body


def unallocated_reasons(out: dict) -> dict[str, str]:
    return {u["target_id"]: u["reason"] for p in out["pointings"] for u in p["unallocated"]}


def test_plan_api_default_limit_and_null(tmp_path) -> None:
    app = create_app(Settings(job_db=tmp_path / "j.db"))
    with TestClient(app) as c:
        default = c.post("/v1/plans", json=sky_body())
        unlimited = c.post("/v1/plans", json=sky_body(None))
        bad = c.post("/v1/plans", json=sky_body(-5))
        text = c.post("/v1/plans", json=sky_body("abc"))
    assert default.status_code == 200, default.text
    assert unlimited.status_code == 200, unlimited.text
    d, u = default.json(), unlimited.json()
    assert len(d["pointings"]) == 1
    assert unallocated_reasons(d) == {"t0": "beyond_park_move_limit", "t1": "beyond_park_move_limit",
                                      "t2": "beyond_park_move_limit"}
    assert unallocated_reasons(u) == {}
    assert d["executable"] is True
    for r in (bad, text):
        assert r.status_code == 422
        assert "park_move_limit_s" in r.text


def test_the_default_mode_turns_the_pointing_to_reach_rim_targets(tmp_path) -> None:
    """The default segmentation (the programme optimiser) searches the position angle: the rim
    targets the requested angle leaves beyond the park move limit are reached at another
    angle, within the same limit (issue 38: no target lost where some angle reaches it)."""
    app = create_app(Settings(job_db=tmp_path / "j.db"))
    body = sky_body(mode="fewest-exposures")
    with TestClient(app) as c:
        r = c.post("/v1/plans", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert unallocated_reasons(out) == {}
    assert out["executable"] is True
    assert all(p["position_angle_deg"] not in (None, 0.0) for p in out["pointings"])
    # the request without a mode is this request: the optimiser is the default
    default = PlanRequest.model_validate({k: v for k, v in body.items() if k != "segmentation_mode"})
    assert pointing_plans.plan_mode(default) == body["segmentation_mode"]


def test_cli_park_move_limit_flags(monkeypatch, tmp_path) -> None:
    p = build_parser()
    assert p.parse_args(["plan", "x.csv", "--out", "o"]).park_move_limit == LIMIT_S
    assert p.parse_args(["plan", "x.csv", "--out", "o", "--no-park-move-limit"]).no_park_move_limit
    with pytest.raises(SystemExit):
        p.parse_args(["plan", "x.csv", "--out", "o", "--no-park-move-limit", "--park-move-limit", "90"])
    csv = tmp_path / "t.csv"
    csv.write_text("id,ra_deg,dec_deg,priority\na,150.0,20.0,5\n")
    rc = main(["plan", str(csv), "--out", str(tmp_path / "o"), "--park-move-limit", "-3", "--quiet"])
    assert rc == EXIT_INVALID_INPUT
