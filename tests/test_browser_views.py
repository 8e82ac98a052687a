"""The page's pictures in Chromium (issue 40): one orientation (the sky as seen, North up and
East left), labels laid out without overlaps in crowded fields, a legend of what each picture
holds, sexagesimal coordinates, and a finding chart drawn under the targets.

Positions are checked against the server's own projection (models.sky) and astropy, never
against the page's code. Screenshots go to $MXS_ARTEFACTS (default: the test's tmp_path)."""

from __future__ import annotations

import base64
import io
import math
import os
from pathlib import Path

import numpy as np
import test_browser
from astropy import units as u
from astropy.coordinates import Angle, SkyCoord

from models.sky import sky_to_focal_mm

# The uvicorn server, Chromium and page fixtures of the page's other browser tests.
server, browser, page = test_browser.server, test_browser.browser, test_browser.page

ROOT = Path(__file__).resolve().parents[1]
M67 = ROOT / "tests" / "data" / "m67-like-150-vizier.csv"
FOCAL_CONVENTION = "Sky as seen: North up, East left (focal-plane +x drawn leftwards)"
PLATE_SCALE = 1.2  # arcsec/mm of the default instrument (GET /v1/instrument is checked below)


def _artefacts(tmp_path: Path) -> Path:
    out = Path(os.environ.get("MXS_ARTEFACTS") or tmp_path)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _plan_on_page(page, server: str, *, file: Path | None = None, csv_text: str | None = None,
                  time_limit_s: float = 20, pa_deg: float = 0.0) -> dict:
    page.goto(server + "/")
    page.fill("#pa", str(pa_deg))
    if file is not None:
        page.set_input_files("#file", str(file))
    else:
        page.fill("#targets", csv_text)
    page.fill("#time-limit", str(time_limit_s))
    page.click("#go")
    page.wait_for_selector("#result:not([hidden])", timeout=120_000)
    page.wait_for_function("!document.querySelector('#go').disabled")
    assert page.evaluate("mxs.state.instrument.plate_scale_arcsec_per_mm") == PLATE_SCALE
    return page.evaluate("({result: mxs.state.result, request: mxs.state.request})")


def _pointing_pa(p: dict, request: dict) -> float:
    pa = p.get("position_angle_deg")
    return request.get("position_angle_deg", 0.0) if pa is None else pa


# ------------------------------------------------------------------ orientation

_SCREEN_MARKS = """(sel) => {
  const root = document.querySelector(sel);
  const c = root.querySelector('circle.fov, circle.pointing-fov').getBoundingClientRect();
  const s = root.getBoundingClientRect();
  const marks = [...root.querySelectorAll('[data-id]')].map((n) => {
    const r = n.getBoundingClientRect();
    return {id: n.dataset.id, x: r.x + r.width / 2, y: r.y + r.height / 2};
  });
  return {fov: {x: c.x + c.width / 2, y: c.y + c.height / 2, w: c.width},
          svg: {x: s.x + s.width / 2, y: s.y + s.height / 2}, marks};
}"""


def _check_configuration_orientation(page, p: dict, request: dict, byid: dict) -> int:
    """Every target marker of the first configuration sits where the server's projection puts
    it, drawn with focal-plane +x to the left and +y up; a target east of the centre is left of it
    at PA 0; the compass's East is 90 deg counter-clockwise of North on the screen."""
    sel = f".pointing[data-pointing='{p['id']}'] svg[data-configuration]"
    got = page.evaluate(_SCREEN_MARKS, sel)
    pa = _pointing_pa(p, request)
    px_per_mm = got["fov"]["w"] / 250.0
    ids = [m["id"] for m in got["marks"]]
    x_mm, y_mm = sky_to_focal_mm([byid[i]["ra_deg"] for i in ids], [byid[i]["dec_deg"] for i in ids],
                                 p["ra_deg"], p["dec_deg"], PLATE_SCALE, pa)
    for m, x, y in zip(got["marks"], x_mm, y_mm, strict=True):
        assert abs((m["x"] - got["fov"]["x"]) - (-x * px_per_mm)) < 0.6, m  # +x drawn leftwards
        assert abs((m["y"] - got["fov"]["y"]) - (-y * px_per_mm)) < 0.6, m  # +y drawn up
    centre = SkyCoord(p["ra_deg"] * u.deg, p["dec_deg"] * u.deg)
    east = [m for m in got["marks"] if centre.spherical_offsets_to(
        SkyCoord(byid[m["id"]]["ra_deg"] * u.deg, byid[m["id"]]["dec_deg"] * u.deg))[0].arcsec > 20]
    if abs(pa) < 1e-9:
        assert all(m["x"] < got["fov"]["x"] for m in east)
    arrows = page.evaluate("""(sel) => Object.fromEntries([...document.querySelector(sel)
        .querySelectorAll('.compass line')].map((l) => [l.dataset.dir,
        [l.x2.baseVal.value - l.x1.baseVal.value, l.y2.baseVal.value - l.y1.baseVal.value]]))""", sel)
    (nx, ny), (ex, ey) = arrows["N"], arrows["E"]
    t = math.radians(pa)  # North on the sky is PA degrees clockwise of the picture's up
    assert abs(math.remainder(math.atan2(nx, -ny) - t, 2 * math.pi)) < 1e-6
    assert abs(math.remainder(math.atan2(-ey, ex) - math.atan2(-ny, nx) - math.pi / 2, 2 * math.pi)) < 1e-6
    assert page.locator(sel + " text.convention").text_content() == FOCAL_CONVENTION
    return len(east) if abs(pa) < 1e-9 else 0


def _check_sky_orientation(page, result: dict, request: dict) -> None:
    """The sky view: xi (East) leftwards and eta (North) up about the tangent point, in
    arcmin (the server's TAN projection at 60 arcsec per unit)."""
    got = page.evaluate(_SCREEN_MARKS, "svg.sky")
    tp = result.get("tangent_point") or result["pointings"][0]
    byid = {t["id"]: t for t in request["targets"]}
    ids = [m["id"] for m in got["marks"]]
    xi, eta = sky_to_focal_mm([byid[i]["ra_deg"] for i in ids], [byid[i]["dec_deg"] for i in ids],
                              tp["ra_deg"], tp["dec_deg"], 60.0, 0.0)
    scale = got["fov"]["w"] / (2 * 125.0 * PLATE_SCALE / 60)  # px per arcmin: a FOV is 250 mm across
    for m, x, y in zip(got["marks"], xi, eta, strict=True):
        assert abs((m["x"] - got["svg"]["x"]) + x * scale) < 0.6, m  # East leftwards
        assert abs((m["y"] - got["svg"]["y"]) + y * scale) < 0.6, m  # North up
    assert page.locator("svg.sky text.convention").text_content() == "Sky as seen: North up, East left"


# ------------------------------------------------------------------ labels and legends

_LABEL_BOXES = """(sel) => {
  const root = document.querySelector(sel);
  const box = (b) => [b.x, b.y, b.x + b.width, b.y + b.height];
  return {
    labels: [...root.querySelectorAll('g.labels text')].map((t) => ({
      id: t.dataset.for, box: box(t.getBBox()), estimate: t.dataset.box.split(' ').map(Number)})),
    markers: [...root.querySelectorAll('[data-id]')].map((m) => ({id: m.dataset.id,
      box: box(m.getBBox()), title: m.querySelector('title').textContent})),
  };
}"""


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _check_labels(page, sel: str) -> dict:
    """No two labels overlap (the text boxes Chromium measured), no label covers a marker, and
    each measured box lies inside the box the layout estimated for it."""
    got = page.evaluate(_LABEL_BOXES, sel)
    labels = got["labels"]
    assert labels
    for lab in labels:
        b, e = lab["box"], lab["estimate"]
        assert e[0] - 1e-6 <= b[0] and b[2] <= e[2] + 1e-6 and e[1] - 1e-6 <= b[1] and b[3] <= e[3] + 1e-6, lab
    for i, a in enumerate(labels):
        for b in labels[i + 1:]:
            assert not _overlap(a["box"], b["box"]), (a, b)
    if ".sky" not in sel:  # the sky's markers are scaled symbols; their boxes are checked below
        for lab in labels:
            for m in got["markers"]:
                assert not _overlap(lab["box"], m["box"]), (lab, m)
    return got


def _legend_kinds(page, sel: str) -> set[str]:
    return set(page.evaluate("""(sel) => [...document.querySelector(sel).closest('.viewer')
        .querySelectorAll('.legend li[data-kind]')].map((li) => li.dataset.kind)""", sel))


def _expected_configuration_kinds(p: dict) -> set[str]:
    first = p["configurations"][0]["assignments"]
    later = {a["target_id"] for c in p["configurations"][1:] for a in c["assignments"] if a["target_id"]}
    now = {a["target_id"] for a in first if a["target_id"]}
    kinds = {f"arm-{a['kind'] or ('target' if a['target_id'] else 'park')}" for a in first}
    kinds |= {"target-this"} if now else set()
    kinds |= {"target-pending"} if later else set()
    kinds |= {"target-unallocated"} if set(p["target_ids"]) - now - later else set()
    return kinds


def _expected_sky_kinds(result: dict, request: dict) -> set[str]:
    observed = {a["target_id"] for p in result["pointings"] for c in p["configurations"]
                for a in c["assignments"] if a["target_id"]}
    kinds = {"pointing-label"} | {"fov-executable" if p["executable"] else "fov-not-executable"
                                  for p in result["pointings"]}
    kinds |= {"sky-observed"} if observed else set()
    kinds |= {"sky-unobserved"} if {t["id"] for t in request["targets"]} - observed else set()
    return kinds


def _sexagesimal(ra_deg: float, dec_deg: float) -> str:
    ra = Angle(ra_deg, u.deg).to_string(unit=u.hour, sep="hms", precision=2, pad=True)
    dec = Angle(dec_deg, u.deg).to_string(unit=u.deg, sep=("°", "′", "″"), precision=1, pad=True,
                                          alwayssign=True).replace("-", "−")
    return f"{ra} {dec} ({ra_deg:.5f}°"


# ------------------------------------------------------------------ the tests


def test_m67_views(page, server, tmp_path: Path) -> None:
    """The 150-star M67-like VizieR table: orientation, labels, legends and coordinates."""
    got = _plan_on_page(page, server, file=M67, time_limit_s=10)
    result, request = got["result"], got["request"]
    byid = {t["id"]: t for t in request["targets"]}
    out = _artefacts(tmp_path)
    page.screenshot(path=str(out / "m67_page.png"), full_page=True)
    _check_sky_orientation(page, result, request)
    _check_labels(page, "svg.sky")
    assert _legend_kinds(page, "svg.sky") == _expected_sky_kinds(result, request)
    # every pointing is named beside its circle, and no name sits on a target's marker
    names = page.evaluate("""() => { const box = (b) => [b.x, b.y, b.x + b.width, b.y + b.height];
        return {names: [...document.querySelectorAll('svg.sky text.pointing-label')].map((t) => box(t.getBBox())),
                marks: [...document.querySelectorAll('svg.sky .sky-target')].map((m) => box(m.getBoundingClientRect()))}; }""")
    assert len(names["names"]) == len(result["pointings"])
    screen_names = page.evaluate("""() => [...document.querySelectorAll('svg.sky text.pointing-label')]
        .map((t) => { const b = t.getBoundingClientRect(); return [b.x, b.y, b.x + b.width, b.y + b.height]; })""")
    assert not any(_overlap(n, m) for n in screen_names for m in names["marks"])
    assert _sexagesimal(*(lambda t: (t["ra_deg"], t["dec_deg"]))(result.get("tangent_point") or result["pointings"][0])) \
        in page.inner_text(".field h3")
    east_at_pa0 = 0
    for p in result["pointings"]:
        if not p["configurations"]:
            continue
        sel = f".pointing[data-pointing='{p['id']}'] svg[data-configuration]"
        east_at_pa0 += _check_configuration_orientation(page, p, request, byid)
        _check_labels(page, sel)
        assert _legend_kinds(page, sel) == _expected_configuration_kinds(p)
        assert _sexagesimal(p["ra_deg"], p["dec_deg"]) in page.inner_text(
            f".pointing[data-pointing='{p['id']}'] h3")
    assert east_at_pa0 > 0  # targets east of a centre at PA 0, all drawn left of it
    page.locator(".field").screenshot(path=str(out / "m67_sky.png"))
    page.locator(".pointing svg[data-configuration]").first.screenshot(path=str(out / "m67_c1.png"))


def _crowded_csv(n: int = 475, seed: int = 40) -> str:
    """n stars within 2.2 arcmin of one centre (one 2.5-arcmin-radius FOV), priorities 1-4."""
    rng = np.random.default_rng(seed)
    r = 2.2 / 60 * np.sqrt(rng.uniform(0, 1, n))
    th = rng.uniform(0, 2 * np.pi, n)
    ra0, dec0 = 132.85, 11.80
    rows = [f"s{i},{ra0 + r[i] * np.cos(th[i]) / np.cos(np.radians(dec0)):.7f},"
            f"{dec0 + r[i] * np.sin(th[i]):.7f},{1 + i % 4}" for i in range(n)]
    return "id,ra,dec,priority\n" + "\n".join(rows) + "\n"


def test_crowded_field_labels(page, server, tmp_path: Path) -> None:
    """475 stars in one field: labels never overlap, in several configurations; a star whose
    label found no place keeps its id on hover (title) and on tap."""
    got = _plan_on_page(page, server, csv_text=_crowded_csv(), time_limit_s=8)
    result, request = got["result"], got["request"]
    byid = {t["id"]: t for t in request["targets"]}
    p = max(result["pointings"], key=lambda q: len(q["configurations"]))
    assert len(p["target_ids"]) > 300 and len(p["configurations"]) > 3
    _check_configuration_orientation(page, p, request, byid)
    sec = f".pointing[data-pointing='{p['id']}']"
    sel = sec + " svg[data-configuration]"
    out = _artefacts(tmp_path)
    for k in (0, len(p["configurations"]) // 2):
        page.locator(sec + " .stepper button").nth(k).click()
        shown = _check_labels(page, sel)
        page.locator(sel).screenshot(path=str(out / f"crowded_c{k + 1}.png"))
    labelled = {lab["id"] for lab in shown["labels"]}
    pending = page.evaluate(f"""() => [...document.querySelectorAll("{sel} .target.pending")].map((m) => m.dataset.id)""")
    hidden = [i for i in pending if i not in labelled]
    assert hidden, "a crowded field where every label fits tests nothing"
    titles = {m["id"]: m["title"] for m in shown["markers"]}
    assert all(titles[i].startswith(f"{i} (priority ") for i in hidden)
    page.evaluate(f"""(id) => document.querySelector(`{sel} [data-id="${{id}}"]`)
        .dispatchEvent(new MouseEvent('click', {{bubbles: true}}))""", hidden[0])
    assert page.inner_text(sec + " .picked").startswith(f"{hidden[0]} (priority ")
    _check_labels(page, "svg.sky")
    page.locator(".field").screenshot(path=str(out / "crowded_sky.png"))


# ------------------------------------------------------------------ the finding chart


def _synthetic_fits(ra_deg: float, dec_deg: float) -> bytes:
    """A 400 x 400 image at 0.9 arcsec/px whose WCS is rotated by 30 deg and flipped, with a
    Gaussian star (sigma 2.5 px) at (ra_deg, dec_deg) on a faint noisy sky."""
    from astropy.io import fits
    from astropy.wcs import WCS

    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [ra_deg + 0.4 / 60, dec_deg - 0.3 / 60]
    w.wcs.crpix = [200.5, 200.5]
    s, t = 0.9 / 3600, math.radians(30)
    w.wcs.cd = [[s * math.cos(t), -s * math.sin(t)], [-s * math.sin(t), -s * math.cos(t)]]
    col, row = w.all_world2pix([[ra_deg, dec_deg]], 0)[0]
    yy, xx = np.mgrid[0:400, 0:400]
    rng = np.random.default_rng(1)
    data = 100 + rng.normal(0, 3, (400, 400)) + 5000 * np.exp(-((xx - col) ** 2 + (yy - row) ** 2) / (2 * 2.5 ** 2))
    buf = io.BytesIO()
    fits.PrimaryHDU(data.astype(np.float32), header=w.to_header()).writeto(buf)
    return buf.getvalue()


def _peak_offset_px(png: bytes, cx: float, cy: float, radius: int = 14) -> float:
    """Distance from (cx, cy) (px in the screenshot) to the star's peak: the centroid of the
    pixels where the image, smoothed over 5 x 5 px against the sky's noise, departs most from the
    window's median (a dark or a light star, clipped flat or not)."""
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=float)
    x0, y0 = int(round(cx)) - radius, int(round(cy)) - radius
    win = img[y0 - 2:y0 + 2 * radius + 3, x0 - 2:x0 + 2 * radius + 3]
    n = 2 * radius + 1
    smooth = sum(win[dy:dy + n, dx:dx + n] for dy in range(5) for dx in range(5)) / 25
    dev = np.abs(smooth - np.median(smooth))
    ys, xs = np.nonzero(dev >= 0.9 * dev.max())
    return math.hypot(x0 + xs.mean() + 0.5 - cx, y0 + ys.mean() + 0.5 - cy)


def test_finding_chart_under_the_targets(page, server, tmp_path: Path) -> None:
    """A synthetic FITS with a rotated, flipped WCS and a star at a target's position: in the
    sky view and in the configuration viewer the star's peak is within 1 px of the marker."""
    csv_text = "id,ra,dec,priority\nstar,132.8500,11.8000,10\nb,132.8420,11.8150,5\nc,132.8610,11.7880,1\n"
    got = _plan_on_page(page, server, csv_text=csv_text, time_limit_s=8, pa_deg=30)
    p = got["result"]["pointings"][0]
    assert abs(_pointing_pa(p, got["request"])) > 1  # the chart under the configuration is turned
    fits_b64 = base64.b64encode(_synthetic_fits(132.85, 11.80)).decode()
    err = page.evaluate("""async (b64) => {
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        return await MXSViewer.setFindingImage(new File([bytes], 'synthetic.fits')); }""", fits_b64)
    assert err is None
    assert page.locator("svg.sky image.finding-image").count() == 1
    assert page.locator("svg[data-configuration] image.finding-image").count() >= 1
    out = _artefacts(tmp_path)
    for name, sel, mark in (("sky", "svg.sky", "svg.sky .sky-target[data-id='star']"),
                            ("c1", "svg[data-configuration]", "svg[data-configuration] [data-id='star']")):
        root = page.locator(sel).first
        box = root.bounding_box()
        m = page.locator(mark).first.bounding_box()
        cx, cy = m["x"] + m["width"] / 2 - box["x"], m["y"] + m["height"] / 2 - box["y"]
        style = page.add_style_tag(content="svg > :not(.finding-chart) { visibility: hidden !important; }")
        png = root.screenshot()
        style.evaluate("(s) => s.remove()")
        (out / f"chart_{name}.png").write_bytes(png)
        assert _peak_offset_px(png, cx, cy) <= 1.0, sel
    # a file that is no FITS image gives the endpoint's one-line reason, not a broken picture
    err = page.evaluate("""async () => await MXSViewer.setFindingImage(new File(['no image'], 'x.fits'))""")
    assert err and err.startswith("finding chart: ")
    assert page.locator("image.finding-image").count() == 0
    assert page.locator(".field .finding-note").text_content() == err
