"""The fields of the motion benchmark (benchmarks/motion.py): the thesis 6.4.2 protocol's
prioritised fields (uniform and Gaussian clusters about the FOV centre, the thesis 5.5.3
priority mix) and the easy protocol's uniform fields of priority 1."""

from __future__ import annotations

import numpy as np

from models.types import PlaneTargets

FOV_RADIUS_MM = 125.0
FIELD_SIGMAS_MM: tuple[float | None, ...] = (None, 40.0, 60.0, 90.0)  # None: uniform
PRIORITY_VALUES = (500, 100, 10, 1)
PRIORITY_SHARES = (0.1, 0.4, 0.4, 0.1)


def shape_name(sigma_mm: float | None) -> str:
    return "uniform" if sigma_mm is None else f"gauss{sigma_mm:g}"


def field_xy_mm(n: int, sigma_mm: float | None, rng: np.random.Generator,
                radius_mm: float = FOV_RADIUS_MM) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points uniform in the FOV disc (sigma None) or Gaussian about the centre, clipped."""
    if sigma_mm is None:
        r_mm = radius_mm * np.sqrt(rng.random(n))
        a_rad = rng.random(n) * 2 * np.pi
        return r_mm * np.cos(a_rad), r_mm * np.sin(a_rad)
    pts = np.zeros((0, 2))
    while len(pts) < n:
        p = rng.normal(0.0, sigma_mm, (2 * n, 2))
        pts = np.vstack([pts, p[np.hypot(p[:, 0], p[:, 1]) <= radius_mm]])
    return pts[:n, 0], pts[:n, 1]


def make_field(n: int, sigma_mm: float | None, rng: np.random.Generator) -> PlaneTargets:
    """A field of ``n`` targets with the thesis priority mix (as benchmarks/allocation.py)."""
    x_mm, y_mm = field_xy_mm(n, sigma_mm, rng)
    priority = rng.choice(PRIORITY_VALUES, size=n, p=PRIORITY_SHARES).astype(np.int64)
    return PlaneTargets.from_lists([f"t{i}" for i in range(n)], x_mm, y_mm, priority)


def thesis_field(n: int, seed: int, field_index: int) -> tuple[str, PlaneTargets]:
    sigma_mm = FIELD_SIGMAS_MM[field_index % len(FIELD_SIGMAS_MM)]
    rng = np.random.default_rng([seed, field_index])
    return shape_name(sigma_mm), make_field(n, sigma_mm, rng)


def easy_field(n: int, rng: np.random.Generator) -> PlaneTargets:
    x_mm, y_mm = field_xy_mm(n, None, rng)
    return PlaneTargets.from_lists(range(n), x_mm, y_mm, np.ones(n, dtype=np.int64))


def thesis_field_parameters() -> dict:
    return {"field_shapes": [shape_name(s) for s in FIELD_SIGMAS_MM],
            "priority_mix": dict(zip(map(str, PRIORITY_VALUES), PRIORITY_SHARES, strict=True))}
