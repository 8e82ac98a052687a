"""Pictures of configurations (matplotlib, Agg), drawn for an astronomer at the telescope.

The view is the field of view, drawn as the sky is seen: focal-plane +y up and +x to the LEFT
(:mod:`service.plot_style` states the convention on the picture; at PA 0 North is up and East
left). The arms are drawn at their joint angles to scale, as capsule outlines with a light fill
(the arms' outer parts run off the frame). Every target is coloured by its priority tier and
marked by its state in the pointing's sequence (observed in this configuration, in an earlier
one, still pending, or not observed). Target and arm labels are placed by
:mod:`service.plot_labels` so that none overlaps another or a marker; a label with no free
place is dropped and the picture says how many were. A compass (N and E through the mirror for
the position angle), an arcsec scale bar, an arcsec axis and a legend of the priority tiers and
of the kinds of targets and arms complete it. An optional background image (a finding chart,
:mod:`models.finding_chart`) lies under everything.

Geometry comes from :mod:`models.kinematics`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from models.instrument import Instrument  # noqa: E402
from models.kinematics import joint_positions_fov  # noqa: E402
from service.plot_labels import (  # noqa: E402
    LabelLayout,
    LabelSpec,
    bbox_array,
    marker_boxes,
    place_labels,
)
from service.plot_style import (  # noqa: E402
    ARM_COLOURS,
    SKY_MARKER,
    arm_handles,
    compass,
    draw_capsule,
    orientation_line,
    priority_tiers,
    sky_handle,
    target_handles,
    tier_colours,
)

STATES = ("this", "earlier", "pending", "unallocated")
STATE_LABELS = {"this": "observed in this configuration", "earlier": "observed earlier",
                "pending": "pending (later configuration)", "unallocated": "not observed"}
#: Marker style of each state (scatter keywords; ``s`` in points^2).
STATE_STYLE = {
    "this": dict(s=46, marker="o", linewidths=0.9, zorder=5),
    "pending": dict(s=40, marker="o", linewidths=1.6, zorder=4),
    "earlier": dict(s=12, marker="o", linewidths=0.0, zorder=3),
    "unallocated": dict(s=28, marker="x", linewidths=1.0, zorder=3),
}
VIEW_MARGIN = 1.12  # half-width of the view / FOV radius
SCALE_BAR_ARCSEC = 60.0
FIGSIZE_IN = (9.2, 8.4)
DPI = 100
AXES_RECT = (0.06, 0.08, 0.73, 0.80)  # the view; the legend stands to its right
LEGEND_X = AXES_RECT[0] + AXES_RECT[2] + 0.008
LABEL_STYLE = {"this": dict(fontsize=6.5, color="black"), "pending": dict(fontsize=6.5, color="0.3")}


def view_size_px() -> int:
    """The side of the square view in the saved PNG, pixels (a finding chart rendered at this
    size maps one chart pixel onto one PNG pixel)."""
    return int(min(AXES_RECT[2] * FIGSIZE_IN[0], AXES_RECT[3] * FIGSIZE_IN[1]) * DPI)


def plot_configuration(instrument: Instrument, joints: Mapping[int, tuple[float, float]],
                       path: str | Path, **kwargs) -> Path:
    """Draw one configuration to ``path`` (PNG); ``kwargs`` are those of
    :func:`configuration_figure`."""
    fig = configuration_figure(instrument, joints, **kwargs)
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
    arm_targets: Mapping[int, str | None] | None = None,
    arm_kinds: Mapping[int, str | None] | None = None,
    background: np.ndarray | None = None,
) -> Figure:
    """The figure of one configuration (the caller closes it). ``joints`` maps arm ->
    (theta1, theta2). Each target's state is ``target_status[i]`` (one of :data:`STATES`);
    without it, ``allocated[i]`` means 'this' and the rest 'pending'. ``arm_targets`` maps arm
    -> its target id (None: blank sky) to tell arms on targets from idle ones; without it every
    arm away from park is on a target. ``arm_kinds`` maps arm -> its plan kind (target, sky,
    park, fixed, blank): a sky arm is drawn in its own colour with a star at its tip (legend:
    'sky position'). ``background`` holds grey levels 0..1 (1 = brightest
    sky, NaN = no image; rows from the top) spanning the whole view, its left column on the
    focal-plane +x side: a finding chart at the pointing's PA, :func:`view_half_width_mm` wide,
    drawn inverted (stars dark) so the coloured markers stay readable."""
    fig = plt.figure(figsize=FIGSIZE_IN, dpi=DPI)
    ax = fig.add_axes(AXES_RECT)
    half = view_half_width_mm(instrument)
    if background is not None:
        ax.imshow(background, extent=(half, -half, -half, half), origin="upper", zorder=0,
                  cmap="gray_r", vmin=0.0, vmax=1.0, interpolation="nearest", gid="finding-chart")
    ax.set_xlim(half, -half)  # the mirror: focal-plane +x is drawn leftwards
    ax.set_ylim(-half, half)
    ax.set_aspect("equal")
    ax.add_patch(Circle((0, 0), instrument.fov_radius_mm, fill=False, color="0.3", lw=1.2,
                        ls="--", gid="fov"))
    compass(ax, position_angle_deg)
    ax.text(0.03, 0.97, f"PA {position_angle_deg:.1f}°", transform=ax.transAxes, va="top",
            fontsize=9, gid="position-angle")
    _scale_bar(ax, instrument, half)
    _arcsec_axes(ax, instrument)
    ax.apply_aspect()  # the final transforms, before any label is measured
    drawn, arm_labels, tips = _draw_arms(ax, instrument, joints, half, arm_targets, arm_kinds)
    n = len(target_x_mm)
    x, y = np.asarray(target_x_mm, float), np.asarray(target_y_mm, float)
    pr = np.asarray(target_priority, float) if len(target_priority) else np.ones(n)
    status = _states(n, target_status, allocated)
    tiers = priority_tiers(pr)
    if n:
        _draw_targets(ax, x, y, pr, status, tiers)
    layout = place_labels(ax, arm_labels + _target_labels(x, y, pr, status, list(target_ids), fig.dpi),
                          _obstacles(ax, x, y, status, tips))
    kinds = {STATE_LABELS[s]: _legend_marker(s) for s in STATES if s in status}
    _legend(fig, target_handles(tiers, kinds) + arm_handles(drawn)
            + ([sky_handle()] if "on sky" in drawn else [])
            + [plt.Line2D([], [], color="0.3", ls="--", label=f"FOV ({instrument.fov_diameter_mm:g} mm)")])
    _notes(fig, title, orientation_line(position_angle_deg), layout)
    return fig


def view_half_width_mm(instrument: Instrument) -> float:
    """Half the side of the square view, mm (the FOV radius and a margin)."""
    return VIEW_MARGIN * instrument.fov_radius_mm


def _states(n: int, status: Sequence[str], allocated: Sequence[bool]) -> list[str]:
    if len(status):
        bad = [s for s in status if s not in STATES]
        if len(status) != n or bad:
            raise ValueError(f"target_status: {n} of {STATES} expected, got {list(status)[:5]}")
        return list(status)
    if len(allocated):
        return ["this" if a else "pending" for a in allocated]
    return ["pending"] * n


def arm_kind(arm, theta: tuple[float, float], target: str | None | bool, plan_kind: str | None = None) -> str:
    """'on sky' for a plan's sky arm; else 'parked' (at the arm's park angles), else 'on
    target' or 'on blank sky'."""
    if plan_kind == "sky":
        return "on sky"
    if np.allclose(theta, arm.park, atol=1e-6):
        return "parked"
    return "on target" if target else "on blank sky"


def _draw_arms(ax, instrument: Instrument, joints: Mapping[int, tuple[float, float]],
               half: float, arm_targets: Mapping[int, str | None] | None,
               plan_kinds: Mapping[int, str | None] | None = None,
               ) -> tuple[list[str], list[LabelSpec], np.ndarray]:
    """Capsule bodies to scale (a sky arm's tip marked with a star); returns the arm kinds
    drawn, the arm labels to place and the tips (k, 2) in the view."""
    kinds, labels, tips = [], [], []
    for arm in instrument.arms:
        if arm.index not in joints:
            continue
        target = True if arm_targets is None else arm_targets.get(arm.index)
        kind = arm_kind(arm, joints[arm.index], target, (plan_kinds or {}).get(arm.index))
        kinds.append(kind)
        colour = ARM_COLOURS[kind]
        p = {k: np.asarray(v) for k, v in
             joint_positions_fov(instrument, arm.index, *joints[arm.index]).items()}
        for body in arm.bodies:
            draw_capsule(ax, p[body.joint_from], p[body.joint_to], body.half_width_mm, colour,
                         f"arm{arm.index}-{body.name}")
        tip = p["tip"]
        ax.plot(*tip, "o", color=colour, ms=3, gid=f"arm-tip-{arm.index}")
        if kind == "on sky":
            ax.plot(*tip, ls="", gid=f"arm-sky-{arm.index}", **SKY_MARKER)
        if max(abs(tip[0]), abs(tip[1])) < half:
            tips.append(tip)
            labels.append(LabelSpec(f"arm {arm.index}", float(tip[0]), float(tip[1]), 3.0,
                                    f"arm-label-{arm.index}", dict(fontsize=7, color=colour)))
    order = ("on target", "on sky", "on blank sky", "parked")
    return [k for k in order if k in kinds], labels, np.asarray(tips, float).reshape(-1, 2)


def _draw_targets(ax, x: np.ndarray, y: np.ndarray, pr: np.ndarray, status: list[str],
                  tiers) -> None:
    colours = np.array(tier_colours(pr, tiers), dtype=object)
    st = np.asarray(status)
    for state in STATES:
        m = st == state
        if not m.any():
            continue
        kw = dict(STATE_STYLE[state])
        c = list(colours[m])
        if state == "this":
            kw.update(c=c, edgecolors="black")
        elif state == "pending":
            kw.update(facecolors="white", edgecolors=c)
        elif state == "earlier":
            kw.update(c="0.65")
        else:
            kw.update(c=c)
        ax.scatter(x[m], y[m], label=STATE_LABELS[state], gid=f"targets-{state}", **kw)


def _legend_marker(state: str) -> dict:
    """The legend's marker for a target state (grey: the tiers give the colours)."""
    return {"this": dict(marker="o", ms=7, mfc="0.6", mec="black"),
            "pending": dict(marker="o", ms=6.5, mfc="white", mec="0.4", mew=1.6),
            "earlier": dict(marker="o", ms=3.5, mfc="0.65", mec="0.65"),
            "unallocated": dict(marker="x", ms=5.5, mec="0.4", mew=1.0)}[state]


def marker_radius_px(state: str, dpi: float) -> float:
    """Half the drawn size of a target marker, display pixels."""
    return float(np.sqrt(STATE_STYLE[state]["s"])) / 2 * dpi / 72.0 + 0.5


def _target_labels(x: np.ndarray, y: np.ndarray, pr: np.ndarray, status: list[str],
                   ids: list[str], dpi: float) -> list[LabelSpec]:
    """Labels of the targets in this configuration, then of the pending ones, each by
    priority (highest first), so the crowded field keeps the labels that matter."""
    out = []
    for state in ("this", "pending"):
        idx = [i for i in range(len(ids)) if status[i] == state]
        for i in sorted(idx, key=lambda i: -pr[i]):
            out.append(LabelSpec(ids[i], float(x[i]), float(y[i]), marker_radius_px(state, dpi),
                                 f"target-label-{ids[i]}", LABEL_STYLE[state]))
    return out


def _obstacles(ax, x: np.ndarray, y: np.ndarray, status: list[str], tips: np.ndarray) -> np.ndarray:
    """Boxes no label may cover: every target marker, the arm tips, the compass, the PA text
    and the scale bar (display pixels)."""
    dpi = ax.figure.dpi
    r = np.array([marker_radius_px(s, dpi) for s in status])
    renderer = ax.figure.canvas.get_renderer()
    fixed = [a.get_window_extent(renderer) for a in ax.get_children()
             if str(a.get_gid() or "").startswith(("compass", "position-angle", "scale-bar"))]
    return np.vstack([marker_boxes(ax, x, y, r), marker_boxes(ax, tips[:, 0], tips[:, 1], 3.0),
                      bbox_array(fixed)])


def _legend(fig: Figure, handles: list) -> None:
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=(LEGEND_X, 0.88), fontsize=7,
               framealpha=0.9, title="legend", title_fontsize=8)


def _notes(fig: Figure, title: str, orientation: str, layout: LabelLayout) -> None:
    """The title, the orientation line and how many labels found no free place."""
    if title:
        fig.text(AXES_RECT[0] + AXES_RECT[2] / 2, 0.99, title, ha="center", va="top", fontsize=10, gid="title")
    fig.text(AXES_RECT[0], 0.012, orientation, fontsize=8, gid="orientation")
    if layout.dropped:
        n = len(layout.dropped)
        fig.text(LEGEND_X, 0.03, f"{n} label{'' if n == 1 else 's'} not drawn (no free place);\n"
                 "every id is in plan.json", fontsize=7, va="bottom", gid="labels-dropped")


def _scale_bar(ax, instrument: Instrument, half: float) -> None:
    """A 60" bar at the bottom right of the view (x is drawn mirrored)."""
    length_mm = SCALE_BAR_ARCSEC / instrument.plate_scale_arcsec_per_mm
    x_right, y = -0.95 * half, -0.93 * half
    ax.plot([x_right + length_mm, x_right], [y, y], color="black", lw=2.5,
            solid_capstyle="butt", gid="scale-bar")
    ax.text(x_right + length_mm / 2, y + 0.02 * half, f'{SCALE_BAR_ARCSEC:g}"', ha="center",
            va="bottom", fontsize=9, gid="scale-bar-label")


def _arcsec_axes(ax, instrument: Instrument) -> None:
    s = instrument.plate_scale_arcsec_per_mm
    ax.set_xlabel("focal-plane x [mm] (+x drawn leftwards)", fontsize=9)
    ax.set_ylabel("focal-plane y [mm]", fontsize=9, labelpad=1)
    ax.tick_params(labelsize=8)
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
