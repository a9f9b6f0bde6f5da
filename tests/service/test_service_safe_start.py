"""The safe start through the service (issue 22): what the bench's safe start found is an event and part of
``GET /api/bench``; while the bench is not safe a test request gets 409 with the reason."""

from __future__ import annotations

from svc_helpers import ScriptedRunner, serve, wait_for

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 100, "cycles": 1, "rate_nm_per_s": 400}
FOUND = {"found_state": "OPERATION ENABLED", "found_torque_nm": -800.0, "found_error_code": 0,
         "actions": ["target torque 0 (ramped)", "failed: link lost"], "safe": False, "safe_torque_nm": 20.0,
         "message": "safe start: drive found OPERATION ENABLED at -800.0 N·m: NOT safe (link lost)",
         "final_state": "OPERATION ENABLED", "final_torque_nm": -800.0}


class UnsafeAtStart(ScriptedRunner):
    """A scripted bench whose safe start left the drive unsafe until ``made_safe``."""

    made_safe = False

    def safe_start(self) -> dict:
        return {**FOUND, "safe": self.made_safe}

    def not_ready_reason(self) -> str | None:
        return None if self.made_safe else f"the bench is not safe yet: {FOUND['message']}"


def test_no_test_is_accepted_until_the_bench_is_safe(settings_factory):
    runner = UnsafeAtStart()
    with serve(settings_factory(), runner=runner) as srv, srv.client() as c:
        refused = c.post("/api/tests", json=REQUEST)
        assert refused.status_code == 409
        assert "not safe yet" in refused.json()["detail"] and "OPERATION ENABLED" in refused.json()["detail"]
        assert c.get("/api/tests").json() == []  # nothing stored for a refused request
        events = [e for e in srv.app.state.events.history if e["type"] == "bench_safe_start"]
        assert len(events) == 1 and events[0]["found_state"] == "OPERATION ENABLED" and not events[0]["safe"]
        runner.made_safe = True
        accepted = c.post("/api/tests", json=REQUEST)
        assert accepted.status_code == 202, accepted.text
        run_id = accepted.json()["id"]
        wait_for(lambda: c.get(f"/api/tests/{run_id}").json()["status"] == "completed", timeout_s=60)


def test_bench_status_carries_the_safe_start_and_each_readings_age(settings_factory, sim_config):
    """The real runner over the in-process simulated bench: the safe start's report, and per instrument the age of
    its last reading and its link state."""
    with serve(settings_factory(config_path=sim_config, sim_speed=10.0)) as srv, srv.client() as c:
        status = wait_for(lambda: (s := c.get("/api/bench").json())["instruments"]["loader"].get("status") and s)
        assert status["safe_start"]["safe"] and status["safe_start"]["found_state"] == "SWITCH ON DISABLED"
        assert status["not_ready"] is None
        for kind in ("angle", "torque", "loader"):
            view = status["instruments"][kind]
            assert view["link"] == "up" and 0 <= view["age_s"] < 5.0, (kind, view)
        assert status["instruments"]["loader"]["status"]["live"] is True
        assert 0 <= status["instruments"]["loader"]["status"]["age_s"] < 5.0


def test_the_runner_accepts_tests_once_a_fresh_status_shows_the_bench_safe():
    """BenchRunner: a bench its safe start left unsafe refuses tests with the reason, and the status poll's
    disable (``disable_pending``) making it safe is seen from the next fresh loader status."""
    from types import SimpleNamespace

    from tcms_daq.drivers.base import LoaderStatus

    from tcms_daq.acquisition.bench import SafeStart
    from tcms_daq.service.runner import BenchRunner

    report = SafeStart("OPERATION ENABLED", 650.0, 0, ["failed: link lost"], False,
                       "safe start: drive found OPERATION ENABLED at 650.0 N·m: NOT safe", 20.0)
    link = {"link": "down"}
    acq = SimpleNamespace(last_status=LoaderStatus("OPERATION ENABLED", 650.0, False),
                          channel_stats=lambda: {"loader": link})
    runner = BenchRunner(config=None, config_path=None, bench=SimpleNamespace(safe_start=report), reducers={})
    runner.acq = acq
    assert "not safe yet" in runner.not_ready_reason() and "650.0" in runner.not_ready_reason()
    acq.last_status = LoaderStatus("SWITCH ON DISABLED", 0.4, False)
    assert runner.not_ready_reason() is not None  # its link is down: an old reading proves nothing
    link["link"] = "up"
    assert runner.not_ready_reason() is None
    assert report.safe and "safe since (SWITCH ON DISABLED" in report.message
