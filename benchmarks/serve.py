"""A planner served for the benchmarks: start ``mxs-planner serve`` on a free port with its
job database and ``MXS_*`` settings, watch its process tree (alive, RSS, CPU seconds), probe
its health while other threads load it, and stop it (:mod:`benchmarks.load`,
:mod:`benchmarks.upload_attack`, :mod:`benchmarks.programme`, :mod:`benchmarks.survey`)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Server:
    proc: subprocess.Popen[bytes]
    url: str

    @property
    def pid(self) -> int:
        return self.proc.pid


def start_server(db: Path, start_timeout_s: float = 60.0, **env: Any) -> Server:
    """``mxs-planner serve`` on a free port with job database ``db`` and the settings ``env``
    (``workers=1`` is ``MXS_WORKERS=1``), once its health answers (within ``start_timeout_s``)."""
    port = free_port()
    full = {**os.environ, "MXS_JOB_DB": str(db), **{f"MXS_{k.upper()}": str(v)
                                                     for k, v in env.items()}}
    proc = subprocess.Popen([sys.executable, "-m", "service.cli", "serve", "--port", str(port),
                             "--log-level", "warning"], cwd=ROOT, env=full,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + start_timeout_s
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/v1/health", timeout=1).status_code == 200:
                return Server(proc, url)
        except httpx.HTTPError:
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("server did not start")


def _stat(pid: int) -> list[str] | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def alive(pid: int) -> bool:
    st = _stat(pid)
    return st is not None and st[0] not in ("Z", "X")


def tree(pid: int) -> list[int]:
    """``pid`` and all its descendants."""
    parents: dict[int, int] = {}
    for p in Path("/proc").glob("[0-9]*"):
        st = _stat(int(p.name))
        if st is not None:
            parents[int(p.name)] = int(st[1])
    out, frontier = [pid], [pid]
    while frontier:
        frontier = [c for c, pp in parents.items() if pp in frontier]
        out += frontier
    return out


def rss_mb(pids: list[int]) -> float:
    total = 0
    for pid in pids:
        try:
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total / 1024


def cpu_s(pids: list[int]) -> float:
    tick = os.sysconf("SC_CLK_TCK")
    return sum((int(st[11]) + int(st[12])) / tick for p in pids if (st := _stat(p)))


class RssMonitor:
    """Peak RSS of a process tree, sampled every 0.2 s in a thread."""

    def __init__(self, pid: int):
        self.pid, self.peak_mb, self._stop = pid, 0.0, threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            self.peak_mb = max(self.peak_mb, rss_mb(tree(self.pid)))

    def stop(self) -> float:
        self._stop.set()
        self._t.join()
        return round(self.peak_mb, 1)


def end(server: Server, sig: int = signal.SIGTERM) -> dict[str, Any]:
    """Stop a server with ``sig``; seconds to exit and processes of its tree left 5 s later."""
    pids = tree(server.pid)
    t0 = time.monotonic()
    server.proc.send_signal(sig)
    try:
        server.proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        server.proc.kill()
        server.proc.wait()
    exit_s = time.monotonic() - t0
    time.sleep(max(5.0 - (time.monotonic() - t0), 0.0))
    left = [p for p in pids[1:] if alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    return {"exit_s": round(exit_s, 2), "orphans_after_5s": len(left)}


@contextmanager
def workdir() -> Any:
    with tempfile.TemporaryDirectory(prefix="mxs-load-") as d:
        yield Path(d)


def probe_health(url: str, threads: list[threading.Thread], every_s: float = 0.05
                 ) -> tuple[list[float], int]:
    """Start ``threads`` and ask ``/v1/health`` every ``every_s`` until they end: the
    latencies of its answers (s), and how many probes failed."""
    for t in threads:
        t.start()
    out = probe_while(url, lambda: any(t.is_alive() for t in threads), every_s)
    for t in threads:
        t.join()
    return out


def probe_while(url: str, going: Callable[[], bool], every_s: float) -> tuple[list[float], int]:
    """Ask ``/v1/health`` every ``every_s`` while ``going()``: the latencies of its answers
    (s), and how many probes failed."""
    lat: list[float] = []
    fails = 0
    with httpx.Client(base_url=url, timeout=10) as c:
        while going():
            t0 = time.perf_counter()
            try:
                ok = c.get("/v1/health").status_code == 200
            except httpx.HTTPError:
                ok = False
            if ok:
                lat.append(time.perf_counter() - t0)
            else:
                fails += 1
            time.sleep(every_s)
    return lat, fails
