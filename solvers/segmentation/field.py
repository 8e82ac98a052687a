"""Field segmentation: split a scattered target list into telescope pointings (thesis ch. 4).

Pipeline of :func:`segment_field`:

1. project every target onto one global gnomonic plane about the field centre (models.sky);
2. threshold complete-linkage clustering there (thesis Algorithm 1, :mod:`.linkage`), default threshold
   sqrt(3) R -- the side of the equilateral triangle inscribed in the FOV, so by Jung's
   theorem every cluster fits a circle of radius R (thesis fig. 4.3);
3. smallest enclosing circle of each cluster (thesis Algorithm 2, :mod:`.enclosing_circle`);
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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial import cKDTree

from models.budget import Budget
from models.errors import InputError, TimeLimitExceeded
from models.sky import (
    focal_mm_to_sky,
    sky_to_focal_mm,
    spherical_centroid_deg,
    tangent_radius_mm,
)
from models.types import AllocationResult
from solvers.segmentation.enclosing_circle import smallest_enclosing_circle
from solvers.segmentation.linkage import (
    cluster_pair_max_dist,
    hull_vertices,
    threshold_complete_linkage,
)

if TYPE_CHECKING:
    from solvers.programme.angle import AngleChoice

FOV_TOL_MM = 1e-6  # a member may sit this far outside the FOV circle (rounding only)
Mode = Literal["complete-linkage", "balanced"]
#: the modes of :func:`solvers.programme.segment_programme`: these, and the optimiser's
MODES = ("complete-linkage", "balanced", "fewest-exposures")


@dataclass(frozen=True)
class Pointing:
    """One telescope pointing: centre on the sky, on the field's global plane, and members.

    ``radius_mm`` is the farthest member from the centre on this pointing's own tangent plane
    (<= the FOV radius). ``target_indices`` index the input arrays, ascending. The programme
    optimiser (mode "fewest-exposures", :mod:`solvers.programme`) also sets the pointing's
    ``position_angle_deg`` (None: the plan's), the ``exposures`` its allocation needed,
    ``only_here``: the members no other pointing of the plan holds, and that ``allocation`` of
    its members (target ids: ``str`` of the programme's indices), which the plan keeps unless
    its own allocation of the pointing is better. ``position_angle_search``: how its angle
    was chosen, when a search chose it (:class:`solvers.programme.angle.AngleChoice`).
    """

    id: str
    ra_deg: float
    dec_deg: float
    x_mm: float
    y_mm: float
    radius_mm: float
    target_indices: tuple[int, ...]
    position_angle_deg: float | None = None
    exposures: int | None = None
    only_here: tuple[int, ...] = ()
    allocation: AllocationResult | None = field(default=None, compare=False, repr=False)
    position_angle_search: AngleChoice | None = field(default=None, compare=False, repr=False)
    #: the plan observes ``allocation`` as it is instead of searching its own (the programme
    #: optimiser's witness, :mod:`solvers.programme.segment`; a pointing the plan's
    #: consolidation changed, :mod:`planner.consolidation`)
    allocation_final: bool = False


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment_field`; ``stats`` is JSON-ready (counts, spread, timing)."""

    tangent_ra_deg: float
    tangent_dec_deg: float
    pointings: tuple[Pointing, ...]
    stats: dict = field(default_factory=dict)


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
    hv, off = hull_vertices(xy, labels, k)
    out = np.empty((k, 2))
    for g in range(k):
        cx, cy, _ = smallest_enclosing_circle(hv[off[g]:off[g + 1]], seed=seed)
        out[g] = cx, cy
    return out


def local_fit(idx, ra, dec, ra_c, dec_c, scale, seed=0):
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
            rc, dc = local_fit(g, ra, dec, rc, dc, scale, seed)
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
        hv, off = hull_vertices(xy, labels, k)
        pairs = cKDTree(cxy).query_pairs(2 * R, output_type="ndarray").astype(np.int64)
        if pairs.size == 0:
            break
        a, b = pairs[:, 0], pairs[:, 1]
        far = cluster_pair_max_dist(hv, off, a, b)
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
    if mode not in MODES:
        raise InputError("mode", f"must be one of {', '.join(repr(m) for m in MODES)}, got {mode!r}")
    if tangent_point is not None:
        tra, tdec = (float(v) for v in tangent_point)
        if not (0.0 <= tra < 360.0):
            raise InputError("tangent_point.ra_deg", f"must be finite in [0, 360), got {tra!r}")
        if not (-90.0 <= tdec <= 90.0):
            raise InputError("tangent_point.dec_deg", f"must be finite in [-90, 90], got {tdec!r}")
    return ra, dec, t


def field_plane(
    ra_deg, dec_deg, *,
    threshold_mm: float | None = None,
    tangent_point: tuple[float, float] | None = None,
    fov_radius_mm: float = 125.0,
    plate_scale_arcsec_per_mm: float = 1.2,
    mode: Mode = "complete-linkage",
) -> tuple[np.ndarray, np.ndarray, float, tuple[float, float], np.ndarray]:
    """The checks of :func:`segment_field` and step 1 of its pipeline, without the clustering:
    (ra, dec, threshold_mm, tangent point, (n, 2) focal-plane mm about the tangent point).

    O(n) and vectorised, so a caller can refuse a field before admitting its segmentation.
    Raises InputError naming the field: a bad coordinate or option, targets spread over the
    whole sphere (no centre), a target >= 90 deg from the tangent point ("targets[i].dec_deg").
    """
    R, scale = float(fov_radius_mm), float(plate_scale_arcsec_per_mm)
    ra, dec, t = _validate(ra_deg, dec_deg, threshold_mm, tangent_point, R, scale, mode)
    tangent = (tuple(float(v) for v in tangent_point) if tangent_point is not None
               else spherical_centroid_deg(ra, dec))
    try:
        x, y = sky_to_focal_mm(ra, dec, tangent[0], tangent[1], scale)
    except InputError as e:  # rename "dec_deg[i]" to the target it is about
        raise InputError(e.field.replace("dec_deg[", "targets[").replace("]", "].dec_deg"),
                         e.message) from None
    return ra, dec, t, (float(tangent[0]), float(tangent[1])), np.column_stack([x, y])


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
    if time_limit_s is not None and not (isinstance(time_limit_s, int | float) and math.isfinite(time_limit_s)
                                         and time_limit_s > 0):
        raise InputError("time_limit_s", "must be a positive finite number of seconds")
    budget = Budget.start(time_limit_s)

    def check() -> None:
        if budget.expired():
            raise TimeLimitExceeded("segmentation", time_limit_s)

    if mode == "fewest-exposures":
        raise InputError("mode", "'fewest-exposures' needs the priorities and the instrument: "
                         "solvers.programme.segment_programme plans it")
    R, scale = float(fov_radius_mm), float(plate_scale_arcsec_per_mm)
    ra, dec, t, tangent, xy = field_plane(ra_deg, dec_deg, threshold_mm=threshold_mm,
                                          tangent_point=tangent_point, fov_radius_mm=R,
                                          plate_scale_arcsec_per_mm=scale, mode=mode)
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

    pointings = checked_pointings(groups, pra, pdec, ra, dec, tangent, R, scale)
    stats = {
        "mode": mode, "n_targets": int(len(ra)), "n_pointings": len(pointings),
        "n_complete_linkage_clusters": n_cl, "n_repaired_clusters": n_repaired,
        "threshold_mm": t, "fov_radius_mm": R, **member_stats(pointings),
        "time_s": budget.elapsed_s(),
    }
    return Segmentation(tangent[0], tangent[1], pointings, stats)


def checked_pointings(groups, pra, pdec, ra, dec, tangent, R: float, scale: float,
                      extras: list[dict] | None = None) -> tuple[Pointing, ...]:
    """The pointings of ``groups`` (target indices) centred on (``pra``, ``pdec``), after the
    guarantees every segmentation gives, checked on the final answer: each target in exactly
    one pointing, inside that pointing's FOV on its own plane (never return a target outside
    its FOV). ``extras``: more :class:`Pointing` fields, one dict per group."""
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
    return tuple(
        Pointing(id=f"P{g + 1:0{width}d}", ra_deg=float(pra[g]), dec_deg=float(pdec[g]),
                 x_mm=float(px[g]), y_mm=float(py[g]), radius_mm=float(radius[g]),
                 target_indices=tuple(int(i) for i in np.sort(idx)), **(extras[g] if extras else {}))
        for g, idx in enumerate(groups))


def member_stats(pointings: tuple[Pointing, ...]) -> dict:
    """The spread of a segmentation's pointings: farthest member, members per pointing."""
    sizes = np.array([len(p.target_indices) for p in pointings])
    return {"max_radius_mm": float(max(p.radius_mm for p in pointings)),
            "members_min": int(sizes.min()), "members_max": int(sizes.max()),
            "members_mean": float(sizes.mean()), "members_std": float(sizes.std())}
