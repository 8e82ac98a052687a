"""Small, fast geometry primitives for the motion planner (kaiju-style: no orchestration here).

* :class:`ArmGeom` — the capsule bodies of one arm from (theta1, theta2) arrays, with the
  per-arm constants (base, axes, links, body list) resolved once. It reproduces
  :func:`models.collision.body_segments_mm` (tested) without the per-call dictionary and
  ``Links.of`` overhead, which dominates when the state-time search asks for a few dozen
  configurations at a time.
* :func:`edges_in_zoa` — the ZoA test of straight joint-space edges (thesis 6.3.4.1, the
  ``IsInZoA`` sensing function of 6.3.2), vectorised over many edges with Lipschitz
  certification and adaptive bisection. Same answer as
  :func:`models.kinematics.segment_in_zoa` (an excursion deeper than ``tol_mm`` is always
  found; tested), at a fraction of the samples.
* :func:`body_speed_bound_mm_s` — an upper bound on how fast any body point of an arm can
  move, used to skip provably clear intervals.
* :func:`timed_collisions` — the planner's own collision re-check of timed way-points of
  all arms (the strategies' repair and feedback oracle; the driver's verifier is separate).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from models import clock
from models.instrument import Instrument
from models.kinematics import THETA1_TOL_RAD
from planner.clearance import clearance_rows

_JOINT_INDEX = {"J1": 0, "J2": 1, "J3": 2, "J4": 3, "tip": 4}


@dataclass(frozen=True)
class ArmGeom:
    """Constants of one arm for fast forward kinematics of its capsule bodies (FOV frame)."""

    arm: int
    base: np.ndarray  # (2,)
    ex: np.ndarray  # (2,)
    ey: np.ndarray  # (2,)
    d12: float
    d13: float
    d24: float
    d3tip: float
    stop_min: float
    stop_max: float
    theta1_min: float
    theta1_max: float
    body_from: np.ndarray  # (nb,) joint indices into (J1, J2, J3, J4, tip)
    body_to: np.ndarray  # (nb,)
    radius: np.ndarray  # (nb,) half widths (capsule radii)
    v1_max: float
    v2_max: float

    @staticmethod
    def of(instrument: Instrument, arm: int) -> ArmGeom:
        a = instrument.arms[arm]
        o = a.orientation_rad
        ex = np.array([np.cos(o), np.sin(o)])
        bf = [_JOINT_INDEX[b.joint_from] for b in a.bodies]
        bt = [_JOINT_INDEX[b.joint_to if b.shape != "sphere" else b.joint_from] for b in a.bodies]
        return ArmGeom(
            arm=arm, base=np.array([a.base_x_mm, a.base_y_mm]), ex=ex, ey=np.array([-ex[1], ex[0]]),
            d12=a.d12_mm, d13=a.d13_mm, d24=a.d24_mm, d3tip=a.d3tip_mm,
            stop_min=a.stop_min_mm, stop_max=a.stop_max_mm,
            theta1_min=a.theta1_min_rad, theta1_max=a.theta1_max_rad,
            body_from=np.array(bf), body_to=np.array(bt),
            radius=np.array([b.half_width_mm for b in a.bodies], dtype=float),
            v1_max=a.joint1_speed_rad_s, v2_max=a.joint2_speed_rad_s,
        )

    def joints(self, theta1: np.ndarray, theta2: np.ndarray) -> np.ndarray:
        """(..., 5, 2) positions of J1, J2, J3, J4, tip in the FOV frame (thesis eqs. 3.4-3.16)."""
        t1 = np.asarray(theta1, float)
        t2 = np.asarray(theta2, float)
        j3a = self.d13 * np.cos(t1)
        j3b = self.d13 * np.sin(t1)
        j4a = self.d12 - self.d24 * np.cos(t2)
        j4b = self.d24 * np.sin(t2)
        wa, wb = j4a - j3a, j4b - j3b
        k = self.d3tip / np.hypot(wa, wb)
        ta, tb = j3a + k * wa, j3b + k * wb
        zero = np.zeros_like(j3a)
        a = np.stack([zero, zero + self.d12, j3a, j4a, ta], -1)
        b = np.stack([zero, zero, j3b, j4b, tb], -1)
        out = np.empty(a.shape + (2,))
        out[..., 0] = self.base[0] + a * self.ex[0] + b * self.ey[0]
        out[..., 1] = self.base[1] + a * self.ex[1] + b * self.ey[1]
        return out

    def segments(self, theta1: np.ndarray, theta2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Capsule axes (start (..., nb, 2), end (..., nb, 2)); radii are ``self.radius``.
        One-dimensional angle arrays go through a compiled kernel (:func:`_segments_1d`, the
        same formulas as :meth:`joints`): the planner's searches ask for a few poses at a
        time, where numpy's per-call overhead dominates."""
        t1, t2 = np.ascontiguousarray(theta1, float), np.ascontiguousarray(theta2, float)
        clock.work("segments", t1.size)
        if t1.ndim == 1 and t1.shape == t2.shape:
            return _segments_1d(t1, t2, self.base, self.ex, self.ey, self.d12, self.d13, self.d24, self.d3tip,
                                self.body_from, self.body_to)
        j = self.joints(theta1, theta2)
        return np.take(j, self.body_from, axis=-2), np.take(j, self.body_to, axis=-2)  # C-contiguous

    def d34(self, theta1: np.ndarray, theta2: np.ndarray) -> np.ndarray:
        dx = self.d12 - self.d24 * np.cos(theta2) - self.d13 * np.cos(theta1)
        dy = self.d24 * np.sin(theta2) - self.d13 * np.sin(theta1)
        return np.hypot(dx, dy)

    def zoa_margin(self, theta1: np.ndarray, theta2: np.ndarray) -> np.ndarray:
        """Signed distance (mm of d34) to the J4 stops; <= 0 means in the ZoA (thesis eq. 3.2)."""
        d = self.d34(theta1, theta2)
        return np.minimum(d - self.stop_min, self.stop_max - d)

    def theta1_ok(self, theta1: np.ndarray) -> np.ndarray:
        t1 = np.asarray(theta1, float)
        return (t1 >= self.theta1_min - THETA1_TOL_RAD) & (t1 <= self.theta1_max + THETA1_TOL_RAD)

    def in_zoa(self, theta1: np.ndarray, theta2: np.ndarray) -> np.ndarray:
        m = self.zoa_margin(theta1, theta2)
        return ~self.theta1_ok(theta1) | ~(m > 0) | ~np.isfinite(m)

    def move_time_s(self, q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
        """Estimated travel time of a straight edge, both joints at full speed (thesis eq. 6.23)."""
        dq = np.abs(np.asarray(q_to, float) - np.asarray(q_from, float))
        return np.maximum(dq[..., 0] / self.v1_max, dq[..., 1] / self.v2_max)


@numba.njit(cache=True)
def _segments_1d(t1, t2, base, ex, ey, d12, d13, d24, d3tip, body_from, body_to):
    """:meth:`ArmGeom.segments` of (n,) angle arrays: (n, nb, 2) capsule axis starts and ends
    (thesis eqs. 3.4-3.16, as :meth:`ArmGeom.joints`)."""
    n, nb = t1.shape[0], body_from.shape[0]
    s = np.empty((n, nb, 2))
    e = np.empty((n, nb, 2))
    pa = np.zeros(5)
    pb = np.zeros(5)
    pa[1] = d12
    for i in range(n):
        j3a, j3b = d13 * math.cos(t1[i]), d13 * math.sin(t1[i])
        j4a, j4b = d12 - d24 * math.cos(t2[i]), d24 * math.sin(t2[i])
        wa, wb = j4a - j3a, j4b - j3b
        k = d3tip / math.hypot(wa, wb)
        pa[2], pa[3], pa[4] = j3a, j4a, j3a + k * wa
        pb[2], pb[3], pb[4] = j3b, j4b, j3b + k * wb
        for b in range(nb):
            f, t = body_from[b], body_to[b]
            s[i, b, 0] = base[0] + pa[f] * ex[0] + pb[f] * ey[0]
            s[i, b, 1] = base[1] + pa[f] * ex[1] + pb[f] * ey[1]
            e[i, b, 0] = base[0] + pa[t] * ex[0] + pb[t] * ey[0]
            e[i, b, 1] = base[1] + pa[t] * ex[1] + pb[t] * ey[1]
    return s, e


def edges_in_zoa(geom: ArmGeom, q_from: np.ndarray, q_to: np.ndarray, tol_mm: float = 0.01) -> np.ndarray:
    """True where the straight joint-space edge q_from -> q_to touches the ZoA (thesis 6.3.4.1).

    ``q_*`` are (n, 2) with theta2 unwrapped (the sign of the difference is the direction
    of rotation). theta1 is linear along an edge, so its limits are checked at the ends.
    d34 along an edge is Lipschitz in the edge parameter s with constant
    L = d13 |dtheta1| + d24 |dtheta2|; an interval whose end margins m_a, m_b satisfy
    (m_a + m_b)/2 - L (b - a)/2 > 0 is certified clear, the rest is bisected until a sample
    lands in the ZoA or L (b - a)/2 < tol_mm (then any excursion is shallower than tol_mm,
    the guarantee of :func:`models.kinematics.segment_in_zoa`).
    """
    q0 = np.atleast_2d(np.asarray(q_from, float))
    q1 = np.atleast_2d(np.asarray(q_to, float))
    q0, q1 = np.broadcast_arrays(q0, q1)
    n = len(q0)
    clock.work("zoa_edges", n)
    dq = q1 - q0
    lip = geom.d13 * np.abs(dq[:, 0]) + geom.d24 * np.abs(dq[:, 1])
    hit = ~geom.theta1_ok(q0[:, 0]) | ~geom.theta1_ok(q1[:, 0])
    n0 = 32
    s = np.linspace(0.0, 1.0, n0 + 1)
    m = geom.zoa_margin(q0[:, None, 0] + dq[:, None, 0] * s, q0[:, None, 1] + dq[:, None, 1] * s)
    hit |= ~(m > 0).all(axis=1)
    # uncertain intervals: (edge, a, b, m_a, m_b)
    h = 1.0 / n0
    need = (0.5 * (m[:, :-1] + m[:, 1:]) - 0.5 * lip[:, None] * h <= 0) & (0.5 * lip[:, None] * h >= tol_mm)
    need &= ~hit[:, None]
    e, i = np.nonzero(need)
    a, b, ma, mb = s[i], s[i + 1], m[e, i], m[e, i + 1]
    for _ in range(40):
        if len(e) == 0:
            break
        c = 0.5 * (a + b)
        mc = geom.zoa_margin(q0[e, 0] + dq[e, 0] * c, q0[e, 1] + dq[e, 1] * c)
        bad = ~(mc > 0)
        hit[e[bad]] = True
        keep = ~hit[e]
        half = 0.5 * (b - a)
        e2 = np.concatenate([e, e])
        a2 = np.concatenate([a, c])
        b2 = np.concatenate([c, b])
        ma2 = np.concatenate([ma, mc])
        mb2 = np.concatenate([mc, mb])
        k2 = np.concatenate([keep, keep])
        w = np.concatenate([0.5 * half, 0.5 * half])
        unsure = (0.5 * (ma2 + mb2) - lip[e2] * w <= 0) & (lip[e2] * w >= tol_mm) & k2
        e, a, b, ma, mb = e2[unsure], a2[unsure], b2[unsure], ma2[unsure], mb2[unsure]
    return hit.reshape(n)


def body_speed_bound_mm_s(geom: ArmGeom, w1_rad_s: float, w2_rad_s: float) -> float:
    """Upper bound of the speed of any body point (mm/s) at joint rates w1, w2.

    J3 moves at d13 w1, J4 at d24 w2; the L3 direction turns at most
    (|dJ3| + |dJ4|)/|J4 - J3| <= (d13 w1 + d24 w2)/stop_min, so a point at distance
    <= max(d3tip, stop_max) from J3 moves at most d13 w1 + r (d13 w1 + d24 w2)/stop_min.
    Segment-segment distance is 1-Lipschitz in the end points, so clearance between two
    arms changes no faster than the sum of their bounds.
    """
    r = max(geom.d3tip, geom.stop_max)
    return geom.d13 * w1_rad_s + geom.d24 * w2_rad_s + r * (geom.d13 * w1_rad_s + geom.d24 * w2_rad_s) / geom.stop_min


def clearance_between(sa: np.ndarray, ea: np.ndarray, ra: np.ndarray,
                      sb: np.ndarray, eb: np.ndarray, rb: np.ndarray) -> np.ndarray:
    """Min clearance over body pairs: ``s*``/``e*`` (..., nb, 2) broadcast against each other
    (the compiled kernel :func:`planner.clearance.clearance_rows`)."""
    return clearance_rows(sa, ea, ra, sb, eb, rb)


def timed_collisions(geoms: Sequence[ArmGeom], timed: Sequence[tuple[np.ndarray, np.ndarray]], buffer_mm: float,
                     dt_check_s: float = 0.01, stride: int = 10) -> list[tuple[int, int]]:
    """Arm pairs whose timed way-points ``timed[k] = (t, q)`` (linear joint motion between
    them, at rest after the last) come closer than ``buffer_mm``.

    The planner's own re-check of a candidate (the driver's verifier stays independent):
    both arms are sampled on one grid of ``dt_check_s`` plus every way-point time; the exact
    clearance is computed on every ``stride``-th sample, and the samples in between only
    where the clearance, changing no faster than the two arms' body-point speed bounds
    (:func:`body_speed_bound_mm_s` at full joint speed), could drop below the buffer.
    """
    n = len(timed)
    T = max(float(t[-1]) for t, _ in timed)
    grid = np.arange(0.0, T + 0.5 * dt_check_s, dt_check_s)
    ts = np.unique(np.round(np.concatenate([grid, *[np.asarray(t, float) for t, _ in timed], [T]]), 9))
    coarse = np.unique(np.concatenate([np.arange(0, len(ts), stride), [len(ts) - 1]]))
    tc = ts[coarse]
    half = 0.5 * float(np.max(np.diff(tc), initial=0.0))
    speed = [body_speed_bound_mm_s(g, g.v1_max, g.v2_max) for g in geoms]
    seg, box = [], []
    for k in range(n):
        s, e = _segments_at(geoms[k], timed[k], tc)
        r = geoms[k].radius[None, :, None]
        pad = speed[k] * half  # the arm between two coarse samples
        seg.append((s, e))
        box.append(np.concatenate([(np.minimum(s, e) - r).min(axis=(0, 1)) - pad,
                                   (np.maximum(s, e) + r).max(axis=(0, 1)) + pad]))
    out = []
    for i in range(n):
        for j in range(i + 1, n):
            bi, bj = box[i], box[j]
            if (bi[0] - buffer_mm > bj[2] or bj[0] - buffer_mm > bi[2]
                    or bi[1] - buffer_mm > bj[3] or bj[1] - buffer_mm > bi[3]):
                continue
            gi, gj = geoms[i], geoms[j]
            c = clearance_between(seg[i][0], seg[i][1], gi.radius, seg[j][0], seg[j][1], gj.radius)
            if (c < buffer_mm).any():
                out.append((i, j))
                continue
            unsure = np.flatnonzero(0.5 * (c[:-1] + c[1:]) - 0.5 * (speed[i] + speed[j]) * np.diff(tc) < buffer_mm)
            if len(unsure) == 0:
                continue
            idx = np.unique(np.concatenate([np.arange(coarse[u], coarse[u + 1] + 1) for u in unsure]))
            sa, ea = _segments_at(gi, timed[i], ts[idx])
            sb, eb = _segments_at(gj, timed[j], ts[idx])
            if (clearance_between(sa, ea, gi.radius, sb, eb, gj.radius) < buffer_mm).any():
                out.append((i, j))
    return out


def _segments_at(geom: ArmGeom, tq: tuple[np.ndarray, np.ndarray], ts: np.ndarray):
    t, q = tq
    return geom.segments(np.interp(ts, t, q[:, 0]), np.interp(ts, t, q[:, 1]))


def compile_kernels() -> None:
    """Compile (or load from the on-disk cache) this module's kernel."""
    z, i = np.zeros(1), np.zeros(1, np.int64)
    _segments_1d(z, z, np.zeros(2), np.ones(2), np.ones(2), 1.0, 1.0, 1.0, 1.0, i, i)
