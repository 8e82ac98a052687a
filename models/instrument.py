"""Instrument description: FOV, plate scale and the 12 probe arms, loaded from a TOML file.

The default file (``models/instruments/miradas.toml``) carries the assumed geometry of
ARCHITECTURE.md; a calibrated file replaces it without code changes. Every arm value can
be overridden per arm (a calibrated arm differs from its siblings) and an arm can be
marked out of service with ``enabled = false``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

JOINT_NAMES = ("J1", "J2", "J3", "J4", "tip")
BODY_SHAPES = ("capsule", "box", "sphere")
#: The configuration time goal T_p (thesis 6.3.1, problem 1): every arm at its new
#: configuration within 120 s. The motion planner aims at it; the plan pipeline's default
#: park move limit keeps every location within it of park.
CONFIGURATION_TIME_GOAL_S = 120.0


class InstrumentError(ValueError):
    """An instrument file is malformed; the message names the offending field."""


@dataclass(frozen=True)
class Body:
    """One rigid body of an arm, attached between two joints (thesis fig. 3.2)."""

    name: str
    shape: str
    joint_from: str
    joint_to: str
    radius_mm: float = 0.0
    width_mm: float = 0.0
    height_mm: float = 10.0

    @property
    def half_width_mm(self) -> float:
        """Lateral reach of the body from its axis (capsule radius or half box width)."""
        return self.radius_mm if self.shape in ("capsule", "sphere") else 0.5 * self.width_mm


@dataclass(frozen=True)
class Arm:
    """Geometry, limits and state of one probe arm; lengths in mm, angles in rad."""

    index: int
    enabled: bool
    base_x_mm: float
    base_y_mm: float
    orientation_rad: float  # direction of the arm frame x-axis in the FOV frame
    d12_mm: float
    d13_mm: float
    d24_mm: float
    d3tip_mm: float
    stop_min_mm: float
    stop_max_mm: float
    theta1_min_rad: float
    theta1_max_rad: float
    park_theta1_rad: float
    park_theta2_rad: float
    joint1_speed_rad_s: float
    joint2_speed_rad_s: float
    bodies: tuple[Body, ...]

    @property
    def park(self) -> tuple[float, float]:
        return (self.park_theta1_rad, self.park_theta2_rad)


@dataclass(frozen=True)
class Instrument:
    """The whole multiplexing system. Arrays over arms are cached for vectorised kernels."""

    name: str
    fov_diameter_mm: float
    plate_scale_arcsec_per_mm: float
    collision_buffer_mm: float
    arms: tuple[Arm, ...]
    source: str = field(default="", compare=False)

    @property
    def n_arms(self) -> int:
        return len(self.arms)

    @property
    def fov_radius_mm(self) -> float:
        return 0.5 * self.fov_diameter_mm

    @property
    def enabled_arms(self) -> tuple[int, ...]:
        return tuple(a.index for a in self.arms if a.enabled)

    def arm_array(self, name: str) -> np.ndarray:
        """Per-arm numeric attribute as an array of shape (n_arms,)."""
        return self._arrays[name]

    @cached_property
    def _arrays(self) -> dict[str, np.ndarray]:
        names = (
            "base_x_mm base_y_mm orientation_rad d12_mm d13_mm d24_mm d3tip_mm stop_min_mm "
            "stop_max_mm theta1_min_rad theta1_max_rad park_theta1_rad park_theta2_rad "
            "joint1_speed_rad_s joint2_speed_rad_s"
        ).split()
        out = {n: np.array([getattr(a, n) for a in self.arms], dtype=float) for n in names}
        out["enabled"] = np.array([a.enabled for a in self.arms], dtype=bool)
        return out

    @cached_property
    def uniform_bodies(self) -> bool:
        """True when every arm has the same body list (enables the vectorised fast path)."""
        first = self.arms[0].bodies
        return all(a.bodies == first for a in self.arms)

    @property
    def all_capsules(self) -> bool:
        return all(b.shape == "capsule" for a in self.arms for b in a.bodies)

    @property
    def park_configuration(self) -> np.ndarray:
        """(n_arms, 2) park joint angles."""
        return np.column_stack([self.arm_array("park_theta1_rad"), self.arm_array("park_theta2_rad")])

    @property
    def max_joint_speed_rad_s(self) -> float:
        return float(
            min(self.arm_array("joint1_speed_rad_s").min(), self.arm_array("joint2_speed_rad_s").min())
        )

    def with_arms_disabled(self, indices: list[int] | tuple[int, ...]) -> Instrument:
        arms = tuple(
            Arm(**{**a.__dict__, "enabled": a.enabled and a.index not in set(indices)})
            for a in self.arms
        )
        return Instrument(
            self.name, self.fov_diameter_mm, self.plate_scale_arcsec_per_mm,
            self.collision_buffer_mm, arms, self.source,
        )

    def with_collision_buffer(self, buffer_mm: float) -> Instrument:
        if not (math.isfinite(buffer_mm) and buffer_mm >= 0):
            raise InstrumentError("collision_buffer_mm: must be a finite number >= 0")
        return Instrument(
            self.name, self.fov_diameter_mm, self.plate_scale_arcsec_per_mm, buffer_mm,
            self.arms, self.source,
        )


_ARM_FLOAT_FIELDS = (
    "d12_mm", "d13_mm", "d24_mm", "d3tip_mm", "stop_min_mm", "stop_max_mm",
    "theta1_min_rad", "theta1_max_rad", "park_theta1_rad", "park_theta2_rad",
    "joint1_speed_rad_s", "joint2_speed_rad_s",
)


def _number(d: dict[str, Any], key: str, where: str, *, positive: bool = False) -> float:
    if key not in d:
        raise InstrumentError(f"{where}.{key}: missing")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InstrumentError(f"{where}.{key}: must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise InstrumentError(f"{where}.{key}: must be > 0, got {v!r}")
    return float(v)


def _parse_body(b: dict[str, Any], where: str) -> Body:
    name = str(b.get("name", where))
    shape = b.get("shape", "capsule")
    if shape not in BODY_SHAPES:
        raise InstrumentError(f"{where}.shape: must be one of {BODY_SHAPES}, got {shape!r}")
    jf, jt = b.get("from"), b.get("to", b.get("from"))
    for key, j in (("from", jf), ("to", jt)):
        if j not in JOINT_NAMES:
            raise InstrumentError(f"{where}.{key}: must be one of {JOINT_NAMES}, got {j!r}")
    if shape in ("capsule", "sphere"):
        return Body(name, shape, jf, jt, radius_mm=_number(b, "radius_mm", where, positive=True))
    return Body(
        name, shape, jf, jt,
        width_mm=_number(b, "width_mm", where, positive=True),
        height_mm=float(b.get("height_mm", 10.0)),
    )


def _parse_arm(index: int, base: tuple[float, float], orientation: float,
               values: dict[str, Any], where: str) -> Arm:
    nums = {}
    for key in _ARM_FLOAT_FIELDS:
        positive = key.endswith("_mm") or key.endswith("speed_rad_s")
        nums[key] = _number(values, key, where, positive=positive)
    if not nums["stop_min_mm"] < nums["stop_max_mm"]:
        raise InstrumentError(f"{where}.stop_min_mm: must be below stop_max_mm")
    if not nums["theta1_min_rad"] < nums["theta1_max_rad"]:
        raise InstrumentError(f"{where}.theta1_min_rad: must be below theta1_max_rad")
    bodies_raw = values.get("bodies")
    if not isinstance(bodies_raw, list) or not bodies_raw:
        raise InstrumentError(f"{where}.bodies: at least one body is required")
    bodies = tuple(_parse_body(b, f"{where}.bodies[{i}]") for i, b in enumerate(bodies_raw))
    enabled = values.get("enabled", True)
    if not isinstance(enabled, bool):
        raise InstrumentError(f"{where}.enabled: must be true or false")
    return Arm(index=index, enabled=enabled, base_x_mm=base[0], base_y_mm=base[1],
               orientation_rad=orientation, bodies=bodies, **nums)


def parse_instrument(data: dict[str, Any], source: str = "<dict>") -> Instrument:
    """Validate a decoded instrument document and build the :class:`Instrument`."""
    top = {k: _number(data, k, "instrument", positive=True)
           for k in ("fov_diameter_mm", "plate_scale_arcsec_per_mm")}
    buffer_mm = _number(data, "collision_buffer_mm", "instrument")
    if buffer_mm < 0:
        raise InstrumentError("instrument.collision_buffer_mm: must be >= 0")
    layout = data.get("layout")
    if not isinstance(layout, dict):
        raise InstrumentError("layout: missing table")
    n = layout.get("arm_count")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise InstrumentError(f"layout.arm_count: must be a positive integer, got {n!r}")
    ring_r = _number(layout, "base_radius_mm", "layout", positive=True)
    first = _number(layout, "first_angle_deg", "layout")
    step = _number(layout, "step_deg", "layout")
    defaults = data.get("arm_defaults", {})
    overrides: dict[int, dict[str, Any]] = {}
    for i, o in enumerate(data.get("arms", [])):
        idx = o.get("index")
        if not isinstance(idx, int) or isinstance(idx, bool) or not 0 <= idx < n:
            raise InstrumentError(f"arms[{i}].index: must be an integer in [0, {n - 1}], got {idx!r}")
        if idx in overrides:
            raise InstrumentError(f"arms[{i}].index: arm {idx} listed twice")
        overrides[idx] = o
    arms = []
    for k in range(n):
        values = {**defaults, **overrides.get(k, {})}
        phi = math.radians(first + step * k)
        base = (ring_r * math.cos(phi), ring_r * math.sin(phi))
        if "base_x_mm" in values or "base_y_mm" in values:
            base = (_number(values, "base_x_mm", f"arms[{k}]"), _number(values, "base_y_mm", f"arms[{k}]"))
        orientation = math.atan2(-base[1], -base[0])
        if "orientation_deg" in values:
            orientation = math.radians(_number(values, "orientation_deg", f"arms[{k}]"))
        arms.append(_parse_arm(k, base, orientation, values, f"arms[{k}]"))
    return Instrument(
        name=str(data.get("name", "instrument")),
        fov_diameter_mm=top["fov_diameter_mm"],
        plate_scale_arcsec_per_mm=top["plate_scale_arcsec_per_mm"],
        collision_buffer_mm=buffer_mm,
        arms=tuple(arms),
        source=source,
    )


def load_instrument(path: str | Path | None = None) -> Instrument:
    """Load and validate an instrument TOML file; ``None`` gives the packaged default."""
    if path is None:
        text = resources.files("models.instruments").joinpath("miradas.toml").read_text()
        source = "models/instruments/miradas.toml"
    else:
        p = Path(path)
        if not p.is_file():
            raise InstrumentError(f"instrument file not found: {p}")
        text, source = p.read_text(), str(p)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InstrumentError(f"{source}: not valid TOML: {exc}") from exc
    return parse_instrument(data, source)


_DEFAULT: Instrument | None = None


def default_instrument() -> Instrument:
    """The packaged default instrument (loaded once)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = load_instrument(None)
    return _DEFAULT
