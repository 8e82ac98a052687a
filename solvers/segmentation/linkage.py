"""Threshold complete-linkage clustering (thesis Algorithm 1) on the focal plane.

Three exact methods give the same partition as ``fcluster(linkage(points, "complete"),
threshold, "distance")``: the nearest-neighbour chain of the thesis (dense), a staged
KD-tree with reciprocal-nearest-neighbour rounds (O(n) memory), and scipy's dense linkage.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import shapely
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist, squareform

from models.errors import InputError

__all__ = ["SCIPY_MAX_POINTS", "STAGE_PAIRS_PER_POINT", "cluster_pair_max_dist", "hull_vertices",
           "nn_chain_complete_linkage", "sparse_complete_linkage", "threshold_complete_linkage"]

STAGE_PAIRS_PER_POINT = 64  # sparse linkage: at most this many first-stage pairs per point
SCIPY_MAX_POINTS = 2_500  # "auto": below this scipy's dense linkage is the fastest exact path


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


def hull_vertices(points: np.ndarray, labels: np.ndarray, m: int):
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


def cluster_pair_max_dist(xy, offsets, a, b, chunk=4_000_000) -> np.ndarray:
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
            xy, offsets = hull_vertices(pts, labels, m)
            w = cluster_pair_max_dist(xy, offsets, a, b)
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
