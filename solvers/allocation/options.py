"""Typed options of the allocation entry point, one frozen dataclass per concern.

* the engine of one configuration: :class:`BnbOptions`, :class:`HighsOptions`,
  :class:`CpsatOptions` (the exact model, thesis 5.4) or :class:`SemiGreedyOptions`
  (SGPBTA, thesis 5.3);
* the sequence and its post-passes: :class:`~solvers.sequencing.options.SequenceOptions`,
  :class:`~solvers.sequencing.options.RescueOptions`,
  :class:`~solvers.sequencing.options.RepairOptions`,
  :class:`~solvers.sequencing.options.PackingOptions`;
* :class:`AllocationOptions`, which holds one of each.

Every dataclass validates its fields once, in ``__post_init__`` (``InputError`` naming the
field).  :meth:`AllocationOptions.sequencing` resolves the fields left at ``None`` for the
chosen method and mode, in one place: the semi-greedy fast path
(:data:`SEMIGREEDY_SEQUENCING`) and the "one configuration" mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from models.errors import InputError
from solvers.sequencing.options import (
    DEFAULTS,
    PackingOptions,
    RepairOptions,
    RescueOptions,
    SequenceOptions,
    SequencingOptions,
    check_bool,
    check_int,
)

__all__ = ["CONFIG_MODES", "DEFAULT_SOLVER", "ENGINE_SEQUENCING", "FORMS", "METHODS", "SEMIGREEDY_SEQUENCING", "SOLVERS",
           "AllocationOptions", "BnbOptions", "CpsatOptions", "EngineOptions", "HighsOptions", "PackingOptions",
           "RepairOptions", "RescueOptions", "SemiGreedyOptions", "SequenceOptions", "SequencingOptions",
           "backend_name"]

METHODS = ("ilp", "semigreedy")
SOLVERS = ("highs", "cpsat", "bnb")
#: The exact engine of the library, the API, the CLI and the page (which reads it from the served
#: /openapi.json): the single place it is set.  CP-SAT, the customer's engine: on whole programmes
#: and dense sequences it loses nothing against ``bnb`` (docs/allocation.md, "Why CP-SAT is the
#: default").  It runs the staged model (:mod:`solvers.allocation.exact`): a branch-and-bound dive
#: gives the incumbent, which fixes the columns no better solution uses, settles stage 1 when it
#: meets the per-arm bound and is CP-SAT's complete hint (>= 2 workers).  ``"bnb"`` stays available.
DEFAULT_SOLVER = "cpsat"
CONFIG_MODES = ("one", "all")
FORMS = ("aggregated", "pairwise")
ArmSelection = Literal["gas", "pbas"]
PatrolSpec = Literal["thesis", "workspace"]

#: The semi-greedy fast path.  SGPBTA computes its crowding tie-break itself, incrementally
#: from cached neighbour pairs, so the driver's per-configuration k-d tree is not needed
#: (``tie_break=True`` passes the driver's weights, which SGPBTA then uses); no CP-SAT
#: repacking (seconds of solver time); a short ejection-chain repair; blank-sky rests (with
#: park only, a rim target in front of an arm's park can stay ``conflict``).
SEMIGREEDY_SEQUENCING = SequencingOptions(
    SequenceOptions(tie_break=False, blank_per_arm=16),
    RescueOptions(),
    RepairOptions(time_limit_s=0.5),
    PackingOptions(enabled=False),
)
#: The HiGHS and CP-SAT sequences hold back a quarter of the call for the post-passes.  An
#: engine proves what it can within each configuration's share, so its greedy loop uses the
#: whole time it is given, where the bitset search stops at its node limit; the ejection-chain
#: repair after it is what takes a dense sequence from its greedy ~115 configurations to the
#: bound (1,200 targets, sigma 40 mm, 20 s: HiGHS 116 -> 103-105 configurations with a tenth
#: held back, 101-102 with a quarter; ``python -m benchmarks.exact``).
ENGINE_SEQUENCING = SequencingOptions(SequenceOptions(reserve_fraction=0.25))
#: The per-configuration cap of a sequence, at most the call's limit.
SEQUENCE_CONFIG_TIME_LIMIT_S = 5.0


def _check_form(form) -> None:
    if form not in FORMS:
        raise InputError("form", "must be 'aggregated' or 'pairwise'")


@dataclass(frozen=True)
class BnbOptions:
    """The bitset branch-and-bound (:mod:`solvers.allocation.bnb`): node budgets of the
    three lexicographic stages, the CP-SAT ``fallback`` past ``node_limit`` (only when a
    solve has at least ``fallback_min_s``), and ``hint="semigreedy"`` for a heuristic
    incumbent."""

    node_limit: int = 4_000
    minimize_move: bool = True
    fallback: str | None = "cpsat"
    hint: str | None = None
    tie_node_limit: int = 2_000
    move_node_limit: int = 5_000
    fallback_min_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("node_limit", "tie_node_limit", "move_node_limit"):
            check_int(name, getattr(self, name), 1)
        check_bool("minimize_move", self.minimize_move)
        if self.fallback not in (None, "cpsat"):
            raise InputError("fallback", f"must be 'cpsat' or null, got {self.fallback!r}")
        if self.hint not in (None, "semigreedy"):
            raise InputError("hint", f"must be 'semigreedy' or null, got {self.hint!r}")
        v = self.fallback_min_s
        if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and v >= 0):
            raise InputError("fallback_min_s", "must be a finite number of seconds >= 0")


@dataclass(frozen=True)
class _ModelOptions:
    """What both exact-model engines share: the conflict rows (``form``), stage 2 of the
    lexicographic solve (``minimize_move``) and the lazy model's first candidates per arm
    (``candidates_per_arm``, None: the full model at once)."""

    form: str = "aggregated"
    minimize_move: bool = True
    candidates_per_arm: int | None = 8

    def __post_init__(self) -> None:
        _check_form(self.form)
        check_bool("minimize_move", self.minimize_move)
        check_int("candidates_per_arm", self.candidates_per_arm, 1, allow_none=True)


@dataclass(frozen=True)
class HighsOptions(_ModelOptions):
    """HiGHS (:mod:`solvers.allocation.highs`); ``interface``: "highspy" or "pyomo"."""

    interface: str = "highspy"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.interface not in ("highspy", "pyomo"):
            raise InputError("interface", f"must be 'highspy' or 'pyomo', got {self.interface!r}")


@dataclass(frozen=True)
class CpsatOptions(_ModelOptions):
    """CP-SAT (:mod:`solvers.allocation.cpsat`): ``workers`` (None: the problem's
    threads; at least 2) and ``linearization_level`` (0, 1 or 2)."""

    workers: int | None = None
    linearization_level: int = 2

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int("workers", self.workers, 1, allow_none=True)
        if self.linearization_level not in (0, 1, 2) or isinstance(self.linearization_level, bool):
            raise InputError("linearization_level", f"must be 0, 1 or 2, got {self.linearization_level!r}")


@dataclass(frozen=True)
class SemiGreedyOptions:
    """Parameters of SGPBTA (thesis 5.5.3.1 defaults: 30 runs, gamma 0.1, PBAS, eq. 5.21 matrix).

    ``penalty_matrix``: ``"thesis"`` (eq. 5.3), ``"workspace"`` (any reachable target,
    penalty 0) or an (n_arms, n_slices) integer matrix. ``first_slice_deg`` is the azimuth
    of the centre of slice 0 (arm 0's azimuth in the default instrument).
    ``time_limit_s`` defaults to the problem's. ``early_stop`` ends the multistart when
    a solution meets the matching upper bound in priority and yield; ``max_stall`` ends it
    after that many iterations without improvement (default 10; ``None`` runs all
    ``n_iter`` as the thesis does). ``crowding`` / ``crowding_radius_mm``: the hard-to-place
    tie-break in the solution update and replace moves (``problem.tie_break`` when the
    driver supplies one); ``eject_trials``: ejection moves evaluated per local-search pass
    (0 = the thesis' swap and replace moves only). Both are departures, see the module
    docstring.
    """

    alpha: float = 0.2
    gamma: float = 0.1
    n_iter: int = 30
    seed: int | None = None
    arm_selection: ArmSelection = "pbas"
    penalty_matrix: PatrolSpec | np.ndarray = "thesis"
    first_slice_deg: float = 0.0
    local_search: bool = True
    lookahead: bool = True
    early_stop: bool = True
    max_stall: int | None = 10
    time_limit_s: float | None = None
    crowding: bool = True
    crowding_radius_mm: float = 25.0
    eject_trials: int = 24

    def __post_init__(self) -> None:
        for name, lo, hi in (("alpha", 0.0, 1.0), ("gamma", 0.0, 10.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= v <= hi):
                raise InputError(name, f"must be a number in [{lo:g}, {hi:g}], got {v!r}")
        if isinstance(self.n_iter, bool) or not isinstance(self.n_iter, (int, np.integer)) or self.n_iter < 1:
            raise InputError("n_iter", f"must be an integer >= 1, got {self.n_iter!r}")
        if self.arm_selection not in ("gas", "pbas"):
            raise InputError("arm_selection", f"must be 'gas' or 'pbas', got {self.arm_selection!r}")
        if self.max_stall is not None and (isinstance(self.max_stall, bool) or self.max_stall < 1):
            raise InputError("max_stall", f"must be an integer >= 1 or None, got {self.max_stall!r}")
        if not isinstance(self.crowding, bool):
            raise InputError("crowding", f"must be true or false, got {self.crowding!r}")
        r = self.crowding_radius_mm
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not (np.isfinite(r) and r > 0):
            raise InputError("crowding_radius_mm", f"must be a number > 0, got {r!r}")
        e = self.eject_trials
        if isinstance(e, bool) or not isinstance(e, (int, np.integer)) or e < 0:
            raise InputError("eject_trials", f"must be an integer >= 0, got {e!r}")
        if self.time_limit_s is not None and not self.time_limit_s > 0:
            raise InputError("time_limit_s", f"must be > 0, got {self.time_limit_s!r}")


EngineOptions = BnbOptions | HighsOptions | CpsatOptions | SemiGreedyOptions
ENGINE_OPTIONS = {"bnb": BnbOptions, "highs": HighsOptions, "cpsat": CpsatOptions, "semigreedy": SemiGreedyOptions}


def backend_name(method: str, solver: str) -> str:
    """The registry name of the engine of ``method`` / ``solver`` (checked, naming the field)."""
    if method not in METHODS:
        raise InputError("method", f"must be one of {METHODS}, got {method!r}")
    if method == "semigreedy":
        return "semigreedy"
    if solver not in SOLVERS:
        raise InputError("solver", f"must be one of {SOLVERS}, got {solver!r}")
    return solver


@dataclass(frozen=True)
class AllocationOptions:
    """All options of one :func:`solvers.allocation.allocate` call.

    ``engine``: the options of the chosen engine (None: its defaults); a type that does
    not match the engine is refused (``options.engine``).  The sequence parts' ``None``
    fields take the defaults of the method and mode (:meth:`sequencing`).
    """

    engine: EngineOptions | None = None
    sequence: SequenceOptions = field(default_factory=SequenceOptions)
    rescue: RescueOptions = field(default_factory=RescueOptions)
    repair: RepairOptions = field(default_factory=RepairOptions)
    packing: PackingOptions = field(default_factory=PackingOptions)

    def __post_init__(self) -> None:
        if self.engine is not None and not isinstance(self.engine, tuple(ENGINE_OPTIONS.values())):
            raise InputError("options.engine", f"must be one of {sorted(c.__name__ for c in ENGINE_OPTIONS.values())}")
        SequencingOptions(self.sequence, self.rescue, self.repair, self.packing)  # type checks

    def engine_for(self, backend: str) -> EngineOptions:
        """The engine options for registry name ``backend`` (its defaults when unset)."""
        cls = ENGINE_OPTIONS[backend]
        if self.engine is None:
            return cls()
        if type(self.engine) is not cls:
            raise InputError("options.engine", f"{type(self.engine).__name__} is not an option set of "
                                               f"engine {backend!r} (expected {cls.__name__})")
        return self.engine

    def sequencing(self, configurations: str, time_limit_s: float,
                   backend_defaults: SequencingOptions | None = None) -> SequencingOptions:
        """The driver's options with every default resolved, in this order: "one
        configuration" mode (exactly one configuration, the call's whole limit, no adaptive
        share), the back-end's own defaults (``Backend.sequencing``:
        :data:`SEMIGREEDY_SEQUENCING`, :data:`ENGINE_SEQUENCING` for HiGHS and CP-SAT), the
        driver's (:data:`solvers.sequencing.options.DEFAULTS`), and the per-configuration cap
        ``min(time_limit_s, SEQUENCE_CONFIG_TIME_LIMIT_S)``."""
        seq = self.sequence
        if configurations == "one":
            seq = replace(seq, max_configurations=1,
                          adaptive_limits=False if seq.adaptive_limits is None else seq.adaptive_limits,
                          config_time_limit_s=time_limit_s if seq.config_time_limit_s is None
                          else seq.config_time_limit_s)
        if seq.config_time_limit_s is None:
            seq = replace(seq, config_time_limit_s=min(time_limit_s, SEQUENCE_CONFIG_TIME_LIMIT_S))
        out = SequencingOptions(seq, self.rescue, self.repair, self.packing)
        if backend_defaults is not None:
            out = out.with_defaults(backend_defaults)
        return out.with_defaults(DEFAULTS)
