"""The semi-greedy back-end, SGPBTA (thesis 5.3): :mod:`.solve` (the multistart and the
registry entry), :mod:`.prepare` (shared tables and the solution state), :mod:`.construct`
(construction and padding), :mod:`.local_search`, :mod:`.patrolling` (penalty matrices)."""

from solvers.allocation.options import SemiGreedyOptions
from solvers.allocation.semigreedy.construct import construct, lpc, pad
from solvers.allocation.semigreedy.local_search import (
    eject_pass,
    local_search,
    replace_pass,
    swap_pass,
)
from solvers.allocation.semigreedy.prepare import (
    DISP_EPS,
    Prepared,
    State,
    field_static,
    matching_bound,
    penalty_spec,
    prepare,
    tie_break_weights,
)
from solvers.allocation.semigreedy.solve import (
    BACKEND,
    solve_semigreedy,
    warm_start,
    warm_start_vector,
)

__all__ = ["BACKEND", "DISP_EPS", "Prepared", "SemiGreedyOptions", "State", "construct", "eject_pass", "field_static",
           "local_search", "lpc", "matching_bound", "pad", "penalty_spec", "prepare", "replace_pass",
           "solve_semigreedy", "swap_pass", "tie_break_weights", "warm_start", "warm_start_vector"]
