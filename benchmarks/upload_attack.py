"""Upload-attack benchmark of the HTTP service (issue-41 protocol): ``benchmarks/load.py --attack``.

Builds the hostile-upload corpus of ``tests/hostile_corpus.py`` at the size of the upload limit
(``--attack-mb``, default 50 MB less 64 KB of multipart framing; compression bombs
decompressing to 2.5 x the server's decompressed-bytes limit), starts a real server
(``python -m service.cli serve``, default settings) and, for each file alone and then for
pairs of files at once:

* uploads it (``POST /v1/target-lists``) and records the status, the seconds to the answer,
  the answer's size and whether it names the problem;
* probes ``/v1/health`` every 20 ms meanwhile: latency p99 and max, failures;
* samples the RSS of the server's process tree (psutil, children included: the fork server
  and the upload readers) every 20 ms: the peak.

The goals: each answer a 4xx naming the problem within 10 s, health within 100 ms, the tree
within 2 GB. A valid 100,000-row list (``valid_100k_rows``, answered with all its targets)
runs alone and two at once the same way. Prints JSON. Timings depend on the machine's load: run it alone.

    python benchmarks/load.py --attack                # the full sizes
    python benchmarks/load.py --attack --attack-mb 4  # a smoke size
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from hostile_corpus import Attack, build  # noqa: E402

from benchmarks.serve import end, probe_health, start_server, workdir  # noqa: E402

GOAL_S, GOAL_HEALTH_MS, GOAL_RSS_MB = 10.0, 100.0, 2048.0
PAIRS = (("fits_many_rows", "gzip_bomb"), ("many_columns", "many_columns"),
         ("duplicate_columns_to_limit", "long_cell_to_limit"), ("bzip2_bomb", "votable_many_rows"),
         ("valid_100k_rows", "valid_100k_rows"))
_PROBE_S = 0.02


class TreeRss:
    """Peak RSS of a process and all its descendants, sampled in a thread."""

    def __init__(self, pid: int):
        self.root = psutil.Process(pid)
        self.peak_mb = 0.0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def now_mb(self) -> float:
        total = 0
        for p in [self.root, *self.root.children(recursive=True)]:
            try:
                total += p.memory_info().rss
            except psutil.Error:
                pass
        return total / 2**20

    def _run(self) -> None:
        while not self._stop.wait(_PROBE_S):
            try:
                self.peak_mb = max(self.peak_mb, self.now_mb())
            except psutil.Error:
                pass

    def stop(self) -> float:
        self._stop.set()
        self._t.join()
        return round(self.peak_mb, 1)


def valid_survey(directory: Path, n: int = 100_000) -> Attack:
    """Not an attack: a valid list at the default target limit (its answer, with every target,
    is about 11 MB), read and answered while health is probed."""
    rng = np.random.default_rng(1)
    ra, dec = 150 + rng.uniform(-1, 1, n), 2 + rng.uniform(-1, 1, n)
    path = directory / "survey.csv"
    path.write_text("id,ra_deg,dec_deg,priority\n" + "".join(
        f"s{i},{r!r},{d!r},{1 + i % 9}\n" for i, (r, d) in enumerate(zip(ra.tolist(), dec.tolist(),
                                                                        strict=True))))
    return Attack("valid_100k_rows", "survey.csv", path, (200,), f'"n_targets":{n}')


def _upload(url: str, att: Attack, out: dict[str, Any]) -> None:
    t0 = time.monotonic()
    try:
        with open(att.path, "rb") as f:
            r = httpx.post(url + "/v1/target-lists", params={"include_targets": "true"},
                           files={"file": (att.filename, f)}, timeout=120)
        body = r.text
        out.update(status=r.status_code, answer_bytes=len(r.content),
                   message=body[:200], names_problem=att.says in body[:1000],
                   retry_after=r.headers.get("retry-after"))
    except httpx.HTTPError as exc:
        out.update(status=None, message=f"{type(exc).__name__}: {exc}"[:200], names_problem=False)
    out["s"] = round(time.monotonic() - t0, 2)
    out["ok"] = (out["status"] in att.statuses and out["names_problem"] and out["s"] <= GOAL_S)


def _ms(xs: list[float], q: float) -> float | None:
    return round(float(np.percentile(xs, q)) * 1000, 1) if xs else None


def run_attacks(url: str, pid: int, attacks: list[Attack]) -> dict[str, Any]:
    """Upload ``attacks`` at once; health latency and the tree's peak RSS meanwhile."""
    outs: list[dict[str, Any]] = [{"attack": a.name, "file_bytes": a.path.stat().st_size}
                                  for a in attacks]
    threads = [threading.Thread(target=_upload, args=(url, a, o)) for a, o in zip(attacks, outs, strict=True)]
    rss = TreeRss(pid)
    lat, fails = probe_health(url, threads, _PROBE_S)
    peak = rss.stop()
    health = {"probes": len(lat) + fails, "failures": fails, "p99_ms": _ms(lat, 99),
              "max_ms": _ms(lat, 100)}
    ok = (all(o["ok"] for o in outs) and fails == 0 and (health["max_ms"] or 0) <= GOAL_HEALTH_MS
          and peak <= GOAL_RSS_MB)
    return {"uploads": outs, "health": health, "peak_rss_mb": peak, "meets_goals": ok}


def _valid_upload(url: str) -> dict[str, Any]:
    path = ROOT / "examples" / "ngc869_targets.csv"
    t0 = time.monotonic()
    r = httpx.post(url + "/v1/target-lists", files={"file": (path.name, path.read_bytes())},
                   params={"include_targets": "false"}, timeout=60)
    return {"status": r.status_code, "n_targets": r.json().get("n_targets"),
            "s": round(time.monotonic() - t0, 2)}


def scenario_attack(a: argparse.Namespace) -> dict[str, Any]:
    """The attack scenario (see the module doc), on a planner served by :mod:`benchmarks.serve`."""
    size = int(a.attack_mb * 1e6) - 65_536
    decompressed_limit = 100_000_000 if a.attack_mb >= 50 else int(a.attack_mb * 1e6)
    with workdir() as d:
        t0 = time.monotonic()
        corpus = build(d / "corpus", size, int(decompressed_limit * 2.5)) + [valid_survey(d)]
        built_s = round(time.monotonic() - t0, 1)
        srv = start_server(d / "jobs.sqlite3", max_upload_decompressed_bytes=decompressed_limit)
        try:
            idle = TreeRss(srv.pid)
            time.sleep(0.5)
            out: dict[str, Any] = {"upload_limit_bytes": 50_000_000, "attack_file_bytes": size,
                                   "decompressed_limit_bytes": decompressed_limit,
                                   "corpus_built_s": built_s, "idle_rss_mb": idle.stop(),
                                   "valid_upload_before": _valid_upload(srv.url)}
            by_name = {att.name: att for att in corpus}
            out["alone"] = {att.name: run_attacks(srv.url, srv.pid, [att]) for att in corpus}
            out["pairs"] = {f"{x}+{y}": run_attacks(srv.url, srv.pid, [by_name[x], by_name[y]])
                            for x, y in PAIRS}
            out["valid_upload_after"] = _valid_upload(srv.url)
            runs = [*out["alone"].values(), *out["pairs"].values()]
            out["summary"] = {
                "all_meet_goals": all(r["meets_goals"] for r in runs),
                "max_answer_s": max(u["s"] for r in runs for u in r["uploads"]),
                "max_health_ms": max((r["health"]["max_ms"] or 0) for r in runs),
                "max_health_p99_ms": max((r["health"]["p99_ms"] or 0) for r in runs),
                "max_peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
                "failing": [k for k, r in [*out["alone"].items(), *out["pairs"].items()]
                            if not r["meets_goals"]]}
            return out
        finally:
            end(srv)
