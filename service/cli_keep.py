"""``mxs-planner plan --keep PLAN.json:K``: keep configurations c1..cK of every pointing of a
previous plan file and plan the rest again (the request's ``keep_configurations``,
:mod:`service.keep_schemas`)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from service.table_checks import TargetFileError

#: the keys of a plan's assignment that a kept configuration carries
ASSIGNMENT_KEYS = ("arm", "target_id", "theta1_rad", "theta2_rad", "x_mm", "y_mm")


def keep_arg(text: str) -> tuple[str, int]:
    """``PLAN.json:K`` as (path, K): K >= 1 configurations kept (the path may hold ':')."""
    path, sep, k = text.rpartition(":")
    if not sep or not path or not k.strip().isdigit() or int(k) < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected PLAN.json:K with K an integer >= 1")
    return path, int(k)


def keep_from_plan(plan: Mapping[str, Any], k: int) -> dict[str, Any] | None:
    """The ``keep_configurations`` of a PlanResponse dict keeping c1..ck of every pointing
    that has configurations (all of a pointing that has fewer); None when none has any."""
    pointings = [{
        "id": p["id"], "ra_deg": p["ra_deg"], "dec_deg": p["dec_deg"],
        "position_angle_deg": p.get("position_angle_deg"), "target_ids": list(p["target_ids"]),
        "configurations": [[{key: a[key] for key in ASSIGNMENT_KEYS if key in a} for a in c["assignments"]]
                           for c in p["configurations"][:k]],
    } for p in plan["pointings"] if p.get("configurations")]
    return {"pointings": pointings} if pointings else None


def read_keep(spec: tuple[str, int]) -> dict[str, Any] | None:
    """``--keep``'s (path, K) read as :func:`keep_from_plan`; a file that is not a plan is a
    :class:`TargetFileError` naming ``--keep`` and the file."""
    path, k = spec
    try:
        plan = json.loads(Path(path).read_text())
        return keep_from_plan(plan, k)
    except OSError as exc:
        raise TargetFileError(f"--keep {path}: cannot read the file ({exc.strerror})") from exc
    except ValueError as exc:
        raise TargetFileError(f"--keep {path}: not a JSON file ({exc})") from exc
    except (KeyError, TypeError, AttributeError) as exc:
        raise TargetFileError(f"--keep {path}: not a plan file (plan.json of `mxs-planner plan`): "
                              f"missing or bad {exc}") from exc
