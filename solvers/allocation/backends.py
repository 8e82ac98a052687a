"""The single-configuration back-ends behind one small interface, and their registry.

A :class:`Backend` solves one :class:`~solvers.problem.ConfigProblem` with its own typed,
frozen options (:mod:`solvers.allocation.options`).  The registry maps a name to the
module or package that exports the back-end's ``BACKEND`` (everything under that name is
the back-end's own code); modules are imported on first use, so an
engine's library (highspy, OR-Tools) is loaded only when that engine is asked for, or by
:func:`load_engine_libraries` when a worker starts.  A
back-end that needs another engine (the ``bnb`` fallback to CP-SAT, its semi-greedy
incumbent) asks the registry, never the other module: no back-end imports another.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from solvers.problem import ConfigProblem, ConfigSolution

if TYPE_CHECKING:
    from solvers.sequencing.options import SequencingOptions

__all__ = ["BACKEND_MODULES", "ENGINE_LIBRARIES", "Backend", "backend_names", "get_backend", "load_engine_libraries",
           "note_incumbent"]

Solve = Callable[..., ConfigSolution]

#: The engines' libraries a default plan loads: CP-SAT for its allocations (OR-Tools loads
#: pandas with it, about 0.3 s) and HiGHS for the programme optimiser's model and bound.
ENGINE_LIBRARIES = ("ortools.sat.python.cp_model", "highspy")


def load_engine_libraries() -> None:
    """Import :data:`ENGINE_LIBRARIES`, so that a worker pays for them once at its start,
    not inside the first plan's budget."""
    for name in ENGINE_LIBRARIES:
        importlib.import_module(name)


@dataclass(frozen=True)
class Backend:
    """One engine: ``solve(problem, options, *, hint=None, columns=None)``.

    ``method``: ``"ilp"`` (exact) or ``"semigreedy"`` (heuristic); ``options_type``: the
    frozen dataclass of its options; ``exact``: whether ``optimal`` answers are proofs;
    ``rescue``: the registry name of the exact engine the sequence's conflict rescue uses
    for one leftover target at a time (its own for HiGHS and CP-SAT; CP-SAT for ``bnb``,
    whose node-limited search wanders in the zero-weight rest placements of a rescue model,
    and for the heuristic); ``description``: what ``stats["engines"]["configurations"]`` says;
    ``sequencing``: the back-end's own defaults for a whole sequence
    (:class:`~solvers.sequencing.options.SequencingOptions`, below the caller's and above
    the driver's; None: the driver's alone).
    ``hint`` (a feasible choice, one assignment per arm) and ``columns`` (a column mask
    proven to hold every solution at least as good as the hint) are exact-model inputs;
    back-ends without them ignore them.
    """

    name: str
    method: str
    options_type: type
    solve: Solve
    exact: bool
    rescue: str
    description: str
    sequencing: SequencingOptions | None = None

    def solver(self, options: Any) -> Callable[[ConfigProblem], ConfigSolution]:
        """``problem -> solution`` with ``options`` bound (what the sequencing driver calls)."""
        if not isinstance(options, self.options_type):
            raise TypeError(f"back-end {self.name!r} takes {self.options_type.__name__}, "
                            f"got {type(options).__name__}")

        def solve_one(problem: ConfigProblem, hint: np.ndarray | None = None,
                      columns: np.ndarray | None = None) -> ConfigSolution:
            return self.solve(problem, options, hint=hint, columns=columns)

        return solve_one


def note_incumbent(solution: ConfigSolution, caller_hint: np.ndarray | None) -> ConfigSolution:
    """Say in ``solution.stats["incumbent"]`` where an exact-model engine's start came from:
    ``"caller"`` (the hint it was given), ``"bnb"`` (the staged model's branch-and-bound dive,
    :func:`solvers.allocation.exact.presolve_columns`, which also fixed the columns and is the
    answer whenever the engine does not beat it) or ``"none"``.  The staged stats say
    ``hint`` when the model had a start."""
    if caller_hint is not None:
        solution.stats["incumbent"] = "caller"
    elif solution.stats.get("hint") and "incumbent_s" in solution.stats:
        solution.stats["incumbent"] = "bnb"
    else:
        solution.stats["incumbent"] = "none"
    return solution


BACKEND_MODULES = {
    "bnb": "solvers.allocation.bnb",
    "highs": "solvers.allocation.highs",
    "cpsat": "solvers.allocation.cpsat",
    "semigreedy": "solvers.allocation.semigreedy",
}


def backend_names() -> tuple[str, ...]:
    return tuple(BACKEND_MODULES)


def get_backend(name: str) -> Backend:
    """The registered back-end ``name`` (KeyError naming the known ones otherwise)."""
    try:
        module = BACKEND_MODULES[name]
    except KeyError:
        raise KeyError(f"unknown back-end {name!r}; known: {sorted(BACKEND_MODULES)}") from None
    backend = importlib.import_module(module).BACKEND
    if backend.name != name:
        raise RuntimeError(f"{module}.BACKEND is named {backend.name!r}, registered as {name!r}")
    return backend
