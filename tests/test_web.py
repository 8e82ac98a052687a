"""The page's server side: offline /docs, static files, and POST /v1/target-lists reading the
same files as the CLI (row and column named on bad cells, 413 when too large)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from astropy import units as u
from astropy.io.votable import from_table
from astropy.table import Table
from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings
from service.tables import read_targets

URL_ATTR = re.compile(r"""(?:src|href|url)\s*[:=]\s*["']([^"']+)["']""", re.I)


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(job_db=tmp_path / "jobs.sqlite3", max_upload_bytes=64_000,
                        max_target_list_targets=50)
    with TestClient(create_app(settings)) as c:
        yield c


def _local_refs(html: str) -> list[str]:
    refs = URL_ATTR.findall(html)
    assert refs, "no references found: the pattern no longer matches the page"
    return refs


@pytest.mark.parametrize("page", ["/docs", "/"])
def test_pages_reference_no_external_host(client: TestClient, page: str) -> None:
    r = client.get(page)
    assert r.status_code == 200
    assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", r.text, re.I), "external host"
    for ref in _local_refs(r.text):
        if ref.startswith(("data:", "#")):
            continue
        path = ref if ref.startswith("/") else "/" + ref
        assert client.get(path).status_code == 200, ref


def test_page_script_fetches_only_relative_paths(client: TestClient) -> None:
    html = client.get("/").text
    scripts = re.findall(r'<script src="([^"]+)"', html)
    assert scripts == ["static/format.js", "static/viewer.js", "static/labels.js", "static/finding.js",
                       "static/controls.js", "static/locks.js", "static/validate.js", "static/form.js",
                       "static/app.js"]
    js = "".join(client.get("/" + src).text for src in scripts)
    assert "fetch(" in js and not re.search(r"https?://(?!www\.w3\.org/2000/svg)", js)
    assert client.get("/docs-assets/swagger-ui-bundle.js").status_code == 200
    assert client.get("/redoc").status_code == 404  # ReDoc would need a CDN


def _files(tmp: Path) -> dict[str, Path]:
    t = Table()
    t["Name"] = ["a", "b", "c"]
    t["RAJ2000"] = [250.4235, 250.43, 250.41]
    t["DEJ2000"] = [36.4613, 36.47, 36.45]
    t["prio"] = [1, 50, 7]
    out = {"ecsv": tmp / "t.ecsv", "fits": tmp / "t.fits"}
    t.write(out["ecsv"], format="ascii.ecsv")
    t.write(out["fits"])
    out["csv"] = tmp / "t.csv"
    out["csv"].write_text("Name,RA,DEC,priority\na,16:41:41.7,+36:27:41,1\nb,250.43,36.47,50\n")
    v = Table({"_RAJ2000": [250.4235, 250.43] * u.deg, "_DEJ2000": [36.46, 36.47] * u.deg})
    vt = from_table(v)
    f = vt.get_first_table()
    f.get_field_by_id("_RAJ2000").ucd = "pos.eq.ra;meta.main"
    f.get_field_by_id("_DEJ2000").ucd = "pos.eq.dec;meta.main"
    out["vizier"] = tmp / "vizier.vot"
    vt.to_xml(str(out["vizier"]))
    g = Table({"source_id": np.array([4295806720, 38655544960], dtype=np.int64),
               "ra": [45.0045, 45.0051] * u.deg, "dec": [0.0218, 0.0236] * u.deg})
    out["gaia"] = tmp / "gaia.ecsv"
    g.write(out["gaia"], format="ascii.ecsv")
    return out


def test_upload_reads_what_the_cli_reads(client: TestClient, tmp_path: Path) -> None:
    for kind, path in _files(tmp_path).items():
        r = client.post("/v1/target-lists", files={"file": (path.name, path.read_bytes())})
        assert r.status_code == 200, (kind, r.text)
        body = r.json()
        got = [{k: t[k] for k in ("id", "ra_deg", "dec_deg", "priority")} for t in body["targets"]]
        assert got == read_targets(path), kind
        assert [t["row"] for t in body["targets"]] == list(range(1, len(got) + 1))
        if kind == "vizier":
            assert body["columns"]["id"] is None and any("no id column" in n
                                                          for n in body["notices"])
        # what the upload returns is a valid request: the segmentation accepts it as it is
        seg = client.post("/v1/segmentations", json={"targets": got})
        assert seg.status_code == 200, (kind, seg.text)


def test_upload_errors(client: TestClient) -> None:
    r = client.post("/v1/target-lists",
                    files={"file": ("obs.csv", b"id,ra,dec,priority\na,1,2,1\nb,1,2,high\n")})
    assert r.status_code == 422
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "file"]
    assert "obs.csv: row 2, line 3, column 'priority'" in err["msg"]
    big = b"id,ra,dec\n" + b"".join(b"t%d,10.0,20.0\n" % i for i in range(6000))
    r = client.post("/v1/target-lists", files={"file": ("big.csv", big)})
    assert r.status_code == 413 and "MXS_MAX_UPLOAD_BYTES=64000" in r.json()["detail"]
    many = b"id,ra,dec\n" + b"".join(b"t%d,10.0,20.0\n" % i for i in range(60))
    r = client.post("/v1/target-lists", files={"file": ("many.csv", many)})
    assert r.status_code == 422 and "at most 50" in r.json()["message"]
    assert "MXS_MAX_TARGET_LIST_TARGETS=50" in r.json()["message"]
    r = client.post("/v1/target-lists", files={"file": ("../../etc/x.fits", b"not fits")})
    assert r.status_code == 422 and "x.fits: cannot read" in r.json()["message"]
    assert client.post("/v1/target-lists").status_code == 422


def test_upload_needs_the_token_when_set(tmp_path: Path) -> None:
    s = Settings(job_db=tmp_path / "j.sqlite3", api_token="sesame")
    with TestClient(create_app(s)) as c:
        f = {"file": ("t.csv", b"id,ra,dec\na,1,2\n")}
        assert c.post("/v1/target-lists", files=f).status_code == 401
        ok = c.post("/v1/target-lists", files=f, headers={"Authorization": "Bearer sesame"})
        assert ok.status_code == 200
        stored = f"/v1/target-lists/{ok.json()['target_list_id']}"
        assert c.get(stored).status_code == 401
        assert c.get(stored, headers={"Authorization": "Bearer sesame"}).status_code == 200
