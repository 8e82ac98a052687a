"""The process that draws one finding chart from an uploaded FITS image (the server side is
:mod:`service.finding_charts`).

:func:`child_main` runs in a process of its own, forked for one request from the upload
readers' fork server (:mod:`service.uploads`): it limits its own address space
(``RLIMIT_AS``: what it starts with plus ``ChartJob.memory_bytes``) and CPU time, dies with its
parent, reads the image with :func:`models.finding_chart.read_fits_image` (whose size cap is
checked from the header before any pixel is read), renders the chart and sends one outcome
back through a pipe:

* ``("ok", png_bytes)``: the chart;
* ``("invalid", (field, message))``: an :class:`~models.errors.InputError` of the file or the
  chart (422 naming the field);
* ``("memory", "")``: a ``MemoryError`` (the address-space limit was reached; 413);
* ``("failed", reason)``: any other error of the reader (422).
"""

from __future__ import annotations

import errno
import os
from dataclasses import dataclass
from typing import Any

from models.errors import InputError
from service.parent_death import kill_with_parent
from service.upload_child import MEMORY_EXIT, limit_resources


@dataclass(frozen=True)
class ChartJob:
    """One chart to draw: the uploaded FITS file on disk, the chart's geometry and the bounds
    of the process drawing it."""

    path: str
    ra_deg: float
    dec_deg: float
    half_width_arcmin: float
    up_pa_deg: float
    size_px: int
    max_pixels: int
    time_limit_s: float
    memory_bytes: int


def draw(job: ChartJob) -> bytes:
    """The PNG of ``job``'s chart."""
    from models.finding_chart import load_fits_image, render_chart

    image = load_fits_image(job.path, max_pixels=job.max_pixels)
    chart = render_chart(image, job.ra_deg, job.dec_deg, job.half_width_arcmin, job.up_pa_deg,
                         job.size_px)
    return chart.to_png()


def _preload() -> None:
    """Import the chart's libraries before the limits apply: their code is not the file's
    doing and must not count against the memory the file may take."""
    import PIL.Image  # noqa: F401
    import scipy.ndimage  # noqa: F401
    from astropy.visualization import ZScaleInterval  # noqa: F401

    import models.finding_chart  # noqa: F401


def _reason(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"[:200]


def child_main(conn: Any, job: ChartJob) -> None:
    """The child process: draw ``job`` under its limits and send the outcome on ``conn``."""
    kill_with_parent()
    outcome: tuple[str, Any]
    try:
        _preload()
        limit_resources(job.memory_bytes, job.time_limit_s)
        outcome = ("ok", draw(job))
    except InputError as exc:
        outcome = ("invalid", (exc.field, exc.message))
    except MemoryError:
        outcome = ("memory", "")
    except OSError as exc:
        outcome = ("memory", "") if exc.errno == errno.ENOMEM else ("failed", _reason(exc))
    except Exception as exc:  # noqa: BLE001 - astropy raises many kinds on odd files
        outcome = ("failed", _reason(exc))
    try:
        conn.send(outcome)
        conn.close()
    except MemoryError:
        os._exit(MEMORY_EXIT)
