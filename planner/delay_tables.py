"""Pairwise relative-delay tables of the departure-delay CSP (:mod:`planner.delays`).

For every arm pair and option pair, the set of collision-free *relative* delays
tau_j - tau_i is computed vectorised (:func:`pair_table`): both motions sampled every
dt_col, including the rests before departure and after arrival, clearance >= buffer at
every sample. Each sequence of samples is walked by conservative advancement
(:mod:`planner.clearance`): a sample's clearance, or its bounding-box lower bound, certifies
as many following samples as the clearance cannot lose in that time (two arms' clearance
changes no faster than the sum of their body-point speed bounds), and the walk jumps over
them; a sample below the buffer is found exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from models.budget import Budget
from planner.clearance import diagonals_bad, rest_clear
from planner.geometry import ArmGeom, body_speed_bound_mm_s


@dataclass
class Option:
    """One motion of one arm, relative to its departure: way-points at times ``t_rel``."""

    arm: int
    waypoints: np.ndarray  # (n, 2), theta2 unwrapped, waypoints[0] == start
    t_rel: np.ndarray  # (n,), t_rel[0] == 0
    stops: int
    kind: str  # straight | detour | stay | aside
    # filled by prepare()
    samples: np.ndarray | None = None  # (N + 1, 2) every dt_col from departure, last = end
    seg: tuple[np.ndarray, np.ndarray] | None = None
    box: np.ndarray | None = None  # (N + 1, 4)

    @property
    def duration_s(self) -> float:
        return float(self.t_rel[-1])

    @property
    def n(self) -> int:
        return len(self.samples) - 1


@dataclass
class DelayStats:
    pair_samples: int = 0  # arm-pair x dt_col-sample clearances computed (thesis table 6.2 "checks")
    nodes: int = 0  # CSP nodes (assignments tried)
    tables: int = 0
    repairs: int = 0  # re-check rejections repaired by forbidding the offending relative delay
    log: list = field(default_factory=list)



def prepare(option: Option, geom: ArmGeom, dt_col_s: float) -> None:
    """Sample an option every dt_col from its departure until it rests at its end."""
    T = option.duration_s
    n = int(math.ceil(T / dt_col_s - 1e-9)) if T > 0 else 0
    t = np.minimum(np.arange(n + 1) * dt_col_s, T)
    q = np.column_stack([np.interp(t, option.t_rel, option.waypoints[:, 0]),
                         np.interp(t, option.t_rel, option.waypoints[:, 1])])
    option.samples = q
    s, e = geom.segments(q[:, 0], q[:, 1])
    option.seg = (np.ascontiguousarray(s, float), np.ascontiguousarray(e, float))  # the kernels' layout
    r = geom.radius[None, :, None]
    lo = np.minimum(s, e) - r
    hi = np.maximum(s, e) + r
    option.box = np.ascontiguousarray(np.concatenate([lo.min(axis=1), hi.max(axis=1)], axis=1))


def _boxes_overlap(ba: np.ndarray, bb: np.ndarray, pad: float) -> np.ndarray:
    return ((ba[..., 0] - pad <= bb[..., 2]) & (bb[..., 0] - pad <= ba[..., 2])
            & (ba[..., 1] - pad <= bb[..., 3]) & (bb[..., 1] - pad <= ba[..., 3]))


def _rest_ok(om: Option, gm: ArmGeom, orest: Option, grest: ArmGeom, j: int, lip_mm: float, thr: float,
             stats: DelayStats) -> np.ndarray:
    """ok[i]: option ``om`` at its sample i keeps clearance >= thr to option ``orest`` resting at
    its sample j (:func:`planner.clearance.rest_clear`)."""
    ok, n_exact = rest_clear(om.seg[0], om.seg[1], gm.radius, om.box, orest.seg[0], orest.seg[1], grest.radius,
                             orest.box, j, lip_mm, thr)
    stats.pair_samples += n_exact
    return ok


def pair_table(oa: Option, ga: ArmGeom, ob: Option, gb: ArmGeom, M: int, K: int, thr: float,
               lip: tuple[float, float], stats: DelayStats) -> np.ndarray:
    """ok[k + K] for relative delays k in [-K, K] (b departs k dt after a), both arms resting
    at their starts before departure and at their ends after arrival."""
    Na, Nb = oa.n, ob.n
    la, lb = lip
    # a moving vs b at rest at its start / end, and b moving vs a at rest
    a_bs = _rest_ok(oa, ga, ob, gb, 0, la, thr, stats)
    a_be = _rest_ok(oa, ga, ob, gb, Nb, la, thr, stats)
    b_as = _rest_ok(ob, gb, oa, ga, 0, lb, thr, stats)
    b_ae = _rest_ok(ob, gb, oa, ga, Na, lb, thr, stats)
    cs = lambda ok: np.concatenate([[0], np.cumsum(~ok)])  # noqa: E731 - prefix counts of bad samples
    c_a_bs, c_a_be, c_b_as, c_b_ae = cs(a_bs), cs(a_be), cs(b_as), cs(b_ae)

    def bad(c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:  # any bad sample in [lo, hi], per k
        lo, hi = np.maximum(lo, 0), np.minimum(hi, len(c) - 2)
        some = hi >= lo
        return some & (c[np.where(some, hi + 1, 0)] - c[np.where(some, lo, 0)] > 0)

    ks = np.arange(-K, K + 1)
    ok = np.ones(2 * K + 1, bool)
    # both moving: the diagonals a - b = M k
    kmin, kmax = max(-K, -(Nb // M) - 1), min(K, Na // M + 1)
    if kmax >= kmin:
        badk, n_exact = diagonals_bad(oa.seg[0], oa.seg[1], ga.radius, oa.box, ob.seg[0], ob.seg[1], gb.radius,
                                      ob.box, M, kmin, kmax, la + lb, thr)
        stats.pair_samples += n_exact
        ok[kmin + K: kmax + K + 1] &= ~badk
    # a moving while b rests at its start (before b departs) or at its end (after b arrived), and
    # b moving while a rests
    Mk = M * ks
    zero, na, nb = np.zeros_like(ks), np.full_like(ks, Na), np.full_like(ks, Nb)
    ok &= ~(bad(c_a_bs, zero, Mk - 1) | bad(c_a_be, Nb + Mk + 1, na)
            | bad(c_b_as, zero, -Mk - 1) | bad(c_b_ae, Na - Mk + 1, nb))
    stats.tables += 1
    return ok


@dataclass
class DelayProblem:
    """Options per arm and pairwise tables tab[(i, j)][p_i, p_j, k + K] (i != j, both orders)."""

    options: list[list[Option]]
    K: int  # horizon in dt steps
    dt_s: float
    horizon_s: float
    tables: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)
    neighbours: list[list[int]] = field(default_factory=list)


def build_problem(geoms: list[ArmGeom], options: list[list[Option]], dt_s: float, dt_col_s: float,
                  horizon_s: float, buffer_mm: float, stats: DelayStats,
                  old: DelayProblem | None = None, margin_mm: float = 0.0,
                  budget: Budget | None = None) -> DelayProblem | None:
    """Pairwise relative-delay tables of every arm pair whose options can come close; None
    once ``budget`` (None: no limit) has passed its deadline.

    With ``old`` (same arms, options extended by appending), tables of option pairs already
    computed are reused.
    """
    n = len(options)
    M = max(1, int(round(dt_s / dt_col_s)))
    K = int(math.floor(horizon_s / dt_s + 1e-9))
    for k in range(n):
        for o in options[k]:
            if o.samples is None:
                prepare(o, geoms[k], dt_col_s)
    vmax = [body_speed_bound_mm_s(g, g.v1_max, g.v2_max) for g in geoms]
    prob = DelayProblem(options, K, dt_s, horizon_s, {}, [[] for _ in range(n)])
    arm_box = []
    for k in range(n):
        b = np.concatenate([o.box for o in options[k]])
        arm_box.append(np.array([b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()]))
    for i in range(n):
        if budget is not None and budget.past_deadline():
            return None  # out of time: the caller falls back
        for j in range(i + 1, n):
            if budget is not None and budget.past_deadline():
                return None
            if not _boxes_overlap(arm_box[i], arm_box[j], buffer_mm + 5.0):
                continue
            thr = buffer_mm + margin_mm
            lip = (vmax[i] * dt_col_s, vmax[j] * dt_col_s)
            Pi, Pj = len(options[i]), len(options[j])
            tab = np.ones((Pi, Pj, 2 * K + 1), bool)
            prev = old.tables.get((i, j)) if old is not None else None
            for a in range(Pi):
                # detour options multiply the option pairs of one arm pair: honour the
                # deadline inside a pair too, or one crowded pair overruns the whole budget
                if a and budget is not None and budget.past_deadline():
                    return None
                for b in range(Pj):
                    if prev is not None and a < prev.shape[0] and b < prev.shape[1]:
                        tab[a, b] = prev[a, b]
                    else:
                        tab[a, b] = pair_table(options[i][a], geoms[i], options[j][b], geoms[j], M, K, thr, lip, stats)
            if tab.all():
                continue
            prob.tables[(i, j)] = tab
            prob.tables[(j, i)] = tab.transpose(1, 0, 2)[:, :, ::-1]
            prob.neighbours[i].append(j)
            prob.neighbours[j].append(i)
    return prob
