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

__all__ = ["Candidates", "maximal_sets"]

#: at most this many centres are examined; a field with more pairs keeps a thinned set
#: (then the model's optimum is no longer a bound: ``Candidates.complete`` says so)
MAX_CENTRES = 30_000
#: sets inside another are removed only up to this many distinct sets (the check is
#: quadratic); a model over more keeps them: harmless, a subset is never a better choice
DOMINANCE_MAX_SETS = 3_000
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


def _centres(xy: np.ndarray, radius_mm: float, extra: np.ndarray | None) -> tuple[np.ndarray, bool]:
    from solvers.programme.bound import disc_centres

    c = disc_centres(xy, radius_mm)
    complete = True
    if len(c) > MAX_CENTRES:  # keep the targets and an even thinning of the pair discs
        keep = np.r_[np.arange(len(xy)), np.linspace(len(xy), len(c) - 1, MAX_CENTRES - len(xy)).astype(int)]
        c, complete = c[keep], False
    if extra is not None and len(extra):
        c = np.vstack([c, extra])
    return c, complete


def maximal_sets(xy: np.ndarray, radius_mm: float, extra_centres: np.ndarray | None = None,
                 ) -> Candidates:
    """The distinct maximal member sets of the discs of ``radius_mm`` through the targets
    ``xy`` ((n, 2) mm), plus those of ``extra_centres``. A set kept is never a subset of
    another kept set (up to :data:`DOMINANCE_MAX_SETS` sets); its centre is the first disc
    found holding it."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    n = len(xy)
    centres, complete = _centres(xy, radius_mm, extra_centres)
    tree = cKDTree(xy)
    words = (n + 63) // 64
    bits = np.zeros((len(centres), words), dtype=np.uint64)
    for s in range(0, len(centres), 4096):
        lists = tree.query_ball_point(centres[s:s + 4096], radius_mm)
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
    bits, centres = bits[keep], centres[keep]
    start = [0]
    index: list[np.ndarray] = []
    for row in bits:
        m = np.flatnonzero(np.unpackbits(row.view(np.uint8), bitorder="little")[:n])
        index.append(m)
        start.append(start[-1] + len(m))
    return Candidates(centres, np.asarray(start, np.int64),
                      np.concatenate(index) if index else np.zeros(0, np.int64), complete)


def _not_dominated(bits: np.ndarray) -> np.ndarray:
    """Of sets ordered by decreasing size, those not contained in an earlier kept one."""
    keep: list[int] = []
    kept = np.zeros((0, bits.shape[1]), dtype=np.uint64)
    for j in range(len(bits)):
        if len(kept) and np.any(np.all((bits[j] & ~kept) == 0, axis=1)):
            continue
        keep.append(j)
        kept = np.vstack([kept, bits[j:j + 1]])
    return np.asarray(keep, dtype=np.int64)
