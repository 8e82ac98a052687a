"""The pictures ``mxs-planner plan`` writes: one PNG per configuration
(``pointing<id>_c<k>.png``, c1 ... cn as on the page) and the sky overview
(``sky_overview.png``), optionally over a finding chart made from the astronomer's FITS image
(``--image``; :mod:`models.finding_chart`).

Every picture shows the sky as seen (North up, East left; the focal plane mirrored, +x drawn
leftwards) and says so. A pointing is drawn at its own position angle: the one the segmentation
chose (``position_angle_deg`` of the pointing) or, when it chose none, the request's.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from service.sky_text import plural, priority_text, radec_text

OVERVIEW_NAME = "sky_overview.png"


def pointing_pa_deg(pointing: Mapping[str, Any], req: Any) -> float:
    """The position angle a pointing is observed at (deg)."""
    pa = pointing.get("position_angle_deg")
    return float(req.position_angle_deg if pa is None else pa)


def configuration_title(pointing: Mapping[str, Any], conf: Mapping[str, Any], pa_deg: float) -> str:
    """Two title lines: the pointing (sexagesimal and decimal, PA) and the configuration."""
    arms = int(conf["arm_yield"])
    return (f"pointing {pointing['id']} at {radec_text(pointing['ra_deg'], pointing['dec_deg'])}, "
            f"PA {pa_deg:g}°\nconfiguration c{int(conf['index']) + 1}: {plural(arms, 'arm')} on "
            f"targets, summed priority {priority_text(conf['total_priority'])}")


def chart_values(image: Any, ra_deg: float, dec_deg: float, half_width_arcmin: float,
                 up_pa_deg: float, size_px: int) -> np.ndarray:
    """The finding chart's grey levels (0..1, NaN outside the image) about (ra, dec), up at
    ``up_pa_deg``: :func:`models.finding_chart.render_chart`."""
    from models.finding_chart import render_chart

    return render_chart(image, ra_deg % 360.0, dec_deg, half_width_arcmin, up_pa_deg,
                        size_px).values


def chart_or_none(image: Any, ra_deg: float, dec_deg: float, half_width_arcmin: float,
                  up_pa_deg: float, size_px: int, what: str) -> np.ndarray | None:
    """:func:`chart_values`, or None with a notice on stderr when the chart cannot be drawn
    (a view wider than a chart may be): the picture is then drawn without it."""
    from models.errors import InputError

    try:
        return chart_values(image, ra_deg, dec_deg, half_width_arcmin, up_pa_deg, size_px)
    except InputError as exc:
        print(f"notice: --image: {what} drawn without the finding chart ({exc})", file=sys.stderr)
        return None


def write_pictures(result: Mapping[str, Any], req: Any, inst: Any, out: Path,
                   quiet: bool = False, image: Any = None) -> list[Path]:
    """One PNG per configuration, ``pointing<id>_c<k>.png``: configurations are c1 ... cn
    (``index`` + 1), as on the page and in the motion legs' reasons. With ``image`` (a
    :class:`models.finding_chart.FitsImage`) each pointing's finding chart lies under its
    configurations, up at the pointing's PA."""
    from tqdm import tqdm

    from service import pointing_plans
    from service.plots import plot_configuration, sequence_states, view_half_width_mm, view_size_px

    by_id = {t.id: t for t in req.targets}
    jobs = [(p, c) for p in result["pointings"] for c in p["configurations"]]
    charts: dict[str, np.ndarray] = {}
    paths = []
    for p, c in tqdm(jobs, desc="pictures", disable=quiet or not jobs):
        pa = pointing_pa_deg(p, req)
        members = [by_id[t] for t in p["target_ids"]]
        x, y = pointing_plans.sky_to_focal(members, p["ra_deg"] % 360.0, p["dec_deg"], inst, pa)
        if image is not None and p["id"] not in charts:
            half_arcmin = view_half_width_mm(inst) * inst.plate_scale_arcsec_per_mm / 60.0
            charts[p["id"]] = chart_or_none(image, p["ra_deg"], p["dec_deg"], half_arcmin, pa,
                                            view_size_px(), f"pointing {p['id']}")
        paths.append(plot_configuration(
            inst, {a["arm"]: (a["theta1_rad"], a["theta2_rad"]) for a in c["assignments"]},
            out / f"pointing{p['id']}_c{c['index'] + 1}.png",
            target_x_mm=x, target_y_mm=y, target_priority=[t.priority for t in members],
            target_status=sequence_states(p["configurations"], c, [t.id for t in members]),
            target_ids=[t.id for t in members], position_angle_deg=pa,
            arm_targets={a["arm"]: a.get("target_id") for a in c["assignments"]},
            arm_kinds={a["arm"]: a.get("kind") for a in c["assignments"]},
            background=charts.get(p["id"]), title=configuration_title(p, c, pa)))
    return paths


def write_overview(result: Mapping[str, Any], req: Any, inst: Any, out: Path,
                   image: Any = None) -> Path:
    """``sky_overview.png``: every pointing's FOV circle and every target of the request, N up
    E left; over the finding chart (up_pa 0) when ``image`` is given."""
    from service import sky_plots

    observed = {a["target_id"] for p in result["pointings"] for c in p["configurations"]
                for a in c["assignments"] if a.get("target_id")}
    marks = [sky_plots.SkyMark(t.id, t.ra_deg, t.dec_deg, t.priority, t.id in observed)
             for t in req.targets]
    pointings = [sky_plots.SkyPointing(p["id"], p["ra_deg"], p["dec_deg"])
                 for p in result["pointings"]]
    radius_arcmin = inst.fov_radius_mm * inst.plate_scale_arcsec_per_mm / 60.0
    background = None
    if image is not None:
        ra, dec = sky_plots.sky_tangent_deg(marks)
        half = sky_plots.overview_half_width_arcmin(marks, pointings, radius_arcmin)
        background = chart_or_none(image, ra, dec, half, 0.0, sky_plots.view_size_px(),
                                   OVERVIEW_NAME)
    return sky_plots.plot_sky_overview(out / OVERVIEW_NAME, marks, pointings, radius_arcmin,
                                       background=background)
