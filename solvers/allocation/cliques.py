"""Clique inequalities for the single-configuration integer program (thesis 5.4, eq. 5.15).

The rows of :mod:`solvers.model` describe the conflicts pair by pair or per arm pair
(aggregated form).  Near the FOV centre the conflict structure is a set of large cliques
across many arms: only one arm at a time fits into a disc of ~15 mm, so every assignment
whose tip lies in that disc excludes every other.  Pairwise rows let the LP relaxation
put 1/2 on many members of such a clique; one row ``sum x <= 1`` over the whole clique
removes those fractional points.

A set ``C`` of columns gives a *valid* row ``sum_{a in C} x_a <= 1`` when every two members
exclude each other in the model: same arm (eq. 5.13), same target (eq. 5.14) or an
incompatible pair (eq. 5.15).  Every row returned here is checked against exactly that
graph, so it cuts off no feasible configuration of the model, only fractional points.

Cliques are grown greedily (a greedy clique cover of the conflict graph) from two kinds of
seeds: *geometric* seeds — the columns whose tip lies in a small disc on a grid over the
field, taken in order of distance to the disc centre — and *column* seeds — each column,
growing through its neighbours nearest to its own tip.  Rows of size <= 2 are dropped (the
pairwise and aggregated rows already imply them), as are duplicates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from models import clock
from solvers.effort import CLIQUE_CELL_S, CLIQUE_DISC_S, CLIQUE_STEP_S

__all__ = ["CliqueOptions", "clique_rows", "exclusion_matrix"]


@dataclass(frozen=True)
class CliqueOptions:
    """How clique rows are seeded.

    ``disc_radius_mm``: radius of the geometric seed discs (tips inside are the seed set);
    ``disc_spacing_mm``: grid step of the disc centres; ``column_seeds``: also grow one
    clique from each of the first ``column_seeds`` columns in the caller's order (0: none),
    and only on models of at most ``column_seed_max_columns`` columns (each clique costs
    O(size x columns), and near a dense centre cliques hold hundreds of columns);
    ``max_columns``: above this many model columns the dense
    exclusion matrix would be too large and no rows are built.
    """

    disc_radius_mm: float = 15.0
    disc_spacing_mm: float = 7.5
    column_seeds: int = 200
    column_seed_max_columns: int = 2500
    max_columns: int = 2500

    def __post_init__(self) -> None:
        if not (self.disc_radius_mm > 0 and self.disc_spacing_mm > 0):
            raise ValueError("disc_radius_mm and disc_spacing_mm must be > 0")
        if self.max_columns < 1:
            raise ValueError("max_columns must be >= 1")
        if self.column_seeds < 0:
            raise ValueError("column_seeds must be >= 0")


def exclusion_matrix(adj: sparse.csr_matrix, cols: np.ndarray, arm_of: np.ndarray,
                     target_of: np.ndarray) -> np.ndarray:
    """(n, n) bool over the model columns ``cols`` (assignment indices): True when two
    columns cannot both be 1 — same arm, same real target, or an incompatible pair."""
    n = len(cols)
    ex = adj[cols][:, cols].toarray().astype(bool)
    clock.charge(2 * n * n * CLIQUE_CELL_S)
    ex |= arm_of[:, None] == arm_of[None, :]
    real = target_of >= 0
    ex |= (target_of[:, None] == target_of[None, :]) & real[:, None] & real[None, :]
    ex[np.arange(n), np.arange(n)] = False
    return ex


def _grow(ex: np.ndarray, order: np.ndarray) -> list[int]:
    """Greedy clique: walk ``order`` and keep each column that excludes every kept one."""
    clique: list[int] = []
    rest = np.asarray(order)
    cells = 0
    while len(rest):
        c = int(rest[0])
        clique.append(c)
        rest = rest[1:]
        cells += len(rest)
        rest = rest[ex[c, rest]]
    clock.charge(len(clique) * CLIQUE_STEP_S + cells * CLIQUE_CELL_S)
    return clique


def clique_rows(ex: np.ndarray, xy_mm: np.ndarray, options: CliqueOptions | None = None,
                seed_order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Clique rows over the columns of ``ex`` (see :func:`exclusion_matrix`).

    ``xy_mm`` (n, 2): each column's tip location; ``seed_order``: the columns in the order
    they seed cliques (default: column order; e.g. best weight first).  Returns CSR ``(indptr, indices)`` of rows
    ``sum x <= 1`` with >= 3 members, every one a clique of ``ex`` (checked).
    """
    options = options or CliqueOptions()
    n = ex.shape[0]
    if n == 0 or n > options.max_columns:
        return np.zeros(1, np.int64), np.zeros(0, np.int64)
    x, y = xy_mm[:, 0], xy_mm[:, 1]
    seen: set[tuple[int, ...]] = set()
    rows: list[list[int]] = []

    def add(clique: list[int]) -> None:
        if len(clique) < 3:
            return
        key = tuple(sorted(clique))
        if key not in seen:
            seen.add(key)
            rows.append(list(key))

    r, step = options.disc_radius_mm, options.disc_spacing_mm
    gx = np.arange(np.floor(x.min() / step) * step, x.max() + step, step)
    gy = np.arange(np.floor(y.min() / step) * step, y.max() + step, step)
    for cx in gx:
        near_x = np.abs(x - cx) <= r
        if not near_x.any():
            continue
        clock.charge(len(gy) * (CLIQUE_DISC_S + n * CLIQUE_CELL_S))
        for cy in gy:
            d = np.hypot(x - cx, y - cy)
            inside = np.flatnonzero(near_x & (d <= r))
            if len(inside) >= 3:
                add(_grow(ex, inside[np.argsort(d[inside], kind="stable")]))
    seeds = np.arange(n) if seed_order is None else np.asarray(seed_order, np.int64)
    n_seeds = options.column_seeds if n <= options.column_seed_max_columns else 0
    for a in seeds[:n_seeds].tolist():
        nb = np.flatnonzero(ex[a])
        if len(nb) < 2:
            continue
        d = np.hypot(x[nb] - x[a], y[nb] - y[a])
        add(_grow(ex, np.r_[a, nb[np.argsort(d, kind="stable")]]))
    for row in rows:  # the guarantee the model relies on
        sub = ex[np.ix_(row, row)]
        if not (sub | np.eye(len(row), dtype=bool)).all():
            raise AssertionError("clique_rows produced a non-clique")
    indptr = np.r_[0, np.cumsum([len(q) for q in rows])].astype(np.int64)
    indices = np.array([c for q in rows for c in q], np.int64)
    return indptr, indices
