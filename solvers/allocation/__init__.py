"""Allocation of arms to targets (thesis ch. 5): the entry point, its typed options and the
single-configuration back-ends.

* :func:`allocate` (:mod:`.driver`) — the entry point: one configuration or a sequence;
* :mod:`.options` — frozen option dataclasses, validated once;
* :mod:`.backends` — the :class:`Backend` interface and the registry of engines:
  :mod:`.bnb` (bitset branch-and-bound), :mod:`.highs`, :mod:`.cpsat` (the exact model)
  and :mod:`.semigreedy` (SGPBTA);
* shared by the exact engines: :mod:`solvers.model` (the model arrays), :mod:`.lazy`
  (lazy candidate loop), :mod:`.exact` (staged, presolved solve), :mod:`.bitset` (the
  branch-and-bound search and its proven column pruning), :mod:`.cliques` (clique rows).
"""

from solvers.allocation.backends import Backend, backend_names, get_backend
from solvers.allocation.driver import allocate, rotate_targets, stage_engines, timed_out_result
from solvers.allocation.options import (
    AllocationOptions,
    BnbOptions,
    CpsatOptions,
    HighsOptions,
    PackingOptions,
    RepairOptions,
    RescueOptions,
    SemiGreedyOptions,
    SequenceOptions,
)

__all__ = ["AllocationOptions", "Backend", "BnbOptions", "CpsatOptions", "HighsOptions", "PackingOptions",
           "RepairOptions", "RescueOptions", "SemiGreedyOptions", "SequenceOptions", "allocate", "backend_names",
           "get_backend", "rotate_targets", "stage_engines", "timed_out_result"]
