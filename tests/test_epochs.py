"""Epoch propagation (issue 39, item 1): positions at the observation date agree with astropy's
own ``apply_space_motion`` (star by star, computed here) and with the hand formula; a Gaia-like
2016.0 list observed at 2027-01-01 moves by each star's proper motion x 11 years in the focal
plane; a fast star's allocation changes with the date, through the API and the CLI."""

from __future__ import annotations

import datetime as dt
import json
import math
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import Distance, SkyCoord
from astropy.table import Table
from astropy.time import Time
from fastapi.testclient import TestClient

from models.epochs import Motions, at_date, julian_year, parse_date, propagate
from models.errors import InputError
from models.sky import sky_to_focal_mm
from service import pipeline
from service.app import create_app
from service.cli import main
from service.response_schemas import PlanResponse
from service.schemas import PlanRequest
from service.settings import Settings
from service.tables import read_target_table

OBS = "2027-01-01"
PLATE_SCALE = 1.2  # arcsec/mm, the default instrument's


def astropy_at(ra: float, dec: float, pmra: float, pmdec: float, plx: float | None,
               rv: float, ref: float, date: str) -> SkyCoord:
    """One star at ``date`` by astropy itself (no parallax: no distance given)."""
    kw: dict[str, Any] = {} if plx is None else {"distance": Distance(parallax=plx * u.mas)}
    c = SkyCoord(ra * u.deg, dec * u.deg, pm_ra_cosdec=pmra * u.mas / u.yr,
                 pm_dec=pmdec * u.mas / u.yr, radial_velocity=rv * u.km / u.s,
                 obstime=Time(ref, format="jyear"), **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return c.apply_space_motion(new_obstime=Time(date))


# ------------------------------------------------------------------ the domain


def test_positions_agree_with_astropy_star_by_star_to_a_milliarcsecond() -> None:
    rng = np.random.default_rng(39)
    n = 40
    ra, dec = rng.uniform(0, 360, n), np.degrees(np.arcsin(rng.uniform(-0.99, 0.99, n)))
    pmra, pmdec = rng.normal(0, 2000, n), rng.normal(0, 2000, n)
    plx = np.where(rng.random(n) < 0.5, rng.uniform(0.1, 300, n), np.nan)
    rv = np.where(rng.random(n) < 0.5, rng.normal(0, 80, n), np.nan)
    ref = rng.choice([2016.0, 2000.0, 1991.25, np.nan], n)
    m = Motions(pmra, pmdec, plx, rv, ref)
    got = propagate(ra, dec, m, julian_year(dt.date(2027, 1, 1)))
    for i in range(n):
        want = astropy_at(ra[i], dec[i], pmra[i], pmdec[i],
                          None if math.isnan(plx[i]) else plx[i],
                          0.0 if math.isnan(rv[i]) else rv[i],
                          2000.0 if math.isnan(ref[i]) else ref[i], OBS)
        sep = want.separation(SkyCoord(got.ra_deg[i] * u.deg, got.dec_deg[i] * u.deg))
        assert sep.to_value(u.mas) < 1.0, (i, sep.to(u.mas))
    assert got.n_moving == n and got.default_epoch.sum() == np.isnan(ref).sum()


def test_a_star_without_parallax_follows_the_hand_formula_over_a_month() -> None:
    """d(ra) cos(dec) = pmra dt, d(dec) = pmdec dt: dt from 2016.0 (2016-01-01 12:00 TT) to
    2016-02-01 00:00 UTC (TT - UTC = 68.184 s), counted by hand."""
    dt_yr = (30.5 - 68.184 / 86400.0) / 365.25
    ra, dec, pmra, pmdec = 200.0, 40.0, 1500.0, -800.0
    m = Motions.of(1, pmra_mas_yr=[pmra], pmdec_mas_yr=[pmdec], ref_epoch_yr=[2016.0])
    got = propagate(np.array([ra]), np.array([dec]), m, julian_year(dt.date(2016, 2, 1)))
    dra_mas = (got.ra_deg[0] - ra) * 3.6e6 * math.cos(math.radians(dec))
    ddec_mas = (got.dec_deg[0] - dec) * 3.6e6
    assert abs(dra_mas - pmra * dt_yr) < 0.01 and abs(ddec_mas - pmdec * dt_yr) < 0.01
    assert got.shift_arcsec[0] == pytest.approx(math.hypot(pmra, pmdec) * dt_yr / 1000, abs=1e-5)


def test_a_star_without_motion_keeps_its_position_to_the_bit() -> None:
    ra, dec = np.array([10.123456789, 20.0]), np.array([-5.5, 89.9])
    m = Motions.of(2, pmra_mas_yr=[None, 0.0], pmdec_mas_yr=[None, 0.0], parallax_mas=[5.0, 7.0],
                   ref_epoch_yr=[2016.0, None])
    got = propagate(ra, dec, m, 2030.0)
    assert np.array_equal(got.ra_deg, ra) and np.array_equal(got.dec_deg, dec)
    assert got.n_moving == 0 and got.max_shift_arcsec == 0.0


@pytest.mark.parametrize("text", ["2027-13-01", "1899-12-31", "2101-01-01", "tomorrow",
                                  "2027-1-1", "2027-01-01T00:00"])
def test_a_bad_observation_date_names_obs_date(text: str) -> None:
    with pytest.raises(InputError) as e:
        parse_date(text)
    assert e.value.field == "obs_date"


def test_without_a_date_the_report_gives_the_shift_a_year_after_today() -> None:
    today = dt.date(2026, 3, 1)
    m = Motions.of(2, pmra_mas_yr=[1000.0, None], pmdec_mas_yr=[0.0, None])
    ra, dec, report = at_date(np.array([1.0, 2.0]), np.array([0.0, 0.0]), m, None, today)
    assert np.array_equal(ra, [1.0, 2.0]) and np.array_equal(dec, [0.0, 0.0])
    assert report is not None and report.obs_date is None and report.shift_date == "2027-03-01"
    years = julian_year(dt.date(2027, 3, 1)) - 2000.0  # no epoch given: J2000.0
    assert report.max_shift_arcsec == pytest.approx(years, abs=1e-6)
    assert report.targets_with_motion == 1 and report.default_epoch_targets == 1
    text = " ".join(report.notices())
    assert "1 target has proper motions" in text and "2027-03-01" in text and "J2000.0" in text
    assert at_date(ra, dec, Motions.of(2), None, today)[2] is None  # nothing to say


def test_the_pipeline_reads_today_from_one_place(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(pipeline, "today", lambda: dt.date(2030, 6, 15))
    req = PlanRequest(targets=[{"id": "a", "ra_deg": 1.0, "dec_deg": 2.0, "priority": 1,
                                "pmra_mas_yr": 100.0, "ref_epoch_yr": 2016.0}])
    same, epoch = pipeline.at_epoch(req)
    assert same.targets[0].ra_deg == 1.0 and epoch["epoch"].shift_date == "2031-06-15"


# ------------------------------------------------------------------ a Gaia-like list


#: Gaia DR3-like stars around (150, 20) (pmra, pmdec mas/yr; parallax mas; rv km/s).
GAIA = [
    (1001, 150.000, 20.000, 4000.0, -2500.0, 200.0, 30.0),
    (1002, 150.010, 20.008, -3000.0, 1200.0, float("nan"), float("nan")),
    (1003, 149.990, 19.995, 50.0, 10.0, 2.5, float("nan")),
    (1004, 150.005, 19.990, float("nan"), float("nan"), float("nan"), float("nan")),
]


def gaia_table() -> Table:
    """Gaia archive column names, units and UCDs, ``ref_epoch`` 2016.0."""
    cols = list(zip(*GAIA, strict=True))
    t = Table([np.array(cols[0], np.int64), *(np.array(c, float) for c in cols[1:])],
              names=["source_id", "ra", "dec", "pmra", "pmdec", "parallax", "radial_velocity"])
    t["ref_epoch"] = np.full(len(GAIA), 2016.0)
    units = {"ra": u.deg, "dec": u.deg, "pmra": u.mas / u.yr, "pmdec": u.mas / u.yr,
             "parallax": u.mas, "radial_velocity": u.km / u.s, "ref_epoch": u.yr}
    ucds = {"source_id": "meta.id", "ra": "pos.eq.ra;meta.main", "dec": "pos.eq.dec;meta.main",
            "pmra": "pos.pm;pos.eq.ra", "pmdec": "pos.pm;pos.eq.dec",
            "parallax": "pos.parallax.trig", "radial_velocity": "spect.dopplerVeloc.opt;em.opt.I",
            "ref_epoch": "meta.ref;time.epoch"}
    for name, unit in units.items():
        t[name].unit = unit
    for name, ucd in ucds.items():
        t[name].meta["ucd"] = ucd
    return t


def gaia_file(tmp_path: Path, fmt: str) -> Path:
    t = gaia_table()
    if fmt == "csv":  # a CSV: names only, empty cells for the missing values
        p = tmp_path / "gaia.csv"
        rows = [",".join("" if isinstance(v, float) and math.isnan(v) else repr(v) for v in row)
                for row in GAIA]
        p.write_text("source_id,ra,dec,pmra,pmdec,parallax,radial_velocity,ref_epoch\n"
                     + "\n".join(r + ",2016.0" for r in rows) + "\n")
        return p
    p = tmp_path / "gaia.vot"
    t.write(p, format="votable")
    return p


@pytest.mark.parametrize("fmt", ["vot", "csv"])
def test_a_2016_gaia_list_at_2027_moves_by_its_proper_motion_times_11_years_in_mm(
        tmp_path: Path, fmt: str) -> None:
    table = read_target_table(gaia_file(tmp_path, fmt))
    assert table.columns["pmra_mas_yr"] == "pmra" and table.columns["ref_epoch_yr"] == "ref_epoch"
    req = PlanRequest(targets=table.rows(), obs_date=OBS)
    moved, epoch = pipeline.at_epoch(req)
    dt_yr = (Time(OBS) - Time(2016.0, format="jyear")).to_value(u.yr)
    assert abs(dt_yr - 11.0) < 2e-3
    ra0 = np.array([t.ra_deg for t in req.targets])
    dec0 = np.array([t.dec_deg for t in req.targets])
    ra1 = np.array([t.ra_deg for t in moved.targets])
    dec1 = np.array([t.dec_deg for t in moved.targets])
    x1, y1 = sky_to_focal_mm(ra1, dec1, 150.0, 20.0, PLATE_SCALE, 0.0)
    for i, (_, ra, dec, pmra, pmdec, plx, rv) in enumerate(GAIA):
        if math.isnan(rv):  # no perspective acceleration: pm x dt, +x East, +y North, in the
            # focal plane of a pointing on the star's catalogue position
            want = np.nan_to_num([pmra, pmdec]) * dt_yr / 1000.0 / PLATE_SCALE
            x, y = sky_to_focal_mm(ra1[i], dec1[i], ra0[i], dec0[i], PLATE_SCALE, 0.0)
            assert abs(float(x) - want[0]) < 1e-3 and abs(float(y) - want[1]) < 1e-3, i
        c = astropy_at(ra, dec, np.nan_to_num(pmra), np.nan_to_num(pmdec),
                       None if math.isnan(plx) else plx, np.nan_to_num(rv), 2016.0, OBS)
        x, y = sky_to_focal_mm(c.ra.deg, c.dec.deg, 150.0, 20.0, PLATE_SCALE, 0.0)
        assert math.hypot(x1[i] - float(x), y1[i] - float(y)) < 1e-3, i
    assert epoch["epoch"].targets_with_motion == 3
    assert (ra1[3], dec1[3]) == (ra0[3], dec0[3])  # no proper motion: not moved


# ------------------------------------------------------------------ the API and the CLI

#: A fast star B 1 arcsec East of A at 2016.0, moving 10 arcsec/yr East: at 2016-01-01 the
#: two are 0.8 mm apart (one configuration cannot hold both), at 2027-01-01 92 mm.
FAST = [{"id": "A", "ra_deg": 150.0, "dec_deg": 20.0, "priority": 5},
        {"id": "B", "ra_deg": 150.0 + 1.0 / 3600.0 / math.cos(math.radians(20.0)),
         "dec_deg": 20.0, "priority": 5, "pmra_mas_yr": 10000.0, "pmdec_mas_yr": 0.0,
         "ref_epoch_yr": 2016.0}]


def observed(plan: dict[str, Any]) -> list[list[str]]:
    """The targets of each configuration of the plan."""
    return [sorted(a["target_id"] for a in c["assignments"] if a["target_id"])
            for p in plan["pointings"] for c in p["configurations"]]


def b_tip_matches_astropy(plan: dict[str, Any], date: str) -> None:
    """The arm on B stands where astropy puts B at ``date``, projected about the pointing."""
    b = FAST[1]
    want = astropy_at(b["ra_deg"], b["dec_deg"], 10000.0, 0.0, None, 0.0, 2016.0, date)
    for p in plan["pointings"]:
        for c in p["configurations"]:
            for a in c["assignments"]:
                if a["target_id"] == "B":
                    pa = p["position_angle_deg"] or 0.0
                    x, y = sky_to_focal_mm(want.ra.deg, want.dec.deg, p["ra_deg"], p["dec_deg"],
                                           PLATE_SCALE, pa)
                    assert math.hypot(a["x_mm"] - float(x), a["y_mm"] - float(y)) < 1e-3


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(job_db=tmp_path_factory.mktemp("db") / "jobs.sqlite3", workers=1)
    with TestClient(create_app(settings)) as c:
        yield c


def test_the_api_plans_a_fast_star_where_it_is_on_the_date(client: TestClient) -> None:
    plans = {}
    for date in ("2016-01-01", OBS):
        r = client.post("/v1/plans", json={"targets": FAST, "obs_date": date, "seed": 1,
                                           "time_limit_s": 30})
        assert r.status_code == 200, r.text[:300]
        plans[date] = PlanResponse.model_validate(r.json()).model_dump()
        b_tip_matches_astropy(plans[date], date)
    assert observed(plans["2016-01-01"]) in ([["A"], ["B"]], [["B"], ["A"]])
    assert observed(plans[OBS]) == [["A", "B"]]
    epoch = plans[OBS]["epoch"]
    assert epoch["obs_date"] == OBS and epoch["targets_with_motion"] == 1
    assert epoch["max_shift_arcsec"] == pytest.approx(10.0 * 10.9993, abs=0.01)
    assert any("propagated to the observation date 2027-01-01: 1 target moved" in n
               for n in plans[OBS]["notices"])


def test_the_api_without_a_date_says_how_far_the_stars_move_in_a_year(client: TestClient) -> None:
    r = client.post("/v1/plans", json={"targets": FAST, "seed": 1, "time_limit_s": 30})
    assert r.status_code == 200, r.text[:300]
    body = r.json()
    ahead = dt.datetime.now(dt.UTC).date()
    ahead = ahead.replace(year=ahead.year + 1, day=28 if (ahead.month, ahead.day) == (2, 29)
                          else ahead.day)
    assert body["epoch"]["obs_date"] is None and body["epoch"]["shift_date"] == ahead.isoformat()
    assert any("1 target has proper motions" in n and ahead.isoformat() in n
               for n in body["notices"])
    assert len(observed(body)) == 2  # planned at the catalogue positions: still 1 arcsec apart


def test_a_plan_job_plans_at_obs_date(client: TestClient) -> None:
    """The page's path: a plan job moves its targets as the synchronous plan does."""
    r = client.post("/v1/jobs", json={"kind": "plan", "request": {
        "targets": FAST, "obs_date": OBS, "seed": 1, "time_limit_s": 30}})
    assert r.status_code == 202, r.text[:300]
    job_id, deadline = r.json()["job_id"], time.monotonic() + 120
    while (job := client.get(f"/v1/jobs/{job_id}").json())["status"] not in ("done", "failed"):
        assert time.monotonic() < deadline, job
        time.sleep(0.2)
    assert job["status"] == "done", job
    plan = job["result"]
    assert observed(plan) == [["A", "B"]] and plan["epoch"]["targets_with_motion"] == 1
    b_tip_matches_astropy(plan, OBS)


@pytest.mark.parametrize("date", ["2027-02-30", "1850-01-01", "soon", " 2027-01-01", 2027])
def test_a_bad_obs_date_is_a_422_naming_it(client: TestClient, date: Any) -> None:
    r = client.post("/v1/plans", json={"targets": FAST, "obs_date": date})
    assert r.status_code == 422
    assert ["body", "obs_date"] in [d["loc"] for d in r.json()["detail"]]


def test_a_proper_motion_out_of_range_is_a_422_naming_it(client: TestClient) -> None:
    bad = [dict(FAST[0]), {**FAST[1], "pmra_mas_yr": 1e9}]
    r = client.post("/v1/plans", json={"targets": bad})
    assert r.status_code == 422
    assert ["body", "targets", 1, "pmra_mas_yr"] in [d["loc"] for d in r.json()["detail"]]


def test_a_segmentation_at_a_date_reports_its_epoch(client: TestClient) -> None:
    r = client.post("/v1/segmentations", json={"targets": FAST, "obs_date": OBS})
    assert r.status_code == 200, r.text[:300]
    assert r.json()["stats"]["epoch"]["targets_with_motion"] == 1


def test_an_uploaded_gaia_list_keeps_its_motions_for_a_plan_by_id(client: TestClient,
                                                                   tmp_path: Path) -> None:
    p = gaia_file(tmp_path, "vot")
    r = client.post("/v1/target-lists", files={"file": ("gaia.vot", p.read_bytes())})
    assert r.status_code == 200, r.text[:300]
    listed = r.json()
    assert listed["targets"][0]["pmra_mas_yr"] == 4000.0
    assert listed["targets"][3].get("pmra_mas_yr") is None
    assert listed["columns"]["parallax_mas"] == "parallax"
    r = client.post("/v1/segmentations", json={"target_list_id": listed["target_list_id"],
                                               "obs_date": OBS})
    assert r.status_code == 200, r.text[:300]
    assert r.json()["stats"]["epoch"]["targets_with_motion"] == 3


def _fast_csv(path: Path) -> Path:
    lines = ["id,ra,dec,priority,pmra,pmdec,ref_epoch"]
    for t in FAST:
        lines.append(f"{t['id']},{t['ra_deg']!r},{t['dec_deg']!r},{t['priority']},"
                     f"{t.get('pmra_mas_yr', '')},{t.get('pmdec_mas_yr', '')},"
                     f"{t.get('ref_epoch_yr', '')}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_cli_plans_at_obs_date(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = _fast_csv(tmp_path / "fast.csv")
    plans = {}
    for date in ("2016-01-01", OBS):
        out = tmp_path / date
        code = main(["plan", str(src), "--out", str(out), "--obs-date", date, "--seed", "1",
                     "--time-limit", "30", "--quiet"])
        err = capsys.readouterr().err
        assert code == 0, err
        assert f"notice: Positions propagated to the observation date {date}" in err
        plans[date] = json.loads((out / "plan.json").read_text())
        b_tip_matches_astropy(plans[date], date)
    assert len(observed(plans["2016-01-01"])) == 2 and observed(plans[OBS]) == [["A", "B"]]


def test_the_cli_refuses_a_bad_date(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = _fast_csv(tmp_path / "fast.csv")
    code = main(["plan", str(src), "--out", str(tmp_path / "o"), "--obs-date", "2027-02-30"])
    assert code == 2 and "obs_date" in capsys.readouterr().err
