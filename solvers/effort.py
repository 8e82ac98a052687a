"""The engines on the effort clock of :mod:`models.clock`: CP-SAT and HiGHS limits and charges.

On the wall clock (the default) both engines keep their limits in seconds, as before.
Inside :func:`models.clock.effort` their searches must stop at the same point whatever the
machine's load, so:

* **CP-SAT** runs on ``max_deterministic_time`` (the budget in reference seconds over
  :data:`~models.clock.CPSAT_DETERMINISTIC_S`) with ``interleave_search`` (a search that
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

__all__ = ["CPSAT_INTERLEAVED_SKIP", "HighsMeter", "WALL_GUARD_FACTOR", "WALL_GUARD_MIN_S", "charge_literals",
           "cpsat_solve", "wall_guard_s"]

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


def wall_guard_s(budget_s: float, effort: clock.EffortClock | None = None) -> float:
    """Real seconds an engine may run in effort mode: what is left before the effort
    clock's wall-clock guard (at least 1 ms), else a generous multiple of ``budget_s``."""
    effort = effort if effort is not None else clock.effort_clock()
    if effort is not None and effort.wall_end is not None:
        return max(effort.wall_end - time.perf_counter(), 1e-3)
    return WALL_GUARD_FACTOR * max(float(budget_s), 0.0) + WALL_GUARD_MIN_S


def charge_literals(n_literals: int) -> None:
    """Charge the Python-side building of a CP-SAT model of ``n_literals`` literals."""
    clock.charge(n_literals * clock.CPSAT_LITERAL_S)


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
    p.max_deterministic_time = limit_s / clock.CPSAT_DETERMINISTIC_S
    model.ClearHints()  # see CPSAT_INTERLEAVED_SKIP
    p.interleave_search = True
    if CPSAT_INTERLEAVED_SKIP not in p.ignore_subsolvers:
        p.ignore_subsolvers.append(CPSAT_INTERLEAVED_SKIP)
    p.max_time_in_seconds = wall_guard_s(limit_s, effort)
    code = solver.Solve(model)
    effort.t_s += clock.CPSAT_SOLVE_S + float(solver.response_proto.deterministic_time) * clock.CPSAT_DETERMINISTIC_S
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
            self._charge(new_its * clock.HIGHS_SIMPLEX_ITERATION_S)
            return
        self.callbacks += 1
        nodes = max(int(getattr(data_out, "mip_node_count", 0) or 0), 0)
        new_nodes = max(nodes - self.nodes, 0)
        self.nodes = max(nodes, self.nodes)
        self._charge(self.nnz * clock.HIGHS_CALLBACK_NONZERO_S + new_nodes * clock.HIGHS_MIP_NODE_S)

    def finish(self, info) -> None:
        """Charge the run's own counts (``info``: ``Highs.getInfo()``) beyond the callbacks'."""
        if self.effort is None:
            return
        its = max(int(info.simplex_iteration_count), 0) + max(int(info.ipm_iteration_count), 0)
        nodes = max(int(info.mip_node_count), 0)
        self._charge(clock.HIGHS_RUN_S + self.nnz * clock.HIGHS_NONZERO_S
                     + max(its - self.iterations, 0) * clock.HIGHS_SIMPLEX_ITERATION_S
                     + max(nodes - self.nodes, 0) * clock.HIGHS_MIP_NODE_S)

    def wall_guard_s(self, budget_s: float) -> float:
        return wall_guard_s(budget_s, self.effort)
