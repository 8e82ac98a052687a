"""The allocator on the effort clock of :mod:`models.clock`: what its work costs, and the
CP-SAT and HiGHS limits and charges.

**Costs.** Every module of solvers/ charges its work with ``clock.charge(n * X_S)`` at the
costs below, in reference seconds; the incompatibility structure (:mod:`models.incompatibility`,
which knows no costs) reports its work through ``clock.work(kind, units)``, priced by
:data:`INCOMPATIBILITY_WORK_S`, registered with :func:`models.clock.register_work_costs`
when this module is imported (every module of solvers/ that builds the structure imports
it). The costs are scaled so that an effort second is a CPU second of the reference
machine: the CP-SAT solve's two (:data:`CPSAT_DETERMINISTIC_S`, :data:`CPSAT_SOLVE_S`) are
a least-squares fit of the CPU seconds of 436 solves of the benchmark below (bnb and cpsat
methods) on their deterministic time (0.46-0.50 CPU s per unit, 5-10 ms per solve);
:data:`BNB_NODE_S` is what a node of the bitset search costs in these calls; the others are
an earlier fit scaled by 0.5. Measured with these costs (2 cores, another process on the
other core):

* ``python -m benchmarks.effort_allocation --sizes 40 100 400 --limit 5 --methods bnb semigreedy``:
  effort / CPU seconds per call of median 1.04 for bnb (0.40-1.27) and 1.11 for semi-greedy
  (0.85-1.38); with ``--methods highs cpsat``: 0.89 (0.74-1.29) and 0.92 (0.73-1.44). Every
  call below 0.8 is on 40 targets, where the fixed costs of a call weigh most;
* ``tests/test_effort_calibration.py`` (bnb and semi-greedy on 40 and 150 targets, uniform
  and sigma 40 mm): 0.82-0.87 over the calls together (four runs). It fails outside 0.5-2.0: then
  re-fit with the command above.

**Engines.** On the wall clock (the default) both engines keep their limits in seconds.
Inside :func:`models.clock.effort` their searches must stop at the same point whatever the
machine's load, so:

* **CP-SAT** runs on ``max_deterministic_time`` (the budget in reference seconds over
  :data:`CPSAT_DETERMINISTIC_S`) with ``interleave_search`` (a search that
  does not depend on the number of workers or on thread timing; without the subsolver
  :data:`CPSAT_INTERLEAVED_SKIP`, and without the model's hint); ``max_time_in_seconds``
  becomes the wall-clock guard
  only.  After the solve, its reported deterministic time is charged.
* **HiGHS** is stopped by its interrupt callback (:class:`HighsMeter`), which charges the
  branch-and-bound nodes and callbacks since the last call to the caller's effort clock and
  compares it with the deadline; HiGHS' own ``time_limit`` becomes the wall-clock guard.
  After the run, the simplex iterations and the matrix size are charged.

Every charge goes to the clock object captured where the solve starts, not to the context
variable, so a callback run on another thread charges the right clock.
"""

from __future__ import annotations

import time

from models import clock

__all__ = [
    "BNB_NODE_S", "BNB_TABLE_BIT_S", "BNB_TABLE_ROW_S", "CLIQUE_CELL_S", "CLIQUE_DISC_S", "CLIQUE_STEP_S",
    "CONFIGURATION_BUILD_S", "CPSAT_DETERMINISTIC_S", "CPSAT_INTERLEAVED_SKIP", "CPSAT_LITERAL_S", "CPSAT_SOLVE_S",
    "HIGHS_CALLBACK_NONZERO_S", "HIGHS_MIP_NODE_S", "HIGHS_NONZERO_S", "HIGHS_RUN_S", "HIGHS_SIMPLEX_ITERATION_S",
    "INCOMPATIBILITY_WORK_S", "LP_CELL_S", "LP_SOLVE_S", "MODEL_COLUMN_S", "MODEL_NONZERO_S", "PRUNE_PROBE_S",
    "REPAIR_STEP_S", "SEMIGREEDY_ITERATION_S", "SEMIGREEDY_PASS_S", "SEMIGREEDY_PREPARE_COLUMN_S", "TABU_CELL_S",
    "TABU_MOVE_S", "VERIFY_CONFIGURATION_S", "HighsMeter", "WALL_GUARD_FACTOR", "WALL_GUARD_MIN_S",
    "charge_literals", "cpsat_solve", "interrupt_at", "wall_guard_s",
]

# the interleaved search of OR-Tools 9.15 aborts the process (``Check failed:
# heuristics.fixed_search != nullptr``) on some models with an incomplete hint (an
# infeasible exact-cover packing with the sequence as hint), in this subsolver and in others:
# it runs without this one, and every model is solved without its hint (:func:`cpsat_solve`)
CPSAT_INTERLEAVED_SKIP = "max_lp"
SIMPLEX_INTERRUPT = 1  # highspy.cb.HighsCallbackType.kCallbackSimplexInterrupt, as the callback gets it
# without a wall-clock guard on the effort clock, an engine still stops after this many
# times its budget (plus WALL_GUARD_MIN_S) of real seconds: a limit no healthy run reaches
WALL_GUARD_FACTOR = 20.0
WALL_GUARD_MIN_S = 10.0

# ------------------------------------------------------------ costs of the allocator's work
# (reference seconds; see the module's docstring for how they are measured)
# bitset branch-and-bound (solvers.allocation.bitset)
BNB_NODE_S = 9e-6  # one node of the depth-first search
BNB_TABLE_BIT_S = 0.55e-9  # one bit of the per-arm conflict bitsets built for the search
BNB_TABLE_ROW_S = 0.8e-6  # one (location, arm) bitset turned into a Python int
PRUNE_PROBE_S = 3e-6  # one column probed by the exact column pruning
# the exact model (solvers.model, solvers.allocation.cliques, solvers.allocation.exact)
MODEL_NONZERO_S = 0.02e-6  # one non-zero of the model arrays built
MODEL_COLUMN_S = 0.25e-6  # one column of the model arrays built
CLIQUE_STEP_S = 4e-6  # one column added to a greedy clique
CLIQUE_DISC_S = 5e-6  # one seed disc of the clique rows
CLIQUE_CELL_S = 1e-9  # one cell of the dense exclusion matrix read or built
# OR-Tools CP-SAT (every model of solvers/)
CPSAT_LITERAL_S = 0.4e-6  # one literal added to a model from Python
CPSAT_DETERMINISTIC_S = 0.5  # one unit of CP-SAT's deterministic time
CPSAT_SOLVE_S = 5e-3  # the fixed cost of one solve (setup, presolve bookkeeping)
# HiGHS (solvers.allocation.highs, exact.relaxation_bound)
HIGHS_RUN_S = 0.5e-3  # the fixed cost of one run
HIGHS_NONZERO_S = 0.1e-6  # one non-zero of the matrix passed to HiGHS
HIGHS_SIMPLEX_ITERATION_S = 10e-6  # one simplex iteration (LP or inside the MIP)
HIGHS_MIP_NODE_S = 0.5e-3  # one branch-and-bound node
HIGHS_CALLBACK_NONZERO_S = 0.9e-6  # per non-zero of the matrix, the MIP work between two callbacks
# semi-greedy heuristic (solvers.allocation.semigreedy)
SEMIGREEDY_PREPARE_COLUMN_S = 0.35e-6  # one assignment in the per-configuration preparation
SEMIGREEDY_ITERATION_S = 0.65e-3  # one construction + padding
SEMIGREEDY_PASS_S = 0.14e-3  # one local-search pass
# sequencing post-passes (solvers.sequencing)
TABU_MOVE_S = 30e-6  # one move of the packing tabu search
TABU_CELL_S = 2.5e-9  # one cell of the cost arrays a move reads or updates
REPAIR_STEP_S = 90e-6  # one frontier target expanded by an ejection chain
LP_SOLVE_S = 1e-3  # one master LP of the column generation (scipy HiGHS) ...
LP_CELL_S = 25e-9  # ... and per cell of its dense matrix
VERIFY_CONFIGURATION_S = 1e-3  # one configuration checked on the geometry
CONFIGURATION_BUILD_S = 0.3e-3  # one configuration turned into its result record
#: the incompatibility structure (models.incompatibility), as (per call, per unit) of
#: ``clock.work(kind, units)``
INCOMPATIBILITY_WORK_S: dict[str, tuple[float, float]] = {
    "incompatibility_pair": (0.0, 0.03e-6),  # unit: candidate pair of locations checked
    "incompatibility_assignment": (0.0, 30e-6),  # unit: reachable location built (reach, bodies)
    "incompatibility_found_pair": (0.0, 0.075e-6),  # unit: incompatible pair stored (CSR assembly)
    "incompatibility_blank": (0.0, 0.65e-3),  # unit: blank-sky pose sampled for an arm
}

clock.register_work_costs(INCOMPATIBILITY_WORK_S)


def wall_guard_s(budget_s: float, effort: clock.EffortClock | None = None) -> float:
    """Real seconds an engine may run in effort mode: what is left before the effort
    clock's wall-clock guard (at least 1 ms), else a generous multiple of ``budget_s``."""
    effort = effort if effort is not None else clock.effort_clock()
    if effort is not None and effort.wall_end is not None:
        return max(effort.wall_end - time.perf_counter(), 1e-3)
    return WALL_GUARD_FACTOR * max(float(budget_s), 0.0) + WALL_GUARD_MIN_S


def charge_literals(n_literals: int) -> None:
    """Charge the Python-side building of a CP-SAT model of ``n_literals`` literals."""
    clock.charge(n_literals * CPSAT_LITERAL_S)


def cpsat_solve(solver, model, time_limit_s: float):
    """``solver.Solve(model)`` within ``time_limit_s``: seconds on the wall clock; in effort
    mode a deterministic limit, an interleaved search and the wall guard, then the solve's
    deterministic time charged.  The caller sets every other parameter (``num_workers`` >= 2
    and ``random_seed`` included).  Returns the status code."""
    p = solver.parameters
    limit_s = max(float(time_limit_s), 0.0)
    effort = clock.effort_clock()
    if effort is None:
        p.max_time_in_seconds = limit_s
        return solver.Solve(model)
    p.max_deterministic_time = limit_s / CPSAT_DETERMINISTIC_S
    model.ClearHints()  # see CPSAT_INTERLEAVED_SKIP
    p.interleave_search = True
    if CPSAT_INTERLEAVED_SKIP not in p.ignore_subsolvers:
        p.ignore_subsolvers.append(CPSAT_INTERLEAVED_SKIP)
    p.max_time_in_seconds = wall_guard_s(limit_s, effort)
    code = solver.Solve(model)
    effort.t_s += CPSAT_SOLVE_S + float(solver.response_proto.deterministic_time) * CPSAT_DETERMINISTIC_S
    return code


class HighsMeter:
    """The work of one HiGHS run on the effort clock current when it was made.

    :meth:`now` reads that clock (the wall clock outside effort); :meth:`on_callback`
    charges what each interrupt callback reports (simplex iterations; inside the MIP search,
    where HiGHS reports no iterations, the nodes and the callbacks themselves);
    :meth:`finish` charges the rest of the run from HiGHS' final counts (simplex
    iterations, nodes, matrix size)."""

    def __init__(self, nnz: int = 0) -> None:
        self.effort = clock.effort_clock()
        self.nnz = int(nnz)
        self.nodes = 0
        self.callbacks = 0
        self.lp_its = 0  # the current LP solve's iteration count, at the last simplex callback
        self.iterations = 0  # simplex iterations charged by the callbacks
        self.charged_s = 0.0

    def _charge(self, t_s: float) -> None:
        self.charged_s += t_s
        self.effort.t_s += t_s

    def now(self) -> float:
        return time.perf_counter() if self.effort is None else self.effort.read()

    def on_callback(self, callback_type, data_out) -> None:
        """Charge what an interrupt callback of ``callback_type`` reports: in the simplex
        the iterations since the previous one (HiGHS counts them per LP solve), in the MIP
        search the nodes since the previous one plus the work between two callbacks (which grows with
        the matrix: HiGHS reports no iterations there)."""
        if self.effort is None:
            return
        if int(callback_type) == SIMPLEX_INTERRUPT:
            its = int(getattr(data_out, "simplex_iteration_count", 0) or 0)
            new_its = its - self.lp_its if its >= self.lp_its else max(its, 0)
            self.lp_its = max(its, 0)
            self.iterations += new_its
            self._charge(new_its * HIGHS_SIMPLEX_ITERATION_S)
            return
        self.callbacks += 1
        nodes = max(int(getattr(data_out, "mip_node_count", 0) or 0), 0)
        new_nodes = max(nodes - self.nodes, 0)
        self.nodes = max(nodes, self.nodes)
        self._charge(self.nnz * HIGHS_CALLBACK_NONZERO_S + new_nodes * HIGHS_MIP_NODE_S)

    def finish(self, info) -> None:
        """Charge the run's own counts (``info``: ``Highs.getInfo()``) beyond the callbacks'."""
        if self.effort is None:
            return
        its = max(int(info.simplex_iteration_count), 0) + max(int(info.ipm_iteration_count), 0)
        nodes = max(int(info.mip_node_count), 0)
        self._charge(HIGHS_RUN_S + self.nnz * HIGHS_NONZERO_S
                     + max(its - self.iterations, 0) * HIGHS_SIMPLEX_ITERATION_S
                     + max(nodes - self.nodes, 0) * HIGHS_MIP_NODE_S)

    def wall_guard_s(self, budget_s: float) -> float:
        return wall_guard_s(budget_s, self.effort)


def interrupt_at(h, deadline: float, meter: HighsMeter | None = None) -> list[bool]:
    """Stop the HiGHS instance ``h`` at ``deadline`` (a :func:`models.clock.now` instant)
    inside its simplex, IPM and MIP loops (their interrupt callbacks), not only where HiGHS
    checks its own ``time_limit``.  ``meter`` (default: one made here, on the caller's
    clock) charges the work each callback reports to the effort clock and reads it, so
    that in effort mode the run stops after the same work on any machine.  Returns a
    one-element flag, set when the callback stopped the run."""
    import highspy

    fired = [False]
    meter = HighsMeter() if meter is None else meter

    def callback(callback_type, message, data_out, data_in, user_data):
        if data_in is None:
            return
        meter.on_callback(callback_type, data_out)
        if meter.now() > deadline:
            data_in.user_interrupt = True
            fired[0] = True

    h.setCallback(callback, None)
    kinds = highspy.cb.HighsCallbackType
    for kind in (kinds.kCallbackSimplexInterrupt, kinds.kCallbackIpmInterrupt, kinds.kCallbackMipInterrupt):
        h.startCallback(kind)
    return fired
