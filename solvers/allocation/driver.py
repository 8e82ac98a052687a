"""The allocation entry point (thesis ch. 5): one configuration or a full sequence.

``allocate`` checks its inputs (``InputError`` naming the field), takes the engine of the
chosen method from the back-end registry (:mod:`solvers.allocation.backends`: the exact
model on HiGHS or CP-SAT, the bitset branch-and-bound, or the semi-greedy heuristic) with
its typed options (:mod:`solvers.allocation.options`), and runs the one sequencing driver,
:func:`solvers.sequencing.sequence_configurations`.  ``position_angles_deg`` adds the
position-angle search of thesis 7.3: the field is rotated about the FOV centre by each
angle, every rotation is sequenced in parallel threads (the solvers release the GIL) and
the rotation with the fewest configurations, then highest priority completeness, wins.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import solvers.effort  # noqa: F401  (prices the work of the incompatibility structure)
from models import clock
from models.budget import Budget
from models.errors import InputError, TimeLimitExceeded
from models.incompatibility import build_assignments, incompatibility_for_targets
from models.instrument import Instrument
from models.locks import (
    LockColumns,
    TargetLock,
    check_exclusions,
    check_locks,
    lock_columns,
    lock_reason,
)
from models.types import AllocationResult, PlaneTargets, Unallocated
from solvers.allocation.backends import Backend, get_backend
from solvers.allocation.options import (
    CONFIG_MODES,
    DEFAULT_SOLVER,
    ENGINE_OPTIONS,
    AllocationOptions,
    backend_name,
)
from solvers.problem import ConfigProblem, ConfigSolution
from solvers.sequencing import Progress, sequence_configurations

__all__ = ["allocate", "rotate_targets", "stage_engines", "timed_out_result"]

MAX_ANGLE_THREADS = 4


def stage_engines(backend: Backend) -> tuple[Callable[[ConfigProblem], ConfigSolution], dict[str, str]]:
    """The rescue's exact one-target solve for the chosen engine, and which engine does
    which part of a sequence (returned as ``stats["engines"]``).

    HiGHS and CP-SAT requests rescue with their own engine; ``bnb`` and the semi-greedy
    heuristic with CP-SAT (``Backend.rescue``).  Repacking and the configuration lower
    bounds are multi-configuration CP-SAT / LP models whatever the engine.
    """
    rescue = get_backend(backend.rescue)
    exact_one = rescue.solver(ENGINE_OPTIONS[rescue.name](minimize_move=False))
    engines = {"configurations": backend.description, "rescue": rescue.name,
               "repair": "ejection chains (no engine)", "repacking": "cpsat + tabu search",
               "lower_bounds": "max-flow, cpsat, LP (highs via scipy)"}
    return exact_one, engines


def rotate_targets(targets: PlaneTargets, angle_deg: float) -> PlaneTargets:
    """The field rotated by ``angle_deg`` about the FOV centre (a change of position angle)."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    x, y = np.asarray(targets.x_mm, float), np.asarray(targets.y_mm, float)
    return PlaneTargets(targets.ids, c * x - s * y, s * x + c * y, targets.priority)


def timed_out_result(instrument: Instrument, targets: PlaneTargets,
                     fixed: dict[int, tuple[float, float]] | None, elapsed_s: float,
                     park_move_limit_s: float | None = None, locks: LockColumns | None = None,
                     excluded: Sequence[int] | None = None) -> AllocationResult:
    """The partial answer of a call whose time ran out while the incompatibility structure
    was built: no configuration; each target ``unreachable`` (no enabled arm reaches it,
    cheap to know), ``beyond_park_move_limit`` or ``no_time``;
    ``stats["stop_reason"] == "no_time"``."""
    reach = build_assignments(instrument, targets.x_mm, targets.y_mm, fixed=fixed,
                              park_move_limit_s=park_move_limit_s, locks=locks, excluded=excluded)
    unreachable = set(reach.unreachable.tolist())
    beyond = set(reach.beyond_limit.tolist())
    n = len(targets)
    unalloc = tuple(Unallocated(i, targets.ids[i], "beyond_park_move_limit" if i in beyond
                                else "unreachable" if i in unreachable else "no_time")
                    for i in range(n))
    stats = {"n_targets": n, "n_reachable": n - len(unreachable), "n_configurations": 0,
             "n_allocated": 0, "n_unreachable": len(unreachable),
             "field_completeness": 0.0 if n else 1.0, "priority_completeness": 0.0 if n else 1.0, "stop_reason": "no_time",
             "timed_out_in": "incompatibility", "timers_s": {"incompatibility_s": elapsed_s}}
    return AllocationResult((), unalloc, stats)


def with_lock_reasons(result: AllocationResult, locks: LockColumns, excluded: Sequence[int]) -> AllocationResult:
    """``result`` with its excluded targets' reason ``excluded`` and its unobserved locked
    targets' reason prefixed ``locked_`` (:func:`models.locks.lock_reason`);
    ``stats["n_excluded"]`` counts the excluded ones."""
    if not locks and not excluded:
        return result
    out = set(int(i) for i in excluded)
    unalloc = tuple(dataclasses.replace(u, reason="excluded") if u.target_index in out
                    else dataclasses.replace(u, reason=lock_reason(u.reason)) if u.target_index in locks
                    else u for u in result.unallocated)
    return AllocationResult(result.configurations, unalloc, dict(result.stats, n_excluded=len(out)))


def _check_inputs(instrument: Instrument, configurations: str, time_limit_s, seed, collision_buffer_mm,
                  start_q, fixed) -> np.ndarray | None:
    """The call's own inputs, each checked once (``InputError`` naming the field); returns
    ``start_q`` as an array."""
    if configurations not in CONFIG_MODES:
        raise InputError("configurations", f"must be one of {CONFIG_MODES}, got {configurations!r}")
    if not (isinstance(time_limit_s, int | float) and math.isfinite(time_limit_s) and time_limit_s > 0):
        raise InputError("time_limit_s", "must be a positive finite number of seconds")
    if not isinstance(seed, int | np.integer) or isinstance(seed, bool):
        raise InputError("seed", "must be an integer")
    if collision_buffer_mm is not None and not (math.isfinite(collision_buffer_mm) and collision_buffer_mm >= 0):
        raise InputError("collision_buffer_mm", "must be a finite number >= 0")
    if start_q is not None:
        start_q = np.asarray(start_q, float)
        if start_q.shape != (instrument.n_arms, 2) or not np.isfinite(start_q).all():
            raise InputError("start_q", f"must be {instrument.n_arms} finite (theta1_rad, theta2_rad) pairs")
    for k, q in (fixed or {}).items():
        if not (isinstance(k, int | np.integer) and 0 <= k < instrument.n_arms):
            raise InputError(f"fixed[{k}]", f"arm index must be in 0..{instrument.n_arms - 1}")
        if len(q) != 2 or not all(math.isfinite(v) for v in q):
            raise InputError(f"fixed[{k}]", "must be a finite (theta1_rad, theta2_rad) pair")
    return start_q


def _best_angle(angles: list[float], results: list[AllocationResult]) -> AllocationResult:
    """The rotation with the fewest configurations at the highest completeness (thesis 7.3)."""
    def key(i: int):
        s = results[i].stats
        return (-s["field_completeness"], s["n_configurations"], -s["priority_completeness"])

    best = min(range(len(angles)), key=key)
    r = results[best]
    stats = dict(r.stats, position_angle_deg=angles[best],
                 position_angle_search=[{"angle_deg": a, "n_configurations": x.stats["n_configurations"],
                                         "priority_completeness": x.stats["priority_completeness"]}
                                        for a, x in zip(angles, results, strict=True)])
    return AllocationResult(r.configurations, r.unallocated, stats)


def allocate(
    instrument: Instrument,
    targets: PlaneTargets,
    *,
    method: str = "ilp",
    solver: str = DEFAULT_SOLVER,
    configurations: str = "one",
    time_limit_s: float = 10.0,
    seed: int = 0,
    collision_buffer_mm: float | None = None,
    start_q: np.ndarray | None = None,
    fixed: dict[int, tuple[float, float]] | None = None,
    progress: Progress | None = None,
    position_angles_deg: tuple[float, ...] | None = None,
    options: AllocationOptions | None = None,
    budget: Budget | None = None,
    locked: Sequence[TargetLock] | None = None,
    excluded_targets: Sequence[str] | None = None,
) -> AllocationResult:
    """Allocate arms to targets: ``configurations="one"`` (best single configuration) or
    ``"all"`` (sequence to full completeness).  ``budget`` (on the caller's clock) bounds
    the whole call; without one, ``time_limit_s`` from now does.

    ``method``: "ilp" (exact, engine ``solver``: "bnb", "highs" or "cpsat") or
    "semigreedy" (SGPBTA).  ``options``: the typed options of the engine and of the
    sequence (:class:`~solvers.allocation.options.AllocationOptions`; default: every
    default).  With ``position_angles_deg`` the returned stats hold ``position_angle_deg``:
    the returned x/y of assignments are in the rotated frame of that angle.

    ``locked`` (:class:`~models.locks.TargetLock`): each such target is observed only by its
    arm (and IK branch), in the structure every engine and post-pass reads; a lock that
    cannot be honoured is an ``InputError`` naming ``locked[i]``. Locked targets take
    precedence in the engines' objective; one left unobserved is reported with its reason
    prefixed ``locked_``. ``excluded_targets`` (ids): observed by no arm, reported
    ``excluded``. See :mod:`models.locks`.
    """
    name = backend_name(method, solver)
    if budget is not None and not isinstance(budget, Budget):
        raise InputError("budget", f"must be a Budget, got {type(budget).__name__}")
    limit_s = time_limit_s if budget is None else budget.limit_s
    start_q = _check_inputs(instrument, configurations, limit_s, seed, collision_buffer_mm, start_q, fixed)
    opts = AllocationOptions() if options is None else options
    if not isinstance(opts, AllocationOptions):
        raise InputError("options", f"must be an AllocationOptions, got {type(opts).__name__}")
    backend = get_backend(name)
    solve_one = backend.solver(opts.engine_for(name))
    sequencing = opts.sequencing(configurations, float(limit_s), backend.sequencing)
    exact_one, engines = stage_engines(backend)
    check_exclusions(targets.ids, excluded_targets)
    check_locks(instrument, targets, locked, excluded_targets, fixed=fixed,
                park_move_limit_s=sequencing.sequence.park_move_limit_s, buffer_mm=collision_buffer_mm)
    locks = lock_columns(targets.ids, locked)
    excluded = [targets.ids.index(t) for t in excluded_targets or ()]

    def run(tgts: PlaneTargets, call: Budget) -> AllocationResult:
        # the structure build counts against the call's budget; the sequence gets a budget
        # of its own of what is left
        try:
            inc = incompatibility_for_targets(
                instrument, tgts.x_mm, tgts.y_mm, buffer_mm=collision_buffer_mm, fixed=fixed,
                blank_per_arm=sequencing.sequence.blank_per_arm, seed=int(seed),
                budget=call,
                park_move_limit_s=sequencing.sequence.park_move_limit_s, locks=locks, excluded=excluded)
        except TimeLimitExceeded:
            return with_lock_reasons(timed_out_result(instrument, tgts, fixed, call.elapsed_s(),
                                                      sequencing.sequence.park_move_limit_s, locks, excluded),
                                     locks, excluded)
        rest = Budget.start(max(call.left_s(), 1e-3))
        return with_lock_reasons(
            sequence_configurations(instrument, tgts, solve_one, sequencing, start_q=start_q, fixed=fixed,
                                    buffer_mm=collision_buffer_mm, budget=rest, seed=int(seed),
                                    progress=progress, incompatibility=inc, exact_one=exact_one,
                                    engines=engines, locks=locks, excluded=excluded),
            locks, excluded)

    if not position_angles_deg:
        return run(targets, Budget.start(limit_s) if budget is None else budget)
    angles = [float(a) for a in position_angles_deg]
    rotation_s = limit_s if budget is None else budget.left_s()
    return _best_angle(angles, _rotations(run, targets, angles, rotation_s))


def _rotations(run: Callable[[PlaneTargets, Budget], AllocationResult], targets: PlaneTargets,
               angles: list[float], limit_s: float) -> list[AllocationResult]:
    """``run`` on every rotation of ``targets``, in parallel threads, each with a budget of
    ``limit_s``.  In effort mode each rotation runs on an effort clock of its own (same
    wall-clock guard), and its budget is started on that clock, so that it does not depend
    on how the threads interleave; the work of all of them is then charged to the caller's
    clock."""
    parent = clock.effort_clock()

    def one(angle: float) -> tuple[AllocationResult, clock.EffortClock | None]:
        if parent is None:
            return run(rotate_targets(targets, angle), Budget.start(limit_s)), None
        wall_s = None if parent.wall_end is None else parent.wall_end - time.perf_counter()
        with clock.effort(wall_limit_s=wall_s) as own:
            return run(rotate_targets(targets, angle), Budget.start(limit_s)), own

    with ThreadPoolExecutor(max_workers=min(len(angles), MAX_ANGLE_THREADS)) as ex:
        done = list(ex.map(one, angles))
    for _, own in done:
        if parent is not None and own is not None:
            parent.t_s += own.t_s
            parent.overran |= own.overran
    return [r for r, _ in done]
