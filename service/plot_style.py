"""What every CLI picture shares: the orientation (sky as seen: North up, East left), its one-line
statement, the N/E compass, priority tiers (colours), capsule-shaped arm bodies and the legend.

Orientation: focal-plane views draw +y up and +x to the LEFT (the x axis is inverted), sky views
draw the standard coordinate xi (East) to the LEFT and eta (North) up. :mod:`models.sky` puts
focal-plane +x East and +y North at PA 0, so both views show the sky as the observer sees it.
At position angle PA the compass draws North along focal-plane (-sin PA, cos PA) and East along
(cos PA, sin PA), both through the same mirror, so East is always 90 degrees counter-clockwise
of North, as on the sky.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Polygon

from service.sky_text import priority_text

#: Tier colours, highest priority first (no blue: the arms are drawn in blue-grey).
TIER_COLOURS = ("#d62728", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b")
MAX_TIERS = len(TIER_COLOURS)
ARM_COLOURS = {"on target": "#1f4e9c", "parked": "0.45", "on blank sky": "#6b6b6b", "on sky": "#1b8a6b"}
#: the tip of a spare arm on sky (planner.sky): a star, distinct from target markers
SKY_MARKER = dict(marker="*", ms=9, mfc="#1b8a6b", mec="black", mew=0.5)


def sky_handle() -> Line2D:
    """The legend entry of a sky arm's tip."""
    return Line2D([], [], ls="", label="sky position (spare arm)", **SKY_MARKER)
FOCAL_ORIENTATION = "Sky as seen: North up, East left (focal-plane +x drawn leftwards)"
SKY_ORIENTATION = "Sky as seen: North up, East left (xi, East, increases leftwards)"


def orientation_line(position_angle_deg: float | None = None) -> str:
    """The picture's one-line statement of its orientation (``None``: a sky view)."""
    if position_angle_deg is None:
        return SKY_ORIENTATION
    if math.isclose(position_angle_deg % 360.0, 0.0, abs_tol=1e-9):
        return FOCAL_ORIENTATION
    return (f"Sky as seen (focal-plane +x drawn leftwards, +y up); at PA {position_angle_deg:g}° "
            f"North and East as the compass shows")


@dataclass(frozen=True)
class PriorityTier:
    """Priorities ``lo`` .. ``hi`` (inclusive), drawn in ``colour``."""

    lo: float
    hi: float
    colour: str

    @property
    def label(self) -> str:
        if self.lo == self.hi:
            return f"priority {priority_text(self.lo)}"
        return f"priority {priority_text(self.lo)}–{priority_text(self.hi)}"


def priority_tiers(priorities: Sequence[float]) -> list[PriorityTier]:
    """At most :data:`MAX_TIERS` tiers, highest first: one per distinct priority when there are
    few, else the distinct values split into runs of about equal count (so a tier is never
    empty and the highest priorities always have their own colour)."""
    values = np.unique(np.asarray(priorities, float))[::-1]
    if not values.size:
        return []
    groups = np.array_split(values, min(MAX_TIERS, values.size))
    return [PriorityTier(float(g.min()), float(g.max()), TIER_COLOURS[k])
            for k, g in enumerate(groups)]


def tier_colours(priorities: Sequence[float], tiers: Sequence[PriorityTier]) -> list[str]:
    """The colour of each priority's tier."""
    out = []
    for p in priorities:
        out.append(next((t.colour for t in tiers if t.lo <= p <= t.hi), "black"))
    return out


def capsule(a: np.ndarray, b: np.ndarray, half_width: float, n: int = 12) -> np.ndarray:
    """Outline (m, 2) of the capsule of radius ``half_width`` around segment a-b (data units)."""
    d = b - a
    angle = math.atan2(d[1], d[0]) if np.hypot(*d) > 0 else 0.0
    t1 = np.linspace(angle + math.pi / 2, angle + 3 * math.pi / 2, n)
    t2 = t1 + math.pi
    return np.vstack([a + half_width * np.column_stack([np.cos(t1), np.sin(t1)]),
                      b + half_width * np.column_stack([np.cos(t2), np.sin(t2)])])


def draw_capsule(ax: Axes, a: np.ndarray, b: np.ndarray, half_width: float, colour: str,
                 gid: str) -> None:
    """An arm body drawn to scale as an outline with a light fill, so overlapping neighbours
    show two outlines crossing (not one dark blob that reads as a collision)."""
    ax.add_patch(Polygon(capsule(a, b, half_width), closed=True, facecolor=(*_rgb(colour), 0.10),
                         edgecolor=colour, lw=0.8, gid=gid))


def _rgb(colour: str) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb

    return to_rgb(colour)


def compass(ax: Axes, position_angle_deg: float, origin: tuple[float, float] = (0.88, 0.86)) -> None:
    """N and E arrows in axes fraction, drawn through the focal-plane mirror (x negated): at
    PA 0 North is up and East left. The axes have equal aspect, so directions are true."""
    pa = math.radians(position_angle_deg)
    o = np.asarray(origin)
    for name, (vx, vy) in (("N", (-math.sin(pa), math.cos(pa))),
                           ("E", (math.cos(pa), math.sin(pa)))):
        v = np.array([-vx, vy])  # the mirror: focal-plane +x is drawn leftwards
        ax.annotate("", xy=o + 0.07 * v, xytext=o, xycoords="axes fraction",
                    arrowprops=dict(arrowstyle="->", lw=1.3, color="black"), gid=f"compass-{name}")
        ax.text(*(o + 0.095 * v), name, transform=ax.transAxes, ha="center", va="center",
                fontsize=10, fontweight="bold", gid=f"compass-label-{name}")


def sky_compass(ax: Axes, origin: tuple[float, float] = (0.88, 0.86)) -> None:
    """N up, E left: the compass of a sky view (the focal-plane compass at PA 0)."""
    compass(ax, 0.0, origin)


def target_handles(tiers: Sequence[PriorityTier], kinds: dict[str, dict]) -> list:
    """Legend entries: one per priority tier (colour) and one per target kind (marker)."""
    handles: list = [Patch(facecolor=t.colour, edgecolor="black", lw=0.5, label=t.label)
                     for t in tiers]
    for label, kw in kinds.items():
        handles.append(Line2D([], [], ls="", label=label, **kw))
    return handles


def arm_handles(kinds: Sequence[str]) -> list:
    """Legend entries of the arm kinds shown (on target, parked, on blank sky)."""
    return [Patch(facecolor=(*_rgb(ARM_COLOURS[k]), 0.10), edgecolor=ARM_COLOURS[k], lw=0.7,
                  label=f"arm {k}") for k in kinds]
