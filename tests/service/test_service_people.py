"""Users with roles, their tokens and sessions, the audit trail and saved plans over real HTTP (issue 26 items
1–3): an operator starts a test from a plan and may not upload a compensation; an engineer may; the audit trail
names both; the run names its user and its plan."""

from __future__ import annotations

import subprocess
import sys

import httpx
import pytest
from svc_helpers import ScriptedRunner, serve, wait_for

from tcms_daq.service.users import hash_password, new_api_token
from tcms_daq.store import StoreError, open_store

REQUEST = {"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 2, "profile": "continuous", "rate_nm_per_s": 2000}
COMPENSATION = "[compensator]\ndescription = 'engineer upload'\n"


def _people(data_dir) -> dict[str, str]:
    """Three users (one per role) with an API token each, written to the store the service will open."""
    tokens = {}
    with open_store(None, data_dir) as store:
        for name, role in (("olga", "operator"), ("erik", "engineer"), ("ada", "admin")):
            store.add_user(name, role, hash_password(f"{name}-password"))
            tokens[role] = new_api_token(store, name, "test")
    return tokens


def _client(srv, token: str | None) -> httpx.Client:
    return srv.client(token)


def test_roles_plans_and_the_audit_trail(settings_factory, tmp_path):
    settings = settings_factory()
    tokens = _people(settings.data_dir)
    with serve(settings, runner=ScriptedRunner()) as srv, srv.client() as service, \
            _client(srv, tokens["operator"]) as operator, _client(srv, tokens["engineer"]) as engineer, \
            _client(srv, tokens["admin"]) as admin:
        assert operator.get("/api/me").json()["role"] == "operator"
        # an operator may not save a plan, start a free test or upload a compensation: 403 naming the role
        r = operator.post("/api/plans", json={"name": "incoming RV-110E", "request": REQUEST})
        assert r.status_code == 403 and "engineer" in r.json()["detail"], r.text
        r = operator.post("/api/tests", json=REQUEST)
        assert r.status_code == 403 and "engineer" in r.json()["detail"]
        r = operator.put("/api/compensation", content=COMPENSATION)
        assert r.status_code == 403 and "needs the role engineer" in r.json()["detail"]
        assert operator.get("/api/users").status_code == 403
        # an engineer saves a plan (serial numbers are the unit's, not the plan's) and uploads a compensation
        r = engineer.post("/api/plans", json={"name": "incoming RV-110E", "note": "first",
                                              "request": {**REQUEST, "serial_number": "not kept"}})
        assert r.status_code == 201, r.text
        plan = r.json()
        assert plan["version"] == 1 and "serial_number" not in plan["request"] and plan["created_by"] == "erik"
        r = engineer.post("/api/plans", json={"name": "incoming RV-110E", "note": "three loops",
                                              "request": {**REQUEST, "cycles": 3}})
        v2 = r.json()
        assert v2["version"] == 2 and v2["id"] != plan["id"]
        assert [p["version"] for p in operator.get("/api/plans").json()] == [2]
        assert len(operator.get("/api/plans", params={"all_versions": True}).json()) == 2
        # a plan the bench cannot run is refused when saved
        r = engineer.post("/api/plans", json={"name": "too much", "request": {**REQUEST, "max_torque_nm": 5000}})
        assert r.status_code == 422 and "max_torque_nm" in r.json()["detail"]
        r = engineer.put("/api/compensation", content=COMPENSATION, params={"note": "engineer's"})
        assert r.status_code == 200, r.text
        version = r.headers["X-Compensation-Version"]
        # the operator starts version 2 of the plan for one unit
        r = operator.post("/api/tests/from-plan", json={"plan_id": v2["id"], "serial_number": "SN-0042"})
        assert r.status_code == 202, r.text
        run_id = r.json()["id"]
        assert operator.post("/api/tests/from-plan", json={"plan_id": 999}).status_code in (404, 409)
        wait_for(lambda: service.get(f"/api/tests/{run_id}").json()["status"] == "completed")
        run = service.get(f"/api/tests/{run_id}").json()
        assert run["user"] == "olga" and run["request"]["serial_number"] == "SN-0042"
        assert run["plan"] == {"id": v2["id"], "name": "incoming RV-110E", "version": 2}
        assert run["request"]["cycles"] == 3
        identity = service.get(f"/api/tests/{run_id}/metadata").json()
        text = str(identity)
        assert "olga" in text and "incoming RV-110E" in text
        # an unknown plan is 404 when the bench is idle
        r = operator.post("/api/tests/from-plan", json={"plan_id": 999})
        assert r.status_code == 404 and "999" in r.json()["detail"]

        # the audit trail: both actions with the users' names, before/after versions
        entries = operator.get("/api/audit").json()
        by_action = {e["action"]: e for e in reversed(entries)}  # the newest of each action
        assert by_action["test.start"]["user"] == "olga" and by_action["test.start"]["target"] == run_id
        assert "incoming RV-110E v2" in by_action["test.start"]["after"]
        upload = by_action["compensation.upload"]
        assert upload["user"] == "erik" and upload["role"] == "engineer"
        assert upload["after"].startswith(f"v{version} ") and upload["before"].startswith("v")
        assert by_action["plan.save"]["before"].startswith("v1") and by_action["plan.save"]["after"].startswith("v2")
        page = operator.get("/api/audit", params={"action": "compensation", "limit": 1})
        assert page.headers["X-Total-Count"] == "1" and page.json()[0]["action"] == "compensation.upload"
        assert operator.get("/api/audit", params={"user": "olga"}).json()[0]["user"] == "olga"
        # nothing can change or remove an entry through the API
        for method in ("PUT", "PATCH", "DELETE"):
            assert admin.request(method, "/api/audit").status_code == 405
            assert admin.request(method, f"/api/audit/{entries[0]['id']}").status_code in (404, 405)

        # admin: users, a token, disabling; the automation token may not administer users
        assert service.get("/api/users").status_code == 403
        r = admin.post("/api/users", json={"name": "nina", "role": "operator", "password": "nina-password"})
        assert r.status_code == 201, r.text
        assert admin.post("/api/users", json={"name": "nina", "role": "operator",
                                              "password": "nina-password"}).status_code == 409
        nina_token = admin.post("/api/users/nina/tokens", json={"label": "script"}).json()["token"]
        with _client(srv, nina_token) as nina:
            assert nina.get("/api/me").json()["name"] == "nina"
            assert admin.post("/api/users/nina/disable").json()["disabled"] is True
            assert nina.get("/api/me").status_code == 401
        assert [e["action"] for e in admin.get("/api/audit", params={"target": "nina"}).json()] == [
            "user.disable", "user.token", "user.add"]


def test_sign_in_session_and_failed_sign_in_is_audited(settings_factory):
    settings = settings_factory()
    _people(settings.data_dir)
    with serve(settings, runner=ScriptedRunner()) as srv, srv.client(None) as browser, srv.client() as service:
        r = browser.post("/api/login", json={"name": "olga", "password": "wrong-password"})
        assert r.status_code == 401 and "wrong user name or password" in r.json()["detail"]
        assert browser.post("/api/login", json={"name": "nobody", "password": "x"}).status_code == 401
        r = browser.post("/api/login", json={"name": "erik", "password": "erik-password"})
        assert r.status_code == 200 and r.json()["role"] == "engineer"
        cookie = r.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie
        assert browser.get("/api/me").json()["name"] == "erik"
        # a signed-in change needs the header a page of another site cannot send
        r = browser.put("/api/compensation", content=COMPENSATION)
        assert r.status_code == 403 and "X-Requested-By" in r.json()["detail"]
        r = browser.put("/api/compensation", content=COMPENSATION, headers={"X-Requested-By": "tcms"})
        assert r.status_code == 200, r.text
        assert browser.post("/api/logout", headers={"X-Requested-By": "tcms"}).status_code == 204
        assert browser.get("/api/me").status_code == 401
        failed = service.get("/api/audit", params={"action": "user.login_failed"}).json()
        assert sorted(e["user"] for e in failed) == ["nobody", "olga"]


def test_the_audit_trail_refuses_changes_in_the_store(tmp_path):
    with open_store(None, tmp_path) as store:
        store.append_audit("someone", "test.start", target="run-1")
        with pytest.raises(Exception, match="append-only"):
            store._people_execute("UPDATE audit SET user_name = 'other'")
        with pytest.raises(Exception, match="append-only"):
            store._people_execute("DELETE FROM audit")
        assert store.audit()[0].user == "someone"
        with pytest.raises(StoreError, match="unknown role"):
            store.add_user("x", "superuser", "h")


def test_cli_users_add_list_token_disable(tmp_path):
    def tcms(*args: str, stdin: str = "") -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "tcms_daq.cli", "users", "--data-dir", str(tmp_path), *args],
                              input=stdin, capture_output=True, text=True, timeout=60)

    assert tcms("add", "olga", "--role", "operator", stdin="olga-password\n").returncode == 0
    short = tcms("add", "pete", "--role", "operator", stdin="short\n")
    assert short.returncode == 2 and "at least 8 characters" in short.stderr
    token = tcms("token", "olga", "--label", "line 3").stdout.strip()
    assert token.startswith("tcms_")
    assert tcms("disable", "olga").returncode == 0
    listed = tcms("list").stdout
    assert "olga" in listed and "operator" in listed and "disabled" in listed
    with open_store(None, tmp_path) as store:
        assert store.user_of_token(token) is None  # disabled
        assert [e.action for e in store.audit()] == ["user.disable", "user.token", "user.add"]
        assert store.audit()[0].user.startswith("cli:")


def test_admin_settings_validated_stored_audited_and_used(settings_factory):
    settings = settings_factory()
    tokens = _people(settings.data_dir)
    with serve(settings, runner=ScriptedRunner()) as srv, srv.client() as service, \
            _client(srv, tokens["admin"]) as admin, _client(srv, tokens["engineer"]) as engineer:
        defaults = admin.get("/api/settings").json()
        assert defaults["session_lifetime_h"] == 12.0 and defaults["default_language"] is None
        for who in (engineer, service):  # the automation token administers nothing either
            r = who.put("/api/settings", json={"lockout_s": 60})
            assert r.status_code == 403 and "admin" in r.json()["detail"]
        assert engineer.get("/api/settings").status_code == 403
        for bad, field in (({"session_lifetime_h": 0}, "session_lifetime_h"), ({"lockout_s": 5}, "lockout_s"),
                           ({"default_language": "fr"}, "default_language"), ({"colour": "red"}, "colour"),
                           ({"lockout_failures_per_user": None}, "lockout_failures_per_user"),
                           ({"bench_display_name": "a\nb"}, "bench_display_name")):
            r = admin.put("/api/settings", json=bad)
            assert r.status_code == 422 and field in r.json()["detail"], (bad, r.text)
        r = admin.put("/api/settings", json={"session_lifetime_h": 1.5, "default_language": "zh",
                                             "bench_display_name": "Line A · 刚度台"})
        assert r.status_code == 200 and r.json()["lockout_s"] == 300, r.text
        assert admin.get("/api/settings").json()["session_lifetime_h"] == 1.5
        assert admin.put("/api/settings", json={"default_language": "zh"}).status_code == 200  # no change: no entry
        entries = admin.get("/api/audit", params={"action": "settings"}).json()
        assert len(entries) == 1 and entries[0]["user"] == "ada"
        assert entries[0]["before"] == "session_lifetime_h=12.0 default_language=None bench_display_name=None"
        assert entries[0]["after"] == "session_lifetime_h=1.5 default_language=zh bench_display_name=Line A · 刚度台"
        # what the settings change: the session's lifetime, the pages' name and language, the report's language
        with srv.client(None) as browser:
            r = browser.post("/api/login", json={"name": "olga", "password": "olga-password"})
            assert "max-age=5400" in r.headers["set-cookie"].lower()
        assert service.get("/api/bench").json()["display_name"] == "Line A · 刚度台"
        assert 'window.TCMS_DEFAULT_LANG = "zh";' in httpx.get(srv.base + "/i18n/messages.js").text


def test_repeated_failed_sign_ins_get_429_with_retry_after_and_are_audited(settings_factory):
    settings = settings_factory()
    tokens = _people(settings.data_dir)
    with serve(settings, runner=ScriptedRunner()) as srv, _client(srv, tokens["admin"]) as admin, \
            srv.client(None) as browser:
        assert admin.put("/api/settings", json={"lockout_failures_per_user": 3, "lockout_failures_per_address": 5,
                                                "lockout_s": 600}).status_code == 200
        for _ in range(3):
            assert browser.post("/api/login", json={"name": "olga", "password": "wrong-pass"}).status_code == 401
        # locked: even the right password is refused until the window has passed
        r = browser.post("/api/login", json={"name": "olga", "password": "olga-password"})
        assert r.status_code == 429 and "olga" in r.json()["detail"]
        assert 590 <= int(r.headers["Retry-After"]) <= 600
        # another user from the same address is not locked yet; two more failures lock the address
        assert browser.post("/api/login", json={"name": "erik", "password": "erik-password"}).status_code == 200
        for _ in range(2):
            assert browser.post("/api/login", json={"name": "nobody", "password": "wrong-pass"}).status_code == 401
        r = browser.post("/api/login", json={"name": "ada", "password": "ada-password"})
        assert r.status_code == 429 and "127.0.0.1" in r.json()["detail"] and int(r.headers["Retry-After"]) > 0
        locked = admin.get("/api/audit", params={"action": "user.login_locked"}).json()
        assert [e["user"] for e in locked] == ["nobody", "olga"], locked
        assert "127.0.0.1" in locked[1]["detail"]


def test_the_sign_in_lock_ends_when_the_failures_leave_the_window():
    from tcms_daq.service.admin_settings import AdminSettings
    from tcms_daq.service.signin_limit import SignInLimiter

    policy = AdminSettings(lockout_failures_per_user=2, lockout_failures_per_address=100, lockout_s=60)
    limiter = SignInLimiter()
    limiter.failed("Olga", "10.0.0.1", 0.0)
    assert limiter.retry_after_s("olga", "10.0.0.2", 1.0, policy) is None
    limiter.failed("olga", "10.0.0.2", 30.0)  # the name is counted whatever its case and address
    assert limiter.retry_after_s("olga", "10.0.0.3", 30.0, policy) == 30  # until the first failure is 60 s old
    assert limiter.retry_after_s("olga", "10.0.0.3", 59.5, policy) == 1
    assert limiter.retry_after_s("olga", "10.0.0.3", 60.0, policy) is None
    limiter.failed("olga", "10.0.0.2", 61.0)
    assert limiter.retry_after_s("olga", "10.0.0.2", 61.0, policy) == 29
    limiter.succeeded("olga")
    assert limiter.retry_after_s("olga", "10.0.0.2", 61.0, policy) is None
