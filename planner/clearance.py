"""Compiled capsule clearance between two arms' bodies, the planner's hot kernel.

The delay tables (:mod:`planner.delay_tables`), the evasion search and the planner's own
re-check ask for the clearance of millions of body-pair samples per leg. The numpy form
(:func:`models.collision.segment_distance_xy` broadcast over body pairs) materialises a dozen
temporaries per body pair; this kernel loops over samples and body pairs in compiled code
(numba), with the same closest-point algorithm (Ericson, *Real-Time Collision Detection*,
5.1.9) and the same treatment of degenerate and (nearly) parallel segments, so the two agree
to rounding (tested against the numpy form, which stays the reference and the verifier's).

Compiled functions are cached on disk (``cache=True``); the first call in a fresh
environment compiles them once (about a second).
"""

from __future__ import annotations

import numba
import numpy as np

from models import clock

_EPS = 1e-12  # as models.collision


@numba.njit(cache=True, inline="always")
def _point_segment(px, py, ax, ay, bx, by):
    dx = bx - ax
    dy = by - ay
    ll = dx * dx + dy * dy
    t = ((px - ax) * dx + (py - ay) * dy) / ll if ll > _EPS else 0.0
    t = min(max(t, 0.0), 1.0)
    return np.hypot(px - ax - t * dx, py - ay - t * dy)


@numba.njit(cache=True, inline="always")
def _clamp01(x):
    return min(max(x, 0.0), 1.0)


@numba.njit(cache=True)
def segment_distance(p0x, p0y, p1x, p1y, q0x, q0y, q1x, q1y):
    """Distance between segments p0-p1 and q0-q1 (scalars); zero-length segments are points."""
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
    if not a_ok and not e_ok:
        return np.hypot(rx, ry)
    if not a_ok:
        t = _clamp01(f / e)
        return np.hypot(rx - d2x * t, ry - d2y * t)
    if not e_ok:
        s = _clamp01(-c / a)
        return np.hypot(rx + d1x * s, ry + d1y * s)
    denom = a * e - b * b
    general = denom > _EPS * max(a * e, _EPS)
    s = _clamp01((b * f - c * e) / denom) if general else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        s = _clamp01(-c / a)
    elif t > 1.0:
        s = _clamp01((b - c) / a)
    t = _clamp01(t)
    d = np.hypot(rx + d1x * s - d2x * t, ry + d1y * s - d2y * t)
    if not general:  # (nearly) parallel: the closest pair involves an end point
        d = min(d, _point_segment(p0x, p0y, q0x, q0y, q1x, q1y), _point_segment(p1x, p1y, q0x, q0y, q1x, q1y),
                _point_segment(q0x, q0y, p0x, p0y, p1x, p1y), _point_segment(q1x, q1y, p0x, p0y, p1x, p1y))
    return d


@numba.njit(cache=True, inline="always")
def _bodies_clearance(sa, ea, ra, i, sb, eb, rb, j):
    """Min over body pairs of arm a at sample i (``sa``/``ea`` (N, nb, 2)) and arm b at sample j."""
    m = np.inf
    for p in range(sa.shape[1]):
        for q in range(sb.shape[1]):
            d = segment_distance(sa[i, p, 0], sa[i, p, 1], ea[i, p, 0], ea[i, p, 1],
                                 sb[j, q, 0], sb[j, q, 1], eb[j, q, 0], eb[j, q, 1]) - ra[p] - rb[q]
            if d < m:
                m = d
    return m


# the kernel above for other compiled modules of the planner (planner.timeline)
bodies_clearance = _bodies_clearance


@numba.njit(cache=True)
def _clearance_rows(sa, ea, ra, sb, eb, rb):
    n = sa.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = _bodies_clearance(sa, ea, ra, i, sb, eb, rb, i)
    return out


def clearance_rows(sa: np.ndarray, ea: np.ndarray, ra: np.ndarray,
                   sb: np.ndarray, eb: np.ndarray, rb: np.ndarray) -> np.ndarray:
    """Min clearance over body pairs: ``s*``/``e*`` (..., nb, 2) broadcast against each other,
    ``ra`` / ``rb`` the body radii (nb,); returns the broadcast leading shape."""
    sa, ea, sb, eb = (np.asarray(x, float) for x in (sa, ea, sb, eb))
    lead = np.broadcast_shapes(sa.shape[:-2], ea.shape[:-2], sb.shape[:-2], eb.shape[:-2])
    n = int(np.prod(lead, dtype=np.int64))
    if n == 0:
        return np.empty(lead)
    clock.work("clearance_rows", n)

    def rows(x: np.ndarray) -> np.ndarray:  # C-contiguous and writable: one compiled signature
        return np.require(np.broadcast_to(x, lead + x.shape[-2:]).reshape(n, *x.shape[-2:]), float, ("C", "W"))

    out = _clearance_rows(rows(sa), rows(ea), np.require(ra, float, ("C", "W")),
                          rows(sb), rows(eb), np.require(rb, float, ("C", "W")))
    return out.reshape(lead)


@numba.njit(cache=True, inline="always")
def _box_gap(box_a, i, box_b, j):
    """Gap between the bounding boxes of arm a at sample i and arm b at sample j: a lower
    bound of their clearance."""
    gx = max(box_a[i, 0] - box_b[j, 2], box_b[j, 0] - box_a[i, 2])
    gy = max(box_a[i, 1] - box_b[j, 3], box_b[j, 1] - box_a[i, 3])
    return max(gx, gy)


# the box gap for other compiled modules of the planner (planner.timeline)
box_gap = _box_gap

# a box gap this many Lipschitz steps above the threshold is used as the clearance bound
# (cheaper than the exact clearance, and it already lets the walk jump that far)
BOX_GAP_STEPS = 8.0


@numba.njit(cache=True)
def _walk(sa, ea, ra, box_a, ia0, da, sb, eb, rb, box_b, ib0, db, n, lip, thr, first_only, ok):
    """Samples p = 0..n-1 of arm a at ia0 + da p against arm b at ib0 + db p (conservative
    advancement): a sample whose clearance (or box-gap bound) c is at least ``thr`` certifies
    the next floor((c - thr) / lip) samples, as the clearance changes by at most ``lip`` per
    sample; the walk jumps over them. ok[p] = False at every sample below ``thr`` (the others
    are left as they are); with ``first_only`` the walk stops at the first such sample and
    ``ok`` is not written. Returns (first sample below thr or -1, exact clearances computed)."""
    far = thr + BOX_GAP_STEPS * lip
    p = 0
    n_exact = 0
    first = -1
    while p < n:
        i = ia0 + da * p
        j = ib0 + db * p
        c = _box_gap(box_a, i, box_b, j)
        if c < far:
            c = _bodies_clearance(sa, ea, ra, i, sb, eb, rb, j)
            n_exact += 1
        if c < thr:
            if first < 0:
                first = p
            if first_only:
                return first, n_exact
            ok[p] = False
            p += 1
        elif lip > 0.0:
            p += int(min((c - thr) / lip, float(n))) + 1
        else:  # neither arm moves: as clear at every sample
            break
    return first, n_exact


@numba.njit(cache=True)
def _diagonals_bad(sa, ea, ra, box_a, na, sb, eb, rb, box_b, nb, m, k_lo, k_hi, lip, thr):
    bad = np.zeros(k_hi - k_lo + 1, np.bool_)
    scratch = np.ones(1, np.bool_)
    n_exact = 0
    for k in range(k_lo, k_hi + 1):
        a0 = max(0, m * k)
        a1 = min(na, nb + m * k)
        if a1 < a0:
            continue
        first, e = _walk(sa, ea, ra, box_a, a0, 1, sb, eb, rb, box_b, a0 - m * k, 1, a1 - a0 + 1, lip, thr,
                         True, scratch)
        n_exact += e
        bad[k - k_lo] = first >= 0
    return bad, n_exact


def _f(x: np.ndarray) -> np.ndarray:
    """``x`` as the kernels' one compiled layout (C-contiguous, writable float64), copied only
    when it is not already."""
    if x.dtype == np.float64 and x.flags.c_contiguous and x.flags.writeable:
        return x
    return np.require(x, float, ("C", "W"))


def rest_clear(sa: np.ndarray, ea: np.ndarray, ra: np.ndarray, box_a: np.ndarray, sb: np.ndarray,
               eb: np.ndarray, rb: np.ndarray, box_b: np.ndarray, j: int, lip_mm: float,
               thr_mm: float) -> tuple[np.ndarray, int]:
    """ok[i]: arm a at its sample i (every sample of ``sa``/``ea`` (N, nb, 2), boxes ``box_a``)
    keeps clearance >= ``thr_mm`` to arm b resting at its sample ``j``; the clearance changes
    by at most ``lip_mm`` per sample of a (:func:`_walk`). Returns (ok, exact clearances)."""
    ok = np.ones(sa.shape[0], np.bool_)
    _, n_exact = _walk(_f(sa), _f(ea), _f(ra), _f(box_a), 0, 1, _f(sb), _f(eb), _f(rb), _f(box_b), int(j), 0,
                       sa.shape[0], float(lip_mm), float(thr_mm), False, ok)
    clock.work("walk", n_exact)
    return ok, n_exact


def diagonals_bad(sa: np.ndarray, ea: np.ndarray, ra: np.ndarray, box_a: np.ndarray, sb: np.ndarray,
                  eb: np.ndarray, rb: np.ndarray, box_b: np.ndarray, m: int, k_lo: int, k_hi: int,
                  lip_mm: float, thr_mm: float) -> tuple[np.ndarray, int]:
    """bad[k - k_lo] for k in [k_lo, k_hi]: with arm b's sample index trailing a's by m k (b
    departs m k samples after a), some sample while both move (a's samples max(0, m k) ..
    min(Na, Nb + m k)) comes closer than ``thr_mm``; ``lip_mm`` bounds the change of the
    clearance per sample of both. Each diagonal stops at its first close sample. Returns
    (bad, exact clearances)."""
    bad, n_exact = _diagonals_bad(_f(sa), _f(ea), _f(ra), _f(box_a), sa.shape[0] - 1, _f(sb), _f(eb), _f(rb),
                                  _f(box_b), sb.shape[0] - 1, int(m), int(k_lo), int(k_hi), float(lip_mm),
                                  float(thr_mm))
    clock.work("walk", n_exact)
    return bad, n_exact


@numba.njit(cache=True)
def _to_arms(cs, ce, r, S, E, R):
    A = S.shape[0]
    n = max(cs.shape[0], S.shape[1])
    out = np.empty((A, n))
    for a in range(A):
        for t in range(n):
            out[a, t] = _bodies_clearance(cs, ce, r, t if cs.shape[0] > 1 else 0,
                                          S[a], E[a], R[a], t if S.shape[1] > 1 else 0)
    return out


def clearance_to_arms(cs: np.ndarray, ce: np.ndarray, r: np.ndarray,
                      S: np.ndarray, E: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(A, n) clearances of one arm's capsules ``cs``/``ce`` ((n, nb, 2), or (1, nb, 2) for a
    fixed pose) to A other arms ``S``/``E`` ((A, n, nb', 2), or (A, 1, nb', 2) for fixed
    poses; radii ``R`` (A, nb'))."""
    if cs.shape[0] != 1 and S.shape[1] != 1 and cs.shape[0] != S.shape[1]:
        raise ValueError(f"sample counts differ: {cs.shape[0]} and {S.shape[1]}")
    clock.work("clearance_to_arms", S.shape[0] * max(cs.shape[0], S.shape[1]))
    return _to_arms(_f(cs), _f(ce), _f(r), _f(S), _f(E), _f(R))


def compile_kernels() -> None:
    """Compile (or load from the on-disk cache) this module's kernels
    (:func:`planner.kernels.compile_kernels` compiles every kernel of the planner)."""
    z = np.zeros((1, 1, 2))
    r = np.zeros(1)
    clearance_rows(z, z, r, z, z, r)
    b = np.zeros((1, 4))
    rest_clear(z, z, r, b, z, z, r, b, 0, 1.0, 0.0)
    diagonals_bad(z, z, r, b, z, z, r, b, 1, 0, 0, 1.0, 0.0)
    clearance_to_arms(z, z, r, z[None], z[None], r[None])
