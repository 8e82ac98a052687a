"""ASGI middleware of the server's own: a deadline for reading the request body.

A client must deliver its whole body within ``MXS_BODY_TIMEOUT_S`` of the request's start;
otherwise the request is answered 408 and the connection closed, so slow senders cannot hold
buffers (up to the body limit each) for ever. After a large body the allocator is asked to
hand freed memory back to the operating system (``malloc_trim`` on glibc).
"""

from __future__ import annotations

import asyncio
import ctypes
import ctypes.util
import json
import sys
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.errors import error_body

_TRIM_AFTER_BYTES = 1 << 20


class _BodyTimeout(Exception):
    pass


def _malloc_trim() -> Any:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return libc.malloc_trim
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return None


_TRIM = _malloc_trim()


def release_memory() -> None:
    """Return freed heap pages to the OS where the C library can."""
    if _TRIM is not None:
        _TRIM(0)


class BodyTimeoutMiddleware:
    """Answer 408 when the request body is not complete ``timeout_s`` after the start."""

    def __init__(self, app: ASGIApp, timeout_s: float):
        self.app = app
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout_s
        body_done = False
        size = 0
        started = False

        async def timed_receive() -> Message:
            nonlocal body_done, size
            if body_done:  # e.g. polling for a disconnect while the answer is computed
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), max(deadline - loop.time(), 0.0))
            except TimeoutError as exc:
                raise _BodyTimeout() from exc
            if message["type"] == "http.request":
                size += len(message.get("body", b""))
                body_done = not message.get("more_body", False)
            else:
                body_done = True
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, timed_receive, tracking_send)
        except _BodyTimeout:
            if not started:
                await _send_408(send, self.timeout_s)
        finally:
            if size >= _TRIM_AFTER_BYTES:
                release_memory()


async def _send_408(send: Send, timeout_s: float) -> None:
    raw = json.dumps(error_body(
        "timeout", f"the request body was not received within {timeout_s:g} s")).encode()
    await send({
        "type": "http.response.start",
        "status": 408,
        "headers": [(b"content-type", b"application/json"),
                    (b"content-length", str(len(raw)).encode()), (b"connection", b"close")],
    })
    await send({"type": "http.response.body", "body": raw})
