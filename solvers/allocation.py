"""Top-level allocation entry point (thesis ch. 5): one configuration or a full sequence.

``allocate`` validates options (``InputError`` naming the field), picks the single-
configuration back-end (exact ILP on HiGHS or CP-SAT, or the semi-greedy heuristic) and
runs :func:`solvers.sequencing.sequence_configurations`.  ``position_angles_deg`` adds the
position-angle search of thesis 7.3: the field is rotated about the FOV centre by each
angle, every rotation is sequenced in parallel threads (the solvers release the GIL) and
the rotation with the fewest configurations, then highest priority completeness, wins.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np

from models.errors import InputError, TimeLimitExceeded
from models.incompatibility import build_assignments, incompatibility_for_targets
from models.instrument import Instrument
from models.types import AllocationResult, PlaneTargets, Unallocated
from solvers.problem import ConfigProblem, ConfigSolution
from solvers.sequencing import Progress, sequence_configurations

METHODS = ("ilp", "semigreedy")
SOLVERS = ("highs", "cpsat", "bnb")
CONFIG_MODES = ("one", "all")
ILP_OPTIONS = {"form", "minimize_move", "candidates_per_arm", "workers", "linearization_level", "interface"}
SEQ_OPTIONS = {"config_time_limit_s", "mip_rel_gap", "threads", "tie_break", "repack", "repack_max_window",
               "repack_time_limit_s", "max_configurations", "adaptive_limits", "lower_bound_flow", "rescue", "blank_per_arm", "tail_fraction",
               "repair", "repair_time_limit_s", "lp_bound_time_limit_s"}
BNB_OPTIONS = {"node_limit", "minimize_move", "fallback", "hint", "tie_node_limit", "move_node_limit",
               "fallback_min_s"}


def _solver_fn(method: str, solver: str, options: dict) -> Callable[[ConfigProblem], ConfigSolution]:
    if method == "semigreedy":
        try:
            from solvers.semigreedy import solve_semigreedy  # lazy: lands with issue 5
        except ImportError as e:
            raise NotImplementedError("method='semigreedy' needs solvers.semigreedy.solve_semigreedy "
                                      "(issue 5), which is not available yet") from e
        return partial(solve_semigreedy, **options)
    from solvers.ilp import solve_ilp_cpsat, solve_ilp_highs

    if solver == "bnb":
        from solvers.bnb import solve_ilp_bnb

        bad = set(options) - BNB_OPTIONS
        if bad:
            raise InputError(f"options.{sorted(bad)[0]}", "not an option of solver 'bnb'")
        return partial(solve_ilp_bnb, **options)
    if solver == "highs":
        bad = set(options) - {"form", "minimize_move", "candidates_per_arm", "interface"}
        if bad:
            raise InputError(f"options.{sorted(bad)[0]}", "not an option of solver 'highs'")
        return partial(solve_ilp_highs, **options)
    bad = set(options) - {"form", "minimize_move", "candidates_per_arm", "workers", "linearization_level"}
    if bad:
        raise InputError(f"options.{sorted(bad)[0]}", "not an option of solver 'cpsat'")
    return partial(solve_ilp_cpsat, **options)


def stage_engines(method: str, solver: str) -> tuple[Callable[[ConfigProblem], ConfigSolution], dict[str, str]]:
    """The rescue's exact one-target solve for the chosen engine, and which engine does
    which part of a sequence (returned as ``stats["engines"]``).

    HiGHS and CP-SAT requests rescue with their own engine.  ``bnb`` rescues with CP-SAT,
    its exact fallback (a node-limited bitset search wanders in the zero-weight rest
    placements of a rescue model), as does the semi-greedy heuristic.  Repacking and the
    configuration lower bounds are multi-configuration CP-SAT / LP models whatever the engine.
    """
    from solvers.ilp import solve_ilp_cpsat, solve_ilp_highs

    if method == "ilp" and solver == "highs":
        rescue, name = partial(solve_ilp_highs, minimize_move=False), "highs"
    else:
        rescue, name = partial(solve_ilp_cpsat, minimize_move=False), "cpsat"
    configurations = {"highs": "highs", "cpsat": "cpsat", "bnb": "bnb (cpsat for proofs past its node limit)"}
    engines = {"configurations": configurations[solver] if method == "ilp" else "semigreedy",
               "rescue": name, "repair": "ejection chains (no engine)", "repacking": "cpsat + tabu search",
               "lower_bounds": "max-flow, cpsat, LP (highs via scipy)"}
    return rescue, engines


def rotate_targets(targets: PlaneTargets, angle_deg: float) -> PlaneTargets:
    """The field rotated by ``angle_deg`` about the FOV centre (a change of position angle)."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    x, y = np.asarray(targets.x_mm, float), np.asarray(targets.y_mm, float)
    return PlaneTargets(targets.ids, c * x - s * y, s * x + c * y, targets.priority)


def timed_out_result(instrument: Instrument, targets: PlaneTargets,
                     fixed: dict[int, tuple[float, float]] | None, elapsed_s: float) -> AllocationResult:
    """The partial answer of a call whose time ran out while the incompatibility structure
    was built: no configuration; each target ``unreachable`` (no enabled arm reaches it,
    cheap to know) or ``no_time``; ``stats["stop_reason"] == "no_time"``."""
    reach = build_assignments(instrument, targets.x_mm, targets.y_mm, fixed=fixed)
    unreachable = set(reach.unreachable.tolist())
    n = len(targets)
    unalloc = tuple(Unallocated(i, targets.ids[i], "unreachable" if i in unreachable else "no_time")
                    for i in range(n))
    stats = {"n_targets": n, "n_reachable": n - len(unreachable), "n_configurations": 0,
             "field_completeness": 0.0 if n else 1.0, "reachable_completeness": 0.0 if n else 1.0,
             "priority_completeness": 0.0 if n else 1.0, "stop_reason": "no_time",
             "timed_out_in": "incompatibility", "timers_s": {"incompatibility_s": elapsed_s}}
    return AllocationResult((), unalloc, stats)


def allocate(
    instrument: Instrument,
    targets: PlaneTargets,
    *,
    method: str = "ilp",
    solver: str = "bnb",
    configurations: str = "one",
    time_limit_s: float = 10.0,
    seed: int = 0,
    collision_buffer_mm: float | None = None,
    start_q: np.ndarray | None = None,
    fixed: dict[int, tuple[float, float]] | None = None,
    progress: Progress | None = None,
    position_angles_deg: tuple[float, ...] | None = None,
    **method_options,
) -> AllocationResult:
    """Allocate arms to targets: ``configurations="one"`` (best single configuration) or
    ``"all"`` (sequence to full completeness).  ``time_limit_s`` bounds the whole call.

    ``method_options``: sequencing options (``config_time_limit_s``, ``mip_rel_gap``,
    ``threads``, ``tie_break``, ``repack``, ``repack_max_window``, ``repack_time_limit_s``,
    ``max_configurations``) and back-end options (ILP: ``form``, ``minimize_move``,
    ``candidates_per_arm``; HiGHS: ``interface``; CP-SAT: ``workers``,
    ``linearization_level``; semi-greedy: whatever ``solve_semigreedy`` accepts).
    With ``position_angles_deg`` the returned stats hold ``position_angle_deg``: the
    returned x/y of assignments are in the rotated frame of that angle.
    """
    if method not in METHODS:
        raise InputError("method", f"must be one of {METHODS}, got {method!r}")
    if method == "ilp" and solver not in SOLVERS:
        raise InputError("solver", f"must be one of {SOLVERS}, got {solver!r}")
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
    seq_opts = {k: method_options.pop(k) for k in list(method_options) if k in SEQ_OPTIONS}
    if configurations == "one":
        # one configuration: the request's whole limit is its limit (the adaptive share of
        # a sequence's budget is for sequences)
        seq_opts["max_configurations"] = 1
        seq_opts.setdefault("adaptive_limits", False)
        seq_opts.setdefault("config_time_limit_s", time_limit_s)
    for name in ("config_time_limit_s", "repack_time_limit_s", "repair_time_limit_s"):
        v = seq_opts.get(name)
        if v is not None and not (math.isfinite(v) and v > 0):
            raise InputError(name, "must be a positive finite number of seconds")
    v = seq_opts.get("lp_bound_time_limit_s")
    if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
        raise InputError("lp_bound_time_limit_s", "must be a finite number of seconds >= 0 (0: no LP bound)")
    mc = seq_opts.get("max_configurations")
    if mc is not None and not (isinstance(mc, int) and mc >= 1):
        raise InputError("max_configurations", "must be an integer >= 1")
    if method == "ilp":
        form = method_options.get("form", "aggregated")
        if form not in ("aggregated", "pairwise"):
            raise InputError("form", "must be 'aggregated' or 'pairwise'")
    solve_one = _solver_fn(method, solver, method_options)
    if method == "semigreedy":
        # SGPBTA computes its crowding tie-break itself, incrementally from cached neighbour
        # pairs (solvers.semigreedy.tie_break_weights): the driver's per-configuration k-d
        # tree is not needed (tie_break=True passes the driver's weights, which SGPBTA then uses)
        seq_opts.setdefault("tie_break", False)
        # the fast path: no CP-SAT repacking (seconds of solver time), a short ejection-chain
        # repair, and blank-sky rests (with park only, a rim target in front of an arm's park
        # can stay `conflict` — see README, semi-greedy)
        seq_opts.setdefault("repack", False)
        seq_opts.setdefault("repair_time_limit_s", 0.5)
        seq_opts.setdefault("blank_per_arm", 16)
    seq_opts.setdefault("config_time_limit_s", min(time_limit_s, 5.0))
    exact_one, engines = stage_engines(method, solver)

    def run(tgts: PlaneTargets) -> AllocationResult:
        # the structure build counts against the call's limit: it gets the same deadline
        # and the sequence only what is left
        t0 = time.perf_counter()
        try:
            inc = incompatibility_for_targets(
                instrument, tgts.x_mm, tgts.y_mm, buffer_mm=collision_buffer_mm, fixed=fixed,
                blank_per_arm=seq_opts.get("blank_per_arm", 0), seed=int(seed),
                deadline_s=t0 + time_limit_s, time_limit_s=time_limit_s)
        except TimeLimitExceeded:
            return timed_out_result(instrument, tgts, fixed, time.perf_counter() - t0)
        left_s = max(time_limit_s - (time.perf_counter() - t0), 1e-3)
        return sequence_configurations(instrument, tgts, solve_one, start_q=start_q, fixed=fixed,
                                       buffer_mm=collision_buffer_mm, time_limit_s=left_s, seed=int(seed),
                                       progress=progress, incompatibility=inc, exact_one=exact_one,
                                       engines=engines, **seq_opts)

    if not position_angles_deg:
        return run(targets)
    angles = [float(a) for a in position_angles_deg]
    with ThreadPoolExecutor(max_workers=min(len(angles), 4)) as ex:
        results = list(ex.map(lambda a: run(rotate_targets(targets, a)), angles))

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
