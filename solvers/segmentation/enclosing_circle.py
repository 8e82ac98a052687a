"""Smallest enclosing circle of a planar point set (thesis Algorithm 2, Welzl 1991).

Welzl's recursion (minidiskWithSupport(P, R)) is unrolled into its classic three nested
incremental loops -- "circle with no / one / two given boundary points" -- so there is no
recursion depth limit. Each loop scans the remaining points with one vectorised numpy test
to find the next point outside the current circle; after a random shuffle (seeded) the
expected work is O(n).
"""

from __future__ import annotations

import math

import numpy as np

# A point counts as inside when it is within this distance beyond the circle: far below any
# physical tolerance, but above the rounding of coordinates of up to ~1e5 mm.
INSIDE_TOL_MM = 1e-9
SMALL_SET = 96  # below this size the plain-float loops beat the vectorised scans


def _first_outside(pts: np.ndarray, start: int, c: np.ndarray, r: float) -> int:
    """Index >= start of the first point outside circle (c, r), or -1."""
    if start >= len(pts):
        return -1
    d = np.hypot(pts[start:, 0] - c[0], pts[start:, 1] - c[1])
    out = np.flatnonzero(d > r + INSIDE_TOL_MM + 1e-12 * r)
    return start + int(out[0]) if out.size else -1


def _diameter_circle(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    c = 0.5 * (a + b)
    return c, float(np.hypot(*(a - c)))


def _circumcircle(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, float]:
    """Circle through three points; for (nearly) collinear ones, the widest diameter circle
    (the only case where the circumcircle is unstable, and then that circle is the answer)."""
    bx, by = b - a
    cx, cy = p - a
    d = 2.0 * (bx * cy - by * cx)
    scale = max(bx * bx + by * by, cx * cx + cy * cy)
    if abs(d) <= 1e-14 * scale:
        best = max(((a, b), (a, p), (b, p)), key=lambda q: float(np.hypot(*(q[0] - q[1]))))
        return _diameter_circle(*best)
    b2, c2 = bx * bx + by * by, cx * cx + cy * cy
    ux = (cy * b2 - by * c2) / d
    uy = (bx * c2 - cx * b2) / d
    centre = a + np.array([ux, uy])
    r = max(float(np.hypot(*(centre - q))) for q in (a, b, p))
    return centre, r


def _with_two(pts: np.ndarray, p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, float]:
    """Smallest circle enclosing pts with p and q on its boundary."""
    c, r = _diameter_circle(p, q)
    k = _first_outside(pts, 0, c, r)
    while k >= 0:
        c, r = _circumcircle(p, q, pts[k])
        k = _first_outside(pts, k + 1, c, r)
    return c, r


def _with_one(pts: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, float]:
    """Smallest circle enclosing pts with p on its boundary."""
    c, r = p.copy(), 0.0
    j = _first_outside(pts, 0, c, r)
    while j >= 0:
        c, r = _with_two(pts[:j], pts[j], p)
        j = _first_outside(pts, j + 1, c, r)
    return c, r


def _small_set(xs: list[float], ys: list[float]) -> tuple[float, float, float]:
    """The same three nested loops in plain Python floats: faster than numpy below ~100 points
    (numpy's per-call overhead dominates for the handful of hull vertices of a cluster)."""
    tol = INSIDE_TOL_MM

    def out(k: int, cx: float, cy: float, r: float) -> bool:
        return math.hypot(xs[k] - cx, ys[k] - cy) > r + tol + 1e-12 * r

    cx, cy, r = xs[0], ys[0], 0.0
    for i in range(1, len(xs)):
        if not out(i, cx, cy, r):
            continue
        cx, cy, r = xs[i], ys[i], 0.0  # circle with p_i on the boundary
        for j in range(i):
            if not out(j, cx, cy, r):
                continue
            cx, cy = 0.5 * (xs[i] + xs[j]), 0.5 * (ys[i] + ys[j])  # p_i, p_j on the boundary
            r = math.hypot(xs[i] - cx, ys[i] - cy)
            for k in range(j):
                if out(k, cx, cy, r):
                    c, r = _circumcircle(np.array([xs[i], ys[i]]), np.array([xs[j], ys[j]]),
                                         np.array([xs[k], ys[k]]))
                    cx, cy = float(c[0]), float(c[1])
    return cx, cy, r


def smallest_enclosing_circle(
    points_mm: np.ndarray, seed: int = 0,
) -> tuple[float, float, float]:
    """Smallest circle containing every point of an (n, 2) array: (cx_mm, cy_mm, radius_mm).

    Thesis Algorithm 2 (Welzl), iterative. Degenerate sets are fine: one point (radius 0),
    duplicates, collinear points (circle on the two extremes). Raises ValueError when empty.
    """
    pts = np.asarray(points_mm, dtype=float).reshape(-1, 2)
    if len(pts) == 0:
        raise ValueError("points_mm: no points")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points_mm: must be finite")
    pts = pts[np.random.default_rng(seed).permutation(len(pts))]
    if len(pts) <= SMALL_SET:
        return _small_set(pts[:, 0].tolist(), pts[:, 1].tolist())
    c, r = pts[0].copy(), 0.0
    i = _first_outside(pts, 1, c, r)
    while i >= 0:
        c, r = _with_one(pts[:i], pts[i])
        i = _first_outside(pts, i + 1, c, r)
    return float(c[0]), float(c[1]), float(r)
