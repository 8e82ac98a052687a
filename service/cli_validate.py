"""``mxs-planner validate plan.json``: re-check a plan file anyone hands over
(:func:`planner.validate.validate_plan`), with the exit codes below."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

EXIT_VALID = 0
EXIT_UNREADABLE = 2
EXIT_NOT_EXECUTABLE = 4
EXIT_INVALID = 5
SHOWN = 20  # violations printed at most
EXIT_CODES = """exit codes of `validate`:
  0  valid: the content hash matches and every configuration and motion leg checks out
  2  the file cannot be read as a plan (not JSON, or a field missing or of the wrong type;
     the message names the field)
  4  valid, but the plan says it is not executable (some motion leg was not planned): do
     not execute its failed legs
  5  invalid: the first violations are printed, one per line, naming the pointing,
     configuration or leg, and arm"""


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def read_json(path: str) -> Any:
    """The parsed file (ValueError / OSError when it is unreadable or not strict JSON)."""
    return json.loads(Path(path).read_text(encoding="utf-8"), parse_constant=_reject_constant)


def violation_line(v: dict[str, Any]) -> str:
    """One violation as ``pointing P, leg L, arm A: kind: message``."""
    where = [f"{name}{v[key]}" for key, name in (("pointing", "pointing "), ("configuration", "configuration c"),
                                                 ("leg", "leg "), ("arm", "arm ")) if v.get(key) is not None]
    return f"{', '.join(where) or 'plan'}: {v['kind']}: {v['message']}"


def cmd_validate(args: argparse.Namespace) -> int:
    from models.errors import InputError
    from planner.validate import validate_plan
    from service import pipeline
    from service.adapters import plain
    from service.settings import Settings

    try:
        plan = read_json(args.plan)
    except (OSError, ValueError) as exc:
        print(f"error: {args.plan}: cannot be read as JSON: {exc}", file=sys.stderr)
        return EXIT_UNREADABLE
    inst_file = args.instrument or Settings().instrument_file
    inst = pipeline.instrument_from(str(inst_file) if inst_file else None)
    try:
        report = plain(validate_plan(inst, plan))
    except InputError as exc:
        print(f"error: {args.plan}: not a plan: {exc.field}: {exc.message}", file=sys.stderr)
        return EXIT_UNREADABLE
    if args.json:
        print(json.dumps(report, indent=1))
    c = report["checked"]
    summary = (f"{c['pointings']} pointings, {c['configurations']} configurations, {c['legs']} legs "
               f"({c['legs_failed']} not planned), {c['pair_samples']} pair clearances checked; "
               f"hash {'ok' if report['hash_ok'] else 'MISMATCH'}")
    if not report["valid"]:
        for v in report["violations"][:SHOWN]:
            print(f"violation: {violation_line(v)}", file=sys.stderr)
        more = report["violations_total"] - min(SHOWN, len(report["violations"]))
        if more > 0:
            print(f"violation: ... and {more} more", file=sys.stderr)
        print(f"INVALID: {report['violations_total']} violations; {summary}", file=sys.stderr)
        return EXIT_INVALID
    if not report["executable"]:
        print(f"valid but NOT EXECUTABLE (some motion leg was not planned); {summary}", file=sys.stderr)
        return EXIT_NOT_EXECUTABLE
    print(f"valid: {summary}")
    return EXIT_VALID


def add_validate_parser(sub: Any) -> None:
    """The ``validate`` subcommand on the CLI's subparsers."""
    v = sub.add_parser("validate", help="re-check a plan file (plan.json): configurations, motion legs, hash",
                       epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter)
    v.add_argument("plan", help="the plan JSON (POST /v1/plans' answer, a plan job's result or plan.json)")
    v.add_argument("--instrument", default=None,
                   help="instrument TOML file the plan was made for (default: $MXS_INSTRUMENT_FILE "
                   "or the packaged one)")
    v.add_argument("--json", action="store_true", help="also print the whole report as JSON on stdout")
    v.set_defaults(func=cmd_validate)
