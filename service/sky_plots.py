"""The sky overview of a plan (matplotlib, Agg): every pointing's field-of-view circle and
every target, drawn as the sky is seen (North up, East left).

The view is the tangent plane about the targets' centre in standard coordinates, arcmin:
xi (East) increases to the LEFT and eta (North) upwards (:func:`models.sky.sky_to_focal_mm`
with a plate scale of 60 arcsec per unit and PA 0 gives exactly (xi, eta) in arcmin). Targets
are coloured by priority tier and marked observed (a configuration of the plan holds them) or
not. Pointing labels are placed by :mod:`service.plot_labels` clear of the target markers, so
they never hide under them. An optional background image (a finding chart at up_pa 0,
:mod:`models.finding_chart`) lies under everything.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from models.sky import sky_to_focal_mm, spherical_centroid_deg  # noqa: E402
from service.plot_labels import LabelSpec, marker_boxes, place_labels  # noqa: E402
from service.plot_style import (  # noqa: E402
    orientation_line,
    priority_tiers,
    sky_compass,
    target_handles,
    tier_colours,
)
from service.sky_text import plural, radec_text  # noqa: E402

ARCSEC_PER_ARCMIN = 60.0
POINTING_COLOUR = "#1f3a93"
MARGIN = 1.08  # half-width of the view / the farthest target or circle edge
FIGSIZE_IN = (10.4, 8.4)
DPI = 100
AXES_RECT = (0.08, 0.08, 0.64, 0.82)
POINTING_RINGS_PX = (0.0, 9.0, 20.0, 34.0, 50.0, 70.0, 95.0)
OBSERVED = dict(s=30, marker="o", linewidths=0.7, zorder=4)
NOT_OBSERVED = dict(s=26, marker="x", linewidths=1.0, zorder=3)


@dataclass(frozen=True)
class SkyPointing:
    """A pointing of the plan: its id and the centre of its field of view."""

    id: str
    ra_deg: float
    dec_deg: float


@dataclass(frozen=True)
class SkyMark:
    """A target: where it is, its priority and whether a configuration of the plan holds it."""

    id: str
    ra_deg: float
    dec_deg: float
    priority: int
    observed: bool


def sky_tangent_deg(targets: Sequence[SkyMark]) -> tuple[float, float]:
    """The centre of the overview: the targets' spherical centroid (RA, Dec) in degrees."""
    return spherical_centroid_deg([t.ra_deg for t in targets], [t.dec_deg for t in targets])


def standard_arcmin(ra_deg, dec_deg, tangent: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Standard coordinates (xi East, eta North) in arcmin about ``tangent`` (TAN)."""
    return sky_to_focal_mm(np.asarray(ra_deg, float), np.asarray(dec_deg, float), tangent[0],
                           tangent[1], ARCSEC_PER_ARCMIN, 0.0)


def overview_half_width_arcmin(targets: Sequence[SkyMark], pointings: Sequence[SkyPointing],
                               fov_radius_arcmin: float) -> float:
    """Half the side of the square view: the farthest target or FOV circle edge, with a margin."""
    tangent = sky_tangent_deg(targets)
    xi, eta = standard_arcmin([t.ra_deg for t in targets], [t.dec_deg for t in targets], tangent)
    pxi, peta = standard_arcmin([p.ra_deg for p in pointings], [p.dec_deg for p in pointings], tangent)
    far = max(float(np.max(np.abs(np.r_[xi, eta]), initial=0.0)),
              float(np.max(np.abs(np.r_[pxi, peta]), initial=0.0)) + fov_radius_arcmin)
    return MARGIN * max(far, fov_radius_arcmin)


def view_size_px() -> int:
    """The side of the square view in the saved PNG, pixels (a finding chart rendered at this
    size maps one chart pixel onto one PNG pixel)."""
    return int(min(AXES_RECT[2] * FIGSIZE_IN[0], AXES_RECT[3] * FIGSIZE_IN[1]) * DPI)


def plot_sky_overview(path: str | Path, targets: Sequence[SkyMark],
                      pointings: Sequence[SkyPointing], fov_radius_arcmin: float, **kwargs) -> Path:
    """Draw the overview to ``path`` (PNG); the arguments are those of :func:`sky_overview_figure`."""
    fig = sky_overview_figure(targets, pointings, fov_radius_arcmin, **kwargs)
    try:
        out = Path(path)
        fig.savefig(out)
        return out
    finally:
        plt.close(fig)


def sky_overview_figure(targets: Sequence[SkyMark], pointings: Sequence[SkyPointing],
                        fov_radius_arcmin: float, *, title: str = "",
                        background: np.ndarray | None = None) -> Figure:
    """The overview figure (the caller closes it). ``background`` holds grey levels 0..1 (1 =
    brightest sky, NaN = no image; rows from the top) spanning the whole view, centred on
    :func:`sky_tangent_deg`, East on its left, of half-width :func:`overview_half_width_arcmin`:
    a finding chart at up_pa 0, drawn inverted (stars dark)."""
    tangent = sky_tangent_deg(targets)
    half = overview_half_width_arcmin(targets, pointings, fov_radius_arcmin)
    fig = plt.figure(figsize=FIGSIZE_IN, dpi=DPI)
    ax = fig.add_axes(AXES_RECT)
    if background is not None:
        ax.imshow(background, extent=(half, -half, -half, half), origin="upper", zorder=0,
                  cmap="gray_r", vmin=0.0, vmax=1.0, interpolation="nearest", gid="finding-chart")
    ax.set_xlim(half, -half)  # xi (East) increases leftwards: the sky as seen
    ax.set_ylim(-half, half)
    ax.set_aspect("equal")
    ax.set_xlabel("xi, East [arcmin] (increases leftwards)")
    ax.set_ylabel("eta, North [arcmin]")
    sky_compass(ax)
    ax.apply_aspect()
    pxi, peta = _draw_pointings(ax, pointings, tangent, fov_radius_arcmin)
    xi, eta, tiers = _draw_marks(ax, targets, tangent)
    _place_pointing_labels(ax, pointings, pxi, peta, xi, eta, targets)
    fig.legend(handles=_handles(tiers, targets), loc="upper left", bbox_to_anchor=(0.745, 0.90),
               fontsize=7.5, framealpha=0.9, title="legend", title_fontsize=8)
    n_obs = sum(t.observed for t in targets)
    head = title or (f"Sky overview: {plural(len(pointings), 'pointing')}, "
                     f"{plural(len(targets), 'target')} ({n_obs} observed)")
    fig.text(0.40, 0.975, head, ha="center", va="top", fontsize=10, gid="title")
    fig.text(0.40, 0.945, f"centre {radec_text(*tangent)}", ha="center", va="top", fontsize=8,
             gid="centre")
    fig.text(0.08, 0.012, orientation_line(None), fontsize=8, gid="orientation")
    return fig


def _draw_pointings(ax, pointings: Sequence[SkyPointing], tangent: tuple[float, float],
                    radius: float) -> tuple[np.ndarray, np.ndarray]:
    pxi, peta = standard_arcmin([p.ra_deg for p in pointings], [p.dec_deg for p in pointings], tangent)
    for p, x, y in zip(pointings, pxi, peta, strict=True):
        ax.add_patch(Circle((x, y), radius, fill=False, color=POINTING_COLOUR, lw=1.1,
                            gid=f"fov-{p.id}"))
    ax.scatter(pxi, peta, marker="+", s=50, c=POINTING_COLOUR, linewidths=1.2, zorder=5,
               gid="pointing-centres")
    return np.atleast_1d(pxi), np.atleast_1d(peta)


def _draw_marks(ax, targets: Sequence[SkyMark], tangent: tuple[float, float]):
    xi, eta = standard_arcmin([t.ra_deg for t in targets], [t.dec_deg for t in targets], tangent)
    pr = [t.priority for t in targets]
    tiers = priority_tiers(pr)
    colours = np.array(tier_colours(pr, tiers), dtype=object)
    obs = np.array([t.observed for t in targets], bool)
    if obs.any():
        ax.scatter(xi[obs], eta[obs], c=list(colours[obs]), edgecolors="black",
                   gid="targets-observed", **OBSERVED)
    if (~obs).any():
        ax.scatter(xi[~obs], eta[~obs], c=list(colours[~obs]), gid="targets-not-observed",
                   **NOT_OBSERVED)
    return xi, eta, tiers


def mark_radius_px(observed: bool, dpi: float) -> float:
    """Half the drawn size of a target mark, display pixels."""
    s = (OBSERVED if observed else NOT_OBSERVED)["s"]
    return float(np.sqrt(s)) / 2 * dpi / 72.0 + 0.5


def _place_pointing_labels(ax, pointings, pxi, peta, xi, eta, targets) -> None:
    """Pointing ids clear of every target mark and pointing centre (forced on top when a crowded
    field leaves no free place)."""
    dpi = ax.figure.dpi
    r = np.array([mark_radius_px(t.observed, dpi) for t in targets])
    obstacles = np.vstack([marker_boxes(ax, xi, eta, r), marker_boxes(ax, pxi, peta, 5.0)])
    specs = [LabelSpec(p.id, float(x), float(y), 5.0, f"pointing-label-{p.id}",
                       dict(fontsize=8, color=POINTING_COLOUR, fontweight="bold", zorder=7,
                            bbox=dict(boxstyle="square,pad=0.1", fc="white", ec="none", alpha=0.75)),
                       POINTING_RINGS_PX, True)
             for p, x, y in zip(pointings, pxi, peta, strict=True)]
    place_labels(ax, specs, obstacles)


def _handles(tiers, targets: Sequence[SkyMark]) -> list:
    kinds = {}
    if any(t.observed for t in targets):
        kinds["observed (in a configuration)"] = dict(marker="o", ms=6, mfc="0.6", mec="black")
    if not all(t.observed for t in targets):
        kinds["not observed"] = dict(marker="x", ms=5.5, mec="0.4", mew=1.0)
    handles = target_handles(tiers, kinds)
    handles.append(Line2D([], [], color=POINTING_COLOUR, lw=1.1, marker="+", ms=8,
                          label="pointing: FOV circle, centre"))
    return handles
