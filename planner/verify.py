"""Independent verifier of multi-arm trajectories (the service never returns an unverified plan).

It shares nothing with the planner's search: it re-simulates every trajectory from its
way-points alone (linear joint motion between way-points, the contract of
:class:`models.types.ArmTrajectory`) on a ``dt_check_s`` grid (10 ms default) that also
contains every way-point time, and checks

* structure (one finite, time-ordered trajectory per arm),
* start and goal reached (theta2 modulo 2 pi, since J2 turns freely),
* joint speed <= v_max per joint and per segment,
* start-stop cycles <= ``max_start_stop`` (thesis 3.5.1.2, 6.3.4.4),
* joint limits and zone of avoidance at every sample (:func:`models.kinematics.in_zoa`),
* every arm pair's clearance >= buffer at every sample (capsule fast path of
  :mod:`models.collision`, which is tested against FCL).

The pair clearance is computed at every 10 ms sample *unless provably unnecessary*: the
clearance of two arms changes no faster than the sum of bounds on their body-point speeds
(derived below from the joint speeds actually used), so on a coarse sub-grid an interval
whose end clearances c_a, c_b satisfy (c_a + c_b)/2 - L (t_b - t_a)/2 >= buffer cannot hold
any sample below the buffer, and only the other intervals are sampled at 10 ms. The
answer equals brute-force 10 ms sampling (``exhaustive=True`` forces it; tested).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from models import clock
from models.collision import body_segments_mm, clearance_mm
from models.instrument import Instrument
from models.kinematics import THETA1_TOL_RAD, Links, d34_mm
from models.types import ArmTrajectory, MotionPlan

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Violation:
    kind: str  # structure | start | goal | speed | stops | joint_limit | zoa | collision | commands
    arms: tuple[int, ...]
    t_s: float
    detail: str


@dataclass(frozen=True)
class VerificationReport:
    ok: bool
    violations: tuple[Violation, ...]
    min_clearance_mm: float
    n_samples: int  # time samples of the re-simulation
    pair_samples_checked: int  # arm-pair x sample clearances actually computed

    @property
    def arms(self) -> tuple[int, ...]:
        """Arms involved in any violation."""
        return tuple(sorted({a for v in self.violations for a in v.arms}))


def _angle_diff(a: float, b: float) -> float:
    d = (a - b + np.pi) % TWO_PI - np.pi
    return abs(d)


def _stop_count(t: np.ndarray, q: np.ndarray, tol: float = 1e-9) -> int:
    """Moving segments with distinct velocity, minus one (rests and reversals both count)."""
    dq = np.diff(q, axis=0)
    v = dq / np.diff(t)[:, None]
    n, prev = 0, None
    for vi, d in zip(v, dq, strict=True):
        if np.all(np.abs(d) <= 1e-12):
            prev = None
            continue
        if prev is None or np.any(np.abs(vi - prev) > tol * max(1.0, float(np.abs(vi).max()))):
            n += 1
        prev = vi
    return max(n - 1, 0)


def _point_speed_bound(instrument: Instrument, arm: int, w1: np.ndarray, w2: np.ndarray) -> np.ndarray:
    """Bound on the speed of any body point (mm/s) at joint rates w1, w2.

    J3 moves at d13 w1 and J4 at d24 w2; the line J3 -> tip turns at most
    (|J3'| + |J4'|) / |J4 - J3| with |J4 - J3| > stop_min, and its points lie within
    max(d3tip, stop_max) of J3; points of L1 and L2 move slower than J3 and J4.
    """
    a = instrument.arms[arm]
    r = max(a.d3tip_mm, a.stop_max_mm)
    v3 = a.d13_mm * w1
    v4 = a.d24_mm * w2
    return v3 + v4 + r * (v3 + v4) / a.stop_min_mm


def _by_arm(trajectories: Sequence[ArmTrajectory], n: int) -> tuple[dict[int, ArmTrajectory], list[Violation]]:
    """One trajectory per arm, or structure violations."""
    vio: list[Violation] = []
    by_arm = {}
    for tr in trajectories:
        if tr.arm in by_arm or not 0 <= tr.arm < n:
            vio.append(Violation("structure", (int(tr.arm),), 0.0, "duplicate or unknown arm"))
            continue
        by_arm[tr.arm] = tr
    for k in range(n):
        if k not in by_arm:
            vio.append(Violation("structure", (k,), 0.0, "no trajectory"))
    return by_arm, vio


def _check_arm(instrument: Instrument, tr: ArmTrajectory, start_q: np.ndarray, goal_q: np.ndarray,
               max_start_stop: int | None, angle_tol_rad: float, vio: list[Violation]) -> float:
    """Structure, ends, speeds, stops and commands of one arm's trajectory (violations
    appended to ``vio``); returns its end time (0 when malformed)."""
    k = tr.arm
    t = np.asarray(tr.t_s, float)
    q = np.column_stack([np.asarray(tr.theta1_rad, float), np.asarray(tr.theta2_rad, float)])
    if t.ndim != 1 or len(t) == 0 or q.shape != (len(t), 2) or not np.all(np.isfinite(t)) or not np.all(np.isfinite(q)):
        vio.append(Violation("structure", (k,), 0.0, "way-points must be finite arrays of equal length"))
        return 0.0
    if np.any(np.diff(t) <= 0) or t[0] < 0:
        vio.append(Violation("structure", (k,), float(t[0]), "way-point times must start >= 0 and increase"))
        return 0.0
    if abs(q[0, 0] - start_q[0]) > angle_tol_rad or _angle_diff(q[0, 1], start_q[1]) > angle_tol_rad:
        vio.append(Violation("start", (k,), float(t[0]), f"starts at {q[0].tolist()}, expected {start_q.tolist()}"))
    if abs(q[-1, 0] - goal_q[0]) > angle_tol_rad or _angle_diff(q[-1, 1], goal_q[1]) > angle_tol_rad:
        vio.append(Violation("goal", (k,), float(t[-1]), f"ends at {q[-1].tolist()}, expected {goal_q.tolist()}"))
    if len(t) > 1:
        a = instrument.arms[k]
        sp = np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]
        vmax = np.array([a.joint1_speed_rad_s, a.joint2_speed_rad_s])
        bad = np.nonzero(sp > vmax * (1 + 1e-9) + 1e-12)
        for i, j in zip(*bad, strict=True):
            vio.append(Violation("speed", (k,), float(t[i]),
                                 f"joint {j + 1} at {sp[i, j]:.6g} rad/s > {vmax[j]:.6g}"))
            break
        if max_start_stop is not None:
            ns = _stop_count(t, q)
            if ns > max_start_stop:
                vio.append(Violation("stops", (k,), 0.0, f"{ns} start-stop cycles > {max_start_stop}"))
    for c in tr.commands:
        th = q[:, c.joint - 1]
        i = np.flatnonzero(np.abs(t - c.t_start_s) < 1e-9)
        if len(i) == 0 or i[0] + 1 >= len(t) or abs(th[i[0]] - c.from_rad) > 1e-9 or abs(th[i[0] + 1] - c.to_rad) > 1e-9:
            vio.append(Violation("commands", (k,), float(c.t_start_s), "command does not match the way-points"))
            break
    return float(t[-1])


def verify_trajectories(
    instrument: Instrument,
    trajectories: Sequence[ArmTrajectory],
    start_q: np.ndarray,
    goal_q: np.ndarray,
    *,
    collision_buffer_mm: float | None = None,
    max_start_stop: int | None = 1,
    dt_check_s: float = 0.01,
    angle_tol_rad: float = 1e-6,
    exhaustive: bool = False,
    coarse_stride: int = 50,
) -> VerificationReport:
    """Re-simulate and check a set of arm trajectories (see module docstring)."""
    buffer_mm = instrument.collision_buffer_mm if collision_buffer_mm is None else collision_buffer_mm
    start_q = np.asarray(start_q, float)
    goal_q = np.asarray(goal_q, float)
    n = instrument.n_arms
    by_arm, vio = _by_arm(trajectories, n)
    if vio:
        return VerificationReport(False, tuple(vio), float("nan"), 0, 0)
    T_end = 0.0
    for k in range(n):
        T_end = max(T_end, _check_arm(instrument, by_arm[k], start_q[k], goal_q[k], max_start_stop,
                                      angle_tol_rad, vio))
    if any(v.kind == "structure" for v in vio):
        return VerificationReport(False, tuple(vio), float("nan"), 0, 0)

    # ---- re-simulation grid: every dt_check plus every way-point time
    grid = np.arange(0.0, T_end + 0.5 * dt_check_s, dt_check_s)
    wp_t = np.concatenate([np.asarray(by_arm[k].t_s, float) for k in range(n)] + [[T_end]])
    t = np.unique(np.round(np.concatenate([grid, wp_t]), 9))
    th1 = np.stack([np.interp(t, by_arm[k].t_s, by_arm[k].theta1_rad) for k in range(n)])  # (n, N)
    th2 = np.stack([np.interp(t, by_arm[k].t_s, by_arm[k].theta2_rad) for k in range(n)])
    N = len(t)
    arms = np.arange(n)

    # ---- joint limits and ZoA (thesis eqs. 3.1-3.2)
    lk = Links.of(instrument, arms[:, None])
    t1min = instrument.arm_array("theta1_min_rad")[:, None]
    t1max = instrument.arm_array("theta1_max_rad")[:, None]
    lim_bad = (th1 < t1min - THETA1_TOL_RAD) | (th1 > t1max + THETA1_TOL_RAD)
    d = d34_mm(th1, th2, lk)
    zoa_bad = ~((d > lk.stop_min_mm) & (d < lk.stop_max_mm)) & ~lim_bad
    for kind, bad in (("joint_limit", lim_bad), ("zoa", zoa_bad)):
        for k in np.flatnonzero(bad.any(1)):
            i = int(np.argmax(bad[k]))
            vio.append(Violation(kind, (int(k),), float(t[i]), f"at theta = ({th1[k, i]:.6f}, {th2[k, i]:.6f})"))

    # ---- pair clearances
    S, E, R = body_segments_mm(instrument, arms[:, None], th1, th2)  # (n, N, nb, 2)
    pi, pj = np.triu_indices(n, 1)
    dt = np.diff(t)
    # per-arm body-point speed bound on each fine interval, from the joint rates actually used
    w1 = np.abs(np.diff(th1, axis=1)) / dt
    w2 = np.abs(np.diff(th2, axis=1)) / dt
    Lf = np.stack([_point_speed_bound(instrument, k, w1[k], w2[k]) for k in range(n)])  # (n, N-1)
    fine_pairs, checked, coarse_min = _fine_pairs(S, E, R, pi, pj, t, Lf, buffer_mm, coarse_stride, exhaustive)
    min_clear = np.inf
    for p, idx in fine_pairs:
        a, b = pi[p], pj[p]
        c = clearance_mm((S[a, idx], E[a, idx], R[a, idx]), (S[b, idx], E[b, idx], R[b, idx]))
        checked += len(idx)
        min_clear = min(min_clear, float(c.min()))
        if (c < buffer_mm).any():
            i = int(np.argmax(c < buffer_mm))
            vio.append(Violation("collision", (int(a), int(b)), float(t[idx[i]]),
                                 f"clearance {c[i]:.3f} mm < buffer {buffer_mm} mm"))
    min_clear = min(min_clear, coarse_min)
    out = _dedupe(vio)
    clock.work("verify", int(checked))
    return VerificationReport(not out, tuple(out), float(min_clear), N, int(checked))


def _fine_pairs(S, E, R, pi: np.ndarray, pj: np.ndarray, t: np.ndarray, Lf: np.ndarray, buffer_mm: float,
                coarse_stride: int, exhaustive: bool) -> tuple[list, int, float]:
    """(pair, sample indices) whose clearance must be computed at every sample: intervals of
    the coarse sub-grid not provably clear (see module docstring). Also the coarse clearances
    computed and their minimum."""
    N = len(t)
    if exhaustive or N < 3:
        return [(p, np.arange(N)) for p in range(len(pi))], 0, np.inf
    coarse = np.unique(np.concatenate([np.arange(0, N, max(1, coarse_stride)), [N - 1]]))
    cc = clearance_mm((S[pi][:, coarse], E[pi][:, coarse], R[pi][:, coarse]),
                      (S[pj][:, coarse], E[pj][:, coarse], R[pj][:, coarse]))  # (P, C)
    Lc = np.maximum.reduceat(Lf, coarse[:-1], axis=1) if len(coarse) > 1 else np.zeros((len(Lf), 0))
    span = t[coarse[1:]] - t[coarse[:-1]]
    lower = 0.5 * (cc[:, :-1] + cc[:, 1:]) - 0.5 * (Lc[pi] + Lc[pj]) * span
    need = lower < buffer_mm
    fine_pairs = []
    for p in np.flatnonzero(need.any(1)):
        iv = np.flatnonzero(need[p])
        idx = np.unique(np.concatenate([np.arange(coarse[i], coarse[i + 1] + 1) for i in iv]))
        fine_pairs.append((p, idx))
    if (cc < buffer_mm).any():
        for p in np.flatnonzero((cc < buffer_mm).any(1)):
            fine_pairs.append((p, coarse))
    return fine_pairs, int(cc.size), float(cc.min())


def _dedupe(vio: list[Violation]) -> list[Violation]:
    """One collision report per pair."""
    seen, out = set(), []
    for v in vio:
        key = (v.kind, v.arms)
        if v.kind == "collision" and key in seen:
            continue
        seen.add(key)
        out.append(v)
    return out


def verify_plan(instrument: Instrument, plan: MotionPlan, start_q: np.ndarray, goal_q: np.ndarray,
                **kwargs) -> VerificationReport:
    """:func:`verify_trajectories` on a :class:`~models.types.MotionPlan`'s trajectories."""
    return verify_trajectories(instrument, plan.trajectories, start_q, goal_q, **kwargs)
