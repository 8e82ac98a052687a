"""The service's own pages and files: the observation-preparation page (``/``, files under
``/static``), Swagger UI at ``/docs`` served from a packaged copy (no CDN, so it works on an
observatory network without internet). Uploaded target tables are read and stored by
:mod:`service.target_lists`.

The page is an ordinary client of the public API: it uses nothing the API does not offer.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

SWAGGER_PREFIX = "/docs-assets"


def _static_root() -> Path:
    return Path(str(resources.files("service").joinpath("static")))


def _swagger_root() -> Path:
    import swagger_ui_bundle

    return Path(swagger_ui_bundle.swagger_ui_path)


def install_web(app: FastAPI) -> None:
    """Add the page and the offline ``/docs`` to ``app`` (built with ``docs_url=None``)."""
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
