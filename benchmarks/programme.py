"""Whole-programme plan jobs on Dask (issue 20): prints JSON to stdout.

    python benchmarks/programme.py                  # 2,000 targets over 0.25 deg^2, 1 and 2 workers
    python benchmarks/programme.py --smoke          # a tiny field, for CI
    python benchmarks/programme.py --kill-restart   # kill the API and a worker mid-job, restart

Throughput: the thesis' UKIDSS case, 2,000 targets over 0.5 x 0.5 deg (70 % uniform, 30 % in
25 clumps, as ``benchmarks/segmentation.py``) with the thesis priority mix (500/100/10/1 in
shares 0.1/0.4/0.4/0.1), planned as one plan job (``service.programme.run_plan``: segmentation,
then one Dask task per pointing, each committed to a job database) on a local Dask cluster of
1, then 2 single-thread worker processes, warmed up first (the domain imported, the planner's
kernels loaded). It reports the wall time, the throughput ratio, the cost of one pointing
(median, p90: its own wall time on its worker, ``stats.compute_s``), whether both runs gave
the same plan, and whether every pointing has a verified plan or a stated reason.

Kill and restart: a server (``python -m service.cli serve``) with ``MXS_DASK_SCHEDULER`` on a
``dask scheduler`` with two ``dask worker`` processes takes a plan job; once a third of its
pointings are committed the server (with its job-pool process) and one worker are killed
with SIGKILL, a new server and a new worker start on the same database, and the job must end
``done`` with every pointing once, the pointings committed before the kill unchanged and not
computed again.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.segmentation import scattered_field  # noqa: E402

PRIORITY_VALUES = (500, 100, 10, 1)
PRIORITY_SHARES = (0.1, 0.4, 0.4, 0.1)


def programme(n: int, side_deg: float, seed: int = 0) -> list[dict[str, Any]]:
    ra, dec = scattered_field(n, side_deg, seed)
    prio = np.random.default_rng([seed, 1]).choice(PRIORITY_VALUES, size=n, p=PRIORITY_SHARES)
    return [{"id": f"t{i}", "ra_deg": float(a), "dec_deg": float(d), "priority": int(p)}
            for i, (a, d, p) in enumerate(zip(ra, dec, prio, strict=True))]


def content(plan: dict[str, Any]) -> Any:
    """A plan without its ``stats`` (timings), to compare two runs."""
    if isinstance(plan, dict):
        return {k: content(v) for k, v in plan.items() if k != "stats"}
    if isinstance(plan, list):
        return [content(v) for v in plan]
    return plan


def pct(xs: list[float], q: float) -> float | None:
    return round(float(np.percentile(xs, q)), 3) if xs else None


def accounted(plan: dict[str, Any]) -> dict[str, int]:
    """Pointings with a verified executable plan, and those whose answer states why not."""
    ps = plan["pointings"]
    return {"pointings": len(ps), "executable": sum(p["executable"] for p in ps),
            "with_reasons": sum((not p["executable"]) and bool(p["reasons"]) for p in ps),
            "unexplained": sum((not p["executable"]) and not p["reasons"] for p in ps)}


# ------------------------------------------------------------------ throughput


def run_on_cluster(workers: int, request: dict[str, Any], time_limit_s: float,
                   budget_s: float) -> dict[str, Any]:
    from distributed import Client, LocalCluster

    from service import jobs, pipeline, programme
    from service.runners import DaskRunner

    os.environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    inst = pipeline.instrument_from(None)
    with tempfile.TemporaryDirectory(prefix="mxs-programme-") as d, \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                         dashboard_address=None) as cluster, Client(cluster) as client:
        client.run(pipeline.warm_up)
        store = jobs.JobStore(Path(d) / "j.db")
        store.init()
        job_id = store.create("plan", request, time_limit_s, budget_s)
        runner = DaskRunner(cluster.scheduler_address)
        t0 = time.perf_counter()
        plan = programme.run_plan(store, job_id, "", request, inst, runner, budget_s=budget_s)
        wall_s = time.perf_counter() - t0
        runner.close()
    assert plan is not None
    cost = [p["stats"].get("compute_s", 0.0) for p in plan["pointings"]]
    return {"workers": workers, "wall_s": round(wall_s, 2),
            "pointings_per_s": round(len(cost) / wall_s, 4),
            "per_pointing_s": {"median": pct(cost, 50), "p90": pct(cost, 90),
                               "max": pct(cost, 100), "sum": round(sum(cost), 1)},
            "accounted": accounted(plan),
            "motion_plans_failed": plan["stats"]["motion_plans_failed"],
            "unallocated_by_reason": plan["stats"]["unallocated_by_reason"],
            "_plan": plan}


def throughput(a: argparse.Namespace) -> dict[str, Any]:
    targets = programme(a.targets, a.side_deg)
    request = {"targets": targets, "seed": 1}
    runs = [run_on_cluster(w, request, a.time_limit_s, a.budget_s) for w in a.workers]
    plans = [r.pop("_plan") for r in runs]
    by_w = {r["workers"]: r for r in runs}
    out: dict[str, Any] = {
        "case": f"programme_{a.targets}", "n_targets": a.targets,
        "area_deg2": a.side_deg ** 2, "n_pointings": len(plans[0]["pointings"]),
        "time_limit_s": a.time_limit_s, "budget_s": a.budget_s, "runs": runs,
        "same_plan_every_worker_count": all(content(p) == content(plans[0]) for p in plans),
    }
    if 1 in by_w and 2 in by_w:
        out["throughput_ratio_2_vs_1"] = round(by_w[2]["pointings_per_s"]
                                               / by_w[1]["pointings_per_s"], 3)
    med = runs[0]["per_pointing_s"]["median"]
    per_target = len(plans[0]["pointings"]) / a.targets
    out["sizing_100k_targets"] = {
        "pointings_est": round(100_000 * per_target),
        "worker_hours_est": round(100_000 * per_target
                                  * statistics.mean(p["stats"].get("compute_s", 0.0)
                                                    for p in plans[0]["pointings"]) / 3600, 2),
        "note": "same density as this field; one pointing is one single-thread task",
        "per_pointing_median_s": med,
    }
    return out


# -------------------------------------------------------------- kill and restart


def _spawn(args: list[str], env: dict[str, str]) -> subprocess.Popen[bytes]:
    return subprocess.Popen(args, cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def _committed(db: Path, job_id: str) -> dict[int, str]:
    con = sqlite3.connect(str(db), timeout=30)
    try:
        return {int(i): r for i, r in con.execute(
            "SELECT idx, result FROM job_pointings WHERE job_id=?", (job_id,))}
    finally:
        con.close()


def kill_restart(a: argparse.Namespace) -> dict[str, Any]:
    import httpx

    from benchmarks.serve import end, free_port, start_server

    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    port = free_port()
    sched = f"tcp://127.0.0.1:{port}"
    procs = [_spawn(["dask", "scheduler", "--port", str(port), "--dashboard-address", ":0"], env)]
    worker = ["dask", "worker", sched, "--nthreads", "1", "--nworkers", "1", "--no-nanny"]
    workers = [_spawn(worker, env) for _ in range(2)]
    procs += workers
    out: dict[str, Any] = {"case": "kill_restart"}
    try:
        with tempfile.TemporaryDirectory(prefix="mxs-kill-") as d:
            db = Path(d) / "jobs.sqlite3"
            settings = {"dask_scheduler": sched, "workers": 1, "job_lease_s": 3}
            srv = start_server(db, **settings)
            request = {"targets": programme(a.targets, a.side_deg), "seed": 1}
            r = httpx.post(srv.url + "/v1/jobs", json={"kind": "plan", "request": request},
                           timeout=30)
            r.raise_for_status()
            job_id = r.json()["job_id"]
            deadline = time.monotonic() + a.timeout_s
            while True:
                job = httpx.get(f"{srv.url}/v1/jobs/{job_id}", timeout=30).json()
                total, done = job.get("pointings_total"), job.get("pointings_done") or 0
                if total and done >= max(total // 3, 1) or job["status"] in ("done", "failed"):
                    break
                assert time.monotonic() < deadline, job
                time.sleep(0.2)
            end(srv, signal.SIGKILL)
            workers[0].kill()
            before = _committed(db, job_id)
            out.update({"pointings_total": total, "committed_at_kill": len(before),
                        "status_at_kill": job["status"]})
            procs.append(_spawn(worker, env))
            t0 = time.monotonic()
            srv = start_server(db, **settings)
            while (job := httpx.get(f"{srv.url}/v1/jobs/{job_id}", timeout=30).json())[
                    "status"] not in ("done", "failed"):
                assert time.monotonic() < deadline, job
                time.sleep(0.5)
            out["resume_to_done_s"] = round(time.monotonic() - t0, 1)
            end(srv)
        result = job.get("result") or {}
        ids = [p["id"] for p in result.get("pointings", [])]
        kept = all(json.loads(v) == result["pointings"][i] for i, v in before.items()) \
            if result else False
        out.update({
            "status": job["status"], "error": job.get("error"),
            "pointings_in_result": len(ids), "pointings_unique": len(set(ids)) == len(ids),
            "targets_once": sorted(t for p in result.get("pointings", []) for t in p["target_ids"])
            == sorted(t["id"] for t in request["targets"]),
            "committed_before_kill_unchanged": kept,
            "pointings_resumed": result.get("stats", {}).get("pointings_resumed"),
            "pointings_computed_after_restart": result.get("stats", {}).get("pointings_computed"),
        })
        out["ok"] = bool(job["status"] == "done" and out["pointings_unique"] and kept
                         and out["targets_once"] and len(ids) == total
                         and out["pointings_resumed"] == len(before))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--smoke", action="store_true", help="a tiny field (CI)")
    ap.add_argument("--kill-restart", action="store_true")
    ap.add_argument("--targets", type=int, default=2000)
    ap.add_argument("--side-deg", type=float, default=0.5)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--time-limit-s", type=float, default=30.0,
                    help="stored with the job (a plan job is bounded by --budget-s alone)")
    ap.add_argument("--budget-s", type=float, default=3600.0, help="the whole job")
    ap.add_argument("--timeout-s", type=float, default=1800.0, help="kill-restart: give up after")
    a = ap.parse_args()
    if a.smoke:
        a.targets, a.side_deg = 24, 0.12
    out = kill_restart(a) if a.kill_restart else throughput(a)
    out["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version(),
                      "load_avg_1m": round(os.getloadavg()[0], 2)}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
