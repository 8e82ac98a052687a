"""Pictures of configurations (matplotlib, Agg), drawn for an astronomer at the telescope.

The view is the field of view (filling most of the figure width), with the arms at their joint
angles drawn to scale (capsule widths in mm; the arms' outer parts run off the frame), every
target coloured by priority and marked by its state in the pointing's sequence (observed in
this configuration, in an earlier one, still pending, or not observed), target ids, a compass
(N and E on the focal plane for the position angle), an arcsec scale bar and an arcsec axis.

Sky orientation follows :mod:`models.sky`: the focal-plane +y axis points to the position
angle PA East of North, so North is ``(-sin PA, cos PA)`` and East ``(cos PA, sin PA)``.
Geometry comes from :mod:`models.kinematics`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from models.instrument import Instrument  # noqa: E402
from models.kinematics import joint_positions_fov  # noqa: E402

STATES = ("this", "earlier", "pending", "unallocated")
STATE_LABELS = {"this": "observed in this configuration", "earlier": "observed earlier",
                "pending": "pending (a later configuration)", "unallocated": "not observed"}
VIEW_MARGIN = 1.12  # half-width of the view / FOV radius
SCALE_BAR_ARCSEC = 60.0


def plot_configuration(
    instrument: Instrument,
    joints: Mapping[int, tuple[float, float]],
    path: str | Path,
    *,
    target_x_mm: Sequence[float] = (),
    target_y_mm: Sequence[float] = (),
    target_priority: Sequence[int] = (),
    allocated: Sequence[bool] = (),
    target_status: Sequence[str] = (),
    target_ids: Sequence[str] = (),
    position_angle_deg: float = 0.0,
    title: str = "",
) -> Path:
    """Draw one configuration to ``path`` (PNG); the arguments are those of
    :func:`configuration_figure`."""
    fig = configuration_figure(
        instrument, joints, target_x_mm=target_x_mm, target_y_mm=target_y_mm,
        target_priority=target_priority, allocated=allocated, target_status=target_status,
        target_ids=target_ids, position_angle_deg=position_angle_deg, title=title)
    try:
        out = Path(path)
        fig.savefig(out)
        return out
    finally:
        plt.close(fig)


def configuration_figure(
    instrument: Instrument,
    joints: Mapping[int, tuple[float, float]],
    *,
    target_x_mm: Sequence[float] = (),
    target_y_mm: Sequence[float] = (),
    target_priority: Sequence[int] = (),
    allocated: Sequence[bool] = (),
    target_status: Sequence[str] = (),
    target_ids: Sequence[str] = (),
    position_angle_deg: float = 0.0,
    title: str = "",
) -> Figure:
    """The figure of one configuration (the caller closes it). ``joints`` maps arm ->
    (theta1, theta2). Each target's state is ``target_status[i]`` (one of :data:`STATES`);
    without it, ``allocated[i]`` means 'this' and the rest 'pending'."""
    fig = plt.figure(figsize=(8.0, 8.0), dpi=100)
    ax = fig.add_axes((0.09, 0.06, 0.78, 0.86))
    cax = fig.add_axes((0.89, 0.25, 0.022, 0.5))
    half = VIEW_MARGIN * instrument.fov_radius_mm
    ax.set_xlim(-half, half)
    ax.set_ylim(-half, half)
    ax.set_aspect("equal")
    ax.add_patch(Circle((0, 0), instrument.fov_radius_mm, fill=False, color="0.3", lw=1.2,
                        ls="--", label=f"FOV ({instrument.fov_diameter_mm:g} mm)"))
    _draw_arms(fig, ax, instrument, joints, half)
    n = len(target_x_mm)
    if n:
        status = _states(n, target_status, allocated)
        sc = _draw_targets(ax, np.asarray(target_x_mm, float), np.asarray(target_y_mm, float),
                           np.asarray(target_priority, float) if len(target_priority)
                           else np.ones(n), status, list(target_ids))
        fig.colorbar(sc, cax=cax, label="priority")
    else:
        cax.set_visible(False)
    _compass(ax, position_angle_deg)
    _scale_bar(ax, instrument, half)
    _arcsec_axes(ax, instrument)
    if title:
        ax.set_title(title, fontsize=10)
    ax.legend(loc="lower left", fontsize=7, framealpha=0.85)
    return fig


def _states(n: int, status: Sequence[str], allocated: Sequence[bool]) -> list[str]:
    if len(status):
        bad = [s for s in status if s not in STATES]
        if len(status) != n or bad:
            raise ValueError(f"target_status: {n} of {STATES} expected, got {list(status)[:5]}")
        return list(status)
    if len(allocated):
        return ["this" if a else "pending" for a in allocated]
    return ["pending"] * n


def _draw_arms(fig: Figure, ax, instrument: Instrument,
               joints: Mapping[int, tuple[float, float]], half: float) -> None:
    fig.canvas.draw()  # data mm -> points, so capsule widths are drawn to scale
    pt_per_mm = ax.get_window_extent().width / (2 * half) * 72.0 / fig.dpi
    for arm in instrument.arms:
        if arm.index not in joints:
            continue
        p = {k: np.asarray(v) for k, v in
             joint_positions_fov(instrument, arm.index, *joints[arm.index]).items()}
        colour = "tab:blue" if arm.enabled else "0.6"
        for body in arm.bodies:
            a, b = p[body.joint_from], p[body.joint_to]
            ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, alpha=0.35,
                    lw=max(2 * body.half_width_mm * pt_per_mm, 0.5), solid_capstyle="round",
                    gid=f"arm{arm.index}-{body.name}")
        tip = p["tip"]
        ax.plot(*tip, "o", color=colour, ms=3)
        if max(abs(tip[0]), abs(tip[1])) < half:
            ax.annotate(f"arm {arm.index}", tip, textcoords="offset points", xytext=(-4, -10),
                        fontsize=7, color=colour, gid=f"arm-label-{arm.index}")


def _draw_targets(ax, x: np.ndarray, y: np.ndarray, pr: np.ndarray, status: list[str],
                  ids: list[str]):
    norm = LogNorm(vmin=max(pr.min(), 1.0), vmax=max(pr.max(), pr.min() + 1.0, 2.0))
    st = np.asarray(status)
    style = {
        "this": dict(s=46, edgecolors="black", linewidths=0.9, zorder=5),
        "pending": dict(s=40, facecolors="white", linewidths=1.6, zorder=4),
        "earlier": dict(s=12, c="0.65", zorder=3),
        "unallocated": dict(s=28, marker="x", linewidths=1.0, zorder=3),
    }
    mappable = None
    for state in STATES:
        m = st == state
        if not m.any():
            continue
        kw = dict(style[state])
        if state in ("this", "unallocated"):
            kw.update(c=pr[m], cmap="viridis", norm=norm)
        elif state == "pending":
            kw.update(edgecolors=plt.get_cmap("viridis")(norm(pr[m])))
        coll = ax.scatter(x[m], y[m], label=STATE_LABELS[state], gid=f"targets-{state}", **kw)
        if state == "this" or mappable is None:
            mappable = coll
    if mappable is None or mappable.get_array() is None:
        mappable = ax.scatter([], [], c=[], cmap="viridis", norm=norm)
    for i, name in enumerate(ids):
        if status[i] in ("this", "pending"):
            ax.annotate(name, (x[i], y[i]), textcoords="offset points", xytext=(4, 3),
                        fontsize=6.5, gid=f"target-label-{name}",
                        color="black" if status[i] == "this" else "0.35")
    return mappable


def _compass(ax, position_angle_deg: float) -> None:
    """N and E arrows (axes fraction; the axes have equal aspect, so directions are true)."""
    pa = math.radians(position_angle_deg)
    origin = np.array([0.12, 0.86])
    for name, v in (("N", (-math.sin(pa), math.cos(pa))), ("E", (math.cos(pa), math.sin(pa)))):
        tip = origin + 0.07 * np.asarray(v)
        ax.annotate("", xy=tip, xytext=origin, xycoords="axes fraction",
                    arrowprops=dict(arrowstyle="->", lw=1.3, color="black"), gid=f"compass-{name}")
        ax.text(*(origin + 0.095 * np.asarray(v)), name, transform=ax.transAxes, ha="center",
                va="center", fontsize=10, fontweight="bold", gid=f"compass-label-{name}")
    ax.text(0.03, 0.97, f"PA {position_angle_deg:.1f}°", transform=ax.transAxes, va="top",
            fontsize=9, gid="position-angle")


def _scale_bar(ax, instrument: Instrument, half: float) -> None:
    length_mm = SCALE_BAR_ARCSEC / instrument.plate_scale_arcsec_per_mm
    x1, y = 0.95 * half, -0.93 * half
    ax.plot([x1 - length_mm, x1], [y, y], color="black", lw=2.5, solid_capstyle="butt",
            gid="scale-bar")
    ax.text(x1 - length_mm / 2, y + 0.02 * half, f'{SCALE_BAR_ARCSEC:g}"', ha="center",
            va="bottom", fontsize=9, gid="scale-bar-label")


def _arcsec_axes(ax, instrument: Instrument) -> None:
    s = instrument.plate_scale_arcsec_per_mm
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    top = ax.secondary_xaxis("top", functions=(lambda v: v * s, lambda v: v / s))
    top.set_xlabel("x [arcsec]", fontsize=8)
    top.tick_params(labelsize=7)


def sequence_states(configurations: Sequence[Mapping], shown: Mapping,
                    target_ids: Sequence[str]) -> list[str]:
    """Each target's state (:data:`STATES`) when configuration ``shown`` (one of the plan
    response's ``configurations`` dicts of a pointing, in sequence order) is on the bench."""
    k = next(j for j, c in enumerate(configurations) if c is shown)
    where = {a["target_id"]: j for j, c in enumerate(configurations)
             for a in c["assignments"] if a.get("target_id")}
    out = []
    for t in target_ids:
        j = where.get(t)
        out.append("unallocated" if j is None else "this" if j == k
                   else "earlier" if j < k else "pending")
    return out
