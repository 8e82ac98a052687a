"""Field segmentation: split a scattered target list into telescope pointings (thesis ch. 4).

Pipeline of :func:`segment_field`:

1. project every target onto one global gnomonic plane about the field centre (models.sky);
2. threshold complete-linkage clustering there (thesis Algorithm 1), default threshold
   sqrt(3) R -- the side of the equilateral triangle inscribed in the FOV, so by Jung's
   theorem every cluster fits a circle of radius R (thesis fig. 4.3);
3. smallest enclosing circle of each cluster (thesis Algorithm 2, solvers.enclosing_circle);
   its centre, projected back to RA/Dec, is the pointing;
4. re-check every member on a tangent plane about *its own pointing's* centre and repair
   (re-centre on that plane, else split) any cluster that does not fit -- a global plane
   distorts wide fields, and thresholds above sqrt(3) R do not guarantee a fit;
5. optionally (mode "balanced") fewer, better-balanced pointings: merge pointings whose
   union still fits one FOV, drop pointings whose members other FOVs already cover, and move
   targets lying in FOV overlaps from heavier to lighter pointings.

Guarantees, checked before returning: every target is in exactly one pointing and lies
within ``fov_radius_mm`` (+ FOV_TOL_MM) of its pointing centre on that pointing's plane.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import shapely
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist, squareform

from models.errors import InputError, TimeLimitExceeded
from models.sky import (
    focal_mm_to_sky,
    sky_to_focal_mm,
    spherical_centroid_deg,
    tangent_radius_mm,
)
from solvers.enclosing_circle import smallest_enclosing_circle

FOV_TOL_MM = 1e-6  # a member may sit this far outside the FOV circle (rounding only)
STAGE_PAIRS_PER_POINT = 64  # sparse linkage: at most this many first-stage pairs per point
SCIPY_MAX_POINTS = 2_500  # "auto": below this scipy's dense linkage is the fastest exact path
Mode = Literal["complete-linkage", "balanced"]


@dataclass(frozen=True)
class Pointing:
    """One telescope pointing: centre on the sky, on the field's global plane, and members.

    ``radius_mm`` is the farthest member from the centre on this pointing's own tangent plane
    (<= the FOV radius). ``target_indices`` index the input arrays, ascending.
    """

    id: str
    ra_deg: float
    dec_deg: float
    x_mm: float
    y_mm: float
    radius_mm: float
    target_indices: tuple[int, ...]


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment_field`; ``stats`` is JSON-ready (counts, spread, timing)."""

    tangent_ra_deg: float
    tangent_dec_deg: float
    pointings: tuple[Pointing, ...]
    stats: dict = field(default_factory=dict)


def _dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # the same formula as scipy's pdist, so threshold comparisons agree bit for bit
    dx = a[:, 0] - b[:, 0]
    dy = a[:, 1] - b[:, 1]
    return np.sqrt(dx * dx + dy * dy)


def _compact(labels: np.ndarray) -> np.ndarray:
    """Relabel to 0..k-1 in order of first appearance (deterministic cluster ids)."""
    _, first, inv = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    return rank[inv.ravel()]


def _rnn_rounds(m: int, u: np.ndarray, v: np.ndarray, w: np.ndarray, check=lambda: None) -> np.ndarray:
    """Complete-linkage agglomeration of m clusters joined by sparse edges (u < v, distance w).

    An absent edge means "farther than the threshold": with complete linkage
    d(A u B, X) = max(d(A, X), d(B, X)) (Lance-Williams), so a merged cluster keeps an edge
    only to clusters that had one with *both* parts. Every round merges all reciprocal
    nearest-neighbour pairs at once; reducibility (thesis eq. 4.17) makes that give the same
    hierarchy as merging them one at a time in an NN-chain. Ties are broken by position in
    the weight-sorted edge list, so the first edge is always a reciprocal pair.
    Returns the root of every cluster.
    """
    parent = np.arange(m, dtype=np.int64)
    lab = np.arange(m, dtype=np.int64)
    mult = np.ones(m, dtype=np.int64)
    merged = np.zeros(m, dtype=bool)
    order = np.argsort(w, kind="stable")
    u, v, w = u[order], v[order], w[order]
    while u.size:
        check()
        # edges are sorted by w; the sort position is a strict total order even with tied
        # distances, so the first edge is always a reciprocal pair and every round merges
        rank = np.arange(u.size, dtype=np.int64)
        first = np.full(m, u.size, dtype=np.int64)
        np.minimum.at(first, u, rank)
        np.minimum.at(first, v, rank)
        mutual = (first[u] == rank) & (first[v] == rank)
        mu, mv = u[mutual], v[mutual]
        parent[mv] = mu
        lab[mv] = mu
        merged[mu] = merged[mv] = True
        mult[mu] = 2
        touched = merged[u] | merged[v]
        ku, kv, kw = u[~touched], v[~touched], w[~touched]
        tu, tv, tw = lab[u[touched]], lab[v[touched]], w[touched]
        a, b = np.minimum(tu, tv), np.maximum(tu, tv)
        keep = a != b
        a, b, tw = a[keep], b[keep], tw[keep]
        if a.size:
            key = a * m + b
            o = np.argsort(key, kind="stable")
            key, a, b, tw = key[o], a[o], b[o], tw[o]
            starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
            count = np.diff(np.r_[starts, key.size])
            wmax = np.maximum.reduceat(tw, starts)
            ga, gb = a[starts], b[starts]
            ok = count == mult[ga] * mult[gb]
            # untouched edges are still sorted; timsort merges the two sorted runs in O(E)
            o = np.argsort(wmax[ok], kind="stable")
            w = np.concatenate([kw, wmax[ok][o]])
            order = np.argsort(w, kind="stable")
            u = np.concatenate([ku, ga[ok][o]])[order]
            v = np.concatenate([kv, gb[ok][o]])[order]
            w = w[order]
        else:
            u, v, w = ku, kv, kw
        # reset the per-round scratch state of the clusters touched this round
        lab[mv] = mv
        merged[mu] = merged[mv] = False
        mult[mu] = 1
    while True:  # pointer jumping to the roots
        nxt = parent[parent]
        if np.array_equal(nxt, parent):
            return parent
        parent = nxt


def _hull_vertices(points: np.ndarray, labels: np.ndarray, m: int):
    """Convex-hull vertices of every cluster (shapely/GEOS, vectorised over clusters).

    The farthest pair between two clusters is always a pair of hull vertices, so complete-
    linkage distances need only these. Returns (xy, offsets) grouped by cluster.
    """
    order = np.argsort(labels, kind="stable")
    lab_sorted = labels[order]
    geoms = shapely.multipoints(points[order], indices=lab_sorted)
    hulls = shapely.convex_hull(geoms)
    xy, idx = shapely.get_coordinates(hulls, return_index=True)
    # polygons repeat their first vertex; harmless for a max
    counts = np.bincount(idx, minlength=m)
    offsets = np.r_[0, np.cumsum(counts)]
    return xy, offsets


def _cluster_pair_max_dist(xy, offsets, a, b, chunk=4_000_000) -> np.ndarray:
    """max over hull-vertex pairs of clusters a[k], b[k] (vectorised, chunked)."""
    ha = offsets[a + 1] - offsets[a]
    hb = offsets[b + 1] - offsets[b]
    sizes = ha * hb
    out = np.empty(a.size)
    cum = np.cumsum(sizes)
    lo = 0
    while lo < a.size:
        base = cum[lo - 1] if lo else 0
        hi = int(np.searchsorted(cum, base + chunk, side="right"))
        hi = max(hi, lo + 1)
        s = sizes[lo:hi]
        starts = np.r_[0, np.cumsum(s)[:-1]]
        pid = np.repeat(np.arange(hi - lo), s)
        off = np.arange(pid.size) - starts[pid]
        hbp = hb[lo:hi][pid]
        ia = offsets[a[lo:hi]][pid] + off // hbp
        ib = offsets[b[lo:hi]][pid] + off % hbp
        out[lo:hi] = np.maximum.reduceat(_dist(xy[ia], xy[ib]), starts)
        lo = hi
    return out


def sparse_complete_linkage(points_mm: np.ndarray, threshold_mm: float,
                            stages: int = 4, *, check=lambda: None) -> np.ndarray:
    """Threshold complete linkage without the O(n^2) matrix; returns labels.

    Only pairs closer than the threshold can ever merge, so edges come from a KD-tree. To
    avoid enumerating the ~n * density * pi t^2 point pairs of a dense field at the full
    threshold, heights are processed in stages t/2^(s-1), ..., t/2, t: the cut of the
    dendrogram at t_k is the complete-linkage partition at t_k, and the next stage continues
    from those clusters (complete-linkage distance is always the farthest member pair,
    whatever the merge history), finding candidate cluster pairs by a KD-tree over one
    anchor member per cluster and their exact distance from convex-hull vertices.

    The first stage is lowered (more stages) until its point pairs number at most
    ``STAGE_PAIRS_PER_POINT`` per point, so a field packed into a few millimetres costs
    O(n) memory too; exact duplicates merge at height 0 without changing any other
    complete-linkage distance, so only the distinct points are clustered. ``check`` is
    called between stages and rounds (a deadline raises from it).
    """
    pts = np.asarray(points_mm, dtype=float)
    _, first, inverse = np.unique(pts, axis=0, return_index=True, return_inverse=True)
    if len(first) < len(pts):
        order = np.argsort(first, kind="stable")  # distinct points in order of first appearance
        rank = np.empty(len(first), dtype=np.int64)
        rank[order] = np.arange(len(first))
        sub = sparse_complete_linkage(pts[first[order]], threshold_mm, stages, check=check)
        return _compact(sub[rank[inverse.ravel()]])
    n = len(pts)
    if n > 1:
        tree = cKDTree(pts)
        budget = STAGE_PAIRS_PER_POINT * n
        while stages < 64 and (int(tree.count_neighbors(tree, threshold_mm / 2.0 ** (stages - 1))) - n) // 2 > budget:
            check()
            stages += 1
    labels = np.arange(n, dtype=np.int64)
    radii = [threshold_mm / 2.0 ** k for k in range(stages - 1, -1, -1)]
    for k, r in enumerate(radii):
        check()
        r_query = r * (1 + 1e-9) + 1e-12  # KD-tree rounding; exact filter below
        if k == 0:
            m = n
            pairs = cKDTree(pts).query_pairs(r_query, output_type="ndarray").astype(np.int64)
            a, b = pairs[:, 0], pairs[:, 1]
            w = _dist(pts[a], pts[b])
        else:
            labels = _compact(labels)
            m = int(labels.max()) + 1
            anchor = np.full(m, n, dtype=np.int64)
            np.minimum.at(anchor, labels, np.arange(n))
            pairs = cKDTree(pts[anchor]).query_pairs(r_query, output_type="ndarray")
            a, b = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
            xy, offsets = _hull_vertices(pts, labels, m)
            w = _cluster_pair_max_dist(xy, offsets, a, b)
        keep = w <= r
        a, b, w = a[keep], b[keep], w[keep]
        swap = a > b
        a[swap], b[swap] = b[swap], a[swap]
        root = _rnn_rounds(m, a, b, w, check)
        labels = root if k == 0 else root[labels]
    return _compact(labels)


def nn_chain_complete_linkage(points_mm: np.ndarray, threshold_mm: float) -> np.ndarray:
    """Thesis Algorithm 1: threshold complete linkage with a nearest-neighbour chain.

    Dense O(n^2) distance matrix (use for n up to a few thousand; the scalable path is
    :func:`sparse_complete_linkage`). The chain grows until its last two clusters are
    reciprocal nearest neighbours; they merge if within the threshold (Lance-Williams update
    d(A u B, X) = max(d(A, X), d(B, X))), otherwise every cluster on the chain is final (its
    nearest neighbour is beyond the threshold and complete-linkage distances only grow). The
    premature end the thesis notes -- clusters left on the chain when none remain outside
    it -- cannot strand clusters here: the loop runs until no agglomerable cluster is left,
    restarting the chain from the remaining ones.
    """
    pts = np.asarray(points_mm, dtype=float)
    n = len(pts)
    if n == 1:
        return np.zeros(1, dtype=np.int64)
    d = squareform(pdist(pts))
    np.fill_diagonal(d, np.inf)
    agglomerable = np.ones(n, dtype=bool)
    root = np.arange(n, dtype=np.int64)
    chain: list[int] = []
    while True:
        if not chain:
            rest = np.flatnonzero(agglomerable)
            if rest.size == 0:
                break
            chain.append(int(rest[0]))
        a = chain[-1]
        row = np.where(agglomerable, d[a], np.inf)
        b = int(np.argmin(row))
        if len(chain) > 1 and row[chain[-2]] <= row[b]:
            b = chain[-2]  # prefer the previous element on ties: the chain must terminate
        if not row[b] <= threshold_mm:  # nearest neighbour too far: the whole chain is final
            agglomerable[chain] = False
            chain.clear()
        elif len(chain) > 1 and b == chain[-2]:  # reciprocal nearest neighbours: merge
            chain.pop()
            chain.pop()
            d[a] = np.maximum(d[a], d[b])
            d[:, a] = d[a]
            d[a, a] = np.inf
            agglomerable[b] = False
            d[b] = d[:, b] = np.inf
            root[root == b] = a
        else:
            chain.append(b)
    return _compact(root)


def threshold_complete_linkage(
    points_mm: np.ndarray, threshold_mm: float,
    method: Literal["auto", "sparse", "nn-chain", "scipy"] = "auto",
    check=lambda: None,
) -> np.ndarray:
    """Cluster labels (0..k-1, in order of first appearance) of threshold complete linkage.

    Same partition as ``fcluster(linkage(points, "complete"), threshold, "distance")``: two
    points share a cluster iff their merge height is <= threshold. ``method``: "nn-chain"
    (thesis Algorithm 1, dense), "sparse" (staged KD-tree + reciprocal-NN rounds, O(n)
    memory), "scipy" (dense linkage), "auto" (scipy below SCIPY_MAX_POINTS, else sparse).
    """
    pts = np.asarray(points_mm, dtype=float).reshape(-1, 2)
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    if method == "auto":
        method = "scipy" if len(pts) <= SCIPY_MAX_POINTS else "sparse"
    if method == "sparse":
        return sparse_complete_linkage(pts, threshold_mm, check=check)
    if method == "nn-chain":
        return nn_chain_complete_linkage(pts, threshold_mm)
    if method == "scipy":
        if len(pts) == 1:
            return np.zeros(1, dtype=np.int64)
        return _compact(fcluster(linkage(pts, "complete"), threshold_mm, "distance"))
    raise InputError("method", f"unknown clustering method {method!r}")


# --------------------------------------------------------------------------- segment_field


def _groups(labels: np.ndarray) -> list[np.ndarray]:
    order = np.argsort(labels, kind="stable")
    cuts = np.flatnonzero(np.diff(labels[order])) + 1
    return np.split(order, cuts)


def _centres(xy: np.ndarray, groups: list[np.ndarray], seed: int) -> np.ndarray:
    """Smallest-enclosing-circle centre of every group, run on convex-hull vertices only
    (the circle of a set is that of its hull; GEOS hulls are vectorised over all groups)."""
    k = len(groups)
    labels = np.empty(len(xy), dtype=np.int64)
    for g, idx in enumerate(groups):
        labels[idx] = g
    hv, off = _hull_vertices(xy, labels, k)
    out = np.empty((k, 2))
    for g in range(k):
        cx, cy, _ = smallest_enclosing_circle(hv[off[g]:off[g + 1]], seed=seed)
        out[g] = cx, cy
    return out


def _local_fit(idx, ra, dec, ra_c, dec_c, scale, seed):
    """Re-centre a group on the smallest enclosing circle *on its own tangent plane*."""
    x, y = sky_to_focal_mm(ra[idx], dec[idx], ra_c, dec_c, scale)
    cx, cy, _ = smallest_enclosing_circle(np.column_stack([x, y]), seed=seed)
    ra2, dec2 = focal_mm_to_sky(np.array([cx]), np.array([cy]), ra_c, dec_c, scale)
    return float(ra2[0]), float(dec2[0])


def _repair(idx, ra, dec, ra_c, dec_c, R, scale, seed):
    """Make a group that fails the FOV check fit: re-centre on its local plane, else bisect
    it by complete linkage on that plane (recursively, with an explicit stack).
    A single target always fits (it becomes its own centre), so this terminates."""
    out = []
    stack = [(idx, ra_c, dec_c)]
    while stack:
        g, rc, dc = stack.pop()
        for _ in range(3):
            rc, dc = _local_fit(g, ra, dec, rc, dc, scale, seed)
            if tangent_radius_mm(ra[g], dec[g], rc, dc, scale).max() <= R + FOV_TOL_MM:
                out.append((g, rc, dc))
                break
        else:  # bisect by complete linkage on the local plane (fewest extra pointings)
            x, y = sky_to_focal_mm(ra[g], dec[g], rc, dc, scale)
            lab = fcluster(linkage(np.column_stack([x, y]), "complete"), 2, "maxclust")
            for sub in _groups(lab):
                stack.append((g[sub], *spherical_centroid_deg(ra[g[sub]], dec[g[sub]])))
    return out


def _verify_and_repair(groups, pra, pdec, ra, dec, R, scale, seed):
    lab = np.empty(len(ra), dtype=np.int64)
    for g, idx in enumerate(groups):
        lab[idx] = g
    r = tangent_radius_mm(ra, dec, pra[lab], pdec[lab], scale)
    bad = set(np.unique(lab[r > R + FOV_TOL_MM]).tolist())
    if not bad:
        return groups, pra, pdec, 0
    new_groups, new_ra, new_dec = [], [], []
    for g, idx in enumerate(groups):
        parts = _repair(idx, ra, dec, pra[g], pdec[g], R, scale, seed) if g in bad else [
            (idx, pra[g], pdec[g])]
        for sub, rc, dc in parts:
            new_groups.append(np.sort(sub))
            new_ra.append(rc)
            new_dec.append(dc)
    return new_groups, np.array(new_ra), np.array(new_dec), len(bad)


def _balance(groups, pra, pdec, xy, ra, dec, tangent, R, scale, seed):
    """Mode "balanced": fewer pointings, even loads, every target still inside its FOV.

    1. Merge pointing pairs whose union fits one FOV (complete linkage at sqrt(3) R refuses
       some unions whose enclosing circle is still <= R); greedy by union radius.
    2. Drop a pointing when every member lies in some other surviving FOV (thesis 4.3.3:
       overlaps), handing each member to its least-loaded covering pointing.
    3. Move targets in FOV overlaps from heavier to lighter pointings (thesis 4.3.3: bias).
    """
    rng = np.random.default_rng(seed)
    cxy = np.column_stack(sky_to_focal_mm(pra, pdec, *tangent, scale))
    groups = list(groups)
    for _ in range(3):  # 1. pair merges, repeated while they help
        k = len(groups)
        labels = np.empty(len(xy), dtype=np.int64)
        for g, idx in enumerate(groups):
            labels[idx] = g
        hv, off = _hull_vertices(xy, labels, k)
        pairs = cKDTree(cxy).query_pairs(2 * R, output_type="ndarray").astype(np.int64)
        if pairs.size == 0:
            break
        a, b = pairs[:, 0], pairs[:, 1]
        far = _cluster_pair_max_dist(hv, off, a, b)
        ok = far <= 2 * R  # a union wider than the FOV diameter can never fit
        a, b = a[ok], b[ok]
        radius = np.empty(a.size)
        centre = np.empty((a.size, 2))
        for q in range(a.size):
            pts = np.concatenate([hv[off[a[q]]:off[a[q] + 1]], hv[off[b[q]]:off[b[q] + 1]]])
            cx, cy, radius[q] = smallest_enclosing_circle(pts, seed=seed)
            centre[q] = cx, cy
        alive = np.ones(k, dtype=bool)
        merged_groups, merged_c = [], []
        for q in np.argsort(radius, kind="stable"):
            if radius[q] > R * (1 - 1e-6) or not (alive[a[q]] and alive[b[q]]):
                continue
            alive[a[q]] = alive[b[q]] = False
            merged_groups.append(np.concatenate([groups[a[q]], groups[b[q]]]))
            merged_c.append(centre[q])
        if not merged_groups:
            break
        keep = np.flatnonzero(alive)
        groups = [groups[g] for g in keep] + merged_groups
        cxy = np.vstack([cxy[keep], np.array(merged_c)])
    pra, pdec = focal_mm_to_sky(cxy[:, 0], cxy[:, 1], *tangent, scale)
    groups, pra, pdec, _ = _verify_and_repair(groups, pra, pdec, ra, dec, R, scale, seed)
    cxy = np.column_stack(sky_to_focal_mm(pra, pdec, *tangent, scale))

    # coverage: (pointing, target) pairs within R on the pointing's own plane. The global
    # plane only stretches distances, so a slightly larger global radius finds candidates.
    k = len(groups)
    assign = np.empty(len(xy), dtype=np.int64)
    for g, idx in enumerate(groups):
        assign[idx] = g
    cov = cKDTree(cxy).sparse_distance_matrix(cKDTree(xy), 1.05 * R, output_type="ndarray")
    p, t = cov["i"].astype(np.int64), cov["j"].astype(np.int64)
    inside = tangent_radius_mm(ra[t], dec[t], pra[p], pdec[p], scale) <= R - FOV_TOL_MM
    p, t = p[inside], t[inside]
    order = np.lexsort((p, t))
    p, t = p[order], t[order]
    start = np.searchsorted(t, np.arange(len(xy) + 1))
    covers = [p[start[i]:start[i + 1]] for i in range(len(xy))]
    load = np.bincount(assign, minlength=k)
    alive = np.ones(k, dtype=bool)
    for g in np.argsort(load, kind="stable"):  # 2. drop covered pointings, emptiest first
        mem = np.flatnonzero(assign == g)
        alts = [c[(c != g) & alive[c]] for c in (covers[i] for i in mem)]
        if any(x.size == 0 for x in alts):
            continue
        alive[g] = False
        for i, c in zip(mem, alts, strict=True):
            dest = c[np.argmin(load[c])]
            assign[i] = dest
            load[dest] += 1
        load[g] = 0
    multi = [i for i in range(len(xy)) if covers[i].size > 1]
    for _ in range(4):  # 3. level the loads through overlaps
        moved = 0
        for i in rng.permutation(multi) if multi else []:
            c = covers[i][alive[covers[i]]]
            dest = c[np.argmin(load[c])]
            if load[dest] + 1 < load[assign[i]]:
                load[assign[i]] -= 1
                load[dest] += 1
                assign[i] = dest
                moved += 1
        if not moved:
            break
    keep = np.flatnonzero(np.bincount(assign, minlength=k) > 0)
    return [np.flatnonzero(assign == g) for g in keep], pra[keep], pdec[keep]


def _validate(ra_deg, dec_deg, threshold_mm, tangent_point, R, scale, mode):
    ra = np.asarray(ra_deg, dtype=float)
    dec = np.asarray(dec_deg, dtype=float)
    if ra.ndim != 1 or dec.shape != ra.shape:
        raise InputError("targets", "ra_deg and dec_deg must be 1-D arrays of equal length")
    if ra.size == 0:
        raise InputError("targets", "the target list is empty")
    bad = np.flatnonzero(~((ra >= 0.0) & (ra < 360.0)))
    if bad.size:
        raise InputError(f"targets[{bad[0]}].ra_deg", f"must be finite in [0, 360), got {ra[bad[0]]!r}")
    bad = np.flatnonzero(~((dec >= -90.0) & (dec <= 90.0)))
    if bad.size:
        raise InputError(f"targets[{bad[0]}].dec_deg",
                         f"must be finite in [-90, 90], got {dec[bad[0]]!r}")
    if not (math.isfinite(R) and R > 0):
        raise InputError("fov_radius_mm", f"must be a finite number > 0, got {R!r}")
    if not (math.isfinite(scale) and scale > 0):
        raise InputError("plate_scale_arcsec_per_mm", f"must be a finite number > 0, got {scale!r}")
    t = math.sqrt(3.0) * R if threshold_mm is None else float(threshold_mm)
    if not (math.isfinite(t) and t > 0):
        raise InputError("threshold_mm", f"must be a finite number > 0, got {threshold_mm!r}")
    if t > 2 * R:
        raise InputError("threshold_mm", f"{t} mm is larger than the FOV diameter {2 * R} mm: "
                         "targets that far apart can never share a pointing")
    if mode not in ("complete-linkage", "balanced"):
        raise InputError("mode", f"must be 'complete-linkage' or 'balanced', got {mode!r}")
    if tangent_point is not None:
        tra, tdec = (float(v) for v in tangent_point)
        if not (0.0 <= tra < 360.0):
            raise InputError("tangent_point.ra_deg", f"must be finite in [0, 360), got {tra!r}")
        if not (-90.0 <= tdec <= 90.0):
            raise InputError("tangent_point.dec_deg", f"must be finite in [-90, 90], got {tdec!r}")
    return ra, dec, t


def segment_field(
    ra_deg, dec_deg, *,
    threshold_mm: float | None = None,
    tangent_point: tuple[float, float] | None = None,
    fov_radius_mm: float = 125.0,
    plate_scale_arcsec_per_mm: float = 1.2,
    mode: Mode = "complete-linkage",
    seed: int = 0,
    time_limit_s: float | None = None,
) -> Segmentation:
    """Group targets into pointings that each fit the FOV (thesis ch. 4.3, Algorithms 1-2).

    ``threshold_mm`` defaults to sqrt(3) * fov_radius_mm (216.5 mm for the 250 mm FOV); it
    must be in (0, 2R] -- above sqrt(3) R clusters may not fit one FOV and are split by the
    repair step. ``tangent_point`` (ra_deg, dec_deg) defaults to the spherical centroid of the
    targets; all targets must lie within 90 deg of it. ``mode="balanced"`` trades the plain
    complete-linkage partition for fewer, more even pointings. Invalid input raises
    InputError naming the field ("targets[3].dec_deg", "threshold_mm", ...).
    ``time_limit_s`` bounds the call: past it (checked between phases and inside the
    clustering rounds) :class:`~models.errors.TimeLimitExceeded` is raised, since a partial
    partition would leave targets in no pointing.
    """
    t0 = time.perf_counter()
    if time_limit_s is not None and not (isinstance(time_limit_s, int | float) and math.isfinite(time_limit_s)
                                         and time_limit_s > 0):
        raise InputError("time_limit_s", "must be a positive finite number of seconds")

    def check() -> None:
        if time_limit_s is not None and time.perf_counter() - t0 > time_limit_s:
            raise TimeLimitExceeded("segmentation", time_limit_s)

    R, scale = float(fov_radius_mm), float(plate_scale_arcsec_per_mm)
    ra, dec, t = _validate(ra_deg, dec_deg, threshold_mm, tangent_point, R, scale, mode)
    tangent = (tuple(float(v) for v in tangent_point) if tangent_point is not None
               else spherical_centroid_deg(ra, dec))
    try:
        x, y = sky_to_focal_mm(ra, dec, tangent[0], tangent[1], scale)
    except InputError as e:  # rename "dec_deg[i]" to the target it is about
        raise InputError(e.field.replace("dec_deg[", "targets[").replace("]", "].dec_deg"),
                         e.message) from None
    xy = np.column_stack([x, y])
    labels = threshold_complete_linkage(xy, t, check=check)
    check()
    groups = _groups(labels)
    cxy = _centres(xy, groups, seed)
    check()
    pra, pdec = focal_mm_to_sky(cxy[:, 0], cxy[:, 1], tangent[0], tangent[1], scale)
    groups, pra, pdec, n_repaired = _verify_and_repair(groups, pra, pdec, ra, dec, R, scale, seed)
    n_cl = len(groups)
    if mode == "balanced":
        check()
        groups, pra, pdec = _balance(groups, pra, pdec, xy, ra, dec, tangent, R, scale, seed)
        check()
        groups, pra, pdec, n_rep2 = _verify_and_repair(groups, pra, pdec, ra, dec, R, scale, seed)
        n_repaired += n_rep2
    check()

    # the guarantees, checked on the final answer (never return a target outside its FOV)
    lab = np.full(len(ra), -1, dtype=np.int64)
    for g, idx in enumerate(groups):
        if np.any(lab[idx] >= 0):
            raise AssertionError("segmentation: a target is in two pointings")
        lab[idx] = g
    if np.any(lab < 0):
        raise AssertionError("segmentation: a target is in no pointing")
    r = tangent_radius_mm(ra, dec, pra[lab], pdec[lab], scale)
    if np.any(r > R + FOV_TOL_MM):
        raise AssertionError("segmentation: a target lies outside its pointing's FOV")
    radius = np.zeros(len(groups))
    np.maximum.at(radius, lab, r)
    px, py = sky_to_focal_mm(pra, pdec, tangent[0], tangent[1], scale)
    width = max(4, len(str(len(groups))))
    pointings = tuple(
        Pointing(id=f"P{g + 1:0{width}d}", ra_deg=float(pra[g]), dec_deg=float(pdec[g]),
                 x_mm=float(px[g]), y_mm=float(py[g]), radius_mm=float(radius[g]),
                 target_indices=tuple(int(i) for i in np.sort(idx)))
        for g, idx in enumerate(groups)
    )
    sizes = np.array([len(g) for g in groups])
    stats = {
        "mode": mode, "n_targets": int(len(ra)), "n_pointings": len(pointings),
        "n_complete_linkage_clusters": n_cl, "n_repaired_clusters": n_repaired,
        "threshold_mm": t, "fov_radius_mm": R, "max_radius_mm": float(radius.max()),
        "members_min": int(sizes.min()), "members_max": int(sizes.max()),
        "members_mean": float(sizes.mean()), "members_std": float(sizes.std()),
        "time_s": time.perf_counter() - t0,
    }
    return Segmentation(tangent[0], tangent[1], pointings, stats)
