"""A discrepancy for any stored run, from the dashboard and from the fleet page, in headless Chromium: the run was
made over the API before the page was opened (not in this page session); each page starts the analysis from the
run's row and shows it in words and in the analyses' history."""

from __future__ import annotations

import contextlib
import os

import pytest
from svc_helpers import TOKEN, serve, wait_for
from test_service_browser import ARGS, CHROMIUM

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 400, "cycles": 1, "profile": "continuous", "rate_nm_per_s": 250}

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason="needs Debian's chromium at /usr/bin/chromium"),
]


@contextlib.contextmanager
def _service_with_a_stored_run(settings_factory, sim_config):
    """(server, API client, headless Chromium, run id): the service on the simulated bench with one test made
    over the API before any page is opened."""
    from playwright.sync_api import sync_playwright

    settings = settings_factory(config_path=sim_config, sim_speed=20.0)
    with serve(settings) as srv, srv.client() as c, sync_playwright() as pw:
        run_id = c.post("/api/tests", json=REQUEST).json()["id"]
        wait_for(lambda: c.get(f"/api/tests/{run_id}").json()["status"] == "completed", timeout_s=90)
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            yield srv, c, browser, run_id
        finally:
            browser.close()


def _page(browser, errors: list[str]):
    """A new 1500 × 900 page whose script errors land in ``errors``."""
    page = browser.new_page(viewport={"width": 1500, "height": 900})
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    return page


@pytest.mark.timeout(180)
def test_dashboard_and_fleet_page_analyse_a_stored_run(settings_factory, sim_config):
    with _service_with_a_stored_run(settings_factory, sim_config) as (srv, c, browser, run_id):
        errors: list[str] = []
        page = _page(browser, errors)
        page.goto(f"{srv.base}/?token={TOKEN}")
        page.wait_for_selector(f"#history button.find-effects[data-run='{run_id}']", timeout=20_000)
        assert page.is_hidden("#discrepancy-history")  # no analyses yet: no empty table
        page.click(f"#history button.find-effects[data-run='{run_id}']")
        page.wait_for_selector("#discrepancy-link:not([hidden])", timeout=90_000)
        said = page.text_content("#discrepancy-result")
        assert said.startswith("consistent: Measurement and simulation agree"), said
        assert "(against bench model v0)" in said
        page.wait_for_selector(f"#discrepancy-history tr:has-text('{run_id}')", timeout=20_000)
        assert "consistent" in page.text_content("#discrepancy-history")

        fleet = _page(browser, errors)
        fleet.goto(f"{srv.base}/fleet?token={TOKEN}")
        button = f"#runs button.find-effects[data-run='{run_id}']"
        fleet.wait_for_selector(button, timeout=20_000)
        fleet.wait_for_selector(f"#discrepancy-history tr:has-text('{run_id}')", timeout=20_000)  # the history
        fleet.click(button)
        fleet.wait_for_function(
            "document.querySelector('#discrepancy-result').textContent.includes('against bench model v0')",
            timeout=90_000)
        assert fleet.text_content("#discrepancy-result").startswith(f"run {run_id}: consistent")
        fleet.wait_for_function("document.querySelectorAll('#discrepancy-history tbody tr').length === 2",
                                timeout=20_000)

        # in Chinese: the verdict, its sentence (the core's coded notice) and the labels from the catalogue
        zh = _page(browser, errors)
        zh.goto(f"{srv.base}/fleet?token={TOKEN}&lang=zh")
        zh.wait_for_selector(button, timeout=20_000)
        zh.click(button)
        zh.wait_for_function(
            "document.querySelector('#discrepancy-result').textContent.includes('对照试验台模型 v0')", timeout=90_000)
        said = zh.text_content("#discrepancy-result")
        assert said.startswith(f"试验 {run_id}：一致：测量与仿真在噪声范围内一致"), said
        assert "识别出：无" in said and "留出数据 RMS" in said, said
        zh.wait_for_function("document.querySelectorAll('#discrepancy-history tbody tr').length === 3",
                             timeout=20_000)
        assert "一致" in zh.text_content("#discrepancy-history")
        assert errors == []


@pytest.mark.timeout(180)
def test_a_suggested_run_starts_from_its_button(settings_factory, sim_config):
    """Where an analysis cannot tell two effects apart, its suggested run is a button that starts exactly that
    request. The analysis is the service's own, with an alias group and the suggestion the store makes for it
    (``separating_request``) added on its way to the page: the default bench hides no such pair."""
    from tcms_daq.discrepancy import effects as fx
    from tcms_daq.discrepancy.stored import separating_request
    from tcms_daq.discrepancy.workflow import NamedEffect

    names = [fx.TIME_SKEW, fx.BACKLASH]
    named = NamedEffect("thermal_drift", {"rate_arcsec_per_s": 0.030123}, 0.75, 0.21, 1.0,
                        standard_uncertainty={"rate_arcsec_per_s": 0.000217}, degrees_of_freedom=7)
    suggested = separating_request(fx.SECOND_RATE, REQUEST, reducer=REQUEST["reducer"],
                                   max_torque_nm=REQUEST["max_torque_nm"], rate_nm_per_s=REQUEST["rate_nm_per_s"],
                                   max_rate_nm_per_s=2000.0)
    assert suggested is not None and suggested["rates"][0] == REQUEST["rate_nm_per_s"]

    def with_alias(route):
        if route.request.method != "POST":
            route.continue_()
            return
        response = route.fetch()
        doc = response.json()
        doc["aliases"] = [{"names": names, "in_model": False, "separating_experiment": "a second loading rate"}]
        doc["suggested_runs"] = [{"names": names, "kind": fx.SECOND_RATE, "why": "a skew grows with the rate",
                                  "request": suggested}]
        doc["effects"] = [named.to_dict()]  # a named effect with its U, as the workflow writes it
        route.fulfill(response=response, json=doc)

    with _service_with_a_stored_run(settings_factory, sim_config) as (srv, c, browser, run_id):
        errors: list[str] = []
        page = _page(browser, errors)
        page.route("**/api/discrepancy", with_alias)
        page.goto(f"{srv.base}/?token={TOKEN}")
        page.click(f"#history button.find-effects[data-run='{run_id}']", timeout=20_000)
        button = page.wait_for_selector("button.start-suggested[data-kind='second_rate']", timeout=90_000)
        rates = " / ".join(f"{r:g}" for r in suggested["rates"])
        assert button.text_content() == \
            f"Start the run that separates time_skew / backlash: the same test at {rates} N·m/s"
        said = page.text_content("#discrepancy-result")
        assert "cannot be told apart: time_skew / backlash" in said
        # a named parameter with its expanded uncertainty (Student's k for 7 degrees of freedom: 2.36)
        assert "thermal_drift (rate_arcsec_per_s = 0.03012 ± 0.00051 (k = 2.36))" in said, said
        button.click()
        started = page.wait_for_selector(".suggested-started", timeout=20_000)
        new_id = started.get_attribute("data-run")
        assert new_id and new_id != run_id and button.is_disabled()
        run = c.get(f"/api/tests/{new_id}").json()
        assert run["request"]["rates"] == suggested["rates"], run["request"]
        assert run["request"]["max_torque_nm"] == REQUEST["max_torque_nm"]
        c.post(f"/api/tests/{new_id}/abort")
        wait_for(lambda: c.get(f"/api/tests/{new_id}").json()["status"] not in ("queued", "running"),
                 timeout_s=60)
        assert errors == []
