"""Benchmark: a survey-size target list through the API (issue goal: 100,000 targets over
4 deg2 segmented through ``POST /v1/segmentations`` in <= 10 s wall and <= 2 GB server RSS).

Starts ``mxs-planner serve`` (``python -m service.cli serve``) in its own process with a fresh
job database, then, for ``--n`` uniform random targets in a square of ``--area-deg2`` at
(RA 150, Dec 2):

1. uploads the list as CSV and as FITS (``POST /v1/target-lists?include_targets=false``);
2. segments it by ``target_list_id`` and with the same targets inline (``POST
   /v1/segmentations``), checking that both answers put every target in exactly one pointing
   and agree.

Each step reports its wall time (client side, request sent to answer read) and the server's
RSS after it and peak (``VmRSS`` / ``VmHWM`` of the server process; the job pool's worker
processes are not involved and not counted). Prints one JSON document. Timings depend on the
machine's load: run it on an idle machine.

    python benchmarks/survey.py                  # 100,000 targets over 4 deg2
    python benchmarks/survey.py --n 5000         # a smoke run
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.serve import start_server  # noqa: E402


def targets(n: int, area_deg2: float, seed: int) -> tuple[list[str], np.ndarray, np.ndarray,
                                                          np.ndarray]:
    rng = np.random.default_rng(seed)
    half = area_deg2 ** 0.5 / 2
    ra = 150.0 + rng.uniform(-half, half, n) / np.cos(np.radians(2.0))
    dec = 2.0 + rng.uniform(-half, half, n)
    return [f"s{i}" for i in range(n)], ra, dec, 1 + rng.integers(0, 9, n)


def csv_file(ids: list[str], ra: np.ndarray, dec: np.ndarray, prio: np.ndarray) -> bytes:
    rows = "".join(f"{i},{r!r},{d!r},{p}\n" for i, r, d, p in
                   zip(ids, ra.tolist(), dec.tolist(), prio.tolist(), strict=True))
    return ("id,ra_deg,dec_deg,priority\n" + rows).encode()


def fits_file(ids: list[str], ra: np.ndarray, dec: np.ndarray, prio: np.ndarray) -> bytes:
    from astropy.table import Table

    buf = io.BytesIO()
    Table({"id": ids, "ra_deg": ra, "dec_deg": dec, "priority": prio}).write(buf, format="fits")
    return buf.getvalue()


def memory_mb(pid: int) -> dict[str, float]:
    status = Path(f"/proc/{pid}/status").read_text().splitlines()
    kb = {ln.split(":")[0]: int(ln.split()[1]) for ln in status if ln.startswith(("VmRSS", "VmHWM"))}
    return {"rss_mb": kb["VmRSS"] / 1024, "peak_rss_mb": kb["VmHWM"] / 1024}


def step(name: str, pid: int, call: Any) -> tuple[dict[str, Any], httpx.Response]:
    t0 = time.perf_counter()
    r = call()
    wall = time.perf_counter() - t0
    if r.status_code != 200:
        raise RuntimeError(f"{name}: HTTP {r.status_code}: {r.text[:500]}")
    return {"step": name, "wall_s": round(wall, 3), **memory_mb(pid)}, r


def partition(seg: dict[str, Any], ids: list[str]) -> int:
    members = [t for p in seg["pointings"] for t in p["target_ids"]]
    if len(members) != len(ids) or set(members) != set(ids):
        raise RuntimeError("the pointings do not hold every target exactly once")
    return len(seg["pointings"])


def run(n: int, area_deg2: float, seed: int) -> dict[str, Any]:
    ids, ra, dec, prio = targets(n, area_deg2, seed)
    files = {"csv": csv_file(ids, ra, dec, prio), "fits": fits_file(ids, ra, dec, prio)}
    inline = {"targets": [{"id": i, "ra_deg": r, "dec_deg": d, "priority": p} for i, r, d, p in
                          zip(ids, ra.tolist(), dec.tolist(), prio.tolist(), strict=True)]}
    body = json.dumps(inline).encode()
    with tempfile.TemporaryDirectory(prefix="mxs-survey-") as tmp:
        srv = start_server(Path(tmp) / "jobs.sqlite3", start_timeout_s=120.0, workers=1)
        proc, url = srv.proc, srv.url
        try:
            rows = [{"step": "idle server", "wall_s": 0.0, **memory_mb(proc.pid)}]
            with httpx.Client(base_url=url, timeout=600) as c:
                list_ids = {}
                for fmt, data in files.items():
                    row, r = step(f"upload {fmt} ({len(data)} bytes)", proc.pid, lambda d=data, f=fmt: c.post(
                        "/v1/target-lists", params={"include_targets": "false"},
                        files={"file": (f"survey.{f}", d)}))
                    list_ids[fmt] = r.json()["target_list_id"]
                    rows.append(row)
                row, by_id = step("segmentation by target_list_id", proc.pid, lambda: c.post(
                    "/v1/segmentations", json={"target_list_id": list_ids["csv"]}))
                rows.append({**row, "pointings": partition(by_id.json(), ids)})
                row, direct = step(f"segmentation inline ({len(body)} bytes)", proc.pid,
                                   lambda: c.post("/v1/segmentations", content=body,
                                                  headers={"content-type": "application/json"}))
                rows.append({**row, "pointings": partition(direct.json(), ids)})
                if by_id.json()["pointings"] != direct.json()["pointings"]:
                    raise RuntimeError("by id and inline give different pointings")
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    return {"benchmark": "survey", "targets": n, "area_deg2": area_deg2, "seed": seed,
            "machine": {"cpus": os.cpu_count(), "load_avg": os.getloadavg(),
                        "python": platform.python_version()},
            "steps": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100_000, help="targets (default 100,000)")
    ap.add_argument("--area-deg2", type=float, default=4.0, help="field area (default 4 deg2)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    print(json.dumps(run(a.n, a.area_deg2, a.seed), indent=2))


if __name__ == "__main__":
    main()
