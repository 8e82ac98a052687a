"""Sequencing of configurations until a field is complete (thesis 5.5).

* :func:`sequence_configurations` (:mod:`.driver`) — the greedy loop, then the named
  post-passes of :mod:`.passes` (rescue, repair, packing, bounds, repacking) over one
  :class:`~.state.SequenceState`, within the budget of :mod:`.budget`;
* :mod:`.options` — the typed options of the loop and of each pass;
* the passes' parts: :mod:`.rescue`, :mod:`.repair` (ejection chains), :mod:`.repack`,
  :mod:`.packing` (:mod:`.tabu`, :mod:`.packing_cpsat`), :mod:`.bounds`.
"""

from solvers.sequencing.driver import Progress, sequence_configurations
from solvers.sequencing.options import (
    PackingOptions,
    RepairOptions,
    RescueOptions,
    SequenceOptions,
    SequencingOptions,
)
from solvers.sequencing.packing import complete_partial, pack_targets
from solvers.sequencing.state import UnverifiedConfigurationError, hard_to_place, joint_speeds

__all__ = ["PackingOptions", "Progress", "RepairOptions", "RescueOptions", "SequenceOptions", "SequencingOptions",
           "UnverifiedConfigurationError", "complete_partial", "hard_to_place", "joint_speeds", "pack_targets",
           "sequence_configurations"]
