"""Stored target lists: ``POST /v1/target-lists`` reads an uploaded table with the CLI's reader
(:mod:`service.tables`) and stores it; segmentation, plan and job requests then name it by
``target_list_id`` instead of carrying a ``targets`` array, so that a survey-size list is sent
once, as a file, and never as inline JSON.

An upload is read in a process of its own (:mod:`service.uploads`), in a heavy-request slot
(503 with ``Retry-After`` when every slot is taken), under a wall-clock limit
(``MXS_UPLOAD_PARSE_TIME_S``, 422) and a memory limit (``MXS_UPLOAD_PARSE_MEMORY_BYTES``, 413),
and stopped when its client leaves. It is limited in bytes (``MXS_MAX_UPLOAD_BYTES``, 413;
``MXS_MAX_UPLOAD_DECOMPRESSED_BYTES`` once decompressed, 422) and in targets
(``MXS_MAX_TARGET_LIST_TARGETS``, 422, applied while the file is read); a request that
references a list is then held to its own stage's target limit.

A list is stored in the job database (its own table ``target_lists``), so every server on that
database sees it. Lists older than ``MXS_TARGET_LIST_RETENTION_S`` or beyond the newest
``MXS_TARGET_LIST_RETENTION_COUNT`` are deleted. A job copies the list's targets into its request
when it is queued, so a list deleted later never breaks a job.
"""

from __future__ import annotations

import json
import sqlite3
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

from fastapi import FastAPI, File, Query, Request, UploadFile
from fastapi.params import Depends
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from service.epoch_schemas import PARALLAX_DOC, PMDEC_DOC, PMRA_DOC, REF_EPOCH_DOC, RV_DOC
from service.errors import NotFound, clip
from service.executor import HeavyExecutor, Ticket, run_heavy
from service.response_schemas import ErrorResponse
from service.schemas import SkyTarget
from service.settings import Settings, env_name
from service.tables import COMPRESSED, table_suffix
from service.upload_child import ParsedList, ParseLimits, json_text, listed_targets
from service.uploads import parse_upload

#: A longer file name is cut to this many characters, keeping its suffix (``.fits.gz``).
MAX_FILENAME_CHARS = 200
_SCHEMA = """
CREATE TABLE IF NOT EXISTS target_lists (
    list_id    TEXT PRIMARY KEY,
    filename   TEXT NOT NULL,
    n_targets  INTEGER NOT NULL,
    columns    TEXT NOT NULL,
    notices    TEXT NOT NULL,
    targets    TEXT NOT NULL,
    created_at REAL NOT NULL
)
"""


# --------------------------------------------------------------------------- schemas


class ListedTarget(BaseModel):
    id: str
    ra_deg: float
    dec_deg: float
    priority: int
    row: int = Field(description="Row of the file (1 = first data row).")
    line: int | None = Field(description="Line of the file (CSV only; null when unknown).")
    pmra_mas_yr: float | None = Field(None, description=PMRA_DOC + " Absent: the file has no "
                                      "such column.")
    pmdec_mas_yr: float | None = Field(None, description=PMDEC_DOC)
    parallax_mas: float | None = Field(None, description=PARALLAX_DOC)
    radial_velocity_km_s: float | None = Field(None, description=RV_DOC)
    ref_epoch_yr: float | None = Field(None, description=REF_EPOCH_DOC)


class TargetList(BaseModel):
    """A stored target list. ``targets`` (less ``row``/``line``) is a valid ``targets`` array for
    segmentation, plan and job requests; or pass ``target_list_id`` instead."""

    target_list_id: str = Field(description="Give it as `target_list_id` in segmentation, plan "
                                "and job requests instead of `targets`.")
    filename: str
    n_targets: int = Field(ge=1, description="Targets in the list.")
    created_at: float = Field(description="Unix time the list was stored.")
    expires_at: float = Field(description="Unix time after which the list may be deleted "
                              "(MXS_TARGET_LIST_RETENTION_S; the newest "
                              "MXS_TARGET_LIST_RETENTION_COUNT are kept).")
    targets: list[ListedTarget] = Field(description="The targets in file order; empty when "
                                        "asked with `include_targets=false`.")
    columns: dict[str, str | None] = Field(
        description="The file's column read for each field (null: none, defaults used).")
    notices: list[str] = Field(description="Defaults applied and mixed value forms found.")


# --------------------------------------------------------------------------- the store


@dataclass(frozen=True)
class StoredList:
    """One stored list: its targets as columns (``line`` None when unknown)."""

    list_id: str
    filename: str
    created_at: float
    columns: dict[str, str | None]
    notices: list[str]
    ids: list[str]
    ra_deg: list[float]
    dec_deg: list[float]
    priority: list[int]
    line: list[int | None]
    motion: dict[str, list[float | None]] = field(default_factory=dict)

    @property
    def n_targets(self) -> int:
        return len(self.ids)

    def listed(self) -> list[dict[str, Any]]:
        return listed_targets(self.ids, self.ra_deg, self.dec_deg, self.priority, self.line,
                              self.motion)

    def motion_of(self, k: int) -> dict[str, float]:
        """The motion fields target ``k`` gives."""
        return {f: v[k] for f, v in self.motion.items() if v[k] is not None}  # type: ignore[misc]


def _connect(db_path: Path) -> sqlite3.Connection:
    con = sqlite3.connect(str(db_path), timeout=30.0, isolation_level=None)
    con.execute("PRAGMA busy_timeout = 30000")
    con.execute("PRAGMA synchronous = FULL")
    return con


class TargetListStore:
    """The SQL of the ``target_lists`` table; one short-lived connection per call."""

    def __init__(self, db_path: str | Path, retention_s: float, retention_count: int):
        self.db_path = Path(db_path)
        self.retention_s = retention_s
        self.retention_count = retention_count

    def init(self) -> None:
        if self.db_path.parent and not self.db_path.parent.exists():
            self.db_path.parent.mkdir(parents=True, exist_ok=True)
        con = _connect(self.db_path)
        try:
            con.execute("PRAGMA journal_mode = WAL")
            con.execute(_SCHEMA)
        finally:
            con.close()

    def put(self, parsed: ParsedList) -> tuple[str, float]:
        """Store a read table (then apply the retention); return its id and creation time."""
        now = time.time()
        list_id = uuid.uuid4().hex
        con = _connect(self.db_path)
        try:
            con.execute("INSERT INTO target_lists VALUES (?, ?, ?, ?, ?, ?, ?)",
                        (list_id, parsed.source, parsed.n_targets, json.dumps(parsed.columns),
                         json.dumps(parsed.notices), parsed.blob, now))
            self._expire(con, now)
        finally:
            con.close()
        return list_id, now

    def get(self, list_id: str) -> StoredList | None:
        """The list, or None when there is none (never stored, or deleted by the retention)."""
        now = time.time()
        con = _connect(self.db_path)
        try:
            row = con.execute(
                "SELECT filename, created_at, columns, notices, targets FROM target_lists "
                "WHERE list_id = ? AND created_at >= ?", (list_id, now - self.retention_s),
            ).fetchone()
        finally:
            con.close()
        if row is None:
            return None
        cols = json.loads(row[4])
        return StoredList(list_id, row[0], row[1], json.loads(row[2]), json.loads(row[3]),
                          cols["id"], cols["ra_deg"], cols["dec_deg"], cols["priority"],
                          cols["line"], cols.get("motion", {}))

    def _expire(self, con: sqlite3.Connection, now: float) -> None:
        con.execute(
            "DELETE FROM target_lists WHERE created_at < ? OR list_id NOT IN ("
            "SELECT list_id FROM target_lists ORDER BY created_at DESC LIMIT ?)",
            (now - self.retention_s, self.retention_count))

    def expires_at(self, stored: StoredList) -> float:
        return stored.created_at + self.retention_s

    def kept(self) -> str:
        return (f"target lists are kept for {self.retention_s:g} s, at most the newest "
                f"{self.retention_count}")


# ----------------------------------------------------------------- reading an upload


def short_name(filename: str | None, most: int = MAX_FILENAME_CHARS) -> str:
    """The base name of an uploaded file (``upload.csv`` when it has none), cut to ``most``
    characters keeping its suffix, so that a long ``....fits.gz`` name is still read as FITS."""
    name = Path(filename or "").name or "upload.csv"
    if len(name) <= most:
        return name
    suffix = table_suffix(name)
    if suffix is not None:
        zipped = next((z for z in COMPRESSED if name.lower().endswith(z)), "")
        tail = name[len(name) - len(suffix) - len(zipped):]
    else:
        tail = Path(name).suffix[:16]
    return name[:most - len(tail) - 3] + "..." + tail


def parse_limits(settings: Settings) -> ParseLimits:
    """The bounds of reading one upload on this server, each with its setting."""
    most, rows_setting = settings.target_limit("target-list")
    return ParseLimits(
        most, rows_setting,
        settings.max_upload_decompressed_bytes, env_name("max_upload_decompressed_bytes"),
        settings.upload_parse_time_s, env_name("upload_parse_time_s"),
        settings.upload_parse_memory_bytes, env_name("upload_parse_memory_bytes"))


def created_out(store: TargetListStore, parsed: ParsedList, list_id: str, created_at: float,
                include_targets: bool) -> Response:
    """The answer of ``POST /v1/target-lists``, as :func:`list_out` writes a stored list, from
    the text the reader's process encoded (no large encoding in the server)."""
    head = {"target_list_id": list_id, "filename": parsed.source,
            "n_targets": parsed.n_targets, "created_at": created_at,
            "expires_at": created_at + store.retention_s}
    tail = {"columns": parsed.columns, "notices": parsed.notices}
    body = (json_text(head)[:-1] + ',"targets":' + (parsed.listed if include_targets else "[]")
            + "," + json_text(tail)[1:])
    return Response(body.encode(), media_type="application/json")


def list_out(store: TargetListStore, stored: StoredList, include_targets: bool) -> JSONResponse:
    body = {"target_list_id": stored.list_id, "filename": stored.filename,
            "n_targets": stored.n_targets, "created_at": stored.created_at,
            "expires_at": store.expires_at(stored),
            "targets": stored.listed() if include_targets else [],
            "columns": stored.columns, "notices": stored.notices}
    return JSONResponse(body)


# ----------------------------------------------------------- requests naming a list


def resolve(req: Any, store: TargetListStore, prefix: tuple[str | int, ...] = ("body",)) -> Any:
    """``req`` with its ``target_list_id`` replaced by the stored list's ``targets`` (``req``
    itself when it has none); an id that names no stored list is a missing resource, a 404
    ``not_found`` naming ``target_list_id`` (under ``prefix``) and the id. Call off the event
    loop: a survey-size list takes a fraction of a second to load."""
    list_id = getattr(req, "target_list_id", None)
    if list_id is None:
        return req
    stored = store.get(list_id)
    if stored is None:
        where = ".".join(str(p) for p in (*prefix, "target_list_id"))
        raise NotFound(f"{where}: no stored target list {clip(list_id)!r} (never uploaded, or "
                       f"deleted: {store.kept()}); upload the table with POST /v1/target-lists")
    # a stored list was validated cell by cell when it was read (service.tables checks what
    # SkyTarget checks: ids, ranges, priorities), so its targets are built without re-validation
    targets = [SkyTarget.model_construct(id=i, ra_deg=r, dec_deg=d, priority=p,
                                         **stored.motion_of(k))
               for k, (i, r, d, p) in enumerate(zip(stored.ids, stored.ra_deg, stored.dec_deg,
                                                    stored.priority, strict=True))]
    return req.model_copy(update={"targets": targets, "target_list_id": None})


# --------------------------------------------------------------------------- routes


IncludeTargets = Annotated[bool, Query(description="Return the targets (default); false "
                                       "answers the summary only, for survey-size lists.")]


def install_target_lists(app: FastAPI, store_of: Callable[[Request], TargetListStore],
                         heavy_of: Callable[[Request], HeavyExecutor], settings: Settings, *,
                         auth: Depends, responses: dict[Any, Any]) -> None:
    """Add ``POST /v1/target-lists`` (read in a slot of ``heavy_of(request)``) and
    ``GET /v1/target-lists/{target_list_id}``."""

    @app.post("/v1/target-lists", operation_id="create_target_list", response_model=TargetList,
              tags=["targets"], dependencies=[auth], responses=responses)
    async def create_target_list(
        request: Request,
        file: Annotated[UploadFile, File(description="Target table: CSV, VizieR's TSV, ECSV, "
                                         "VOTable or FITS, plain or compressed with gzip, bzip2 "
                                         "or xz (by the file name's suffix; by the content "
                                         "when the name has none known; CSV when neither "
                                         "tells).")],
        include_targets: IncludeTargets = True,
    ) -> Response:
        """Read a target table the way `mxs-planner plan` does and store it: VizieR's TSV export
        as it is downloaded (comment lines, units and dashes rows), VO UCDs and common
        column names (VizieR `_RAJ2000`/`_DEJ2000`, Gaia `source_id`/`ra`/`dec`, ...),
        sexagesimal or decimal values cell by cell, column units, row ids and priority 1 when
        the file has none (said in `notices`). A bad cell is a 422 naming the file's row (and
        CSV or TSV line) and column; more than `MXS_MAX_TARGET_LIST_TARGETS` targets a 422, a body
        over `MXS_MAX_UPLOAD_BYTES` a 413. Also a 422 naming the file, for what the file's
        content decides: a file that is not a table (one line, "<file>: not a table: <what it
        is>"), a table with no rows or no RA or Dec
        column, duplicate ids, empty or duplicate column names, more than the bounds on
        columns, line or cell length and decompressed bytes, a read past
        `MXS_UPLOAD_PARSE_TIME_S`. Pass `target_list_id` to a segmentation, plan or job request
        instead of `targets`."""
        store = store_of(request)
        name = short_name(file.filename)
        limits = parse_limits(settings)

        def work(ticket: Ticket) -> Response:
            parsed = parse_upload(file.file, name, limits, ticket.cancel)
            list_id, created_at = store.put(parsed)
            return created_out(store, parsed, list_id, created_at, include_targets)

        return await run_heavy(heavy_of(request), work, request.is_disconnected,
                               settings.retry_after_s, what="upload")

    @app.get("/v1/target-lists/{target_list_id}", operation_id="get_target_list",
             response_model=TargetList, tags=["targets"], dependencies=[auth],
             responses={404: {"model": ErrorResponse, "description": "No such target list (never stored, or deleted "
                                             "by the retention)."}, **responses})
    async def get_target_list(target_list_id: str, request: Request,
                              include_targets: IncludeTargets = True) -> JSONResponse:
        """A stored target list, as `POST /v1/target-lists` answered it."""
        store = store_of(request)

        def work() -> JSONResponse:
            stored = store.get(target_list_id)
            if stored is None:
                raise NotFound(f"target list {target_list_id!r} not found ({store.kept()})")
            return list_out(store, stored, include_targets)

        return await run_in_threadpool(work)
