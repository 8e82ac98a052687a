"""A proven lower bound on the exposures of a whole programme, wherever its pointings are
placed and whatever their position angles.

**The argument.** One exposure observes at most ``arms`` targets, all inside one FOV circle of
radius R. Give every target a weight ``w_i >= 0`` such that no such set weighs more than 1:
for every disc D of radius R, the ``arms`` heaviest targets inside D weigh at most 1. Then each
exposure observes at most 1 of weight, so every plan that observes all targets takes at least
``sum(w)`` exposures (the dual of the fractional cover by discs; weak LP duality). ``w = 1/arms``
gives the trivial ``ceil(t / arms)``; ``w = 1`` on targets pairwise more than 2R apart gives
the number of FOVs a sparse field needs.

**Every disc is checked.** Every set of targets a disc of radius R holds lies in a disc of
radius R with two of them on its rim, or centred on one of them (slide the disc until it
touches). So the discs centred on each target and those through each pair closer than 2R
(:func:`disc_centres`) hold every maximal set, and checking the weight condition on them
checks it on every disc.

**The weights** come from a cutting-plane LP (:func:`lower_bound`): HiGHS maximises ``sum(w)``
over the violated discs found so far; the heaviest discs of its answer are added until none
is violated or the rounds run out. Whatever the LP returns is divided by the heaviest disc's
top-``arms`` weight over *all* discs, so the bound holds even when the cutting planes stop
early. Targets in different components of the 2R-neighbour graph never share an exposure,
so the bound is the sum over components of each component's weight rounded up.

**Crowding.** Targets closer than the instrument's exclusion distance never share an
exposure (:mod:`solvers.programme.crowding`: 25 mm on the default instrument). Grouped into
cells that are cliques of that relation, an exposure observes at most one target of a cell, so
the condition above becomes: the ``arms`` heaviest *cells* with a member inside D weigh at most
1, a cell of m targets counting m times its weight in ``sum(w)``. A crowded clump of m
targets alone then needs m exposures, which no disc argument sees. Without crowding every
target is its own cell and the two conditions are the same.

Distances are on the programme's tangent plane; the radius is enlarged by ``RADIUS_SLACK``
so that the plane's distortion of a few arcminutes (parts in 10^6) cannot make a true FOV
set look wider than R (a larger radius only weakens the bound).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from models import clock
from models.budget import Budget

__all__ = ["ExposureBound", "RADIUS_SLACK", "disc_centres", "lower_bound"]

#: relative enlargement of the FOV radius used by the bound (keeps it valid under the
#: tangent plane's distortion and rounding)
RADIUS_SLACK = 1e-4
#: a disc holds the targets within its radius times (1 + this) plus MEMBER_TOL_MM: the two
#: targets a pair disc is drawn through lie on its rim, where rounding would drop them
MEMBER_REL_TOL = 1e-9
MEMBER_TOL_MM = 1e-9
#: the bound enumerates pair discs only up to this many centres; beyond, the trivial and
#: component bounds alone are reported (still valid)
MAX_CENTRES = 400_000
#: cutting-plane rounds and discs added per round
ROUNDS = 15
CUTS_PER_ROUND = 200
#: the cutting-plane rounds examine at most this many discs (every k-th): the final check
#: examines them all, so the bound holds whatever the rounds saw
ROUND_CENTRES = 8_000
#: effort seconds charged per (disc, target) cell examined and per cutting-plane LP solve
#: (reference seconds, as the costs of solvers.effort)
CELL_S = 1.5e-8
LP_S = 0.02
#: targets per block of the all-discs check (memory: block x targets floats)
BLOCK_CELLS = 4_000_000


@dataclass(frozen=True)
class ExposureBound:
    """``exposures``: the proven lower bound; ``trivial``: ceil(t / arms); ``components``:
    groups of targets that can never share a FOV; ``weight``: the certified weights' sum
    (before rounding per component); ``method``: "lp" or "trivial" (too many discs to check)."""

    exposures: int
    trivial: int
    components: int
    weight: float
    method: str
    rounds: int = 0


def disc_centres(xy: np.ndarray, radius_mm: float) -> np.ndarray:
    """Centres of the discs of radius ``radius_mm`` that hold every maximal set of targets:
    each target, and the two discs through each pair closer than twice the radius.
    (k, 2) mm; may hold duplicates."""
    pairs = cKDTree(xy).query_pairs(2.0 * radius_mm, output_type="ndarray")
    if pairs.size == 0:
        return xy.copy()
    a, b = xy[pairs[:, 0]], xy[pairs[:, 1]]
    mid = 0.5 * (a + b)
    d = b - a
    dist = np.hypot(d[:, 0], d[:, 1])
    h = np.sqrt(np.maximum(radius_mm ** 2 - 0.25 * dist ** 2, 0.0))
    perp = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(dist, 1e-12)[:, None]
    return np.vstack([xy, mid + h[:, None] * perp, mid - h[:, None] * perp])


def _top_sums(xy: np.ndarray, w: np.ndarray, centres: np.ndarray, radius_mm: float, arms: int,
              cells: _Cells | None = None) -> tuple[np.ndarray, np.ndarray]:
    """For every centre, the summed weight of its ``arms`` heaviest cells with a member within
    ``radius_mm`` (``w``: per cell; without ``cells`` every target is its own cell) and
    (k, arms) indices of those cells (-1: fewer)."""
    clock.charge(CELL_S * len(centres) * len(xy))
    block = max(1, BLOCK_CELLS // max(len(xy), 1))
    parts = [_heaviest(_inside(xy, centres[s:s + block], radius_mm, cells), w, arms)
             for s in range(0, len(centres), block)]
    if not parts:
        return np.empty(0), np.full((0, min(arms, len(w))), -1, dtype=np.int64)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _inside(xy: np.ndarray, centres: np.ndarray, radius_mm: float, cells: _Cells | None) -> np.ndarray:
    """(k, cells) whether each of the discs at ``centres`` holds a member of each cell (every
    target its own cell without ``cells``)."""
    r2 = (radius_mm * (1.0 + MEMBER_REL_TOL) + MEMBER_TOL_MM) ** 2
    pts = xy if cells is None else xy[cells.order]
    inside = (centres[:, 0, None] - pts[None, :, 0]) ** 2 + (centres[:, 1, None] - pts[None, :, 1]) ** 2 <= r2
    return inside if cells is None else np.logical_or.reduceat(inside, cells.starts, axis=1)


def _heaviest(inside: np.ndarray, w: np.ndarray, arms: int) -> tuple[np.ndarray, np.ndarray]:
    """Per disc of the membership ``inside`` (k, cells), the summed weight of its ``arms``
    heaviest cells (``w``) and their indices (-1: fewer)."""
    m = inside.shape[1]
    k = min(arms, m)
    wm = np.where(inside, w[None, :], -1.0)
    idx = np.argpartition(-wm, k - 1, axis=1)[:, :k] if k < m else np.tile(np.arange(m), (len(wm), 1))
    top = np.take_along_axis(wm, idx, axis=1)
    return np.where(top > 0, top, 0.0).sum(axis=1), np.where(top >= 0, idx, -1)


@dataclass(frozen=True)
class _Cells:
    """Targets grouped by crowding cell: ``order`` sorts them by cell, ``starts[c]`` is where
    cell c begins in it; ``size[c]`` its members; ``first[c]`` one of them."""

    order: np.ndarray
    starts: np.ndarray
    size: np.ndarray
    first: np.ndarray

    @property
    def count(self) -> int:
        return len(self.starts)

    @staticmethod
    def of(cell: np.ndarray) -> _Cells:
        order = np.argsort(cell, kind="stable")
        size = np.bincount(cell)
        starts = np.r_[0, np.cumsum(size)[:-1]].astype(np.int64)
        return _Cells(order, starts, size, order[starts])


def _lp(value: np.ndarray, cuts: list[np.ndarray]) -> np.ndarray:
    """max sum(value * w) s.t. sum(w[cut]) <= 1 for every cut, 0 <= w <= 1 (HiGHS)."""
    import highspy

    n = len(value)
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = n, len(cuts)
    lp.col_cost_ = np.asarray(value, float)
    lp.col_lower_, lp.col_upper_ = np.zeros(n), np.ones(n)
    lp.row_lower_, lp.row_upper_ = np.full(len(cuts), -np.inf), np.ones(len(cuts))
    lp.sense_ = highspy.ObjSense.kMaximize
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = np.r_[0, np.cumsum([len(c) for c in cuts])].astype(np.int32)
    lp.a_matrix_.index_ = (np.concatenate(cuts) if cuts else np.zeros(0)).astype(np.int32)
    lp.a_matrix_.value_ = np.ones(int(sum(len(c) for c in cuts)))
    h.passModel(lp)
    h.run()
    clock.charge(LP_S)
    return np.clip(np.asarray(h.getSolution().col_value, float), 0.0, 1.0)


def lower_bound(xy: np.ndarray, fov_radius_mm: float, arms: int, budget: Budget | None = None,
                cell: np.ndarray | None = None) -> ExposureBound:
    """The proven lower bound on the exposures that observe every target of ``xy`` ((n, 2)
    mm on the programme's tangent plane) with FOVs of radius ``fov_radius_mm`` and ``arms``
    arms (module docstring). ``budget``: the cutting planes stop when it expires (the bound
    stays valid, only weaker). ``cell``: each target's crowding cell
    (:func:`solvers.programme.crowding.crowding_cells`), whose members one exposure observes
    at most one of (None: no crowding)."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    n = len(xy)
    trivial = math.ceil(n / arms)
    if n == 0:
        return ExposureBound(0, 0, 0, 0.0, "trivial")
    cells = None if cell is None or len(np.unique(cell)) == n else _Cells.of(np.asarray(cell, np.int64))
    crowd = 0 if cells is None else int(cells.size.max())
    R = fov_radius_mm * (1.0 + RADIUS_SLACK) + 1e-9
    pairs = cKDTree(xy).query_pairs(2.0 * R, output_type="ndarray")
    graph_n, labels = _components(n, pairs)
    if n + 2 * len(pairs) > MAX_CENTRES:
        return ExposureBound(max(trivial, graph_n, crowd), trivial, graph_n, float(n) / arms, "trivial")
    centres = disc_centres(xy, R)
    value = np.ones(n) if cells is None else cells.size.astype(float)
    w = np.ones(len(value))  # the LP with no cut yet
    cuts: list[np.ndarray] = []
    rounds = 0
    sample = centres[::max(1, math.ceil(len(centres) / ROUND_CENTRES))]
    block = max(1, BLOCK_CELLS // n)  # the sample's membership, found once for every round
    held = np.concatenate([_inside(xy, sample[s:s + block], R, cells) for s in range(0, len(sample), block)])
    while rounds < ROUNDS:
        rounds += 1
        clock.charge(CELL_S * len(sample) * n)  # each round is charged its whole sample
        sums, tops = _heaviest(held, w, arms)
        worst = np.argsort(-sums, kind="stable")[:CUTS_PER_ROUND]
        worst = worst[sums[worst] > 1.0 + 1e-7]
        if worst.size == 0 or (budget is not None and budget.expired()):
            break
        cuts.extend(np.unique(tops[j][tops[j] >= 0]) for j in worst)
        # a cut holds a disc's top targets; the disc's full member set is what binds, so the
        # next round re-checks every disc with the new weights
        w = _lp(value, cuts)
    sums, _ = _top_sums(xy, w, centres, R, arms, cells)
    w = w / max(float(sums.max(initial=0.0)), 1e-12)
    owner = labels if cells is None else labels[cells.first]  # a cell lies in one component
    per = np.bincount(owner, weights=w * value, minlength=graph_n)
    exposures = int(sum(math.ceil(v - 1e-9) for v in per))
    return ExposureBound(max(exposures, trivial, crowd), trivial, graph_n, float((w * value).sum()), "lp", rounds)


def _components(n: int, pairs: np.ndarray) -> tuple[int, np.ndarray]:
    from scipy import sparse as sp

    g = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])) if len(pairs) else
                      (np.zeros(0), (np.zeros(0, int), np.zeros(0, int))), shape=(n, n))
    return connected_components(g, directed=False)
