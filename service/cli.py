"""Command line: ``mxs-planner serve`` (the HTTP API) and ``mxs-planner plan`` (a target file
through the whole pipeline, with a JSON result and one picture per configuration)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from models.instrument import CONFIGURATION_TIME_GOAL_S
from planner.programme import DEFAULT_LIMIT_S, DEFAULT_SEGMENTATION_MODE
from planner.telescope_time import DEFAULT_ACQUISITION_S, DEFAULT_EXPOSURE_TIME_S
from service.tables import TargetFileError, read_target_table, read_targets
from solvers.programme.segment import MAX_TARGETS
from solvers.segmentation.field import MODES as SEGMENTATION_MODES

__all__ = ["TargetFileError", "main", "read_targets"]

EXIT_OK = 0
EXIT_INVALID_INPUT = 2
EXIT_NOT_EXECUTABLE = 4
EXIT_CODES = """exit codes of `plan`:
  0  the plan is executable (every motion leg planned); plan.json and pictures written
  2  invalid input: a bad target table (the message names the file, row and column) or
     option
  4  plan not executable: some motion leg could not be planned (the failed pointings, legs,
     arms and reasons are printed on stderr); plan.json and pictures are still written"""


# ------------------------------------------------------------------------- commands


def cmd_serve(args: argparse.Namespace) -> int:
    """uvicorn on ``service.app:app``; SIGTERM gives open requests ``MXS_SHUTDOWN_GRACE_S``,
    then cancels them, stops the job workers and re-queues their jobs (a few seconds)."""
    import uvicorn

    from service.auth import warn_if_open
    from service.settings import Settings

    settings = Settings()
    warn_if_open(args.host, settings)
    uvicorn.run("service.app:app", host=args.host, port=args.port, log_level=args.log_level,
                workers=args.workers, timeout_graceful_shutdown=settings.shutdown_grace_s)
    return 0


def cmd_plan(args: argparse.Namespace) -> int:
    from pydantic import ValidationError
    from tqdm import tqdm

    from service import pipeline
    from service.errors import ServiceError
    from service.schemas import PlanRequest

    try:
        table = read_target_table(args.targets)
        for notice in table.notices:
            print(f"notice: {notice}", file=sys.stderr)
        rows = table.rows()
        req = PlanRequest(targets=rows, method=args.method, solver=args.solver,
                          position_angle_deg=args.position_angle, time_limit_s=args.time_limit,
                          seed=args.seed, threshold_mm=args.threshold_mm,
                          segmentation_mode=args.segmentation_mode,
                          park_move_limit_s=None if args.no_park_move_limit else args.park_move_limit,
                          exposure_time_s=args.exposure_time, acquisition_s=args.acquisition,
                          max_exposures=args.max_exposures,
                          min_priority_per_exposure=args.min_priority_per_exposure,
                          min_targets_per_exposure=args.min_targets_per_exposure)
    except TargetFileError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INVALID_INPUT
    except ValidationError as exc:
        for e in exc.errors()[:20]:
            loc = ".".join(str(x) for x in e["loc"])
            print(f"error: {loc}: {e['msg']}", file=sys.stderr)
        return EXIT_INVALID_INPUT
    from service.settings import Settings

    inst_file = args.instrument or Settings().instrument_file
    inst = pipeline.instrument_from(str(inst_file) if inst_file else None)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tqdm(total=100, desc="planning", unit="%", disable=args.quiet) as bar:
        def progress(p: float) -> None:
            bar.update(max(0, round(100 * p) - bar.n))

        try:
            result = pipeline.plan(req, inst, progress)
        except (ServiceError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_INVALID_INPUT
    (out / "plan.json").write_text(json.dumps(result, indent=1))
    pictures = write_pictures(result, req, inst, out, quiet=args.quiet)
    s = result["stats"]
    print(f"{s['targets']} targets, {s['pointings']} pointings, {s['configurations']} "
          f"configurations, {s['allocated_targets']} targets allocated; wrote {out / 'plan.json'}"
          f" and {len(pictures)} pictures")
    print(time_summary(s["telescope_time"]))
    summary = changes_summary(s)
    if summary:
        print(f"changes so that every leg can be executed: {summary}")
    # never fail silently: name every target left out and every motion leg not planned
    for reason, n in sorted(s.get("unallocated_by_reason", {}).items()):
        print(f"warning: {n} targets not allocated ({reason}); see 'unallocated' in plan.json",
              file=sys.stderr)
    if result["executable"]:
        return EXIT_OK
    for p in result["pointings"]:
        if p["executable"]:
            continue
        failed = [i for i, m in enumerate(p.get("motions", [])) if m.get("status") != "ok"]
        print(f"error: pointing {p['id']}: motion legs {failed} not planned", file=sys.stderr)
        for reason in p.get("reasons") or [
            f"leg {i}: arms {p['motions'][i].get('failed_arms')} not planned" for i in failed
        ]:
            print(f"error: pointing {p['id']}: {reason}", file=sys.stderr)
    print("error: the plan is not executable; do not execute the failed legs (see 'reasons' "
          "in plan.json)", file=sys.stderr)
    return EXIT_NOT_EXECUTABLE


def hours_minutes(t_s: float) -> str:
    """``t_s`` seconds as h:mm (rounded to the minute)."""
    h, m = divmod(round(t_s / 60.0), 60)
    return f"{h}:{m:02d}"


def time_summary(t: dict[str, Any]) -> str:
    """One line: a plan's exposures and telescope time (h:mm) with its breakdown
    (``stats.telescope_time`` of the plan)."""
    n, a = int(t["exposures"]), int(t["acquisitions"])
    line = (f"{n} exposure{'' if n == 1 else 's'}, telescope time {hours_minutes(t['total_s'])} (h:mm) = "
            f"exposures {hours_minutes(t['exposure_s'])} + {a} acquisition{'' if a == 1 else 's'} "
            f"{hours_minutes(t['acquisition_s'])} + reconfiguration {hours_minutes(t['reconfiguration_s'])}")
    if t["unplanned_legs"]:
        line += f" ({t['unplanned_legs']} motion legs not planned, not counted)"
    return line


def changes_summary(stats: dict[str, Any]) -> str:
    """One line naming the changes counted in a plan's ``stats`` ('' when there were none)."""
    parts = []
    for key, one, many in (
        ("targets_moved", "target moved to another configuration",
         "targets moved to other configurations"),
        ("legs_via_park", "leg through park", "legs through park"),
        ("configurations_added", "configuration added", "configurations added"),
        ("targets_dropped", "target dropped", "targets dropped"),
    ):
        n = int(stats.get(key) or 0)
        if n:
            parts.append(f"{n} {one if n == 1 else many}")
    return ", ".join(parts)


def write_pictures(result: dict[str, Any], req: Any, inst: Any, out: Path,
                   quiet: bool = False) -> list[Path]:
    """One PNG per configuration, ``pointing<id>_c<k>.png``: configurations are c1 ... cn
    (``index`` + 1), as on the page and in the motion legs' reasons."""
    from tqdm import tqdm

    from service import pipeline
    from service.plots import plot_configuration, sequence_states

    by_id = {t.id: t for t in req.targets}
    jobs = [(p, c) for p in result["pointings"] for c in p["configurations"]]
    paths = []
    for p, c in tqdm(jobs, desc="pictures", disable=quiet or not jobs):
        members = [by_id[t] for t in p["target_ids"]]
        x, y = pipeline.sky_to_focal(members, p["ra_deg"] % 360.0, p["dec_deg"], inst,
                                     req.position_angle_deg)
        paths.append(plot_configuration(
            inst, {a["arm"]: (a["theta1_rad"], a["theta2_rad"]) for a in c["assignments"]},
            out / f"pointing{p['id']}_c{c['index'] + 1}.png",
            target_x_mm=x, target_y_mm=y, target_priority=[t.priority for t in members],
            target_status=sequence_states(p["configurations"], c, [t.id for t in members]),
            target_ids=[t.id for t in members], position_angle_deg=req.position_angle_deg,
            title=f"pointing {p['id']} (RA {p['ra_deg']:.5f}, Dec {p['dec_deg']:.5f}) - "
                  f"configuration c{c['index'] + 1}: {c['arm_yield']} arms, "
                  f"priority {c['total_priority']}",
        ))
    return paths


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mxs-planner", description=__doc__, epilog=EXIT_CODES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("serve", help="run the HTTP API (settings from MXS_* variables)")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument("--log-level", default="info")
    s.add_argument("--workers", type=int, default=None,
                   help="server processes (uvicorn --workers); they share the job database")
    s.set_defaults(func=cmd_serve)
    p = sub.add_parser("plan", help="plan a target list (CSV, ECSV, VOTable, FITS)",
                       epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("targets", help="target table: columns id, ra_deg, dec_deg, priority")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--method", choices=["ilp", "semigreedy"], default="ilp")
    p.add_argument("--solver", choices=["highs", "cpsat", "bnb"], default="bnb")
    p.add_argument("--position-angle", type=float, default=0.0, help="deg")
    p.add_argument("--time-limit", type=float, default=DEFAULT_LIMIT_S,
                   help="wall-clock limit of the whole plan, s (default %(default)s, as "
                   "POST /v1/plans)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--threshold-mm", type=float, default=None)
    p.add_argument("--segmentation-mode", choices=list(SEGMENTATION_MODES),
                   default=None,
                   help="how the field is split into pointings: 'complete-linkage' (thesis ch. 4), "
                   "'balanced', or 'fewest-exposures' (the programme optimiser: fewest exposures, "
                   f"with a proven lower bound) (default: {DEFAULT_SEGMENTATION_MODE} up to {MAX_TARGETS:,} "
                   "targets, complete-linkage beyond)")
    reach = p.add_mutually_exclusive_group()
    reach.add_argument("--park-move-limit", type=float, default=CONFIGURATION_TIME_GOAL_S, metavar="S",
                       help="observe each target from a location its arm reaches from park within S "
                       "seconds (J2 turning the positive way), so no move from park exceeds the "
                       "configuration time goal; targets reached only farther away are reported "
                       "'beyond_park_move_limit' (default: 120, the thesis' T_p)")
    reach.add_argument("--no-park-move-limit", action="store_true",
                       help="no park move limit: every reachable target, some moves from park up to 200 s")
    p.add_argument("--exposure-time", type=float, default=DEFAULT_EXPOSURE_TIME_S, metavar="S",
                   help="exposure time of one configuration, s (default %(default)s); counted in the "
                   "plan's telescope time")
    p.add_argument("--acquisition", type=float, default=DEFAULT_ACQUISITION_S, metavar="S",
                   help="acquisition overhead of one pointing, s (default %(default)s)")
    p.add_argument("--max-exposures", type=int, default=None, metavar="N",
                   help="stop rule: at most N exposures over the whole plan, spent on the highest "
                   "priorities; targets left out: 'beyond_max_exposures' (default: no limit)")
    p.add_argument("--min-priority-per-exposure", type=int, default=None, metavar="P",
                   help="stop rule: no exposure observing less summed priority than P; their targets: "
                   "'below_exposure_threshold' (default: none)")
    p.add_argument("--min-targets-per-exposure", type=int, default=None, metavar="N",
                   help="stop rule: no exposure observing fewer than N targets; their targets: "
                   "'below_exposure_threshold' (default: none)")
    p.add_argument("--instrument", default=None,
                   help="instrument TOML file (default: $MXS_INSTRUMENT_FILE or the packaged one)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_plan)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
