"""Error types, their HTTP answers, and the safety net that keeps every answer below 500.

- request validation -> 422 ``{"detail": [pydantic errors], "message": "field: why"}``
- a body that cannot be parsed at all (not UTF-8, nested too deeply, a number with too many
  digits, malformed JSON) -> 422 naming ``body``
- domain input errors (``InputError``, ``InstrumentError``, :class:`FieldError`) -> 422
- a stage out of time with no partial answer (``TimeLimitExceeded``) -> 422 naming ``time_limit_s``
- :class:`ServiceError` -> its own status with ``{"error": code, "detail": message}``
- anything unexpected -> logged with its traceback, answered 503 ``internal_error``
- bodies over the configured size -> 413
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections import deque
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from models.errors import InputError, TimeLimitExceeded
from models.instrument import InstrumentError

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


MAX_ECHO_DEPTH = 32  # deeper parts of an echoed input are replaced by OMITTED
OMITTED = "<omitted>"


def json_safe(obj: Any, max_depth: int | None = None) -> Any:
    """A copy of ``obj`` that ``json.dumps(allow_nan=False)`` accepts (odd values -> str);
    containers nested deeper than ``max_depth`` become ``"<omitted>"``."""
    if isinstance(obj, (dict, list, tuple)):
        if max_depth is not None and max_depth <= 0:
            return OMITTED
        depth = None if max_depth is None else max_depth - 1
        if isinstance(obj, dict):
            return {str(k): json_safe(v, depth) for k, v in obj.items()}
        return [json_safe(v, depth) for v in obj]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else str(obj)
    if obj is None or isinstance(obj, (str, int, bool)):
        return obj
    return str(obj)


def error_body(code: str, message: str) -> dict[str, str]:
    """The body of every error but a 422: its message quotes at most :data:`ECHO_CHARS`
    characters of any input (a path parameter, a file name)."""
    return {"error": code, "detail": clip_message(message)}


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


ECHO_CHARS = 100  # an answer quotes at most this many characters of any one input
MAX_MESSAGE_CHARS = 1000  # and no error message is longer
MAX_ERRORS = 50  # errors listed in a 422's detail (the message sums up the first 10)
# a run of non-blank characters this long is an echo (a clipped one, with its quotes, is shorter)
_LONG_RUN = re.compile(rf"\S{{{ECHO_CHARS + 11},}}")


def clip(text: str, limit: int = ECHO_CHARS) -> str:
    """``text`` if it has at most ``limit`` characters, else its first ``limit`` and its length."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


def clip_message(message: str, inputs: tuple[str, ...] = ()) -> str:
    """``message`` quoting at most about :data:`ECHO_CHARS` characters of any input: each
    long string of ``inputs`` and every longer run of non-blank characters is clipped
    (:func:`clip`), and the whole to :data:`MAX_MESSAGE_CHARS`."""
    for text in inputs:
        if len(text) > ECHO_CHARS and text in message:
            message = message.replace(text, clip(text))
    if len(message) > ECHO_CHARS:
        message = _LONG_RUN.sub(lambda m: clip(m.group()), message)
    return clip(message, MAX_MESSAGE_CHARS)


def _huge(v: Any) -> bool:
    """An integer whose decimal form would be longer than :data:`ECHO_CHARS` digits."""
    return isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 3.33 * ECHO_CHARS


def _huge_text(v: int) -> str:
    """A huge integer described, not written out (``str()`` refuses over 4300 digits)."""
    return f"<an integer of about {v.bit_length() * 0.30103:.0f} digits>"


def _short(value: Any) -> Any:
    """An echoed input as it goes into the answer: itself when its JSON has at most
    :data:`ECHO_CHARS` characters, else the first of them as a string (:func:`clip`)."""
    if _huge(value):
        return _huge_text(value)
    v = _encodable(json_safe(value, MAX_ECHO_DEPTH))
    if isinstance(v, str):
        return clip(v)
    if isinstance(v, (list, dict)):
        text = json.dumps(v)
        return v if len(text) <= ECHO_CHARS else clip(text)
    return v


def _strings(value: Any) -> tuple[str, ...]:
    """The strings an error's input or context holds at its top level."""
    if isinstance(value, str):
        return (value,)
    if isinstance(value, dict):
        return tuple(v for v in value.values() if isinstance(v, str))
    return ()


def _ctx_value(v: Any, inputs: tuple[str, ...]) -> Any:
    """A value of an error's ``ctx`` (a limit, a pattern, the error raised) as answered."""
    if _huge(v):
        return _huge_text(v)
    if isinstance(v, (bool, int, float)):
        return v
    return clip_message(_encodable(str(json_safe(v, MAX_ECHO_DEPTH))), inputs)


def _answer_item(raw: dict[str, Any]) -> dict[str, Any]:
    """One error of a 422 with every echo of the input clipped: ``input``, the string parts
    of ``loc`` (an unknown field's name), ``ctx`` and ``msg``."""
    e = {k: v for k, v in raw.items() if k not in ("input", "url", "ctx")}
    e = _encodable(json_safe(e, MAX_ECHO_DEPTH))
    e["loc"] = [clip(p) if isinstance(p, str) else p for p in e.get("loc", [])]
    inputs = _strings(raw.get("input")) + _strings(raw.get("ctx"))
    if "msg" in e:
        e["msg"] = clip_message(str(e["msg"]), inputs)
    if isinstance(raw.get("ctx"), dict):
        e["ctx"] = {str(k): _ctx_value(v, inputs) for k, v in raw["ctx"].items()}
    if "input" in raw:
        e["input"] = _short(raw["input"])
    return e


def _validation_answer(errors: list[dict[str, Any]]) -> JSONResponse:
    errs = [_answer_item(raw) for raw in errors[:MAX_ERRORS]]
    msg = "; ".join(f"{_loc_str(e.get('loc', []))}: {e.get('msg', '')}" for e in errs[:10])
    if len(errors) > 10:
        shown = min(len(errors), MAX_ERRORS)
        msg += f"; ... {len(errors)} errors in all, the first {shown} in detail"
    return JSONResponse(status_code=422, content={"detail": errs, "message": msg})


async def _on_validation(_: Request, exc: RequestValidationError) -> JSONResponse:
    return _validation_answer([_json_decode_error(e) for e in exc.errors()])


def _json_decode_error(e: dict[str, Any]) -> dict[str, Any]:
    """FastAPI's malformed-JSON error (``loc`` ("body", offset)) with the parser's reason."""
    loc = list(e.get("loc", ()))
    if e.get("type") != "json_invalid" or len(loc) != 2 or not isinstance(loc[1], int):
        return e
    why = (e.get("ctx") or {}).get("error", "")
    return {"loc": ["body"], "type": "json_invalid",
            "msg": f"the body is not valid JSON: {why} at character {loc[1]}"}


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


def unparsable_body_reason(cause: BaseException) -> str:
    """Why a request body could not be read as JSON at all."""
    if isinstance(cause, UnicodeError):
        return "the body is not valid UTF-8 text (JSON must be UTF-8 encoded)"
    if isinstance(cause, RecursionError):
        return "the JSON is nested too deeply"
    if isinstance(cause, ValueError) and "digits" in str(cause):
        return f"a number has too many digits ({cause})"
    return f"the body is not valid JSON ({type(cause).__name__}: {cause})"


async def _on_http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
    if exc.status_code == 400:
        # the body could not be parsed (FastAPI's "There was an error parsing the body" for
        # JSON, Starlette's multipart errors): a 422 naming the body and why
        cause = exc.__cause__ or exc.__context__
        generic = exc.detail == "There was an error parsing the body"
        why = (unparsable_body_reason(cause) if generic and cause is not None
               else f"the body cannot be read: {exc.detail}")
        return _validation_answer([{"loc": ["body"], "msg": why,
                                    "type": "json_invalid" if generic else "body_invalid"}])
    codes = {401: "unauthorized", 404: "not_found", 405: "method_not_allowed", 413: "too_large"}
    detail = exc.detail if isinstance(exc.detail, str) else json.dumps(json_safe(exc.detail))
    return JSONResponse(
        status_code=exc.status_code,
        content=error_body(codes.get(exc.status_code, "http_error"), detail),
        headers=getattr(exc, "headers", None),
    )


async def _on_time_limit(_: Request, exc: TimeLimitExceeded) -> JSONResponse:
    """A stage that cannot answer partially ran out of the request's time: the limit is the
    client's to raise (422 on ``time_limit_s``), not a server fault."""
    msg = f"{exc}; the {exc.stage} stage needs a longer time_limit_s for this input"
    return _validation_answer([{"loc": ["body", "time_limit_s"], "msg": msg, "type": "time_limit"}])


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(RequestValidationError, _on_validation)  # type: ignore[arg-type]
    app.add_exception_handler(ServiceError, _on_service_error)  # type: ignore[arg-type]
    app.add_exception_handler(StarletteHTTPException, _on_http_error)  # type: ignore[arg-type]
    for t in (InstrumentError, InputError):
        app.add_exception_handler(t, _on_domain_input_error)  # type: ignore[arg-type]
    app.add_exception_handler(TimeLimitExceeded, _on_time_limit)  # type: ignore[arg-type]


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
    """Reject request bodies larger than the route's limit with 413 before the app parses
    them: ``routes`` maps a path to its ``(bytes, setting)``, every other path gets
    ``(max_bytes, setting)``; the 413 names the setting and its value."""

    def __init__(self, app: ASGIApp, max_bytes: int, setting: str = "MXS_MAX_BODY_BYTES",
                 routes: dict[str, tuple[int, str]] | None = None):
        self.app = app
        self.max_bytes = max_bytes
        self.setting = setting
        self.routes = dict(routes or {})

    def limit(self, scope: Scope) -> tuple[int, str]:
        path = scope.get("path", "")
        root = scope.get("root_path", "")
        if root and path.startswith(root):
            path = path[len(root):]
        return self.routes.get(path.rstrip("/") or "/", (self.max_bytes, self.setting))

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        max_bytes, setting = self.limit(scope)
        too_large = error_body(
            "too_large", f"request body exceeds the limit of {max_bytes} bytes ({setting}="
            f"{max_bytes} on this server)")
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    n = int(value)
                except ValueError:
                    await _send_json(send, 422, {
                        "detail": [{"loc": ["header", "content-length"], "msg": "not an integer",
                                    "type": "int_parsing"}],
                        "message": "header.content-length: not an integer"})
                    return
                if n > max_bytes:
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
            if size > max_bytes:
                await _send_json(send, 413, too_large)
                return
            chunks.append(body)
            more = message.get("more_body", False)
        # replayed as received: a big body in one message would be parsed (multipart) in
        # one call on the event loop
        replay = deque({"type": "http.request", "body": c, "more_body": True} for c in chunks)
        if replay:
            replay[-1]["more_body"] = False

        async def rest() -> Message:
            if replay:
                return replay.popleft()
            return await receive()

        await self.app(scope, rest, send)


def _replay(messages: list[Message], receive: Receive) -> Receive:
    async def replay() -> Message:
        return messages.pop(0) if messages else await receive()

    return replay
