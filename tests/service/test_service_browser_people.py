"""The dashboard and the fleet page as an operator sees them, in headless Chromium at 1280 px, in English and in
Chinese (issue 26 items 4–5): the browser's language zh-CN gives the Chinese catalogue (扭转刚度 on the rigidity
result), no label is broken inside a word, no result cell overflows, the fleet table fits, the readouts show the
live torque and the run state, a disabled Abort looks disabled, /favicon.ico answers.

Set TCMS_UPDATE_SCREENSHOT=1 to write docs/screenshot-dashboard-{en,zh}.png and docs/screenshot-fleet-{en,zh}.png.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import httpx
import pytest
from svc_helpers import TOKEN, ScriptedRunner, serve
from test_service_browser_fleet import _seed

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


def _check_layout(page) -> None:
    assert page.evaluate(OUTSIDE_PANEL) == []
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
            page.fill("#f-positions", "2")
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
            stages = page.inner_text("#stages")
            assert "位置 / °" in stages and "极差" in stages
            # values to the decimal place of their U: no six-digit figures in the per-position table
            assert not any(len(part.split(".")[-1]) > 3 for part in stages.split() if part.replace(".", "").isdigit())
            page.wait_for_function("document.querySelectorAll('#history tbody tr').length > 0")
            assert "已完成" in page.inner_text("#history")
            _check_layout(page)
            _keep(page, "screenshot-dashboard-zh.png", tmp_path)

            # the switch: English, kept for this browser
            page.select_option("#lang", "en")
            page.wait_for_function("document.documentElement.lang === 'en'")
            page.wait_for_selector("#results td.pass, #results td.fail, #results td.undecided")
            assert page.inner_text("#start") == "Start test"
            assert "rigidity / N·m/arcmin" in page.inner_text("#results")
            page.wait_for_function("window.tcms.state.frames > 5")
            _check_layout(page)
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
            headers = page.inner_text("#runs thead")
            assert ("扭转刚度" in headers and "背隙" in headers) if lang == "zh" else "backlash" in headers
            _keep(page, f"screenshot-fleet-{lang}.png", tmp_path)
            assert errors == []
        finally:
            browser.close()
