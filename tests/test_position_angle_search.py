"""The position angle search of a plan (issue 39, item 2): ``position_angle_deg: "auto"``, its
range and step, through the library, the API, the JSON schema and the CLI.

The field: three targets on the FOV rim whose arms reach them from park only beyond the park
move limit at PA 0, but within it at some other angle, and four inner targets. The oracle
counts the targets lost at an angle with the models' reachability directly
(:func:`models.incompatibility.build_assignments`), not with the search's own code."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.incompatibility import build_assignments
from models.instrument import CONFIGURATION_TIME_GOAL_S, default_instrument
from models.sky import focal_mm_to_sky, sky_to_focal_mm
from service.app import create_app
from service.cli import EXIT_INVALID_INPUT, main
from service.response_schemas import PlanResponse
from service.schemas import PlanRequest
from service.settings import Settings
from solvers.programme.angle import DEFAULT_STEP_DEG, AngleSearch, choose_angle, reach_exposures

INS = default_instrument()
SCALE = INS.plate_scale_arcsec_per_mm
CENTRE = (150.0, 20.0)
RIM_MM = 124.0
RIM_IDS = ("r30", "r150", "r270")
LIMIT_S = CONFIGURATION_TIME_GOAL_S


def field_targets() -> list[dict]:
    """Three rim targets at 30, 150 and 270 deg about the centre (out of reach within the park
    move limit at PA 0) and four inner targets, priorities 1..7."""
    x = [RIM_MM * math.cos(math.radians(a)) for a in (30, 150, 270)] + [20.0, -30.0, 0.0, 40.0]
    y = [RIM_MM * math.sin(math.radians(a)) for a in (30, 150, 270)] + [10.0, 40.0, -50.0, -20.0]
    ra, dec = focal_mm_to_sky(np.array(x), np.array(y), *CENTRE, SCALE, 0.0)
    ids = [*RIM_IDS, "i1", "i2", "i3", "i4"]
    return [{"id": i, "ra_deg": float(r), "dec_deg": float(d), "priority": k + 1}
            for k, (i, r, d) in enumerate(zip(ids, ra, dec, strict=True))]


def lost_at(targets: list[dict], centre: tuple[float, float], pa_deg: float) -> set[str]:
    """Oracle: the targets no arm reaches within the park move limit, about ``centre`` at
    ``pa_deg``."""
    x, y = sky_to_focal_mm(np.array([t["ra_deg"] for t in targets]), np.array([t["dec_deg"] for t in targets]),
                           centre[0], centre[1], SCALE, pa_deg)
    reach = build_assignments(INS, np.asarray(x, float), np.asarray(y, float), park_move_limit_s=LIMIT_S,
                              include_park=False)
    reached = {int(k) for k in reach.assignments.target if k >= 0}
    return {t["id"] for k, t in enumerate(targets) if k not in reached}


def body(**extra) -> dict:
    return {"targets": field_targets(), "seed": 1, "time_limit_s": 30,
            "segmentation_mode": "complete-linkage", **extra}


def lost_reasons(out: dict) -> dict[str, str]:
    return {u["target_id"]: u["reason"] for p in out["pointings"] for u in p["unallocated"]}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app(Settings(job_db=tmp_path_factory.mktemp("pa") / "j.db"))
    with TestClient(app) as c:
        yield c


# ------------------------------------------------------------------------ library


def test_the_angles_of_a_search() -> None:
    assert AngleSearch().angles() == tuple(float(a) for a in np.arange(0.0, 360.0, DEFAULT_STEP_DEG))
    assert AngleSearch((-4.0, 4.0), 5.0).angles() == (-4.0, 1.0, 4.0)  # both ends included
    assert AngleSearch((0.0, 360.0), 90.0).angles() == (0.0, 90.0, 180.0, 270.0)  # 360 is 0
    assert AngleSearch((10.0, 10.0), 5.0).angles() == (10.0,)


def test_the_search_loses_none_where_brute_force_finds_an_angle_that_reaches_all() -> None:
    t = field_targets()
    assert lost_at(t, CENTRE, 0.0) == set(RIM_IDS)  # the field is what it claims to be
    search = AngleSearch()
    oracle = {a: len(lost_at(t, CENTRE, a)) for a in search.angles()}
    assert min(oracle.values()) == 0
    c = choose_angle(INS, [x["ra_deg"] for x in t], [x["dec_deg"] for x in t], [x["priority"] for x in t],
                     CENTRE, search, LIMIT_S)
    assert oracle[c.chosen_deg] == 0
    assert c.tried_deg == search.angles()
    assert {s.angle_deg: s.lost for s in c.scores} == oracle
    # of the angles that lose none, the search takes the one nearest 0 (then the smaller)
    exposures = {s.angle_deg: s.exposures for s in c.scores}
    best = [a for a in oracle if oracle[a] == 0 and exposures[a] == min(exposures[b] for b in oracle if oracle[b] == 0)]
    assert c.chosen_deg == min(best, key=lambda a: (min(a % 360, 360 - a % 360), a))
    assert "0 of 7 targets lost" in c.objective
    # deterministic: the same field gives the same search
    again = choose_angle(INS, [x["ra_deg"] for x in t], [x["dec_deg"] for x in t], [x["priority"] for x in t],
                         CENTRE, search, LIMIT_S)
    assert again == c


def test_when_no_angle_reaches_both_the_higher_priority_is_reached() -> None:
    """Two rim targets (at 30 and 45 deg about the centre) whose reaching angles of a 15 deg grid
    never meet: every angle loses one, so the priority decides, whichever target holds it."""
    search = AngleSearch(None, 15.0)
    for prio_a, prio_b in ((1, 10), (10, 1)):
        t = []
        for name, phi, prio in (("A", 30.0, prio_a), ("B", 45.0, prio_b)):
            ra, dec = focal_mm_to_sky(np.array([RIM_MM * math.cos(math.radians(phi))]),
                                      np.array([RIM_MM * math.sin(math.radians(phi))]), *CENTRE, SCALE, 0.0)
            t.append({"id": name, "ra_deg": float(ra[0]), "dec_deg": float(dec[0]), "priority": prio})
        assert all(len(lost_at(t, CENTRE, a)) == 1 for a in search.angles())  # the oracle's premise
        c = choose_angle(INS, [x["ra_deg"] for x in t], [x["dec_deg"] for x in t], [x["priority"] for x in t],
                         CENTRE, search, LIMIT_S)
        higher = "A" if prio_a > prio_b else "B"
        assert higher not in lost_at(t, CENTRE, c.chosen_deg)


def test_ties_go_to_the_range_centre_then_the_smaller_angle() -> None:
    """One target at the centre: every angle reaches it with every arm, so only the last two
    keys decide."""
    def chosen(search: AngleSearch) -> float:
        return choose_angle(INS, [CENTRE[0]], [CENTRE[1]], [5], CENTRE, search, LIMIT_S).chosen_deg

    assert chosen(AngleSearch()) == 0.0
    assert chosen(AngleSearch((10.0, 50.0), 10.0)) == 30.0
    assert chosen(AngleSearch((-10.0, 10.0), 20.0)) == -10.0


def test_reach_exposures_bound() -> None:
    every = (1 << 12) - 1
    assert reach_exposures(np.full(24, every, np.int64), 12) == 2  # 24 targets over 12 arms
    assert reach_exposures(np.full(25, every, np.int64), 12) == 3
    assert reach_exposures(np.array([1, 1, 1, every], np.int64), 12) == 3  # only arm 0 reaches three
    assert reach_exposures(np.array([0b11] * 5, np.int64), 12) == 3  # two arms, five targets
    assert reach_exposures(np.array([0, 0], np.int64), 12) == 0  # nobody reaches them


def test_a_bad_search_names_its_field() -> None:
    from models.errors import InputError

    with pytest.raises(InputError, match="position_angle_range_deg"):
        AngleSearch((30.0, -30.0))
    with pytest.raises(InputError, match="position_angle_step_deg"):
        AngleSearch(None, 0.0)


# ---------------------------------------------------------------------------- API


def test_auto_reaches_the_rim_targets_a_fixed_angle_loses(client) -> None:
    fixed = client.post("/v1/plans", json=body())
    auto = client.post("/v1/plans", json=body(position_angle_deg="auto"))
    assert fixed.status_code == auto.status_code == 200, auto.text
    assert lost_reasons(fixed.json()) == {i: "beyond_park_move_limit" for i in RIM_IDS}
    out = auto.json()
    PlanResponse.model_validate(out)
    assert lost_reasons(out) == {}
    assert out["executable"] is True
    for p in out["pointings"]:
        s = p["position_angle_search"]
        assert s["chosen_deg"] == p["position_angle_deg"] and p["position_angle_deg"] in s["tried_deg"]
        assert len(s["tried_deg"]) == 360 / DEFAULT_STEP_DEG
        members = [t for t in field_targets() if t["id"] in p["target_ids"]]
        assert lost_at(members, (p["ra_deg"], p["dec_deg"]), p["position_angle_deg"]) == set()
        assert "fewest targets out of every arm's reach" in s["objective"]
    # a number is used as given, and reported as the angle used
    assert [(p["position_angle_deg"], p["position_angle_search"]) for p in fixed.json()["pointings"]] == [(0.0, None)]


def test_a_range_without_a_reaching_angle_loses_them_inside_the_range(client) -> None:
    r = client.post("/v1/plans", json=body(position_angle_deg="auto", position_angle_range_deg=[-4, 4],
                                           position_angle_step_deg=2))
    assert r.status_code == 200, r.text
    out = r.json()
    for p in out["pointings"]:
        assert -4.0 <= p["position_angle_deg"] <= 4.0
        tried = p["position_angle_search"]["tried_deg"]
        # the grid, then (every grid angle losing them) every 0.5 deg between, inside the range
        assert tried[:5] == [-4.0, -2.0, 0.0, 2.0, 4.0]
        assert sorted(tried) == [a / 2 for a in range(-8, 9)]
        members = [t for t in field_targets() if t["id"] in p["target_ids"]]
        fewest = min(len(lost_at(members, (p["ra_deg"], p["dec_deg"]), a)) for a in (-4, -2, 0, 2, 4))
        assert len(lost_at(members, (p["ra_deg"], p["dec_deg"]), p["position_angle_deg"])) == fewest > 0
    assert set(lost_reasons(out)) == set(RIM_IDS)


def test_the_default_mode_searches_auto_too(client) -> None:
    r = client.post("/v1/plans", json=body(position_angle_deg="auto", position_angle_range_deg=[-60, 60],
                                           segmentation_mode="fewest-exposures"))
    assert r.status_code == 200, r.text
    out = r.json()
    assert lost_reasons(out) == {}
    for p in out["pointings"]:
        assert -60.0 <= p["position_angle_deg"] <= 60.0
        assert p["position_angle_search"]["chosen_deg"] == p["position_angle_deg"]
        members = [t for t in field_targets() if t["id"] in p["target_ids"]]
        assert lost_at(members, (p["ra_deg"], p["dec_deg"]), p["position_angle_deg"]) == set()


@pytest.mark.parametrize(("extra", "field"), [
    ({"position_angle_deg": "sideways"}, "position_angle_deg"),
    ({"position_angle_deg": 400}, "position_angle_deg"),
    ({"position_angle_deg": 10, "position_angle_range_deg": [-30, 30]}, "position_angle_range_deg"),
    ({"position_angle_range_deg": [-30, 30]}, "position_angle_range_deg"),  # the default is a number
    ({"position_angle_deg": "auto", "position_angle_range_deg": [30, -30]}, "position_angle_range_deg"),
    ({"position_angle_deg": "auto", "position_angle_range_deg": [0, 400]}, "position_angle_range_deg"),
    ({"position_angle_deg": "auto", "position_angle_step_deg": 0}, "position_angle_step_deg"),
    ({"position_angle_deg": 5, "position_angle_step_deg": 5}, "position_angle_step_deg"),
])
def test_bad_angles_are_a_422_naming_the_field(client, extra, field) -> None:
    r = client.post("/v1/plans", json=body(**extra))
    assert r.status_code == 422, r.text
    assert any(e["loc"][:2] == ["body", field] for e in r.json()["detail"]), r.text


def test_the_json_schema_takes_auto_and_refuses_sideways(client) -> None:
    doc = client.get("/openapi.json").json()
    for schema in (PlanRequest.model_json_schema()["properties"]["position_angle_deg"],
                   doc["components"]["schemas"]["PlanRequest"]["properties"]["position_angle_deg"]):
        jsonschema.validate("auto", schema)
        jsonschema.validate(-15.5, schema)
        for bad in ("sideways", 361, None):
            with pytest.raises(jsonschema.ValidationError):
                jsonschema.validate(bad, schema)


def test_the_json_schema_states_that_a_range_or_a_step_needs_auto() -> None:
    schema = PlanRequest.model_json_schema()
    targets = field_targets()
    for good in ({}, {"position_angle_deg": 15}, {"position_angle_deg": "auto", "position_angle_range_deg": [-30, 30],
                                                   "position_angle_step_deg": 10}):
        jsonschema.validate({"targets": targets, **good}, schema)
        PlanRequest.model_validate({"targets": targets, **good})
    for bad in ({"position_angle_range_deg": [-30, 30]}, {"position_angle_deg": 15, "position_angle_step_deg": 10}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate({"targets": targets, **bad}, schema)


# ---------------------------------------------------------------------------- CLI


def write_csv(path: Path) -> Path:
    rows = ["id,ra_deg,dec_deg,priority"] + [f"{t['id']},{t['ra_deg']!r},{t['dec_deg']!r},{t['priority']}"
                                              for t in field_targets()]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_cli_plans_auto_and_prints_each_angle(tmp_path, capsys) -> None:
    src = write_csv(tmp_path / "rim.csv")
    code = main(["plan", str(src), "--out", str(tmp_path / "o"), "--seed", "1", "--time-limit", "30", "--quiet",
                 "--segmentation-mode", "complete-linkage", "--position-angle", "auto",
                 "--position-angle-range", "-60", "60", "--position-angle-step", "10"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    result = json.loads((tmp_path / "o" / "plan.json").read_text())
    assert lost_reasons(result) == {}
    for p in result["pointings"]:
        assert p["position_angle_search"]["tried_deg"] == [float(a) for a in range(-60, 61, 10)]
        assert f"PA {p['position_angle_deg']:g}° (auto)" in printed


def test_cli_refuses_sideways_naming_the_field(tmp_path, capsys) -> None:
    src = write_csv(tmp_path / "rim.csv")
    code = main(["plan", str(src), "--out", str(tmp_path / "o"), "--quiet", "--position-angle", "sideways"])
    assert code == EXIT_INVALID_INPUT
    assert "position_angle_deg" in capsys.readouterr().err
