"""CLI: target-table reading, pictures, `plan`, and the Docker image's command run directly."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from astropy.table import Table

from models.instrument import default_instrument
from service.cli import TargetFileError, main, read_targets
from service.plots import plot_configuration

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _table() -> Table:
    t = Table()
    t["Name"] = ["a", "b", "c"]
    t["RAJ2000"] = [10.0, 10.01, 10.02]
    t["DEJ2000"] = [-30.0, -30.01, -30.02]
    t["PRIO"] = [1, 500, 2**32 - 1]
    return t


@pytest.mark.parametrize("suffix,fmt", [(".csv", "ascii.csv"), (".ecsv", "ascii.ecsv"),
                                        (".vot", "votable"), (".fits", "fits")])
def test_read_targets_all_formats_and_aliases(tmp_path: Path, suffix: str, fmt: str) -> None:
    path = tmp_path / f"t{suffix}"
    _table().write(path, format=fmt)
    rows = read_targets(path)
    assert [r["id"] for r in rows] == ["a", "b", "c"]
    assert rows[1]["ra_deg"] == pytest.approx(10.01)
    assert rows[2]["dec_deg"] == pytest.approx(-30.02)
    assert [r["priority"] for r in rows] == [1, 500, 2**32 - 1]


def test_read_examples() -> None:
    csv = read_targets(EXAMPLES / "ngc869_targets.csv")
    ecsv = read_targets(EXAMPLES / "ngc869_targets.ecsv")
    assert len(csv) == 60 and csv == ecsv
    assert len(read_targets(EXAMPLES / "m13_targets.csv")) == 40


def test_read_targets_sexagesimal_and_defaults(tmp_path: Path) -> None:
    p = tmp_path / "s.csv"
    p.write_text("ra,dec\n02:19:00.0,+57:08:00\n02:19:01.0,+57:08:30\n")
    rows = read_targets(p)
    assert rows[0] == {"id": "1", "ra_deg": pytest.approx(34.75), "dec_deg": pytest.approx(57 + 8 / 60),
                       "priority": 1}


def test_read_targets_errors(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("id,x,y\n1,2,3\n")
    with pytest.raises(TargetFileError, match="ra_deg"):
        read_targets(p)
    with pytest.raises(TargetFileError, match="no such file"):
        read_targets(tmp_path / "missing.csv")
    p.write_text("id,ra,dec,priority\na,1,2,1.5\n")
    with pytest.raises(TargetFileError, match="priority"):
        read_targets(p)


def test_cli_rejects_bad_rows(tmp_path: Path, capsys) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("id,ra,dec,priority\na,1,95,1\n")
    assert main(["plan", str(p), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "bad.csv: row 1, line 2, column 'dec'" in capsys.readouterr().err


def test_plot_configuration(tmp_path: Path) -> None:
    inst = default_instrument()
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-100, 100, (2, 30))
    out = plot_configuration(
        inst, {a.index: a.park for a in inst.arms}, tmp_path / "park.png",
        target_x_mm=x, target_y_mm=y, target_priority=rng.integers(1, 500, 30),
        allocated=rng.uniform(size=30) < 0.3, title="park",
    )
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_cli_plan(tmp_path: Path, capsys) -> None:
    """`plan` on a small one-pointing field (the 12 M13 stars of examples/requests/plan.json)."""
    from service.response_schemas import PlanResponse

    rows = json.loads((EXAMPLES / "requests" / "plan.json").read_text())["targets"]
    t = Table(rows=[(r["id"], r["ra_deg"], r["dec_deg"], r["priority"]) for r in rows],
              names=["id", "ra_deg", "dec_deg", "priority"])
    src = tmp_path / "m13_small.ecsv"
    t.write(src, format="ascii.ecsv")
    out = tmp_path / "out"
    code = main(["plan", str(src), "--out", str(out), "--seed", "1", "--time-limit", "20", "--quiet"])
    assert code == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "12 targets" in printed
    # the sky overview is written and named in the output
    assert f"sky overview {out / 'sky_overview.png'}" in printed
    assert (out / "sky_overview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = json.loads((out / "plan.json").read_text())
    PlanResponse.model_validate(result)
    assert sorted(i for p in result["pointings"] for i in p["target_ids"]) == sorted(t["id"])
    n_cfg = sum(len(p["configurations"]) for p in result["pointings"])
    assert n_cfg >= 1 and result["stats"]["allocated_targets"] == len(rows)
    for p in result["pointings"]:
        assert len(p["motions"]) == len(p["configurations"]) + 1
        assert all(m["status"] in ("ok", "failed") for m in p["motions"])
    pngs = sorted(out.glob("pointing*.png"))
    assert len(pngs) == n_cfg
    # configurations c1 ... cn, as the page and the legs' reasons count them
    assert {p.name for p in pngs} == {f"pointing{p['id']}_c{k}.png" for p in result["pointings"]
                                      for k in range(1, len(p["configurations"]) + 1)}
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)


def _dockerfile_instruction(name: str) -> str:
    text = (ROOT / "Dockerfile").read_text().replace("\\\n", " ")
    return next(line for line in text.splitlines() if line.startswith(name + " "))


def test_image_command_serves_health(tmp_path: Path) -> None:
    """Run the Dockerfile's CMD (on a free port) and its HEALTHCHECK command against it."""
    cmd = json.loads(_dockerfile_instruction("CMD")[4:])
    assert cmd[:2] == ["mxs-planner", "serve"]
    port = free_port()
    cmd = [c.replace("8000", str(port)) for c in cmd]
    cmd[cmd.index("--host") + 1] = "127.0.0.1"
    exe = Path(sys.executable).parent / "mxs-planner"
    cmd[0] = str(exe) if exe.exists() else cmd[0]
    env = {**os.environ, "MXS_JOB_DB": str(tmp_path / "jobs.sqlite3"), "MXS_WORKERS": "1"}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                r = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=1)
                if r.status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert proc.poll() is None, proc.stdout.read().decode() if proc.stdout else ""
            time.sleep(0.2)
        else:
            raise AssertionError("mxs-planner serve did not answer /v1/health")
        assert r.json()["status"] == "ok"
        hc = _dockerfile_instruction("HEALTHCHECK")
        py = re.search(r'CMD python -c "(.*)"\s*$', hc)
        assert py is not None, hc
        code = py.group(1).replace("8000", str(port))
        assert subprocess.run([sys.executable, "-c", code], timeout=30).returncode == 0
        assert (tmp_path / "jobs.sqlite3").exists()  # job DB opened at start-up
    finally:
        proc.terminate()
        proc.wait(timeout=15)


def test_cli_plans_the_m13_example_executably(tmp_path: Path, capsys) -> None:
    """The project's own example, seed 1, whose chained legs need the plan changes: exit code 0, every
    leg ok, and every leg re-checked here by the verifier from the written way-points."""
    import numpy as np

    from models.instrument import default_instrument
    from models.types import ArmTrajectory
    from planner import verify_trajectories

    out = tmp_path / "out"
    code = main(["plan", str(EXAMPLES / "m13_targets.csv"), "--out", str(out), "--seed", "1", "--quiet"])
    assert code == 0, capsys.readouterr().err
    result = json.loads((out / "plan.json").read_text())
    assert result["executable"] is True and result["reasons"] == []
    inst = default_instrument()
    for p in result["pointings"]:
        goals = [np.array([[a["theta1_rad"], a["theta2_rad"]] for a in c["assignments"]])
                 for c in p["configurations"]] + [inst.park_configuration]
        start = inst.park_configuration
        assert len(p["motions"]) == len(goals)
        for m, goal in zip(p["motions"], goals, strict=True):
            assert m["status"] == "ok"
            trajs = [ArmTrajectory(tr["arm"], np.array([w["t_s"] for w in tr["waypoints"]]),
                                   np.array([w["theta1_rad"] for w in tr["waypoints"]]),
                                   np.array([w["theta2_rad"] for w in tr["waypoints"]]))
                     for tr in m["trajectories"]]
            rep = verify_trajectories(inst, trajs, start, goal, max_start_stop=None)
            assert rep.ok, rep.violations[:3]
            start = np.array([[t.theta1_rad[-1], t.theta2_rad[-1]] for t in trajs])


def test_cli_prints_the_plans_notices(tmp_path: Path, capsys, monkeypatch) -> None:
    """The plan's notices (the time-limit advice among them) reach the CLI user on stderr."""
    from service import pipeline

    real_plan = pipeline.plan
    advice = "The time limit of 5 s is too short for this field: it needs about 40 s."

    def plan_with_advice(*args, **kwargs):
        return {**real_plan(*args, **kwargs), "notices": [advice]}

    monkeypatch.setattr(pipeline, "plan", plan_with_advice)
    rows = json.loads((EXAMPLES / "requests" / "plan.json").read_text())["targets"][:4]
    src = tmp_path / "four.csv"
    src.write_text("id,ra_deg,dec_deg,priority\n" + "".join(
        f"{r['id']},{r['ra_deg']},{r['dec_deg']},{r['priority']}\n" for r in rows))
    code = main(["plan", str(src), "--out", str(tmp_path / "o"), "--seed", "1", "--time-limit", "30",
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"notice: {advice}" in err.splitlines()
