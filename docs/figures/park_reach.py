"""Where the park move limit leaves targets out: ``python docs/figures/park_reach.py``.

Draws the field of view of the default instrument on a 0.25 mm grid: every point an arm
reaches from park within 120 s turning J2 the positive way, and in red the points an arm
reaches only farther from park (``models.incompatibility.build_assignments`` with and
without ``park_move_limit_s``). Writes ``docs/figures/park_reach.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from models.incompatibility import build_assignments  # noqa: E402
from models.instrument import CONFIGURATION_TIME_GOAL_S, default_instrument  # noqa: E402

STEP_MM = 0.25


def beyond_points(step_mm: float = STEP_MM) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(x, y, beyond) on a grid over the FOV, and the FOV radius."""
    inst = default_instrument()
    r_fov = inst.fov_radius_mm
    g = np.arange(-r_fov, r_fov + step_mm / 2, step_mm)
    gx, gy = np.meshgrid(g, g)
    inside = np.hypot(gx, gy) <= r_fov - 1e-9
    x, y = gx[inside], gy[inside]
    beyond = np.zeros(len(x), bool)
    for s in range(0, len(x), 40_000):  # the IK is vectorised over targets x arms
        sl = slice(s, s + 40_000)
        r = build_assignments(inst, x[sl], y[sl], park_move_limit_s=CONFIGURATION_TIME_GOAL_S)
        beyond[s + r.beyond_limit] = True
    return x, y, beyond, r_fov


def main() -> None:
    inst = default_instrument()
    x, y, beyond, r_fov = beyond_points()
    share = beyond.mean()
    fig, (ax, zoom) = plt.subplots(1, 2, figsize=(11, 5.4), gridspec_kw={"width_ratios": [1, 1]})
    for a in (ax, zoom):
        a.add_patch(plt.Circle((0, 0), r_fov, fill=False, color="0.3", lw=1))
        a.scatter(x[beyond], y[beyond], s=0.3 if a is ax else 2, color="crimson", lw=0)
        a.set_aspect("equal")
        a.set_xlabel("x [mm]")
    bases = np.array([[arm.base_x_mm, arm.base_y_mm] for arm in inst.arms])
    ang = np.arctan2(bases[:, 1], bases[:, 0])
    for k, t in enumerate(ang):
        ax.annotate(str(k), (1.12 * r_fov * np.cos(t), 1.12 * r_fov * np.sin(t)), ha="center", va="center",
                    fontsize=8, color="0.3")
    ax.set_xlim(-1.2 * r_fov, 1.2 * r_fov)
    ax.set_ylim(-1.2 * r_fov, 1.2 * r_fov)
    ax.set_ylabel("y [mm]")
    ax.set_title(f"FOV (r = {r_fov:.0f} mm): reached only beyond {CONFIGURATION_TIME_GOAL_S:.0f} s "
                 f"from park\n{100 * share:.1f} % of the area (red); arm numbers at their bases' bearing",
                 fontsize=9)
    sel = beyond & (x > 40) & (y > 90)
    zoom.set_xlim(x[sel].min() - 8, x[sel].max() + 8)
    zoom.set_ylim(y[sel].min() - 6, r_fov + 2)
    zoom.set_title(f"zoom: a sliver within {r_fov - np.hypot(x[beyond], y[beyond]).min():.1f} mm "
                   "of the edge", fontsize=9)
    fig.tight_layout()
    out = Path(__file__).with_suffix(".png")
    fig.savefig(out, dpi=110)
    print(f"{out}: {beyond.sum()} of {len(x)} grid points ({100 * share:.2f} %) beyond the limit")


if __name__ == "__main__":
    main()
