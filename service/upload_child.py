"""The process that reads one uploaded target table (the server side is :mod:`service.uploads`).

:func:`child_main` runs in a process of its own, forked for one upload: it limits its own
address space (``RLIMIT_AS``: what it starts with plus ``ParseLimits.memory_bytes``) and CPU
time (``RLIMIT_CPU``, a backstop behind the server's wall-clock limit), dies with its parent,
stream-decompresses a compressed file under a bound on the decompressed bytes, reads the
table with :func:`service.tables.read_target_table` (whose checks refuse a bad shape before
the table reader sees it, and apply the row limit while reading) and sends one outcome back
through a pipe:

* ``("ok", ParsedList)``: the table, encoded as the server stores and answers it;
* ``("invalid", message)``: a :class:`~service.tables.TargetFileError` (422);
* ``("memory", "")``: a ``MemoryError`` (the address-space limit was reached; 413);
* ``("failed", reason)``: any other error of the reader (422).

This module imports only the table reader and the standard library, so that a forked child
starts in milliseconds from a fork server that preloaded it.
"""

from __future__ import annotations

import errno
import json
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from service.parent_death import kill_with_parent
from service.table_checks import RowLimit, decompress
from service.tables import (
    TargetFileError,
    TargetTable,
    motion_lists,
    read_target_table,
    table_suffix,
)

# A child imports its parent's main module (multiprocessing does) by running it under another
# name; the fork server has it loaded already, which runpy notes with this warning in every child.
warnings.filterwarnings("ignore", message=r"'[\w.]+' found in sys.modules after import of package",
                        category=RuntimeWarning, module="runpy")

#: Exit code of a child that could not even report its ``MemoryError``.
MEMORY_EXIT = 3


@dataclass(frozen=True)
class ParseLimits:
    """The bounds of reading one upload, each with the setting that sets it."""

    max_rows: int
    rows_setting: str
    max_decompressed_bytes: int
    decompressed_setting: str
    time_limit_s: float
    time_setting: str
    memory_bytes: int
    memory_setting: str


@dataclass(frozen=True)
class ParseJob:
    """One upload to read: the file as received, its (client's) name and the limits."""

    path: str
    name: str
    limits: ParseLimits


def listed_targets(ids: list[str], ra_deg: list[float], dec_deg: list[float],
                   priority: list[int], line: list[int | None],
                   motion: dict[str, list[float | None]] | None = None) -> list[dict[str, Any]]:
    """The ``targets`` array of a stored list's answer: each target with its ``row`` (1 = first
    data row), ``line`` (of a CSV; None when unknown) and the motion fields the list gives
    (:func:`service.tables.motion_lists`)."""
    motion = motion or {}
    return [{"id": i, "ra_deg": r, "dec_deg": d, "priority": p, "row": k + 1, "line": ln,
             **{f: v[k] for f, v in motion.items()}}
            for k, (i, r, d, p, ln) in enumerate(zip(ids, ra_deg, dec_deg, priority, line,
                                                     strict=True))]


def json_text(value: Any) -> str:
    """``value`` as the server's JSON answers write it (compact, UTF-8, no NaN)."""
    return json.dumps(value, ensure_ascii=False, allow_nan=False, separators=(",", ":"))


@dataclass(frozen=True)
class ParsedList:
    """A read table as the server stores and answers it, encoded in the reader's process so
    that the server only copies text: ``blob`` the stored columns (JSON, the format of
    :class:`service.target_lists.TargetListStore`), ``listed`` the answer's ``targets`` array
    (JSON, :func:`listed_targets`)."""

    source: str
    columns: dict[str, str | None]
    notices: list[str]
    n_targets: int
    blob: str
    listed: str

    @classmethod
    def of(cls, table: TargetTable) -> ParsedList:
        t = table.targets
        cols: dict[str, list[Any]] = {
            "id": [r.id for r in t], "ra_deg": [r.ra_deg for r in t],
            "dec_deg": [r.dec_deg for r in t], "priority": [r.priority for r in t],
            "line": [r.line for r in t]}
        motion = motion_lists(t)
        if motion:
            cols["motion"] = motion  # type: ignore[assignment]
        listed = listed_targets(cols["id"], cols["ra_deg"], cols["dec_deg"], cols["priority"],
                                cols["line"], motion)
        return cls(table.source, dict(table.columns), list(table.notices), len(t),
                   json.dumps(cols), json_text(listed))


def row_limit(limits: ParseLimits) -> RowLimit:
    return RowLimit(limits.max_rows, f" in a target list on this server "
                    f"({limits.rows_setting}={limits.max_rows})")


def parse(job: ParseJob) -> ParsedList:
    """Read ``job``'s file: decompress it when it is compressed, then read the table."""
    lim = job.limits
    src = Path(job.path)
    plain = src.with_name("plain" + (table_suffix(job.name) or ".csv"))
    path = plain if decompress(src, plain, lim.max_decompressed_bytes, job.name,
                               lim.decompressed_setting) else src
    rows = row_limit(lim)
    table = read_target_table(path, name=job.name, rows=rows)
    if len(table.targets) > lim.max_rows:
        raise rows.refuse(job.name, f"{len(table.targets)} targets")
    return ParsedList.of(table)


def _address_space_bytes() -> int:
    """This process's address space now (what it inherited from the fork server)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[0])
    except (OSError, ValueError, IndexError):  # pragma: no cover - not Linux
        return 0
    return pages * os.sysconf("SC_PAGE_SIZE")


def limit_resources(memory_bytes: int, time_limit_s: float) -> None:
    """Bound this process: its address space to what it holds + ``memory_bytes``
    (``RLIMIT_AS``) and its CPU time to ``time_limit_s`` + 2 s (``RLIMIT_CPU``)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not Unix: the wall-clock limit alone
        return
    mem = _address_space_bytes() + memory_bytes
    resource.setrlimit(resource.RLIMIT_AS, (mem, mem))
    cpu_s = math.ceil(time_limit_s) + 2
    resource.setrlimit(resource.RLIMIT_CPU, (cpu_s, cpu_s + 1))


def _reason(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"[:200]


def child_main(conn: Any, job: ParseJob) -> None:
    """The child process: read ``job`` under its limits and send the outcome on ``conn``."""
    kill_with_parent()
    outcome: tuple[str, Any]
    try:
        limit_resources(job.limits.memory_bytes, job.limits.time_limit_s)
        outcome = ("ok", parse(job))
    except TargetFileError as exc:
        outcome = ("invalid", str(exc))
    except MemoryError:
        outcome = ("memory", "")
    except OSError as exc:
        outcome = ("memory", "") if exc.errno == errno.ENOMEM else ("failed", _reason(exc))
    except Exception as exc:  # noqa: BLE001 - the reader raises many kinds on odd files
        outcome = ("failed", _reason(exc))
    try:
        conn.send(outcome)
        conn.close()
    except MemoryError:
        os._exit(MEMORY_EXIT)
