"""PNG pictures: checked on the figure's artists (texts, limits, collections), not pixels."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

from models.instrument import default_instrument
from models.kinematics import inverse_fov
from service.plots import STATES, configuration_figure, plot_configuration, sequence_states

INST = default_instrument()


def _artist(fig, gid: str):
    hits = [a for a in fig.findobj() if getattr(a, "get_gid", lambda: None)() == gid]
    assert len(hits) == 1, (gid, len(hits))
    return hits[0]


def _figure(pa_deg: float = 0.0, n: int = 12, seed: int = 3):
    rng = np.random.default_rng(seed)
    r = 100 * np.sqrt(rng.uniform(size=n))
    phi = rng.uniform(0, 2 * math.pi, n)
    x, y = r * np.cos(phi), r * np.sin(phi)
    status = [STATES[i % 4] for i in range(n)]
    ids = [f"T{i:02d}" for i in range(n)]
    fig = configuration_figure(INST, {a.index: a.park for a in INST.arms}, target_x_mm=x,
                               target_y_mm=y, target_priority=rng.integers(1, 500, n),
                               target_status=status, target_ids=ids, position_angle_deg=pa_deg)
    return fig, x, y, status, ids


def test_fov_fills_most_of_the_width_and_axes_are_equal() -> None:
    fig, *_ = _figure()
    try:
        ax = fig.axes[0]
        hi, lo = ax.get_xlim()  # mirrored: focal-plane +x is drawn leftwards
        assert ax.get_ylim() == (lo, hi) and ax.get_aspect() == 1.0 and hi > lo
        fov_frac_of_axes = INST.fov_diameter_mm / (hi - lo)
        fig.canvas.draw()
        ax_frac_of_fig = ax.get_window_extent().width / fig.bbox.width
        assert fov_frac_of_axes * ax_frac_of_fig > 0.65
        assert fov_frac_of_axes > 0.85
    finally:
        plt.close(fig)


def test_ids_compass_scale_bar_and_position_angle_are_drawn() -> None:
    fig, _, _, status, ids = _figure(pa_deg=30.0)
    try:
        texts = {t.get_text() for t in fig.findobj(plt.Text)}
        for name, st in zip(ids, status, strict=True):
            assert (name in texts) == (st in ("this", "pending")), name
        assert {"N", "E", "PA 30.0°", '60"'} <= texts
        bar = _artist(fig, "scale-bar")
        length = np.ptp(bar.get_xdata())
        assert length == pytest.approx(60.0 / INST.plate_scale_arcsec_per_mm)
        assert any("arcsec" in (a.get_xlabel() or "") for a in fig.findobj(
            lambda o: hasattr(o, "get_xlabel")))
    finally:
        plt.close(fig)


@pytest.mark.parametrize("pa_deg", [0.0, 90.0, 217.0])
def test_compass_points_to_north_and_east(pa_deg: float) -> None:
    fig, *_ = _figure(pa_deg=pa_deg)
    try:
        pa = math.radians(pa_deg)
        # models.sky: focal +y is at PA east of north, so N = (-sin PA, cos PA), E = (cos, sin)
        # on the focal plane, drawn through the mirror (focal +x leftwards): x negated
        for name, want in (("N", (math.sin(pa), math.cos(pa))),
                           ("E", (-math.cos(pa), math.sin(pa)))):
            arrow = _artist(fig, f"compass-{name}")
            v = np.subtract(arrow.xy, arrow.xyann)
            assert v / np.linalg.norm(v) == pytest.approx(want, abs=1e-9)
        # as on the sky seen by the observer: East is North turned counter-clockwise by 90 deg
        n = np.subtract(_artist(fig, "compass-N").xy, _artist(fig, "compass-N").xyann)
        e = np.subtract(_artist(fig, "compass-E").xy, _artist(fig, "compass-E").xyann)
        assert n[0] * e[1] - n[1] * e[0] > 0
    finally:
        plt.close(fig)


def test_target_states_are_drawn_distinctly() -> None:
    fig, x, y, status, _ = _figure(n=16)
    try:
        st = np.asarray(status)
        looks = {}
        for state in STATES:
            coll = _artist(fig, f"targets-{state}")
            assert np.allclose(coll.get_offsets(), np.c_[x[st == state], y[st == state]])
            looks[state] = (tuple(np.round(coll.get_sizes(), 3)), coll.get_paths()[0].vertices.shape,
                            coll.get_facecolor().shape[0] > 0 and tuple(np.round(coll.get_facecolor()[0], 3)))
        earlier, pending = looks["earlier"], looks["pending"]
        assert earlier != pending
        assert _artist(fig, "targets-pending").get_facecolor()[0][:3] == pytest.approx((1, 1, 1))
        assert _artist(fig, "targets-earlier").get_sizes()[0] < _artist(fig, "targets-pending").get_sizes()[0]
    finally:
        plt.close(fig)


def test_arms_are_drawn_to_scale_at_their_joint_angles(tmp_path: Path) -> None:
    """An arm placed by IK on a target ends on that target in the picture."""
    sol = inverse_fov(INST, 0, 30.0, -20.0)
    valid = np.ravel(sol.valid)
    k = int(np.flatnonzero(valid)[0])
    joints = {a.index: a.park for a in INST.arms}
    joints[0] = (float(np.ravel(sol.theta1_rad)[k]), float(np.ravel(sol.theta2_rad)[k]))
    fig = configuration_figure(INST, joints, target_x_mm=[30.0], target_y_mm=[-20.0],
                               target_priority=[5], target_status=["this"], target_ids=["X"])
    try:
        l3 = [b for b in INST.arms[0].bodies if b.joint_to == "tip"][0]
        outline = _artist(fig, f"arm0-{l3.name}").get_xy()
        # a capsule of the body's true half width: its tip end is an arc about the target
        d = np.hypot(outline[:, 0] - 30.0, outline[:, 1] + 20.0)
        assert np.sum(np.isclose(d, l3.half_width_mm, atol=1e-9)) >= 10
        assert d.min() == pytest.approx(l3.half_width_mm, abs=1e-9)
    finally:
        plt.close(fig)
    out = plot_configuration(INST, joints, tmp_path / "c.png", target_x_mm=[30.0],
                             target_y_mm=[-20.0], allocated=[True])
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sequence_states_and_bad_states() -> None:
    confs = [{"assignments": [{"target_id": "a"}, {"target_id": None}]},
             {"assignments": [{"target_id": "b"}]}, {"assignments": [{"target_id": "c"}]}]
    assert sequence_states(confs, confs[1], ["a", "b", "c", "d"]) == [
        "earlier", "this", "pending", "unallocated"]
    with pytest.raises(ValueError, match="target_status"):
        configuration_figure(INST, {}, target_x_mm=[0.0], target_y_mm=[0.0],
                             target_status=["observed"])
    plt.close("all")
