"""Users, tokens, sessions, the append-only audit trail and saved plans behave alike on SQLite and PostgreSQL."""

from __future__ import annotations

from pathlib import Path

import pytest

from tcms_daq.store import StoreError, open_store
from tcms_daq.store.people import AuditQuery


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request, tmp_path: Path):
    url = request.getfixturevalue("postgres_url") if request.param == "postgresql" else None
    opened = open_store(url, tmp_path, bench_id="bench-a", bench_name="Bench A")
    yield opened
    opened.close()


def test_people_records_on_both_backends(store):
    store.add_user("olga", "operator", "hash-1")
    with pytest.raises(StoreError, match="exists"):
        store.add_user("olga", "engineer", "hash-2")
    with pytest.raises(StoreError, match="user name"):
        store.add_user("no spaces", "operator", "h")
    store.add_api_token("olga", "secret-token", "script")
    assert store.user_of_token("secret-token").role == "operator"
    assert store.user_of_token("other") is None
    store.add_session("olga", "session-id")
    assert store.user_of_session("session-id").name == "olga"
    store.set_user_disabled("olga", True)
    assert store.user_of_token("secret-token") is None and store.user_of_session("session-id") is None
    assert store.users()[0].disabled

    for i in range(3):
        store.append_audit("olga", "compensation.upload", target="compensation", before=f"v{i}", after=f"v{i + 1}")
    store.append_audit("erik", "test.start", target="run-1")
    assert store.count_audit() == 4
    assert [e.after for e in store.audit(AuditQuery(action="compensation"), limit=2)] == ["v3", "v2"]
    assert store.audit(AuditQuery(user="erik"))[0].bench_id == "bench-a"
    assert store.count_audit(AuditQuery(action="compensation_")) == 0  # LIKE wildcards are literal
    with pytest.raises(Exception, match="append-only"):
        store._people_execute("UPDATE audit SET user_name = 'x'")
    with pytest.raises(Exception, match="append-only"):
        store._people_execute("DELETE FROM audit")
    assert store.count_audit() == 4

    first = store.add_plan("incoming", {"reducer": "RV-110E", "max_torque_nm": 500}, "erik", "first")
    second = store.add_plan("incoming", {"reducer": "RV-110E", "max_torque_nm": 400}, "erik", "lower")
    store.add_plan("other", {"reducer": "RV-110E", "max_torque_nm": 100}, "erik")
    assert (first.version, second.version) == (1, 2)
    assert store.plan(first.id).request["max_torque_nm"] == 500
    assert [(p.name, p.version) for p in store.plans()] == [("incoming", 2), ("other", 1)]
    assert len(store.plans(all_versions=True)) == 3
    assert store.plan_by_name("incoming", 1).id == first.id and store.plan(10_000) is None


def test_bench_settings_one_row_per_bench(store, tmp_path):
    assert store.bench_settings() == {}
    store.put_bench_settings({"lockout_s": 60, "default_language": "zh"}, "ada")
    store.put_bench_settings({"lockout_s": 120, "default_language": None}, "ada")
    assert store.bench_settings() == {"lockout_s": 120, "default_language": None}
