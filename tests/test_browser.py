"""The observation-preparation page and /docs in a real browser (Debian's chromium, driven by
playwright), against a uvicorn server on a free localhost port. Every request the page makes
outside that server fails the test."""

from __future__ import annotations

import csv
import io
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARTEFACTS = Path(os.environ.get("MXS_TEST_ARTEFACTS", ROOT / "out" / "browser"))
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update"]
N_EXAMPLE = 8  # targets of the M13 example: two configurations, a job of a few seconds


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[str]:
    port = _free_port()
    env = {**os.environ, "MXS_JOB_DB": str(tmp_path_factory.mktemp("db") / "jobs.sqlite3"),
           "MXS_WORKERS": "1", "MXS_API_TOKEN": ""}
    proc = subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "service.app:app", "--host", "127.0.0.1", "--port",
         str(port), "--log-level", "warning"], cwd=ROOT, env=env, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(300):
            try:
                if httpx.get(url + "/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert proc.poll() is None, "the server exited"
            time.sleep(0.1)
        yield url
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser, server) -> Iterator[object]:
    """A page whose every request outside the server is refused and recorded."""
    context = browser.new_context(accept_downloads=True, viewport={"width": 1300, "height": 1000})
    outside: list[str] = []
    here = urlsplit(server).netloc

    def route(r) -> None:
        u = urlsplit(r.request.url)
        if u.scheme in ("data", "blob") or u.netloc == here:
            r.continue_()
        else:
            outside.append(r.request.url)
            r.abort()

    context.route("**/*", route)
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    yield pg
    context.close()
    assert outside == [], f"the page fetched outside the service: {outside}"
    assert errors == [], f"JavaScript errors: {errors}"


def _example_csv(path: Path) -> Path:
    """The first targets of the M13 example, with CLI aliases and one sexagesimal row."""
    rows = list(csv.DictReader((ROOT / "examples" / "m13_targets.csv").open()))[:N_EXAMPLE]
    lines = ["Name,RAJ2000,DEJ2000,prio"]
    for i, r in enumerate(rows):
        ra = float(r["ra_deg"])
        if i == 1:
            h = ra / 15
            ra_text = f"{int(h):02d}:{int(h * 60 % 60):02d}:{h * 3600 % 60:09.6f}"
        else:
            ra_text = f"{ra:.7f}"
        lines.append(f"{r['id']},{ra_text},{r['dec_deg']},{r['priority']}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_plan_an_uploaded_table(page, server, tmp_path: Path) -> None:
    page.goto(server + "/")
    page.set_input_files("#file", str(_example_csv(tmp_path / "m13.csv")))
    page.fill("#time-limit", "10")  # legs get planned on a loaded machine too
    page.fill("#pa", "30")  # the page's projection must rotate as the server's does
    page.select_option("#segmentation", "balanced")
    page.fill("#exposure-time", "600")  # the page's default 900 s replaced
    page.click("#go")
    assert page.is_disabled("#go")  # no second job while this one runs
    page.wait_for_selector("#result:not([hidden])", timeout=90_000)
    assert not page.is_disabled("#go")
    assert f"{N_EXAMPLE} targets read from m13.csv" in page.inner_text("#table-info")
    assert "column 'RAJ2000' mixes" in page.inner_text("#table-info")
    assert page.inner_text("#status").startswith("done: ") and "(100 %)" in page.inner_text("#status")
    result = page.evaluate("mxs.state.result")
    assert page.evaluate("mxs.state.request.position_angle_deg") == 30
    assert page.evaluate("mxs.state.request.park_move_limit_s") == 120  # the page's default, T_p
    page.check("#park-unlimited")
    assert page.evaluate("mxs.planRequest({targets: []}).park_move_limit_s") is None
    page.uncheck("#park-unlimited")
    page.fill("#park-limit", "90")
    assert page.evaluate("mxs.planRequest({targets: []}).park_move_limit_s") == 90
    _telescope_time_is_shown(page, result)
    banner = page.inner_text("#banner")
    assert ("NOT executable" in banner) == (not result["executable"])
    summary = page.inner_text("#summary")
    assert "Targets observed per priority" in summary
    s = result["stats"]
    if s.get("exposures_lower_bound"):  # a bound (mode fewest-exposures): the configurations over it
            assert f"proven lower bound on configurations\t{s['exposures_lower_bound']} (this plan: " \
               f"{s['configurations'] / s['exposures_lower_bound']:.2f}×)" in summary
    assert ("configurations observing at most 2 targets" in summary) == bool(s["few_target_exposures"])
    # every target: where the server put it, or why not
    where = {a["target_id"]: (p["id"], f"c{c['index'] + 1}", str(a["arm"]))
             for p in result["pointings"] for c in p["configurations"] for a in c["assignments"]
             if a["target_id"]}
    why = {u["target_id"]: u["reason"] for p in result["pointings"] for u in p["unallocated"]}
    rows = page.evaluate("""() => [...document.querySelectorAll('.every-target tbody tr')]
        .map((tr) => [...tr.children].map((td) => td.textContent))""")
    assert len(rows) == N_EXAMPLE
    for target, _prio, _ra, _dec, _ra_deg, _dec_deg, pointing, conf, arm, reason in rows:
        assert ((pointing, conf, arm) == where[target] and reason == "") if target in where \
            else (conf == "" and reason == why[target])
    n_conf = sum(len(p["configurations"]) for p in result["pointings"])
    # one picture per pointing; the first configuration shows all 12 arms to scale
    svg = page.locator(".pointing svg[data-configuration]").first
    assert svg.locator("g.arm").count() == 12
    # the page's own projection of the targets lands on the arm tips the server computed
    marks = page.evaluate("""() => [...document.querySelectorAll('.pointing')].flatMap((sec) => {
        const svg = sec.querySelector('svg[data-configuration]');
        const tips = [...svg.querySelectorAll('g.arm')].map((g) => [+g.dataset.tipX, +g.dataset.tipY]);
        return [...svg.querySelectorAll('.target.this')].map((t) => ({
          x: +t.dataset.x, y: +t.dataset.y,
          d: Math.min(...tips.map(([x, y]) => Math.hypot(x - +t.dataset.x, y - +t.dataset.y)))}));
    })""")
    assert marks and max(m["d"] for m in marks) < 0.05
    first = result["pointings"][0]
    if len(first["configurations"]) > 1:
        page.locator(".pointing").first.locator(".stepper button").nth(1).click()
        shown = page.locator(".pointing").first.locator("svg[data-configuration]")
        assert shown.get_attribute("data-configuration") == "2"
        assert shown.locator(".target.earlier").count() == sum(
            a["target_id"] is not None for a in first["configurations"][0]["assignments"])
    # the field on the sky: one FOV circle per pointing
    assert page.locator("svg.sky circle.pointing-fov").count() == len(result["pointings"])
    assert page.locator("svg.sky .sky-target").count() == N_EXAMPLE
    _play_first_leg(page, result)
    with page.expect_download() as dl:
        page.locator(".pointing").first.locator("button.save-svg").click()
    picture = Path(dl.value.path()).read_text()
    assert picture.startswith("<svg") and picture.count('class="arm"') == 12
    with page.expect_download() as dl:
        page.click("#dl-commands")
    commands = list(csv.DictReader(io.StringIO(Path(dl.value.path()).read_text())))
    assert len(commands) == sum(len(t["commands"]) for p in result["pointings"]
                                for m in p["motions"] for t in m["trajectories"])
    with page.expect_download() as dl:
        page.click("#dl-csv")
    rows = list(csv.DictReader(io.StringIO(Path(dl.value.path()).read_text())))
    assert sum(r["kind"] != "unallocated" for r in rows) == 12 * n_conf
    observed = {r["target_id"] for r in rows if r["kind"] == "target"}
    assert len(observed) == result["stats"]["allocated_targets"]
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTEFACTS / "plan.png"), full_page=True)
    _not_executable_is_flagged(page, result)


def _hmm(t_s: float) -> str:
    h, m = divmod(round(t_s / 60), 60)
    return f"{h}:{m:02d}"


def _telescope_time_is_shown(page, result) -> None:
    """The exposure time and acquisition reach the request (the acquisition at its default),
    the stop rules only when set; the plan's telescope time and each pointing's are shown."""
    request = page.evaluate("mxs.state.request")
    assert (request["exposure_time_s"], request["acquisition_s"]) == (600, 300)
    assert not {"max_exposures", "min_priority_per_exposure", "min_targets_per_exposure"} & set(request)
    page.fill("#max-exposures", "3")
    page.fill("#min-priority", "50")
    page.fill("#min-targets", "2")
    asked = page.evaluate("mxs.planRequest({targets: []})")
    assert (asked["max_exposures"], asked["min_priority_per_exposure"], asked["min_targets_per_exposure"]) == (3, 50, 2)
    for sel in ("#max-exposures", "#min-priority", "#min-targets"):
        page.fill(sel, "")
    t = result["stats"]["telescope_time"]
    assert t["exposure_s"] == 600 * t["exposures"]
    row = page.evaluate("""() => [...document.querySelectorAll('#summary tr')].map((tr) => tr.textContent)
        .find((r) => r.startsWith('telescope time'))""")
    assert row is not None and f"{_hmm(t['total_s'])} = {t['exposures']} exposure" in row
    assert f"reconfiguration {_hmm(t['reconfiguration_s'])}" in row
    shown = page.locator(".pointing .telescope-time").all_inner_texts()
    assert len(shown) == len(result["pointings"])
    for text, p in zip(shown, result["pointings"], strict=True):
        assert f"Telescope time (h:mm): {_hmm(p['stats']['telescope_time']['total_s'])} = " in text


def _not_executable_is_flagged(page, result) -> None:
    """The same answer with a failed leg: a banner with the reasons, the pointing flagged."""
    reason = "leg 1 (park -> c1): arms 5 not planned"
    page.evaluate("""([reason]) => {
        const r = structuredClone(mxs.state.result);
        r.executable = false; r.pointings[0].executable = false;
        r.pointings[0].reasons = [reason]; r.reasons = ["pointing " + r.pointings[0].id + ": " + reason];
        r.pointings[0].motions[0].status = "failed"; r.pointings[0].motions[0].failed_arms = [5];
        mxs.showResult(r, mxs.state.request, mxs.state.list); }""", [reason])
    banner = page.inner_text("#banner")
    assert "NOT executable" in banner and "leg 1 (park -> c1): arms 5 not planned" in banner  # legs from 1
    sec = page.locator(".pointing.not-executable")
    assert sec.count() == 1 and "NOT planned (arms 5)" in sec.inner_text()
    assert "failed" in sec.locator(".stepper button").first.get_attribute("class")
    assert page.locator("svg.sky circle.pointing-fov[stroke='#c62828']").count() == 1


def _play_first_leg(page, result) -> None:
    """The first planned leg into a configuration plays as an animation and ends on the
    configuration's arm tips."""
    legs = [(i, k) for i, p in enumerate(result["pointings"]) for k in range(len(p["configurations"]))
            if p["motions"][k]["status"] == "ok" and p["motions"][k]["makespan_s"] > 0]
    assert legs, "no motion leg into a configuration was planned"
    i, k = legs[0]
    sec = page.locator(".pointing").nth(i)
    sec.locator(".stepper button").nth(k).click()
    page.evaluate("""(i) => { const svg = document.querySelectorAll('.pointing')[i].querySelector('svg[data-configuration]');
        window.frames_seen = 0;
        new MutationObserver(() => { window.frames_seen += 1; }).observe(svg, {childList: true, subtree: true}); }""", i)
    sec.locator("button.play").click()
    page.wait_for_function("window.frames_seen > 3")
    page.wait_for_function("(i) => !document.querySelectorAll('.pointing')[i].querySelector('svg[data-configuration]')"
                           "?.dataset.playing", arg=i, timeout=15_000)
    p = result["pointings"][i]
    # the motion's last waypoints are the configuration's joint angles
    end = page.evaluate("""([p, k]) => [...mxs.anglesAt(p.motions[k], 1e9).entries()]""", [p, k])
    goal = {a["arm"]: (a["theta1_rad"], a["theta2_rad"]) for a in p["configurations"][k]["assignments"]}
    assert {arm for arm, _ in end} == set(goal)
    for arm, (t1, t2) in end:
        assert abs(t1 - goal[arm][0]) < 1e-6
        assert abs(math.remainder(t2 - goal[arm][1], 2 * math.pi)) < 1e-6


def test_bad_rows_are_named_by_file_row_and_column(page, server, tmp_path: Path) -> None:
    page.goto(server + "/")
    bad = tmp_path / "bad.csv"
    bad.write_text("id,ra,dec,priority\na,250.42,36.46,1\nb,250.43,36.47,2\nc,250.44,95,3\n")
    page.set_input_files("#file", str(bad))
    page.wait_for_selector("#error:not([hidden])")  # read at once, before planning
    assert "bad.csv: row 3, line 4, column 'dec'" in page.inner_text("#error")
    page.click("#go")
    page.wait_for_function("!document.querySelector('#go').disabled")
    assert "bad.csv: row 3, line 4, column 'dec'" in page.inner_text("#error")
    assert page.is_hidden("#result")
    # a 422 of the job request names the form's field ...
    page.set_input_files("#file", [])
    page.fill("#pa", "400")
    page.click("#go")
    page.wait_for_function("document.querySelector('#error').textContent.includes('position angle')")
    # ... and a target's loc maps back to the uploaded file's row, line and column
    listed = {"filename": "t.csv", "columns": {"dec_deg": "DEJ2000"},
              "targets": [{"id": "a", "row": 1, "line": 2}, {"id": "b", "row": 2, "line": 4}]}
    text = page.evaluate("([loc, list]) => mxs.describeLoc(loc, list)",
                         [["body", "plan", "request", "targets", 1, "dec_deg"], listed])
    assert text == "t.csv: row 2, line 4, column 'DEJ2000' (target b)"


def test_example_files_are_read_on_upload(page, server, tmp_path: Path) -> None:
    from astropy import units as u
    from astropy.io.votable import from_table
    from astropy.table import Table

    page.goto(server + "/")
    page.set_input_files("#file", str(ROOT / "examples" / "ngc869_targets.ecsv"))
    page.wait_for_function("document.querySelector('#table-info').textContent.includes('60 targets')")
    assert "read from ngc869_targets.ecsv" in page.inner_text("#table-info")
    vt = from_table(Table({"_RAJ2000": [250.4235, 250.43] * u.deg,
                           "_DEJ2000": [36.46, 36.47] * u.deg}))
    vt.get_first_table().get_field_by_id("_RAJ2000").ucd = "pos.eq.ra;meta.main"
    vt.get_first_table().get_field_by_id("_DEJ2000").ucd = "pos.eq.dec;meta.main"
    vt.to_xml(str(tmp_path / "vizier.vot"))
    page.set_input_files("#file", str(tmp_path / "vizier.vot"))
    page.wait_for_function("document.querySelector('#table-info').textContent.includes('2 targets')")
    info = page.inner_text("#table-info")
    assert "ra_deg <- _RAJ2000" in info and "no id column" in info
    assert page.is_hidden("#error")


def test_docs_render_offline(page, server) -> None:
    page.goto(server + "/docs")
    page.wait_for_selector(".swagger-ui .info .title", timeout=20_000)
    assert "MXS planner" in page.inner_text(".swagger-ui .info .title")
    assert page.locator(".opblock").count() >= 5


def test_cancel_a_running_plan(page, server) -> None:
    """Last in this module: the job's worker may be restarted to stop it."""
    import numpy as np

    page.goto(server + "/")
    assert page.is_disabled("#cancel")  # no job runs
    rng = np.random.default_rng(3)
    rows = [f"t{i},{250.42 + rng.normal(0, 0.006):.6f},{36.46 + rng.normal(0, 0.006):.6f},{1 + i % 5}"
            for i in range(300)]  # one crowded pointing: minutes of work
    page.fill("#targets", "id,ra,dec,priority\n" + "\n".join(rows) + "\n")
    page.click("#go")
    page.wait_for_function("document.querySelector('#status').dataset.state === 'running'",
                           timeout=60_000)
    assert not page.is_disabled("#cancel")
    job_id = page.evaluate("mxs.state.jobId")
    page.click("#cancel")
    page.wait_for_function("document.querySelector('#status').textContent.includes('cancelled')",
                           timeout=20_000)
    assert page.is_disabled("#cancel") and not page.is_disabled("#go")
    assert page.is_hidden("#result") and page.is_hidden("#error")
    job = httpx.get(f"{server}/v1/jobs/{job_id}", timeout=10).json()
    assert (job["status"], job["result"]) == ("cancelled", None)
