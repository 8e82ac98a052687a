"""Probe-arm kinematics, vectorised over arrays of configurations and points.

Arm frame (ARCHITECTURE.md): origin at J1, x-axis toward the FOV centre. Link lengths are
passed explicitly so every function broadcasts over arms as well as configurations; the
``*_fov`` helpers look them up from an :class:`~models.instrument.Instrument`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.instrument import Instrument

TWO_PI = 2.0 * np.pi
THETA1_TOL_RAD = 1e-9  # park sits exactly on the theta1 = pi limit
#: relative rounding of the J3 circle intersection taken as tangency (a point at the arm's full reach)
H2_TOL = 1e-12


@dataclass(frozen=True)
class Links:
    """Link lengths and stops of one or many arms (arrays broadcast against configurations)."""

    d12_mm: np.ndarray | float
    d13_mm: np.ndarray | float
    d24_mm: np.ndarray | float
    d3tip_mm: np.ndarray | float
    stop_min_mm: np.ndarray | float
    stop_max_mm: np.ndarray | float
    theta1_min_rad: np.ndarray | float = 0.0
    theta1_max_rad: np.ndarray | float = np.pi

    @staticmethod
    def of(instrument: Instrument, arm: np.ndarray | int) -> Links:
        """Links of the given arm index (or array of indices, broadcasting)."""
        arm = np.asarray(arm, dtype=int)
        g = instrument.arm_array
        return Links(*(g(n)[arm] for n in (
            "d12_mm", "d13_mm", "d24_mm", "d3tip_mm", "stop_min_mm", "stop_max_mm",
            "theta1_min_rad", "theta1_max_rad")))


# ---------------------------------------------------------------------------- forward


def joint_positions(theta1_rad, theta2_rad, links: Links) -> dict[str, np.ndarray]:
    """J1, J2, J3, J4 and tip in the arm frame, each of shape (..., 2) (thesis eqs. 3.4, 3.9–3.16)."""
    t1 = np.asarray(theta1_rad, dtype=float)
    t2 = np.asarray(theta2_rad, dtype=float)
    j3 = np.stack(np.broadcast_arrays(links.d13_mm * np.cos(t1), links.d13_mm * np.sin(t1)), -1)
    j4 = np.stack(np.broadcast_arrays(links.d12_mm - links.d24_mm * np.cos(t2),
                                      links.d24_mm * np.sin(t2)), -1)
    j3, j4 = np.broadcast_arrays(j3, j4)
    w = j4 - j3
    d34 = np.hypot(w[..., 0], w[..., 1])
    tip = j3 + (np.asarray(links.d3tip_mm) / d34)[..., None] * w
    zero = np.zeros_like(j3)
    j2 = zero + np.stack(np.broadcast_arrays(np.asarray(links.d12_mm, float), 0.0 * t1), -1)
    return {"J1": zero, "J2": j2, "J3": j3, "J4": j4, "tip": tip}


def d34_mm(theta1_rad, theta2_rad, links: Links) -> np.ndarray:
    """Distance J3–J4 (thesis eq. 3.5)."""
    t1 = np.asarray(theta1_rad, dtype=float)
    t2 = np.asarray(theta2_rad, dtype=float)
    dx = links.d12_mm - links.d24_mm * np.cos(t2) - links.d13_mm * np.cos(t1)
    dy = links.d24_mm * np.sin(t2) - links.d13_mm * np.sin(t1)
    return np.hypot(dx, dy)


def forward_tip(theta1_rad, theta2_rad, links: Links) -> np.ndarray:
    """Pick-off mirror position in the arm frame, shape (..., 2) (thesis eq. 3.13)."""
    return joint_positions(theta1_rad, theta2_rad, links)["tip"]


# ----------------------------------------------------------------- zone of avoidance


def in_zoa(theta1_rad, theta2_rad, links: Links) -> np.ndarray:
    """True where a configuration is in the zone of avoidance (thesis eqs. 3.1–3.2).

    Outside the theta1 range [min, max] (inclusive, the park sits on pi) or with J4 not
    strictly between its stops.
    """
    t1 = np.asarray(theta1_rad, dtype=float)
    d = d34_mm(t1, theta2_rad, links)
    bad_t1 = (t1 < links.theta1_min_rad - THETA1_TOL_RAD) | (t1 > links.theta1_max_rad + THETA1_TOL_RAD)
    return bad_t1 | ~((d > links.stop_min_mm) & (d < links.stop_max_mm)) | ~np.isfinite(d)


def segment_in_zoa(q_from: np.ndarray, q_to: np.ndarray, links: Links, tol_mm: float = 0.01) -> np.ndarray:
    """True where the straight joint-space segment q_from -> q_to touches the ZoA.

    ``q_*`` have shape (..., 2) as (theta1, theta2); theta2 is *not* wrapped, so the
    direction of rotation is the sign of the difference. Sampled so that d34 changes by at
    most ``tol_mm`` between samples (|dd34| <= d13 |dtheta1| + d24 |dtheta2|): an excursion
    into the ZoA deeper than ``tol_mm`` is always detected. theta1 limits are checked at
    the end points (theta1 is linear along the segment).
    """
    q_from = np.asarray(q_from, dtype=float)
    q_to = np.asarray(q_to, dtype=float)
    q_from, q_to = np.broadcast_arrays(q_from, q_to)
    dq = q_to - q_from
    bound = np.abs(dq[..., 0]) * np.max(links.d13_mm) + np.abs(dq[..., 1]) * np.max(links.d24_mm)
    n = int(np.clip(np.ceil(np.max(bound, initial=0.0) / tol_mm), 1, 200_000))
    s = np.linspace(0.0, 1.0, n + 1)
    shape = q_from.shape[:-1]
    t1 = q_from[..., 0][..., None] + dq[..., 0][..., None] * s
    t2 = q_from[..., 1][..., None] + dq[..., 1][..., None] * s
    lk = Links(*(np.asarray(v, dtype=float)[..., None] if np.ndim(v) else v for v in (
        links.d12_mm, links.d13_mm, links.d24_mm, links.d3tip_mm, links.stop_min_mm,
        links.stop_max_mm, links.theta1_min_rad, links.theta1_max_rad)))
    return in_zoa(t1, t2, lk).any(axis=-1).reshape(shape)


# ---------------------------------------------------------------------------- inverse


@dataclass(frozen=True)
class IKSolutions:
    """Every feasible (theta1, theta2) for each point: up to 4 per point (2 J3 × 2 J4 choices).

    Arrays have shape (n_points, 4); ``valid`` marks real, feasible solutions.
    """

    theta1_rad: np.ndarray
    theta2_rad: np.ndarray
    valid: np.ndarray


def inverse(x_mm, y_mm, links: Links) -> IKSolutions:
    """All feasible joint solutions reaching arm-frame point(s) (thesis eqs. 3.17–3.27).

    J3 is an intersection of the circle of radius d13 about J1 with the circle of radius
    d3tip about the tip (two choices); J4 is an intersection of the line J3→tip with the
    circle of radius d24 about J2 (two choices). A solution is kept when theta1 is in range
    and J4 lies strictly between its stops on the ray from J3 through the tip.
    """
    px = np.atleast_1d(np.asarray(x_mm, dtype=float))
    py = np.atleast_1d(np.asarray(y_mm, dtype=float))
    px, py = np.broadcast_arrays(px, py)
    d13, d3t, d12, d24 = (np.asarray(v, float)[..., None] for v in (
        links.d13_mm, links.d3tip_mm, links.d12_mm, links.d24_mm))
    smin, smax = (np.asarray(v, float)[..., None] for v in (links.stop_min_mm, links.stop_max_mm))
    t1min, t1max = (np.asarray(v, float)[..., None] for v in (links.theta1_min_rad, links.theta1_max_rad))
    P = np.stack([px, py], -1)[..., None, :]  # (..., 1, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.hypot(px, py)[..., None]
        a = (d**2 + d13**2 - d3t**2) / (2 * d)
        h2 = d13**2 - a**2
        # a point at the full reach (tangent circles) rounds h2 to a tiny negative: h = 0 there
        h = np.sqrt(np.where((h2 < 0.0) & (h2 > -H2_TOL * d13**2), 0.0, h2))
        ux, uy = px[..., None] / d, py[..., None] / d
        sign3 = np.array([1.0, 1.0, -1.0, -1.0])
        sign4 = np.array([1.0, -1.0, 1.0, -1.0])
        j3x = a * ux - sign3 * h * uy
        j3y = a * uy + sign3 * h * ux
        theta1 = np.arctan2(j3y, j3x)
        # theta1 in [0, pi]: atan2 gives (-pi, pi]; -0 and tiny negatives snap to the limits
        theta1 = np.where((theta1 < 0) & (theta1 > -THETA1_TOL_RAD), 0.0, theta1)
        theta1 = np.where(theta1 <= -np.pi + THETA1_TOL_RAD, np.pi, theta1)
        lx = (P[..., 0] - j3x) / d3t
        ly = (P[..., 1] - j3y) / d3t
        rx, ry = j3x - d12, j3y
        B = lx * rx + ly * ry
        C = rx**2 + ry**2 - d24**2
        s = -B + sign4 * np.sqrt(B**2 - C)
        j4x = j3x + s * lx
        j4y = j3y + s * ly
        theta2 = np.mod(np.arctan2(j4y, d12 - j4x), TWO_PI)
        valid = (
            np.isfinite(theta1) & np.isfinite(theta2) & np.isfinite(s)
            & (theta1 >= t1min - THETA1_TOL_RAD) & (theta1 <= t1max + THETA1_TOL_RAD)
            & (s > smin) & (s < smax)
        )
    # identical solutions (tangent circles, h == 0 or discriminant 0) are reported once
    dup = np.zeros_like(valid)
    for i in range(4):
        for j in range(i):
            same = (np.abs(theta1[..., i] - theta1[..., j]) < 1e-12) & (
                np.abs(theta2[..., i] - theta2[..., j]) < 1e-12) & valid[..., j]
            dup[..., i] |= same
    valid &= ~dup
    theta1 = np.where(valid, theta1, np.nan)
    theta2 = np.where(valid, theta2, np.nan)
    return IKSolutions(theta1, theta2, valid)


# --------------------------------------------------------------- distances, Jacobian


def joint_displacement(q_from: np.ndarray, q_to: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint-space displacement with the theta2 wrap (thesis eq. 3.8).

    Returns (dtheta1, dtheta2_ccw, dtheta2_cw): dtheta2_ccw in [0, 2pi) turning
    counterclockwise, dtheta2_cw = dtheta2_ccw - 2pi (<= 0) turning clockwise.
    """
    q_from = np.asarray(q_from, dtype=float)
    q_to = np.asarray(q_to, dtype=float)
    d1 = q_to[..., 0] - q_from[..., 0]
    ccw = np.mod(q_to[..., 1] - q_from[..., 1], TWO_PI)
    cw = np.where(ccw > 0, ccw - TWO_PI, 0.0)
    return d1, ccw, cw


def joint_distance(q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """Max-norm joint distance taking the shorter theta2 direction (rad)."""
    d1, ccw, cw = joint_displacement(q_from, q_to)
    return np.maximum(np.abs(d1), np.minimum(ccw, -cw))


def direct_move_time_s(q_from: np.ndarray, q_to: np.ndarray, v1_rad_s, v2_rad_s) -> np.ndarray:
    """Time of a straight joint move, both joints at full speed, shorter theta2 way (thesis eq. 5.1)."""
    d1, ccw, cw = joint_displacement(q_from, q_to)
    return np.maximum(np.abs(d1) / v1_rad_s, np.minimum(ccw, -cw) / v2_rad_s)


def positive_turn_move_time_s(q_from: np.ndarray, q_to: np.ndarray, v1_rad_s, v2_rad_s) -> np.ndarray:
    """Time of a straight joint move, both joints at full speed, theta2 turning the positive
    way (counterclockwise), however far that is.

    From park this is the move an arm can make: turning the negative way from park swings
    its L3 link through its next neighbour (docs/motion.md, "Leaving park one way round").
    """
    d1, ccw, _ = joint_displacement(q_from, q_to)
    return np.maximum(np.abs(d1) / v1_rad_s, ccw / v2_rad_s)


def jacobian(theta1_rad, theta2_rad, links: Links) -> np.ndarray:
    """d(tip)/d(theta1, theta2) in the arm frame, shape (..., 2, 2) (thesis eqs. 3.40–3.46).

    Written in vector form (tip = J3 + d3tip ŵ, w = J4 − J3) rather than through the
    thesis' u = tan(alpha), which is singular where J4 − J3 is vertical.
    """
    p = joint_positions(theta1_rad, theta2_rad, links)
    t1 = np.asarray(theta1_rad, float)
    t2 = np.asarray(theta2_rad, float)
    dj3 = np.stack(np.broadcast_arrays(-links.d13_mm * np.sin(t1), links.d13_mm * np.cos(t1)), -1)
    dj4 = np.stack(np.broadcast_arrays(links.d24_mm * np.sin(t2), links.d24_mm * np.cos(t2)), -1)
    w = p["J4"] - p["J3"]
    n = np.linalg.norm(w, axis=-1, keepdims=True)
    wh = w / n
    scale = np.asarray(links.d3tip_mm)[..., None] / n

    def proj(v):
        return v - np.sum(v * wh, -1, keepdims=True) * wh

    c1 = dj3 + scale * proj(-dj3)
    c2 = scale * proj(dj4)
    return np.stack([c1, c2], -1)


# ------------------------------------------------------------------- frame changes


def arm_axes(instrument: Instrument, arm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(base (..., 2), e_x (..., 2), e_y (..., 2)) of the given arm(s) in the FOV frame."""
    arm = np.asarray(arm, dtype=int)
    base = np.stack([instrument.arm_array("base_x_mm")[arm], instrument.arm_array("base_y_mm")[arm]], -1)
    o = instrument.arm_array("orientation_rad")[arm]
    ex = np.stack([np.cos(o), np.sin(o)], -1)
    ey = np.stack([-ex[..., 1], ex[..., 0]], -1)
    return base, ex, ey


def fov_to_arm(instrument: Instrument, arm, x_mm, y_mm) -> tuple[np.ndarray, np.ndarray]:
    """FOV-frame point(s) in the frame of the given arm(s) (thesis eqs. 3.47–3.49)."""
    base, ex, ey = arm_axes(instrument, arm)
    dx = np.asarray(x_mm, float) - base[..., 0]
    dy = np.asarray(y_mm, float) - base[..., 1]
    return dx * ex[..., 0] + dy * ex[..., 1], dx * ey[..., 0] + dy * ey[..., 1]


def arm_to_fov(instrument: Instrument, arm, a_mm, b_mm) -> tuple[np.ndarray, np.ndarray]:
    """Arm-frame point(s) of the given arm(s) in the FOV frame."""
    base, ex, ey = arm_axes(instrument, arm)
    a = np.asarray(a_mm, float)
    b = np.asarray(b_mm, float)
    return base[..., 0] + a * ex[..., 0] + b * ey[..., 0], base[..., 1] + a * ex[..., 1] + b * ey[..., 1]


def joint_positions_fov(instrument: Instrument, arm, theta1_rad, theta2_rad) -> dict[str, np.ndarray]:
    """Every joint of the given arm(s) at the given configuration(s), FOV frame, (..., 2)."""
    arm = np.asarray(arm, dtype=int)
    p = joint_positions(theta1_rad, theta2_rad, Links.of(instrument, arm))
    base, ex, ey = arm_axes(instrument, arm)
    out = {}
    for name, v in p.items():
        out[name] = base + v[..., :1] * ex + v[..., 1:] * ey
    return out


def tip_fov(instrument: Instrument, arm, theta1_rad, theta2_rad) -> np.ndarray:
    return joint_positions_fov(instrument, arm, theta1_rad, theta2_rad)["tip"]


def inverse_fov(instrument: Instrument, arm, x_mm, y_mm) -> IKSolutions:
    """Every feasible configuration of arm(s) ``arm`` reaching FOV point(s) (x, y).

    ``arm`` and the points broadcast; result arrays have shape broadcast + (4,).
    """
    a, b = fov_to_arm(instrument, arm, x_mm, y_mm)
    arm_b = np.broadcast_to(np.asarray(arm, dtype=int), np.shape(a))
    return inverse(a, b, Links.of(instrument, arm_b))


#: :func:`inverse_fov_every_arm` solves only the points within this distance of an arm's
#: annulus of reach (J1 to the tip between |d13 - d3tip| and d13 + d3tip); beyond it the
#: circles of J3 miss each other by far more than the tangent tolerance ``H2_TOL``, so the
#: solutions left out are exactly those :func:`inverse` finds invalid
REACH_MARGIN_MM = 1.0


def inverse_fov_every_arm(instrument: Instrument, x_mm, y_mm) -> IKSolutions:
    """:func:`inverse_fov` of every arm at every FOV point, arrays (n_arms, n_points, 4),
    solved only where a point lies in the arm's annulus of reach (:data:`REACH_MARGIN_MM`):
    the same solutions, element by element, at the cost of the points each arm can reach."""
    x = np.asarray(x_mm, float).ravel()
    y = np.asarray(y_mm, float).ravel()
    arms = np.arange(instrument.n_arms)
    a, b = fov_to_arm(instrument, arms[:, None], x[None, :], y[None, :])
    d13, d3t = instrument.arm_array("d13_mm")[:, None], instrument.arm_array("d3tip_mm")[:, None]
    d = np.hypot(a, b)
    k, t = np.nonzero((d >= np.abs(d13 - d3t) - REACH_MARGIN_MM) & (d <= d13 + d3t + REACH_MARGIN_MM))
    some = inverse(a[k, t], b[k, t], Links.of(instrument, k))
    shape = (len(arms), len(x), 4)
    theta1, theta2 = np.full(shape, np.nan), np.full(shape, np.nan)
    valid = np.zeros(shape, bool)
    theta1[k, t], theta2[k, t], valid[k, t] = some.theta1_rad, some.theta2_rad, some.valid
    return IKSolutions(theta1, theta2, valid)
