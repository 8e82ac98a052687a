"""Motion-planning benchmark on the allocations users meet (thesis 6.4.2 protocol): prints JSON.

What it measures: how :func:`planner.plan_motion` does on the legs of real allocator output,
park -> c1 -> c2 -> ... -> cn -> park, and how often a whole field ends up executable through
the plan's own per-pointing function, :func:`planner.programme.plan_pointing`.

Protocol "thesis" (the default; Sabater 2019, 6.4.2: 200 prioritised SGPBTA assignment plans,
97 % of park -> targets and 93 % of chained plans in one pass, median configuration time
102.55 s, goal <= 120 s):

* ``--fields`` fields of ``--targets`` targets in the 250 mm FOV; field i is seeded with
  ``np.random.default_rng([seed, i])``; its shape cycles over uniform and Gaussian clusters
  about the centre (sigma 40, 60, 90 mm, clipped to the FOV); priorities 10 % 500,
  40 % 100, 40 % 10, 10 % 1 (thesis 5.5.3).
* every method of ``--methods`` (``ilp``: the exact allocator with the bnb solver;
  ``semigreedy``: SGPBTA) plans each field as a single-pointing plan does: one call of
  ``plan_pointing`` (allocation with every configuration, then the executable motion sequence
  ``planner.sequence.plan_sequence``, on the effort clock) at the share a one-pointing plan gets
  at the plan's limit ``--time-limit`` (default 120 s, as ``POST /v1/plans`` and the CLI:
  ``pointing_shares(limit, [pointing_need(targets)])[0]``), with the seed of its first pointing
  and the allocation's park move limit ``--park-move-limit`` (default 120 s, as
  ``PlanRequest.park_move_limit_s``; ``none``, the allocator's own default, is a secondary row:
  some moves from park then need up to 200 s).
* legs, planner alone: the configurations of that pointing's allocation (the first
  ``--max-configurations`` of them), each leg ``plan_motion(instrument, start_q, goal_q,
  seed=seed, time_budget_s=leg_budget)`` with the planner's defaults otherwise (thesis table
  6.1). A leg starts where the previous one ended (the last way-point of every arm), or at its
  intended goal after a failed leg; park -> c_i is planned for every other configuration too.

Reported per method and per leg kind ("park_to_configuration": leg 0 and park -> c_i,
"chained": c_i -> c_(i+1), "to_park": the last leg): legs, success rate, compute time
(median, p90, p99, max), makespan (median; ratio to the lower bound max_k direct-move time,
median and p90; share <= 120 s), stops per arm (max, mean), strategies, the failed legs and
the five slowest legs with the strategy that planned them. For the whole field: the share of
fields with no failed leg (a) with the planner alone and (b) in the pointing's plan
(``plan_pointing``: every configuration, with the changes ``plan_sequence`` makes where a leg
fails: legs through park, moved targets, new configurations), with its wall time, its effort
seconds and the wall time of its allocation.

Protocol "easy" (secondary, a lighter load than users meet): fields of 100 uniform targets,
all of priority 1, drawn one after another from ``np.random.default_rng(seed)``; the first
configuration of each (``allocate(..., configurations="one")`` with the time a pointing's plan
gives its allocation); legs park -> c_i and, across fields, chained c_i -> c_(i+1).

Usage:
    python benchmarks/motion.py                      # thesis protocol, 20 fields, both methods
    python benchmarks/motion.py --smoke              # 2 fields, 60 targets, 2 configurations, 10 s limit
    python benchmarks/motion.py --fields 100 --methods semigreedy --out motion.json
    python benchmarks/motion.py --save-legs failed_legs.npz   # start/goal of failed legs
    python benchmarks/motion.py --protocol easy --fields 200
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import planner.programme as programme  # noqa: E402
from benchmarks.motion_fields import easy_field, thesis_field, thesis_field_parameters  # noqa: E402
from models.instrument import CONFIGURATION_TIME_GOAL_S, Instrument, default_instrument  # noqa: E402
from models.kinematics import positive_turn_move_time_s  # noqa: E402
from models.types import AllocationResult, MotionPlan, PlaneTargets  # noqa: E402
from planner import MotionOptions, plan_motion, stop_count  # noqa: E402
from planner.programme import PointingOptions, PointingPlan, plan_pointing  # noqa: E402
from solvers.allocation import allocate  # noqa: E402
from solvers.allocation.options import AllocationOptions  # noqa: E402

MAKESPAN_GOAL_S = CONFIGURATION_TIME_GOAL_S
INSTRUMENT = default_instrument()
LEG_KINDS = ("park_to_configuration", "chained", "to_park")
THESIS_REFERENCE = {
    "park_to_configuration": {"success_rate": 0.97, "makespan_s_median": 102.55,
                              "makespan_s_range": [96.0, 114.0]},
    "chained": {"success_rate": 0.93, "makespan_s_median": 90.6, "makespan_s_max": 108.0},
}
SMOKE = {"fields": 2, "targets": 60, "max_configurations": 2, "leg_budget": 3.0, "time_limit": 10.0}
DEFAULTS = {"fields": 20, "targets": 150, "max_configurations": None, "leg_budget": 10.0,
            "time_limit": programme.DEFAULT_LIMIT_S}
EASY_TARGETS = 100


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------- legs


@dataclass(frozen=True)
class LegRecord:
    """One planned leg and what the benchmark reports of it."""

    method: str
    field: int
    leg: int
    kind: str
    status: str
    compute_s: float
    makespan_s: float
    lower_bound_s: float
    stops_per_arm: tuple[int, ...]
    strategy: str | None
    failed_arms: tuple[int, ...]
    start_q: np.ndarray
    goal_q: np.ndarray

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def plan_end_q(plan: MotionPlan, goal_q: np.ndarray) -> np.ndarray:
    """Where the arms really are after ``plan``: the last way-points; the goal if it failed."""
    if plan.status != "ok":
        return np.array(goal_q, float)
    end_q = np.array(goal_q, float)
    for tr in plan.trajectories:
        end_q[tr.arm] = (tr.theta1_rad[-1], tr.theta2_rad[-1])
    return end_q


def plan_leg(instrument: Instrument, start_q: np.ndarray, goal_q: np.ndarray, *, method: str,
             field: int, leg: int, kind: str, seed: int,
             leg_budget_s: float) -> tuple[LegRecord, np.ndarray]:
    t0 = time.perf_counter()
    plan = plan_motion(instrument, start_q, goal_q, seed=seed, time_budget_s=leg_budget_s)
    compute_s = time.perf_counter() - t0
    stops = tuple(int(stop_count(tr.t_s, tr.theta1_rad, tr.theta2_rad))
                  for tr in plan.trajectories) if plan.status == "ok" else ()
    strategy = plan.stats.get("strategy")
    record = LegRecord(method, field, leg, kind, plan.status, compute_s, float(plan.makespan_s),
                       float(plan.stats["lower_bound_s"]), stops,
                       None if strategy is None else str(strategy),
                       tuple(int(a) for a in plan.failed_arms),
                       np.array(start_q, float), np.array(goal_q, float))
    return record, plan_end_q(plan, goal_q)


def leg_kind(leg: int, n_legs: int) -> str:
    if leg == n_legs - 1:
        return "to_park"
    return "park_to_configuration" if leg == 0 else "chained"


def plan_field_legs(instrument: Instrument, configurations_q: Sequence[np.ndarray], *, method: str,
                    field: int, seed: int, leg_budget_s: float) -> list[LegRecord]:
    """Legs park -> c1 -> ... -> cn -> park, each from where the previous one ended, then
    park -> c_i for every other configuration."""
    park_q = instrument.park_configuration
    goals = [*configurations_q, park_q]
    current_q = park_q
    records = []
    for leg, goal_q in enumerate(goals):
        record, current_q = plan_leg(instrument, current_q, goal_q, method=method, field=field,
                                     leg=leg, kind=leg_kind(leg, len(goals)), seed=seed,
                                     leg_budget_s=leg_budget_s)
        records.append(record)
    # park -> every other configuration too (thesis 6.4.2: park -> targets for every
    # assignment plan); leg index -i marks park -> c_(i+1) planned outside the chain
    for i, goal_q in enumerate(configurations_q[1:], start=1):
        record, _ = plan_leg(instrument, park_q, goal_q, method=method, field=field, leg=-i,
                             kind="park_to_configuration", seed=seed, leg_budget_s=leg_budget_s)
        records.append(record)
    return records


# ---------------------------------------------------------------------- statistics


def _pct(values: Sequence[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def _max(values: Sequence[float]) -> float | None:
    return float(np.max(values)) if len(values) else None


SLOWEST_LEGS = 5  # per leg kind, reported with their strategy


def leg_summary(records: Sequence[LegRecord]) -> dict:
    ok = [r for r in records if r.ok]
    compute_s = [r.compute_s for r in records]
    makespan_s = [r.makespan_s for r in ok]
    ratio = [r.makespan_s / r.lower_bound_s for r in ok if r.lower_bound_s > 0]
    stops = [s for r in ok for s in r.stops_per_arm]
    return {
        "legs": len(records),
        "success_rate": len(ok) / len(records) if records else None,
        "compute_s_median": _pct(compute_s, 50),
        "compute_s_p90": _pct(compute_s, 90),
        "compute_s_p99": _pct(compute_s, 99),
        "compute_s_max": _max(compute_s),
        "makespan_s_median": _pct(makespan_s, 50),
        "makespan_over_lower_bound_median": _pct(ratio, 50),
        "makespan_over_lower_bound_p90": _pct(ratio, 90),
        "makespan_le_120s_rate": (float(np.mean(np.array(makespan_s) <= MAKESPAN_GOAL_S))
                                  if makespan_s else None),
        "over_120s": over_120s(ok),
        "stops_per_arm_max": int(max(stops)) if stops else None,
        "stops_per_arm_mean": float(np.mean(stops)) if stops else None,
        "strategy_counts": dict(sorted(Counter(str(r.strategy) for r in ok).items())),
        "failed_legs": [{"field": r.field, "leg": r.leg, "failed_arms": list(r.failed_arms)}
                        for r in records if not r.ok],
        # the compute tail (the p99 goal): which legs, and which strategy planned them
        "slowest_legs": [{"field": r.field, "leg": r.leg, "compute_s": round(r.compute_s, 2), "status": r.status,
                          "strategy": r.strategy, "makespan_s": round(r.makespan_s, 1)}
                         for r in sorted(records, key=lambda r: -r.compute_s)[:SLOWEST_LEGS]],
    }


def positive_sense_s(start_q: np.ndarray, goal_q: np.ndarray) -> np.ndarray:
    """Each arm's straight move time turning theta2 in the positive sense only (the default
    instrument's joint speeds)."""
    return positive_turn_move_time_s(start_q, goal_q, INSTRUMENT.arm_array("joint1_speed_rad_s"),
                                     INSTRUMENT.arm_array("joint2_speed_rad_s"))


def over_120s(ok: Sequence[LegRecord]) -> dict:
    """The planned legs longer than 120 s, and among those from park the ones where some arm's
    goal lies more than 120 s of theta2 travel ahead in the positive sense (from park an arm
    turning the negative way sweeps through its next neighbour: docs/motion.md)."""
    long = [r for r in ok if r.makespan_s > MAKESPAN_GOAL_S]
    park = INSTRUMENT.park_configuration
    from_park = [r for r in long if np.allclose(r.start_q, park)]
    beyond = [r for r in from_park if positive_sense_s(r.start_q, r.goal_q).max() > MAKESPAN_GOAL_S]
    return {"legs": len(long), "from_park": len(from_park), "from_park_arm_beyond_positive_reach": len(beyond)}


def summaries_by_kind(records: Sequence[LegRecord], kinds: Sequence[str]) -> dict:
    out = {kind: leg_summary([r for r in records if r.kind == kind]) for kind in kinds}
    first = [r for r in records if r.kind == "park_to_configuration" and r.leg == 0]
    if "park_to_configuration" in out and first:  # the first leg of each field's sequence alone
        s = leg_summary(first)
        out["park_to_configuration"]["first_configuration"] = {
            k: s[k] for k in ("legs", "success_rate", "makespan_le_120s_rate")}
    return out


def fields_without_failed_legs(records: Sequence[LegRecord], n_fields: int) -> dict:
    failed_fields = {r.field for r in records if not r.ok and r.leg >= 0}  # the chain's legs
    n_ok = n_fields - len(failed_fields)
    return {"fields": n_fields, "fields_without_failed_legs": n_ok,
            "share": n_ok / n_fields if n_fields else None}


# ---------------------------------------------------------------------- plan_pointing


@dataclass(frozen=True)
class PointingRecord:
    """One field's plan through ``plan_pointing`` and what the benchmark reports of it."""

    field: int
    executable: bool
    wall_s: float
    allocation_s: float  # wall time until the allocation was done (the plan's progress 0.5)
    effort_s: float
    overran: bool
    legs: int
    failed_legs: int
    changes_by_kind: dict[str, int]
    targets_moved: int
    configurations_added: int
    targets_dropped: int
    unplanned_reason: str | None


def pointing_record(pointing: PointingPlan, *, field: int, wall_s: float,
                    allocation_s: float) -> PointingRecord:
    seq = pointing.sequence
    allocated = () if pointing.allocation is None else pointing.allocation.configurations
    kinds = Counter(c.kind for c in seq.changes)
    moved = sum(len(c.target_ids) for c in seq.changes if c.kind == "moved_target")
    # a pointing not attempted, or whose legs were not planned, has no executable plan
    executable = pointing.allocation is not None and pointing.executable
    return PointingRecord(field, executable, wall_s, allocation_s, float(pointing.effort_s),
                          bool(pointing.overran), len(seq.legs), len(seq.failed_legs),
                          dict(sorted(kinds.items())), moved,
                          len(seq.configurations) - len(allocated), len(seq.dropped),
                          pointing.unplanned_reason)


def run_plan_pointing(instrument: Instrument, targets: PlaneTargets, options: PointingOptions,
                      share_s: float, *, field: int) -> tuple[PointingPlan, PointingRecord]:
    """One field as a single-pointing plan plans it; the allocation's wall time is read from
    the plan's progress (0.5 once the allocation is done)."""
    t0 = time.perf_counter()
    marks: dict[str, float] = {}

    def progress(p: float) -> None:
        if p >= 0.5 and "allocation_s" not in marks:
            marks["allocation_s"] = time.perf_counter() - t0

    pointing = plan_pointing(instrument, targets, options, share_s, progress)
    wall_s = time.perf_counter() - t0
    return pointing, pointing_record(pointing, field=field, wall_s=wall_s,
                                     allocation_s=marks.get("allocation_s", wall_s))


def pointing_summary(records: Sequence[PointingRecord]) -> dict:
    kinds: Counter[str] = Counter()
    for r in records:
        kinds.update(r.changes_by_kind)
    n_exec = sum(r.executable for r in records)
    # a pointing that reached its wall-clock share reports no meaningful effort (models.clock)
    effort_s = [r.effort_s for r in records if not r.overran]
    return {
        "fields": len(records),
        "fields_executable": n_exec,
        "share": n_exec / len(records) if records else None,
        "legs": sum(r.legs for r in records),
        "legs_failed": sum(r.failed_legs for r in records),
        "changes_by_kind": dict(sorted(kinds.items())),
        "targets_moved": sum(r.targets_moved for r in records),
        "legs_through_park": kinds.get("via_park", 0),
        "configurations_added": sum(r.configurations_added for r in records),
        "targets_dropped": sum(r.targets_dropped for r in records),
        "wall_s_median": _pct([r.wall_s for r in records], 50),
        "wall_s_max": _max([r.wall_s for r in records]),
        "effort_s_median": _pct(effort_s, 50),
        "effort_s_max": _max(effort_s),
        "overran": sum(r.overran for r in records),
        "fields_not_executable": [{"field": r.field, "failed_legs": r.failed_legs,
                                   "unplanned_reason": r.unplanned_reason}
                                  for r in records if not r.executable],
    }


# ---------------------------------------------------------------------- protocols


@dataclass(frozen=True)
class Params:
    protocol: str
    fields: int
    seed: int
    methods: tuple[str, ...]
    targets: int
    leg_budget_s: float
    time_limit_s: float
    max_configurations: int | None
    smoke: bool
    park_move_limit_s: float | None = CONFIGURATION_TIME_GOAL_S

    def allocation_options(self) -> AllocationOptions:
        """What the plan pipeline passes (``PlanRequest.park_move_limit_s``, default T_p)."""
        return programme.allocation_options(self.park_move_limit_s)

    def pointing_share_s(self, n_targets: int) -> float:
        """The share of a single-pointing plan of ``n_targets`` at the plan's limit."""
        return programme.pointing_shares(self.time_limit_s, [programme.pointing_need(n_targets)])[0]

    def pointing_options(self, method: str) -> PointingOptions:
        """A single-pointing plan's options: its first pointing's seed, the pipeline's limit."""
        return PointingOptions(method=method, solver="bnb", seed=programme.pointing_seed(self.seed, 0),
                               park_move_limit_s=self.park_move_limit_s)

    def allocation_limit_s(self, n_targets: int) -> float:
        """The effort seconds ``plan_pointing`` gives a pointing's allocation (the easy protocol's
        single-configuration allocations get as much)."""
        return programme.SHARES.effort_share * programme.SHARES.allocation_share * self.pointing_share_s(n_targets)


def allocation_summary(results: Sequence[AllocationResult], alloc_s: Sequence[float]) -> dict:
    counts = [len(r.configurations) for r in results]
    return {
        "fields": len(results),
        "configurations_median": _pct(counts, 50),
        "configurations_max": int(max(counts)) if counts else None,
        "field_completeness_mean": (float(np.mean([r.stats.get("field_completeness", np.nan)
                                                   for r in results])) if results else None),
        "unallocated_mean": float(np.mean([len(r.unallocated) for r in results])) if results else None,
        "beyond_park_move_limit_mean": (float(np.mean([r.stats.get("n_beyond_park_move_limit", 0)
                                                       for r in results])) if results else None),
        "priority_completeness_mean": (float(np.mean([r.stats.get("priority_completeness", np.nan)
                                                      for r in results])) if results else None),
        "allocation_s_median": _pct(alloc_s, 50),
        "allocation_s_max": _max(alloc_s),
    }


def planned_configurations(pointing: PointingPlan, max_configurations: int | None) -> list[np.ndarray]:
    """The joint angles of the pointing's allocation, the first ``max_configurations`` of them."""
    configurations = () if pointing.allocation is None else pointing.allocation.configurations
    return [c.q for c in configurations[:max_configurations]]


def thesis_method(instrument: Instrument, params: Params, method: str) -> dict:
    legs: list[LegRecord] = []
    pointings: list[PointingRecord] = []
    results, shapes = [], []
    share_s = params.pointing_share_s(params.targets)
    for i in range(params.fields):
        shape, targets = thesis_field(params.targets, params.seed, i)
        pointing, record = run_plan_pointing(instrument, targets, params.pointing_options(method),
                                             share_s, field=i)
        pointings.append(record)
        shapes.append(shape)
        if pointing.allocation is not None:
            results.append(pointing.allocation)
        configurations_q = planned_configurations(pointing, params.max_configurations)
        field_legs = plan_field_legs(instrument, configurations_q, method=method, field=i,
                                     seed=params.seed, leg_budget_s=params.leg_budget_s)
        legs.extend(field_legs)
        n_conf = 0 if pointing.allocation is None else len(pointing.allocation.configurations)
        log(f"[{method}] field {i} ({shape}): {n_conf} configurations, allocation "
            f"{record.allocation_s:.1f} s; plan_pointing executable={record.executable} in {record.wall_s:.1f} s "
            f"({'overran its share' if record.overran else f'{record.effort_s:.1f} effort-s'}); "
            f"{len(field_legs)} legs planned alone, {sum(not r.ok for r in field_legs)} failed")
    return {
        "allocation": {**allocation_summary(results, [r.allocation_s for r in pointings]),
                       "shapes": shapes},
        "legs": summaries_by_kind(legs, LEG_KINDS),
        "whole_field": {
            "planner_alone": fields_without_failed_legs(legs, params.fields),
            "plan_pointing": {"share_s": share_s, **pointing_summary(pointings)},
        },
        "_records": legs,
    }


def easy_method(instrument: Instrument, params: Params, method: str) -> dict:
    """Secondary protocol: first configuration of uniform priority-1 fields."""
    rng = np.random.default_rng(params.seed)
    fields = [easy_field(EASY_TARGETS, rng) for _ in range(params.fields)]
    park_q = instrument.park_configuration
    results, alloc_s, configurations_q = [], [], []
    for targets in fields:
        t0 = time.perf_counter()
        result = allocate(instrument, targets, method=method, solver="bnb", configurations="one",
                          options=params.allocation_options(),
                          time_limit_s=params.allocation_limit_s(EASY_TARGETS), seed=params.seed)
        alloc_s.append(time.perf_counter() - t0)
        results.append(result)
        configurations_q.append(result.configurations[0].q if result.configurations else park_q)
    legs: list[LegRecord] = []
    current_q = park_q
    for i, goal_q in enumerate(configurations_q):
        record, end_q = plan_leg(instrument, park_q, goal_q, method=method, field=i, leg=0,
                                 kind="park_to_configuration", seed=params.seed,
                                 leg_budget_s=params.leg_budget_s)
        legs.append(record)
        if i == 0:
            current_q = end_q
            continue
        record, current_q = plan_leg(instrument, current_q, goal_q, method=method, field=i, leg=1,
                                     kind="chained", seed=params.seed,
                                     leg_budget_s=params.leg_budget_s)
        legs.append(record)
        log(f"[easy {method}] field {i}: chained {record.status}")
    return {
        "allocation": allocation_summary(results, alloc_s),
        "legs": summaries_by_kind(legs, LEG_KINDS[:2]),
        "_records": legs,
    }


# ---------------------------------------------------------------------- output


def git_commit() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                             text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def planner_defaults() -> dict:
    """The planning options the benchmark leaves at their defaults (thesis table 6.1)."""
    o = MotionOptions()
    out = {f.name: getattr(o, f.name) for f in dataclasses.fields(o)}
    return json.loads(json.dumps(out, default=lambda v: list(v) if isinstance(v, tuple) else str(v)))


def save_failed_legs(path: Path, records: Sequence[LegRecord], n_arms: int, seed: int) -> None:
    failed = [r for r in records if not r.ok]
    shape = (len(failed), n_arms, 2)
    np.savez(path,
             start_q=np.array([r.start_q for r in failed], float).reshape(shape),
             goal_q=np.array([r.goal_q for r in failed], float).reshape(shape),
             method=np.array([r.method for r in failed], dtype=str),
             field=np.array([r.field for r in failed], dtype=np.int64),
             leg=np.array([r.leg for r in failed], dtype=np.int64),
             kind=np.array([r.kind for r in failed], dtype=str),
             seed=np.int64(seed))


def parse_args(argv: list[str] | None) -> tuple[Params, Path | None, Path | None]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", choices=("thesis", "easy"), default="thesis")
    ap.add_argument("--fields", type=int, default=None, help="fields per method (default 20)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--methods", default="ilp,semigreedy", help="comma-separated allocate methods")
    ap.add_argument("--targets", type=int, default=None, help="targets per field (default 150)")
    ap.add_argument("--leg-budget", type=float, default=None,
                    help="plan_motion time_budget_s per leg (default 10)")
    ap.add_argument("--time-limit", type=float, default=None, metavar="S",
                    help="the plan's limit, s: each field is planned with the share a single-pointing "
                    "plan gets at it (default 120, as POST /v1/plans and the CLI)")
    ap.add_argument("--max-configurations", type=int, default=None,
                    help="plan only the first K configurations of each field (default: all)")
    ap.add_argument("--smoke", action="store_true",
                    help="2 fields, 60 targets, 2 configurations, 3 s per leg, a 10 s plan limit "
                    "(explicit options win)")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON to this file")
    ap.add_argument("--park-move-limit", default=str(CONFIGURATION_TIME_GOAL_S), metavar="S",
                    help="the allocation's park move limit, s, as the plan pipeline sets it (default "
                    "120, PlanRequest.park_move_limit_s); 'none': no limit (secondary)")
    ap.add_argument("--save-legs", type=Path, default=None,
                    help=".npz file for the start/goal joint angles of every failed leg")
    args = ap.parse_args(argv)
    base = SMOKE if args.smoke else DEFAULTS

    def pick(name: str):
        value = getattr(args, name)
        return base[name] if value is None else value

    params = Params(protocol=args.protocol, fields=pick("fields"), seed=args.seed,
                    methods=tuple(m for m in args.methods.split(",") if m),
                    targets=pick("targets"), leg_budget_s=float(pick("leg_budget")),
                    time_limit_s=float(pick("time_limit")),
                    max_configurations=pick("max_configurations"), smoke=args.smoke,
                    park_move_limit_s=None if args.park_move_limit.lower() == "none"
                    else float(args.park_move_limit))
    if params.fields < 1 or params.targets < 1 or not params.methods or params.time_limit_s <= 0:
        ap.error("--fields, --targets, --time-limit must be positive and --methods non-empty")
    if params.max_configurations is not None and params.max_configurations < 1:
        ap.error("--max-configurations must be >= 1")
    return params, args.out, args.save_legs


def main(argv: list[str] | None = None) -> dict:
    params, out_path, legs_path = parse_args(argv)
    load_start = list(os.getloadavg())
    t0 = time.perf_counter()
    instrument = default_instrument()
    commit = git_commit()  # the code being measured: read before the run, not after it
    run = thesis_method if params.protocol == "thesis" else easy_method
    methods, records = {}, []
    for method in params.methods:
        res = run(instrument, params, method)
        records.extend(res.pop("_records"))
        methods[method] = res
    out = {
        "benchmark": "motion",
        "protocol": params.protocol,
        "parameters": {
            "fields": params.fields, "seed": params.seed, "methods": list(params.methods),
            "targets": params.targets if params.protocol == "thesis" else EASY_TARGETS,
            "leg_budget_s": params.leg_budget_s, "time_limit_s": params.time_limit_s,
            "pointing_share_s": params.pointing_share_s(
                params.targets if params.protocol == "thesis" else EASY_TARGETS),
            "max_configurations": params.max_configurations, "smoke": params.smoke,
            "park_move_limit_s": params.park_move_limit_s,
            "ilp_solver": "bnb",
            **(thesis_field_parameters() if params.protocol == "thesis"
               else {"field_shapes": ["uniform"], "priority_mix": {"1": 1.0}}),
            "plan_motion_defaults": planner_defaults(),
        },
        "commit": commit,
        "load_average_start": load_start,
        "methods": methods,
        "thesis_reference": THESIS_REFERENCE,
        "load_average_end": list(os.getloadavg()),
        "wall_s": time.perf_counter() - t0,
    }
    if legs_path is not None:
        save_failed_legs(legs_path, records, instrument.n_arms, params.seed)
    text = json.dumps(out, indent=1)
    if out_path is not None:
        out_path.write_text(text + "\n")
    print(text)
    return out


if __name__ == "__main__":
    main()
