"""Shared fixture for the service tests: a real uvicorn server on a free port."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
from hypothesis import settings

# The suite runs on fixed seeds: each property test draws the same examples on every run
# (``derandomize``). MXS_HYPOTHESIS_EXPLORE=1 draws new ones, to look for new edge cases.
settings.register_profile("fixed", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("explore" if os.environ.get("MXS_HYPOTHESIS_EXPLORE") else "fixed")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class LiveServer:
    url: str
    db: Path


@pytest.fixture(scope="session")
def live_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    """``service.app.create_app`` served by uvicorn in a thread (job DB in a temp dir)."""
    import uvicorn

    from service.app import create_app
    from service.settings import Settings

    db = tmp_path_factory.mktemp("live") / "jobs.sqlite3"
    app = create_app(Settings(job_db=db, workers=1, max_targets=500, max_body_bytes=200_000,
                              default_time_limit_s=10.0, heavy_queue=32))
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/v1/health", timeout=1).status_code == 200:
                break
        except httpx.HTTPError:
            time.sleep(0.05)
    else:  # pragma: no cover
        raise RuntimeError("live server did not start")
    yield LiveServer(url, db)
    server.should_exit = True
    thread.join(timeout=10)


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    """The planner's compiled kernels, loaded (or compiled) before any test's time budget starts,
    as the service and the image do at start-up."""
    from planner.kernels import compile_kernels

    compile_kernels()
