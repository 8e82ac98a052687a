"""``POST /v1/finding-charts``: a finding chart (PNG) from the astronomer's own FITS image.

The observatory network has no internet, so the sky image comes with the request: a FITS file
with a celestial WCS (a 2MASS or Pan-STARRS cut-out). The chart is
:func:`models.finding_chart.render_chart`: a gnomonic projection about (``ra_deg``,
``dec_deg``), ``size_px`` square, ``2 * half_width_arcmin`` across, its up at position angle
``up_pa_deg`` and East 90 degrees counter-clockwise of North (the sky as seen); zscale + asinh
stretched, transparent where the image has no data.

An uploaded image is as hostile as an uploaded table, so it is read the same way
(:mod:`service.uploads`): saved to disk in chunks, then read and drawn in a process of its own
(:mod:`service.chart_child`, forked from the upload readers' fork server) under the upload
readers' wall-clock limit (``MXS_UPLOAD_PARSE_TIME_S``, 422) and memory limit
(``MXS_UPLOAD_PARSE_MEMORY_BYTES``, 413), in a heavy-request slot (503 with ``Retry-After`` when
every slot is taken), and stopped when its client leaves. The request body is held to
``MXS_MAX_BODY_BYTES`` (413) and the image to :data:`MAX_CHART_IMAGE_PIXELS` pixels (422,
checked from the header before any pixel is read).
"""

from __future__ import annotations

import logging
import shutil
import signal
import tempfile
import threading
from pathlib import Path
from typing import IO, Annotated, Any

from fastapi import APIRouter, File, Form, Request, UploadFile
from fastapi.responses import Response

from service.auth import Auth
from service.chart_child import ChartJob, child_main
from service.errors import FieldError, ServiceError
from service.executor import Ticket, run_heavy
from service.response_schemas import ErrorResponse, ValidationErrorResponse
from service.settings import Settings, env_name
from service.upload_child import MEMORY_EXIT
from service.uploads import UploadTooLarge, _await, _stop, context

log = logging.getLogger("service.finding_charts")

#: Most pixels of an uploaded image (a 4096 x 4096 cut-out).
MAX_CHART_IMAGE_PIXELS = 4096 * 4096
MIN_SIZE_PX = 16
MAX_SIZE_PX = 2048
MAX_HALF_WIDTH_ARCMIN = 60.0
IMAGE = ("body", "image")
#: Exit codes of a drawing process that ran out of memory before it could answer.
_MEMORY_EXITS = (MEMORY_EXIT, -signal.SIGKILL, -signal.SIGSEGV, -signal.SIGABRT, -signal.SIGBUS)

PNG_ANSWER: dict[str, Any] = {
    "description": "The chart: a size_px x size_px PNG (grey + alpha; sky light, stars dark; "
                   "transparent where the image has no data).",
    "content": {"image/png": {"schema": {"type": "string", "format": "binary"}}}}
RESPONSES: dict[int | str, dict[str, Any]] = {
    200: PNG_ANSWER,
    401: {"model": ErrorResponse, "description": "Missing or wrong bearer token."},
    408: {"model": ErrorResponse,
          "description": "The request body did not arrive within the server's body timeout."},
    413: {"model": ErrorResponse,
          "description": "Request body over MXS_MAX_BODY_BYTES, or reading the image needs "
                         "more memory than MXS_UPLOAD_PARSE_MEMORY_BYTES."},
    422: {"model": ValidationErrorResponse,
          "description": "Invalid input; `detail[].loc` names the field (`image`: not a FITS "
                         "image, no celestial WCS, too many pixels, or a read past "
                         "MXS_UPLOAD_PARSE_TIME_S)."},
    503: {"model": ErrorResponse,
          "headers": {"Retry-After": {"description": "Seconds to wait before retrying.",
                                      "schema": {"type": "integer", "minimum": 1}}},
          "description": "Overloaded (every heavy-request slot is taken), shutting down, or a "
                         "temporary failure: retry after `Retry-After` seconds."},
}

router = APIRouter(tags=["finding charts"])


@router.post("/v1/finding-charts", operation_id="create_finding_chart", response_class=Response,
             dependencies=[Auth], responses=RESPONSES)
async def create_finding_chart(
    request: Request,
    image: Annotated[UploadFile, File(description="A FITS file with a celestial WCS: its first "
                                      "2-D image HDU (other axes of length 1 allowed) is used.")],
    ra_deg: Annotated[float, Form(ge=0.0, le=360.0, allow_inf_nan=False,
                                  description="RA of the chart's centre (ICRS).")],
    dec_deg: Annotated[float, Form(ge=-90.0, le=90.0, allow_inf_nan=False,
                                   description="Dec of the chart's centre (ICRS).")],
    half_width_arcmin: Annotated[float, Form(gt=0.0, le=MAX_HALF_WIDTH_ARCMIN,
                                             allow_inf_nan=False,
                                             description="Half the chart's side.")],
    up_pa_deg: Annotated[float, Form(allow_inf_nan=False, description=(
        "Position angle (East of North) the chart's up points to; its left is 90 deg "
        "counter-clockwise of up on the sky. 0: North up, East left. A pointing's PA: up is "
        "focal-plane +y, left is focal-plane +x."))] = 0.0,
    size_px: Annotated[int, Form(ge=MIN_SIZE_PX, le=MAX_SIZE_PX,
                                 description="Pixels on each side of the PNG.")] = 512,
) -> Response:
    """A finding chart of the uploaded FITS image about (`ra_deg`, `dec_deg`): a gnomonic (TAN)
    projection, `size_px` square, `2 * half_width_arcmin` across, the sky as seen (up at
    position angle `up_pa_deg`, East 90 deg counter-clockwise of North: North up and East left
    at 0). Pixel (col, row), row 0 at the top, at `up_pa_deg` = 0 has standard coordinates
    xi (East) = h - (col + 0.5) * 2h / size_px and eta (North) = h - (row + 0.5) * 2h /
    size_px, h = `half_width_arcmin`. The image's own WCS places its pixels (rotations, flips,
    distortions, its celestial frame); zscale limits then an asinh stretch bring out faint stars
    while bright cores keep their peak. Read in a process of its own under the upload readers'
    time and memory limits."""
    st = request.app.state.mxs
    settings: Settings = st.settings
    job = ChartJob("", ra_deg, dec_deg, half_width_arcmin, up_pa_deg, size_px,
                   MAX_CHART_IMAGE_PIXELS, settings.upload_parse_time_s,
                   settings.upload_parse_memory_bytes)

    def work(ticket: Ticket) -> Response:
        png = draw_chart(image.file, job, ticket.cancel)
        return Response(png, media_type="image/png")

    return await run_heavy(st.heavy, work, request.is_disconnected, settings.retry_after_s)


def draw_chart(src: IO[bytes], job: ChartJob, cancel: threading.Event) -> bytes:
    """The PNG of ``job``'s chart of the FITS file ``src``, drawn in a child process under
    ``job``'s limits; stop it when ``cancel`` is set (raises :class:`Cancelled`). Call from a
    worker thread: it blocks until the child is done."""
    with tempfile.TemporaryDirectory(prefix="mxs-chart-") as tmp:
        path = Path(tmp) / "image.fits"
        src.seek(0)
        with open(path, "wb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
        ctx = context()
        reader, writer = ctx.Pipe(duplex=False)
        todo = ChartJob(str(path), job.ra_deg, job.dec_deg, job.half_width_arcmin, job.up_pa_deg,
                        job.size_px, job.max_pixels, job.time_limit_s, job.memory_bytes)
        proc = ctx.Process(target=child_main, args=(writer, todo), name="mxs-chart-drawer",
                           daemon=True)
        try:
            proc.start()
            writer.close()
            outcome = _await(proc, reader, job.time_limit_s, cancel)
        finally:
            _stop(proc)
            reader.close()
    return _answer(outcome, job, proc.exitcode)


def _answer(outcome: tuple[str, Any] | None, job: ChartJob, exitcode: int | None) -> bytes:
    if outcome is not None and outcome[0] == "ok":
        png: bytes = outcome[1]
        return png
    if outcome is not None and outcome[0] == "invalid":
        field, message = outcome[1]
        raise FieldError(("body", str(field)), message)
    if outcome is not None and outcome[0] == "failed":
        log.warning("finding chart: the image reader failed: %s", outcome[1])
        raise FieldError(IMAGE, f"not a FITS image: cannot read it ({outcome[1][:100]})")
    time_out = outcome is not None and outcome[0] == "time"
    if time_out or exitcode == -signal.SIGXCPU:
        setting = env_name("upload_parse_time_s")
        raise FieldError(IMAGE, f"reading the image and drawing the chart took longer than the "
                         f"limit of {job.time_limit_s:g} s ({setting}={job.time_limit_s:g}); "
                         "it was stopped", "time_limit")
    if outcome is None and exitcode not in _MEMORY_EXITS:  # not the file's doing: a fault
        log.error("finding chart: the drawing process ended with exit code %s and no answer",
                  exitcode)
        raise ServiceError(f"the finding-chart reader failed (exit code {exitcode}); it has "
                           "been logged", status_code=503, code="internal_error")
    setting = env_name("upload_parse_memory_bytes")
    raise UploadTooLarge(f"body.image: reading the image needs more than {job.memory_bytes} "
                         f"bytes of memory ({setting}={job.memory_bytes}); it was stopped")
