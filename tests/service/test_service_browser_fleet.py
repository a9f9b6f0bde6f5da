"""The fleet page in headless Chromium: search by serial number, per-run links, the overlay of two runs' loops,
the SPC chart and the bench bias table. Set TCMS_UPDATE_SCREENSHOT=1 to write docs/screenshot-fleet.png."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from svc_helpers import TOKEN, ScriptedRunner, results_with_uncertainty, serve

from tcms_daq.store import open_store

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
REPO = Path(__file__).resolve().parents[2]
CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason="needs Debian's chromium at /usr/bin/chromium"),
]

# pixels of a colour on a canvas (r, g, b within 40 of the target)
COUNT_PIXELS = """([selector, r, g, b]) => {
  const canvas = document.querySelector(selector);
  const d = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (d[i + 3] > 0 && Math.abs(d[i] - r) < 40 && Math.abs(d[i + 1] - g) < 40 && Math.abs(d[i + 2] - b) < 40) n++;
  }
  return n;
}"""


def _seed(data_dir: Path) -> None:
    """Two benches; reference units REF-0…2 tested twice on each (line-b reads 2 N·m/arcmin stiffer)."""
    rng = np.random.default_rng(2)
    t = np.linspace(0.0, 20.0, 2000)
    n = 0
    for bench, bias in (("line-a", 0.0), ("line-b", 2.0)):
        with open_store(None, data_dir, bench_id=bench, bench_name=f"Bench {bench}", recover=False) as store:
            for unit in range(3):
                for _ in range(2):
                    n += 1
                    rigidity = 290.0 + 3 * unit + bias + rng.normal(0, 0.3)
                    torque = 300.0 * np.sin(2 * np.pi * t / 10.0)
                    angle = torque / rigidity * 60.0 + (10.0 + 2 * unit) * np.sign(np.cos(2 * np.pi * t / 10.0))
                    run_id = f"run-{n:02d}"
                    store.create_run(run_id, {"reducer": "RV-110E", "serial_number": f"REF-{unit}",
                                              "operator": "Ada", "max_torque_nm": 300.0}, CHANNELS)
                    store.append_samples(run_id, [{"time_s": t, "torque_nm": torque, "angle_arcsec": angle,
                                                   "encoder_arcsec": angle}])
                    results = results_with_uncertainty() if n == 1 else {"verdict": {"passed": n % 5 != 0}}
                    store.set_status(run_id, "completed", results={**results, "rigidity_nm_per_arcmin": rigidity})


@pytest.mark.timeout(150)
def test_fleet_page_searches_links_overlays_and_charts(settings_factory, tmp_path):
    from playwright.sync_api import sync_playwright

    settings = settings_factory()
    _seed(settings.data_dir)
    with serve(settings, runner=ScriptedRunner()) as srv, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1500, "height": 1100})
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            console: list[str] = []
            page.on("console", lambda msg: console.append(f"{msg.type}: {msg.text}"))
            page.goto(f"{srv.base}/fleet?token={TOKEN}")
            page.wait_for_function("document.querySelectorAll('#runs tbody tr[data-id]').length === 12")
            assert page.inner_text("#total") == "12"
            first = page.inner_text("#runs tbody tr[data-id='run-01']")
            assert "± 2.3 N·m/arcmin (k = 2.05)" in first and "41.27 ± 0.82″ (k = 2.00)" in first
            assert "U not stated" in page.inner_text("#runs tbody tr[data-id='run-02']")
            hrefs = page.eval_on_selector_all("#runs tbody tr[data-id='run-02'] td.files a", "els => els.map(e => e.href)")
            assert any("/api/tests/run-02/certificate.pdf?" in h and f"token={TOKEN}" in h and "lang=en" in h
                       for h in hrefs)
            assert any("format=mdf4" in h for h in hrefs) and any("/metadata" in h for h in hrefs)

            page.fill("#f-serial", "REF-1")
            page.click("#filters button[type=submit]")
            page.wait_for_function("document.querySelector('#total').textContent === '4'")
            ids = page.eval_on_selector_all("#runs tbody tr[data-id]", "els => els.map(e => e.dataset.id)")
            assert ids == ["run-10", "run-09", "run-04", "run-03"]

            page.check("#runs tbody tr[data-id='run-03'] .pick")
            page.check("#runs tbody tr[data-id='run-10'] .pick")
            page.wait_for_function("document.querySelector('#plot-overlay canvas') !== null")
            blue, orange = "['#plot-overlay canvas', 31, 95, 168]", "['#plot-overlay canvas', 217, 119, 30]"
            try:
                # run-10 (orange, line-b, 2 N·m/arcmin stiffer) is drawn over run-03 (blue) and hides most of it:
                # hiding run-10 in the legend shows run-03's whole loop
                page.wait_for_function(f"({COUNT_PIXELS})({orange}) > 200", timeout=120_000)
                page.click("#plot-overlay .u-legend >> text=run-10")
                page.wait_for_function(f"({COUNT_PIXELS})({blue}) > 200 && ({COUNT_PIXELS})({orange}) < 20")
            except Exception as exc:  # say what the page shows instead of a bare timeout
                state = page.evaluate(f"""() => ({{
                    ids: document.querySelector('#overlay-ids').textContent,
                    message: document.querySelector('#message').textContent,
                    canvases: document.querySelectorAll('#plot-overlay canvas').length,
                    blue: ({COUNT_PIXELS})(['#plot-overlay canvas', 31, 95, 168]),
                    orange: ({COUNT_PIXELS})(['#plot-overlay canvas', 217, 119, 30]),
                    legend: document.querySelector('#plot-overlay').innerText }})""")
                raise AssertionError(f"overlay not drawn: {state}, console {console}, page errors {errors}") from exc
            assert page.inner_text("#overlay-ids") == "run-03 vs run-10"

            page.fill("#s-reducer", "RV-110E")
            page.fill("#s-baseline", "6")
            page.fill("#s-reference", "line-a")
            page.click("#spc-form button[type=submit]")
            page.wait_for_function("document.querySelector('#bias tbody').innerText.includes('line-b')")
            summary = page.inner_text("#spc-summary")
            assert summary.startswith("12 runs of RV-110E, single position (fleet); baseline of 6 runs: limits "
                                      "provisional until 20 runs"), summary
            assert page.inner_text("#s-method") == "single position (12 runs)"
            bias_rows = page.inner_text("#bias tbody")
            assert "line-a (reference)" in bias_rows and "0.000 N·m/arcmin" in bias_rows
            line_b = [row for row in bias_rows.splitlines() if row.startswith("line-b")][0]
            assert abs(float(line_b.split()[1]) - 2.0) < 1.0
            assert page.eval_on_selector("#plot-spc canvas", "c => c.width") > 300
            if os.environ.get("TCMS_UPDATE_SCREENSHOT"):
                page.screenshot(path=str(REPO / "docs" / "screenshot-fleet.png"), full_page=True)
            assert errors == []
        finally:
            browser.close()
