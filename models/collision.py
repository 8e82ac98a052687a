"""Arm body geometry and collision checks.

Two engines answer the same question — the clearance between the bodies of two arms:

* a vectorised capsule fast path (2-D segment–segment distance minus radii) used for
  bulk work (the incompatibility matrix, motion-planning checks), and
* python-fcl, the exact engine for any body shape the instrument file declares (capsule,
  box, sphere) and the oracle the fast path is tested against.

Two arms collide when their clearance is below the collision buffer (thesis table 6.1).
"""

from __future__ import annotations

from itertools import combinations

import fcl
import numpy as np

from models.instrument import Body, Instrument
from models.kinematics import joint_positions_fov

_EPS = 1e-12


# --------------------------------------------------------------- capsule fast path


def segment_distance_mm(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Distance between 2-D segments p0–p1 and q0–q1, vectorised over leading axes.

    Closest points of two segments (Ericson, *Real-Time Collision Detection*, 5.1.9);
    degenerate (zero-length) segments are points.
    """
    p0 = np.asarray(p0, float)
    p1 = np.asarray(p1, float)
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    return segment_distance_xy(p0[..., 0], p0[..., 1], p1[..., 0], p1[..., 1],
                               q0[..., 0], q0[..., 1], q1[..., 0], q1[..., 1])


def segment_distance_xy(p0x, p0y, p1x, p1y, q0x, q0y, q1x, q1y) -> np.ndarray:
    """:func:`segment_distance_mm` on separate coordinate arrays (no stacking, less memory traffic)."""
    d1x = p1x - p0x
    d1y = p1y - p0y
    d2x = q1x - q0x
    d2y = q1y - q0y
    rx = p0x - q0x
    ry = p0y - q0y
    a = d1x * d1x + d1y * d1y
    e = d2x * d2x + d2y * d2y
    f = d2x * rx + d2y * ry
    c = d1x * rx + d1y * ry
    b = d1x * d2x + d1y * d2y
    a_ok = a > _EPS
    e_ok = e > _EPS
    safe_a = np.where(a_ok, a, 1.0)
    safe_e = np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    general = denom > _EPS * np.maximum(a * e, _EPS)
    s = np.where(general, (b * f - c * e) / np.where(general, denom, 1.0), 0.0)
    s = np.clip(s, 0.0, 1.0)
    t = (b * s + f) / safe_e
    s = np.where(t < 0.0, np.clip(-c / safe_a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / safe_a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # degenerate segments (points)
    s = np.where(~a_ok, 0.0, np.where(~e_ok, np.clip(-c / safe_a, 0.0, 1.0), s))
    t = np.where(~e_ok, 0.0, np.where(~a_ok, np.clip(f / safe_e, 0.0, 1.0), t))
    dx = rx + d1x * s - d2x * t
    dy = ry + d1y * s - d2y * t
    out = np.hypot(dx, dy)
    par = ~general & a_ok & e_ok
    if np.any(par):
        # (nearly) parallel: the closest pair involves an end point, whichever end it is
        out = np.array(out, float, copy=True)
        full = np.broadcast_arrays(p0x, p0y, p1x, p1y, q0x, q0y, q1x, q1y, par)
        m = full[-1]
        ax_, ay_, bx_, by_, cx_, cy_, ex_, ey_ = (np.asarray(v, float)[m] for v in full[:-1])
        ends = np.minimum(np.minimum(_point_segment(ax_, ay_, cx_, cy_, ex_, ey_),
                                     _point_segment(bx_, by_, cx_, cy_, ex_, ey_)),
                          np.minimum(_point_segment(cx_, cy_, ax_, ay_, bx_, by_),
                                     _point_segment(ex_, ey_, ax_, ay_, bx_, by_)))
        # nearly parallel segments that cross (each one's ends on either side of the other)
        ends = np.where(_crossing(ax_, ay_, bx_, by_, cx_, cy_, ex_, ey_), 0.0, ends)
        if out.ndim == 0:
            return np.asarray(min(float(out), float(ends[0])))
        out[m] = np.minimum(out[m], ends)
    return out


def _crossing(ax, ay, bx, by, cx, cy, ex, ey) -> np.ndarray:
    """Whether nearly parallel segments a-b and c-e cross: c and e lie on either side of
    a-b's line (or on it), a and b on either side of c-e's, and their spans along a-b
    overlap (which keeps the rounding of the side tests on collinear segments from making
    disjoint ones cross; collinear ones keep their end points' distance, exact for them)."""
    def side(px, py, qx, qy, rx, ry):
        return (qx - px) * (ry - py) - (qy - py) * (rx - px)

    dx, dy = bx - ax, by - ay
    ll = np.where(dx * dx + dy * dy > _EPS, dx * dx + dy * dy, 1.0)
    tc, te = ((cx - ax) * dx + (cy - ay) * dy) / ll, ((ex - ax) * dx + (ey - ay) * dy) / ll
    overlap = np.maximum(np.minimum(tc, te), 0.0) <= np.minimum(np.maximum(tc, te), 1.0)
    return (overlap & (side(ax, ay, bx, by, cx, cy) * side(ax, ay, bx, by, ex, ey) <= 0.0)
            & (side(cx, cy, ex, ey, ax, ay) * side(cx, cy, ex, ey, bx, by) <= 0.0))


def _point_segment(px, py, ax, ay, bx, by) -> np.ndarray:
    """Distance from points (px, py) to segments a-b (b may equal a)."""
    dx, dy = bx - ax, by - ay
    ll = dx * dx + dy * dy
    t = np.clip(((px - ax) * dx + (py - ay) * dy) / np.where(ll > _EPS, ll, 1.0), 0.0, 1.0)
    return np.hypot(px - ax - t * dx, py - ay - t * dy)


def body_segments_mm(instrument: Instrument, arm, theta1_rad, theta2_rad) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capsule model of the arm bodies in the FOV frame.

    Returns (start (..., n_bodies, 2), end (..., n_bodies, 2), half_width (..., n_bodies)).
    Spheres are zero-length capsules; boxes are approximated by their inscribed capsule
    here and only the FCL engine treats them exactly.
    """
    arm = np.asarray(arm, dtype=int)
    joints = joint_positions_fov(instrument, arm, theta1_rad, theta2_rad)
    if instrument.uniform_bodies:
        bodies = instrument.arms[0].bodies
        start = np.stack([joints[b.joint_from] for b in bodies], axis=-2)
        end = np.stack([joints[b.joint_to if b.shape != "sphere" else b.joint_from] for b in bodies], axis=-2)
        hw = np.broadcast_to(np.array([b.half_width_mm for b in bodies]), start.shape[:-1])
        return start, end, hw
    # per-arm body lists: pad to the longest list with far-away dummy points
    n_b = max(len(a.bodies) for a in instrument.arms)
    shape = np.broadcast_shapes(arm.shape, np.shape(theta1_rad), np.shape(theta2_rad))
    arm_b = np.broadcast_to(arm, shape)
    start = np.full(shape + (n_b, 2), 1e9)
    end = np.full(shape + (n_b, 2), 1e9)
    hw = np.zeros(shape + (n_b,))
    for k, a in enumerate(instrument.arms):
        m = arm_b == k
        for i, b in enumerate(a.bodies):
            start[m, i] = joints[b.joint_from][m]
            end[m, i] = joints[b.joint_to if b.shape != "sphere" else b.joint_from][m]
            hw[m, i] = b.half_width_mm
    return start, end, hw


def clearance_mm(seg_a: tuple[np.ndarray, np.ndarray, np.ndarray],
                 seg_b: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Minimum clearance over all body pairs of two arms (capsule model), vectorised.

    ``seg_*`` are outputs of :func:`body_segments_mm` with matching leading shapes.
    """
    sa, ea, ra = seg_a
    sb, eb, rb = seg_b
    d = segment_distance_mm(sa[..., :, None, :], ea[..., :, None, :], sb[..., None, :, :], eb[..., None, :, :])
    d = d - ra[..., :, None] - rb[..., None, :]
    return d.min(axis=(-2, -1))


def arm_pair_clearance_mm(instrument: Instrument, arm_a, q_a: np.ndarray, arm_b, q_b: np.ndarray) -> np.ndarray:
    """Clearance (mm) between arm(s) ``arm_a`` at ``q_a`` (..., 2) and ``arm_b`` at ``q_b``."""
    q_a = np.asarray(q_a, float)
    q_b = np.asarray(q_b, float)
    sa = body_segments_mm(instrument, arm_a, q_a[..., 0], q_a[..., 1])
    sb = body_segments_mm(instrument, arm_b, q_b[..., 0], q_b[..., 1])
    return clearance_mm(sa, sb)


def configuration_clearances_mm(instrument: Instrument, q: np.ndarray, arms: np.ndarray | None = None) -> np.ndarray:
    """Symmetric (n, n) matrix of clearances between the arms of one configuration.

    ``q`` is (n, 2), one row per arm in ``arms`` (default: all arms in order); the diagonal
    is +inf.
    """
    q = np.asarray(q, float)
    arms = np.arange(len(q)) if arms is None else np.asarray(arms, int)
    s, e, r = body_segments_mm(instrument, arms, q[:, 0], q[:, 1])
    d = segment_distance_mm(s[:, None, :, None, :], e[:, None, :, None, :], s[None, :, None, :, :], e[None, :, None, :, :])
    d = d - r[:, None, :, None] - r[None, :, None, :]
    c = d.min(axis=(-2, -1))
    np.fill_diagonal(c, np.inf)
    return c


def colliding_arm_pairs(instrument: Instrument, q: np.ndarray, buffer_mm: float | None = None,
                        arms: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Arm pairs of a configuration whose clearance is below the collision buffer."""
    buffer_mm = instrument.collision_buffer_mm if buffer_mm is None else buffer_mm
    arms = np.arange(len(q)) if arms is None else np.asarray(arms, int)
    c = configuration_clearances_mm(instrument, q, arms)
    i, j = np.nonzero(np.triu(c < buffer_mm, 1))
    return [(int(arms[a]), int(arms[b])) for a, b in zip(i, j, strict=True)]


# ------------------------------------------------------------------------- FCL engine


def _rotation_z_to(direction: np.ndarray) -> np.ndarray:
    """Rotation matrix taking the z-axis onto the in-plane unit vector ``direction``."""
    dx, dy = direction
    # z -> (dx, dy, 0): rotate 90 deg about k = z x d = (-dy, dx, 0)
    k = np.array([-dy, dx, 0.0])
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + K + K @ K  # Rodrigues with sin = 1, 1 - cos = 1


def _fcl_body(body: Body, p0: np.ndarray, p1: np.ndarray) -> fcl.CollisionObject:
    mid = np.array([(p0[0] + p1[0]) / 2, (p0[1] + p1[1]) / 2, 0.0])
    vec = np.asarray(p1, float) - np.asarray(p0, float)
    length = float(np.hypot(*vec))
    direction = vec / length if length > _EPS else np.array([1.0, 0.0])
    if body.shape == "sphere":
        return fcl.CollisionObject(fcl.Sphere(body.radius_mm), fcl.Transform(np.array([p0[0], p0[1], 0.0])))
    if body.shape == "capsule":
        R = _rotation_z_to(direction)
        return fcl.CollisionObject(fcl.Capsule(body.radius_mm, length), fcl.Transform(R, mid))
    # box: length along the segment (x after rotation about z), width across, height in z
    ang = np.arctan2(direction[1], direction[0])
    R = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1.0]])
    return fcl.CollisionObject(fcl.Box(max(length, _EPS), body.width_mm, body.height_mm), fcl.Transform(R, mid))


def fcl_arm_objects(instrument: Instrument, arm: int, theta1_rad: float, theta2_rad: float) -> list[fcl.CollisionObject]:
    """FCL collision objects of every body of one arm at one configuration."""
    joints = joint_positions_fov(instrument, arm, theta1_rad, theta2_rad)
    return [_fcl_body(b, joints[b.joint_from], joints[b.joint_to]) for b in instrument.arms[arm].bodies]


def fcl_clearance_mm(instrument: Instrument, arm_a: int, q_a, arm_b: int, q_b) -> float:
    """Exact clearance between two arms with FCL (0 when bodies overlap)."""
    oa = fcl_arm_objects(instrument, arm_a, float(q_a[0]), float(q_a[1]))
    ob = fcl_arm_objects(instrument, arm_b, float(q_b[0]), float(q_b[1]))
    best = np.inf
    for x in oa:
        for y in ob:
            res = fcl.DistanceResult()
            d = fcl.distance(x, y, fcl.DistanceRequest(), res)
            best = min(best, max(d, 0.0))
    return float(best)


def fcl_configuration_collisions(instrument: Instrument, q: np.ndarray, buffer_mm: float | None = None,
                                 arms: np.ndarray | None = None) -> list[tuple[int, int]]:
    """Arm pairs of a configuration closer than the buffer, by FCL (the oracle path)."""
    buffer_mm = instrument.collision_buffer_mm if buffer_mm is None else buffer_mm
    arms = list(range(len(q))) if arms is None else [int(a) for a in arms]
    out = []
    for (i, a), (j, b) in combinations(enumerate(arms), 2):
        if fcl_clearance_mm(instrument, a, q[i], b, q[j]) < buffer_mm:
            out.append((a, b))
    return out
