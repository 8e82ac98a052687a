"""Error types, their HTTP answers, and the safety net that keeps every answer below 500.

- request validation -> 422 ``{"detail": [pydantic errors], "message": "field: why"}``
- domain input errors (``InputError``, ``InstrumentError``, :class:`FieldError`) -> 422
- :class:`ServiceError` -> its own status with ``{"error": code, "detail": message}``
- a stage whose domain module has not landed -> 501 ``stage_unavailable``
- anything unexpected -> logged with its traceback, answered 503 ``internal_error``
- bodies over the configured size -> 413
"""

from __future__ import annotations

import json
import logging
import math
import re
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger("service")


class ServiceError(Exception):
    """An error with a definite HTTP status and machine-readable code."""

    status_code = 400
    code = "bad_request"

    def __init__(self, message: str, *, status_code: int | None = None, code: str | None = None):
        super().__init__(message)
        self.message = message
        if status_code is not None:
            self.status_code = status_code
        if code is not None:
            self.code = code


class StageUnavailable(ServiceError):
    """The domain code of a pipeline stage is not installed (yet)."""

    status_code = 501
    code = "stage_unavailable"

    def __init__(self, stage: str, why: str = ""):
        msg = f"the {stage} stage is not available in this build"
        super().__init__(msg + (f": {why}" if why else ""))
        self.stage = stage


class NotFound(ServiceError):
    status_code = 404
    code = "not_found"


class FieldError(ServiceError):
    """Valid JSON whose meaning is invalid: 422 naming the field (``loc`` as in pydantic)."""

    status_code = 422
    code = "invalid_input"

    def __init__(self, loc: tuple[str | int, ...], message: str, type_: str = "value_error"):
        super().__init__(f"{_loc_str(loc)}: {message}")
        self.loc = loc
        self.type = type_
        self.bare = message


def _loc_str(loc: tuple[str | int, ...] | list[Any]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def json_safe(obj: Any) -> Any:
    """A copy of ``obj`` that ``json.dumps(allow_nan=False)`` accepts (odd values -> str)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else str(obj)
    if obj is None or isinstance(obj, (str, int, bool)):
        return obj
    return str(obj)


def error_body(code: str, message: str) -> dict[str, str]:
    return {"error": code, "detail": message}


def _encodable(obj: Any) -> Any:
    """``obj`` with every string made encodable as UTF-8: a lone surrogate (valid in JSON as
    ``"\\ud800"``, not in UTF-8) is echoed as its escape instead of failing the answer."""
    if isinstance(obj, str):
        return obj.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(obj, dict):
        return {_encodable(k): _encodable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_encodable(v) for v in obj]
    return obj


def _validation_answer(errors: list[dict[str, Any]]) -> JSONResponse:
    errs = _encodable(json_safe(errors))
    for e in errs:
        if isinstance(e.get("input"), (str, list, dict)) and len(json.dumps(e["input"])) > 500:
            e["input"] = "<omitted>"
        e.pop("url", None)
    msg = "; ".join(f"{_loc_str(e.get('loc', []))}: {e.get('msg', '')}" for e in errs[:10])
    return JSONResponse(status_code=422, content={"detail": errs, "message": msg})


async def _on_validation(_: Request, exc: RequestValidationError) -> JSONResponse:
    return _validation_answer(list(exc.errors()))


async def _on_service_error(_: Request, exc: ServiceError) -> JSONResponse:
    if isinstance(exc, FieldError):
        return _validation_answer(
            [{"loc": list(exc.loc), "msg": exc.bare, "type": exc.type}]
        )
    return JSONResponse(status_code=exc.status_code, content=error_body(exc.code, exc.message))


async def _on_domain_input_error(_: Request, exc: ValueError) -> JSONResponse:
    field = getattr(exc, "field", None)
    loc: list[Any] = ["body", *parse_loc(str(field))] if field else ["body"]
    msg = getattr(exc, "message", None) or str(exc)
    return _validation_answer([{"loc": loc, "msg": msg, "type": "value_error"}])


def parse_loc(field: str) -> list[str | int]:
    """``"targets[3].dec_deg"`` -> ``["targets", 3, "dec_deg"]``."""
    out: list[str | int] = []
    for part in re.findall(r"[^.\[\]]+|\[\d+\]", field):
        out.append(int(part[1:-1]) if part.startswith("[") else part)
    return out


async def _on_http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
    codes = {401: "unauthorized", 404: "not_found", 405: "method_not_allowed", 413: "too_large"}
    detail = exc.detail if isinstance(exc.detail, str) else json.dumps(json_safe(exc.detail))
    return JSONResponse(
        status_code=exc.status_code,
        content=error_body(codes.get(exc.status_code, "http_error"), detail),
        headers=getattr(exc, "headers", None),
    )


def domain_input_errors() -> tuple[type[Exception], ...]:
    """Exception types the domain raises for invalid input (imported lazily: may not exist)."""
    types: list[type[Exception]] = []
    try:
        from models.instrument import InstrumentError

        types.append(InstrumentError)
    except ImportError:  # pragma: no cover
        pass
    try:
        from models.errors import InputError

        types.append(InputError)
    except ImportError:
        pass
    return tuple(types)


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, _on_validation)  # type: ignore[arg-type]
    app.add_exception_handler(ServiceError, _on_service_error)  # type: ignore[arg-type]
    app.add_exception_handler(StarletteHTTPException, _on_http_error)  # type: ignore[arg-type]
    for t in domain_input_errors():
        app.add_exception_handler(t, _on_domain_input_error)  # type: ignore[arg-type]


async def _send_json(send: Send, status: int, body: dict[str, Any]) -> None:
    raw = json.dumps(body).encode()
    await send({
        "type": "http.response.start",
        "status": status,
        "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(raw)).encode())],
    })
    await send({"type": "http.response.body", "body": raw})


class CatchAllMiddleware:
    """Last line of defence: an unexpected exception is logged and answered 503, never 500."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except Exception as exc:  # noqa: BLE001 - the whole point
            log.exception("unhandled error on %s %s", scope.get("method"), scope.get("path"))
            if not started:
                await _send_json(send, 503, error_body(
                    "internal_error",
                    f"the server could not complete this request ({type(exc).__name__}); "
                    "it has been logged",
                ))


class _BodyTooLarge(Exception):
    pass


class BodyLimitMiddleware:
    """Reject request bodies larger than ``max_bytes`` with 413 before the app parses them."""

    def __init__(self, app: ASGIApp, max_bytes: int):
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        too_large = error_body(
            "too_large", f"request body exceeds the limit of {self.max_bytes} bytes"
        )
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    n = int(value)
                except ValueError:
                    await _send_json(send, 400, error_body("bad_request", "bad Content-Length"))
                    return
                if n > self.max_bytes:
                    await _send_json(send, 413, too_large)
                    return
        # also count what actually arrives (chunked bodies carry no Content-Length)
        chunks: list[bytes] = []
        size = 0
        more = True
        while more:
            message = await receive()
            if message["type"] != "http.request":
                await self.app(scope, _replay([message], receive), send)
                return
            body = message.get("body", b"")
            size += len(body)
            if size > self.max_bytes:
                await _send_json(send, 413, too_large)
                return
            chunks.append(body)
            more = message.get("more_body", False)
        replay = [{"type": "http.request", "body": b"".join(chunks), "more_body": False}]

        async def rest() -> Message:
            if replay:
                return replay.pop()
            return await receive()

        await self.app(scope, rest, send)


def _replay(messages: list[Message], receive: Receive) -> Receive:
    async def replay() -> Message:
        return messages.pop(0) if messages else await receive()

    return replay
