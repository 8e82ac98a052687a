"""Schemathesis with every check against a real server, with and without a token.

Starts ``uvicorn service.app:app`` on a free loopback port (short solver limits so the run
stays bounded), runs ``schemathesis run --checks all`` three ways — a server without a token,
a server with one and the token sent, the same server without it — and prints JSON: per run
the number of cases, answers >= 500, schema violations, undocumented status codes and the
other failures by check, read from schemathesis' NDJSON event report.

    python -m benchmarks.contract                  # 100 examples per operation and mode
    python -m benchmarks.contract --smoke          # 10

422 is an accepted answer to schema-valid data (``positive_data_acceptance``): geometry and
deployment limits (a target 90 deg from the tangent point, more targets than the server
takes) cannot be said in JSON Schema and are the documented 422 naming the field.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parent.parent
TOKEN = "benchmark-contract-token"
CONFIG = """
[checks.positive_data_acceptance]
expected-statuses = ["2xx", 401, 404, 422]
"""
SERVER_ENV = {"MXS_WORKERS": "1", "MXS_MAX_TARGETS": "20", "MXS_DEFAULT_TIME_LIMIT_S": "0.5",
              "MXS_MAX_TIME_LIMIT_S": "1", "MXS_PLAN_BUDGET_S": "1", "MXS_JOB_BUDGET_S": "1",
              "MXS_CORS_ORIGINS": "https://form.example",
              # the fuzzer submits hundreds of jobs: the queue bound (a quota answered 429, measured
              # by benchmarks/load.py's flood) is kept out of its way
              "MXS_MAX_QUEUED_JOBS": "100000"}
SCHEMA_VIOLATIONS = {"response_schema_conformance", "content_type_conformance",
                     "response_headers_conformance"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _server(tmp: Path, token: str | None) -> tuple[subprocess.Popen[bytes], str]:
    port = _free_port()
    env = {**os.environ, **SERVER_ENV, "MXS_JOB_DB": str(tmp / f"jobs-{port}.sqlite3")}
    env.pop("MXS_API_TOKEN", None)
    if token is not None:
        env["MXS_API_TOKEN"] = token
    proc = subprocess.Popen([sys.executable, "-m", "uvicorn", "service.app:app", "--host",
                             "127.0.0.1", "--port", str(port), "--log-level", "warning"],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    for _ in range(150):
        try:
            if httpx.get(url + "/v1/health", timeout=1).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            time.sleep(0.2)
    proc.kill()
    raise RuntimeError("the server did not start")


def _summary(ndjson: Path) -> dict[str, Any]:
    """Counts over schemathesis' NDJSON events: every recorded response by status, every
    check that did not pass by name, and the errors (timeouts, refused connections)."""
    statuses: Counter[str] = Counter()
    failures: Counter[str] = Counter()
    errors: Counter[str] = Counter()
    for line in ndjson.read_text().splitlines():
        event = json.loads(line)
        if "NonFatalError" in event:
            e = event["NonFatalError"]
            errors[f"{e.get('label')}: {e.get('value', {}).get('type')}"] += 1
            continue
        rec = event.get("ScenarioFinished", {}).get("recorder")
        if not rec:
            continue
        for inter in rec.get("interactions", {}).values():
            code = (inter.get("response") or {}).get("status_code")
            if isinstance(code, int):
                statuses[str(code)] += 1
        for checks in rec.get("checks", {}).values():
            for c in checks:
                if c.get("status") != "success":
                    failures[c.get("name", "?")] += 1
    return {"responses": sum(statuses.values()), "by_status": dict(sorted(statuses.items())),
            "responses_5xx": sum(n for code, n in statuses.items() if int(code) >= 500),
            "failures_by_check": dict(failures), "errors": dict(errors),
            "schema_violations": sum(n for c, n in failures.items() if c in SCHEMA_VIOLATIONS),
            "undocumented_status": failures.get("status_code_conformance", 0)}


def run_schemathesis(url: str, headers: dict[str, str], examples: int, tmp: Path, name: str
                     ) -> dict[str, Any]:
    config = tmp / "schemathesis.toml"
    config.write_text(CONFIG)
    report = tmp / f"{name}.ndjson"
    cmd = [sys.executable, "-m", "schemathesis.cli", "--config-file", str(config), "run",
           url + "/openapi.json", "--checks", "all", "--max-examples", str(examples),
           "--continue-on-failure", "--request-timeout", "30", "--report", "ndjson",
           "--report-ndjson-path", str(report), "--seed", "1"]
    for k, v in headers.items():
        cmd += ["-H", f"{k}: {v}"]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=3600)
    out = {"mode": name, "exit_code": proc.returncode, "wall_s": round(time.monotonic() - t0, 1)}
    out.update(_summary(report) if report.exists() else {"error": proc.stdout[-2000:]})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--examples", type=int, default=None)
    args = ap.parse_args(argv)
    examples = args.examples or (10 if args.smoke else 100)
    runs = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for name, token, headers in (("no token on the server", None, {}),
                                     ("token sent", TOKEN, {"Authorization": f"Bearer {TOKEN}"}),
                                     ("token not sent", TOKEN, {})):
            proc, url = _server(tmp, token)
            try:
                runs.append(run_schemathesis(url, headers, examples, tmp, name.replace(" ", "-")))
            finally:
                proc.terminate()
                proc.wait(timeout=30)
    print(json.dumps({"examples_per_operation": examples, "runs": runs,
                      "goal_met": all(r.get("responses_5xx", 1) == 0 and r.get("schema_violations", 1) == 0
                                      and r.get("undocumented_status", 1) == 0 for r in runs)}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
