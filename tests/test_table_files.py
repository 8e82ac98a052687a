"""Table files as astronomers hand them in: VizieR's TSV export read through the reader, the API
(the page's upload) and the CLI, the same targets as the same stars in a CSV; a file that is
no table refused in one line "not a table: ..." on the CLI and in the API's 422; messages that
echo a value write it as the file did ("-5", "row 1")."""

from __future__ import annotations

import gzip
import json
import zipfile
from collections.abc import Iterator
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import Table
from fastapi.testclient import TestClient
from test_browser import browser, page, server  # noqa: F401 - the Chromium harness's fixtures

from service.app import create_app
from service.cli import main
from service.settings import Settings
from service.table_checks import MAX_COLUMNS, RowLimit
from service.tables import TargetFileError, read_target_table

matplotlib.use("Agg")

#: Six stars of M67 (name, RA h:m:s, Dec d:m:s, priority, V), as in a VizieR cone search.
STARS = [
    ("Sanders 1850", "08 51 18.476", "+11 46 50.67", 500, 15.57),
    ("Sanders 1569", "08 51 10.932", "+11 46 48.18", 10, 12.42),
    ("Sanders 1071", "08 51 25.204", "+11 48 26.98", 1, 13.43),
    ("Sanders 2005", "08 51 20.753", "+11 49 27.51", 10, 12.22),
    ("Sanders 1026", "08 51 10.405", "+11 49 20.28", 100, 11.42),
    ("Sanders 1328", "08 51 07.070", "+11 47 32.93", 100, 12.19),
]

#: VizieR's header of an asu-tsv answer (comment lines, then one #Column line per column).
HEADER = """#
#   VizieR Astronomical Server vizier.cds.unistra.fr
#    Date: 2026-11-30T10:12:41 [V7.4.6]
#   In case of problem, please report to:\tcds-question@unistra.fr
#
#
#Coosys\tJ2000:\teq_FK5 J2000
#INFO\tvotable-version=1.99+ (14-Oct-2013)\t
#INFO\t-ref=VIZ6747e4a1b2c3\t
#INFO\t-out.max=50\t
#INFO\tqueryParameters=9\t
#-oc.form={form}
#-out.add=_r
#-out.add=_RAJ,_DEJ
#-sort=_r
#-c=132.825 +11.8
#-c.r=  5
#-c.u=arcmin
#-source=II/999/m67
#

#RESOURCE=yCat_2999
#Name: II/999
#Title: Photometry of M67 (Sanders 1977)
#Table\tII_999_m67:
#Name: II/999/m67
#Title: The stars of M67
#Column\t_r\t(F5.2)\tDistance from center (132.825000+11.800000)[FK5/J2000], at Epoch of catalog\t[ucd=pos.angDistance]
#Column\t_RAJ2000\t({ra_fmt})\tRight ascension (FK5, Equinox=J2000.0) (computed by VizieR, not part of the original data)\t[ucd=pos.eq.ra;meta.main]
#Column\t_DEJ2000\t({de_fmt})\tDeclination (FK5, Equinox=J2000.0) (computed by VizieR, not part of the original data)\t[ucd=pos.eq.dec;meta.main]
#Column\tName\t(A12)\tSanders number\t[ucd=meta.id;meta.main]
#Column\tVmag\t(F5.2)\tV magnitude\t[ucd=phot.mag;em.opt.V]
#Column\tprio\t(I3)\tPriority (added by the astronomer)\t[ucd=meta.code]
"""


def _coords(ra: str, dec: str) -> SkyCoord:
    return SkyCoord(ra, dec, unit=(u.hourangle, u.deg))


def vizier_tsv(sexagesimal: bool = True, stars: list[tuple] = STARS) -> str:  # type: ignore[type-arg]
    """The exact layout of VizieR's TSV export: comments, a blank line, the header row, the
    units row, a row of dashes, data cells padded with spaces to the column's width."""
    form, ra_fmt, de_fmt = ("sexa", "A12", "A12") if sexagesimal else ("dec", "F10.6", "F10.6")
    lines = [HEADER.format(form=form, ra_fmt=ra_fmt, de_fmt=de_fmt).rstrip("\n"), ""]
    lines.append("_r\t_RAJ2000\t_DEJ2000\tName\tVmag\tprio")
    units = '"h:m:s"\t"d:m:s"' if sexagesimal else "deg\tdeg"
    lines.append(f"arcmin\t{units}\t\tmag\t")
    width = 12 if sexagesimal else 10
    lines.append("\t".join("-" * n for n in (5, width, width, 12, 5, 3)))
    centre = SkyCoord(132.825 * u.deg, 11.8 * u.deg)
    for name, ra, dec, prio, vmag in stars:
        c = _coords(ra, dec)
        r = f"{c.separation(centre).arcmin:5.2f}"
        pos = (f"{ra:>12}\t{dec:>12}" if sexagesimal
               else f"{c.ra.deg:10.6f}\t{c.dec.deg:+10.6f}")
        lines.append(f"{r}\t{pos}\t{name:<12}\t{vmag:5.2f}\t{prio:3d}")
    return "\n".join(lines) + "\n"


def stars_csv(stars: list[tuple] = STARS) -> str:  # type: ignore[type-arg]
    """The same stars as a plain CSV (sexagesimal strings, as the M67 case file has them)."""
    rows = [f"{ra},{dec},{name},{prio},{vmag}" for name, ra, dec, prio, vmag in stars]
    return "\n".join(["_RAJ2000,_DEJ2000,Name,prio,Vmag", *rows]) + "\n"


def _targets(rows: list[dict]) -> list[tuple]:  # type: ignore[type-arg]
    return [(r["id"], r["ra_deg"], r["dec_deg"], r["priority"]) for r in rows]


def _expected() -> list[tuple]:  # type: ignore[type-arg]
    """The stars' positions by astropy's SkyCoord, independently of the reader."""
    return [(n, _coords(ra, dec).ra.deg, _coords(ra, dec).dec.deg, p) for n, ra, dec, p, _ in STARS]


def _assert_same(got: list[tuple], want: list[tuple], tol_deg: float = 0.0) -> None:  # type: ignore[type-arg]
    assert [g[0] for g in got] == [w[0] for w in want]
    assert [g[3] for g in got] == [w[3] for w in want]
    for g, w in zip(got, want, strict=True):
        assert abs(g[1] - w[1]) <= tol_deg + 1e-12 and abs(g[2] - w[2]) <= tol_deg + 1e-12, (g, w)


# ----------------------------------------------------------------- VizieR TSV: the reader


@pytest.mark.parametrize("sexagesimal", [True, False])
def test_vizier_tsv_reads_as_the_same_stars_in_a_csv(tmp_path: Path, sexagesimal: bool) -> None:
    tsv, csv = tmp_path / "asu.tsv", tmp_path / "m67.csv"
    tsv.write_text(vizier_tsv(sexagesimal), encoding="utf-8")
    csv.write_text(stars_csv(), encoding="utf-8")
    from_tsv, from_csv = read_target_table(tsv), read_target_table(csv)
    assert from_tsv.columns == {"id": "Name", "ra_deg": "_RAJ2000", "dec_deg": "_DEJ2000",
                                "priority": "prio"}
    # the decimal export has 6 decimals: 0.5e-6 deg
    _assert_same(_targets(from_tsv.rows()), _targets(from_csv.rows()),
                 0.0 if sexagesimal else 0.6e-6)
    _assert_same(_targets(from_tsv.rows()), _expected(), 1e-9 if sexagesimal else 0.6e-6)
    # rows count the data; lines are the file's (after 30-odd comment lines)
    text = vizier_tsv(sexagesimal).splitlines()
    first = next(i for i, ln in enumerate(text, start=1) if "Sanders 1850" in ln)
    assert [(t.row, t.line) for t in from_tsv.targets] == [(k + 1, first + k) for k in range(6)]
    assert from_tsv.notices == ()


def test_the_units_row_says_hours_and_degrees(tmp_path: Path) -> None:
    """A sexagesimal RA whose units row says h:m:s is hours; one in d:m:s is degrees."""
    p = tmp_path / "units.tsv"
    p.write_text("RA\tDE\tid\n\"h:m:s\"\t\"d:m:s\"\t\n-----\t-----\t--\n01 00 00\t+10 30 00\ta\n"
                 "\n", encoding="utf-8")
    (t,) = read_target_table(p).targets
    assert (t.ra_deg, t.dec_deg) == pytest.approx((15.0, 10.5))
    p.write_text("RA\tDE\tid\n\"d:m:s\"\t\"d:m:s\"\t\n-----\t-----\t--\n01 00 00\t+10 30 00\ta\n",
                 encoding="utf-8")
    (t,) = read_target_table(p).targets
    assert (t.ra_deg, t.dec_deg) == pytest.approx((1.0, 10.5))


def test_the_column_ucds_of_the_comment_lines_choose_the_columns(tmp_path: Path) -> None:
    """By name alone _RAJ2000 comes first; the #Column lines mark RA_ICRS as the main position."""
    text = ("#Column\t_RAJ2000\t(F10.6)\tcomputed\t[ucd=pos.eq.ra]\n"
            "#Column\t_DEJ2000\t(F10.6)\tcomputed\t[ucd=pos.eq.dec]\n"
            "#Column\tRA_ICRS\t(F10.6)\tRA\t[ucd=pos.eq.ra;meta.main]\n"
            "#Column\tDE_ICRS\t(F10.6)\tDec\t[ucd=pos.eq.dec;meta.main]\n"
            "\n_RAJ2000\t_DEJ2000\tRA_ICRS\tDE_ICRS\ndeg\tdeg\tdeg\tdeg\n"
            "--\t--\t--\t--\n10.0\t20.0\t10.5\t20.5\n")
    p = tmp_path / "ucd.tsv"
    p.write_text(text, encoding="utf-8")
    table = read_target_table(p)
    assert table.columns["ra_deg"] == "RA_ICRS" and table.columns["dec_deg"] == "DE_ICRS"
    assert (table.targets[0].ra_deg, table.targets[0].dec_deg) == (10.5, 20.5)


@pytest.mark.parametrize("layout", ["no units row", "no dashes", "bar-separated", "crlf"])
def test_tab_separated_files_without_every_vizier_row(tmp_path: Path, layout: str) -> None:
    body = ["a\t08 51 18.476\t+11 46 50.67", "b\t08 51 10.932\t+11 46 48.18"]
    head = {"no units row": ["id\tra\tdec", "--\t--\t--"], "no dashes": ["id\tra\tdec"],
            "bar-separated": ["id|ra|dec", "|\"h:m:s\"|\"d:m:s\"", "--|--|--"],
            "crlf": ["id\tra\tdec", "\t\"h:m:s\"\t\"d:m:s\"", "--\t--\t--"]}[layout]
    if layout == "bar-separated":
        body = [b.replace("\t", "|") for b in body]
    p = tmp_path / "plain.tsv"
    p.write_bytes(("\r\n" if layout == "crlf" else "\n").join(head + body).encode() + b"\n")
    got = [(t.id, t.ra_deg, t.dec_deg) for t in read_target_table(p).targets]
    assert got == [(n, _coords(r, d).ra.deg, _coords(r, d).dec.deg)
                   for n, r, d in (b.replace("|", "\t").split("\t") for b in body)]


def test_a_bad_tsv_cell_names_its_row_line_and_column(tmp_path: Path) -> None:
    text = vizier_tsv(True, STARS[:3]).replace("08 51 25.204", "08 51 99.000")  # Sanders 1071
    p = tmp_path / "bad.tsv"
    p.write_text(text, encoding="utf-8")
    line = next(i for i, ln in enumerate(text.splitlines(), start=1) if "Sanders 1071" in ln)
    with pytest.raises(TargetFileError, match=rf"bad.tsv: row 3, line {line}, column '_RAJ2000'"):
        read_target_table(p)
    # an empty priority is said as such (VizieR writes a missing value as an empty cell)
    text = vizier_tsv(True, STARS[:3])
    assert text.count("\t  1\n") == 1  # Sanders 1071's priority
    p.write_text(text.replace("\t  1\n", "\t   \n"), encoding="utf-8")
    with pytest.raises(TargetFileError, match=rf"row 3, line {line}, column 'prio': empty priority"):
        read_target_table(p)


def test_tsv_bounds_and_a_second_table(tmp_path: Path) -> None:
    p = tmp_path / "x.tsv"
    p.write_text(vizier_tsv(), encoding="utf-8")
    with pytest.raises(TargetFileError, match="more than 5 rows .*at most 5 targets"):
        read_target_table(p, rows=RowLimit(5))
    p.write_text(vizier_tsv() + "\n#Table\tII_999_other:\n" + vizier_tsv().split("\n\n")[-1],
                 encoding="utf-8")
    with pytest.raises(TargetFileError, match=r"x.tsv: line \d+ starts a second table"):
        read_target_table(p)
    p.write_text("\t".join(f"c{k}" for k in range(MAX_COLUMNS + 1)) + "\n", encoding="utf-8")
    with pytest.raises(TargetFileError, match=f"names {MAX_COLUMNS + 1} columns; at most"):
        read_target_table(p)
    p.write_text("id\tra\tdec\na\t10\t20\textra\n", encoding="utf-8")
    with pytest.raises(TargetFileError, match="row 1, line 2 has 4 cells; the header names 3 "
                       "columns"):
        read_target_table(p)


def test_a_compressed_tsv_and_a_tsv_without_a_suffix(tmp_path: Path) -> None:
    """A name without a known suffix takes the format its content shows (tabs in the header)."""
    want = _expected()
    gz = tmp_path / "asu.tsv.gz"
    gz.write_bytes(gzip.compress(vizier_tsv().encode()))
    _assert_same(_targets(read_target_table(gz).rows()), want, 1e-9)
    bare = tmp_path / "asu"
    bare.write_text(vizier_tsv(), encoding="utf-8")
    _assert_same(_targets(read_target_table(bare).rows()), want, 1e-9)


# ----------------------------------------------------------------- the API and the CLI


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(job_db=tmp_path_factory.mktemp("db") / "jobs.sqlite3", workers=1)
    with TestClient(create_app(settings)) as c:
        yield c


def _upload(c: TestClient, name: str, data: bytes) -> dict:  # type: ignore[type-arg]
    r = c.post("/v1/target-lists", files={"file": (name, data)})
    assert r.status_code == 200, r.text[:300]
    return r.json()  # type: ignore[no-any-return]


@pytest.mark.parametrize("name", ["asu.tsv", "asu.tsv.gz", "asu"])
def test_the_api_reads_a_vizier_tsv_as_the_same_stars_in_a_csv(client: TestClient,
                                                               name: str) -> None:
    """The page uploads through this endpoint: the same targets as the CSV upload."""
    data = vizier_tsv().encode()
    tsv = _upload(client, name, gzip.compress(data) if name.endswith(".gz") else data)
    csv = _upload(client, "m67.csv", stars_csv().encode())
    _assert_same(_targets(tsv["targets"]), _targets(csv["targets"]))
    _assert_same(_targets(tsv["targets"]), _expected(), 1e-9)
    assert tsv["columns"]["ra_deg"] == "_RAJ2000" and tsv["filename"] == name


def test_the_cli_plans_a_vizier_tsv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "asu.tsv"
    p.write_text(vizier_tsv(True, STARS[:3]), encoding="utf-8")
    out = tmp_path / "out"
    code = main(["plan", str(p), "--out", str(out), "--seed", "1", "--time-limit", "30",
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    result = json.loads((out / "plan.json").read_text())
    assert sorted(i for pt in result["pointings"] for i in pt["target_ids"]) == \
        sorted(s[0] for s in STARS[:3])
    assert "notice" not in err  # id and priority columns found: no defaults applied


# ----------------------------------------------------------------- not a table


def _png(path: Path) -> bytes:
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(1, 1))
    fig.savefig(path, format="png")
    fig.savefig(path.with_suffix(".pdf"), format="pdf")
    plt.close(fig)
    return path.read_bytes()


def _not_tables(tmp_path: Path) -> dict[str, tuple[bytes, str]]:
    """Files that are no table, each with what the message must call it."""
    png = _png(tmp_path / "made.png")
    pdf = (tmp_path / "made.pdf").read_bytes()
    zipped = tmp_path / "sheet.zip"
    with zipfile.ZipFile(zipped, "w") as z:
        z.writestr("a.csv", stars_csv())
    return {"png": (png, "a PNG image"), "pdf": (pdf, "a PDF document"),
            "random": (np.random.default_rng(7).bytes(20_000), "binary data"),
            "zip": (zipped.read_bytes(), "a zip archive"),
            "latin-1": ("id,ra,dec\na,1,2\nb,3,4\nc\xe9,5,6\n".encode("latin-1"),
                        "line 4 is not UTF-8 text (byte 0xe9)")}


NAMES = {"png": ["chart.png", "chart.csv", "chart"], "pdf": ["paper.pdf", "paper.tsv"],
         "random": ["blob.bin", "blob.ecsv", "blob.tsv"], "zip": ["sheet.zip"],
         "latin-1": ["list.csv", "list.tsv"]}
CASES = [(kind, name) for kind, names in NAMES.items() for name in names]


@pytest.mark.parametrize(("kind", "name"), CASES)
def test_the_cli_says_not_a_table_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              kind: str, name: str) -> None:
    data, what = _not_tables(tmp_path)[kind]
    p = tmp_path / name
    p.write_bytes(data)
    code = main(["plan", str(p), "--out", str(tmp_path / "o"), "--quiet"])
    captured = capsys.readouterr()
    assert code == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith(f"error: {p}: not a table: "), lines[0]
    assert what in lines[0]
    assert "codec" not in lines[0] and "Format could not be identified" not in captured.err
    assert len(lines[0]) < len(f"error: {p}: ") + 160
    assert not (tmp_path / "o" / "plan.json").exists()


@pytest.mark.parametrize(("kind", "name"), CASES)
def test_the_api_says_not_a_table_in_its_422(client: TestClient, tmp_path: Path, kind: str,
                                             name: str) -> None:
    data, what = _not_tables(tmp_path)[kind]
    r = client.post("/v1/target-lists", files={"file": (name, data)})
    assert r.status_code == 422, r.text[:300]
    body = r.json()
    (detail,) = body["detail"]
    assert detail["loc"] == ["body", "file"]
    msg = detail["msg"]
    if kind == "zip":  # the upload's decompressor refuses it first, with the same advice
        assert msg.startswith(f"{name}: a zip archive is not read"), msg
        return
    assert msg.startswith(f"{name}: not a table: "), msg
    assert what in msg and "codec" not in msg and "\n" not in msg and len(msg) < 200


def test_text_that_no_reader_recognises_is_not_a_table(tmp_path: Path) -> None:
    """A name without a known suffix and content no table reader takes."""
    p = tmp_path / "notes"
    p.write_text("Dear colleague,\n\nplease find the targets attached.\n" * 3, encoding="utf-8")
    with pytest.raises(TargetFileError, match=r"^\S+notes: not a table: neither its name nor its "
                       "content tells a table format"):
        read_target_table(p)


def test_control_bytes_make_binary_data_but_a_stray_one_is_text(tmp_path: Path) -> None:
    """Valid UTF-8 without a NUL is still binary when control bytes are common; a stray one
    (an escape byte pasted into a name) in a short CSV is text, read as written."""
    p = tmp_path / "controls.csv"
    p.write_bytes(b"id,ra,dec\n" + bytes(range(1, 9)) * 200)
    with pytest.raises(TargetFileError, match="controls.csv: not a table: binary data"):
        read_target_table(p)
    p.write_bytes(b"id,ra,dec\na\x1bb,10.5,20.25\n")
    (t,) = read_target_table(p).targets
    assert (t.id, t.ra_deg, t.dec_deg) == ("a\x1bb", 10.5, 20.25)


# ----------------------------------------------------------------- echoed values


@pytest.mark.parametrize("suffix", [".csv", ".fits", ".tsv"])
def test_a_priority_is_echoed_as_the_file_wrote_it(tmp_path: Path, suffix: str) -> None:
    """-5 in a float column (another row says 1.0, or FITS stores E) is echoed as -5."""
    t = Table({"id": ["a", "b"], "ra": [10.0, 10.1], "dec": [20.0, 20.1],
               "priority": np.array([1.0, -5.0])})
    p = tmp_path / f"prio{suffix}"
    if suffix == ".tsv":
        p.write_text("id\tra\tdec\tpriority\na\t10.0\t20.0\t1.0\nb\t10.1\t20.1\t-5\n",
                     encoding="utf-8")
    else:
        t.write(p, format="csv" if suffix == ".csv" else "fits")
    with pytest.raises(TargetFileError) as err:
        read_target_table(p)
    assert "row 2" in str(err.value) and "priority '-5' is not an integer" in str(err.value)
    assert "-5.0" not in str(err.value)
    t["priority"] = [1.0, 2.5]
    if suffix != ".tsv":
        t.write(p, format="csv" if suffix == ".csv" else "fits", overwrite=True)
        with pytest.raises(TargetFileError, match=r"priority '2.5' is not an integer"):
            read_target_table(p)


def test_row_lists_say_row_or_rows(tmp_path: Path) -> None:
    p = tmp_path / "mixed.csv"
    p.write_text("ra,dec\n250.4235,36.4613\n16:41:41.7,+36:27:41\n16:41:42.0,+36:27:40\n"
                 "250.5,36.5\n", encoding="utf-8")
    table = read_target_table(p)
    (notice,) = [n for n in table.notices if "column 'ra' mixes" in n]
    assert "decimal degrees (rows 1, 4)" in notice and "sexagesimal hours (rows 2, 3)" in notice
    p.write_text("ra,dec\n250.4235,36.4613\n16:41:41.7,36.46\n", encoding="utf-8")
    (notice,) = [n for n in read_target_table(p).notices if "mixes" in n]
    said = notice.split(": ", 1)[1]  # after the file's path
    assert "(row 1)" in said and "(row 2)" in said and "rows" not in said
    p.write_text("ra,dec\n250.4235,36.4613\n", encoding="utf-8")
    (notice,) = [n for n in read_target_table(p).notices if "no id column" in n]
    assert notice.endswith("named by their row number (1)")


# ----------------------------------------------------------------- the page, in Chromium


def test_the_page_reads_a_vizier_tsv_and_refuses_a_png(page, server, tmp_path: Path) -> None:  # noqa: F811
    """The page's upload (Chromium, the harness of tests/test_browser.py): the TSV's six stars
    with their names and priorities; a PNG is one line, "not a table: a PNG image"."""
    tsv = tmp_path / "asu.tsv"
    tsv.write_text(vizier_tsv(), encoding="utf-8")
    page.goto(server + "/")
    page.set_input_files("#file", str(tsv))
    page.wait_for_function("document.querySelector('#table-info').textContent.includes('read from')")
    info = page.inner_text("#table-info")
    assert "6 targets read from asu.tsv" in info and "ra_deg <- _RAJ2000" in info, info
    assert "priority <- prio" in info and page.is_hidden("#error")
    png = tmp_path / "chart.png"
    _png(png)
    page.set_input_files("#file", str(png))
    page.wait_for_selector("#error:not([hidden])")
    said = page.inner_text("#error").strip()
    assert "chart.png: not a table: a PNG image" in said and "codec" not in said, said
