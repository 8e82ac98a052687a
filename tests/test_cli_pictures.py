"""The CLI's pictures as an astronomer reads them (issue 40): the sky as seen (North up, East
left) in every PNG, labels that never overlap (checked on matplotlib's own text extents), the
legend, the sky overview, the finding chart under the pictures (checked on the saved PNG's
pixels), and the CLI's help and wording."""

from __future__ import annotations

import math
import re
from pathlib import Path
from types import SimpleNamespace

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import Angle
from astropy.io import fits
from astropy.wcs import WCS
from matplotlib.patches import Polygon
from matplotlib.text import Text

from models.instrument import default_instrument
from models.kinematics import inverse_fov
from models.sky import focal_mm_to_sky, sky_to_focal_mm, spherical_centroid_deg
from service import cli, plots, sky_plots
from service.cli_pictures import chart_values, configuration_title
from service.plot_style import MAX_TIERS, priority_tiers, tier_colours
from service.sky_text import dec_dms, plural, priority_text, ra_hms, radec_text
from service.tables import ALIASES, read_target_table

INST = default_instrument()
DATA = Path(__file__).resolve().parent / "data"
SCALE = INST.plate_scale_arcsec_per_mm


def _gid(artist) -> str:
    return str(getattr(artist, "get_gid", lambda: None)() or "")


def _artists(fig, prefix: str) -> list:
    return [a for a in fig.findobj() if _gid(a).startswith(prefix)]


def _boxes(fig, prefix: str) -> np.ndarray:
    """Display-pixel boxes (x0, y0, x1, y1) of the texts whose gid starts with ``prefix``."""
    r = fig.canvas.get_renderer()
    texts = [t for t in _artists(fig, prefix) if isinstance(t, Text) and t.get_text()]
    return np.array([[b.x0, b.y0, b.x1, b.y1] for b in (t.get_window_extent(r) for t in texts)])


def _overlapping_pairs(b: np.ndarray) -> list[tuple[int, int]]:
    ov_x = np.minimum(b[:, None, 2], b[None, :, 2]) - np.maximum(b[:, None, 0], b[None, :, 0])
    ov_y = np.minimum(b[:, None, 3], b[None, :, 3]) - np.maximum(b[:, None, 1], b[None, :, 1])
    hit = (ov_x > 1e-6) & (ov_y > 1e-6)
    return [(int(i), int(j)) for i, j in zip(*np.nonzero(np.triu(hit, 1)), strict=True)]


def _config(x, y, pr, status, ids, pa_deg=0.0, joints=None, **kw):
    fig = plots.configuration_figure(
        INST, {a.index: a.park for a in INST.arms} if joints is None else joints,
        target_x_mm=x, target_y_mm=y, target_priority=pr, target_status=status,
        target_ids=ids, position_angle_deg=pa_deg, **kw)
    fig.canvas.draw()
    return fig


# ------------------------------------------------------------------ orientation


@pytest.mark.parametrize("pa_deg", [0.0, 30.0, 217.0])
def test_configuration_png_shows_the_sky_as_seen(pa_deg: float) -> None:
    """A star East of the pointing is drawn to the LEFT of the centre at PA 0, and at every PA
    the star East of the centre is 90 degrees counter-clockwise of the star North of it."""
    ra0, dec0 = 132.83, 11.8
    d = 1.0 / 60.0  # 1 arcmin
    east = (ra0 + d / math.cos(math.radians(dec0)), dec0)
    north = (ra0, dec0 + d)
    x, y = sky_to_focal_mm(np.array([east[0], north[0]]), np.array([east[1], north[1]]),
                           ra0, dec0, SCALE, pa_deg)
    fig = _config(x, y, [5, 5], ["this", "this"], ["east", "north"], pa_deg)
    try:
        ax = fig.axes[0]
        c = ax.transData.transform((0.0, 0.0))
        e = ax.transData.transform((x[0], y[0])) - c
        n = ax.transData.transform((x[1], y[1])) - c
        if pa_deg == 0.0:
            assert e[0] < -50 and abs(e[1]) < 1  # East: left
            assert n[1] > 50 and abs(n[0]) < 1  # North: up
        assert n[0] * e[1] - n[1] * e[0] > 0  # East counter-clockwise of North: not mirrored
        assert abs(np.dot(n, e)) < 1e-4 * np.dot(n, n)  # TAN: orthogonal to 1e-4 at 1'
        # the compass arrows point to the stars
        for name, v in (("N", n), ("E", e)):
            arrow = _artists(fig, f"compass-{name}")[0]
            a = np.subtract(arrow.xy, arrow.xyann)
            assert a / np.linalg.norm(a) == pytest.approx(v / np.linalg.norm(v), abs=1e-3)
        line = _artists(fig, "orientation")[0].get_text()
        assert "Sky as seen" in line and "+x drawn leftwards" in line
        if pa_deg == 0.0:
            assert "North up, East left" in line
    finally:
        plt.close(fig)


def test_sky_overview_shows_the_sky_as_seen() -> None:
    ra0, dec0 = 200.0, -30.0
    ras = ra0 + np.array([0.0, 0.05, -0.05, 0.0, 0.0])
    decs = dec0 + np.array([0.0, 0.0, 0.0, 0.04, -0.04])
    marks = [sky_plots.SkyMark(f"t{i}", float(a), float(b), 1 + i, i % 2 == 0)
             for i, (a, b) in enumerate(zip(ras, decs, strict=True))]
    pointings = [sky_plots.SkyPointing("P1", ra0, dec0)]
    fig = sky_plots.sky_overview_figure(marks, pointings, 2.5)
    try:
        fig.canvas.draw()
        ax = fig.axes[0]
        tangent = sky_plots.sky_tangent_deg(marks)
        xi, eta = sky_plots.standard_arcmin(ras, decs, tangent)
        px = ax.transData.transform(np.column_stack([xi, eta]))
        assert px[1, 0] < px[0, 0] < px[2, 0]  # larger RA (East) is drawn left
        assert px[3, 1] > px[0, 1] > px[4, 1]  # North up
        assert "North up, East left" in _artists(fig, "orientation")[0].get_text()
    finally:
        plt.close(fig)


# ------------------------------------------------------------------ labels


def _assert_labels_clear(fig, x, y, status, ids) -> int:
    """No two target labels overlap, none covers a target marker's centre, all lie in the
    axes, and every label not drawn is counted on the picture. Returns the labels drawn."""
    ax = fig.axes[0]
    boxes = _boxes(fig, "target-label-")
    assert not _overlapping_pairs(boxes)
    frame = ax.get_window_extent()
    assert (boxes[:, 0] >= frame.x0 - 1e-6).all() and (boxes[:, 2] <= frame.x1 + 1e-6).all()
    assert (boxes[:, 1] >= frame.y0 - 1e-6).all() and (boxes[:, 3] <= frame.y1 + 1e-6).all()
    centres = ax.transData.transform(np.column_stack([x, y]))
    inside = ((centres[None, :, 0] > boxes[:, None, 0]) & (centres[None, :, 0] < boxes[:, None, 2])
              & (centres[None, :, 1] > boxes[:, None, 1]) & (centres[None, :, 1] < boxes[:, None, 3]))
    assert not inside.any()
    eligible = sum(s in ("this", "pending") for s in status)
    dropped = eligible - len(boxes)
    notes = _artists(fig, "labels-dropped")
    if dropped:
        assert notes and notes[0].get_text().startswith(f"{dropped} label")
    else:
        assert not notes
    drawn = {t.get_text() for t in _artists(fig, "target-label-") if isinstance(t, Text)}
    assert drawn <= {i for i, s in zip(ids, status, strict=True) if s in ("this", "pending")}
    return len(boxes)


def test_m67_like_labels_do_not_overlap() -> None:
    """The 150-star M67-like VizieR list, projected about its centre: 12 stars observed, the
    rest pending, with their full 'Sanders nnnn' names."""
    table = read_target_table(DATA / "m67-like-150-vizier.csv")
    ra = np.array([t.ra_deg for t in table.targets])
    dec = np.array([t.dec_deg for t in table.targets])
    ra0, dec0 = spherical_centroid_deg(ra, dec)
    x, y = sky_to_focal_mm(ra, dec, ra0, dec0, SCALE)
    keep = np.hypot(x, y) < INST.fov_radius_mm
    x, y = x[keep], y[keep]
    pr = np.array([t.priority for t in table.targets])[keep]
    ids = [t.id for t, k in zip(table.targets, keep, strict=True) if k]
    order = np.argsort(-pr, kind="stable")
    status = ["pending"] * len(ids)
    for i in order[:12]:
        status[i] = "this"
    assert len(ids) > 40
    fig = _config(x, y, pr, status, ids)
    try:
        drawn = _assert_labels_clear(fig, x, y, status, ids)
        assert drawn >= 0.8 * len(ids)
    finally:
        plt.close(fig)


def test_crowded_475_labels_do_not_overlap() -> None:
    rng = np.random.default_rng(475)
    n = 475
    r = INST.fov_radius_mm * np.sqrt(rng.uniform(size=n))
    phi = rng.uniform(0, 2 * math.pi, n)
    x, y = r * np.cos(phi), r * np.sin(phi)
    status = list(rng.choice(["this", "pending", "earlier", "unallocated"], n, p=[0.03, 0.6, 0.2, 0.17]))
    ids = [f"star {i}" for i in range(n)]
    fig = _config(x, y, rng.integers(1, 1000, n), status, ids, pa_deg=30.0)
    try:
        drawn = _assert_labels_clear(fig, x, y, status, ids)
        assert drawn >= 0.5 * sum(s in ("this", "pending") for s in status)
        # the arm labels are placed by the same layout: none overlaps a target label
        both = np.vstack([_boxes(fig, "target-label-"), _boxes(fig, "arm-label-")])
        assert not _overlapping_pairs(both)
        # labels moved out of the crowd are joined to their star by a leader line
        assert _artists(fig, "leader-target-label-")
    finally:
        plt.close(fig)


# ------------------------------------------------------------------ arms and legend


def test_arms_outlined_and_legend_names_tiers_and_kinds() -> None:
    sol = inverse_fov(INST, 0, 30.0, -20.0)
    k = int(np.flatnonzero(np.ravel(sol.valid))[0])
    joints = {a.index: a.park for a in INST.arms}
    joints[0] = (float(np.ravel(sol.theta1_rad)[k]), float(np.ravel(sol.theta2_rad)[k]))
    fig = _config([30.0, -40.0, 10.0], [-20.0, 50.0, 90.0], [500, 10, 1],
                  ["this", "pending", "unallocated"], ["a", "b", "c"], joints=joints,
                  arm_targets={0: "a"})
    try:
        bodies = [p for p in fig.findobj(Polygon) if re.fullmatch(r"arm\d+-\w+", _gid(p))]
        assert len(bodies) == sum(len(a.bodies) for a in INST.arms)
        for p in bodies:  # an outline with a light fill: overlaps show as crossing outlines
            assert p.get_facecolor()[3] <= 0.15 and p.get_edgecolor()[3] == 1.0
            assert p.get_linewidth() <= 1.0
        legend = {t.get_text() for t in fig.legends[0].get_texts()}
        assert {"priority 500", "priority 10", "priority 1"} <= legend
        assert {"observed in this configuration", "pending (later configuration)",
                "not observed", "arm on target", "arm parked"} <= legend
        assert "observed earlier" not in legend  # only the kinds shown
    finally:
        plt.close(fig)


def test_priority_tiers_cover_every_priority_highest_first() -> None:
    assert [t.label for t in priority_tiers([1, 10, 500, 10])] == [
        "priority 500", "priority 10", "priority 1"]
    rng = np.random.default_rng(2)
    pr = rng.integers(1, 10_000, 300)
    tiers = priority_tiers(pr)
    assert len(tiers) == MAX_TIERS
    assert all(a.lo > b.hi for a, b in zip(tiers, tiers[1:], strict=False))
    assert tiers[0].hi == pr.max() and tiers[-1].lo == pr.min()
    colours = tier_colours(pr, tiers)
    for p, c in zip(pr, colours, strict=True):
        assert [t.colour for t in tiers if t.lo <= p <= t.hi] == [c]


# ------------------------------------------------------------------ sky overview


def test_sky_overview_pointing_labels_clear_of_the_stars() -> None:
    rng = np.random.default_rng(7)
    ra0, dec0 = 132.83, 11.8
    centres = [(ra0 + dx / 60 / math.cos(math.radians(dec0)), dec0 + dy / 60)
               for dx, dy in ((0, 0), (3.5, 1), (-3, 2), (1, -3.5))]
    marks = []
    for k, (ra, dec) in enumerate(centres):
        for i in range(60):
            r, a = 2.4 * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
            marks.append(sky_plots.SkyMark(
                f"s{k}-{i}", ra + r * math.cos(a) / 60 / math.cos(math.radians(dec)),
                dec + r * math.sin(a) / 60, int(rng.integers(1, 100)), bool(i % 3)))
    pointings = [sky_plots.SkyPointing(f"P000{k + 1}", ra, dec) for k, (ra, dec) in enumerate(centres)]
    fig = sky_plots.sky_overview_figure(marks, pointings, INST.fov_radius_mm * SCALE / 60)
    try:
        fig.canvas.draw()
        ax = fig.axes[0]
        labels = {t.get_text() for t in _artists(fig, "pointing-label-") if isinstance(t, Text)}
        assert labels == {p.id for p in pointings}
        boxes = _boxes(fig, "pointing-label-")
        tangent = sky_plots.sky_tangent_deg(marks)
        xi, eta = sky_plots.standard_arcmin([m.ra_deg for m in marks], [m.dec_deg for m in marks], tangent)
        c = ax.transData.transform(np.column_stack([xi, eta]))
        rad = np.array([sky_plots.mark_radius_px(m.observed, fig.dpi) for m in marks])
        near_x = (c[None, :, 0] + rad > boxes[:, None, 0]) & (c[None, :, 0] - rad < boxes[:, None, 2])
        near_y = (c[None, :, 1] + rad > boxes[:, None, 1]) & (c[None, :, 1] - rad < boxes[:, None, 3])
        assert not (near_x & near_y).any()
        assert not _overlapping_pairs(boxes)
        legend = {t.get_text() for t in fig.legends[0].get_texts()}
        assert {"observed (in a configuration)", "not observed",
                "pointing: FOV circle, centre"} <= legend
        assert any(t.startswith("priority ") for t in legend)
        title = _artists(fig, "title")[0].get_text()
        assert title == "Sky overview: 4 pointings, 240 targets (160 observed)"
    finally:
        plt.close(fig)


# ------------------------------------------------------------------ finding chart


def _synthetic_fits(path: Path, ra_deg: float, dec_deg: float, star: tuple[float, float]) -> None:
    """A 600 x 600 image, 1 arcsec pixels, rotated 30 degrees (CD matrix), faint noise and a
    bright Gaussian star (sigma 2 arcsec) at ``star``."""
    rot = math.radians(30.0)
    s = 1.0 / 3600.0
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [ra_deg, dec_deg]
    w.wcs.crpix = [300.5, 300.5]
    w.wcs.cd = [[-s * math.cos(rot), s * math.sin(rot)], [s * math.sin(rot), s * math.cos(rot)]]
    col, row = w.world_to_pixel_values(*star)
    rr, cc = np.mgrid[0:600, 0:600]
    rng = np.random.default_rng(4)
    data = 100.0 + rng.normal(0.0, 1.0, (600, 600))
    data += 5000.0 * np.exp(-((cc - col) ** 2 + (rr - row) ** 2) / (2 * 2.0 ** 2))
    fits.PrimaryHDU(data.astype(np.float32), header=w.to_header()).writeto(path)


def _peak_near(png: Path, col: float, row: float, window: int = 25) -> tuple[float, float, float]:
    """Where the star's peak is drawn in ``png`` (the chart is drawn inverted: stars dark):
    the centre of the pixels within 0.02 of the darkest grey (the 8-bit PNG flattens the
    stretched core into a small plateau) within ``window`` pixels of (col, row), in pixel
    index units; and the peak's contrast against the window's median."""
    img = mpimg.imread(png)[..., :3].mean(axis=2)
    c0, r0 = int(round(col)), int(round(row))
    win = img[r0 - window:r0 + window + 1, c0 - window:c0 + window + 1]
    rows, cols = np.nonzero(win <= win.min() + 0.02)
    return (c0 - window + float(cols.mean()), r0 - window + float(rows.mean()),
            float(np.median(win) - win.min()))


@pytest.mark.parametrize("pa_deg", [0.0, 30.0])
def test_finding_chart_under_a_configuration_peaks_on_the_target(tmp_path: Path, pa_deg: float) -> None:
    """The CLI's path for ``--image``: the chart of the pointing at its PA, drawn under the
    configuration; the star's peak in the saved PNG is within 1 pixel of where the axes put
    the target (the chart alone: no marker hides the peak)."""
    from models.finding_chart import load_fits_image

    ra0, dec0 = 132.83, 11.8
    tx, ty = 30.0, -20.0
    star = focal_mm_to_sky(np.array([tx]), np.array([ty]), ra0, dec0, SCALE, pa_deg)
    star = (float(star[0][0]), float(star[1][0]))
    _synthetic_fits(tmp_path / "img.fits", ra0 + 0.01, dec0 - 0.005, star)
    image = load_fits_image(tmp_path / "img.fits")
    half_arcmin = plots.view_half_width_mm(INST) * SCALE / 60.0
    values = chart_values(image, ra0, dec0, half_arcmin, pa_deg, plots.view_size_px())
    fig = plots.configuration_figure(INST, {}, position_angle_deg=pa_deg, background=values)
    try:
        fig.canvas.draw()
        px, py = fig.axes[0].transData.transform((tx, ty))
        height = fig.bbox.height
        fig.savefig(tmp_path / "c.png")
    finally:
        plt.close(fig)
    expect_col, expect_row = px - 0.5, height - py - 0.5
    col, row, contrast = _peak_near(tmp_path / "c.png", expect_col, expect_row)
    assert contrast > 0.1
    assert abs(col - expect_col) <= 1.0 and abs(row - expect_row) <= 1.0


def test_finding_chart_under_the_sky_overview_peaks_on_the_star(tmp_path: Path) -> None:
    from models.finding_chart import load_fits_image

    ra0, dec0 = 210.0, 54.3
    ras = ra0 + np.array([-2.0, 2.0, 0.0, 0.0]) / 60 / math.cos(math.radians(dec0))
    decs = dec0 + np.array([0.0, 0.0, -2.0, 2.0]) / 60
    marks = [sky_plots.SkyMark(f"t{i}", float(a), float(b), 3, True)
             for i, (a, b) in enumerate(zip(ras, decs, strict=True))]
    tangent = sky_plots.sky_tangent_deg(marks)
    star = focal_mm_to_sky(np.array([1.1]), np.array([-0.7]), *tangent, 60.0, 0.0)  # arcmin
    star = (float(star[0][0]), float(star[1][0]))
    _synthetic_fits(tmp_path / "img.fits", ra0, dec0, star)
    pointings = [sky_plots.SkyPointing("P1", ra0, dec0)]
    radius = INST.fov_radius_mm * SCALE / 60
    half = sky_plots.overview_half_width_arcmin(marks, pointings, radius)
    values = chart_values(load_fits_image(tmp_path / "img.fits"), *tangent, half, 0.0,
                          sky_plots.view_size_px())
    fig = sky_plots.sky_overview_figure(marks, pointings, radius, background=values)
    try:
        fig.canvas.draw()
        px, py = fig.axes[0].transData.transform((1.1, -0.7))
        height = fig.bbox.height
        fig.savefig(tmp_path / "o.png")
    finally:
        plt.close(fig)
    col, row, contrast = _peak_near(tmp_path / "o.png", px - 0.5, height - py - 0.5, 40)
    assert contrast > 0.1
    assert abs(col - (px - 0.5)) <= 1.0 and abs(row - (height - py - 0.5)) <= 1.0


def test_write_pictures_draws_the_chart_at_the_pointings_own_pa(tmp_path: Path, capsys) -> None:
    """``plan --image``'s writer on a one-configuration result whose pointing has its own PA
    (30 deg, the request's 0): the star under focal-plane (30, -20) mm at PA 30 peaks within
    1 pixel of where the configuration picture's axes put that point."""
    from models.finding_chart import load_fits_image
    from service.cli_pictures import OVERVIEW_NAME, write_overview, write_pictures
    from service.schemas import PlanRequest

    ra0, dec0, pa = 150.0, 20.0, 30.0
    tra, tdec = focal_mm_to_sky(np.array([-60.0, 70.0]), np.array([60.0, 70.0]), ra0, dec0, SCALE, pa)
    req = PlanRequest(targets=[{"id": f"t{i}", "ra_deg": float(a), "dec_deg": float(d), "priority": 3}
                               for i, (a, d) in enumerate(zip(tra, tdec, strict=True))])
    conf = {"index": 0, "arm_yield": 0, "total_priority": 0,
            "assignments": [{"arm": a.index, "theta1_rad": a.park[0], "theta2_rad": a.park[1],
                             "target_id": None} for a in INST.arms]}
    result = {"pointings": [{"id": "P0001", "ra_deg": ra0, "dec_deg": dec0, "position_angle_deg": pa,
                             "target_ids": ["t0", "t1"], "configurations": [conf]}]}
    star = focal_mm_to_sky(np.array([30.0]), np.array([-20.0]), ra0, dec0, SCALE, pa)
    _synthetic_fits(tmp_path / "img.fits", ra0, dec0, (float(star[0][0]), float(star[1][0])))
    image = load_fits_image(tmp_path / "img.fits")
    [png] = write_pictures(result, req, INST, tmp_path, quiet=True, image=image)
    assert png.name == "pointingP0001_c1.png"
    assert (write_overview(result, req, INST, tmp_path, image=image) == tmp_path / OVERVIEW_NAME)
    assert "notice" not in capsys.readouterr().err
    fig = plots.configuration_figure(INST, {}, position_angle_deg=pa)  # the same geometry
    try:
        px, py = fig.axes[0].transData.transform((30.0, -20.0))
        height = fig.bbox.height
    finally:
        plt.close(fig)
    col, row, contrast = _peak_near(png, px - 0.5, height - py - 0.5)
    assert contrast > 0.1
    assert abs(col - (px - 0.5)) <= 1.0 and abs(row - (height - py - 0.5)) <= 1.0


def test_cli_refuses_a_bad_image_naming_the_option(tmp_path: Path, capsys) -> None:
    csv = tmp_path / "t.csv"
    csv.write_text("id,ra_deg,dec_deg,priority\na,150.0,20.0,5\n")
    bad = tmp_path / "chart.fits"
    bad.write_text("this is not FITS\n")
    assert cli.main(["plan", str(csv), "--out", str(tmp_path / "o"), "--image", str(bad),
                     "--quiet"]) == cli.EXIT_INVALID_INPUT
    err = capsys.readouterr().err
    assert f"--image {bad}" in err and "not a FITS image" in err
    assert not (tmp_path / "o" / "plan.json").exists()


# ------------------------------------------------------------------ help and wording


def _plan_parser():
    return cli.build_parser()._subparsers._group_actions[0].choices["plan"]  # type: ignore[union-attr]


def test_plan_help_shows_every_default_from_the_api() -> None:
    from service.schemas import PlanRequest

    parser = _plan_parser()
    for action in parser._actions:
        if action.dest in ("help", "targets", "out"):
            continue
        assert "(default:" in (action.help or ""), action.dest
    text = " ".join(parser.format_help().split())
    for option, field in (("--method", "method"), ("--solver", "solver"),
                          ("--position-angle", "position_angle_deg"),
                          ("--exposure-time", "exposure_time_s"), ("--acquisition", "acquisition_s"),
                          ("--park-move-limit", "park_move_limit_s")):
        default = PlanRequest.model_fields[field].default
        assert re.search(re.escape(option) + r" .*?\(default: " + re.escape(str(default)) + r"[),]",
                         text), option
        action = next(a for a in parser._actions if option in a.option_strings)
        assert action.default == default


def test_plan_help_lists_every_column_alias() -> None:
    text = " ".join(_plan_parser().format_help().split())
    for field, names in ALIASES.items():
        for name in names:
            assert re.search(rf"[ ,:]{re.escape(name)}[,;. ]", text), (field, name)


@pytest.mark.parametrize("ra,dec", [(132.8269833, 11.7807417), (0.0001, -0.0001), (359.9, -89.99),
                                    (15.0, 45.5), (250.4234, -36.461389)])
def test_sexagesimal_matches_astropy(ra: float, dec: float) -> None:
    want_ra = Angle(ra, u.deg).to_string(unit=u.hour, sep="hms", precision=2, pad=True)
    want_dec = Angle(dec, u.deg).to_string(unit=u.deg, sep="dms", precision=1, pad=True,
                                           alwayssign=True)
    assert ra_hms(ra) == want_ra
    got_dec = dec_dms(dec).replace("°", "d").replace("′", "m").replace("″", "s")
    assert got_dec == want_dec or (want_dec == "-00d00m00.0s" and got_dec == "+00d00m00.0s")
    assert radec_text(ra, dec).startswith(f"{ra_hms(ra)} {dec_dms(dec)} ({ra:.5f}°, {dec:+.5f}°)")


def test_sexagesimal_carries_rounding_into_the_minutes() -> None:
    assert ra_hms(359.99999999) == "00h00m00.00s"  # never 24h or 60 s
    assert dec_dms(10.0 - 1e-9) == "+10°00′00.0″"


def test_counts_priorities_and_legs_read_right(tmp_path: Path, capsys) -> None:
    assert (plural(1, "pointing"), plural(2, "pointing"), plural(0, "target")) == (
        "1 pointing", "2 pointings", "0 targets")
    assert priority_text(-5.0) == "-5" and priority_text(500) == "500"
    assert cli.leg_name(0, 3) == "leg 1 (park -> c1)"
    assert cli.leg_name(2, 3) == "leg 3 (c2 -> park)"
    pointing = {"id": "P0001", "ra_deg": 132.82698, "dec_deg": 11.78075, "target_ids": ["a"],
                "position_angle_deg": None, "executable": False,
                "configurations": [{"index": 0, "arm_yield": 1, "total_priority": 7,
                                    "assignments": []}],
                "motions": [{"status": "failed", "failed_arms": [5]}, {"status": "ok"}],
                "reasons": ["leg 1 (park -> c1): arms 5 not planned"]}
    result = {"executable": False, "pointings": [pointing],
              "stats": {"targets": 1, "pointings": 1, "configurations": 1, "allocated_targets": 1,
                        "unallocated_by_reason": {"unreachable": 1},
                        "telescope_time": {"exposures": 1, "acquisitions": 1, "total_s": 1200.0,
                                           "exposure_s": 900.0, "acquisition_s": 300.0,
                                           "reconfiguration_s": 0.0, "unplanned_legs": 1}}}
    req = SimpleNamespace(position_angle_deg=12.5)
    cli.print_summary(result, req, tmp_path, 1, tmp_path / "sky_overview.png")
    cli.print_failed_legs(result)
    cap = capsys.readouterr()
    assert cap.out.startswith("1 target, 1 pointing, 1 configuration, 1 target allocated;")
    assert "1 configuration picture " in cap.out
    assert f"pointing P0001 at {radec_text(132.82698, 11.78075)}, PA 12.5°: 1 configuration, 1 target" in cap.out
    assert "(1 motion leg not planned, not counted)" in cap.out
    assert "warning: 1 target not allocated (unreachable)" in cap.err
    assert "error: pointing P0001: motion leg 1 (park -> c1) not planned" in cap.err
    assert "pointing P0001: leg 1 (park -> c1): arms 5 not planned" in cap.err
    assert "leg 0" not in cap.err
    title = configuration_title(pointing, pointing["configurations"][0], 12.5)
    assert "08h51m18.48s +11°46′50.7″ (132.82698°, +11.78075°), PA 12.5°" in title
    assert "configuration c1: 1 arm on targets, summed priority 7" in title
