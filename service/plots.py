"""Pictures of configurations (matplotlib, Agg): FOV circle, arms at their joint angles,
targets coloured by priority. Geometry comes from :mod:`models.kinematics`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from models.instrument import Instrument  # noqa: E402
from models.kinematics import joint_positions_fov  # noqa: E402


def plot_configuration(
    instrument: Instrument,
    joints: Mapping[int, tuple[float, float]],
    path: str | Path,
    *,
    target_x_mm: Sequence[float] = (),
    target_y_mm: Sequence[float] = (),
    target_priority: Sequence[int] = (),
    allocated: Sequence[bool] = (),
    title: str = "",
) -> Path:
    """Draw one configuration to ``path`` (PNG). ``joints`` maps arm -> (theta1, theta2)."""
    shown = [a for a in instrument.arms if a.index in joints]
    pos = {
        a.index: {k: np.asarray(v) for k, v in joint_positions_fov(
            instrument, a.index, *joints[a.index]).items()}
        for a in shown
    }
    pts = np.array([v for p in pos.values() for v in p.values()] + [[0.0, 0.0]])
    reach = float(np.abs(pts).max()) + 25.0
    fig = plt.figure(figsize=(8.0, 7.0), dpi=100)
    ax = fig.add_axes((0.09, 0.07, 0.74, 0.86))
    cax = fig.add_axes((0.86, 0.2, 0.025, 0.6))
    try:
        r_fov = instrument.fov_radius_mm
        ax.set_xlim(-reach, reach)
        ax.set_ylim(-reach, reach)
        ax.set_aspect("equal")
        ax.add_patch(Circle((0, 0), r_fov, fill=False, color="0.3", lw=1.2, ls="--",
                            label=f"FOV ({instrument.fov_diameter_mm:g} mm)"))
        # data mm -> points, so capsule widths are drawn to scale
        fig.canvas.draw()
        bbox = ax.get_window_extent()
        pt_per_mm = bbox.width / (2 * reach) * 72.0 / fig.dpi
        for arm in instrument.arms:
            if arm.index not in pos:
                continue
            p = pos[arm.index]
            colour = "tab:blue" if arm.enabled else "0.6"
            for body in arm.bodies:
                a, b = p[body.joint_from], p[body.joint_to]
                ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, alpha=0.45,
                        lw=max(2 * body.half_width_mm * pt_per_mm, 0.5), solid_capstyle="round")
            ax.plot(*p["J1"], "ks", ms=4)
            ax.plot(*p["tip"], "o", color=colour, ms=3)
            ax.annotate(str(arm.index), p["J1"], textcoords="offset points", xytext=(4, 4),
                        fontsize=8)
        if len(target_x_mm):
            x = np.asarray(target_x_mm, float)
            y = np.asarray(target_y_mm, float)
            pr = np.asarray(target_priority, float) if len(target_priority) else np.ones_like(x)
            norm = LogNorm(vmin=max(pr.min(), 1.0), vmax=max(pr.max(), pr.min() + 1.0, 2.0))
            sc = ax.scatter(x, y, c=pr, cmap="viridis", norm=norm, s=18, zorder=3,
                            edgecolors="none")
            if len(allocated):
                m = np.asarray(allocated, bool)
                ax.scatter(x[m], y[m], s=70, facecolors="none", edgecolors="tab:red", lw=1.2,
                           zorder=4, label="allocated")
            fig.colorbar(sc, cax=cax, label="priority")
        else:
            cax.set_visible(False)
        ax.set_xlabel("x [mm]")
        ax.set_ylabel("y [mm]")
        if title:
            ax.set_title(title, fontsize=10)
        ax.legend(loc="upper right", fontsize=8)
        out = Path(path)
        fig.savefig(out)
        return out
    finally:
        plt.close(fig)
