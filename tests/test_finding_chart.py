"""Finding charts (issue 40 item 10): a synthetic FITS image made here, with a rotated (and
flipped or not) WCS and stars at known RA/Dec, is drawn about a centre a few arcmin away.

The oracle is independent of the code under test: a star's standard coordinates come from
astropy's coordinate frames (the star's unit vector in the centre's ``SkyOffsetFrame``: xi =
y/x, eta = z/x, the gnomonic projection), its chart pixel from the interface's own words (up
at position angle PA, left 90 deg counter-clockwise of up; pixel centres at (k + 0.5) * 2h / n
from the top-left corner). The code under test projects with wcslib (``models.sky``)."""

from __future__ import annotations

import gzip
import io
import math
from collections.abc import Iterator
from pathlib import Path

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord, SkyOffsetFrame
from astropy.io import fits
from astropy.table import Table
from astropy.wcs import WCS
from fastapi.testclient import TestClient
from PIL import Image

import service.finding_charts as endpoint
from models.errors import InputError
from models.finding_chart import ChartImage, read_fits_image, render_chart, stretch
from models.sky import sky_to_focal_mm
from service.app import create_app
from service.settings import Settings

RA0, DEC0 = 150.0, 20.0  # the image's reference point
SIZE_PX = 256
HALF_ARCMIN = 2.5
SIGMA_PX = 1.5  # the stars' Gaussian width in image pixels
NOISE = 1.0
SKY = 100.0


# ------------------------------------------------------------------------ the oracle


def offset_arcmin(centre: SkyCoord, star: SkyCoord) -> tuple[float, float]:
    """(xi East, eta North) of ``star`` about ``centre``, arcmin, gnomonic: the star's unit
    vector in the centre's offset frame (x toward the centre, y East, z North)."""
    c = star.transform_to(SkyOffsetFrame(origin=centre)).cartesian
    x, y, z = float(c.x), float(c.y), float(c.z)
    return math.degrees(y / x) * 60.0, math.degrees(z / x) * 60.0


def expected_pixel(centre: SkyCoord, star: SkyCoord, up_pa_deg: float,
                   half_arcmin: float = HALF_ARCMIN, size_px: int = SIZE_PX
                   ) -> tuple[float, float]:
    """(col, row) where the interface puts ``star``: its offset along the up direction (PA) and
    along the left one (PA + 90), counted from the top-left corner in pixels, centres at k."""
    xi, eta = offset_arcmin(centre, star)
    up = (math.sin(math.radians(up_pa_deg)), math.cos(math.radians(up_pa_deg)))
    left = (math.sin(math.radians(up_pa_deg + 90)), math.cos(math.radians(up_pa_deg + 90)))
    along_left = xi * left[0] + eta * left[1]
    along_up = xi * up[0] + eta * up[1]
    step = 2.0 * half_arcmin / size_px
    return (half_arcmin - along_left) / step - 0.5, (half_arcmin - along_up) / step - 0.5


# ------------------------------------------------------------------ synthetic images


def image_wcs(rot_deg: float, flip: bool, n_px: int = 300, scale_arcsec: float = 1.0,
              frame: str = "icrs") -> WCS:
    """A TAN WCS about (RA0, Dec0) whose pixel axes are turned by ``rot_deg``; ``flip``: East
    to the left of the pixel grid (as most survey images), else East to the right."""
    w = WCS(naxis=2)
    if frame == "galactic":
        w.wcs.ctype = ["GLON-TAN", "GLAT-TAN"]
        g = SkyCoord(RA0 * u.deg, DEC0 * u.deg).galactic
        w.wcs.crval = [g.l.deg, g.b.deg]
    else:
        w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
        w.wcs.crval = [RA0, DEC0]
    w.wcs.crpix = [n_px / 2 + 0.5, n_px / 2 + 0.5]
    s, t = scale_arcsec / 3600.0, math.radians(rot_deg)
    sx = -s if flip else s
    w.wcs.cd = [[sx * math.cos(t), -s * math.sin(t)], [sx * math.sin(t), s * math.cos(t)]]
    return w


def star_image(wcs: WCS, stars: list[tuple[SkyCoord, float]], n_px: int = 300,
               seed: int = 1) -> np.ndarray:
    """A noisy sky with a Gaussian star of each (position, peak) placed by astropy's WCS."""
    rng = np.random.default_rng(seed)
    data = SKY + rng.normal(0.0, NOISE, (n_px, n_px))
    rows, cols = np.mgrid[:n_px, :n_px]
    for where, peak in stars:
        x, y = wcs.world_to_pixel(where)
        data += peak * np.exp(-((cols - x) ** 2 + (rows - y) ** 2) / (2 * SIGMA_PX ** 2))
    return data


def fits_bytes(data: np.ndarray, wcs: WCS | None) -> bytes:
    header = wcs.to_header() if wcs is not None else None
    buf = io.BytesIO()
    fits.PrimaryHDU(data.astype(np.float32), header).writeto(buf)
    return buf.getvalue()


def sky(ra_off_arcmin: float, dec_off_arcmin: float) -> SkyCoord:
    """A position offset from (RA0, Dec0) by about these arcmin East and North."""
    return SkyCoord((RA0 + ra_off_arcmin / 60.0 / math.cos(math.radians(DEC0))) * u.deg,
                    (DEC0 + dec_off_arcmin / 60.0) * u.deg)


STAR = sky(1.0, 0.6)  # the bright star
CENTRE = sky(-0.4, -0.3)  # the chart's centre, about 1.5 arcmin from it


def peak_of(values: np.ndarray) -> tuple[float, float]:
    """(col, row) of the brightest pixel; the centroid of them when several tie."""
    top = np.nanmax(values)
    rows, cols = np.nonzero(values == top)
    return float(cols.mean()), float(rows.mean())


def chart_of(rot_deg: float, flip: bool, up_pa_deg: float, frame: str = "icrs") -> ChartImage:
    wcs = image_wcs(rot_deg, flip, frame=frame)
    image = read_fits_image(fits_bytes(star_image(wcs, [(STAR, 500.0)]), wcs))
    return render_chart(image, CENTRE.ra.deg, CENTRE.dec.deg, HALF_ARCMIN, up_pa_deg, SIZE_PX)


# ------------------------------------------------------------------ the geometry


@pytest.mark.parametrize("rot_deg,flip", [(30.0, True), (30.0, False), (-117.0, True)])
@pytest.mark.parametrize("up_pa_deg", [0.0, 40.0, -125.0])
def test_the_star_peaks_where_the_interface_puts_it(rot_deg: float, flip: bool,
                                                    up_pa_deg: float) -> None:
    chart = chart_of(rot_deg, flip, up_pa_deg)
    assert chart.values.shape == (SIZE_PX, SIZE_PX)
    col, row = peak_of(chart.values)
    want_col, want_row = expected_pixel(CENTRE, STAR, up_pa_deg)
    assert abs(col - want_col) <= 1.0 and abs(row - want_row) <= 1.0, (col, row, want_col,
                                                                      want_row)
    got = chart.pixel_of(STAR.ra.deg, STAR.dec.deg)
    assert got == pytest.approx((want_col, want_row), abs=1e-3)


def test_east_is_left_and_north_is_up_at_pa_0() -> None:
    chart = chart_of(30.0, True, 0.0)
    col, row = peak_of(chart.values)
    assert STAR.ra.deg > CENTRE.ra.deg and STAR.dec.deg > CENTRE.dec.deg  # east and north
    assert col < SIZE_PX / 2 and row < SIZE_PX / 2
    assert chart.orientation_line() == "Sky as seen: North up, East left"


def test_at_pa_90_east_is_up_and_south_is_left() -> None:
    east = sky(1.5, 0.0)
    wcs = image_wcs(30.0, True)
    image = read_fits_image(fits_bytes(star_image(wcs, [(east, 500.0)]), wcs))
    chart = render_chart(image, RA0, DEC0, HALF_ARCMIN, 90.0, SIZE_PX)
    col, row = peak_of(chart.values)
    assert row < SIZE_PX / 2 - 20 and abs(col - (SIZE_PX / 2 - 0.5)) <= 1.0
    assert "PA 90" in chart.orientation_line()


@pytest.mark.parametrize("pa_deg", [0.0, 33.0, 250.0])
def test_at_the_pointing_pa_left_is_focal_plane_x_and_up_is_y(pa_deg: float) -> None:
    """The chart lines up with the focal plane drawn +x leftwards and +y up (models.sky)."""
    plate_arcsec_per_mm = 1.2
    x_mm, y_mm = sky_to_focal_mm(STAR.ra.deg, STAR.dec.deg, CENTRE.ra.deg, CENTRE.dec.deg,
                                 plate_arcsec_per_mm, pa_deg)
    chart = chart_of(30.0, True, pa_deg)
    col, row = peak_of(chart.values)
    step_mm = 2.0 * HALF_ARCMIN * 60.0 / plate_arcsec_per_mm / SIZE_PX
    assert abs(col - (SIZE_PX / 2 - 0.5 - float(x_mm) / step_mm)) <= 1.0
    assert abs(row - (SIZE_PX / 2 - 0.5 - float(y_mm) / step_mm)) <= 1.0


def test_an_image_in_galactic_coordinates_is_placed_by_its_own_frame() -> None:
    chart = chart_of(10.0, True, 0.0, frame="galactic")
    col, row = peak_of(chart.values)
    want_col, want_row = expected_pixel(CENTRE, STAR, 0.0)
    assert abs(col - want_col) <= 1.0 and abs(row - want_row) <= 1.0


@pytest.mark.parametrize("ra0,dec0,up_pa_deg", [(0.005, -30.0, 0.0), (359.99, 10.0, 70.0),
                                                (200.0, 89.98, 0.0), (20.0, -89.99, 300.0)])
def test_across_ra_0_and_near_the_poles(ra0: float, dec0: float, up_pa_deg: float) -> None:
    centre = SkyCoord(ra0 * u.deg, dec0 * u.deg)
    star = centre.directional_offset_by(50 * u.deg, 1.2 * u.arcmin)
    wcs = image_wcs(25.0, True)
    wcs.wcs.crval = [(ra0 + 0.01) % 360.0, dec0]
    wcs.wcs.set()
    image = read_fits_image(fits_bytes(star_image(wcs, [(star, 500.0)]), wcs))
    chart = render_chart(image, centre.ra.deg, centre.dec.deg, HALF_ARCMIN, up_pa_deg, SIZE_PX)
    col, row = peak_of(chart.values)
    want_col, want_row = expected_pixel(centre, star, up_pa_deg)
    assert abs(col - want_col) <= 1.0 and abs(row - want_row) <= 1.0, (col, row, want_col,
                                                                      want_row)


def test_a_cube_with_one_plane_is_read_as_its_image() -> None:
    wcs2 = image_wcs(30.0, True)
    header = wcs2.to_header()
    header["WCSAXES"] = 3
    header["CTYPE3"], header["CRVAL3"], header["CDELT3"], header["CRPIX3"] = "FREQ", 1e9, 1e6, 1
    data = star_image(wcs2, [(STAR, 500.0)])[np.newaxis].astype(np.float32)
    buf = io.BytesIO()
    fits.PrimaryHDU(data, header).writeto(buf)
    image = read_fits_image(buf.getvalue())
    assert image.shape == (300, 300) and image.wcs.naxis == 2
    chart = render_chart(image, CENTRE.ra.deg, CENTRE.dec.deg, HALF_ARCMIN, 0.0, SIZE_PX)
    col, row = peak_of(chart.values)
    want_col, want_row = expected_pixel(CENTRE, STAR, 0.0)
    assert abs(col - want_col) <= 1.0 and abs(row - want_row) <= 1.0


def test_the_image_in_an_extension_after_a_table_is_found() -> None:
    wcs = image_wcs(30.0, True)
    hdus = fits.HDUList([fits.PrimaryHDU(), fits.BinTableHDU(Table({"a": [1, 2]})),
                         fits.ImageHDU(star_image(wcs, [(STAR, 500.0)]).astype(np.float32),
                                       wcs.to_header())])
    buf = io.BytesIO()
    hdus.writeto(buf)
    image = read_fits_image(buf.getvalue())
    assert image.shape == (300, 300)


# ------------------------------------------------------------ coverage and stretch


def test_sky_the_image_does_not_cover_is_blank_and_transparent() -> None:
    wcs = image_wcs(30.0, True, n_px=100)
    data = star_image(wcs, [], n_px=100)
    data[40:60, 40:60] = np.nan  # blank pixels inside the image
    image = read_fits_image(fits_bytes(data, wcs))
    chart = render_chart(image, RA0, DEC0, 2.0, 0.0, 128)  # 4' across, the image 1.7'
    v = chart.values
    assert np.isnan(v[0, 0]) and np.isnan(v[-1, -1])  # outside the image
    assert np.isnan(v[63, 63])  # its blank middle
    assert np.isfinite(v[64 - 30, 64])  # covered
    la = np.asarray(Image.open(io.BytesIO(chart.to_png())))
    assert la.shape == (128, 128, 2)
    assert (la[..., 1] == np.where(np.isfinite(v), 255, 0)).all()


def test_the_stretch_shows_a_faint_star_and_keeps_the_bright_peak() -> None:
    faint, bright = sky(-1.0, 0.8), sky(0.8, -0.7)
    wcs = image_wcs(30.0, True)
    image = read_fits_image(fits_bytes(star_image(wcs, [(faint, 5.0 * NOISE),
                                                        (bright, 5000.0 * NOISE)]), wcs))
    chart = render_chart(image, RA0, DEC0, HALF_ARCMIN, 0.0, SIZE_PX)
    v = chart.values
    background = float(np.nanmedian(v))
    fc, fr = chart.pixel_of(faint.ra.deg, faint.dec.deg)
    faint_level = float(v[round(fr) - 1:round(fr) + 2, round(fc) - 1:round(fc) + 2].mean())
    # a linear min-max scale puts this star 0.001 above the sky; shown, it stands out
    assert faint_level - background > 0.2
    assert 0.0 <= np.nanmin(v) and np.nanmax(v) <= 1.0
    col, row = peak_of(v)
    bc, br = chart.pixel_of(bright.ra.deg, bright.dec.deg)
    assert abs(col - bc) <= 1.0 and abs(row - br) <= 1.0
    assert int((v == np.nanmax(v)).sum()) == 1  # the bright core is not saturated


def test_the_stretch_of_a_flat_image_is_defined() -> None:
    flat = np.full((8, 8), 7.0)
    flat[0, 0] = np.nan
    out = stretch(flat)
    assert np.isnan(out[0, 0]) and np.isfinite(out[1:, 1:]).all()


def test_the_png_is_inverted_grey() -> None:
    chart = chart_of(30.0, True, 0.0)
    la = np.asarray(Image.open(io.BytesIO(chart.to_png())))
    col, row = peak_of(chart.values)
    grey = la[..., 0].astype(float)
    assert grey[round(row), round(col)] < 30  # the star is dark
    assert np.median(grey[la[..., 1] > 0]) > 100  # the sky light


# ------------------------------------------------------------------- bad images


def test_bytes_that_are_not_fits_are_refused_naming_the_field() -> None:
    with pytest.raises(InputError, match="not a FITS image: the file does not start with a "
                       "FITS header") as info:
        read_fits_image(b"id,ra_deg,dec_deg\nA,1,2\n")
    assert info.value.field == "image"


def test_a_wcs_that_cannot_place_pixels_is_an_input_error(monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    wcs = image_wcs(0.0, True, n_px=20)
    image = read_fits_image(fits_bytes(np.zeros((20, 20)), wcs))

    def broken(*_: object, **__: object) -> None:
        raise ValueError("singular matrix")

    monkeypatch.setattr(image.wcs, "all_world2pix", broken)
    with pytest.raises(InputError, match="its WCS cannot place the chart's pixels") as info:
        render_chart(image, RA0, DEC0, 1.0, 0.0, 16)
    assert info.value.field == "image"


def test_a_fits_table_is_not_an_image() -> None:
    buf = io.BytesIO()
    fits.HDUList([fits.PrimaryHDU(), fits.BinTableHDU(Table({"a": [1]}))]).writeto(buf)
    with pytest.raises(InputError, match="not a FITS image"):
        read_fits_image(buf.getvalue())


def test_an_image_without_a_celestial_wcs_is_refused() -> None:
    with pytest.raises(InputError, match="no celestial WCS") as info:
        read_fits_image(fits_bytes(np.zeros((20, 20)), None))
    assert info.value.field == "image"


def test_an_image_over_the_pixel_cap_is_refused_before_its_data_is_read() -> None:
    header = image_wcs(0.0, True).to_header()
    hdu = fits.PrimaryHDU(np.zeros((200, 300), np.float32), header)
    raw = hdu.header.tostring().encode()  # the header alone: the data is never read
    with pytest.raises(InputError, match="image larger than 50000 pixels"):
        read_fits_image(raw, max_pixels=50_000)


def test_a_gzipped_image_reads_as_the_plain_one() -> None:
    raw = _star_fits()
    plain, zipped = read_fits_image(raw), read_fits_image(gzip.compress(raw))
    assert np.array_equal(plain.data, zipped.data)
    assert plain.wcs.to_header_string() == zipped.wcs.to_header_string()


def test_a_gzip_bomb_is_refused_at_the_pixel_cap() -> None:
    raw = gzip.compress(fits_bytes(np.zeros((400, 400)), image_wcs(0.0, True, n_px=400)))
    with pytest.raises(InputError, match="image larger than 10000 pixels") as info:
        read_fits_image(raw, max_pixels=10_000)
    assert info.value.field == "image"


def test_chart_arguments_are_checked_naming_each() -> None:
    wcs = image_wcs(0.0, True, n_px=20)
    image = read_fits_image(fits_bytes(np.zeros((20, 20)), wcs))
    for kwargs, field in (({"ra_deg": 361.0}, "ra_deg"), ({"dec_deg": -91.0}, "dec_deg"),
                          ({"half_width_arcmin": 0.0}, "half_width_arcmin"),
                          ({"up_pa_deg": math.inf}, "up_pa_deg"), ({"size_px": 0}, "size_px")):
        args = {"ra_deg": RA0, "dec_deg": DEC0, "half_width_arcmin": 1.0, "up_pa_deg": 0.0,
                "size_px": 16, **kwargs}
        with pytest.raises(InputError) as info:
            render_chart(image, **args)
        assert info.value.field == field


# ------------------------------------------------------------------- the endpoint


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    db = tmp_path_factory.mktemp("charts") / "jobs.sqlite3"
    settings = Settings(job_db=db, workers=1, max_body_bytes=2_000_000,
                        upload_parse_memory_bytes=60_000_000)
    with TestClient(create_app(settings)) as c:
        yield c


FORM = {"ra_deg": CENTRE.ra.deg, "dec_deg": CENTRE.dec.deg, "half_width_arcmin": HALF_ARCMIN,
        "size_px": SIZE_PX}


def _star_fits() -> bytes:
    wcs = image_wcs(30.0, True)
    return fits_bytes(star_image(wcs, [(STAR, 500.0)]), wcs)


def _post(c: TestClient, raw: bytes, **form: object) -> object:
    return c.post("/v1/finding-charts", files={"image": ("cutout.fits", raw)},
                  data={**FORM, **form})


@pytest.mark.parametrize("up_pa_deg", [0.0, 40.0])
def test_the_endpoint_answers_a_png_whose_peak_is_the_star(client: TestClient,
                                                           up_pa_deg: float) -> None:
    r = _post(client, _star_fits(), up_pa_deg=up_pa_deg)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png"
    la = np.asarray(Image.open(io.BytesIO(r.content)))
    assert la.shape == (SIZE_PX, SIZE_PX, 2)
    brightness = np.where(la[..., 1] > 0, 255.0 - la[..., 0], np.nan)  # inverted grey
    col, row = peak_of(brightness)
    want_col, want_row = expected_pixel(CENTRE, STAR, up_pa_deg)
    assert abs(col - want_col) <= 1.0 and abs(row - want_row) <= 1.0


def test_the_endpoint_defaults_to_512_px_north_up(client: TestClient) -> None:
    form = {k: v for k, v in FORM.items() if k != "size_px"}
    r = client.post("/v1/finding-charts", files={"image": ("c.fits", _star_fits())}, data=form)
    la = np.asarray(Image.open(io.BytesIO(r.content)))
    assert la.shape == (512, 512, 2)
    col, row = peak_of(np.where(la[..., 1] > 0, 255.0 - la[..., 0], np.nan))
    want_col, want_row = expected_pixel(CENTRE, STAR, 0.0, size_px=512)
    assert abs(col - want_col) <= 1.0 and abs(row - want_row) <= 1.0


@pytest.mark.parametrize("field,value", [
    ("ra_deg", 360.5), ("ra_deg", "nan"), ("dec_deg", 90.5), ("half_width_arcmin", 0),
    ("half_width_arcmin", 61), ("up_pa_deg", "inf"), ("size_px", 15), ("size_px", 2049),
    ("size_px", "many")])
def test_bad_form_fields_are_422_naming_the_field(client: TestClient, field: str,
                                                  value: object) -> None:
    r = _post(client, _star_fits(), **{field: value})
    assert r.status_code == 422
    assert ["body", field] in [d["loc"] for d in r.json()["detail"]]


def test_a_missing_image_is_422_naming_it(client: TestClient) -> None:
    r = client.post("/v1/finding-charts", data=FORM)
    assert r.status_code == 422
    assert ["body", "image"] in [d["loc"] for d in r.json()["detail"]]


@pytest.mark.parametrize("raw,words", [
    (b"\x89PNG\r\n\x1a\n" + b"\0" * 100, "not a FITS image"),
    (fits_bytes(np.zeros((20, 20)), None), "no celestial WCS"),
    (_star_fits()[:5000], "not a FITS image")], ids=["png", "no-wcs", "truncated"])
def test_a_bad_image_is_422_naming_image(client: TestClient, raw: bytes, words: str) -> None:
    r = _post(client, raw)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "image"]
    assert words in r.json()["message"]


def test_an_image_over_the_pixel_cap_is_422(client: TestClient,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(endpoint, "MAX_CHART_IMAGE_PIXELS", 80_000)
    r = _post(client, _star_fits())
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "image"]
    assert "image larger than 80000 pixels" in r.json()["message"]


def test_a_body_over_the_limit_is_413(client: TestClient) -> None:
    r = _post(client, b"SIMPLE  = " + b" " * 2_100_000)
    assert r.status_code == 413


def test_an_image_needing_more_memory_than_the_limit_is_413(client: TestClient) -> None:
    """A gzip-compressed 3,000 x 3,000 float64 image: 40 kB sent, 72 MB once read, over the
    60 MB the drawing process may take here."""
    wcs = image_wcs(0.0, True, n_px=3000)
    buf = io.BytesIO()
    fits.PrimaryHDU(np.zeros((3000, 3000)), wcs.to_header()).writeto(buf)
    raw = gzip.compress(buf.getvalue())
    assert len(raw) < 2_000_000
    r = _post(client, raw)
    assert r.status_code == 413, r.text
    assert "MXS_UPLOAD_PARSE_MEMORY_BYTES" in r.json()["detail"]


def test_a_draw_past_the_time_limit_is_stopped_with_a_422(tmp_path: Path) -> None:
    settings = Settings(job_db=tmp_path / "jobs.sqlite3", workers=1, upload_parse_time_s=0.001)
    with TestClient(create_app(settings)) as c:
        r = _post(c, _star_fits())
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "image"]
    assert "MXS_UPLOAD_PARSE_TIME_S" in r.json()["message"]


def test_the_document_describes_the_png(client: TestClient) -> None:
    op = client.get("/openapi.json").json()["paths"]["/v1/finding-charts"]["post"]
    assert "image/png" in op["responses"]["200"]["content"]
    assert {"401", "413", "422", "503"} <= set(op["responses"])
