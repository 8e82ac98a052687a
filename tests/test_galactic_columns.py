"""Galactic and ecliptic input columns (issue 39, item 6): a table of known stars given by
(l, b) or by ecliptic (lon, lat) reads as the RA/Dec astropy's own conversion gives (< 1 mas),
with a notice naming the columns, through the reader, the API's upload and the CLI."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import BarycentricTrueEcliptic, SkyCoord
from astropy.table import Table
from fastapi.testclient import TestClient

from models.sky import sky_to_focal_mm
from service.app import create_app
from service.cli import main
from service.settings import Settings
from service.tables import TargetFileError, read_target_table

#: Known stars (ICRS, deg): Sirius, Vega, Betelgeuse, Polaris, Sgr A*, Canopus.
STARS = [("Sirius", 101.287155, -16.716116), ("Vega", 279.234735, 38.783689),
         ("Betelgeuse", 88.792939, 7.407064), ("Polaris", 37.954561, 89.264109),
         ("SgrA", 266.416817, -29.007825), ("Canopus", 95.987958, -52.695661)]
#: Three M67 stars close enough for one pointing (ICRS, deg).
M67 = [("S1850", 132.826983, 11.780742), ("S1569", 132.795550, 11.780050),
       ("S1071", 132.855017, 11.807494)]


def galactic(stars: list[tuple[str, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    c = SkyCoord([s[1] for s in stars] * u.deg, [s[2] for s in stars] * u.deg).galactic
    return c.l.deg, c.b.deg


def ecliptic(stars: list[tuple[str, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    c = SkyCoord([s[1] for s in stars] * u.deg, [s[2] for s in stars] * u.deg)
    e = c.transform_to(BarycentricTrueEcliptic(equinox="J2000"))
    return e.lon.deg, e.lat.deg


def icrs_of_galactic(lon: np.ndarray, lat: np.ndarray) -> SkyCoord:
    return SkyCoord(l=lon * u.deg, b=lat * u.deg, frame="galactic").icrs


def csv_file(path: Path, names: tuple[str, str], lon: np.ndarray, lat: np.ndarray,
             stars: list[tuple[str, float, float]]) -> Path:
    rows = [f"{s[0]},{float(lo)!r},{float(la)!r},3" for s, lo, la in zip(stars, lon, lat, strict=True)]
    path.write_text(f"Name,{names[0]},{names[1]},prio\n" + "\n".join(rows) + "\n")
    return path


def assert_within_mas(rows: list[dict], want: SkyCoord, most_mas: float = 1.0) -> None:  # type: ignore[type-arg]
    got = SkyCoord([r["ra_deg"] for r in rows] * u.deg, [r["dec_deg"] for r in rows] * u.deg)
    sep = got.separation(want).to_value(u.mas)
    assert np.all(sep < most_mas), sep


@pytest.mark.parametrize("names", [("_Glon", "_Glat"), ("GLON", "GLAT")])
def test_galactic_columns_read_as_astropys_icrs(tmp_path: Path, names: tuple[str, str]) -> None:
    lon, lat = galactic(STARS)
    table = read_target_table(csv_file(tmp_path / "gal.csv", names, lon, lat, STARS))
    assert_within_mas(table.rows(), icrs_of_galactic(lon, lat))
    # and they are the stars themselves (the round trip through l, b)
    assert_within_mas(table.rows(), SkyCoord([s[1] for s in STARS] * u.deg,
                                             [s[2] for s in STARS] * u.deg))
    assert table.columns["ra_deg"] == names[0] and table.columns["dec_deg"] == names[1]
    notice = next(n for n in table.notices if "galactic" in n)
    assert names[0] in notice and names[1] in notice and "ICRS" in notice


def test_galactic_columns_are_found_by_their_ucd_in_a_votable(tmp_path: Path) -> None:
    lon, lat = galactic(STARS)
    t = Table([[s[0] for s in STARS], lon, lat], names=["star", "lon1", "lat1"])
    t["star"].meta["ucd"] = "meta.id;meta.main"
    t["lon1"].meta["ucd"], t["lat1"].meta["ucd"] = "pos.galactic.lon", "pos.galactic.lat"
    t["lon1"].unit = t["lat1"].unit = u.deg
    p = tmp_path / "gal.vot"
    t.write(p, format="votable")
    table = read_target_table(p)
    assert_within_mas(table.rows(), icrs_of_galactic(lon, lat))
    assert (table.columns["ra_deg"], table.columns["dec_deg"]) == ("lon1", "lat1")


def test_a_vizier_tsv_with_galactic_columns(tmp_path: Path) -> None:
    lon, lat = galactic(STARS)
    lines = ["#Column\t_Glon\t(F12.8)\tGalactic longitude (computed by VizieR)\t[ucd=pos.galactic.lon]",
             "#Column\t_Glat\t(F12.8)\tGalactic latitude (computed by VizieR)\t[ucd=pos.galactic.lat]",
             "#Column\tName\t(A10)\tName\t[ucd=meta.id;meta.main]", "",
             "_Glon\t_Glat\tName", "deg\tdeg\t", "------------\t------------\t----------"]
    lines += [f"{lo:12.8f}\t{la:+12.8f}\t{s[0]}" for s, lo, la in zip(STARS, lon, lat, strict=True)]
    p = tmp_path / "asu.tsv"
    p.write_text("\n".join(lines) + "\n")
    table = read_target_table(p)
    # 8 decimals of a degree: 0.018 mas each
    assert_within_mas(table.rows(), icrs_of_galactic(np.round(lon, 8), np.round(lat, 8)), 0.1)
    assert [r["id"] for r in table.rows()] == [s[0] for s in STARS]


def test_ecliptic_columns_read_as_astropys_barycentric_true_ecliptic(tmp_path: Path) -> None:
    lon, lat = ecliptic(STARS)
    table = read_target_table(csv_file(tmp_path / "ecl.csv", ("ELON", "ELAT"), lon, lat, STARS))
    want = SkyCoord(BarycentricTrueEcliptic(lon=lon * u.deg, lat=lat * u.deg,
                                            equinox="J2000")).icrs
    assert_within_mas(table.rows(), want)
    assert any("ecliptic" in n and "ELON" in n and "BarycentricTrueEcliptic" in n
               for n in table.notices)


def test_ra_dec_columns_win_over_galactic_ones(tmp_path: Path) -> None:
    lon, lat = galactic(STARS)
    p = tmp_path / "both.csv"
    rows = [f"{s[0]},{s[1]},{s[2]},{lo + 1.0},{la}" for s, lo, la in zip(STARS, lon, lat, strict=True)]
    p.write_text("Name,RA,Dec,GLON,GLAT\n" + "\n".join(rows) + "\n")
    table = read_target_table(p)
    assert [r["ra_deg"] for r in table.rows()] == [s[1] for s in STARS]
    assert not any("galactic" in n for n in table.notices)


def test_a_table_with_no_position_columns_still_names_what_was_looked_for(tmp_path: Path) -> None:
    p = tmp_path / "none.csv"
    p.write_text("Name,x,y\na,1,2\n")
    with pytest.raises(TargetFileError) as e:
        read_target_table(p)
    text = str(e.value)
    assert "no ra_deg column" in text and "pos.eq.ra" in text and "_Glon/_Glat" in text


def test_a_galactic_latitude_out_of_range_names_its_cell(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("Name,_Glon,_Glat\na,10,20\nb,10,95\n")
    with pytest.raises(TargetFileError) as e:
        read_target_table(p)
    assert "row 2" in str(e.value) and "'_Glat'" in str(e.value)


# ------------------------------------------------------------------ the API and the CLI


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(job_db=tmp_path_factory.mktemp("db") / "jobs.sqlite3", workers=1)
    with TestClient(create_app(settings)) as c:
        yield c


def test_the_api_upload_converts_galactic_columns(client: TestClient, tmp_path: Path) -> None:
    lon, lat = galactic(STARS)
    p = csv_file(tmp_path / "gal.csv", ("_Glon", "_Glat"), lon, lat, STARS)
    r = client.post("/v1/target-lists", files={"file": ("gal.csv", p.read_bytes())})
    assert r.status_code == 200, r.text[:300]
    body = r.json()
    assert_within_mas(body["targets"], icrs_of_galactic(lon, lat))
    assert body["columns"]["ra_deg"] == "_Glon"
    assert any("_Glon" in n and "_Glat" in n and "ICRS" in n for n in body["notices"])


def test_the_cli_plans_a_galactic_table_at_astropys_positions(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    lon, lat = galactic(M67)
    p = csv_file(tmp_path / "m67_gal.csv", ("_Glon", "_Glat"), lon, lat, M67)
    out = tmp_path / "out"
    code = main(["plan", str(p), "--out", str(out), "--seed", "1", "--time-limit", "30",
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "notice:" in err and "_Glon and _Glat were converted to ICRS" in err
    plan = json.loads((out / "plan.json").read_text())
    want = icrs_of_galactic(lon, lat)
    where = {s[0]: (want.ra.deg[i], want.dec.deg[i]) for i, s in enumerate(M67)}
    seen = set()
    for pt in plan["pointings"]:
        pa = pt["position_angle_deg"] or 0.0
        for c in pt["configurations"]:
            for a in c["assignments"]:
                if a["target_id"] in where:
                    x, y = sky_to_focal_mm(*where[a["target_id"]], pt["ra_deg"], pt["dec_deg"],
                                           1.2, pa)
                    assert math.hypot(a["x_mm"] - float(x), a["y_mm"] - float(y)) < 1e-3
                    seen.add(a["target_id"])
    assert seen == set(where)
