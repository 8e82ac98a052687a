"""ASGI middleware of the server's own: a deadline and a memory budget for request bodies.

A client must deliver its whole body within ``MXS_BODY_TIMEOUT_S`` of the request's start;
otherwise the request is answered 408 and the connection closed, so slow senders cannot hold
buffers (up to the body limit each) for ever. The bodies being received at one time may
hold at most ``MXS_MAX_BODY_BUFFER_BYTES`` together; a request that would go beyond is
answered 503 with ``Retry-After``. After a large body the allocator is asked to hand freed
memory back to the operating system (``malloc_trim`` on glibc).
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


class _BufferFull(Exception):
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
    """Answer 408 when the request body is not complete ``timeout_s`` after the start, and
    503 when the bodies in flight would hold more than ``buffer_bytes``."""

    def __init__(self, app: ASGIApp, timeout_s: float, buffer_bytes: int, retry_after_s: int):
        self.app = app
        self.timeout_s = timeout_s
        self.buffer_bytes = buffer_bytes
        self.retry_after_s = retry_after_s
        self.in_flight_bytes = 0  # one event loop: no lock needed

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
                n = len(message.get("body", b""))
                size += n
                self.in_flight_bytes += n
                body_done = not message.get("more_body", False)
                if self.in_flight_bytes > self.buffer_bytes and not body_done:
                    raise _BufferFull()
            else:
                body_done = True
            if body_done:
                self.in_flight_bytes -= size
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
                await _send_closing(send, 408, error_body(
                    "timeout", f"the request body was not received within {self.timeout_s:g} s"))
        except _BufferFull:
            if not started:
                await _send_closing(send, 503, error_body(
                    "overloaded", "too many request bodies are being received at once; retry"),
                    [(b"retry-after", str(self.retry_after_s).encode())])
        finally:
            if not body_done:
                self.in_flight_bytes -= size
            if size >= _TRIM_AFTER_BYTES:
                release_memory()


async def _send_closing(send: Send, status: int, body: dict[str, str],
                        extra: list[tuple[bytes, bytes]] | None = None) -> None:
    raw = json.dumps(body).encode()
    await send({
        "type": "http.response.start",
        "status": status,
        "headers": [(b"content-type", b"application/json"),
                    (b"content-length", str(len(raw)).encode()), (b"connection", b"close"),
                    *(extra or [])],
    })
    await send({"type": "http.response.body", "body": raw})
