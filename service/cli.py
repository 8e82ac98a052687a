"""Command line: ``mxs-planner serve`` (the HTTP API) and ``mxs-planner plan`` (a target file
through the whole pipeline, with a JSON result and one picture per configuration)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, get_args

from planner.programme import DEFAULT_LIMIT_S, DEFAULT_SEGMENTATION_MODE
from service.cli_keep import keep_arg, read_keep
from service.cli_pictures import OVERVIEW_NAME, pointing_pa_deg, write_overview, write_pictures
from service.cli_sky import ASSIGNMENTS_NAME, SkyFileError, read_sky_file, write_assignments
from service.cli_validate import add_validate_parser
from service.sky_text import plural, radec_text
from service.tables import ALIASES, UCDS, TargetFileError, read_target_table, read_targets
from solvers.programme.segment import MAX_TARGETS
from solvers.segmentation.field import MODES as SEGMENTATION_MODES

__all__ = ["TargetFileError", "main", "read_targets", "write_pictures"]

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
        sky = None if args.sky is None else read_sky_file(args.sky)
        keep = None if args.keep is None else read_keep(args.keep)
        req = PlanRequest(locked=args.lock or None, excluded_targets=args.exclude or None,
                          keep_configurations=keep,
                          targets=rows, obs_date=args.obs_date, method=args.method, solver=args.solver,
                          position_angle_deg=args.position_angle,
                          position_angle_range_deg=args.position_angle_range,
                          position_angle_step_deg=args.position_angle_step, time_limit_s=args.time_limit,
                          seed=args.seed, threshold_mm=args.threshold_mm,
                          segmentation_mode=args.segmentation_mode,
                          park_move_limit_s=None if args.no_park_move_limit else args.park_move_limit,
                          exposure_time_s=args.exposure_time, acquisition_s=args.acquisition,
                          max_exposures=args.max_exposures,
                          min_priority_per_exposure=args.min_priority_per_exposure,
                          min_targets_per_exposure=args.min_targets_per_exposure,
                          sky_positions=sky, sky_radius_arcsec=args.sky_radius)
    except (TargetFileError, SkyFileError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INVALID_INPUT
    except ValidationError as exc:
        for e in exc.errors()[:20]:
            loc = ".".join(str(x) for x in e["loc"])
            print(f"error: {loc}: {e['msg']}", file=sys.stderr)
        return EXIT_INVALID_INPUT
    image = None
    if args.image:
        from models.errors import InputError
        from models.finding_chart import load_fits_image

        try:
            image = load_fits_image(args.image, field="--image")
        except InputError as exc:
            print(f"error: --image {args.image}: {exc.message}", file=sys.stderr)
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
    write_assignments(result, out)
    pictures = write_pictures(result, req, inst, out, quiet=args.quiet, image=image)
    overview = overview_or_none(result, req, inst, out, image)
    print_summary(result, req, out, len(pictures), overview)
    for notice in result.get("notices", []):
        print(f"notice: {notice}", file=sys.stderr)
    if result["executable"]:
        return EXIT_OK
    print_failed_legs(result)
    return EXIT_NOT_EXECUTABLE


def overview_or_none(result: Mapping[str, Any], req: Any, inst: Any, out: Path,
                     image: Any) -> Path | None:
    """:func:`service.cli_pictures.write_overview`, or None with a notice when the field has no
    single gnomonic view (targets 90 degrees or more from their centre)."""
    from models.errors import InputError

    try:
        return write_overview(result, req, inst, out, image=image)
    except InputError as exc:
        print(f"notice: no sky overview: {exc}", file=sys.stderr)
        return None


def print_summary(result: Mapping[str, Any], req: Any, out: Path, n_pictures: int,
                  overview: Path | None) -> None:
    """The plan in a few lines: counts, files written, each pointing (sexagesimal and decimal),
    the telescope time, the changes made, and a warning per reason targets were left out."""
    s = result["stats"]
    print(f"{plural(s['targets'], 'target')}, {plural(s['pointings'], 'pointing')}, "
          f"{plural(s['configurations'], 'configuration')}, "
          f"{plural(s['allocated_targets'], 'target')} allocated; wrote {out / 'plan.json'}, {ASSIGNMENTS_NAME}, "
          f"{plural(n_pictures, 'configuration picture')} (pointing<id>_c<k>.png)"
          + (f" and the sky overview {overview}" if overview else ""))
    for p in result["pointings"]:
        auto = " (auto)" if req.position_angle_deg == "auto" else ""
        print(f"pointing {p['id']} at {radec_text(p['ra_deg'], p['dec_deg'])}, PA "
              f"{pointing_pa_deg(p, req):g}°{auto}: {plural(len(p['configurations']), 'configuration')}, "
              f"{plural(len(p['target_ids']), 'target')}")
    print(f"spare arms: {plural(s.get('sky_arms', 0), 'arm')} on sky over all configurations "
          f"(kind 'sky' in {ASSIGNMENTS_NAME})")
    print(time_summary(s["telescope_time"]))
    print(exposures_summary(s))
    summary = changes_summary(s)
    if summary:
        print(f"changes so that every leg can be executed: {summary}")
    # never fail silently: name every target left out and every motion leg not planned
    for reason, n in sorted(s.get("unallocated_by_reason", {}).items()):
        print(f"warning: {plural(n, 'target')} not allocated ({reason}); see 'unallocated' in "
              "plan.json", file=sys.stderr)


def leg_name(i: int, n_legs: int) -> str:
    """Motion leg ``i`` (index into a pointing's ``motions``) counted from 1, like the
    configurations: ``leg 1 (park -> c1)``, ..., ``leg n (cn-1 -> park)``."""
    src = "park" if i == 0 else f"c{i}"
    dst = "park" if i == n_legs - 1 else f"c{i + 1}"
    return f"leg {i + 1} ({src} -> {dst})"


def print_failed_legs(result: Mapping[str, Any]) -> None:
    """On stderr: each pointing's failed legs (counted from 1) and why."""
    for p in result["pointings"]:
        if p["executable"]:
            continue
        motions = p.get("motions", [])
        failed = [i for i, m in enumerate(motions) if m.get("status") != "ok"]
        names = ", ".join(leg_name(i, len(motions)) for i in failed)
        print(f"error: pointing {p['id']}: motion {names} not planned", file=sys.stderr)
        for reason in p.get("reasons") or [
            f"{leg_name(i, len(motions))}: arms {motions[i].get('failed_arms')} not planned"
            for i in failed
        ]:
            print(f"error: pointing {p['id']}: {reason}", file=sys.stderr)
    print("error: the plan is not executable; do not execute the failed legs (see 'reasons' "
          "in plan.json)", file=sys.stderr)


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
        line += f" ({plural(int(t['unplanned_legs']), 'motion leg')} not planned, not counted)"
    return line


def exposures_summary(stats: Mapping[str, Any]) -> str:
    """One line: the plan's exposures against the proven lower bound, how many observe at
    most 2 targets (and of those, how many only for targets no other exposure can take, how
    many with a target another exposure could take and why the consolidation stopped), what
    the programme optimiser's search kept (:func:`_optimiser_parts`) and how many exposures
    the plan's consolidation saved (:mod:`planner.consolidation`)."""
    n = int(stats["configurations"])
    bound = stats.get("exposures_lower_bound")
    parts = [plural(n, "exposure") + (f", proven lower bound {bound} ({n / bound:.2f}x)" if bound else "")]
    few, only = int(stats.get("few_target_exposures", 0)), int(stats.get("few_target_exposures_only_here", 0))
    if few:
        explained = int(stats.get("few_target_exposures_explained", only))
        failed = int(stats.get("few_target_exposures_plan_failed", 0))
        fewer = explained - only - failed
        movable = few - explained
        parts.append(f"{plural(few, 'exposure')} observing at most 2 targets, {only} of them only for "
                     "targets no other exposure can take" + (
                         f", {fewer} more for targets only exposures of 1 target can take"
                         if fewer > 0 else "") + (
                         f", {failed} more whose targets' moves the consolidation planned and failed"
                         " (kept_because)" if failed > 0 else "") + (
                         f", {movable} with a target another exposure could take" if movable > 0 else "")
                     + " (only_here" + (", could_move_to" if movable > 0 else "") + " in plan.json)")
        why = (stats.get("consolidation") or {}).get("reason")
        if movable > 0 and why:
            parts.append(f"the consolidation stopped: {why}")
    saved = int((stats.get("consolidation") or {}).get("exposures_saved", 0))
    if saved:
        parts.append(f"{plural(saved, 'exposure')} saved by moving targets onto idle arms of other exposures")
    return "; ".join(parts + _optimiser_parts(stats))


def _optimiser_parts(stats: Mapping[str, Any]) -> list[str]:
    """What the programme optimiser's search kept (``stats.segmentation.optimiser``), when it
    differs from its first search as the model gives it: another variant of its model (which,
    and what the first's allocations took) and the pointings it merged; then its time
    (:func:`_optimiser_time`)."""
    o = (stats.get("segmentation") or {}).get("optimiser") or {}
    tried = o.get("model_variants") or []
    kept = next((i for i, v in enumerate(tried) if v.get("chosen")), 0)
    parts = []
    if kept:
        v, first = tried[kept], tried[0]
        what = [w for w in ("the crowding rows" if v["crowding"] else "",
                            f"a pointing weighed as {v['pointing_cost']:g} exposures"
                            if v["pointing_cost"] != first["pointing_cost"] else "") if w]
        parts.append(f"the programme optimiser kept its model with {' and '.join(what)} ({v['exposures']} "
                     f"exposures in {v['pointings']} pointings against {first['exposures']} in "
                     f"{first['pointings']} for the first of {len(tried)} searched)")
    merged = int(o.get("pointings_merged") or 0)
    if merged:
        parts.append(f"{plural(merged, 'pointing')} merged into another that one field of view holds")
    return parts + _optimiser_time(stats.get("segmentation") or {})


def _optimiser_time(seg: Mapping[str, Any]) -> list[str]:
    """The programme optimiser's wall time, split into its own and the allocations of the
    pointings the plan observes as they are (``stats.segmentation``), when it allocated any."""
    once = int(seg.get("pointings_allocated_once") or 0)
    if not once or seg.get("own_time_s") is None:
        return []
    return [f"the programme optimiser took {float(seg['time_s']):.1f} s: {float(seg['own_time_s']):.1f} s "
            f"its own and {float(seg['allocations_kept_s']):.1f} s allocating {plural(once, 'pointing')} "
            "the plan observes as allocated there"]


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


def lock_arg(text: str) -> dict[str, Any]:
    """``TARGET:ARM[:BRANCH]`` as a ``locked`` entry (a target id may hold ':'; the last one or
    two integer fields are the arm and the branch)."""
    parts = text.split(":")
    ints = [p.strip().lstrip("-").isdigit() for p in parts]
    if len(parts) >= 3 and ints[-1] and ints[-2]:
        return {"target_id": ":".join(parts[:-2]), "arm": int(parts[-2]), "branch": int(parts[-1])}
    if len(parts) >= 2 and ints[-1] and parts[0]:
        return {"target_id": ":".join(parts[:-1]), "arm": int(parts[-1]), "branch": None}
    raise argparse.ArgumentTypeError(f"{text!r}: expected TARGET:ARM or TARGET:ARM:BRANCH (integers)")


def _angle_or_auto(text: str) -> float | str:
    """``--position-angle``: a number of degrees, or the text as given ("auto"; anything else
    is refused by the request's validation, which names ``position_angle_deg``)."""
    try:
        return float(text)
    except ValueError:
        return text


def _api_default(name: str) -> Any:
    """The default of ``POST /v1/plans``' field ``name`` (:class:`service.schemas.PlanRequest`),
    so ``plan`` and the API cannot drift apart."""
    from service.schemas import PlanRequest

    return PlanRequest.model_fields[name].default


def _api_choices(name: str) -> list[str]:
    """The values ``POST /v1/plans`` accepts for the Literal field ``name``."""
    from service.schemas import PlanRequest

    annotation = PlanRequest.model_fields[name].annotation
    literal = next((a for a in get_args(annotation) if get_args(a)), annotation)
    return [str(v) for v in get_args(literal)]


def targets_help() -> str:
    """The ``targets`` argument's help: the formats and every column name recognised
    (:data:`service.tables.UCDS` and :data:`service.tables.ALIASES`)."""
    cols = "; ".join(
        f"{field}: " + (f"UCD {UCDS[field][0]} or " if field in UCDS else "") + ", ".join(names)
        for field, names in ALIASES.items())
    return ("target table (CSV, ECSV, VOTable, FITS). Columns are found by VO UCD or by name, "
            f"case-insensitively: {cols}. RA/Dec in degrees or sexagesimal (RA in hours). "
            "No id column: row numbers; no priority column: priority 1")


def _add_plan_options(p: argparse.ArgumentParser) -> None:
    """``plan``'s options; every help says the default, taken from the API's defaults."""
    p.add_argument("targets", help=targets_help())
    p.add_argument("--out", required=True, help="output directory (required)")
    p.add_argument("--obs-date", default=_api_default("obs_date"), metavar="YYYY-MM-DD",
                   help="observation date: every target with proper motions (columns pmra/pmdec, "
                   "pmRA/pmDE; parallax, radial velocity and ref_epoch/Epoch when given) is moved "
                   "to it before planning (default: positions as given, with a notice of the "
                   "shift a year ahead)")
    p.add_argument("--method", choices=_api_choices("method"), default=_api_default("method"),
                   help="allocation: exact ILP or the semi-greedy heuristic (default: %(default)s)")
    p.add_argument("--solver", choices=_api_choices("solver"), default=_api_default("solver"),
                   help="exact engine of --method ilp; cpsat and highs start from a branch-and-bound "
                   "dive, bnb is that search alone (default: %(default)s)")
    p.add_argument("--position-angle", type=_angle_or_auto, default=_api_default("position_angle_deg"),
                   metavar="DEG|auto", help="position angle of the instrument, deg East of North; a "
                   "pointing whose PA the segmentation chooses uses its own; 'auto': every pointing "
                   "takes the best angle of --position-angle-range every --position-angle-step (fewest "
                   "targets lost to arm reach, then fewest exposures, then highest priority, then "
                   "nearest the range's centre, then the smaller angle) (default: %(default)s)")
    p.add_argument("--position-angle-range", type=float, nargs=2, default=None, metavar=("MIN", "MAX"),
                   help="with --position-angle auto: the angles searched, deg, both ends included "
                   "(default: any angle, [0, 360))")
    p.add_argument("--position-angle-step", type=float, default=None, metavar="DEG",
                   help="with --position-angle auto: the step between the angles searched, deg "
                   "(default: 5, a sixth of the arms' pitch)")
    p.add_argument("--time-limit", type=float, default=DEFAULT_LIMIT_S, metavar="S",
                   help="wall-clock limit of the whole plan, s, as POST /v1/plans "
                   "(default: %(default)s)")
    p.add_argument("--seed", type=int, default=_api_default("seed"),
                   help="random seed; the same seed and input give the same plan (default: 0)")
    p.add_argument("--threshold-mm", type=float, default=_api_default("threshold_mm"),
                   help="segmentation threshold, mm (default: sqrt(3) x the FOV radius, the side "
                   "of the triangle inscribed in the FOV)")
    p.add_argument("--segmentation-mode", choices=list(SEGMENTATION_MODES),
                   default=_api_default("segmentation_mode"),
                   help="how the field is split into pointings: 'complete-linkage' (thesis ch. 4), "
                   "'balanced', or 'fewest-exposures' (the programme optimiser: fewest exposures, "
                   f"with a proven lower bound) (default: {DEFAULT_SEGMENTATION_MODE} up to "
                   f"{MAX_TARGETS:,} targets, complete-linkage beyond)")
    reach = p.add_mutually_exclusive_group()
    reach.add_argument("--park-move-limit", type=float, default=_api_default("park_move_limit_s"),
                       metavar="S",
                       help="observe each target from a location its arm reaches from park within S "
                       "seconds (J2 turning the positive way), so no move from park exceeds the "
                       "configuration time goal; targets reached only farther away are reported "
                       "'beyond_park_move_limit' (default: %(default)s, the thesis' T_p)")
    reach.add_argument("--no-park-move-limit", action="store_true",
                       help="no park move limit: every reachable target, some moves from park up to "
                       "200 s (default: the limit applies)")
    p.add_argument("--exposure-time", type=float, default=_api_default("exposure_time_s"),
                   metavar="S", help="exposure time of one configuration, s; counted in the plan's "
                   "telescope time (default: %(default)s)")
    p.add_argument("--acquisition", type=float, default=_api_default("acquisition_s"), metavar="S",
                   help="acquisition overhead of one pointing, s (default: %(default)s)")
    p.add_argument("--max-exposures", type=int, default=_api_default("max_exposures"), metavar="N",
                   help="stop rule: at most N exposures over the whole plan, spent on the highest "
                   "priorities; targets left out: 'beyond_max_exposures' (default: no limit)")
    p.add_argument("--min-priority-per-exposure", type=int,
                   default=_api_default("min_priority_per_exposure"), metavar="P",
                   help="stop rule: no exposure observing less summed priority than P; their targets: "
                   "'below_exposure_threshold' (default: none)")
    p.add_argument("--min-targets-per-exposure", type=int,
                   default=_api_default("min_targets_per_exposure"), metavar="N",
                   help="stop rule: no exposure observing fewer than N targets; their targets: "
                   "'below_exposure_threshold' (default: none)")
    p.add_argument("--lock", type=lock_arg, action="append", default=None, metavar="TARGET:ARM[:BRANCH]",
                   help="observe TARGET only with ARM (0..11), through IK BRANCH (0..3) when given, in "
                   "every exposure that observes it (repeatable; a lock that cannot be honoured is an "
                   "error naming it) (default: none)")
    p.add_argument("--exclude", action="append", default=None, metavar="TARGET",
                   help="never observe TARGET: it is reported 'excluded' (repeatable) (default: none)")
    p.add_argument("--keep", type=keep_arg, default=None, metavar="PLAN.json:K",
                   help="keep configurations c1..cK of every pointing of a previous plan file as they "
                   "were (same pointing, position angle, members, arms, targets and joint angles) and "
                   "plan the rest again from cK's arm states; the targets of no kept pointing are "
                   "segmented as usual (default: nothing kept)")
    p.add_argument("--sky", default=None, metavar="FILE",
                   help="sky positions for the spare arms: a CSV of RA,Dec in degrees (a header "
                   "ra,dec optional); positions closer than --sky-radius to a target are not used "
                   "(default: blank sky the planner picks)")
    p.add_argument("--sky-radius", type=float, default=_api_default("sky_radius_arcsec"),
                   metavar="ARCSEC", help="least distance of a spare arm's sky position from every "
                   "target, arcsec (default: %(default)s)")
    p.add_argument("--image", default=None, metavar="FITS",
                   help="a FITS image with a celestial WCS (a 2MASS or Pan-STARRS cut-out, say): "
                   f"drawn as a finding chart under {OVERVIEW_NAME} and under every configuration "
                   "picture (default: none, a blank background)")
    p.add_argument("--instrument", default=None,
                   help="instrument TOML file (default: $MXS_INSTRUMENT_FILE or the packaged one)")
    p.add_argument("--quiet", action="store_true", help="no progress bars (default: shown)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mxs-planner", description=__doc__, epilog=EXIT_CODES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("serve", help="run the HTTP API (settings from MXS_* variables)")
    s.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: %(default)s)")
    s.add_argument("--port", type=int, default=8000, help="TCP port (default: %(default)s)")
    s.add_argument("--log-level", default="info", help="uvicorn's log level (default: %(default)s)")
    s.add_argument("--workers", type=int, default=None,
                   help="server processes (uvicorn --workers); they share the job database "
                   "(default: one)")
    s.set_defaults(func=cmd_serve)
    p = sub.add_parser("plan", help="plan a target list (CSV, ECSV, VOTable, FITS)",
                       epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_plan_options(p)
    p.set_defaults(func=cmd_plan)
    add_validate_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
