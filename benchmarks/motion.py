"""Motion-planning benchmark on the allocations users meet (thesis 6.4.2 protocol): prints JSON.

What it measures: how :func:`planner.plan_motion` does on the legs of real allocator output,
park -> c1 -> c2 -> ... -> cn -> park, and how often a whole field ends up executable.

Protocol "thesis" (the default; Sabater 2019, 6.4.2: 200 prioritised SGPBTA assignment plans,
97 % of park -> targets and 93 % of chained plans in one pass, median configuration time
102.55 s, goal <= 120 s):

* ``--fields`` fields of ``--targets`` targets in the 250 mm FOV; field i is seeded with
  ``np.random.default_rng([seed, i])``; its shape cycles over uniform and Gaussian clusters
  about the centre (sigma 40, 60, 90 mm, clipped to the FOV); priorities 10 % 500,
  40 % 100, 40 % 10, 10 % 1 (thesis 5.5.3).
* every method of ``--methods`` (``ilp``: the exact allocator with the bnb solver;
  ``semigreedy``: SGPBTA) allocates each field with
  ``solvers.allocation.allocate(..., configurations="all")`` and the options the plan
  pipeline passes: every location within ``--park-move-limit`` seconds of park (default
  120 s, as ``PlanRequest.park_move_limit_s``; ``none``, the allocator's own default, is a
  secondary row: some moves from park then need up to 200 s); the configurations planned
  are exactly those it returns (the first ``--max-configurations`` of them).
* each leg is ``plan_motion(instrument, start_q, goal_q, seed=seed, time_budget_s=leg_budget)``
  with the planner's defaults otherwise (thesis table 6.1). A leg starts where the previous
  one ended (the last way-point of every arm), or at its intended goal after a failed leg.

Reported per method and per leg kind ("park_to_configuration": leg 0, "chained":
c_i -> c_(i+1), "to_park": the last leg): legs, success rate, compute time (median, p90,
p99, max), makespan (median; ratio to the lower bound max_k direct-move time, median and
p90; share <= 120 s), stops per arm (max, mean), strategies, the failed legs and the five
slowest legs with the strategy that planned them. For the
whole field: the share of fields with no failed leg (a) with the planner alone and (b) through
``planner.sequence.plan_sequence``, which changes the plan (legs through park, moved targets,
new configurations) where a leg fails; (b) is ``{"available": false}`` when that function is
absent.

Protocol "easy" (secondary, a lighter load than users meet): fields of 100 uniform targets,
all of priority 1, drawn one after another from ``np.random.default_rng(seed)``; the first
configuration of each (``configurations="one"``); legs park -> c_i and, across fields,
chained c_i -> c_(i+1).

Usage:
    python benchmarks/motion.py                      # thesis protocol, 20 fields, both methods
    python benchmarks/motion.py --smoke              # 2 fields, 60 targets, 2 configurations
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

import planner.sequence as sequence_module  # noqa: E402
from models.instrument import CONFIGURATION_TIME_GOAL_S, Instrument, default_instrument  # noqa: E402
from models.kinematics import positive_turn_move_time_s  # noqa: E402
from models.types import AllocationResult, MotionPlan, PlaneTargets  # noqa: E402
from planner import MotionOptions, plan_motion, stop_count  # noqa: E402
from planner.programme import allocation_options as plan_allocation_options  # noqa: E402
from solvers.allocation import allocate  # noqa: E402
from solvers.allocation.options import AllocationOptions  # noqa: E402

FOV_RADIUS_MM = 125.0
FIELD_SIGMAS_MM: tuple[float | None, ...] = (None, 40.0, 60.0, 90.0)  # None: uniform
PRIORITY_VALUES = (500, 100, 10, 1)
PRIORITY_SHARES = (0.1, 0.4, 0.4, 0.1)
MAKESPAN_GOAL_S = CONFIGURATION_TIME_GOAL_S
INSTRUMENT = default_instrument()
LEG_KINDS = ("park_to_configuration", "chained", "to_park")
THESIS_REFERENCE = {
    "park_to_configuration": {"success_rate": 0.97, "makespan_s_median": 102.55,
                              "makespan_s_range": [96.0, 114.0]},
    "chained": {"success_rate": 0.93, "makespan_s_median": 90.6, "makespan_s_max": 108.0},
}
SMOKE = {"fields": 2, "targets": 60, "max_configurations": 2, "leg_budget": 3.0}
DEFAULTS = {"fields": 20, "targets": 150, "max_configurations": None, "leg_budget": 10.0}
EASY_TARGETS = 100


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------- fields


def shape_name(sigma_mm: float | None) -> str:
    return "uniform" if sigma_mm is None else f"gauss{sigma_mm:g}"


def field_xy_mm(n: int, sigma_mm: float | None, rng: np.random.Generator,
                radius_mm: float = FOV_RADIUS_MM) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points uniform in the FOV disc (sigma None) or Gaussian about the centre, clipped."""
    if sigma_mm is None:
        r_mm = radius_mm * np.sqrt(rng.random(n))
        a_rad = rng.random(n) * 2 * np.pi
        return r_mm * np.cos(a_rad), r_mm * np.sin(a_rad)
    pts = np.zeros((0, 2))
    while len(pts) < n:
        p = rng.normal(0.0, sigma_mm, (2 * n, 2))
        pts = np.vstack([pts, p[np.hypot(p[:, 0], p[:, 1]) <= radius_mm]])
    return pts[:n, 0], pts[:n, 1]


def make_field(n: int, sigma_mm: float | None, rng: np.random.Generator) -> PlaneTargets:
    """A field of ``n`` targets with the thesis priority mix (as benchmarks/allocation.py)."""
    x_mm, y_mm = field_xy_mm(n, sigma_mm, rng)
    priority = rng.choice(PRIORITY_VALUES, size=n, p=PRIORITY_SHARES).astype(np.int64)
    return PlaneTargets.from_lists([f"t{i}" for i in range(n)], x_mm, y_mm, priority)


def thesis_field(n: int, seed: int, field_index: int) -> tuple[str, PlaneTargets]:
    sigma_mm = FIELD_SIGMAS_MM[field_index % len(FIELD_SIGMAS_MM)]
    rng = np.random.default_rng([seed, field_index])
    return shape_name(sigma_mm), make_field(n, sigma_mm, rng)


def easy_field(n: int, rng: np.random.Generator) -> PlaneTargets:
    x_mm, y_mm = field_xy_mm(n, None, rng)
    return PlaneTargets.from_lists(range(n), x_mm, y_mm, np.ones(n, dtype=np.int64))


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


# ---------------------------------------------------------------------- plan_sequence


@dataclass(frozen=True)
class SequenceRecord:
    field: int
    executable: bool
    compute_s: float
    changes_by_kind: dict[str, int]
    targets_moved: int
    configurations_added: int
    targets_dropped: int


def run_plan_sequence(plan_sequence, instrument: Instrument, result: AllocationResult,
                      targets: PlaneTargets, n_configurations: int, *, field: int, seed: int,
                      leg_budget_s: float, park_move_limit_s: float | None) -> SequenceRecord:
    """The same configurations through ``planner.sequence.plan_sequence``."""
    configurations = result.configurations[:n_configurations]
    options = sequence_module.SequenceOptions(seed=seed, leg_time_limit_s=leg_budget_s,
                                              park_move_limit_s=park_move_limit_s)
    t0 = time.perf_counter()
    plan = plan_sequence(instrument, configurations, options, targets=targets)
    compute_s = time.perf_counter() - t0
    kinds = Counter(c.kind for c in plan.changes)
    moved = sum(len(c.target_ids) for c in plan.changes if c.kind == "moved_target")
    return SequenceRecord(field, bool(plan.executable), compute_s, dict(sorted(kinds.items())),
                          moved, len(plan.configurations) - len(configurations), len(plan.dropped))


def sequence_summary(records: Sequence[SequenceRecord]) -> dict:
    kinds: Counter[str] = Counter()
    for r in records:
        kinds.update(r.changes_by_kind)
    n_exec = sum(r.executable for r in records)
    return {
        "available": True,
        "fields": len(records),
        "fields_executable": n_exec,
        "share": n_exec / len(records) if records else None,
        "changes_by_kind": dict(sorted(kinds.items())),
        "targets_moved": sum(r.targets_moved for r in records),
        "legs_through_park": kinds.get("via_park", 0),
        "configurations_added": sum(r.configurations_added for r in records),
        "targets_dropped": sum(r.targets_dropped for r in records),
        "compute_s_median": _pct([r.compute_s for r in records], 50),
        "compute_s_max": _max([r.compute_s for r in records]),
        "fields_not_executable": [r.field for r in records if not r.executable],
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
    alloc_time_limit_s: float
    max_configurations: int | None
    smoke: bool
    park_move_limit_s: float | None = CONFIGURATION_TIME_GOAL_S

    def allocation_options(self) -> AllocationOptions:
        """What the plan pipeline passes (``PlanRequest.park_move_limit_s``, default T_p)."""
        return plan_allocation_options(self.park_move_limit_s)


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


def thesis_method(instrument: Instrument, params: Params, method: str) -> dict:
    plan_sequence = getattr(sequence_module, "plan_sequence", None)
    legs: list[LegRecord] = []
    seq: list[SequenceRecord] = []
    results, alloc_s, shapes = [], [], []
    for i in range(params.fields):
        shape, targets = thesis_field(params.targets, params.seed, i)
        t0 = time.perf_counter()
        result = allocate(instrument, targets, method=method, solver="bnb", configurations="all",
                          time_limit_s=params.alloc_time_limit_s, seed=params.seed,
                          options=params.allocation_options())
        alloc_s.append(time.perf_counter() - t0)
        results.append(result)
        shapes.append(shape)
        n_conf = len(result.configurations)
        if params.max_configurations is not None:
            n_conf = min(n_conf, params.max_configurations)
        configurations_q = [c.q for c in result.configurations[:n_conf]]
        field_legs = plan_field_legs(instrument, configurations_q, method=method, field=i,
                                     seed=params.seed, leg_budget_s=params.leg_budget_s)
        legs.extend(field_legs)
        failed = sum(not r.ok for r in field_legs)
        log(f"[{method}] field {i} ({shape}): {len(result.configurations)} configurations, "
            f"{len(field_legs)} legs planned, {failed} failed, allocation {alloc_s[-1]:.1f} s")
        if plan_sequence is not None:
            seq.append(run_plan_sequence(plan_sequence, instrument, result, targets, n_conf, field=i,
                                         seed=params.seed, leg_budget_s=params.leg_budget_s,
                                         park_move_limit_s=params.park_move_limit_s))
            log(f"[{method}] field {i}: plan_sequence executable={seq[-1].executable}")
    return {
        "allocation": {**allocation_summary(results, alloc_s), "shapes": shapes},
        "legs": summaries_by_kind(legs, LEG_KINDS),
        "whole_field": {
            "planner_alone": fields_without_failed_legs(legs, params.fields),
            "plan_sequence": sequence_summary(seq) if plan_sequence is not None
            else {"available": False},
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
                          time_limit_s=params.alloc_time_limit_s, seed=params.seed)
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


def thesis_field_parameters() -> dict:
    return {"field_shapes": [shape_name(s) for s in FIELD_SIGMAS_MM],
            "priority_mix": dict(zip(map(str, PRIORITY_VALUES), PRIORITY_SHARES, strict=True))}


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
    ap.add_argument("--alloc-time-limit", type=float, default=20.0,
                    help="allocate time_limit_s per field")
    ap.add_argument("--max-configurations", type=int, default=None,
                    help="plan only the first K configurations of each field (default: all)")
    ap.add_argument("--smoke", action="store_true",
                    help="2 fields, 60 targets, 2 configurations, 3 s per leg (explicit options win)")
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
                    alloc_time_limit_s=args.alloc_time_limit,
                    max_configurations=pick("max_configurations"), smoke=args.smoke,
                    park_move_limit_s=None if args.park_move_limit.lower() == "none"
                    else float(args.park_move_limit))
    if params.fields < 1 or params.targets < 1 or not params.methods:
        ap.error("--fields, --targets must be >= 1 and --methods non-empty")
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
            "leg_budget_s": params.leg_budget_s, "alloc_time_limit_s": params.alloc_time_limit_s,
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
