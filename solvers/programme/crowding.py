"""Crowding: targets so close that no two arms can observe them in the same exposure, wherever
the pointing is placed and however it is turned.

An arm observes a target with its tip on it. Each arm's body that ends (or is centred) at its
tip holds the disc of the body's radius about the tip: the capsule from J3 to the tip of
radius r (the default instrument's L3, 10 mm) is that segment swept by a disc of radius r; a
sphere at the tip is that disc; a box holds the tip itself (radius 0). Two arms collide when
the clearance between their bodies is below the collision buffer (thesis table 6.1), and that
clearance is at most the distance between the two discs, ``|t_a - t_b| - r_a - r_b``. So two
targets closer than

    d_min = r_(1) + r_(2) + buffer            (the two smallest tip radii of the enabled arms)

can never share an exposure: 25 mm (30 arcsec) on the default instrument. The argument uses
no arm position, reach or angle, so it holds for every pointing: it is part of the
programme's proven bound (:mod:`.bound`) and of the programme model's rows (:mod:`.model`).

**Cells.** A greedy clique partition of the "closer than d_min" graph (:func:`crowding_cells`):
targets in one cell are pairwise closer than d_min, so one exposure observes at most one of a
cell, and a pointing holding m members of a cell takes at least m exposures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from models.instrument import Instrument
from solvers.programme.model import ReachRows

__all__ = ["CrowdingCells", "crowding_cells", "crowding_rows", "exclusion_distance_mm", "with_crowding"]

#: d_min is shrunk by this relative amount and by EXCLUSION_TOL_MM: distances on the
#: programme's tangent plane differ from those on a pointing's own plane by parts in 10^6
EXCLUSION_REL_TOL = 1e-4
EXCLUSION_TOL_MM = 1e-6


def _tip_radius_mm(arm) -> float:
    """The radius of the disc about the tip that the arm's bodies hold (module docstring)."""
    r = 0.0
    for b in arm.bodies:
        at_tip = b.joint_to == "tip" if b.shape != "sphere" else b.joint_from == "tip"
        if at_tip and b.shape in ("capsule", "sphere"):
            r = max(r, float(b.radius_mm))
    return r


def exclusion_distance_mm(inst: Instrument) -> float:
    """d_min of the module docstring, less its tolerances: two targets closer than this (on a
    tangent plane, mm) never share an exposure. 0 when fewer than two arms are enabled."""
    radii = sorted(_tip_radius_mm(a) for a in inst.arms if a.enabled)
    if len(radii) < 2:
        return 0.0
    d = radii[0] + radii[1] + float(inst.collision_buffer_mm)
    return max(d * (1.0 - EXCLUSION_REL_TOL) - EXCLUSION_TOL_MM, 0.0)


@dataclass(frozen=True)
class CrowdingCells:
    """``cell[i]``: the cell of target i (0 .. ``count`` - 1); ``size[c]``: its members."""

    cell: np.ndarray
    count: int

    @property
    def size(self) -> np.ndarray:
        return np.bincount(self.cell, minlength=self.count)

    @property
    def crowded(self) -> bool:
        return self.count < len(self.cell)


def crowding_cells(xy_mm: np.ndarray, d_min_mm: float) -> CrowdingCells:
    """A partition of the targets into cells of pairwise distance below ``d_min_mm``: greedy,
    the target with the most free neighbours first, each cell grown with its free neighbours
    (most neighbours first) that are close to every member so far."""
    xy = np.asarray(xy_mm, float).reshape(-1, 2)
    n = len(xy)
    cell = np.full(n, -1, np.int64)
    if n == 0 or d_min_mm <= 0:
        return CrowdingCells(np.arange(n, dtype=np.int64), n)
    tree = cKDTree(xy)
    neighbours = [np.asarray(v, np.int64) for v in tree.query_ball_point(xy, np.nextafter(d_min_mm, 0.0))]
    degree = np.array([len(v) - 1 for v in neighbours])
    count = 0
    for i in np.argsort(-degree, kind="stable"):
        if cell[i] >= 0:
            continue
        members = [int(i)]
        free = [int(j) for j in neighbours[i] if j != i and cell[j] < 0]
        for j in sorted(free, key=lambda j: (-degree[j], j)):
            d = xy[members] - xy[j]
            if np.all(np.hypot(d[:, 0], d[:, 1]) < d_min_mm):
                members.append(j)
        cell[members] = count
        count += 1
    return CrowdingCells(cell, count)


def crowding_rows(col_set: np.ndarray, member: np.ndarray, cells: CrowdingCells, arms: int | None = None):
    """Rows of the programme model for crowding: per candidate and cell with at least two of
    its members, those entries take at most one per exposure. ``col_set``/``member``: the
    candidate and target of each entry. With ``arms``, only the *dominant* rows: those of a
    cell holding more of the candidate's members than the candidate's members need exposures
    over the arms (m > ceil(|S_j| / arms)), which alone can raise the pointing's exposures
    above what its targets over the arms ask. Returns (start, entries, set, cap) as
    :class:`solvers.programme.model.ReachRows` holds them."""
    if not cells.crowded or len(member) == 0:
        return np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    key_cell = cells.cell[member]
    order = np.lexsort((key_cell, col_set))
    ks, kc = col_set[order], key_cell[order]
    new = np.r_[True, (np.diff(ks) != 0) | (np.diff(kc) != 0)]
    starts = np.flatnonzero(new)
    sizes = np.diff(np.r_[starts, len(order)])
    keep = sizes >= 2
    if arms is not None:
        set_size = np.bincount(col_set, minlength=int(col_set.max(initial=-1)) + 1)
        keep &= sizes > -(-set_size[ks[starts]] // arms)
    groups = [order[s:s + m] for s, m in zip(starts[keep], sizes[keep], strict=True)]
    entries = np.concatenate(groups) if groups else np.zeros(0, np.int64)
    start = np.r_[0, np.cumsum(sizes[keep])].astype(np.int64)
    return start, entries.astype(np.int64), ks[starts[keep]].astype(np.int64), np.ones(int(keep.sum()))


def with_crowding(rows: ReachRows | None, cand, cells: CrowdingCells, arms: int | None = None) -> ReachRows | None:
    """``rows`` (:class:`solvers.programme.model.ReachRows`, or None) with the crowding rows of
    the candidates ``cand`` appended (:func:`crowding_rows`; with ``arms`` the dominant ones)."""
    col_set = np.repeat(np.arange(len(cand)), cand.sizes)
    start, entries, sets, caps = crowding_rows(col_set, cand.index, cells, arms)
    if len(sets) == 0:
        return rows
    if rows is None or len(rows.set) == 0:
        return ReachRows(start, entries, sets, caps)
    return ReachRows(np.r_[rows.start, rows.start[-1] + start[1:]], np.r_[rows.entries, entries],
                     np.r_[rows.set, sets], np.r_[np.asarray(rows.cap, float), caps])
