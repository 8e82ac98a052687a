"""Bearer-token authentication: which requests need the token, and the check itself.

When ``MXS_API_TOKEN`` is set, every route declared with :data:`Auth` (every POST,
``GET /v1/jobs/{job_id}`` and ``GET /v1/target-lists/{target_list_id}``) requires ``Authorization: Bearer <token>``; the health, instrument,
page and API-document routes stay open. :class:`AuthMiddleware` checks the header before the
body is read, so a request without the token is answered 401 whatever its body (malformed,
too large); the :data:`Auth` dependency declares the scheme in the OpenAPI document and
checks again. Tokens are compared in constant time.

An empty (or blank) ``MXS_API_TOKEN`` counts as unset, with a warning at start-up; a server
bound to a non-loopback address without a token logs a warning too (:func:`warn_if_open`).
"""

from __future__ import annotations

import ipaddress
import json
import logging
import secrets
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Request
from fastapi.routing import APIRoute
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.routing import Match
from starlette.types import ASGIApp, Receive, Scope, Send

from service.errors import ServiceError, error_body
from service.settings import Settings

log = logging.getLogger("service")

UNAUTHORIZED = "a valid 'Authorization: Bearer <token>' header is required"

_bearer = HTTPBearer(
    auto_error=False,
    description="Required on POST endpoints, GET /v1/jobs/{job_id} and "
                "GET /v1/target-lists/{target_list_id} when the server has a token (MXS_API_TOKEN).",
)


def effective_token(settings: Settings) -> str | None:
    """The token requests must carry; None when unset, empty or blank."""
    token = settings.api_token
    return token if token is not None and token.strip() else None


def warn_if_empty(settings: Settings) -> None:
    """A loud warning when MXS_API_TOKEN is set but empty: authentication is then off."""
    if settings.api_token is not None and effective_token(settings) is None:
        log.warning("MXS_API_TOKEN is set but empty: authentication is DISABLED and every "
                    "endpoint is open; set a non-empty token (or unset the variable)")


def warn_if_open(host: str, settings: Settings) -> None:
    """A warning when the server listens beyond this machine with no token."""
    if effective_token(settings) is not None or _loopback(host):
        return
    log.warning("listening on %s without MXS_API_TOKEN: anyone who can reach this address can "
                "submit work and read every job; set MXS_API_TOKEN", host)


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def token_matches(header: str | None, token: str) -> bool:
    """``header`` is ``Bearer <token>`` (scheme case-insensitive), compared in constant time."""
    if not header:
        return False
    scheme, _, value = header.strip().partition(" ")
    return scheme.lower() == "bearer" and secrets.compare_digest(
        value.strip().encode("utf-8", "surrogateescape"), token.encode("utf-8"))


def authorize(
    request: Request,
    creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    token = effective_token(request.app.state.mxs.settings)
    if token is None:
        return
    header = None if creds is None else f"{creds.scheme} {creds.credentials}"
    if not token_matches(header, token):
        raise ServiceError(UNAUTHORIZED, status_code=401, code="unauthorized")


Auth = Depends(authorize)


def describe_security(app: FastAPI, required: bool) -> None:
    """The served OpenAPI document says what this server does: the bearer token on the
    :data:`Auth` operations is required when the server has one, optional (``{}`` among the
    requirements) when it has none, as in the committed document."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            doc = build()
            for operations in doc.get("paths", {}).values():
                for op in operations.values():
                    if isinstance(op, dict) and op.get("security"):
                        schemes = [r for r in op["security"] if r]
                        op["security"] = schemes if required else [{}, *schemes]
        return app.openapi_schema  # type: ignore[return-value]

    app.openapi = openapi  # type: ignore[method-assign]


def protected(route: object) -> bool:
    """The route is declared with :data:`Auth`."""
    return isinstance(route, APIRoute) and any(
        d.call is authorize for d in route.dependant.dependencies)


class AuthMiddleware:
    """401 before the body is read for a request to an :data:`Auth` route without the token."""

    def __init__(self, app: ASGIApp, token: str | None):
        self.app = app
        self.token = token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and self.token is not None and self._needs_token(scope):
            headers = dict(scope.get("headers") or [])
            raw = headers.get(b"authorization")
            header = None if raw is None else raw.decode("latin-1")
            if not token_matches(header, self.token):
                await _unauthorized(send)
                return
        await self.app(scope, receive, send)

    @staticmethod
    def _needs_token(scope: Scope) -> bool:
        app = scope.get("app")
        routes = getattr(getattr(app, "router", None), "routes", ())
        return any(protected(r) and r.matches(scope)[0] is Match.FULL for r in routes)


async def _unauthorized(send: Send) -> None:
    raw = json.dumps(error_body("unauthorized", UNAUTHORIZED)).encode()
    await send({"type": "http.response.start", "status": 401, "headers": [
        (b"content-type", b"application/json"), (b"content-length", str(len(raw)).encode()),
        (b"www-authenticate", b"Bearer")]})
    await send({"type": "http.response.body", "body": raw})
