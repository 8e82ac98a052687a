"""The page's controls and layout in a real browser (Debian's chromium through playwright,
the harness of tests/test_browser.py): the controls start at the API's defaults and name what
the API does, the command line repeats a page plan, the result's first screen holds the summary
and the sky view, a plan restored after a reload says so and turns stale when the input
changes, progress names the pointing, and the finding-chart image goes to the viewer."""

from __future__ import annotations

import csv
import io
import json
import re
import shlex
from pathlib import Path

import httpx
from astropy.coordinates import Angle

from service.cli import build_parser
from service.schemas import PlanRequest
from tests import test_browser
from tests.test_browser import ARTEFACTS, ROOT, _example_csv

# The uvicorn server, Chromium and page fixtures of the page's other browser tests.
server, browser, page = test_browser.server, test_browser.browser, test_browser.page

M67 = ROOT / "tests" / "data" / "m67-like-150-vizier.csv"
HEX_ID = re.compile(r"[0-9a-f]{32}")
# The form's controls and the PlanRequest field each one sets.
CONTROL_FIELDS = {"method": "method", "solver": "solver", "pa": "position_angle_deg",
                  "segmentation": "segmentation_mode", "time-limit": "time_limit_s", "seed": "seed",
                  "park-limit": "park_move_limit_s", "exposure-time": "exposure_time_s",
                  "acquisition": "acquisition_s", "max-exposures": "max_exposures",
                  "min-priority": "min_priority_per_exposure",
                  "min-targets": "min_targets_per_exposure"}


def _shown(value: object) -> str:
    """A default as an input shows it: empty for null, 120.0 as '120'."""
    if value is None:
        return ""
    return f"{value:g}" if isinstance(value, float) else str(value)


def _open(page, server: str) -> None:
    page.goto(server + "/")
    page.wait_for_selector("body[data-ready]")


def _controls(page) -> dict[str, str]:
    return page.evaluate("(ids) => Object.fromEntries(ids.map((id) => [id, document.getElementById(id).value]))",
                         list(CONTROL_FIELDS))


def _plan(page, timeout_ms: int = 120_000) -> None:
    page.click("#go")
    page.wait_for_selector("#result:not([hidden])", timeout=timeout_ms)


def test_controls_start_at_the_api_defaults(page, server) -> None:
    _open(page, server)
    fields = PlanRequest.model_fields
    expected = {cid: _shown(fields[f].default) for cid, f in CONTROL_FIELDS.items()}
    assert _controls(page) == expected
    assert page.is_checked("#park-unlimited") == (fields["park_move_limit_s"].default is None)
    # nothing set beyond the targets: the request is the API's default request
    asked = page.evaluate("mxs.planRequest({targets: [{id: 'a', ra_deg: 1, dec_deg: 2, priority: 1}]})")
    assert PlanRequest.model_validate(asked) == PlanRequest(
        targets=[{"id": "a", "ra_deg": 1.0, "dec_deg": 2.0, "priority": 1}])
    # the labels say what the API does with the field
    label = page.locator("label:has(#time-limit)").inner_text()
    assert "whole plan" in label and "per solver call" not in label
    assert "Seed" in page.locator("label:has(#seed)").inner_text()
    page.fill("#seed", "7")
    assert page.evaluate("mxs.planRequest({targets: []}).seed") == 7
    # the defaults come from the server's OpenAPI document: change it, and the page follows
    doc = httpx.get(server + "/openapi.json", timeout=10).json()
    props = doc["components"]["schemas"]["PlanRequest"]["properties"]
    props["solver"]["default"] = "cpsat"
    props["exposure_time_s"]["default"] = 650.0
    page.route("**/openapi.json", lambda r: r.fulfill(status=200, content_type="application/json",
                                                      body=json.dumps(doc)))
    _open(page, server)
    shown = _controls(page)
    assert (shown["solver"], shown["exposure-time"]) == ("cpsat", "650")


def test_which_input_is_used_and_the_checkbox_sits_on_its_line(page, server, tmp_path: Path) -> None:
    _open(page, server)
    box, text = page.evaluate("""() => {
        const cb = document.getElementById('park-unlimited').getBoundingClientRect();
        const r = document.createRange();
        r.selectNodeContents(document.getElementById('park-unlimited').parentElement);
        const line = [...r.getClientRects()].filter((q) => q.width > 0 && q.height > 5)
          .find((q) => q.left > cb.right - 1) || {top: -1e9, bottom: -1e9, left: -1e9};
        return [{top: cb.top, bottom: cb.bottom, right: cb.right},
                {top: line.top, bottom: line.bottom, left: line.left}];
    }""")
    # the checkbox is on the first line of its label's text, left of it
    middle = (box["top"] + box["bottom"]) / 2
    assert text["top"] <= middle <= text["bottom"] and box["right"] <= text["left"]
    one = tmp_path / "one.csv"
    one.write_text("id,ra,dec,priority\na,250.42,36.46,3\n")
    page.set_input_files("#file", str(one))
    page.wait_for_function("document.querySelector('#table-info').textContent.includes('read from one.csv')")
    assert "1 target read from one.csv" in page.inner_text("#table-info")  # not "1 targets"
    assert "not used" in page.inner_text("#input-used") and "one.csv" in page.inner_text("#input-used")
    assert "unused" in page.get_attribute("#targets", "class")
    assert page.is_visible("#clear-file")
    # typing in the table switches back to it
    page.locator("#targets").press("End")
    page.keyboard.type("\n")
    assert page.evaluate("document.getElementById('file').files.length") == 0
    assert page.inner_text("#input-used") == "the pasted table is used"
    assert "unused" not in (page.get_attribute("#targets", "class") or "")
    # the finding-chart image goes to the viewer's setFindingImage
    label = page.locator("label:has(#finding-image)").inner_text()
    assert label.startswith("Sky image for a finding chart (FITS with WCS, optional)")
    assert page.get_attribute("#finding-image", "accept") == ".fits,.fit,.fits.gz"
    page.evaluate("window.handed = []; window.setFindingImage = (f) => window.handed.push(f ? f.name : null)")
    image = tmp_path / "m67_2mass.fits"
    image.write_bytes(b"SIMPLE  =                    T" + b" " * 2850)
    page.set_input_files("#finding-image", str(image))
    assert page.evaluate("window.handed.at(-1)") == "m67_2mass.fits"
    page.set_input_files("#finding-image", [])
    assert page.evaluate("window.handed.at(-1)") is None


def test_progress_names_the_stage_and_the_pointing(page, server) -> None:
    _open(page, server)
    text = lambda job: page.evaluate("(job) => mxs.progressText(job)", job)  # noqa: E731
    base = {"job_id": "5c236a52" * 4, "status": "running", "progress": 0.4}
    assert text({**base, "pointings_done": 2, "pointings_total": 7}) == "planning pointing 3 of 7 (40 %)"
    assert text({**base, "pointings_done": None, "pointings_total": None}).startswith("segmenting")
    staged = text({**base, "pointings_done": 2, "pointings_total": 7, "stage": "planning motion, pointing 3 of 7"})
    assert staged == "planning motion, pointing 3 of 7 (40 %)"
    staged = text({**base, "pointings_done": 7, "pointings_total": 7, "stage": "assembling the plan"})
    assert staged == "assembling the plan (7 of 7 pointings planned) (40 %)"
    assert text({**base, "status": "done", "progress": 1, "pointings_done": 1, "pointings_total": 1}) == \
        "done: 1 pointing planned (100 %)"
    assert text({**base, "status": "queued", "progress": 0}).startswith("queued")
    for job in ({**base, "pointings_done": 2, "pointings_total": 7}, {**base, "status": "done"}):
        assert not HEX_ID.search(text(job))


def _first_screen(page) -> dict[str, dict[str, float]]:
    """Boxes of the summary's table and the sky view with the result's top at the top of the window."""
    page.evaluate("document.getElementById('result').scrollIntoView()")
    return page.evaluate("""() => Object.fromEntries([['summary', '#summary table'], ['sky', 'svg.sky'],
        ['result', '#result']].map(([k, s]) => { const r = document.querySelector(s).getBoundingClientRect();
        return [k, {top: r.top, bottom: r.bottom}]; }))""")


def test_the_banner_says_what_a_short_limit_left_out(page, server) -> None:
    _open(page, server)
    advice = {"time_limit_s": 10, "needed_limit_s": 106, "use_job": True, "pointings_total": 12,
              "pointings_planned": 5, "pointings_not_planned": ["P0006"], "pointings_failed": [],
              "targets_not_planned": 9, "message": "The time limit of 10 s is too short: it needs 106 s."}
    result = {"executable": True, "reasons": [], "time_limit_advice": advice, "notices": [advice["message"]]}
    page.evaluate("(r) => mxs.showBanner(r)", result)
    assert page.get_attribute("#banner", "class") == "warn"
    text = page.inner_text("#banner")
    assert "5 pointings" in text and "1 pointing did not fit" in text and advice["message"] in text
    page.evaluate("(r) => mxs.showBanner(r)", {**result, "time_limit_advice": None, "notices": []})
    assert page.get_attribute("#banner", "class") == "good"
    assert "too short" not in page.inner_text("#banner")


def _optimiser_rows(s: dict) -> list[str]:
    """The summary's "programme optimiser" row as the plan's stats give it (none when the
    search the optimiser kept did not allocate every pointing)."""
    o = s["segmentation"]["optimiser"]
    tried = o["model_variants"]
    kept = next((v for v in tried if v["chosen"]), None)
    if kept is None or not kept["complete"]:
        return []

    def n(k: int, noun: str) -> str:
        return f"{k} {noun}{'' if k == 1 else 's'}"

    text = f"{n(kept['exposures'], 'configuration')} in {n(kept['pointings'], 'pointing')}"
    if len(tried) > 1:
        text += f" (best of {len(tried)} searches" + (
            ")" if kept is tried[0] else f"; the first: {tried[0]['exposures']} in {tried[0]['pointings']})")
    if o["pointings_merged"]:
        text += f"; {n(o['pointings_merged'], 'pointing')} merged"
    if o["exposures_emptied"]:
        text += f"; {n(o['exposures_emptied'], 'configuration')} emptied into idle arms"
    return ["programme optimiser" + text]


def test_m67_result_first_screen_and_command_line(page, server) -> None:
    page.set_viewport_size({"width": 1280, "height": 800})
    _open(page, server)
    page.evaluate("""() => { window.statuses = [];
        new MutationObserver(() => window.statuses.push(document.getElementById('status').textContent))
          .observe(document.getElementById('status'), {childList: true, subtree: true, characterData: true}); }""")
    page.set_input_files("#file", str(M67))
    page.fill("#time-limit", "12")
    page.fill("#seed", "7")
    _plan(page)
    s = page.evaluate("mxs.state.result.stats")
    bound_row = page.evaluate("""() => [...document.querySelectorAll('#summary tr')].map((tr) => tr.textContent)
        .find((r) => r.startsWith('proven lower bound'))""")
    assert bound_row == (f"proven lower bound on configurations{s['exposures_lower_bound']} "
                         f"(this plan: {s['configurations'] / s['exposures_lower_bound']:.2f}×)")
    rows = page.evaluate("() => [...document.querySelectorAll('#summary tr')].map((tr) => tr.textContent)")
    assert [r for r in rows if r.startswith("programme optimiser")] == _optimiser_rows(s)
    # a search kept that is not the first, with merges, emptied exposures and a consolidation
    tried = [{"pointing_cost": 0.3, "crowding": False, "exposures": 20, "pointings": 10, "complete": True,
              "chosen": False},
             {"pointing_cost": 0.6, "crowding": False, "exposures": 18, "pointings": 9, "complete": True,
              "chosen": True}]
    for merged, emptied, saved in ((2, 1, 3), (1, 0, 0), (0, 0, 1)):
        stats = {"segmentation": {"optimiser": {"model_variants": tried, "pointings_merged": merged,
                                                "exposures_emptied": emptied}},
                 "consolidation": {"exposures_saved": saved}}
        got = page.evaluate("(s) => programmeRows(s).map(([k, v]) => k + v)", stats)
        assert got == _optimiser_rows(stats) + (
            [f"configurations emptied after planning{saved} (targets onto idle arms)"] if saved else [])
    assert page.evaluate("programmeRows({})") == []
    boxes = _first_screen(page)
    assert abs(boxes["result"]["top"]) < 1
    for k in ("summary", "sky"):  # whole, on the first screen
        assert 0 <= boxes[k]["top"] and boxes[k]["bottom"] <= 800, (k, boxes)
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTEFACTS / "m67_first_screen.png"))
    # the long table: closed, after every pointing
    assert page.evaluate("document.querySelector('#every-target details').open") is False
    assert page.evaluate("""() => { const last = [...document.querySelectorAll('.pointing')].pop();
        return Boolean(last.compareDocumentPosition(document.querySelector('.every-target'))
          & Node.DOCUMENT_POSITION_FOLLOWING); }""")
    # the closed table takes a line, not its 150 rows (the issue measured 13,672 px with it open)
    table_px = page.evaluate("document.querySelector('#every-target').getBoundingClientRect().height")
    assert table_px < 80, table_px
    page.screenshot(path=str(ARTEFACTS / "m67_result.png"), full_page=True)
    # progress named the pointing, never showed the job's id; the id is a small detail
    statuses = page.evaluate("window.statuses")
    assert any(re.search(r"pointing \d+ of \d+", s) for s in statuses), statuses
    assert not any(HEX_ID.search(s) for s in statuses)
    job_id = page.get_attribute("#job-id", "title")
    assert HEX_ID.fullmatch(job_id.removeprefix("job ")) and page.inner_text("#job-id") == job_id[:12]
    _command_line_repeats_the_request(page)
    _every_target_row_of_sanders_1850(page)


def _command_line_repeats_the_request(page) -> None:
    """The CLI's own parser reads the page's command line back into the page's request."""
    line = page.inner_text("#cli-line code")
    words = shlex.split(line)
    assert words[:3] == ["mxs-planner", "plan", "m67-like-150-vizier.csv"]
    args = build_parser().parse_args(words[1:])
    request = page.evaluate("mxs.state.request")
    limit = page.evaluate("mxs.state.result.stats.time_limit_s")
    assert (args.seed, args.time_limit, limit) == (7, 12, 12)
    assert (args.method, args.solver, args.position_angle) == (
        request.get("method", "ilp"), request.get("solver", "bnb"), request.get("position_angle_deg", 0))
    assert args.segmentation_mode == request.get("segmentation_mode")
    assert not args.no_park_move_limit and args.park_move_limit == request["park_move_limit_s"]
    assert (args.exposure_time, args.acquisition) == (request["exposure_time_s"], request["acquisition_s"])
    assert (args.max_exposures, args.min_priority_per_exposure, args.min_targets_per_exposure) == (None, None, None)


def _every_target_row_of_sanders_1850(page) -> None:
    """The table gives the position in sexagesimal and decimal (astropy's reading of the file's
    '08 51 18.476, +11 46 50.67'), the priority as an integer."""
    head, row = page.evaluate("""() => { const t = document.querySelector('.every-target table');
        const cells = (tr) => [...tr.children].map((c) => c.textContent);
        return [cells(t.querySelector('thead tr')),
                cells([...t.querySelectorAll('tbody tr')].find((tr) => tr.firstChild.textContent === 'Sanders 1850'))]; }""")
    cell = dict(zip(head, row, strict=True))
    ra, dec = Angle("08 51 18.476", unit="hourangle"), Angle("+11 46 50.67", unit="deg")
    assert cell["RA (h:m:s)"] == ra.to_string(sep="hms", precision=2, pad=True)
    assert cell["Dec (d:m:s)"] == dec.to_string(sep=("°", "′", "″"), precision=1, pad=True, alwayssign=True)
    assert (float(cell["RA [deg]"]), float(cell["Dec [deg]"])) == (round(ra.deg, 5), round(dec.deg, 5))
    assert cell["priority"] == "500"


def test_a_plan_restored_after_a_reload_says_so_and_goes_stale(page, server, tmp_path: Path) -> None:
    _open(page, server)
    page.set_input_files("#file", str(_example_csv(tmp_path / "m13.csv")))
    page.fill("#time-limit", "10")
    page.fill("#seed", "3")
    _plan(page, 90_000)
    assert page.inner_text("#plan-origin").startswith("Plan of m13.csv (8 targets), finished at ")
    _legs_count_from_one(page)
    page.reload()
    page.wait_for_selector("#result:not([hidden])", timeout=30_000)
    origin = page.inner_text("#plan-origin")
    assert re.fullmatch(r"Previous plan, restored after a reload: m13\.csv \(8 targets\), finished at "
                        r"\d\d:\d\d:\d\d on \d{4}-\d\d-\d\d\.", origin), origin
    assert (page.input_value("#time-limit"), page.input_value("#seed")) == ("10", "3")  # its controls
    # the input changes: the plan says it is stale
    page.fill("#targets", "id,ra,dec\nx,250.42,36.46\n")
    assert "stale" in page.get_attribute("#result", "class")
    assert page.inner_text("#plan-origin").startswith("Stale: this plan is of the previous input, m13.csv")
    page.reload()
    page.wait_for_selector("#result:not([hidden])", timeout=30_000)
    # a new plan that errors leaves no old plan under its error, and none comes back on reload
    page.fill("#pa", "400")
    page.click("#go")
    page.wait_for_function("document.querySelector('#error').textContent.includes('position angle')")
    assert page.is_hidden("#result")
    page.reload()
    page.wait_for_selector("body[data-ready]")
    assert page.is_hidden("#result") and page.evaluate("sessionStorage.getItem('mxs-job')") is None


def _legs_count_from_one(page) -> None:
    """The controller commands count legs from 1, as configurations: leg k leaves c(k-1)."""
    result = page.evaluate("mxs.state.result")
    with page.expect_download() as dl:
        page.click("#dl-commands")
    rows = list(csv.DictReader(io.StringIO(Path(dl.value.path()).read_text())))
    expected = [(p["id"], str(i + 1), m["status"], str(t["arm"])) for p in result["pointings"]
                for i, m in enumerate(p["motions"]) for t in m["trajectories"] for _ in t["commands"]]
    assert [(r["pointing"], r["leg"], r["leg_status"], r["arm"]) for r in rows] == expected
    assert rows and min(int(r["leg"]) for r in rows) == 1
