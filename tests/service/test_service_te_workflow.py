"""The discrepancy workflow on the transmission error over the service (issue 28): the simulated station in-process
(config/bench-station.toml at 400 × real time) with a hidden order its unit's TE model lacks ([sim.transmission]
extra). Run 1 → ``POST /api/te-discrepancy`` names the order (within 1 %), its amplitude (within 10 %) and its
component → ``POST /api/te-discrepancy/{id}/apply`` makes it the model's next version (``GET /api/te-model``) → run 2
is ``consistent``. An order that belongs to no component is ``unexplained`` with its order, never named, and
nothing is applied; a stiffness run is not a TE run (422)."""

from __future__ import annotations

import pytest
from svc_helpers import serve, wait_for

from tcms_daq.config.loader import resolve_config_path
from tcms_daq.service.runner import BenchRunner

STATION = resolve_config_path("bench-station.toml")


def _run(client, request: dict) -> dict:
    r = client.post("/api/tests", json=request)
    assert r.status_code == 202, r.text
    run_id = r.json()["id"]
    run = wait_for(lambda: (x := client.get(f"/api/tests/{run_id}").json())["status"]
                   in ("completed", "failed", "aborted") and x, timeout_s=120)
    assert run["status"] == "completed", run["error"]
    return run


@pytest.mark.parametrize(("reducer", "hidden", "component"), [
    ("RV-110E", {"order": 78.0, "amplitude_arcsec": 1.5, "phase_deg": 30.0}, "pin_ring 2×"),
    ("HFUC-32-100", {"order": 27.3, "amplitude_arcsec": 1.5, "phase_deg": 200.0}, None),
], ids=["named-and-closed", "unexplained"])
def test_hidden_order_named_applied_and_closed(settings_factory, reducer, hidden, component):
    extra = ("[{" + ", ".join(f"{k} = {hidden[k]:g}" for k in ("order", "amplitude_arcsec", "phase_deg"))
             + "}]")
    runner = BenchRunner.from_config(STATION, sim_speed=400.0,
                                     overrides=[f"sim.transmission.extra={extra}", f'sim.reducer="{reducer}"'])
    with serve(settings_factory(config_path=STATION, sim_speed=400.0), runner) as server, server.client() as c:
        first = _run(c, {"reducer": reducer, "method": "transmission-error"})
        assert c.get("/api/te-model", params={"reducer": reducer}).json()["version"] == 0
        r = c.post("/api/te-discrepancy", json={"run_id": first["id"]})
        assert r.status_code == 201, r.text
        analysis = r.json()
        gaps = [f for f in analysis["findings"] if f["significant"]]
        assert len(gaps) == 1, analysis["verdict_words"]
        found = gaps[0]
        assert found["order"] == pytest.approx(hidden["order"], rel=0.01)
        assert found["amplitude_arcsec"] == pytest.approx(hidden["amplitude_arcsec"], rel=0.10)
        applied = c.post(f"/api/te-discrepancy/{analysis['id']}/apply")
        if component is None:  # an order of no component: reported by its order alone, nothing to apply
            assert analysis["verdict"] == "unexplained" and found["component"] is None and not found["components"]
            assert analysis["unexplained_orders"] == [pytest.approx(hidden["order"], rel=0.01)]
            assert applied.status_code == 422, applied.text
            return
        assert analysis["verdict"] == "explained" and found["component"] == component, analysis["verdict_words"]
        assert applied.status_code == 200, applied.text
        model = c.get("/api/te-model", params={"reducer": reducer}).json()
        assert model["version"] == 1 and model["history"][0]["run_id"] == first["id"]
        assert any(h["order"] == pytest.approx(hidden["order"], rel=0.01) for h in model["harmonics"])
        again = c.post(f"/api/te-discrepancy/{analysis['id']}/apply")
        assert again.status_code == 409, again.text  # made against version 0
        second = _run(c, {"reducer": reducer, "method": "transmission-error"})
        closed = c.post("/api/te-discrepancy", json={"run_id": second["id"]}).json()
        assert closed["verdict"] == "consistent" and closed["against_version"] == 1, closed["verdict_words"]
        stiffness = _run(c, {"reducer": reducer, "max_torque_nm": 100, "cycles": 1})
        assert c.post("/api/te-discrepancy", json={"run_id": stiffness["id"]}).status_code == 422
