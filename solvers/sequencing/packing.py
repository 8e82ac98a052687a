"""Packing a pool of targets into a given number of configurations (thesis eqs. 5.13–5.15
per configuration): the tabu search of :mod:`solvers.sequencing.tabu` first, then CP-SAT's
exact-cover and max-cover models (:mod:`solvers.sequencing.packing_cpsat`)."""

from __future__ import annotations

import numpy as np

from models import clock
from models.incompatibility import Incompatibility
from solvers.sequencing.packing_cpsat import exact_cover, max_cover, packing_columns
from solvers.sequencing.tabu import tabu_pack

__all__ = ["complete_partial", "pack_targets"]


def pack_targets(inc: Incompatibility, pool: np.ndarray, n_configs: int, *, time_limit_s: float,
                 seed: int = 0, threads: int = 2, hint: list[np.ndarray] | None = None,
                 status_out: dict | None = None, tabu_fraction: float = 0.4,
                 proof_fraction: float = 1.0, partial_out: list | None = None) -> list[np.ndarray] | None:
    """Multi-configuration model: place every pooled target in one of ``n_configs``
    configurations (each obeying eqs. 5.13–5.15).  Returns the chosen assignment indices
    per configuration, or None when no packing was found in time.  Three stages share the
    time: the tabu search of :mod:`solvers.sequencing.tabu` (``tabu_fraction``), then CP-SAT's
    exact-cover model (``proof_fraction`` of what is left; it proves infeasibility fast),
    then, when that is below 1, CP-SAT's max-cover model for the rest (it finds the hard
    perfect packings; the repacking windows keep exact cover alone, which took weak-192
    fields 5 and 8 from 18 to their proven 17 where the split left them at 18) — see
    :mod:`solvers.sequencing.packing_cpsat`.  ``status_out["infeasible"]`` is set True when CP-SAT
    proves that no packing exists.  ``partial_out`` (optional list) receives the max-cover
    model's best partial packing when there is no packing (valid configurations that leave
    some pooled targets out)."""
    if status_out is not None:
        status_out["infeasible"] = False
    t0 = clock.now()
    partial = None
    if tabu_fraction > 0:
        # the tabu search finds most packings that exist in a fraction of a second
        partial: list = []
        found = tabu_pack(inc, pool, n_configs, time_limit_s=tabu_fraction * time_limit_s, seed=seed, hint=hint,
                          partial_out=partial)
        if found is not None:
            return found
    m = packing_columns(inc, pool)
    if m is None:
        return None
    left = time_limit_s - (clock.now() - t0)
    out = exact_cover(inc, m, pool, n_configs, time_limit_s=proof_fraction * left if proof_fraction < 1 else left,
                      seed=seed, threads=threads, hint=hint)
    if out.packing is None and not out.infeasible and proof_fraction < 1:
        left = time_limit_s - (clock.now() - t0)
        # the tabu search's best partial packing is the better start: CP-SAT's LNS improves on it
        out = max_cover(inc, m, pool, n_configs, time_limit_s=left, seed=seed, threads=threads,
                        hint=partial or hint)
        if out.partial is not None and partial_out is not None:
            partial_out.extend(out.partial)
    if status_out is not None:
        status_out["infeasible"] = out.infeasible
    return out.packing


def complete_partial(inc: Incompatibility, pool: np.ndarray, partial: list[np.ndarray], max_configs: int, *,
                     time_limit_s: float, seed: int = 0, threads: int = 2) -> list[np.ndarray] | None:
    """A packing of ``pool`` into at most ``max_configs`` configurations from a partial one
    (valid configurations that leave some pooled targets out): its configurations that
    observe something, plus the leftover targets packed by CP-SAT's max-cover model into
    as few more as fit.  None when they do not fit in time."""
    a = inc.assignments
    kept = [ch for ch in partial if (a.target[ch] >= 0).any()]
    seen = np.concatenate([a.target[ch] for ch in kept]) if kept else np.zeros(0, np.int64)
    leftover = np.setdiff1d(pool, seen[seen >= 0])
    if not len(leftover):
        return kept if len(kept) <= max_configs else None
    m = packing_columns(inc, leftover)
    if m is None:
        return None
    t0 = clock.now()
    for n in range(1, max_configs - len(kept) + 1):
        left = time_limit_s - (clock.now() - t0)
        if left <= 0.1:
            return None
        out = max_cover(inc, m, leftover, n, time_limit_s=left, seed=seed, threads=threads)
        if out.packing is not None:
            return kept + out.packing
    return None
