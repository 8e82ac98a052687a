"""Patrolling strategies: the arms x slices-of-pie penalty matrix (thesis 3.7, 5.3.1.1).

A *slice of pie* (SoP) is an angular sector of the FOV about its centre. The penalty
matrix ``C`` (n_arms x n_slices) says how much arm ``i`` dislikes observing a target in
slice ``j``: 0 is the preferred slice, larger is worse, ``-1`` forbids the slice (thesis
eq. 5.2/5.3). The semi-greedy allocator orders candidate arms by this penalty and never
uses a forbidden pair.

Two built-in strategies:

* :func:`thesis_penalty_matrix` -- eq. 5.3: twelve 30 degree slices, arm k prefers its own
  slice (centred on its own azimuth 30 degrees * k), then the counter-clockwise neighbour
  (10), the clockwise neighbour (15), two slices CCW (20), two CW (25), three CCW (30),
  three CW (35); the rest is forbidden.
* :func:`workspace_penalty_matrix` -- workspace patrolling (thesis 3.7.1): one slice that
  is the whole FOV and penalty 0 for every arm, i.e. any reachable target is allowed.

The FOV centre belongs to every slice (thesis 5.5.2: "for a point in the center (it
belongs to all SoPs)"), and so does a point on the border between two slices: its
penalty for an arm is the smallest non-negative penalty over the slices holding it.
"""

from __future__ import annotations

import numpy as np

from models.errors import InputError

# penalty of arm k for slice (k + offset) mod 12 in thesis eq. 5.3; other offsets are -1
THESIS_OFFSET_PENALTY = {0: 0, 1: 10, -1: 15, 2: 20, -2: 25, 3: 30, -3: 35}
FORBIDDEN = -1
CENTRE_TOL_MM = 1e-6  # points this close to the FOV centre lie in every slice
BORDER_TOL_RAD = 1e-9  # points this close to a slice border lie in both slices


def thesis_penalty_matrix(n_arms: int = 12) -> np.ndarray:
    """The default SoP penalty matrix of thesis eq. 5.3 (n_arms slices, one per arm).

    Built from the offset pattern of eq. 5.3 so it generalises to other arm counts; for
    12 arms it is exactly the printed matrix (row 0: 0 10 20 30 -1 -1 -1 -1 -1 35 25 15).
    """
    if n_arms < 1:
        raise InputError("n_arms", "must be >= 1")
    c = np.full((n_arms, n_arms), FORBIDDEN, dtype=np.int64)
    # larger |offset| first so that, for few arms where offsets alias, the preferred
    # (smaller) penalty wins
    for off, pen in sorted(THESIS_OFFSET_PENALTY.items(), key=lambda kv: -kv[1]):
        for k in range(n_arms):
            c[k, (k + off) % n_arms] = pen
    return c


def workspace_penalty_matrix(n_arms: int = 12) -> np.ndarray:
    """Workspace patrolling (thesis 3.7.1): one slice (the whole FOV), penalty 0 for all arms."""
    if n_arms < 1:
        raise InputError("n_arms", "must be >= 1")
    return np.zeros((n_arms, 1), dtype=np.int64)


def validate_penalty_matrix(matrix, n_arms: int, field: str = "penalty_matrix") -> np.ndarray:
    """Check a user-supplied penalty matrix; return it as an int64 array.

    Shape (n_arms, n_slices >= 1); every entry an integer that is -1 (forbidden) or >= 0.
    Raises :class:`InputError` naming the field (and the offending entry).
    """
    try:
        raw = np.asarray(matrix)
    except (ValueError, TypeError) as exc:  # ragged nested lists
        raise InputError(field, f"must be a rectangular matrix: {exc}") from exc
    if raw.dtype == object:
        raise InputError(field, "must be a rectangular matrix of integers")
    if raw.ndim != 2:
        raise InputError(field, f"must be a 2-D matrix (arms x slices), got {raw.ndim} dimension(s)")
    if raw.shape[0] != n_arms:
        raise InputError(field, f"must have one row per arm ({n_arms}), got {raw.shape[0]} rows")
    if raw.shape[1] < 1:
        raise InputError(field, "must have at least one slice (column)")
    if raw.dtype.kind == "b" or raw.dtype.kind not in "iuf":
        raise InputError(field, f"entries must be integers, got dtype {raw.dtype}")
    if raw.dtype.kind == "f":
        bad = ~np.isfinite(raw) | (raw != np.round(raw))
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise InputError(f"{field}[{i}][{j}]", f"must be an integer, got {raw[i, j]!r}")
        if np.abs(raw).max(initial=0) > 2**62:
            raise InputError(field, "entries out of range")
    c = raw.astype(np.int64)
    bad = (c < 0) & (c != FORBIDDEN)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise InputError(f"{field}[{i}][{j}]", f"must be -1 (forbidden) or >= 0, got {int(c[i, j])}")
    return c


def slice_membership(x_mm, y_mm, n_slices: int, first_centre_deg: float = 0.0) -> np.ndarray:
    """(n_points, n_slices) bool: which slices of pie hold each FOV point.

    Slice ``j`` is the sector of azimuths ``[c_j - d/2, c_j + d/2]`` with
    ``c_j = first_centre_deg + j * d`` and ``d = 360 / n_slices`` degrees (thesis 3.7.2:
    the SoP of arm k is symmetric about the line through its J1 and J2, i.e. centred on
    the arm azimuth 30 degrees * k). The centre and the slice borders belong to every
    adjacent slice; with one slice every point belongs to it.
    """
    x = np.atleast_1d(np.asarray(x_mm, float))
    y = np.atleast_1d(np.asarray(y_mm, float))
    n = len(x)
    if n_slices == 1:
        return np.ones((n, 1), bool)
    width = 2 * np.pi / n_slices
    start = np.deg2rad(first_centre_deg) - width / 2
    u = np.mod(np.arctan2(y, x) - start, 2 * np.pi) / width  # in [0, n_slices)
    j = np.minimum(np.floor(u).astype(int), n_slices - 1)
    member = np.zeros((n, n_slices), bool)
    member[np.arange(n), j] = True
    frac = u - np.floor(u)
    tol = BORDER_TOL_RAD / width
    member[np.arange(n), (j - 1) % n_slices] |= frac < tol
    member[np.arange(n), (j + 1) % n_slices] |= frac > 1 - tol
    member[np.hypot(x, y) < CENTRE_TOL_MM] = True
    return member


def slice_of_point(x_mm, y_mm, n_slices: int, first_centre_deg: float = 0.0) -> np.ndarray:
    """Index of the (first) slice holding each point; see :func:`slice_membership`."""
    return np.argmax(slice_membership(x_mm, y_mm, n_slices, first_centre_deg), axis=1)


def point_penalties(matrix: np.ndarray, x_mm, y_mm, first_centre_deg: float = 0.0) -> np.ndarray:
    """(n_arms, n_points) penalty of each arm for each point; -1 where the arm may not patrol it.

    For a point in several slices (centre, borders) the smallest non-negative penalty
    over those slices is taken: the point may be observed under the most lenient one.
    """
    c = np.asarray(matrix, dtype=np.int64)
    member = slice_membership(x_mm, y_mm, c.shape[1], first_centre_deg)  # (n_points, n_slices)
    big = np.iinfo(np.int64).max
    cc = np.where(c >= 0, c, big)  # (n_arms, n_slices)
    pen = np.where(member[None, :, :], cc[:, None, :], big).min(axis=2)
    return np.where(pen == big, FORBIDDEN, pen)
