"""The service's own pages and files: the observation-preparation page (``/``, files under
``/static``), Swagger UI at ``/docs`` served from a packaged copy (no CDN, so it works on an
observatory network without internet), and ``POST /v1/target-lists``, which reads an uploaded
target table with the CLI's reader (:mod:`service.tables`).

The page is an ordinary client of the public API: it uses nothing the API does not offer.
"""

from __future__ import annotations

import tempfile
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

from fastapi import FastAPI, File, Request, UploadFile
from fastapi.openapi.docs import get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.params import Depends
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field

from service.errors import FieldError
from service.tables import FORMATS, TargetFileError, read_target_table

SWAGGER_PREFIX = "/docs-assets"
MAX_FILENAME_CHARS = 200


class ListedTarget(BaseModel):
    id: str
    ra_deg: float
    dec_deg: float
    priority: int
    row: int = Field(description="Row of the file (1 = first data row).")
    line: int | None = Field(description="Line of the file (CSV only; null when unknown).")


class TargetList(BaseModel):
    """An uploaded table read as targets; ``targets`` (less ``row``/``line``) is a valid
    ``targets`` array for segmentation, plan and job requests."""

    filename: str
    targets: list[ListedTarget]
    columns: dict[str, str | None] = Field(
        description="The file's column read for each field (null: none, defaults used).")
    notices: list[str] = Field(description="Defaults applied and mixed value forms found.")


def _static_root() -> Path:
    return Path(str(resources.files("service").joinpath("static")))


def _swagger_root() -> Path:
    import swagger_ui_bundle

    return Path(swagger_ui_bundle.swagger_ui_path)


def _suffix(filename: str) -> str:
    low = filename.lower()
    if low.endswith(".fits.gz"):
        return ".fits.gz"
    return Path(low).suffix if Path(low).suffix in FORMATS else ".csv"


def read_upload(data: bytes, filename: str, max_targets: int) -> dict[str, Any]:
    """Parse an uploaded table; every problem is a 422 naming the file's row and column."""
    name = Path(filename or "upload.csv").name[:MAX_FILENAME_CHARS] or "upload.csv"
    with tempfile.TemporaryDirectory(prefix="mxs-upload-") as tmp:
        path = Path(tmp) / f"upload{_suffix(name)}"
        path.write_bytes(data)
        try:
            table = read_target_table(path, name=name)
        except TargetFileError as exc:
            raise FieldError(("body", "file"), str(exc)) from exc
    if len(table.targets) > max_targets:
        raise FieldError(("body", "file"), f"{name}: {len(table.targets)} targets; at most "
                         f"{max_targets} per request on this server", "too_long")
    return {
        "filename": name,
        "targets": [{**t.request(), "row": t.row, "line": t.line} for t in table.targets],
        "columns": table.columns,
        "notices": list(table.notices),
    }


def install_web(app: FastAPI, *, max_targets: int, auth: Depends, responses: dict[Any, Any]) -> None:
    """Add the page, the offline ``/docs`` and ``POST /v1/target-lists`` to ``app`` (built with
    ``docs_url=None``)."""
    app.mount("/static", StaticFiles(directory=_static_root()), name="static")
    app.mount(SWAGGER_PREFIX, StaticFiles(directory=_swagger_root()), name="swagger-ui")

    @app.get("/", include_in_schema=False, response_class=HTMLResponse)
    def web_form() -> str:
        """The observation-preparation page."""
        return (_static_root() / "index.html").read_text()

    @app.get("/docs", include_in_schema=False)
    def docs(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        return get_swagger_ui_html(
            openapi_url=root + (app.openapi_url or "/openapi.json"),
            title=f"{app.title} - API",
            swagger_js_url=f"{root}{SWAGGER_PREFIX}/swagger-ui-bundle.js",
            swagger_css_url=f"{root}{SWAGGER_PREFIX}/swagger-ui.css",
            swagger_favicon_url=f"{root}{SWAGGER_PREFIX}/favicon-32x32.png",
            oauth2_redirect_url=f"{root}/docs/oauth2-redirect",
        )

    @app.get("/docs/oauth2-redirect", include_in_schema=False)
    def docs_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()

    @app.post("/v1/target-lists", operation_id="create_target_list", response_model=TargetList,
              tags=["targets"], dependencies=[auth], responses=responses)
    async def target_lists(
        file: Annotated[UploadFile, File(description="Target table: CSV, ECSV, VOTable or FITS "
                                         "(by the file name's suffix; CSV otherwise).")],
    ) -> dict[str, Any]:
        """Read a target table the way `mxs-planner plan` does: VO UCDs and common column
        names (VizieR `_RAJ2000`/`_DEJ2000`, Gaia `source_id`/`ra`/`dec`, ...), sexagesimal
        or decimal values cell by cell, column units, row ids and priority 1 when the file
        has none (said in `notices`). A bad cell is a 422 naming the file's row (and CSV
        line) and column. Nothing is stored: pass `targets` on to a request."""
        data = await file.read()
        return read_upload(data, file.filename or "upload.csv", max_targets)
