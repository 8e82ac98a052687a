"""Candidate pointings of a programme: the distinct maximal sets of targets one FOV can hold.

Every set of targets inside a disc of radius R lies inside a disc of radius R centred on one
of them or with two of them on its rim (:func:`solvers.programme.bound.disc_centres`). The
member sets of those discs, without duplicates and without a set inside another
(:func:`maximal_sets`), are every choice a pointing has: a model that picks among them loses
nothing, so its optimum and its dual bound hold for pointings placed anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from models import clock
from solvers.programme.bound import MEMBER_REL_TOL, MEMBER_TOL_MM, disc_centres

__all__ = ["Candidates", "maximal_sets"]

#: at most this many centres are examined; a field with more pairs takes the targets and a
#: grid instead (then the model's optimum is no longer a bound: ``Candidates.complete`` says so)
MAX_CENTRES = 20_000
#: beyond MAX_CENTRES, the centres are the targets and a square grid of this many FOV radii
GRID_STEP = 0.25
#: sets inside another are removed only up to this many distinct sets (the check is
#: quadratic); a model over more keeps them: harmless, a subset is never a better choice
DOMINANCE_MAX_SETS = 20_000
#: effort seconds charged per (set, set, word) of the dominance check (reference seconds)
DOMINANCE_CELL_S = 7e-9
#: effort seconds charged per (centre, member) pair found (reference seconds)
MEMBER_S = 0.15e-6


@dataclass(frozen=True)
class Candidates:
    """``centres_mm`` (k, 2): a disc centre of each set, on the programme's plane;
    ``members``: CSR (``start`` (k + 1,), ``index``) of target indices, ascending per set;
    ``complete``: every maximal set is present (the model's bound is then proven)."""

    centres_mm: np.ndarray
    start: np.ndarray
    index: np.ndarray
    complete: bool

    def __len__(self) -> int:
        return len(self.centres_mm)

    def of(self, j: int) -> np.ndarray:
        return self.index[self.start[j]:self.start[j + 1]]

    @property
    def sizes(self) -> np.ndarray:
        return np.diff(self.start)

    def restrict(self, targets: np.ndarray) -> tuple[Candidates, np.ndarray]:
        """The candidates with only the members in the bool mask ``targets`` (sets left
        empty dropped) and, for each entry, its index in this one's ``index``."""
        entries = np.flatnonzero(np.asarray(targets, bool)[self.index])
        col_set = np.repeat(np.arange(len(self)), self.sizes)[entries]
        keep, sizes = np.unique(col_set, return_counts=True)
        return Candidates(self.centres_mm[keep], np.r_[0, np.cumsum(sizes)].astype(np.int64),
                          self.index[entries], False), entries

    def subset(self, keep: np.ndarray) -> tuple[Candidates, np.ndarray]:
        """The candidates ``keep`` (indices, ascending) and, for each of their entries, its
        index in this one's ``index``."""
        keep = np.asarray(keep, dtype=np.int64)
        sizes = self.sizes[keep]
        entries = np.concatenate([np.arange(self.start[j], self.start[j + 1]) for j in keep]) if len(keep) \
            else np.zeros(0, np.int64)
        return Candidates(self.centres_mm[keep], np.r_[0, np.cumsum(sizes)].astype(np.int64),
                          self.index[entries], False), entries


def _centres(xy: np.ndarray, radius_mm: float) -> tuple[np.ndarray, bool]:

    c = disc_centres(xy, radius_mm)
    complete = True
    if len(c) > MAX_CENTRES:  # a dense field: the targets and a grid of GRID_STEP radii
        c, complete = np.vstack([xy, _grid(xy, GRID_STEP * radius_mm, radius_mm)]), False
    return c, complete


def _grid(xy: np.ndarray, step_mm: float, radius_mm: float) -> np.ndarray:
    """A square grid of ``step_mm`` over the targets' box, grown by ``radius_mm``, keeping
    the points with a target within ``radius_mm``."""
    lo, hi = xy.min(axis=0) - radius_mm, xy.max(axis=0) + radius_mm
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + step_mm, step_mm), np.arange(lo[1], hi[1] + step_mm, step_mm))
    g = np.column_stack([gx.ravel(), gy.ravel()])
    d, _ = cKDTree(xy).query(g, distance_upper_bound=radius_mm)
    return g[np.isfinite(d)]


def maximal_sets(xy: np.ndarray, radius_mm: float) -> Candidates:
    """The distinct maximal member sets of the discs of ``radius_mm`` through the targets
    ``xy`` ((n, 2) mm). A set kept is never a subset of
    another kept set (up to :data:`DOMINANCE_MAX_SETS` sets); its centre is the first disc
    found holding it."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    n = len(xy)
    centres, complete = _centres(xy, radius_mm)
    tree = cKDTree(xy)
    words = (n + 63) // 64
    bits = np.zeros((len(centres), words), dtype=np.uint64)
    for s in range(0, len(centres), 4096):
        lists = tree.query_ball_point(centres[s:s + 4096], radius_mm * (1.0 + MEMBER_REL_TOL) + MEMBER_TOL_MM)
        for r, members in enumerate(lists):
            m = np.asarray(members, dtype=np.int64)
            np.bitwise_or.at(bits[s + r], m // 64, np.left_shift(np.uint64(1), (m % 64).astype(np.uint64)))
    clock.charge(MEMBER_S * sum(int(v).bit_count() for row in bits[:: max(len(bits) // 64, 1)] for v in row)
                 * max(len(bits) // 64, 1))
    _, first = np.unique(bits, axis=0, return_index=True)
    first = np.sort(first)
    bits, centres = bits[first], centres[first]
    count = np.array([sum(int(v).bit_count() for v in row) for row in bits])
    order = np.argsort(-count, kind="stable")
    bits, centres, count = bits[order], centres[order], count[order]
    keep = _not_dominated(bits) if len(bits) <= DOMINANCE_MAX_SETS else np.arange(len(bits))
    clock.charge(DOMINANCE_CELL_S * min(len(bits), DOMINANCE_MAX_SETS) ** 2 * bits.shape[1] / 2)
    bits, centres = bits[keep], centres[keep]
    start = [0]
    index: list[np.ndarray] = []
    for row in bits:
        m = np.flatnonzero(np.unpackbits(row.view(np.uint8), bitorder="little")[:n])
        index.append(m)
        start.append(start[-1] + len(m))
    return Candidates(centres, np.asarray(start, np.int64),
                      np.concatenate(index) if index else np.zeros(0, np.int64), complete)


def _not_dominated(bits: np.ndarray, block: int = 128) -> np.ndarray:
    """Of sets ordered by decreasing size, those contained in no earlier one (a set inside a
    dropped one is inside the one that dropped it, so checking every earlier set is checking
    the kept ones). Blocks of ``block`` sets against all earlier ones, vectorised."""
    k = len(bits)
    dominated = np.zeros(k, dtype=bool)
    for s in range(0, k, block):
        rows = bits[s:s + block]
        inside = np.all((rows[:, None, :] & ~bits[None, :s + len(rows), :]) == 0, axis=2)
        inside &= np.arange(s + len(rows))[None, :] < np.arange(s, s + len(rows))[:, None]
        dominated[s:s + len(rows)] = inside.any(axis=1)
    return np.flatnonzero(~dominated)
