"""benchmarks/load.py --greedy: greedy clients against a served planner, health latency
measured by a prober of its own; a short run checks what it reports."""

from __future__ import annotations

import json

from benchmarks import load


def test_greedy_reports_health_percentiles_and_answers_by_status(tmp_path, capsys) -> None:
    out = tmp_path / "greedy.json"
    assert load.main(["--greedy", "--clients", "3", "--seconds", "4", "--limit", "1",
                      "--server-env", "MXS_HEAVY_THREADS=1", "--server-env", "heavy_queue=0",
                      "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report == json.loads(capsys.readouterr().out)
    assert set(report) == {"smoke", "cpus", "greedy"}  # the greedy scenario alone
    g = report["greedy"]
    assert g["config"]["clients"] == 3 and g["config"]["prober"] == "process"
    assert g["config"]["server_env"] == {"heavy_threads": "1", "heavy_queue": "0"}
    h = g["health"]
    assert h["failures"] == 0 and h["probes"] >= 20  # every 50 ms for 4 s
    assert 0 < h["p50_ms"] <= h["p95_ms"] <= h["p99_ms"] <= h["max_ms"]
    statuses = g["heavy_by_status"]
    # one slot, three clients that never wait: some are answered, the others refused
    assert statuses.get("200", 0) >= 1 and statuses.get("503", 0) >= 1
    assert set(statuses) <= {"200", "503"}, statuses


def test_greedy_defaults_to_12_clients_and_the_load_scenario_to_50(monkeypatch) -> None:
    clients: dict[str, int] = {}

    def recorder(name: str):
        def record(a):
            clients[name] = a.clients
            return {}
        return record

    for name in ("greedy", "load"):
        monkeypatch.setattr(load, f"scenario_{name}", recorder(name))
    load.main(["--greedy"])
    load.main(["--only", "load"])
    assert clients == {"greedy": 12, "load": 50}
