"""Reading an uploaded target table where it cannot hurt the server.

:func:`parse_upload` reads one upload in a child process (:mod:`service.upload_child`),
forked from a fork server that has the table reader (astropy) and the server's main module
imported, so a child starts in tens of milliseconds. The child runs under an address-space
limit (``RLIMIT_AS``: what it starts with plus ``MXS_UPLOAD_PARSE_MEMORY_BYTES``) and the
server kills it past the wall-clock limit (``MXS_UPLOAD_PARSE_TIME_S``) or as soon as its
request is cancelled (client gone, server stopping). The server's own threads only wait on a
pipe, so the event loop and every other request go on whatever the file holds.

The caller runs :func:`parse_upload` in a heavy-request slot
(:class:`service.executor.HeavyExecutor`): uploads share the admission control of the
stage requests (503 with ``Retry-After`` when every slot is taken).

Outcomes: the read table (:class:`~service.upload_child.ParsedList`); a bad file, or one
that took longer than the time limit to read, a 422 naming ``body.file``; a file whose
reading reached the memory limit, a 413; each message names the limit and its setting. A
reader that ends without an answer for another reason is a server fault: logged, 503.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.forkserver
import shutil
import signal
import sys
import tempfile
import threading
import time
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import IO, Any

from service.errors import FieldError, ServiceError
from service.executor import Cancelled
from service.tables import table_suffix
from service.upload_child import MEMORY_EXIT, ParsedList, ParseJob, ParseLimits, child_main

log = logging.getLogger("service.uploads")

#: Modules the fork server imports once, so that each child starts without importing them.
PRELOAD = ["service.upload_child", "service.chart_child", "models.finding_chart", "astropy.table",
           "astropy.io.ascii", "astropy.io.fits", "astropy.io.votable", "astropy.coordinates", "astropy.units"]
_POLL_S = 0.05
#: Exit codes of a reader that ran out of memory before it could answer: its own report, or
#: a signal (the kernel's OOM killer, or C code that failed an allocation).
_MEMORY_EXITS = (MEMORY_EXIT, -signal.SIGKILL, -signal.SIGSEGV, -signal.SIGABRT, -signal.SIGBUS)
_lock = threading.Lock()
_context: Any = None


class UploadTooLarge(ServiceError):
    """Reading the upload reached the memory limit: HTTP 413."""

    status_code = 413
    code = "too_large"


def context() -> Any:
    """The multiprocessing context of the readers: a fork server preloading :data:`PRELOAD`
    (spawn where there is no fork server)."""
    global _context
    with _lock:
        if _context is None:
            if "forkserver" in multiprocessing.get_all_start_methods():
                ctx = multiprocessing.get_context("forkserver")
                ctx.set_forkserver_preload(PRELOAD + _main_module())
            else:  # pragma: no cover - Windows
                ctx = multiprocessing.get_context("spawn")
            _context = ctx
        return _context


def _main_module() -> list[str]:
    """The server's main module, for the fork server to import once: a child process imports
    its parent's main module before it runs (multiprocessing does), which is then a lookup of
    modules already loaded instead of seconds of imports in every child. ``__main__`` for a
    script (``mxs-planner``), the module's name for ``python -m service.cli``."""
    main = sys.modules.get("__main__")
    name = getattr(getattr(main, "__spec__", None), "name", None)
    if name:  # a package's __main__ (python -m pytest) is not imported by children either
        return [] if name.endswith("__main__") else [name]
    return ["__main__"] if getattr(main, "__file__", None) else []


def start_fork_server() -> None:
    """Start the fork server (imports the reader: about a second) in a background thread,
    so that the first upload does not wait for it. Safe to call many times."""
    if context().get_start_method() != "forkserver":  # pragma: no cover - Windows
        return

    def start() -> None:
        try:
            multiprocessing.forkserver.ensure_running()
        except Exception:  # noqa: BLE001 - the first upload will try again and report
            log.exception("could not start the upload readers' fork server")

    threading.Thread(target=start, name="mxs-upload-forkserver", daemon=True).start()


def save_upload(src: IO[bytes], filename: str, workdir: Path) -> Path:
    """Copy the uploaded file to ``workdir`` in chunks (never whole in memory), under a
    name with the format suffix of ``filename`` (CSV when it has none)."""
    path = workdir / f"upload{table_suffix(filename) or '.csv'}"
    src.seek(0)
    with open(path, "wb") as dst:
        shutil.copyfileobj(src, dst, 1 << 20)
    return path


def parse_upload(src: IO[bytes], filename: str, limits: ParseLimits,
                 cancel: threading.Event) -> ParsedList:
    """Read the uploaded file ``src`` (its client's name ``filename``) in a child process under
    ``limits``; stop it when ``cancel`` is set (raises :class:`Cancelled`). Call from a
    worker thread: it blocks until the child is done."""
    with tempfile.TemporaryDirectory(prefix="mxs-upload-") as tmp:
        path = save_upload(src, filename, Path(tmp))
        ctx = context()
        reader, writer = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=child_main, args=(writer, ParseJob(str(path), filename, limits)),
                           name="mxs-upload-reader", daemon=True)
        try:
            proc.start()
            writer.close()
            outcome = _await(proc, reader, limits.time_limit_s, cancel)
        finally:
            _stop(proc)
            reader.close()
    return _answer(outcome, filename, limits, proc.exitcode)


def _await(proc: BaseProcess, reader: Connection, time_limit_s: float,
           cancel: threading.Event) -> tuple[str, Any] | None:
    """The child's outcome; ``("time", "")`` past the limit; None when it died silently."""
    deadline = time.monotonic() + time_limit_s
    while True:
        if reader.poll(_POLL_S):
            try:
                outcome: tuple[str, Any] = reader.recv()
                return outcome
            except (EOFError, OSError):
                return None
        if cancel.is_set():
            raise Cancelled()
        if time.monotonic() >= deadline:
            return ("time", "")
        if not proc.is_alive() and not reader.poll(0):
            return None


def _stop(proc: BaseProcess) -> None:
    if proc.pid is None:
        return
    if proc.is_alive():
        proc.kill()
    proc.join(timeout=5.0)


def _answer(outcome: tuple[str, Any] | None, filename: str, limits: ParseLimits,
            exitcode: int | None) -> ParsedList:
    loc = ("body", "file")
    if outcome is not None and outcome[0] == "ok":
        parsed: ParsedList = outcome[1]
        return parsed
    if outcome is not None and outcome[0] == "invalid":
        raise FieldError(loc, outcome[1])
    if outcome is not None and outcome[0] == "failed":
        log.warning("upload %r: the reader failed: %s", filename[:100], outcome[1])
        raise FieldError(loc, f"{filename}: cannot read as a table ({outcome[1][:100]})")
    time_out = outcome is not None and outcome[0] == "time"
    if time_out or exitcode == -signal.SIGXCPU:
        raise FieldError(loc, f"{filename}: reading the table took longer than the limit of "
                         f"{limits.time_limit_s:g} s ({limits.time_setting}="
                         f"{limits.time_limit_s:g}); the reader was stopped", "time_limit")
    if outcome is None and exitcode not in _MEMORY_EXITS:  # not the file's doing: a fault
        log.error("upload %r: the reader process ended with exit code %s and no answer",
                  filename[:100], exitcode)
        raise ServiceError(f"the upload reader failed (exit code {exitcode}); it has been "
                           "logged", status_code=503, code="internal_error")
    raise UploadTooLarge(f"{filename}: reading the table needs more than {limits.memory_bytes} "
                         f"bytes of memory ({limits.memory_setting}={limits.memory_bytes}); "
                         "the reader was stopped")
