"""A plan file (the JSON of ``POST /v1/plans``, a plan job's result or the CLI's plan.json)
read into plain domain types, and its content hash.

The reader takes the JSON as parsed (dicts, lists, numbers, strings) and keeps only what a
re-check needs: each pointing's centre, position angle and targets (RA/Dec and focal-plane
position), its configurations (one assignment per arm) and its motion legs (timed
way-points and controller commands of every arm). A value of the wrong shape or type is an
:class:`~models.errors.InputError` naming its place in the file
(``pointings[0].motions[2].trajectories[5].waypoints[3].t_s``), so that the service answers
422 and the CLI exit code 2 rather than a verdict on a file it could not read.

The content hash is ``"sha256:"`` + the hex SHA-256 of the plan's canonical JSON: every field
but ``content_hash`` itself, keys sorted, no whitespace, non-ASCII characters as they are
(UTF-8), numbers as Python's ``json`` writes the values the file holds (a whole number as
an integer, whether written ``900`` or ``900.0``; any other float in its shortest form that
reads back to the same double). Any writer whose numbers read back to the same values, a
browser's ``JSON.stringify`` included, gives the same hash; editing any number, string or list
of the plan without recomputing the hash is detected.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.errors import InputError
from models.types import ArmAssignment, ArmTrajectory, Configuration, ControllerCommand

HASH_FIELD = "content_hash"
HASH_PREFIX = "sha256:"


# ------------------------------------------------------------------------------ hash


def _numbers(v: Any) -> Any:
    """``v`` with every whole float written as an integer: JSON does not tell 900 from 900.0,
    and writers differ (JavaScript writes 900), so the hash must not either."""
    if isinstance(v, float):
        return int(v) if v.is_integer() and abs(v) < 2.0**53 else v
    if isinstance(v, Mapping):
        return {k: _numbers(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_numbers(x) for x in v]
    return v


def canonical_json(plan: Mapping[str, Any]) -> bytes:
    """The plan without ``content_hash`` as canonical JSON bytes (see the module doc): keys
    sorted, no whitespace, UTF-8, whole numbers without a fraction."""
    body = {k: _numbers(v) for k, v in plan.items() if k != HASH_FIELD}
    return json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=True).encode("utf-8")


def content_hash(plan: Mapping[str, Any]) -> str:
    """``"sha256:<hex>"`` of :func:`canonical_json`."""
    return HASH_PREFIX + hashlib.sha256(canonical_json(plan)).hexdigest()


# ------------------------------------------------------------------------- domain types


@dataclass(frozen=True)
class FileTarget:
    """A target of one pointing as the file gives it: sky position and focal-plane position
    in that pointing's frame."""

    id: str
    ra_deg: float
    dec_deg: float
    x_mm: float
    y_mm: float


@dataclass(frozen=True)
class FileLeg:
    """One motion leg: ``status`` "ok" (trajectories to check) or "failed" (not planned)."""

    status: str
    makespan_s: float | None
    trajectories: tuple[ArmTrajectory, ...]
    max_stops: int | None  # the leg's own ``stats.max_stops`` when it reports one


@dataclass(frozen=True)
class FilePointing:
    id: str
    ra_deg: float
    dec_deg: float
    position_angle_deg: float | None
    target_ids: tuple[str, ...]
    targets: tuple[FileTarget, ...] | None  # None: the file lists no target positions
    configurations: tuple[Configuration, ...]
    legs: tuple[FileLeg, ...]
    executable: bool
    planned: bool  # False: the plan's time limit left this pointing unplanned (``not_planned``)


@dataclass(frozen=True)
class PlanFile:
    pointings: tuple[FilePointing, ...]
    executable: bool
    content_hash: str | None
    computed_hash: str


# ------------------------------------------------------------------------------ reading


def _where(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def _get(d: Mapping[str, Any], key: str, path: str, *, optional: bool = False) -> Any:
    if key not in d:
        if optional:
            return None
        raise InputError(_where(path, key), "required field missing")
    return d[key]


def _obj(v: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        raise InputError(path or "body", f"must be an object, got {type(v).__name__}")
    return v


def _list(v: Any, path: str) -> Sequence[Any]:
    if not isinstance(v, list):
        raise InputError(path, f"must be a list, got {type(v).__name__}")
    return v


def _num(v: Any, path: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(path, f"must be a finite number, got {v!r}"[:200])
    return float(v)


def _int(v: Any, path: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise InputError(path, f"must be an integer, got {v!r}"[:200])
    return int(v)


def _str(v: Any, path: str) -> str:
    if not isinstance(v, str):
        raise InputError(path, f"must be a string, got {type(v).__name__}")
    return v


def _bool(v: Any, path: str) -> bool:
    if not isinstance(v, bool):
        raise InputError(path, f"must be true or false, got {v!r}"[:200])
    return v


def _field(d: Mapping[str, Any], key: str, path: str, kind: Any, *, optional: bool = False) -> Any:
    """``d[key]`` read by ``kind`` (:func:`_num`, :func:`_str`...); None when optional and
    absent or null."""
    v = _get(d, key, path, optional=optional)
    if v is None and optional:
        return None
    return kind(v, _where(path, key))


def _target(d: Any, path: str) -> FileTarget:
    d = _obj(d, path)
    return FileTarget(_field(d, "id", path, _str), _field(d, "ra_deg", path, _num),
                      _field(d, "dec_deg", path, _num), _field(d, "x_mm", path, _num),
                      _field(d, "y_mm", path, _num))


def _assignment(d: Any, path: str) -> ArmAssignment:
    d = _obj(d, path)
    kind = _field(d, "kind", path, _str, optional=True)
    target_id = _field(d, "target_id", path, _str, optional=True)
    return ArmAssignment(_field(d, "arm", path, _int), kind or ("park" if target_id is None else "target"),
                         _field(d, "theta1_rad", path, _num), _field(d, "theta2_rad", path, _num),
                         _field(d, "x_mm", path, _num), _field(d, "y_mm", path, _num),
                         target_id=target_id)


def _configuration(d: Any, path: str) -> Configuration:
    d = _obj(d, path)
    p = _where(path, "assignments")
    items = _list(_get(d, "assignments", path), p)
    assignments = tuple(_assignment(a, _where(p, i)) for i, a in enumerate(items))
    status = _field(d, "status", path, _str, optional=True) or "feasible"
    return Configuration(_field(d, "index", path, _int), assignments,
                         _field(d, "total_priority", path, _int, optional=True) or 0,
                         _field(d, "arm_yield", path, _int, optional=True) or 0,
                         status)  # type: ignore[arg-type]


def _command(d: Any, path: str) -> ControllerCommand:
    d = _obj(d, path)
    joint = _field(d, "joint", path, _int)
    if joint not in (1, 2):
        raise InputError(_where(path, "joint"), f"must be 1 or 2, got {joint}")
    return ControllerCommand(joint, _field(d, "t_start_s", path, _num),  # type: ignore[arg-type]
                             _field(d, "from_rad", path, _num), _field(d, "to_rad", path, _num),
                             _field(d, "speed_rad_s", path, _num))


def _trajectory(d: Any, path: str) -> ArmTrajectory:
    d = _obj(d, path)
    p = _where(path, "waypoints")
    wps = [_obj(w, _where(p, i)) for i, w in enumerate(_list(_get(d, "waypoints", path), p))]
    cols = {k: np.array([_field(w, k, _where(p, i), _num) for i, w in enumerate(wps)], float)
            for k in ("t_s", "theta1_rad", "theta2_rad")}
    pc = _where(path, "commands")
    cmds = tuple(_command(c, _where(pc, i))
                 for i, c in enumerate(_list(_get(d, "commands", path, optional=True) or [], pc)))
    return ArmTrajectory(_field(d, "arm", path, _int), cols["t_s"], cols["theta1_rad"],
                         cols["theta2_rad"], cmds)


def _leg(d: Any, path: str) -> FileLeg:
    d = _obj(d, path)
    status = _field(d, "status", path, _str)
    if status not in ("ok", "failed"):
        raise InputError(_where(path, "status"), f"must be 'ok' or 'failed', got {status!r}"[:200])
    p = _where(path, "trajectories")
    trajs = tuple(_trajectory(t, _where(p, i)) for i, t in enumerate(_list(_get(d, "trajectories", path), p)))
    stats = _get(d, "stats", path, optional=True)
    stops = stats.get("max_stops") if isinstance(stats, Mapping) else None
    max_stops = _int(stops, _where(_where(path, "stats"), "max_stops")) if stops is not None else None
    return FileLeg(status, _field(d, "makespan_s", path, _num, optional=True), trajs, max_stops)


def _items(d: Mapping[str, Any], key: str, path: str, read: Any) -> tuple[Any, ...]:
    p = _where(path, key)
    return tuple(read(x, _where(p, i)) for i, x in enumerate(_list(_get(d, key, path), p)))


def _pointing(d: Any, path: str) -> FilePointing:
    d = _obj(d, path)
    p = _where(path, "target_ids")
    ids = tuple(_str(t, _where(p, i)) for i, t in enumerate(_list(_get(d, "target_ids", path), p)))
    targets = None
    if _get(d, "targets", path, optional=True) is not None:
        targets = _items(d, "targets", path, _target)
    return FilePointing(
        id=_field(d, "id", path, _str), ra_deg=_field(d, "ra_deg", path, _num),
        dec_deg=_field(d, "dec_deg", path, _num),
        position_angle_deg=_field(d, "position_angle_deg", path, _num, optional=True),
        target_ids=ids, targets=targets,
        configurations=_items(d, "configurations", path, _configuration),
        legs=_items(d, "motions", path, _leg), executable=_field(d, "executable", path, _bool),
        planned=_get(d, "not_planned", path, optional=True) is None)


def read_plan(plan: Any) -> PlanFile:
    """A parsed plan JSON as a :class:`PlanFile` (InputError naming the field on a wrong shape)."""
    d = _obj(plan, "")
    h = _field(d, HASH_FIELD, "", _str, optional=True)
    return PlanFile(_items(d, "pointings", "", _pointing), _field(d, "executable", "", _bool), h,
                    content_hash(d))
