"""Arm reach in the programme model: which arms reach a candidate's members, the rows that
bound how many of them one exposure can take, and the shortlist of candidates the model
chooses among."""

from __future__ import annotations

import math

import numpy as np

from models import clock
from models.incompatibility import build_assignments
from models.instrument import Instrument
from solvers.programme.candidates import Candidates
from solvers.programme.model import ReachRows, greedy_cover

__all__ = ["PER_TARGET_CANDIDATES", "arm_masks", "entry_masks", "reach_least", "reach_rows", "shortlist"]

#: the shortlist keeps, for every target, this many of its best-filled candidates
PER_TARGET_CANDIDATES = 2
#: rows (5) are written for windows of 1 .. this many neighbouring arms
MAX_WINDOW = 4
#: effort seconds charged per point whose reaching arms are computed (reference seconds)
POINT_S = 20e-6
#: :func:`reach_least` checks every set of arms up to this many arms (2^arms sets), and
#: falls back to the targets over the arms beyond
HALL_MAX_ARMS = 16


def arm_masks(inst: Instrument, x_mm, y_mm, park_move_limit_s: float | None) -> np.ndarray:
    """(n,) bit k set when arm k reaches the FOV point (within the park move limit)."""
    x, y = np.atleast_1d(np.asarray(x_mm, float)), np.atleast_1d(np.asarray(y_mm, float))
    clock.charge(POINT_S * len(x))
    reach = build_assignments(inst, x, y, park_move_limit_s=park_move_limit_s, include_park=False)
    a = reach.assignments
    ok = a.target >= 0
    masks = np.zeros(len(x), dtype=np.int64)
    np.bitwise_or.at(masks, a.target[ok], np.left_shift(1, a.arm[ok].astype(np.int64)))
    return masks


def reach_least(masks: np.ndarray, n_arms: int) -> int:
    """The fewest exposures that can observe every target of ``masks`` (bit k: arm k reaches
    it; targets no arm reaches are left out) when each arm observes at most one target per
    exposure: Hall's condition for matching the targets to arms of capacity C holds exactly
    when, for every set A of arms, the targets only A reaches number at most C |A|, so the
    least C is the largest ceil(those targets / |A|). Collisions are ignored, so no exposure
    count below it is possible. Beyond :data:`HALL_MAX_ARMS` arms: ceil(targets / arms)."""
    m = np.asarray(masks, np.int64)
    m = m[m != 0]
    if m.size == 0:
        return 0
    if n_arms > HALL_MAX_ARMS:
        return math.ceil(m.size / n_arms)
    only = np.bincount(m, minlength=1 << n_arms).astype(np.int64)
    sets = np.arange(1 << n_arms)
    size = np.zeros(len(sets), np.int64)  # |A|
    for k in range(n_arms):  # only[A]: the targets whose arms all lie in A (sum over subsets)
        has = (sets >> k) & 1 == 1
        only[has] += only[sets[has] ^ (1 << k)]
        size += has
    some = size > 0
    return int(np.max(-(-only[some] // size[some])))


def entry_masks(inst: Instrument, cand: Candidates, xy_mm: np.ndarray, position_angle_deg: float,
                park_move_limit_s: float | None) -> np.ndarray:
    """Per entry of ``cand.index`` (a candidate's member): the arms that reach it from that
    candidate's centre at ``position_angle_deg``, as a bit mask (0: none)."""
    col_set = np.repeat(np.arange(len(cand)), cand.sizes)
    rel = xy_mm[cand.index] - cand.centres_mm[col_set]
    pa = math.radians(position_angle_deg)
    c, s = math.cos(pa), math.sin(pa)
    return arm_masks(inst, c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1], park_move_limit_s)


def reach_rows(cand: Candidates, masks: np.ndarray, n_arms: int) -> tuple[np.ndarray, ReachRows]:
    """Which entries an arm reaches, and rows (5) of the model: for every window of ``w``
    neighbouring arms (w = 1 .. :data:`MAX_WINDOW`), the members of a candidate that only
    those arms reach take at most ``w`` per exposure (a b-matching bound on arm reach)."""
    col_set = np.repeat(np.arange(len(cand)), cand.sizes)
    allowed = masks != 0
    # a target no candidate's arms reach stays in the model where it lies (the plan then
    # reports it unreachable), so that every target has a pointing
    reached = np.zeros(int(cand.index.max(initial=-1)) + 1, bool)
    reached[cand.index[allowed]] = True
    allowed |= ~reached[cand.index]
    starts, entries, sets, caps = [0], [], [], []
    for w in range(1, MAX_WINDOW + 1):
        for k0 in range(n_arms):
            window = sum(1 << ((k0 + d) % n_arms) for d in range(w))
            inside = np.flatnonzero(allowed & ((masks & ~window) == 0))
            for j, grp in _split(col_set[inside], inside):
                if len(grp) > w:  # a row binds only where the window has more targets than arms
                    entries.append(grp)
                    starts.append(starts[-1] + len(grp))
                    sets.append(j)
                    caps.append(w)
    rows = ReachRows(np.asarray(starts, np.int64),
                     np.concatenate(entries) if entries else np.zeros(0, np.int64),
                     np.asarray(sets, np.int64), np.asarray(caps, float))
    return allowed, rows


def _split(keys: np.ndarray, values: np.ndarray):
    if keys.size == 0:
        return
    cuts = np.flatnonzero(np.diff(keys)) + 1
    for ks, vs in zip(np.split(keys, cuts), np.split(values, cuts), strict=True):
        yield int(ks[0]), vs


def _fill_ratio(cand: Candidates, allowed: np.ndarray, rows: ReachRows, n_arms: int) -> np.ndarray:
    """Members per exposure each candidate would need, alone (rows (2) and (5))."""
    k = len(cand)
    col_set = np.repeat(np.arange(k), cand.sizes)
    u = np.bincount(col_set[allowed], minlength=k).astype(float)
    need = np.ceil(u / n_arms)
    if len(rows.entries):
        f = np.diff(rows.start).astype(float)
        np.maximum.at(need, rows.set, np.ceil(f / rows.cap))
    return u / np.maximum(need, 1.0)


def shortlist(cand: Candidates, n: int, masks: np.ndarray, n_arms: int, most: int) -> np.ndarray:
    """The candidates the model chooses among: those of the greedy cover, for every target
    its :data:`PER_TARGET_CANDIDATES` best-filled candidates, then the best-filled overall,
    up to ``most`` (ascending indices)."""
    allowed, rows = reach_rows(cand, masks, n_arms)
    fill = _fill_ratio(cand, allowed, rows, n_arms)
    k = len(cand)
    col_set = np.repeat(np.arange(k), cand.sizes)
    greedy = greedy_cover(cand, n, np.full(k, float(n_arms)), allowed, rows)
    chosen = set() if greedy is None else {int(j) for j in np.unique(greedy[greedy >= 0])}
    order = np.lexsort((col_set, -fill[col_set], cand.index))  # per target, best fill first
    first = np.searchsorted(cand.index[order], cand.index[order])
    rank = np.arange(len(order)) - first
    chosen |= {int(j) for j in col_set[order][rank < PER_TARGET_CANDIDATES]}
    for j in np.argsort(-fill, kind="stable"):
        if len(chosen) >= most:
            break
        chosen.add(int(j))
    return np.array(sorted(chosen), dtype=np.int64)
