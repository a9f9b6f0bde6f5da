"""The dashboard of the simulated station in headless Chromium (issue 28 item 6): the method picker shows the
method's own fields, a transmission-error test started from the page draws its TE against the output angle and its
order spectrum live, then the evaluated curve, spectrum and lines (order, component, amplitude ± U) as the API
states them; in Chinese too; a saved plan keeps its method.

Set TCMS_UPDATE_SCREENSHOT=1 to write the views at 1280 px to docs/screenshot-te-live.png and docs/screenshot-te.png.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from svc_helpers import TOKEN, serve
from test_service_browser import ARGS, CHROMIUM

from tcms_daq.analysis.rounding import round_to_uncertainty
from tcms_daq.config.loader import resolve_config_path

REPO = Path(__file__).resolve().parents[2]

# Pixels of a method plot's canvas in the forward (#1f5fa8) or reverse (#d9771e) colour: > 0 once uPlot drew it.
COUNT_CURVE_PIXELS = """(id) => {
  const canvas = document.querySelector('#' + id + ' canvas');
  if (!canvas) return 0;
  const d = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    const [r, g, b] = [d[i], d[i + 1], d[i + 2]];
    if (d[i + 3] > 0 && ((b > 140 && r < 90) || (r > 180 && g > 90 && g < 150 && b < 80))) n++;
  }
  return n;
}"""

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason="needs Debian's chromium at /usr/bin/chromium"),
]


def _shot(page, tmp_path, name: str) -> None:
    shot = tmp_path / name
    page.screenshot(path=str(shot), full_page=True)
    if os.environ.get("TCMS_UPDATE_SCREENSHOT") == "1":
        shutil.copyfile(shot, REPO / "docs" / name)


@pytest.mark.timeout(180)
def test_the_transmission_error_view_live_and_evaluated(settings_factory, tmp_path):
    from playwright.sync_api import sync_playwright

    settings = settings_factory(config_path=resolve_config_path("bench-station.toml"), sim_speed=6.0)
    with serve(settings) as srv, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(f"{srv.base}/?token={TOKEN}&lang=en")
            page.wait_for_function("document.querySelector('#f-reducer').options.length > 0")
            # the picker: every method on this bench, each showing its own fields
            page.wait_for_function("[...document.querySelectorAll('#f-method option')].every((o) => !o.disabled)")
            assert page.is_visible("#f-torque") and not page.is_visible("#f-revolutions")
            page.select_option("#f-method", "transmission-error")
            assert not page.is_visible("#f-torque") and not page.is_visible("#f-cycles")
            assert page.is_visible("#f-revolutions") and page.is_visible("#f-input-speed")
            page.select_option("#f-method", "no-load-torque")
            assert page.is_visible("#f-speeds") and not page.is_visible("#f-revolutions")
            page.select_option("#f-method", "transmission-error")
            page.fill("#f-serial", "SN-TE-0001")
            page.click("#start")

            # live: the TE of both directions against the output angle, and the spectrum of what has arrived
            page.wait_for_function("window.tcms.state.testState === 'running'", timeout=20_000)
            page.wait_for_function("(TcmsMethodView.state.live || {forward: {x: []}}).forward.x.length > 100",
                                   timeout=30_000)
            page.wait_for_function(f"({COUNT_CURVE_PIXELS})('plot-method-a') > 200", timeout=10_000)
            page.wait_for_function("document.querySelector('#mv-title-b').textContent.includes('live: forward')",
                                   timeout=20_000)
            assert "live, not yet evaluated" in page.text_content("#mv-state")
            # the reverse pass a third of the way through (its curve visible beside the forward one)
            page.wait_for_function("(x => x.length > 100 && x.reduce((a, v) => Math.max(a, v), -Infinity)"
                                   " - x.reduce((a, v) => Math.min(a, v), Infinity) > 120)"
                                   "(TcmsMethodView.state.live.reverse.x)", timeout=30_000)
            _shot(page, tmp_path, "screenshot-te-live.png")

            page.wait_for_function(
                "['completed','failed','aborted'].includes(document.querySelector('#test-state').textContent)",
                timeout=60_000)
            assert page.text_content("#test-state") == "completed"
            run_id = page.text_content("#test-id")
            res = srv.client().get(f"/api/tests/{run_id}").json()["results"]
            page.wait_for_selector("#te-lines:not([hidden]) tbody tr")
            # the evaluated lines as the API states them: order, component, amplitude ± U (k)
            rows = page.eval_on_selector_all("#te-lines tbody tr",
                                             "rows => rows.map((r) => [...r.cells].map((c) => c.textContent))")
            assert len(rows) == len(res["te_orders"])
            for row, line in zip(rows, res["te_orders"], strict=True):
                entry = res["uncertainty"][f"te_order_{line['order']:.4g}_amplitude_arcsec"]
                v, u = round_to_uncertainty(line["amplitude_arcsec"], entry["U"])
                assert row[0] == f"{line['order']:g}" and row[2] == f"{v} ± {u} (k = {entry['k']:.2f})", row
            named = {row[0]: row[1] for row in rows}
            assert named["39"] == "pin ring" and named["40"] == "crankshaft / cycloid disc" and named["161"] == "input shaft"
            shown = page.text_content("#results")
            entry = res["uncertainty"]["transmission_error_arcsec"]
            v, u = round_to_uncertainty(res["transmission_error_arcsec"], entry["U"])
            assert f"Transmission error (peak-to-peak, the larger direction) / ″{v} ± {u} (k = 1.96)" in shown
            # not a flat or empty plot: the curve spans the unit's TE, the spectrum carries each line's label
            span = page.evaluate("(() => { const s = TcmsMethodView.state.plots[0].scales.y; return s.max - s.min; })()")
            assert span > 15.0, span
            page.wait_for_function(f"({COUNT_CURVE_PIXELS})('plot-method-a') > 200")  # under the lines' dashes
            assert page.evaluate(f"({COUNT_CURVE_PIXELS})('plot-method-b')") > 50
            assert page.evaluate("TcmsMethodView.state.plots[1].marks.labels.length") == len(rows)
            assert page.is_hidden("#loop-view") and page.is_disabled("#discrepancy")
            assert errors == []
            _shot(page, tmp_path, "screenshot-te.png")

            # the plan editor keeps the method: saved, picked, the form shows it fixed
            page.fill("#p-name", "TE incoming")
            page.click("#save-plan")
            page.wait_for_function("document.querySelector('#f-plan').value !== ''")
            saved = srv.client().get("/api/plans").json()[0]
            assert saved["request"]["method"] == "transmission-error"
            assert page.input_value("#f-method") == "transmission-error" and page.is_disabled("#f-method")
            assert page.is_visible("#f-revolutions") and not page.is_visible("#f-torque")

            # in Chinese: the stored run's view in the catalogue's words
            page.goto(f"{srv.base}/?token={TOKEN}&lang=zh")
            page.wait_for_selector("#te-lines:not([hidden]) tbody tr")
            lines = page.text_content("#te-lines")
            assert "针齿壳" in lines and "曲柄轴 / 摆线轮" in lines and "阶次" in lines
            assert "传动误差（峰峰值，取较大方向）" in page.text_content("#results")
            assert page.text_content("#mv-title") == "传动误差" and errors == []
        finally:
            browser.close()
