"""Greedy collision-avoiding placement of labels in a matplotlib axes (the CLI's PNGs).

Each label belongs to an anchor (a target marker, an arm tip, a pointing's circle) with a
clearance radius in display pixels. The labels are placed one by one in the order given (the
caller puts the important ones first): a label takes the first free place among candidate
positions around its anchor (right, left, above, below, then the diagonals), first just
outside the clearance and then on rings further out, where a thin leader line joins it to its
anchor. A place is free when the label's box, measured with matplotlib's own text extents
(renderer + ``get_window_extent``), stays inside the axes and overlaps neither a label placed
before it nor an obstacle (every marker, the compass, the scale bar ...). A label with no free
place is dropped; the caller says how many were dropped, and the CSV / JSON still lists them.

Everything is in display pixels, so the layout holds in the saved PNG as long as the figure is
saved at its own dpi (no ``bbox_inches="tight"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from matplotlib import patheffects
from matplotlib.axes import Axes
from matplotlib.text import Text
from matplotlib.transforms import Bbox

#: Directions tried around an anchor, in order (display pixels, y up): right, left, up, down,
#: then the four diagonals.
DIRECTIONS = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (1, -1), (-1, -1))
#: Extra distance (display px) of each ring of candidates beyond the anchor's clearance; a
#: label on a ring other than the first gets a leader line.
RINGS_PX = (0.0, 9.0, 20.0, 34.0)
PAD_PX = 1.5  # gap between a label's box and its anchor's clearance
#: A thin white halo keeps a label readable over a finding chart or an arm outline.
HALO = (patheffects.withStroke(linewidth=2.0, foreground="white", alpha=0.85),)


@dataclass(frozen=True)
class LabelSpec:
    """One label: ``text`` at data point (``x``, ``y``), kept ``radius_px`` display pixels
    clear of it; ``style`` goes to ``Axes.annotate`` (fontsize, color, ...)."""

    text: str
    x: float
    y: float
    radius_px: float
    gid: str
    style: dict[str, Any] = field(default_factory=dict)
    rings_px: tuple[float, ...] = RINGS_PX
    force: bool = False  # no free place: keep the first place inside the axes (on top)


@dataclass
class LabelLayout:
    """The placed labels (matplotlib texts, in the order placed) and the dropped ones' texts."""

    placed: list[Text]
    dropped: list[str]


class _Boxes:
    """Occupied display-pixel boxes (x0, y0, x1, y1), grown as labels are placed."""

    def __init__(self, boxes: np.ndarray, capacity: int) -> None:
        self.data = np.empty((len(boxes) + capacity, 4))
        self.data[:len(boxes)] = boxes
        self.n = len(boxes)

    def free(self, cand: np.ndarray) -> np.ndarray:
        """For each candidate box (k, 4): it overlaps no occupied box."""
        b = self.data[:self.n]
        hit = ((cand[:, None, 0] < b[None, :, 2]) & (cand[:, None, 2] > b[None, :, 0])
               & (cand[:, None, 1] < b[None, :, 3]) & (cand[:, None, 3] > b[None, :, 1]))
        return ~hit.any(axis=1)

    def add(self, box: np.ndarray) -> None:
        self.data[self.n] = box
        self.n += 1


def bbox_array(boxes: Sequence[Bbox]) -> np.ndarray:
    """Matplotlib boxes as an (n, 4) array of (x0, y0, x1, y1)."""
    return np.array([[b.x0, b.y0, b.x1, b.y1] for b in boxes], float).reshape(-1, 4)


def marker_boxes(ax: Axes, x: np.ndarray, y: np.ndarray, radius_px: np.ndarray | float) -> np.ndarray:
    """Display-pixel boxes of round markers of ``radius_px`` at data points (x, y)."""
    xy = ax.transData.transform(np.column_stack([x, y]).reshape(-1, 2))
    r = np.broadcast_to(np.asarray(radius_px, float), (len(xy),))
    return np.column_stack([xy[:, 0] - r, xy[:, 1] - r, xy[:, 0] + r, xy[:, 1] + r])


def candidates(cx: float, cy: float, r: float, w: float, h: float,
               rings_px: Sequence[float] = RINGS_PX) -> tuple[np.ndarray, np.ndarray]:
    """Candidate label boxes (k, 4) around the anchor (cx, cy) and the ring index of each."""
    boxes, ring = [], []
    for k, extra in enumerate(rings_px):
        d = r + extra + PAD_PX
        for ux, uy in DIRECTIONS:
            mx, my = cx + ux * (d + w / 2), cy + uy * (d + h / 2)
            boxes.append((mx - w / 2, my - h / 2, mx + w / 2, my + h / 2))
            ring.append(k)
    return np.array(boxes), np.array(ring)


def place_labels(ax: Axes, specs: Sequence[LabelSpec], obstacles: np.ndarray) -> LabelLayout:
    """Place ``specs`` in order (see the module doc); ``obstacles`` is an (n, 4) array of
    display-pixel boxes no label may cover. The figure's transforms must be final (call
    ``fig.canvas.draw()`` or ``ax.apply_aspect()`` after the last change of limits)."""
    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    taken = _Boxes(np.asarray(obstacles, float).reshape(-1, 4), len(specs))
    layout = LabelLayout([], [])
    for spec in specs:
        t = ax.annotate(spec.text, (spec.x, spec.y), xytext=(0, 0), textcoords="offset pixels",
                        ha="center", va="center", gid=spec.gid,
                        **{"path_effects": list(HALO), **spec.style})
        ext = t.get_window_extent(renderer)  # no arrow: the text's own box
        cx, cy = ax.transData.transform((spec.x, spec.y))
        cand, ring = candidates(cx, cy, spec.radius_px, ext.width, ext.height, spec.rings_px)
        inside = ((cand[:, 0] >= frame.x0) & (cand[:, 2] <= frame.x1)
                  & (cand[:, 1] >= frame.y0) & (cand[:, 3] <= frame.y1))
        ok = np.flatnonzero(inside & taken.free(cand))
        if not ok.size and spec.force and inside.any():
            ok = np.flatnonzero(inside)
        if not ok.size:
            t.remove()
            layout.dropped.append(spec.text)
            continue
        box = cand[ok[0]]
        mx, my = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
        # shift by the box centre's distance from the measured extent's (at offset 0, which
        # may sit a fraction of a pixel off the anchor: font descent)
        t.xyann = (mx - (ext.x0 + ext.x1) / 2, my - (ext.y0 + ext.y1) / 2)
        taken.add(box)
        layout.placed.append(t)
        if ring[ok[0]] > 0:
            _leader(ax, spec, box, cx, cy)
    return layout


def _leader(ax: Axes, spec: LabelSpec, box: np.ndarray, cx: float, cy: float) -> None:
    """A thin line from the label box's nearest point to the anchor's clearance."""
    nx, ny = float(np.clip(cx, box[0], box[2])), float(np.clip(cy, box[1], box[3]))
    colour = spec.style.get("color", "black")
    ax.annotate("", (spec.x, spec.y), xytext=(nx - cx, ny - cy), textcoords="offset pixels",
                arrowprops=dict(arrowstyle="-", lw=0.5, color=colour, alpha=0.8, shrinkA=0,
                                shrinkB=spec.radius_px * 72.0 / ax.figure.dpi),
                gid=f"leader-{spec.gid}")
