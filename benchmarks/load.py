"""Load and restart benchmark of the HTTP service (issue-17 protocol): prints JSON.

Every scenario runs real ``python -m service.cli serve`` processes on free local ports, with a
fresh job database in a temporary directory, and talks to them with httpx.

* ``load``: after one warm-up request, ``--clients`` threads post motion plans (``examples/requests/motion_plan.json``
  with ``time_limit_s = --limit``) for ``--seconds``; a refused client waits 1 s and retries.
  A prober gets ``/v1/health`` every 50 ms. Reported: health latency p50/p99/max and failures;
  heavy requests answered within limit + 1 s, answered late, refused at once (503/429 with
  ``Retry-After``, < 1 s), refused without ``Retry-After`` or slowly, errors (connection,
  other statuses); the server tree's peak RSS.
* ``greedy`` (``--greedy``: this scenario alone, 12 clients unless ``--clients`` says
  otherwise): after one warm-up request, ``--clients`` greedy clients post motion plans back
  to back for ``--seconds``, ignoring ``Retry-After`` (no pause after a refusal), while a
  prober in a process of its own (``--prober thread``: a thread beside the clients') gets
  ``/v1/health`` every 50 ms. Reported: health latency
  p50/p95/p99/max and failures, the heavy requests' answers by status, and the config.
* ``abandoned``: clients that give up after 1 s; the CPU seconds the server tree spends in
  the ``--seconds / 2`` after they left (work for clients that left should stop).
* ``restarts``: plan jobs submitted, then (a) ``kill -9`` mid-run and a new server,
  (b) SIGTERM (time to exit) and a new server, (c) a second server started on the same
  database while the first computes, (d) a rolling restart of two servers. For each: finished
  results lost, live jobs failed by another server, processes left 5 s after a server
  ended, jobs that end failed (with their reasons) and jobs still not finished at the end.
* ``flood``: ``--flood`` job submissions as fast as possible: 202 / 429 with Retry-After /
  other; the server's RSS and database size growth.
* ``slow_bodies``: ``--slow`` connections each sending 95 % of a body just under the body
  limit, slowly; statuses received, time to be answered, server RSS before / peak / 5 s
  after.
* ``--attack`` (upload attacks, :mod:`benchmarks.upload_attack`): the hostile-upload corpus
  of ``tests/hostile_corpus.py`` at the upload limit (``--attack-mb``), each file alone and
  pairs at once: status, answer time and whether it names the problem; ``/v1/health``
  latency p99/max and the server tree's peak RSS (psutil, children included) meanwhile.

Timings depend on the machine and its load: run it alone.

Usage:
    python benchmarks/load.py                 # 50 clients, 60 s, the full sizes
    python benchmarks/load.py --smoke         # a small size of every scenario (minutes)
    python benchmarks/load.py --only load,flood --out load.json
    python benchmarks/load.py --attack        # upload attacks only, at the 50 MB upload limit
    python benchmarks/load.py --greedy        # 12 greedy clients (no back-off), 60 s
    python benchmarks/load.py --greedy --clients 50
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.serve import (  # noqa: E402
    RssMonitor,
    Server,
    cpu_s,
    end,
    probe_health,
    probe_while,
    rss_mb,
    start_server,
    tree,
    workdir,
)

EXAMPLES = ROOT / "examples" / "requests"
SCENARIOS = ("load", "greedy", "abandoned", "restarts", "flood", "slow_bodies")
DEFAULT_SCENARIOS = ("load", "abandoned", "restarts", "flood", "slow_bodies")
DEFAULT_CLIENTS = {"load": 50, "greedy": 12}


def pct(xs: list[float], q: float) -> float | None:
    return round(float(np.percentile(xs, q)) * 1000, 1) if xs else None


# ---------------------------------------------------------------------- load


def motion_request(limit_s: float) -> dict[str, Any]:
    req = json.loads((EXAMPLES / "motion_plan.json").read_text())
    req["time_limit_s"] = limit_s
    return req


def warm_up(srv: Server, req: dict[str, Any]) -> float:
    """One motion plan before measuring (first calls import and compile the kernels)."""
    t0 = time.monotonic()
    httpx.post(srv.url + "/v1/motion-plans", json=req, timeout=300)
    return round(time.monotonic() - t0, 2)


def scenario_load(a: argparse.Namespace) -> dict[str, Any]:
    with workdir() as d:
        srv = start_server(d / "jobs.sqlite3")
        warm_s = warm_up(srv, motion_request(a.limit))
        mon = RssMonitor(srv.pid)
        try:
            stop = time.monotonic() + a.seconds
            outcomes: list[str] = []
            lock = threading.Lock()
            req = motion_request(a.limit)

            def client() -> None:
                with httpx.Client(base_url=srv.url, timeout=a.limit + 30) as c:
                    while time.monotonic() < stop:
                        kind = _heavy_outcome(c, req, a.limit)
                        with lock:
                            outcomes.append(kind)
                        if kind.startswith("refused"):
                            time.sleep(1.0)

            health = _probe_while(srv.url, [threading.Thread(target=client) for _ in range(a.clients)])
            counts = {k: outcomes.count(k) for k in sorted(set(outcomes))}
            return {"clients": a.clients, "seconds": a.seconds, "limit_s": a.limit,
                    "warm_up_s": warm_s, "health": health, "heavy": counts, "peak_rss_mb": mon.stop()}
        finally:
            mon.stop()
            end(srv)


def _heavy_outcome(c: httpx.Client, req: dict[str, Any], limit_s: float) -> str:
    t0 = time.monotonic()
    try:
        r = c.post("/v1/motion-plans", json=req)
    except httpx.HTTPError as exc:
        return f"error_{type(exc).__name__}"
    dt = time.monotonic() - t0
    if r.status_code == 200:
        return "answered_in_limit" if dt <= limit_s + 1.0 else "answered_late"
    if r.status_code in (429, 503):
        at_once = dt < 1.0 and "retry-after" in r.headers
        return "refused_at_once_with_retry_after" if at_once else "refused_slowly_or_no_retry_after"
    return f"status_{r.status_code}"


def _probe_while(url: str, threads: list[threading.Thread]) -> dict[str, Any]:
    lat, fails = probe_health(url, threads)
    return {"probes": len(lat) + fails, "failures": fails, "p50_ms": pct(lat, 50),
            "p99_ms": pct(lat, 99), "max_ms": pct(lat, 100)}


def scenario_greedy(a: argparse.Namespace) -> dict[str, Any]:
    """Greedy clients (no back-off after a refusal) and a prober in a process of its own, so
    that the clients' threads do not delay the prober's own measurement."""
    with workdir() as d:
        srv = start_server(d / "jobs.sqlite3", **a.server_env)
        warm_s = warm_up(srv, motion_request(a.limit))
        try:
            req = motion_request(a.limit)
            statuses: list[str] = []
            lock = threading.Lock()
            ctx = multiprocessing.get_context("spawn")
            mine, theirs = ctx.Pipe(duplex=False)
            prober: Any = (ctx.Process if a.prober == "process" else threading.Thread)(
                target=_prober, args=(srv.url, a.seconds, 0.05, theirs))
            load0 = os.getloadavg()[0]
            prober.start()
            stop = time.monotonic() + a.seconds

            def client() -> None:
                with httpx.Client(base_url=srv.url, timeout=a.limit + 60) as c:
                    while time.monotonic() < stop:
                        status = _greedy_status(c, req)
                        with lock:
                            statuses.append(status)

            threads = [threading.Thread(target=client) for _ in range(a.clients)]
            for t in threads:
                t.start()
            lat, fails = mine.recv()
            prober.join()
            for t in threads:
                t.join()
            health = {"probes": len(lat) + fails, "failures": fails, "p50_ms": pct(lat, 50),
                      "p95_ms": pct(lat, 95), "p99_ms": pct(lat, 99), "max_ms": pct(lat, 100)}
            return {"config": {"clients": a.clients, "seconds": a.seconds, "limit_s": a.limit,
                               "probe_every_s": 0.05, "prober": a.prober,
                               "server_env": a.server_env,
                               "load_average_1min_at_start": round(load0, 2),
                               "commit": _commit()},
                    "warm_up_s": warm_s, "health": health,
                    "heavy_by_status": {k: statuses.count(k) for k in sorted(set(statuses))}}
        finally:
            end(srv)


def _greedy_status(c: httpx.Client, req: dict[str, Any]) -> str:
    try:
        return str(c.post("/v1/motion-plans", json=req).status_code)
    except httpx.HTTPError as exc:
        return f"error_{type(exc).__name__}"


def _prober(url: str, seconds: float, every_s: float, out: Any) -> None:
    """Get ``/v1/health`` every ``every_s`` for ``seconds``; send (latencies s, failures)."""
    stop = time.monotonic() + seconds
    out.send(probe_while(url, lambda: time.monotonic() < stop, every_s))
    out.close()


def _commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, text=True,
                              capture_output=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def scenario_abandoned(a: argparse.Namespace) -> dict[str, Any]:
    n = max(a.clients * 3 // 5, 1)
    with workdir() as d:
        srv = start_server(d / "jobs.sqlite3")
        try:
            req = motion_request(a.limit)
            warm_up(srv, req)

            def leave() -> None:
                try:
                    httpx.post(srv.url + "/v1/motion-plans", json=req, timeout=1.0)
                except httpx.HTTPError:
                    pass

            threads = [threading.Thread(target=leave) for _ in range(n)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            before = cpu_s(tree(srv.pid))
            window = a.seconds / 2
            time.sleep(window)
            return {"clients_that_left_after_1s": n, "window_s": window,
                    "server_cpu_s_after_they_left": round(cpu_s(tree(srv.pid)) - before, 2)}
        finally:
            end(srv)


# ------------------------------------------------------------------- restarts


PLAN_TARGETS = [12]  # targets of examples/requests/plan.json per plan job (--job-targets)


def plan_job() -> dict[str, Any]:
    req = json.loads((EXAMPLES / "plan.json").read_text())
    req["targets"] = req["targets"][:PLAN_TARGETS[0]]
    return {"kind": "plan", "request": req}


def submit(url: str, n: int) -> list[str]:
    ids = []
    for _ in range(n):
        r = httpx.post(url + "/v1/jobs", json=plan_job(), timeout=30)
        r.raise_for_status()
        ids.append(r.json()["job_id"])
    return ids


def states(url: str, ids: list[str]) -> dict[str, dict[str, Any]]:
    return {j: httpx.get(f"{url}/v1/jobs/{j}", timeout=30).json() for j in ids}


def wait_running(url: str, ids: list[str], timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if any(s["status"] == "running" for s in states(url, ids).values()):
            return
        time.sleep(0.2)


def settle(url: str, ids: list[str], timeout_s: float) -> dict[str, dict[str, Any]]:
    deadline = time.monotonic() + timeout_s
    while True:
        st = states(url, ids)
        if all(s["status"] in ("done", "failed") for s in st.values()) or time.monotonic() > deadline:
            return st


def judge(before: dict[str, dict[str, Any]], after: dict[str, dict[str, Any]]) -> dict[str, Any]:
    lost = sum(1 for j, s in before.items() if s["status"] == "done"
               and (after[j]["status"] != "done" or after[j]["result"] != s["result"]))
    failed = [s["error"] for s in after.values() if s["status"] == "failed"]
    return {"jobs": len(after), "finished_results_lost": lost,
            "done": sum(s["status"] == "done" for s in after.values()),
            "failed": len(failed), "failure_reasons": sorted(set(failed)),
            "not_finished": sum(s["status"] in ("queued", "running") for s in after.values())}


def scenario_restarts(a: argparse.Namespace) -> dict[str, Any]:
    env = {"workers": 1, "job_lease_s": 5}
    out: dict[str, Any] = {}
    with workdir() as d:
        db = d / "jobs.sqlite3"
        for name, sig in (("kill_9", signal.SIGKILL), ("sigterm", signal.SIGTERM)):
            srv = start_server(db, **env)
            ids = submit(srv.url, a.jobs)
            wait_running(srv.url, ids)
            before = states(srv.url, ids)
            stopped = end(srv, sig)
            nxt = start_server(db, **env)
            after = settle(nxt.url, ids, a.settle)
            running = sum(s["status"] == "running" for s in before.values())
            out[name] = {**stopped, "running_at_stop": running, **judge(before, after)}
            end(nxt)
        out["second_server"] = _second_server(db, env, a)
        out["rolling_restart"] = _rolling(db, env, a)
    return out


def _second_server(db: Path, env: dict[str, Any], a: argparse.Namespace) -> dict[str, Any]:
    first = start_server(db, **env)
    ids = submit(first.url, a.jobs)
    wait_running(first.url, ids)
    running = [j for j, s in states(first.url, ids).items() if s["status"] == "running"]
    second = start_server(db, **env)
    time.sleep(1.0)
    failed_live = sum(states(second.url, running)[j]["status"] == "failed" for j in running)
    after = settle(first.url, ids, a.settle)
    res = {"live_jobs_failed_by_second_server": failed_live, **judge({}, after)}
    res["orphans_after_5s"] = end(first)["orphans_after_5s"] + end(second)["orphans_after_5s"]
    return res


def _rolling(db: Path, env: dict[str, Any], a: argparse.Namespace) -> dict[str, Any]:
    servers = [start_server(db, **env), start_server(db, **env)]
    ids = submit(servers[0].url, a.jobs) + submit(servers[1].url, a.jobs)
    wait_running(servers[0].url, ids)
    orphans, snapshots = 0, states(servers[0].url, ids)
    for i in range(2):  # replace each server in turn while the other serves
        orphans += end(servers[i])["orphans_after_5s"]
        servers[i] = start_server(db, **env)
        now = states(servers[i].url, ids)
        snapshots = {j: (s if s["status"] == "done" else now[j]) for j, s in snapshots.items()}
    after = settle(servers[0].url, ids, a.settle)
    res = judge(snapshots, after)
    for s in servers:
        orphans += end(s)["orphans_after_5s"]
    res["live_jobs_failed"] = sum(INTERRUPTED_WORD in (s["error"] or "") for s in after.values())
    res["orphans_after_5s"] = orphans
    return res


INTERRUPTED_WORD = "interrupted"


# ---------------------------------------------------------------------- flood


def scenario_flood(a: argparse.Namespace) -> dict[str, Any]:
    with workdir() as d:
        db = d / "jobs.sqlite3"
        srv = start_server(db, workers=1)
        try:
            rss0 = rss_mb([srv.pid])
            codes: list[str] = []
            t0 = time.monotonic()
            with httpx.Client(base_url=srv.url, timeout=30) as c:
                for _ in range(a.flood):
                    r = c.post("/v1/jobs", json=plan_job())
                    refused = r.status_code in (429, 503) and "retry-after" in r.headers
                    codes.append("202" if r.status_code == 202 else
                                 f"{r.status_code}_retry_after" if refused else str(r.status_code))
            size = sum(p.stat().st_size for p in d.glob("jobs.sqlite3*"))
            return {"submitted": a.flood, "seconds": round(time.monotonic() - t0, 2),
                    "answers": {k: codes.count(k) for k in sorted(set(codes))},
                    "server_rss_growth_mb": round(rss_mb([srv.pid]) - rss0, 1),
                    "db_mb": round(size / 2**20, 2)}
        finally:
            end(srv)


# ---------------------------------------------------------------- slow bodies


def scenario_slow_bodies(a: argparse.Namespace) -> dict[str, Any]:
    limit = int(a.body_mb * 1_000_000)
    with workdir() as d:
        srv = start_server(d / "jobs.sqlite3", max_body_bytes=limit, body_timeout_s=a.body_timeout)
        try:
            port = int(srv.url.rsplit(":", 1)[1])
            rss0 = rss_mb(tree(srv.pid))
            mon = RssMonitor(srv.pid)
            results: list[tuple[str, float]] = []
            send_s = a.body_timeout * 3  # a sender far slower than the timeout allows

            def slow() -> None:
                results.append(_slow_sender(port, limit - 10_000, int(0.95 * limit), send_s))

            threads = [threading.Thread(target=slow) for _ in range(a.slow)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            peak = mon.stop()
            time.sleep(5)
            statuses = [s for s, _ in results]
            return {"connections": a.slow, "body_mb": round(0.95 * limit / 1e6, 2),
                    "body_timeout_s": a.body_timeout,
                    "answers": {k: statuses.count(k) for k in sorted(set(statuses))},
                    "answered_after_s_max": round(max(t for _, t in results), 2),
                    "rss_mb": {"before": round(rss0, 1), "peak": peak,
                               "after_5s": round(rss_mb(tree(srv.pid)), 1)}}
        finally:
            end(srv)


def _slow_sender(port: int, declared: int, send: int, over_s: float) -> tuple[str, float]:
    t0 = time.monotonic()
    chunk = 64 * 1024
    pause = over_s / max(send // chunk, 1)
    with socket.create_connection(("127.0.0.1", port), timeout=over_s + 30) as s:
        s.sendall(b"POST /v1/segmentations HTTP/1.1\r\nHost: x\r\nContent-Type: "
                  b"application/json\r\nContent-Length: " + str(declared).encode() + b"\r\n\r\n")
        s.setblocking(False)
        sent, answer = 0, b""
        while time.monotonic() - t0 < over_s + 30:
            try:
                answer += s.recv(4096)
                if b"\r\n" in answer or not answer:
                    break
            except BlockingIOError:
                pass
            if sent < send:
                try:
                    sent += s.send(b" " * min(chunk, send - sent))
                except (BlockingIOError, BrokenPipeError, ConnectionResetError):
                    pass
            time.sleep(pause)
    status = answer.split(b" ", 2)[1].decode() if answer.startswith(b"HTTP/") else "no_answer"
    return status, time.monotonic() - t0


# ------------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--clients", type=int, default=None,
                   help="heavy clients (default 50; 12 with --greedy)")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--limit", type=float, default=5.0, help="time_limit_s of each motion plan")
    p.add_argument("--jobs", type=int, default=6, help="plan jobs per restart scenario")
    p.add_argument("--job-targets", type=int, default=12, help="targets per plan job (<= 12)")
    p.add_argument("--settle", type=float, default=300.0, help="s to wait for jobs to finish")
    p.add_argument("--flood", type=int, default=500)
    p.add_argument("--slow", type=int, default=50, help="slow-body connections")
    p.add_argument("--body-mb", type=float, default=10.0)
    p.add_argument("--body-timeout", type=float, default=20.0)
    p.add_argument("--only", default=",".join(DEFAULT_SCENARIOS))
    p.add_argument("--greedy", action="store_true",
                   help="run the greedy-clients scenario only (no back-off after a refusal)")
    p.add_argument("--prober", choices=("process", "thread"), default="process",
                   help="--greedy's health prober: a process of its own (default), or a thread "
                   "beside the clients' (then their interpreter lock delays it too)")
    p.add_argument("--server-env", action="append", default=[], metavar="NAME=VALUE",
                   help="a server setting, e.g. heavy_threads=2 (MXS_ prefix optional)")
    p.add_argument("--smoke", action="store_true", help="small sizes of every scenario")
    p.add_argument("--out", type=Path)
    p.add_argument("--attack", action="store_true",
                   help="run the upload-attack scenario only (benchmarks/upload_attack.py)")
    p.add_argument("--attack-mb", type=float, default=50.0,
                   help="size of the big attack files, MB (the upload limit)")
    a = p.parse_args(argv)
    if a.attack:
        return _emit({"cpus": os.cpu_count(), "attack": _attack(a)}, a.out)
    a.server_env = _server_env(p, a.server_env)
    if a.greedy:
        a.only = "greedy"
    if a.clients is None:
        a.clients = DEFAULT_CLIENTS["greedy" if a.greedy else "load"]
    if a.smoke:
        a.clients, a.seconds, a.limit, a.jobs, a.settle = 4, 6.0, 2.0, 2, 120.0
        a.job_targets = 3
        a.flood, a.slow, a.body_mb, a.body_timeout = 30, 3, 1.0, 2.0
    PLAN_TARGETS[0] = a.job_targets
    only = [s.strip() for s in a.only.split(",") if s.strip()]
    unknown = sorted(set(only) - set(SCENARIOS))
    if unknown:
        p.error(f"unknown scenarios {unknown}; choose from {SCENARIOS}")
    out: dict[str, Any] = {"smoke": a.smoke, "cpus": os.cpu_count()}
    for name in only:
        out[name] = globals()[f"scenario_{name}"](a)
    return _emit(out, a.out)


def _server_env(p: argparse.ArgumentParser, pairs: list[str]) -> dict[str, str]:
    out = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name:
            p.error(f"--server-env wants NAME=VALUE, got {pair!r}")
        out[name.lower().removeprefix("mxs_")] = value
    return out


def _attack(a: argparse.Namespace) -> dict[str, Any]:
    from benchmarks.upload_attack import scenario_attack

    return scenario_attack(a)


def _emit(out: dict[str, Any], path: Path | None) -> int:
    text = json.dumps(out, indent=2)
    print(text)
    if path:
        path.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
