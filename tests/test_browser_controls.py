"""Issue 39's controls on the observation-preparation page, in Chromium against the real server
(the harness of tests/test_browser.py): the observation date, the position-angle search, sky
positions, locks and exclusions set by clicking a target or an arm and honoured by the next
plan, configurations kept from the plan shown, and a plan file checked by POST /v1/validations.

Each control's field is read from the request the page sends (POST v1/jobs, seen by playwright)
and its effect from the server's answer; sexagesimal sky positions are checked against astropy."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.coordinates import Angle

from models.instrument import default_instrument
from models.kinematics import inverse_fov
from tests import test_browser

# The uvicorn server, Chromium and page fixtures of the page's other browser tests.
server, browser, page = test_browser.server, test_browser.browser, test_browser.page

CENTRE = (250.4235, 36.4605)  # deg; every target within ~20 arcsec: one pointing, all arms reach
# Four stars about the centre (offsets in arcsec East, North) with proper motions (mas/yr).
STARS = [("a", 0.0, 0.0, 300, 40.0, -30.0), ("b", 12.0, 8.0, 200, 0.0, 0.0),
         ("c", -15.0, 5.0, 100, 0.0, 0.0), ("d", 4.0, -16.0, 50, 0.0, 0.0)]
NEW_CONTROLS = ["obs-date", "pa-auto", "pa-min", "pa-max", "pa-step", "sky-radius", "sky-positions", "sky-file",
                "lock-target", "lock-arm", "keep-k", "plan-file"]


def _csv(stars=STARS, motion: bool = False) -> str:
    import math

    head = "id,ra,dec,priority" + (",pmra,pmdec,ref_epoch" if motion else "")
    rows = []
    for sid, de, dn, prio, pmra, pmdec in stars:
        ra = CENTRE[0] + de / 3600 / math.cos(math.radians(CENTRE[1]))
        dec = CENTRE[1] + dn / 3600
        rows.append(f"{sid},{ra:.7f},{dec:.7f},{prio}" + (f",{pmra},{pmdec},2016.0" if motion else ""))
    return head + "\n" + "\n".join(rows) + "\n"


def _open(page, server: str) -> list[dict]:
    """The page, ready; returns the list the bodies of its POST v1/jobs requests go to."""
    sent: list[dict] = []
    page.on("request", lambda r: sent.append(json.loads(r.post_data)["request"])
            if r.method == "POST" and r.url.endswith("/v1/jobs") else None)
    page.goto(server + "/")
    page.wait_for_selector("body[data-ready]")
    return sent


def _plan(page, timeout_ms: int = 90_000, button: str = "#go") -> dict:
    page.click(button)
    page.wait_for_function("!document.querySelector('#go').disabled && "
                           "(!document.querySelector('#result').hidden || !document.querySelector('#error').hidden)",
                           timeout=timeout_ms)
    assert page.is_hidden("#error"), page.inner_text("#error")
    return page.evaluate("mxs.state.result")


def _small_plan(page, csv_text: str, seed: int = 1, limit_s: int = 15) -> dict:
    page.fill("#targets", csv_text)
    page.fill("#time-limit", str(limit_s))
    page.fill("#seed", str(seed))
    page.check("#park-unlimited")  # every arm reaches the centre
    return _plan(page)


def _where(result: dict) -> dict[str, tuple[str, int, int]]:
    """target -> (pointing, configuration from 1, arm)."""
    return {a["target_id"]: (p["id"], k + 1, a["arm"]) for p in result["pointings"]
            for k, c in enumerate(p["configurations"]) for a in c["assignments"] if a["target_id"]}


def _another_arm_reaching(result: dict, target: str, arm: int) -> int:
    """An arm other than `arm` that reaches the target's tip position (the kinematics' own IK),
    the farthest round the bench first."""
    x, y = next((a["x_mm"], a["y_mm"]) for p in result["pointings"] for c in p["configurations"]
                for a in c["assignments"] if a["target_id"] == target)
    inst = default_instrument()
    for step in (6, 5, 7, 4, 8, 3, 9, 2, 10, 1, 11):
        other = (arm + step) % 12
        if inverse_fov(inst, other, np.array([x]), np.array([y])).valid.any():
            return other
    raise AssertionError(f"no other arm reaches {target}")


def test_controls_send_their_fields(page, server, tmp_path: Path) -> None:
    """Without a plan: every new control has a label and sends its field; bad sky lines and half
    a range are errors naming them; the lock form and its list with remove buttons."""
    _open(page, server)
    for cid in NEW_CONTROLS:
        assert page.locator(f"label:has(#{cid}), label[for='{cid}']").count() >= 1, cid
    ask = "mxs.planRequest({targets: []})"
    assert not {"obs_date", "position_angle_range_deg", "sky_positions", "locked", "excluded_targets",
                "keep_configurations"} & set(page.evaluate(ask))
    page.fill("#obs-date", "2027-01-01")
    assert page.evaluate(ask)["obs_date"] == "2027-01-01"
    # the position angle: a number, or "auto" with a range and a step (checked by keyboard)
    assert page.is_disabled("#pa-min") and not page.is_disabled("#pa")
    page.focus("#pa-auto")
    page.keyboard.press("Space")
    assert page.is_checked("#pa-auto") and page.is_disabled("#pa") and not page.is_disabled("#pa-min")
    page.fill("#pa-min", "10")
    err = page.evaluate(f"() => {{ try {{ {ask}; return null; }} catch (e) {{ return e.message; }} }}")
    assert err and "position angle range" in err
    page.fill("#pa-max", "50")
    page.fill("#pa-step", "20")
    asked = page.evaluate(ask)
    assert (asked["position_angle_deg"], asked["position_angle_range_deg"], asked["position_angle_step_deg"]) == \
        ("auto", [10, 50], 20)
    # sky positions: decimal and sexagesimal, read as astropy reads them
    lines = ["250.47 36.45", "16:41:50.5 +36:27:10", "16 41 39.2 -01 02 03.5", "16h41m45.5s, +36d28m01s"]
    page.fill("#sky-positions", "\n".join(lines))
    got = page.evaluate(ask)["sky_positions"]
    expected = [(250.47, 36.45),
                (Angle("16:41:50.5", u.hourangle).deg, Angle("+36:27:10", u.deg).deg),
                (Angle("16 41 39.2", u.hourangle).deg, Angle("-01 02 03.5", u.deg).deg),
                (Angle("16h41m45.5s").deg, Angle("+36d28m01s").deg)]
    assert len(got) == len(expected)
    for g, (ra, dec) in zip(got, expected, strict=True):
        assert abs(g["ra_deg"] - ra) < 1e-9 and abs(g["dec_deg"] - dec) < 1e-9, (g, ra, dec)
    page.fill("#sky-positions", "250.47 36.45\n\n250.4 91\n")
    err = page.evaluate(f"() => {{ try {{ {ask}; return null; }} catch (e) {{ return e.message; }} }}")
    assert err and err.startswith("sky positions, line 3:")
    sky_file = tmp_path / "sky.csv"
    sky_file.write_text("ra,dec\n250.46,36.47\n250.39,36.44\n")
    page.set_input_files("#sky-file", str(sky_file))
    page.wait_for_function("document.getElementById('sky-positions').value.includes('250.39')")
    assert page.evaluate(ask)["sky_positions"] == [{"ra_deg": 250.46, "dec_deg": 36.47},
                                                   {"ra_deg": 250.39, "dec_deg": 36.44}]
    # the lock form and the list by the Plan button
    page.fill("#lock-target", "b")
    page.select_option("#lock-arm", "7")
    page.click("#lock-add")
    page.fill("#lock-target", "c")
    page.click("#exclude-add")
    assert page.locator("#lock-list li").all_inner_texts() == ["b locked to arm 7 remove", "c excluded remove"]
    asked = page.evaluate(ask)
    assert asked["locked"] == [{"target_id": "b", "arm": 7, "branch": None}] and asked["excluded_targets"] == ["c"]
    page.click("#lock-list li[data-exclude='c'] button.remove")
    asked = page.evaluate(ask)
    assert "excluded_targets" not in asked and len(asked["locked"]) == 1
    line = page.evaluate(f"mxs.cliLine({ask}, 't.csv', null)")
    assert "--obs-date 2027-01-01" in line and "--position-angle auto" in line
    assert "--position-angle-range 10 50" in line and "--lock b:7" in line and "--sky sky.csv" in line


def test_lock_and_exclude_by_clicking_then_plan_again(page, server) -> None:
    """Lock a target to another arm by clicking it in the configuration viewer, exclude one by
    clicking it in the sky view; the next plan observes the first on that arm and lists the
    second as excluded. The excluded star is a pointing of its own, 10' away, so that the
    locked star's pointing is the same in both plans."""
    sent = _open(page, server)
    first = _small_plan(page, _csv(STARS + [("z", 600.0, 0.0, 10, 0.0, 0.0)]))
    where = _where(first)
    assert "b" in where and "z" in where and where["z"][0] != where["b"][0], where
    old_arm = where["b"][2]
    new_arm = _another_arm_reaching(first, "b", old_arm)
    marker = page.locator(".pointing svg.configuration [data-id='b']").first
    if page.locator(".pointing").first.locator("svg.configuration").get_attribute("data-configuration") != str(where["b"][1]):
        page.locator(".pointing").first.locator(".stepper button").nth(where["b"][1] - 1).click()
    marker.click()
    menu = page.locator("#lock-menu")
    assert f"arm {old_arm}" in menu.inner_text()
    assert menu.locator("button.lock-here").inner_text().startswith(f"lock to arm {old_arm}")
    menu.locator("select.lock-arm").select_option(str(new_arm))
    menu.locator("button.lock-to").click()
    assert page.locator("#lock-menu").count() == 0
    page.locator("svg.sky .sky-target[data-id='z']").click()
    page.locator("#lock-menu button.exclude").click()
    assert page.locator("#lock-list li").all_inner_texts() == [f"b locked to arm {new_arm} remove", "z excluded remove"]
    # marked in both views, with a legend entry; the plan shown is stale
    assert page.locator("svg.sky g.lock-mark[data-for='b'][data-kind='mark-locked']").count() == 1
    assert page.locator("svg.sky g.lock-mark[data-for='z'][data-kind='mark-excluded']").count() == 1
    assert page.locator("svg.configuration g.lock-mark[data-for='b']").count() >= 1
    legend = page.locator(".field .legend li[data-kind]").evaluate_all("(ls) => ls.map((l) => l.dataset.kind)")
    assert {"mark-locked", "mark-excluded"} <= set(legend)
    assert "stale" in page.get_attribute("#result", "class")
    second = _plan(page)
    assert sent[-1]["locked"] == [{"target_id": "b", "arm": new_arm, "branch": None}]
    assert sent[-1]["excluded_targets"] == ["z"]
    assert _where(second)["b"][2] == new_arm
    assert "z" not in _where(second)
    unallocated = second.get("unallocated", []) + [u for p in second["pointings"] for u in p["unallocated"]]
    assert {u["reason"] for u in unallocated if u["target_id"] == "z"} == {"excluded"}
    row = page.evaluate("""() => [...document.querySelectorAll('.every-target tbody tr')]
        .map((tr) => [...tr.children].map((td) => td.textContent)).find((r) => r[0] === 'z')""")
    assert row[-1] == "excluded"
    # an arm clicked in the viewer names its target; the lock list survives the new plan
    arm = page.locator(f".pointing svg.configuration g.arm[data-arm='{new_arm}']").first
    arm.dispatch_event("click")
    assert "b: arm" in page.inner_text("#lock-menu")
    page.keyboard.press("Escape")
    assert page.locator("#lock-menu").count() == 0
    assert page.locator("#lock-list li").count() == 2
    # by keyboard: a target focused, Enter opens its menu, Escape closes it and gives the focus back
    page.locator("svg.sky .sky-target[data-id='a']").focus()
    page.keyboard.press("Enter")
    assert page.inner_text("#lock-menu").startswith("a: ")
    assert page.evaluate("document.activeElement.closest('#lock-menu') !== null")
    page.keyboard.press("Escape")
    assert page.locator("#lock-menu").count() == 0
    assert page.evaluate("document.activeElement.dataset.id") == "a"


def test_epochs_position_angle_search_and_sky(page, server) -> None:
    """One plan with an observation date, the position angle searched and sky positions: the
    banner shows the epoch notice, each pointing's header its PA marked (auto), the viewer and
    the arms table the sky arms."""
    sent = _open(page, server)
    page.fill("#obs-date", "2027-01-01")
    page.check("#pa-auto")
    page.fill("#pa-min", "0")
    page.fill("#pa-max", "60")
    page.fill("#pa-step", "30")
    sky = [(CENTRE[0] + 0.012, CENTRE[1] + 0.010), (CENTRE[0] - 0.013, CENTRE[1] - 0.008),
           (CENTRE[0] + 0.004, CENTRE[1] - 0.015)]
    page.fill("#sky-positions", "\n".join(f"{ra:.6f} {dec:.6f}" for ra, dec in sky))
    page.fill("#sky-radius", "6")
    result = _small_plan(page, _csv(motion=True))
    req = sent[-1]
    assert req["obs_date"] == "2027-01-01" and req["position_angle_deg"] == "auto"
    assert (req["position_angle_range_deg"], req["position_angle_step_deg"], req["sky_radius_arcsec"]) == ([0, 60], 30, 6)
    assert [(s["ra_deg"], s["dec_deg"]) for s in req["sky_positions"]] == [(round(ra, 6), round(dec, 6)) for ra, dec in sky]
    assert req["targets"][0]["pmra_mas_yr"] == 40.0 and req["targets"][0]["ref_epoch_yr"] == 2016.0
    banner = page.inner_text("#banner")
    assert result["notices"] and all(n in banner for n in result["notices"])
    assert any("2027-01-01" in n for n in result["notices"]), result["notices"]
    for p in result["pointings"]:
        search = p["position_angle_search"]
        assert search and p["position_angle_deg"] == search["chosen_deg"] and search["chosen_deg"] in (0, 30, 60)
        head = page.locator(f".pointing[data-pointing='{p['id']}'] h3").first.inner_text()
        assert f"PA {p['position_angle_deg']:.1f}° (auto)" in head
    kinds = [a["kind"] for p in result["pointings"] for c in p["configurations"] for a in c["assignments"]]
    assert "sky" in kinds, kinds
    sec = page.locator(".pointing").first
    assert sec.locator("svg.configuration g.arm[data-kind='arm-sky']").count() == \
        sum(a["kind"] == "sky" for a in result["pointings"][0]["configurations"][0]["assignments"])
    assert sec.locator(".legend li[data-kind='arm-sky']").count() == 1
    rows = sec.locator("details.assignments tbody tr").evaluate_all(
        "(trs) => trs.map((tr) => [...tr.children].map((td) => td.textContent))")
    assert [r[2] for r in rows] == [a["kind"] for c in result["pointings"][0]["configurations"] for a in c["assignments"]]
    assert all(r[4] for r in rows if r[2] == "sky")
    assert page.locator("svg.sky .sky-position").count() == len(sky)


def test_check_a_plan_file(page, server, tmp_path: Path) -> None:
    """The plan the page downloads is valid; the same file with an arm's joint angle edited is
    not, and says why."""
    _open(page, server)
    _small_plan(page, _csv())
    with page.expect_download() as dl:
        page.click("#dl-json")
    plan_file = tmp_path / "plan.json"
    plan_file.write_text(Path(dl.value.path()).read_text())
    page.set_input_files("#plan-file", str(plan_file))
    page.wait_for_function("document.getElementById('validation').classList.contains('good') || "
                           "document.getElementById('validation').classList.contains('bad')")
    assert "plan.json: VALID" in page.inner_text("#validation")
    edited = json.loads(plan_file.read_text())
    edited["pointings"][0]["configurations"][0]["assignments"][0]["theta1_rad"] += 0.2
    bad = tmp_path / "edited.json"
    bad.write_text(json.dumps(edited))
    page.set_input_files("#plan-file", str(bad))
    page.wait_for_function("document.getElementById('validation').classList.contains('bad')")
    text = page.inner_text("#validation")
    assert "edited.json: NOT VALID" in text and "does NOT match" in text
    assert page.locator("#validation li").count() >= 1


def test_keep_configurations_of_the_plan_shown(page, server) -> None:
    """Keeping c1 of the plan shown sends its configurations (the plan's own arms, targets and
    joint angles) and the next plan, with another seed, starts with them unchanged."""
    sent = _open(page, server)
    stars = STARS + [(f"e{i}", 20.0 * (i % 4) - 30.0, 9.0 * (i // 4) - 22.0, 10, 0.0, 0.0) for i in range(11)]
    first = _small_plan(page, _csv(stars), limit_s=8)  # 8 configurations: what is kept, not how well
    assert sum(len(p["configurations"]) for p in first["pointings"]) >= 2
    page.fill("#seed", "5")
    page.fill("#keep-k", "1")
    second = _plan(page, button="#keep-go")
    kept = sent[-1]["keep_configurations"]["pointings"]
    with_conf = [p for p in first["pointings"] if p["configurations"]]
    assert [k["id"] for k in kept] == [p["id"] for p in with_conf]
    for k, p in zip(kept, with_conf, strict=True):
        assert k["configurations"] == [[{"arm": a["arm"], "target_id": a["target_id"], "theta1_rad": a["theta1_rad"],
                                          "theta2_rad": a["theta2_rad"]} for a in p["configurations"][0]["assignments"]]]
        new = next(q for q in second["pointings"] if q["id"] == p["id"])
        same = [(a["arm"], a["target_id"], a["theta1_rad"], a["theta2_rad"]) for a in new["configurations"][0]["assignments"]]
        assert same == [(a["arm"], a["target_id"], a["theta1_rad"], a["theta2_rad"])
                        for a in p["configurations"][0]["assignments"]]
    assert page.locator("#lock-list li[data-keep='1']").count() == 1
