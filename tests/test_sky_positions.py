"""Sky positions for spare arms (issue 39 item 4): blank sky clear of every programme target,
the astronomer's sky positions, the kinds target/sky/park through the API, the CLI's
assignments.csv and its pictures.

Oracles independent of planner.sky: astropy's separations on the sphere, forward kinematics,
FCL's clearances and brute-force focal-plane distances."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from fastapi.testclient import TestClient

import planner.pointing as pointing
from models.budget import Budget
from models.collision import fcl_configuration_collisions
from models.instrument import default_instrument
from models.kinematics import tip_fov
from models.sky import focal_mm_to_sky, sky_to_focal_mm
from models.types import ArmAssignment, Configuration
from planner.known_legs import KnownLegs
from planner.pointing import PointingOptions, _sequence_with_sky
from planner.shares import SHARES
from planner.sky import arm_sky, place_sky, sky_field
from service.app import create_app
from service.cli import main
from service.response_schemas import PlanResponse
from service.settings import Settings

INST = default_instrument()
RA0, DEC0 = 150.0, 20.0
#: two targets a few arcsec from the centre (offsets in arcsec, East and North)
TWO = [("a", 10.0, 5.0, 10), ("b", -20.0, -30.0, 5)]


def two_targets() -> list[dict]:
    cos = np.cos(np.radians(DEC0))
    return [{"id": i, "ra_deg": float(RA0 + de / 3600.0 / cos), "dec_deg": float(DEC0 + dn / 3600.0),
             "priority": p}
            for i, de, dn, p in TWO]


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app(Settings(job_db=tmp_path_factory.mktemp("sky") / "j.db"))
    with TestClient(app) as c:
        yield c


def plan(client, **body) -> dict:
    r = client.post("/v1/plans", json={"targets": two_targets(), "seed": 1, "time_limit_s": 60, **body})
    assert r.status_code == 200, r.text
    PlanResponse.model_validate(r.json())
    return r.json()


def separations_arcsec(ra, dec, targets) -> np.ndarray:
    """Astropy's separation of (ra, dec) from every target, arcsec."""
    t = SkyCoord([x["ra_deg"] for x in targets] * u.deg, [x["dec_deg"] for x in targets] * u.deg)
    return SkyCoord(ra * u.deg, dec * u.deg).separation(t).arcsec


def check_verified(conf: dict) -> None:
    """Every arm's tip is where its angles put it, and FCL finds no two arms within the buffer."""
    q = np.array([[a["theta1_rad"], a["theta2_rad"]] for a in conf["assignments"]])
    for a in conf["assignments"]:
        tip = tip_fov(INST, a["arm"], a["theta1_rad"], a["theta2_rad"])
        assert np.hypot(tip[0] - a["x_mm"], tip[1] - a["y_mm"]) < 1e-6
    assert fcl_configuration_collisions(INST, q) == []


# ------------------------------------------------------------------ blank sky, via the API


def test_two_targets_ten_spare_arms_on_blank_sky(client) -> None:
    out = plan(client)
    assert out["executable"], out["reasons"]
    targets = two_targets()
    confs = [c for p in out["pointings"] for c in p["configurations"]]
    assert confs
    for c in confs:
        kinds = [a["kind"] for a in c["assignments"]]
        assert kinds.count("target") == 2 and kinds.count("sky") == 10, kinds
        assert c["stats"]["sky_arms"] == 10
        check_verified(c)
        for a in c["assignments"]:
            if a["kind"] != "sky":
                assert a["sky_ra_deg"] is None and a["sky_dec_deg"] is None
                continue
            assert a["target_id"] is None
            # at least the default radius (6 arcsec) from every target, on the sphere
            assert separations_arcsec(a["sky_ra_deg"], a["sky_dec_deg"], targets).min() >= 6.0 - 1e-6
            # the RA/Dec is where the tip points: back through the projection onto the tip
            p = next(p for p in out["pointings"] if c in p["configurations"])
            x, y = sky_to_focal_mm(a["sky_ra_deg"], a["sky_dec_deg"], p["ra_deg"], p["dec_deg"],
                                   INST.plate_scale_arcsec_per_mm, p["position_angle_deg"] or 0.0)
            assert np.hypot(x - a["x_mm"], y - a["y_mm"]) < 1e-6
            assert np.hypot(a["x_mm"], a["y_mm"]) <= INST.fov_radius_mm
    assert out["stats"]["sky_arms"] == 10 * len(confs)
    assert all(m["status"] == "ok" for p in out["pointings"] for m in p["motions"])


def test_a_large_radius_keeps_spare_arms_farther(client) -> None:
    """With a radius of 100 arcsec (83 mm) the sky arms keep that distance from both targets
    (the sky left is the FOV rim; arms that find none there rest at park)."""
    out = plan(client, sky_radius_arcsec=100)
    assert out["executable"], out["reasons"]
    for p in out["pointings"]:
        for c in p["configurations"]:
            check_verified(c)
            kinds = {a["kind"] for a in c["assignments"]}
            assert kinds <= {"target", "sky", "park"}
            sky = [a for a in c["assignments"] if a["kind"] == "sky"]
            assert sky, "some arm finds sky on the rim"
            for a in sky:
                assert separations_arcsec(a["sky_ra_deg"], a["sky_dec_deg"], two_targets()).min() >= 100 - 1e-6


# ------------------------------------------------------------ the astronomer's positions


def ring_positions(radius_mm: float, n: int) -> list[dict]:
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ra, dec = focal_mm_to_sky(radius_mm * np.cos(ang), radius_mm * np.sin(ang), RA0, DEC0,
                              INST.plate_scale_arcsec_per_mm, 0.0)
    return [{"ra_deg": float(r), "dec_deg": float(d)} for r, d in zip(ra, dec, strict=True)]


def test_sky_positions_are_used_and_those_near_a_target_are_not(client) -> None:
    given = ring_positions(112.0, 36)
    near = two_targets()[0]
    given.append({"ra_deg": near["ra_deg"] + 2.0 / 3600.0, "dec_deg": near["dec_deg"]})
    out = plan(client, sky_positions=given)
    assert out["executable"], out["reasons"]
    assert any("sky_positions[36]" in n and "target a" in n for n in out["notices"]), out["notices"]
    g = SkyCoord([s["ra_deg"] for s in given] * u.deg, [s["dec_deg"] for s in given] * u.deg)
    on_given = 0
    for p in out["pointings"]:
        assert p["stats"]["sky"]["positions_given"] == 37
        for c in p["configurations"]:
            check_verified(c)
            used = []
            for a in c["assignments"]:
                if a["kind"] != "sky":
                    continue
                sep = SkyCoord(a["sky_ra_deg"] * u.deg, a["sky_dec_deg"] * u.deg).separation(g).arcsec
                k = int(np.argmin(sep))
                assert not (k == 36 and sep[k] < 1e-3), "the position 2 arcsec from a target is used"
                if sep[k] < 1e-3:  # on a given position (to 1 mas)
                    on_given += 1
                    used.append(k)
            assert len(used) == len(set(used)), "two arms on one sky position"
    assert on_given >= 6, on_given


# ------------------------------------------------------------------ domain: programme-wide


def test_blank_sky_avoids_every_programme_target_not_only_members() -> None:
    """Targets of other pointings (here: on every arm's park tip, where sky rests would go
    first, and 200 random ones) are avoided by the radius, in the focal plane."""
    rng = np.random.default_rng(3)
    park_tips = np.array([tip_fov(INST, k, *INST.park_configuration[k]) for k in range(12)])
    others = np.vstack([park_tips, rng.uniform(-120, 120, (200, 2))])
    ra, dec = focal_mm_to_sky(others[:, 0], others[:, 1], RA0, DEC0, INST.plate_scale_arcsec_per_mm, 0.0)
    radius_arcsec = 12.0
    sky = sky_field(INST, RA0, DEC0, 0.0, ra, dec, [], [], radius_arcsec)
    asg = tuple(ArmAssignment(k, "park", *INST.park_configuration[k],
                              *tip_fov(INST, k, *INST.park_configuration[k])) for k in range(12))
    conf = Configuration(0, asg, 0, 0, "optimal")
    placed = place_sky(INST, [conf], sky, park_move_limit_s=120.0)[0]
    assert fcl_configuration_collisions(INST, placed.q) == []
    n_sky = 0
    for a in placed.assignments:
        rest = arm_sky(INST, a, sky)
        if rest is None:
            assert a.kind == "park"
            continue
        assert rest.kind == "sky"
        n_sky += 1
        d_mm = np.hypot(others[:, 0] - a.x_mm, others[:, 1] - a.y_mm).min()
        assert d_mm * INST.plate_scale_arcsec_per_mm >= radius_arcsec - 1e-6
    assert n_sky == placed.stats["sky_arms"] >= 6


@pytest.mark.parametrize("seed", range(4))
def test_the_first_fitting_rest_is_the_per_pair_scans(seed: int) -> None:
    """planner.sky._fitting (every other arm at once) picks the candidate a scan of the arms
    one pair at a time picks, on random configurations with candidates near other arms."""
    from models.collision import arm_pair_clearance_mm
    from models.kinematics import inverse_fov
    from planner.sky import CLEAR_MM, _fitting

    rng = np.random.default_rng(seed)
    q = np.array(INST.park_configuration, float)
    for k in range(12):  # each arm on a random reachable point
        for _ in range(20):
            ik = inverse_fov(INST, k, *rng.uniform(-110, 110, (2, 1)))
            if ik.valid.any():
                r, c = np.argwhere(ik.valid)[0]
                trial = q.copy()
                trial[k] = (ik.theta1_rad[r, c], ik.theta2_rad[r, c])
                if not fcl_configuration_collisions(INST, trial):
                    q = trial
                    break
    for arm in range(12):
        pts = rng.uniform(-120, 120, (300, 2))
        ik = inverse_fov(INST, arm, pts[:, 0], pts[:, 1])
        rows, cols = np.nonzero(ik.valid)
        cand = np.column_stack([ik.theta1_rad[rows, cols], ik.theta2_rad[rows, cols]])
        ok = np.ones(len(cand), bool)
        for j in range(12):
            if j != arm:
                ok &= arm_pair_clearance_mm(INST, arm, cand, j, q[j]) >= INST.collision_buffer_mm + CLEAR_MM
        want = int(np.flatnonzero(ok)[0]) if ok.any() else None
        assert _fitting(INST, arm, cand, q, INST.collision_buffer_mm) == want
        if want is not None:  # and FCL agrees the rest clears every arm
            placed = q.copy()
            placed[arm] = cand[want]
            assert not [p for p in fcl_configuration_collisions(INST, placed) if arm in p]


# ------------------------------------------------------------------------ bad input


@pytest.mark.parametrize("body, loc", [
    ({"sky_radius_arcsec": -1}, ["body", "sky_radius_arcsec"]),
    ({"sky_radius_arcsec": 1e6}, ["body", "sky_radius_arcsec"]),
    ({"sky_radius_arcsec": "wide"}, ["body", "sky_radius_arcsec"]),
    ({"sky_positions": [{"ra_deg": 10.0, "dec_deg": 95.0}]}, ["body", "sky_positions", 0, "dec_deg"]),
    ({"sky_positions": [{"ra_deg": 10.0}]}, ["body", "sky_positions", 0, "dec_deg"]),
])
def test_bad_sky_input_is_a_422_naming_the_field(client, body, loc) -> None:
    r = client.post("/v1/plans", json={"targets": two_targets(), **body})
    assert r.status_code == 422, r.text
    assert any(e["loc"] == loc for e in r.json()["detail"]), r.json()


# ----------------------------------------------------------------------------- the CLI


def test_cli_assignments_csv_kinds_and_sky_legend(tmp_path: Path, capsys, monkeypatch) -> None:
    from service import plots

    legends: list[list[str]] = []
    figure = plots.configuration_figure

    def recording(*args, **kwargs):
        fig = figure(*args, **kwargs)
        legends.append([t.get_text() for lg in fig.legends for t in lg.get_texts()])
        return fig

    monkeypatch.setattr(plots, "configuration_figure", recording)
    src = tmp_path / "two.csv"
    src.write_text("id,ra,dec,priority\n" + "".join(
        f"{t['id']},{t['ra_deg']!r},{t['dec_deg']!r},{t['priority']}\n" for t in two_targets()))
    sky = tmp_path / "sky.csv"
    sky.write_text("ra,dec\n" + "".join(f"{s['ra_deg']!r},{s['dec_deg']!r}\n" for s in ring_positions(112.0, 24)))
    out = tmp_path / "out"
    code = main(["plan", str(src), "--out", str(out), "--sky", str(sky), "--seed", "1", "--time-limit", "60",
                 "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert "arms on sky" in capsys.readouterr().out
    result = json.loads((out / "plan.json").read_text())
    rows = list(csv.DictReader((out / "assignments.csv").open()))
    expect = [(p["id"], f"c{c['index'] + 1}", str(a["arm"]), a["kind"], a["target_id"] or "")
              for p in result["pointings"] for c in p["configurations"] for a in c["assignments"]]
    assert [(r["pointing"], r["configuration"], r["arm"], r["kind"], r["target_id"]) for r in rows] == expect
    kinds = [r["kind"] for r in rows]
    assert kinds.count("target") == 2 * len(legends) and kinds.count("sky") == 10 * len(legends)
    for r in rows:
        assert (r["sky_ra_deg"] != "") == (r["kind"] == "sky")
        if r["kind"] == "sky":
            assert separations_arcsec(float(r["sky_ra_deg"]), float(r["sky_dec_deg"]), two_targets()).min() >= 6 - 1e-6
    assert legends and all("sky position (spare arm)" in lg and "arm on sky" in lg for lg in legends), legends


def test_cli_bad_sky_file_and_radius(tmp_path: Path, capsys) -> None:
    src = tmp_path / "two.csv"
    src.write_text("id,ra,dec,priority\n" + "".join(
        f"{t['id']},{t['ra_deg']!r},{t['dec_deg']!r},{t['priority']}\n" for t in two_targets()))
    bad = tmp_path / "sky.csv"
    bad.write_text("ra,dec\n150.0,north\n")
    assert main(["plan", str(src), "--out", str(tmp_path / "o"), "--sky", str(bad), "--quiet"]) == 2
    assert "row 2: Dec 'north' is not a number" in capsys.readouterr().err
    assert main(["plan", str(src), "--out", str(tmp_path / "o"), "--sky-radius", "-3", "--quiet"]) == 2
    assert "sky_radius_arcsec" in capsys.readouterr().err


def _sequencing(monkeypatch, outcomes: dict[str, tuple[bool, int]]) -> list[str]:
    """planner.pointing._sequence replaced by a stand-in that plans the configurations named
    "sky" or "plain" as ``outcomes`` says (executable, targets dropped), recording the order."""
    calls: list[str] = []

    def fake(inst, configs, targets, options, budget, progress):
        name = configs[0].name
        calls.append(name)
        ok, dropped = outcomes[name]
        return SimpleNamespace(executable=ok, dropped=(None,) * dropped, name=name), None

    monkeypatch.setattr(pointing, "_sequence", fake)
    return calls


@pytest.mark.parametrize(("sky", "plain", "order", "kept"), [
    ((True, 0), (True, 0), ["sky"], "sky"),  # the sky legs planned and kept: no plain legs
    ((False, 0), (True, 0), ["sky", "plain"], "plain"),  # a sky leg failed: the plain legs
    ((True, 2), (True, 1), ["sky", "plain"], "plain"),  # the sky legs dropped more targets
    ((True, 1), (True, 1), ["sky", "plain"], "sky"),  # as many dropped: the arms stay on sky
    ((True, 1), (False, 0), ["sky", "plain"], "sky"),  # the plain legs failed
])
def test_the_sky_legs_are_planned_first_and_the_plain_ones_only_when_they_fall_short(
        monkeypatch, sky, plain, order, kept) -> None:
    calls = _sequencing(monkeypatch, {"sky": sky, "plain": plain})
    plain_a = SimpleNamespace(configurations=(SimpleNamespace(name="plain", q=np.zeros((12, 2))),))
    sky_a = SimpleNamespace(configurations=(SimpleNamespace(name="sky", q=np.ones((12, 2))),))
    result, seq, err = _sequence_with_sky(INST, plain_a, sky_a, None, PointingOptions(), Budget.start(10.0),
                                          lambda *_: None, SHARES)
    assert calls == order and err is None
    assert result is (sky_a if kept == "sky" else plain_a) and seq.name == kept


@pytest.mark.parametrize(("sky_ok", "kept"), [(True, "sky"), (False, "plain")])
def test_a_pointing_planned_again_from_known_legs_plans_its_plain_legs_first(monkeypatch, sky_ok,
                                                                              kept) -> None:
    """A pointing planned again from an earlier plan (planner.known_legs: a later round's
    retry, the consolidation) plans its plain legs first, and the sky legs after them."""
    calls = _sequencing(monkeypatch, {"sky": (sky_ok, 0), "plain": (True, 0)})
    plain_a = SimpleNamespace(configurations=(SimpleNamespace(name="plain", q=np.zeros((12, 2))),))
    sky_a = SimpleNamespace(configurations=(SimpleNamespace(name="sky", q=np.ones((12, 2))),))
    options = PointingOptions(known_legs=KnownLegs())
    result, seq, _ = _sequence_with_sky(INST, plain_a, sky_a, None, options, Budget.start(10.0),
                                        lambda *_: None, SHARES)
    assert calls == ["plain", "sky"] and seq.name == kept
    assert result is (sky_a if kept == "sky" else plain_a)
