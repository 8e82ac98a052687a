"""Instrument file loader: defaults, per-arm overrides, validation naming the field."""

from __future__ import annotations

import copy
import math
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from models.errors import InputError
from models.instrument import InstrumentError, default_instrument, load_instrument, parse_instrument
from models.kinematics import tip_fov
from models.types import PlaneTargets


def default_doc() -> dict:
    return tomllib.loads(resources.files("models.instruments").joinpath("miradas.toml").read_text())


def test_default_instrument_matches_architecture() -> None:
    ins = default_instrument()
    assert ins.n_arms == 12
    assert ins.fov_diameter_mm == 250.0 and ins.plate_scale_arcsec_per_mm == 1.2
    assert ins.collision_buffer_mm == 5.0
    for k, arm in enumerate(ins.arms):
        phi = math.radians(30 * k)
        assert math.isclose(arm.base_x_mm, 350 * math.cos(phi), abs_tol=1e-9)
        assert math.isclose(arm.base_y_mm, 350 * math.sin(phi), abs_tol=1e-9)
        # x-axis toward the FOV centre
        assert math.isclose(math.cos(arm.orientation_rad), -math.cos(phi), abs_tol=1e-12)
        assert (arm.d12_mm, arm.d13_mm, arm.d24_mm, arm.d3tip_mm) == (186, 77, 50, 305)
        assert (arm.stop_min_mm, arm.stop_max_mm) == (183, 350)
        assert arm.park == (math.pi, 0.0)
        assert arm.joint1_speed_rad_s == 0.031416
        assert [b.name for b in arm.bodies] == ["L1", "L2", "L3"]
        assert [b.radius_mm for b in arm.bodies] == [8, 8, 10]


def test_per_arm_override_and_enabled_flag(tmp_path: Path) -> None:
    doc = default_doc()
    text = resources.files("models.instruments").joinpath("miradas.toml").read_text()
    text += "\n[[arms]]\nindex = 7\nd3tip_mm = 306.0\n\n[[arms]]\nindex = 2\nenabled = false\n"
    p = tmp_path / "calibrated.toml"
    p.write_text(text)
    ins = load_instrument(p)
    assert ins.arms[7].d3tip_mm == 306.0 and ins.arms[6].d3tip_mm == 305.0
    assert not ins.arms[2].enabled and ins.enabled_arms == tuple(k for k in range(12) if k != 2)
    # the override changes the kinematics of that arm only
    park = ins.park_configuration
    tips = tip_fov(ins, np.arange(12), park[:, 0], park[:, 1])
    r = np.hypot(tips[:, 0], tips[:, 1])
    assert np.isclose(r[7], 121.0) and np.isclose(r[6], 122.0)
    assert doc["layout"]["arm_count"] == 12


def test_new_instrument_needs_no_code_change() -> None:
    doc = default_doc()
    doc["layout"].update(arm_count=8, step_deg=45.0, base_radius_mm=340.0)
    doc["fov_diameter_mm"] = 240.0
    ins = parse_instrument(doc)
    assert ins.n_arms == 8 and ins.fov_radius_mm == 120.0
    assert np.isclose(np.hypot(ins.arms[3].base_x_mm, ins.arms[3].base_y_mm), 340.0)


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d.__setitem__("fov_diameter_mm", -1), "fov_diameter_mm"),
        (lambda d: d.__setitem__("plate_scale_arcsec_per_mm", float("nan")), "plate_scale_arcsec_per_mm"),
        (lambda d: d["arm_defaults"].__setitem__("d12_mm", "long"), "d12_mm"),
        (lambda d: d["arm_defaults"].__setitem__("stop_min_mm", 400.0), "stop_min_mm"),
        (lambda d: d["arm_defaults"]["bodies"][0].__setitem__("shape", "torus"), "shape"),
        (lambda d: d["arm_defaults"]["bodies"][1].__setitem__("to", "J9"), "to"),
        (lambda d: d["layout"].__setitem__("arm_count", 0), "arm_count"),
        (lambda d: d.__setitem__("arms", [{"index": 12}]), "index"),
        (lambda d: d.__setitem__("arms", [{"index": 1, "enabled": "yes"}]), "enabled"),
        (lambda d: d["arm_defaults"].pop("d24_mm"), "d24_mm"),
    ],
)
def test_bad_instrument_file_names_the_field(mutate, field: str) -> None:
    doc = copy.deepcopy(default_doc())
    mutate(doc)
    with pytest.raises(InstrumentError, match=field):
        parse_instrument(doc)


def test_missing_or_malformed_file(tmp_path: Path) -> None:
    with pytest.raises(InstrumentError, match="not found"):
        load_instrument(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("fov_diameter_mm = = 3")
    with pytest.raises(InstrumentError, match="TOML"):
        load_instrument(bad)


@pytest.mark.parametrize(
    ("ids", "x", "y", "prio", "field"),
    [
        (["a", "b"], [0.0, float("nan")], [0.0, 0.0], [1, 1], "targets[1].x_mm"),
        (["a", "b"], [0.0, 1.0], [float("inf"), 0.0], [1, 1], "targets[0].y_mm"),
        (["a", "a"], [0.0, 1.0], [0.0, 0.0], [1, 1], "targets[1].id"),
        (["a", "b"], [0.0, 1.0], [0.0, 0.0], [1, 0], "targets[1].priority"),
        (["a", "b"], [0.0, 1.0], [0.0, 0.0], [1, 2**40], "targets[1].priority"),
    ],
)
def test_bad_plane_targets_name_the_field(ids, x, y, prio, field) -> None:
    with pytest.raises(InputError) as err:
        PlaneTargets.from_lists(ids, x, y, prio)
    assert err.value.field == field


def test_max_priority_is_kept_exactly() -> None:
    t = PlaneTargets.from_lists(["a", "b"], [0, 1], [0, 0], [2**32 - 1, 2**32 - 2])
    assert int(t.priority[0]) == 2**32 - 1 and int(t.priority[0]) > int(t.priority[1])
