"""The dashboard and the fleet page as an operator sees them, in headless Chromium at 1280 px, in English and in
Chinese (issue 26 items 4–5): the browser's language zh-CN gives the Chinese catalogue (扭转刚度 on the rigidity
result), no label is broken inside a word, no result cell overflows, the fleet table fits, the readouts show the
live torque and the run state, a disabled Abort looks disabled, /favicon.ico answers.

Set TCMS_UPDATE_SCREENSHOT=1 to write docs/screenshot-dashboard-{en,zh}.png and docs/screenshot-fleet-{en,zh}.png.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import httpx
import pytest
from svc_helpers import TOKEN, ScriptedRunner, _u_entry, results_with_uncertainty, serve
from test_service_browser_fleet import _seed

from tcms_daq.analysis.gaps import Gap
from tcms_daq.analysis.notices import Notice, prepend_warnings
from tcms_daq.service import messages
from tcms_daq.service.users import hash_password
from tcms_daq.store import open_store

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
REPO = Path(__file__).resolve().parents[2]
WIDTH = 1280

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason="needs Debian's chromium at /usr/bin/chromium"),
]

# Elements whose text overflows their box (a label or a value cut off, or pushed out of its cell), and labels
# that wrap inside a word: a label's lines are only ever broken at spaces (CJK text between characters).
OVERFLOWING = """(selector) => [...document.querySelectorAll(selector)]
  .filter((el) => el.offsetParent !== null && el.scrollWidth > el.clientWidth + 1)
  .map((el) => el.id || el.textContent.trim().slice(0, 40))"""
BROKEN_INSIDE_A_WORD = """(selector) => {
  const broken = [];
  for (const el of document.querySelectorAll(selector)) {
    if (el.offsetParent === null) continue;
    const walker = document.createTreeWalker(el, NodeFilter.SHOW_TEXT);
    for (let node = walker.nextNode(); node; node = walker.nextNode()) {
      const text = node.textContent;
      const range = document.createRange();
      let lastTop = null;
      for (let i = 0; i < text.length; i++) {
        range.setStart(node, i); range.setEnd(node, i + 1);
        const rect = range.getClientRects()[0];
        if (!rect) continue;
        if (lastTop !== null && rect.top > lastTop + 2) {
          const before = text[i - 1] || " ", here = text[i];
          const latin = /[A-Za-z0-9·\\/″°]/;
          if (latin.test(before) && latin.test(here)) broken.push(text.trim().slice(0, 40));
        }
        lastTop = rect.top;
      }
    }
  }
  return broken;
}"""
LABELS = "th, label, button, h1, h2, h3, .readout .label, .readout .unit, #history td, #results td, #stages td"


def _keep(page, name: str, tmp_path: Path) -> Path:
    shot = tmp_path / name
    page.screenshot(path=str(shot), full_page=True)
    if os.environ.get("TCMS_UPDATE_SCREENSHOT") == "1":
        shutil.copyfile(shot, REPO / "docs" / name)
    return shot


# tables wider than their panel (cut off, or pushing the page wider)
OUTSIDE_PANEL = """() => [...document.querySelectorAll('.panel table')]
  .filter((t) => t.offsetParent !== null && t.getBoundingClientRect().right > t.closest('.panel').getBoundingClientRect().right + 1)
  .map((t) => t.id)"""


def _check_layout(page, lang: str) -> None:
    assert page.evaluate(OUTSIDE_PANEL) == []
    # the recent tests still fit with the widest words a row can show (an interrupted run, an undecided verdict)
    from tcms_daq.service.messages import CATALOGUES

    words = CATALOGUES[lang]
    widest = [max((w for k, w in words.items() if k.startswith(prefix)), key=len) for prefix in ("state.", "verdict.")]
    shown = page.evaluate("""(widest) => { const row = document.querySelector('#history tbody tr');
        const was = [row.cells[2].textContent, row.cells[3].textContent];
        [row.cells[2].textContent, row.cells[3].textContent] = widest; return was; }""", widest)
    assert page.evaluate(OUTSIDE_PANEL) == [], widest
    page.evaluate("""(shown) => { const row = document.querySelector('#history tbody tr');
        [row.cells[2].textContent, row.cells[3].textContent] = shown; }""", shown)
    assert page.evaluate(OVERFLOWING, "#results td, #results th, #stages td, #history td, .readout .value") == []
    assert page.evaluate(BROKEN_INSIDE_A_WORD, LABELS) == []
    assert page.evaluate("document.documentElement.scrollWidth") <= WIDTH  # nothing off-screen to the right


@pytest.mark.timeout(240)
def test_dashboard_in_chinese_and_english_at_1280(settings_factory, sim_config, tmp_path):
    from playwright.sync_api import sync_playwright

    settings = settings_factory(config_path=sim_config, sim_speed=8.0)
    with serve(settings) as srv, sync_playwright() as pw:
        assert httpx.get(srv.base + "/favicon.ico").status_code == 200
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            context = browser.new_context(locale="zh-CN", viewport={"width": WIDTH, "height": 900})
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(f"{srv.base}/?token={TOKEN}")
            page.wait_for_function("document.querySelector('#f-reducer').options.length > 0")
            page.wait_for_function("window.tcms.state.frames > 5")
            assert page.evaluate("document.documentElement.lang") == "zh-CN"
            assert page.inner_text("#start") == "开始试验" and page.inner_text("#abort") == "中止"
            assert page.input_value("#lang") == "zh"
            # the live readouts: torque as a number with its unit, the run state
            page.wait_for_function("/^-?\\d+\\.\\d$/.test(document.querySelector('#ro-torque').textContent)")
            assert page.inner_text("#ro-state") == "空闲"
            # a disabled Abort looks disabled: not the red of an active one
            colour = page.evaluate("getComputedStyle(document.querySelector('#abort')).backgroundColor")
            assert page.is_disabled("#abort") and colour != "rgb(179, 38, 30)", colour
            page.select_option("#f-reducer", "RV-110E")
            page.fill("#f-torque", "400")
            page.fill("#f-cycles", "1")
            page.fill("#f-rate", "200")
            page.fill("#f-serial", "SN-1280")
            page.click("#start")
            page.wait_for_function("document.querySelector('#ro-state').dataset.state === 'running'", timeout=20_000)
            page.wait_for_function("/^\\d+(:\\d\\d)?$/.test(document.querySelector('#ro-eta').textContent)",
                                   timeout=20_000)
            assert page.is_enabled("#abort")
            page.wait_for_function(
                "['completed','failed','aborted'].includes(document.querySelector('#ro-state').dataset.state)",
                timeout=150_000)
            assert page.get_attribute("#ro-state", "data-state") == "completed"
            page.wait_for_selector("#results td.pass, #results td.fail, #results td.undecided")
            results = page.inner_text("#results")
            assert "扭转刚度 / N·m/arcmin" in results and "空程" in results and "背隙" in results, results
            # a value to the decimal place of its U ("306.0 ± 2.6"), never six significant digits
            assert re.search(r"扭转刚度 / N·m/arcmin\s+\d+\.\d ± \d\.\d \(k = \d\.\d\d\)", results), results
            # the budget's sources, the decision rule and the buttons in Chinese too (the core names them in English)
            assert "主要分量：" in results and not re.search(r"interpolation|noise within|repeatability|torque scale",
                                                             results), results
            assert "保护带规则" in results or "简单接受规则" in results, results
            page.wait_for_selector("#history button.find-effects")
            assert page.inner_text("#history button.find-effects") == "缺失效应"
            page.wait_for_function("document.querySelectorAll('#history tbody tr').length > 0")
            assert "已完成" in page.inner_text("#history")
            _check_layout(page, "zh")
            _keep(page, "screenshot-dashboard-zh.png", tmp_path)

            # the switch: English, kept for this browser
            page.select_option("#lang", "en")
            page.wait_for_function("document.documentElement.lang === 'en'")
            page.wait_for_selector("#results td.pass, #results td.fail, #results td.undecided")
            assert page.inner_text("#start") == "Start test"
            assert "rigidity / N·m/arcmin" in page.inner_text("#results")
            page.wait_for_function("window.tcms.state.frames > 5")
            _check_layout(page, "en")
            _keep(page, "screenshot-dashboard-en.png", tmp_path)
            assert errors == []
        finally:
            browser.close()


@pytest.mark.timeout(150)
@pytest.mark.parametrize("locale, lang", [("en-US", "en"), ("zh-CN", "zh")])
def test_fleet_table_fits_1280_and_no_result_cell_overflows(settings_factory, tmp_path, locale, lang):
    from playwright.sync_api import sync_playwright

    settings = settings_factory()
    _seed(settings.data_dir)
    with open_store(None, settings.data_dir) as store:
        store.append_audit("erik", "plan.save", role="engineer", target="incoming RV-110E", before="v1", after="v2")
        store.append_audit("olga", "user.login_locked", detail="from 127.0.0.1")
    with serve(settings, runner=ScriptedRunner()) as srv, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            context = browser.new_context(locale=locale, viewport={"width": WIDTH, "height": 1000})
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(f"{srv.base}/fleet?token={TOKEN}")
            page.wait_for_function("document.querySelectorAll('#runs tbody tr[data-id]').length === 12")
            page.wait_for_function("document.querySelectorAll('#audit tbody tr').length > 0")
            # the whole run table is visible: no horizontal scrolling, the files column on screen
            wrap = page.evaluate("(() => { const w = document.querySelector('#runs').parentElement; "
                                 "return [w.scrollWidth, w.clientWidth]; })()")
            assert wrap[0] <= wrap[1], wrap
            right = page.evaluate("document.querySelector('#runs td.files').getBoundingClientRect().right")
            assert right <= WIDTH
            assert page.evaluate(OVERFLOWING, "#runs td, #runs th") == []
            assert page.evaluate(OUTSIDE_PANEL) == []
            assert page.evaluate(BROKEN_INSIDE_A_WORD, "#runs th, #runs td") == []
            assert page.evaluate("document.documentElement.scrollWidth") <= WIDTH
            # the audit trail's actions in the page's language (the code stays the cell's title)
            actions = page.eval_on_selector_all("#audit tbody td[title]", "els => els.map(e => [e.title, e.textContent])")
            assert actions, "no audit entry shown"
            for code, shown in actions:
                assert shown == messages.catalogue(lang).get(f"action.{code}", code), (code, shown)
            headers = page.inner_text("#runs thead")
            assert ("扭转刚度" in headers and "背隙" in headers) if lang == "zh" else "backlash" in headers
            if lang == "zh":  # no English left on the page's own headings and hints
                assert not re.search(r"Missing effects|stored run|press", page.inner_text("body"))
            _keep(page, f"screenshot-fleet-{lang}.png", tmp_path)
            assert errors == []
        finally:
            browser.close()


def _positions_results() -> dict:
    """Results of a test at two output positions, with U per position (as the evaluation writes them)."""
    def entry(position: float, rigidity: float, lost: float, backlash: float) -> dict:
        u = {"rigidity_nm_per_arcmin": _u_entry(rigidity, 2.6813 / 1.96, 1.96, "N·m/arcmin", "torque scale"),
             "lost_motion_arcsec": _u_entry(lost, 0.36412 / 1.97, 1.97, "arcsec", "encoder interpolation"),
             "backlash_arcsec": _u_entry(backlash, 0.33071 / 2.2, 2.2, "arcsec", "loop-to-loop scatter")}
        return {"position_deg": position, "rigidity_nm_per_arcmin": rigidity, "lost_motion_arcsec": lost,
                "backlash_arcsec": backlash, "uncertainty": u}

    results = results_with_uncertainty()
    results.update({
        "positions": [entry(0.0, 304.246123, 24.8712, 7.8893), entry(180.0, 304.816770, 24.9044, 7.7801)],
        "rigidity_nm_per_arcmin_max": 304.81677, "rigidity_nm_per_arcmin_min": 304.246123,
        "rigidity_nm_per_arcmin_spread": 0.570647, "lost_motion_arcsec_max": 24.9044,
        "lost_motion_arcsec_min": 24.8712, "lost_motion_arcsec_spread": 0.0332, "backlash_arcsec_max": 7.8893,
        "backlash_arcsec_min": 7.7801, "backlash_arcsec_spread": 0.1092})
    return results


@pytest.mark.timeout(150)
def test_an_operator_signs_in_picks_a_plan_and_starts_it(settings_factory, tmp_path):
    """Sign-in (session cookie), the plan picker and the start of a plan from the page, as an operator; the page
    opened after a test shows its per-position table rounded to U."""
    from playwright.sync_api import sync_playwright

    settings = settings_factory()
    with open_store(None, settings.data_dir, bench_id="line-a", bench_name="Line A") as store:
        store.add_user("olga", "operator", hash_password("olga-password"))
        plan = store.add_plan("incoming RV-110E", {"reducer": "RV-110E", "max_torque_nm": 300.0, "cycles": 2,
                                                   "profile": "continuous", "rate_nm_per_s": 1000.0}, "erik")
        store.create_run("earlier", {"reducer": "RV-110E", "serial_number": "SN-1", "max_torque_nm": 300.0},
                         ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec"))
        store.set_status("earlier", "completed", results=_positions_results())
    runner = ScriptedRunner()
    runner.bench_id = "line-a"
    with serve(settings, runner=runner) as srv, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_context(locale="en-US", viewport={"width": WIDTH, "height": 900}).new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(srv.base + "/")  # no token: the sign-in form
            page.wait_for_selector("#login-box:not([hidden])")
            # the earlier run of this bench: its per-position table with each value to the decimal place of its U
            page.wait_for_function("!document.querySelector('#stages').hidden")
            stages = page.inner_text("#stages")
            assert "304.2 ± 2.7" in stages and "304.8 ± 2.7" in stages and "24.87 ± 0.36" in stages, stages
            assert "304.246" not in stages and "0.570647" not in stages
            page.fill("#l-name", "olga")
            page.fill("#l-password", "olga-password")
            page.click("#login-form button")
            page.wait_for_function("document.querySelector('#who').textContent.includes('olga (operator)')")
            assert page.is_hidden("#login-box") and page.is_disabled("#save-plan")  # an operator saves no plan
            page.wait_for_function(f"[...document.querySelector('#f-plan').options].some(o => o.value === '{plan.id}')")
            page.select_option("#f-plan", str(plan.id))
            assert page.input_value("#f-torque") == "300" and page.is_disabled("#f-torque")
            page.fill("#f-serial", "SN-0042")
            page.click("#start")
            page.wait_for_function("document.querySelector('#ro-state').dataset.state === 'completed'", timeout=60_000)
            run_id = page.inner_text("#test-id")
            with srv.client() as service:
                run = service.get(f"/api/tests/{run_id}").json()
                assert run["user"] == "olga" and run["plan"]["name"] == "incoming RV-110E"
                assert run["request"]["serial_number"] == "SN-0042" and run["bench_id"] == "line-a"
                started = service.get("/api/audit", params={"action": "test.start"}).json()[0]
                assert started["user"] == "olga" and started["target"] == run_id
            assert errors == []
        finally:
            browser.close()


def _sign_in(page, base: str, name: str) -> None:
    page.goto(base + "/")
    page.wait_for_selector("#login-box:not([hidden])")
    page.fill("#l-name", name)
    page.fill("#l-password", f"{name}-password")
    page.click("#login-form button")
    page.wait_for_function(f"document.querySelector('#who').textContent.includes('{name}')")


@pytest.mark.timeout(150)
@pytest.mark.parametrize("locale, lang", [("en-US", "en"), ("zh-CN", "zh")])
def test_an_engineer_saves_and_edits_a_plan_and_an_operator_starts_it(settings_factory, locale, lang):
    """The plan editor (issue 26 item 3) in both languages: an engineer saves a plan from the form, a plan the
    bench cannot run is refused with the API's error under the editor and its field outlined, the engineer
    edits the plan into version 2; an operator (no editor) picks version 2 and starts it; the run names the plan,
    its version and the operator."""
    from playwright.sync_api import sync_playwright

    settings = settings_factory()
    with open_store(None, settings.data_dir) as store:
        store.add_user("olga", "operator", hash_password("olga-password"))
        store.add_user("erik", "engineer", hash_password("erik-password"))
    with serve(settings, runner=ScriptedRunner()) as srv, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            errors: list[str] = []
            engineer = browser.new_context(locale=locale, viewport={"width": WIDTH, "height": 900}).new_page()
            engineer.on("pageerror", lambda exc: errors.append(str(exc)))
            _sign_in(engineer, srv.base, "erik")
            assert engineer.is_visible("#plan-editor") and engineer.is_enabled("#save-plan")
            assert engineer.inner_text("#save-plan") == ("保存方案" if lang == "zh" else "Save plan")
            engineer.wait_for_function("document.querySelector('#f-reducer').options.length > 0")
            engineer.select_option("#f-reducer", "RV-110E")
            engineer.fill("#f-torque", "300")
            engineer.fill("#f-cycles", "1")
            engineer.fill("#f-rate", "1000")
            engineer.select_option("#f-rule", "guarded")
            engineer.fill("#p-name", "incoming RV-110E")
            engineer.fill("#p-note", "first")
            engineer.click("#save-plan")
            engineer.wait_for_function("document.querySelector('#f-plan').selectedOptions[0].textContent"
                                       ".includes('incoming RV-110E')")
            assert engineer.is_visible("#edit-plan") and engineer.is_disabled("#f-torque")

            # edit: the picked plan's fields open, saving makes version 2; first a torque the bench refuses
            engineer.click("#edit-plan")
            assert engineer.input_value("#f-plan") == "" and engineer.input_value("#p-name") == "incoming RV-110E"
            assert engineer.is_enabled("#f-torque") and engineer.input_value("#f-rule") == "guarded"
            engineer.fill("#f-torque", "5000")
            engineer.fill("#p-note", "too much")
            engineer.click("#save-plan")
            engineer.wait_for_function("document.querySelector('#plan-error').textContent.length > 0")
            assert "422" in engineer.inner_text("#plan-error") and "1000" in engineer.inner_text("#plan-error")
            assert "invalid" in engineer.get_attribute("#f-torque", "class")
            engineer.fill("#f-torque", "250")
            engineer.fill("#p-note", "lower torque")
            engineer.click("#save-plan")
            engineer.wait_for_function("document.querySelector('#f-plan').selectedOptions[0].textContent"
                                       ".includes('2')")
            assert engineer.inner_text("#plan-error") == "" and not engineer.evaluate(
                "document.querySelector('#f-torque').classList.contains('invalid')")
            with srv.client() as service:
                versions = service.get("/api/plans", params={"all_versions": True}).json()
            assert [(p["version"], p["request"]["max_torque_nm"], p["note"]) for p in versions] == [
                (2, 250.0, "lower torque"), (1, 300.0, "first")]
            assert versions[0]["request"]["decision_rule"] == "guarded" and versions[0]["created_by"] == "erik"
            v2 = versions[0]["id"]

            operator = browser.new_context(locale=locale, viewport={"width": WIDTH, "height": 900}).new_page()
            operator.on("pageerror", lambda exc: errors.append(str(exc)))
            _sign_in(operator, srv.base, "olga")
            assert operator.is_hidden("#plan-editor")
            operator.wait_for_function(f"[...document.querySelector('#f-plan').options].some(o => o.value === '{v2}')")
            option = operator.inner_text(f"#f-plan option[value='{v2}']")
            assert option == ("incoming RV-110E 第2版" if lang == "zh" else "incoming RV-110E v2"), option
            operator.select_option("#f-plan", str(v2))
            assert operator.input_value("#f-torque") == "250" and operator.is_hidden("#edit-plan")
            operator.fill("#f-serial", "SN-0077")
            operator.click("#start")
            operator.wait_for_function("document.querySelector('#ro-state').dataset.state === 'completed'",
                                       timeout=60_000)
            run_id = operator.inner_text("#test-id")
            with srv.client() as service:
                run = service.get(f"/api/tests/{run_id}").json()
            assert run["plan"] == {"id": v2, "name": "incoming RV-110E", "version": 2}, run["plan"]
            assert run["user"] == "olga" and run["request"]["max_torque_nm"] == 250.0
            assert run["request"]["serial_number"] == "SN-0077"
            assert errors == []
        finally:
            browser.close()


@pytest.mark.timeout(120)
def test_an_admin_changes_the_bench_settings_on_the_page(settings_factory):
    """The settings section (admin only): a value out of range is refused with the API's error under the form and
    its field outlined; a valid change is saved (and names the bench on the page); an engineer sees no section."""
    from playwright.sync_api import sync_playwright

    settings = settings_factory()
    with open_store(None, settings.data_dir) as store:
        store.add_user("ada", "admin", hash_password("ada-password"))
        store.add_user("erik", "engineer", hash_password("erik-password"))
    with serve(settings, runner=ScriptedRunner()) as srv, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            errors: list[str] = []
            page = browser.new_context(locale="zh-CN", viewport={"width": WIDTH, "height": 900}).new_page()
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            _sign_in(page, srv.base, "erik")
            assert page.is_hidden("#settings-box")
            page.click("#sign-out")
            _sign_in(page, srv.base, "ada")
            page.wait_for_selector("#settings-box:not([hidden])")
            assert page.inner_text("#settings-box summary") == "试验台设置"
            page.click("#settings-box summary")
            page.wait_for_function("document.querySelector('#s-lockout_s').value === '300'")
            page.fill("#s-lockout_s", "5")
            page.click("#save-settings")
            page.wait_for_function("document.querySelector('#settings-error').textContent.includes('lockout_s')")
            assert "invalid" in page.get_attribute("#s-lockout_s", "class")
            page.fill("#s-lockout_s", "600")
            page.fill("#s-bench_display_name", "装配线 A")
            page.click("#save-settings")
            page.wait_for_function("document.querySelector('#bench-name').textContent === '装配线 A'")
            assert page.inner_text("#settings-error") == ""
            with srv.client() as service:
                entry = service.get("/api/audit", params={"action": "settings.change"}).json()[0]
            assert entry["user"] == "ada" and "lockout_s=600" in entry["after"], entry
            assert errors == []
        finally:
            browser.close()


def _degrees_record_results() -> dict:
    """The core's results of a record whose angle column is in degrees (a triangle of ±300 N·m over a spring of
    290 N·m/arcmin with 10″ of play): a coded warning, and a verdict undecided for that reason."""
    import json

    import numpy as np

    from tcms_daq.analysis import evaluate
    from tcms_daq.analysis.evaluation import Limits

    t = np.arange(0.0, 4 * 4 * 300 / 250.0, 1 / 200.0)
    phase = (t % (4 * 300 / 250.0)) / (4 * 300 / 250.0)
    torque = 300.0 * np.where(phase < 0.25, 4 * phase, np.where(phase < 0.75, 2 - 4 * phase, 4 * phase - 4))
    angle_arcsec = torque / 290.0 * 60.0 + np.where(np.gradient(torque) > 0, -5.0, 5.0)
    ev = evaluate(t, torque, angle_arcsec / 3600.0, rated_torque_nm=300.0,
                  limits=Limits(rigidity_min_nm_per_arcmin=200.0))
    return json.loads(json.dumps(ev.to_dict()))


@pytest.mark.timeout(120)
def test_warnings_reasons_and_verdicts_in_chinese(settings_factory):
    """The core's English warning and its reason for an undecided verdict, shown in Chinese from their codes
    (issue 26 item 2) on the dashboard (browser language zh-CN) and in the report (?lang=zh); English stays the
    core's own text."""
    from playwright.sync_api import sync_playwright

    results = _degrees_record_results()
    assert results["verdict"]["decision"] == "undecided" and len(results["notices"]) == 1
    # a left-out loop's warning holds the gap's own coded description: both in Chinese
    gap = Gap("torque", 12.0, 12.5, 100.0, 300.0).describe()
    prepend_warnings(results, [Notice("loop_left_out_gap", "loop {loop} left out, not evaluated across a gap: {gaps}",
                                      loop="2", gaps=[gap])])
    settings = settings_factory()
    with open_store(None, settings.data_dir, bench_id="line-a", bench_name="Line A") as store:
        store.create_run("degrees", {"reducer": "RV-110E", "serial_number": "SN-DEG", "max_torque_nm": 300.0},
                         ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec"))
        store.set_status("degrees", "completed", results=results)
    runner = ScriptedRunner()
    runner.bench_id = "line-a"
    with serve(settings, runner=runner) as srv, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_context(locale="zh-CN", viewport={"width": WIDTH, "height": 900}).new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(f"{srv.base}/?token={TOKEN}")
            page.wait_for_selector("#results td.undecided")
            shown = page.inner_text("#results")
            assert "无法判定" in shown and "简单接受" in shown, shown
            assert "按角秒计不合理地小（若为度则为 134.1″" in shown and "警告" in shown, shown
            assert "implausibly small" not in shown and "扭转刚度 ≥ 200 N·m/arcmin" in shown
            assert "第 2 个循环含数据间隙，未参与评定：扭矩通道：0.50 s 内无读数" in shown and "channel" not in shown, shown
            assert "无法判定" in page.inner_text("#history")
            assert page.evaluate(OVERFLOWING, "#results td, #results th") == []
            assert errors == []
        finally:
            browser.close()
        zh = httpx.get(f"{srv.base}/api/tests/degrees/report", params={"lang": "zh"}, timeout=60).text
        assert "按角秒计不合理地小" in zh and "简单接受" in zh and "扭转刚度 ≥ 200 N·m/arcmin" in zh
        en = httpx.get(f"{srv.base}/api/tests/degrees/report", params={"lang": "en"}, timeout=60).text
        assert "implausibly small for arcsec (in degrees it would be 134.1″" in en and "simple rule" in en
