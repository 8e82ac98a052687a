"""Target tables: VO column recognition, per-cell angle forms, errors naming row and column."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import Angle
from astropy.io.votable import from_table
from astropy.table import Table
from hypothesis import given, settings
from hypothesis import strategies as st

from service.cli import main
from service.table_checks import MAX_CELL_CHARS
from service.tables import TargetFileError, read_target_table, read_targets


def _vizier_votable(path: Path, with_sexagesimal: bool = True) -> None:
    """A VOTable laid out as VizieR serves it: computed _RAJ2000/_DEJ2000 in deg carrying the
    meta.main UCDs, the catalogue's own sexagesimal RAJ2000/DEJ2000, no id column."""
    t = Table()
    t["_RAJ2000"] = [250.4235, 250.4301, 250.41]
    t["_DEJ2000"] = [36.4613, 36.47, 36.45]
    t["_RAJ2000"].unit = t["_DEJ2000"].unit = u.deg
    if with_sexagesimal:
        t["RAJ2000"] = ["00 00 00.0"] * 3  # deliberately different: must not be used
        t["DEJ2000"] = ["+00 00 00"] * 3
    t["Jmag"] = [12.1, 13.4, 11.0]
    vt = from_table(t)
    fields = vt.get_first_table()
    fields.get_field_by_id("_RAJ2000").ucd = "pos.eq.ra;meta.main"
    fields.get_field_by_id("_DEJ2000").ucd = "pos.eq.dec;meta.main"
    if with_sexagesimal:
        fields.get_field_by_id("RAJ2000").ucd = "pos.eq.ra"
        fields.get_field_by_id("DEJ2000").ucd = "pos.eq.dec"
    vt.to_xml(str(path))


def test_vizier_votable_by_ucd_with_row_ids(tmp_path: Path) -> None:
    p = tmp_path / "vizier.vot"
    _vizier_votable(p)
    table = read_target_table(p)
    assert table.columns["ra_deg"] == "_RAJ2000" and table.columns["dec_deg"] == "_DEJ2000"
    assert [t.id for t in table.targets] == ["1", "2", "3"]
    assert [t.priority for t in table.targets] == [1, 1, 1]
    assert [t.ra_deg for t in table.targets] == pytest.approx([250.4235, 250.4301, 250.41])
    assert any("no id column" in n for n in table.notices)
    assert any("no priority column" in n for n in table.notices)


def test_vizier_sexagesimal_columns_with_hms_units(tmp_path: Path) -> None:
    t = Table({"RAJ2000": ["16 41 41.7", "16 41 42.0"], "DEJ2000": ["+36 27 41", "-00 30 00"],
               "Seq": [7, 8]})
    vt = from_table(t)
    f = vt.get_first_table()
    for name, ucd, unit in (("RAJ2000", "pos.eq.ra;meta.main", "h:m:s"),
                            ("DEJ2000", "pos.eq.dec;meta.main", "d:m:s"),
                            ("Seq", "meta.id;meta.main", None)):
        f.get_field_by_id(name).ucd = ucd
        if unit:
            f.get_field_by_id(name).unit = unit
    vt.to_xml(str(tmp_path / "v.vot"))
    rows = read_targets(tmp_path / "v.vot")
    assert [r["id"] for r in rows] == ["7", "8"]
    assert [r["ra_deg"] for r in rows] == pytest.approx([250.42375, 250.425])
    assert [r["dec_deg"] for r in rows] == pytest.approx([36 + 27 / 60 + 41 / 3600, -0.5])


def test_ucd_wins_over_a_misleading_name(tmp_path: Path) -> None:
    t = Table({"ra": [1.0, 2.0], "x1": [10.0, 20.0], "x2": [5.0, 6.0], "label": ["a", "b"]})
    vt = from_table(t)
    f = vt.get_first_table()
    f.get_field_by_id("x1").ucd = "pos.eq.ra;meta.main"
    f.get_field_by_id("x2").ucd = "pos.eq.dec;meta.main"
    f.get_field_by_id("label").ucd = "meta.id;meta.main"
    vt.to_xml(str(tmp_path / "t.xml"))
    rows = read_targets(tmp_path / "t.xml")
    assert [(r["id"], r["ra_deg"], r["dec_deg"]) for r in rows] == [("a", 10.0, 5.0),
                                                                   ("b", 20.0, 6.0)]


def test_gaia_archive_ecsv(tmp_path: Path) -> None:
    t = Table()
    t["source_id"] = np.array([4295806720, 38655544960], dtype=np.int64)
    t["ra"] = [45.0045, 45.0051] * u.deg
    t["dec"] = [0.0218, 0.0236] * u.deg
    t["phot_g_mean_mag"] = [17.6, 18.1]
    t.write(tmp_path / "gaia.ecsv", format="ascii.ecsv")
    rows = read_targets(tmp_path / "gaia.ecsv")
    assert [r["id"] for r in rows] == ["4295806720", "38655544960"]
    assert rows[1]["dec_deg"] == pytest.approx(0.0236)


def test_column_units_are_used(tmp_path: Path) -> None:
    t = Table({"id": ["a"], "ra": [16.694917] * u.hourangle, "dec": [0.636] * u.rad})
    t.write(tmp_path / "h.ecsv", format="ascii.ecsv")
    (row,) = read_targets(tmp_path / "h.ecsv")
    assert row["ra_deg"] == pytest.approx(16.694917 * 15)
    assert row["dec_deg"] == pytest.approx(np.degrees(0.636))


def test_mixed_ra_column_reads_each_cell_by_its_form(tmp_path: Path) -> None:
    p = tmp_path / "mixed.csv"
    p.write_text("id,ra,dec,priority\na,250.4235,36.4613,1\nb,16:41:41.7,+36:27:41,2\n"
                 "c,16h41m41.7s,36°27′41″,3\n", encoding="utf-8")
    table = read_target_table(p)
    expected = Angle("16:41:41.7", unit=u.hourangle).deg
    assert [t.ra_deg for t in table.targets] == pytest.approx([250.4235, expected, expected])
    assert expected == pytest.approx(250.42375)
    assert [t.dec_deg for t in table.targets[1:]] == pytest.approx([36 + 27 / 60 + 41 / 3600] * 2)
    (notice,) = [n for n in table.notices if "column 'ra' mixes" in n]
    assert "'ra'" in notice and "(row 1)" in notice and "(rows 2, 3)" in notice and "hours" in notice


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 359.999), st.floats(-89.99, 89.99), st.booleans()),
                min_size=1, max_size=8))
def test_sexagesimal_round_trip(tmp_path_factory, cells) -> None:
    """Angles written by astropy's own formatter (either form per row) read back to 1e-6 deg."""
    lines = ["id,ra,dec"]
    for i, (ra, dec, sexa) in enumerate(cells):
        if sexa:
            r = Angle(ra, u.deg).to_string(unit=u.hourangle, sep=":", precision=6)
            d = Angle(dec, u.deg).to_string(unit=u.deg, sep=":", precision=5, alwayssign=True)
        else:
            r, d = repr(ra), repr(dec)
        lines.append(f"t{i},{r},{d}")
    p = tmp_path_factory.mktemp("rt") / "t.csv"
    p.write_text("\n".join(lines) + "\n")
    rows = read_targets(p)
    got = np.array([[r["ra_deg"], r["dec_deg"]] for r in rows])
    want = np.array([[ra, dec] for ra, dec, _ in cells])
    dra = (got[:, 0] - want[:, 0] + 180.0) % 360.0 - 180.0
    assert np.abs(dra).max() < 1e-6 and np.abs(got[:, 1] - want[:, 1]).max() < 1e-6


@pytest.mark.parametrize("body,where,what", [
    ("id,ra,dec,priority\na,10,20,1\nb,abc,20,1\n", "row 2, line 3, column 'ra'", "'abc' is not an angle"),
    ("id,ra,dec,priority\na,10,20,1\nb,11,20,high\n", "row 2, line 3, column 'priority'",
     "'high' is not a number"),
    ("id,ra,dec,priority\na,10,95,1\n", "row 1, line 2, column 'dec'", "not in [-90, 90]"),
    ("id,ra,dec,priority\na,360.5,5,1\n", "row 1, line 2, column 'ra'", "not in [0, 360)"),
    ("id,ra,dec,priority\na,10,5,0\n", "row 1, line 2, column 'priority'", "not an integer in"),
    ("id,ra,dec,priority\na,10,5,1\na,11,5,1\n", "row 2, line 3, column 'id'", "duplicate id 'a'"),
    ("id,ra,dec,priority\na,,5,1\n", "row 1, line 2, column 'ra'", "empty ra_deg"),
    ("\nid,ra,dec\na,10,5\n\nb,10,x5\n", "row 2, line 5, column 'dec'", "not an angle"),
    ("id,ra,dec\na,12:60:00,5\n", "row 1, line 2, column 'ra'", "not an angle"),
    ("id,ra,dec\na,-01:00:00,5\n", "row 1, line 2, column 'ra'", "not in [0, 360)"),
])
def test_bad_cells_name_row_line_and_column(tmp_path: Path, body: str, where: str,
                                            what: str) -> None:
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(TargetFileError) as exc:
        read_targets(p)
    assert f"bad.csv: {where}" in str(exc.value) and what in str(exc.value)


@pytest.mark.parametrize("body", ["id,ra,dec,priority\nb,abc,20,1\n",
                                  "id,ra,dec,priority\nb,11,20,high\n"])
def test_cli_bad_cell_exit_2_without_traceback(tmp_path: Path, capsys, body: str) -> None:
    p = tmp_path / "bad.csv"
    p.write_text(body)
    assert main(["plan", str(p), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "row 1, line 2, column" in err and "Traceback" not in err
    assert not (tmp_path / "o" / "plan.json").exists()


def test_fits_table_with_bytes_ids(tmp_path: Path) -> None:
    t = Table({"NAME": np.array([b"s1", b"s2"]), "RA": [10.0, 10.1], "DEC": [-5.0, -5.1],
               "PRIORITY": np.array([3, 7], dtype=np.int32)})
    t.write(tmp_path / "t.fits")
    assert [(r["id"], r["priority"]) for r in read_targets(tmp_path / "t.fits")] == [
        ("s1", 3), ("s2", 7)]


ADVERSARIAL_CELLS = [
    lambda n: "1" * n + "x",            # a digit run that fails at its end
    lambda n: "1" * n + ".",            # ... or ends in a point
    lambda n: "1." + "1" * n + "e",     # a mantissa whose exponent is missing
    lambda n: "12:" + "1" * n + "x",    # a sexagesimal-looking run
    lambda n: "+" + "0" * n + "e+",
]


@pytest.mark.parametrize("make", ADVERSARIAL_CELLS)
def test_angle_cell_patterns_take_linear_time(make) -> None:
    """The number patterns never backtrack: 64 KB of an adversarial cell takes no longer, per
    character, than 4 KB (a quadratic pattern takes 16 times longer per character)."""
    import time

    from service.tables import _DECIMAL, _SEXAGESIMAL

    def per_char_s(n: int) -> float:
        cell = make(n)
        t0 = time.perf_counter()
        for _ in range(3):
            _DECIMAL.match(cell)
            _SEXAGESIMAL.match(cell)
        return (time.perf_counter() - t0) / (3 * len(cell))

    small, large = per_char_s(4_000), per_char_s(64_000)
    assert large < 4 * small + 1e-7, (small, large)


@given(st.from_regex(r"[+-]?[0-9.eE+x-]{0,12}", fullmatch=True))
def test_the_decimal_pattern_reads_what_float_reads(cell: str) -> None:
    """Independent oracle: a plain decimal cell is whatever Python's float() accepts among
    strings of digits, signs, points and exponents (no spaces, underscores, inf or nan)."""
    from service.tables import _DECIMAL

    try:
        float(cell)
        ok = True
    except ValueError:
        ok = False
    assert bool(_DECIMAL.match(cell)) == ok


def test_a_long_cell_is_refused_at_once_naming_the_cell_and_echoing_little(tmp_path: Path) -> None:
    import time

    p = tmp_path / "long.csv"
    for chars, bound in ((3_000, "longer than 64"), (30_000, f"longer than {MAX_CELL_CHARS}")):
        p.write_text("id,ra,dec\na,10,20\nb," + "1" * chars + "x,20\n")
        t0 = time.perf_counter()
        with pytest.raises(TargetFileError) as exc:
            read_targets(p)
        assert time.perf_counter() - t0 < 2.0
        msg = str(exc.value)
        assert "row 2, line 3, column 'ra'" in msg and bound in msg, msg
        assert len(msg) < 300


# ------------------------------------------------ checks before the table reader sees a file


@pytest.fixture
def no_reader(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if astropy's table reader is called (the checks must refuse first)."""

    def refuse(*_: object, **__: object) -> None:
        raise AssertionError("the table reader saw the file")

    monkeypatch.setattr(Table, "read", refuse)


def test_duplicate_columns_are_refused_before_the_reader_in_well_under_a_second(
        tmp_path: Path, no_reader: None) -> None:
    import time

    p = tmp_path / "d.csv"
    p.write_text(",".join(["10", "20"] + ["0"] * 19_998) + "\n")  # 40 KB, 20,000 columns
    t0 = time.perf_counter()
    with pytest.raises(TargetFileError, match="line 1 names 20000 columns; at most 1000"):
        read_targets(p)
    assert time.perf_counter() - t0 < 0.5
    p.write_text("ra,dec,x,x\n1,2,3,4\n")
    with pytest.raises(TargetFileError, match="column 4: the name 'x' repeats column 3"):
        read_targets(p)
    p.write_text("ra,dec, \n1,2,3\n")
    with pytest.raises(TargetFileError, match="line 1, column 3 has no name"):
        read_targets(p)


def test_ecsv_names_are_checked_in_either_delimiter(tmp_path: Path) -> None:
    t = Table({"id": ["a b", "c"], "ra": [1.0, 2.0], "dec": [3.0, 4.0]})
    for delimiter in (" ", ","):
        p = tmp_path / "t.ecsv"
        t.write(p, format="ascii.ecsv", delimiter=delimiter, overwrite=True)
        assert [r["id"] for r in read_targets(p)] == ["a b", "c"]
        text = p.read_text().replace(f"ra{delimiter}dec", f"ra{delimiter}ra")
        p.write_text(text)
        with pytest.raises(TargetFileError, match="the name 'ra' repeats column 2"):
            read_targets(p)


def test_the_row_limit_stops_reading_at_the_first_row_over(tmp_path: Path, no_reader: None) -> None:
    from service.table_checks import RowLimit

    p = tmp_path / "rows.csv"
    p.write_text("ra,dec\n" + "1,2\n" * 500)
    with pytest.raises(TargetFileError, match=r"more than 100 rows \(line 102\); at most 100 "
                       r"targets \(the limit\)"):
        read_target_table(p, rows=RowLimit(100, " (the limit)"))


def test_fits_headers_are_checked_before_the_data_is_read(tmp_path: Path, no_reader: None) -> None:
    from hostile_corpus import table_fits_header

    from service.table_checks import RowLimit

    p = tmp_path / "big.fits"
    p.write_bytes(table_fits_header(1000) + bytes(4000 + 2880 - 4000 % 2880))
    with pytest.raises(TargetFileError, match="HDU 1 declares 1000 rows; at most 999 targets"):
        read_target_table(p, rows=RowLimit(999))
    p.write_bytes(table_fits_header(12_000_000) + bytes(2880))  # 48 MB declared, 2880 B sent
    with pytest.raises(TargetFileError, match=r"declares 48000000 bytes of data \(12000000 rows\) "
                       "but the file holds 2880 bytes"):
        read_target_table(p)
    p.write_bytes(b"not fits")
    with pytest.raises(TargetFileError, match="cannot read as a table"):
        read_target_table(p)


def test_fits_hdus_reads_what_astropy_wrote(tmp_path: Path) -> None:
    from astropy.io import fits

    from service.table_checks import fits_hdus

    p = tmp_path / "multi.fits"
    t1 = fits.BinTableHDU(Table({"ra": np.arange(7.0), "dec": np.zeros(7, ">f4"),
                                 "mag": ["abc"] * 7}))
    t2 = fits.TableHDU.from_columns([fits.Column("x", "E10.4", array=np.arange(3.0))])
    vla = fits.BinTableHDU.from_columns([fits.Column("v", "PJ()", array=[[1, 2], [3], [4, 5, 6]])])
    fits.HDUList([fits.PrimaryHDU(np.zeros((4, 5), ">f4")), t1, t2, vla]).writeto(p)
    hdus = fits_hdus(p, "multi.fits")
    with fits.open(p) as real:
        assert [h.rows for h in hdus] == [0, 7, 3, 3]
        assert [h.table for h in hdus] == [False, True, True, True]
        padded = [-(-h.data_bytes // 2880) * 2880 for h in hdus]
        assert padded == [h._data_size for h in real]  # astropy's padded data sizes
    assert [h.data_bytes for h in hdus] == [80, 7 * 15, 3 * 10, 3 * 8 + 6 * 4]
    assert [r["ra_deg"] for r in read_targets(p)] == list(np.arange(7.0))


def test_decompression_is_bounded(tmp_path: Path) -> None:
    import bz2
    import gzip
    import lzma
    import zipfile

    from service.table_checks import decompress

    plain = b"ra,dec\n" + b"1,2\n" * 1000
    out = tmp_path / "out"
    for name, data in (("t.gz", gzip.compress(plain)), ("t.bz2", bz2.compress(plain)),
                       ("t.xz", lzma.compress(plain))):
        (tmp_path / name).write_bytes(data)
        assert decompress(tmp_path / name, out, len(plain), name)
        assert out.read_bytes() == plain
        with pytest.raises(TargetFileError, match=f"decompresses to more than {len(plain) - 1} "
                           r"bytes \(MXS_X=.*\)"):
            decompress(tmp_path / name, out, len(plain) - 1, name, "MXS_X")
    (tmp_path / "p.csv").write_bytes(plain)
    assert not decompress(tmp_path / "p.csv", out, 10, "p.csv")
    (tmp_path / "2.gz").write_bytes(gzip.compress(gzip.compress(plain)))
    with pytest.raises(TargetFileError, match="compressed twice"):
        decompress(tmp_path / "2.gz", out, 10**6, "2.gz")
    with zipfile.ZipFile(tmp_path / "t.zip", "w") as z:
        z.writestr("t.csv", plain)
    with pytest.raises(TargetFileError, match="zip archive"):
        decompress(tmp_path / "t.zip", out, 10**6, "t.zip")


def test_reader_errors_quote_at_most_100_characters(tmp_path: Path) -> None:
    p = tmp_path / "t.csv"
    p.write_text("ra,dec\n1,2,3," + "9" * 3000 + "\n")  # astropy's message quotes the line
    with pytest.raises(TargetFileError) as exc:
        read_targets(p)
    assert len(str(exc.value)) < 250, str(exc.value)
