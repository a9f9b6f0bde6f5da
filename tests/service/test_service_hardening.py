"""Every bad input a user or a script can send is a 4xx with a one-line reason: never a 500, never a hang
(issue 10). The real bench runner on the in-process simulated bench."""

from __future__ import annotations

import httpx
import pytest
from svc_helpers import TOKEN, serve

GOOD = {"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 1, "rate_nm_per_s": 250}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    from tcms_daq.config.loader import default_bench_config_path
    from tcms_daq.service.app import ServiceSettings

    settings = ServiceSettings(data_dir=tmp_path_factory.mktemp("data"), api_token=TOKEN,
                               config_path=default_bench_config_path(), sim_speed=1000.0,
                               max_body_bytes=64 * 1024)
    with serve(settings) as srv:
        yield srv


def _post_raw(srv, path: str, body: bytes, token: str = TOKEN, content_type: str = "application/json"):
    headers = {"Content-Type": content_type}
    if token is not None:
        headers["Authorization"] = f"Bearer {token}"
    return httpx.post(srv.base + path, content=body, headers=headers, timeout=20)


def _one_line(response: httpx.Response) -> str:
    detail = response.json()["detail"]
    assert isinstance(detail, str) and detail and "\n" not in detail, detail
    return detail


@pytest.mark.parametrize("literal", ["NaN", "-Infinity", "Infinity", "1e400", "-1e400"])
@pytest.mark.parametrize("field", ["max_torque_nm", "rate_nm_per_s"])
def test_non_finite_numbers_in_the_json_are_422(server, field, literal):
    body = ('{"reducer": "RV-110E", "max_torque_nm": 500, "cycles": 1, "rate_nm_per_s": 250}'
            .replace(f'"{field}": {GOOD[field]}', f'"{field}": {literal}'))
    r = _post_raw(server, "/api/tests", body.encode())
    assert r.status_code == 422, r.text
    assert field in _one_line(r)


@pytest.mark.parametrize("changes, part", [
    ({"rate_nm_per_s": 0.001}, "below the bench's slowest rate"),
    ({"rate_nm_per_s": 1e-300}, "below the bench's slowest rate"),
    ({"rate_nm_per_s": 99_000}, "exceeds the bench's fastest rate"),
    ({"profile": "stepped", "step_nm": 1e-9}, "below the bench's smallest step"),
    ({"max_torque_nm": 5000}, "exceeds the bench limit"),
])
def test_requests_outside_the_bench_bounds_are_422_before_anything_runs(server, changes, part):
    with server.client() as c:
        r = c.post("/api/tests", json={**GOOD, **changes})
        assert r.status_code == 422, r.text
        assert part in _one_line(r)
        assert c.get("/api/tests").json() == [] or all(t["status"] != "running" for t in c.get("/api/tests").json())


@pytest.mark.parametrize("header", ["Bearer tökén", "Bearer \u2603\u2603", "Bearer " + "x" * 5000, "Basic abc",
                                    "Bearer"])
def test_odd_bearer_tokens_are_401(server, header):
    r = httpx.post(server.base + "/api/tests", json=GOOD, headers={"Authorization": header.encode("utf-8")},
                   timeout=20)
    assert r.status_code == 401, r.text


def test_bodies_above_the_limit_are_413(server):
    big = b'{"reducer": "' + b"x" * (80 * 1024) + b'"}'
    assert _post_raw(server, "/api/tests", big).status_code == 413
    r = httpx.put(server.base + "/api/compensation", content=b"# " + b"y" * (80 * 1024),
                  headers={"Authorization": f"Bearer {TOKEN}"}, timeout=20)
    assert r.status_code == 413


def test_malformed_json_and_wrong_types_are_422(server):
    for body in (b"{", b"[]", b"null", b'{"reducer": 5}', b'{"reducer": "RV-110E", "max_torque_nm": "lots"}',
                 b"\xff\xfe"):
        r = _post_raw(server, "/api/tests", body)
        assert r.status_code == 422, (body, r.text)


@pytest.mark.parametrize("toml, part", [
    ('[[terms]]\ntype = "scale"\ncoefficient = 0.5\n', "outside ±0.1"),
    ('[[terms]]\ntype = "offset"\nvalue_arcsec = 1e308\n', "exceeds ±3600"),
    ('[[terms]]\ntype = "offset"\nvalue_arcsec = inf\n', "finite"),
    ('[[terms]]\ntype = "scale"\ncoefficient = "abc"\n', "must be a number"),
    ('[[terms]]\ntype = "periodic"\nperiod_arcsec = 0.01\nsin_arcsec = 1.0\n', "outside 1″"),
    ("a = " + "[" * 5000 + "]" * 5000 + "\n", "compensation"),
    ("not toml at all ===", "compensation"),
])
def test_implausible_or_broken_compensation_uploads_are_422_and_change_nothing(server, toml, part):
    with server.client() as c:
        before = c.get("/api/compensation").text
        r = c.put("/api/compensation", content=toml.encode())
        assert r.status_code == 422, r.text
        assert part in _one_line(r)
        assert c.get("/api/compensation").text == before


def test_docs_work_offline(server):
    with server.client() as c:
        for page in ("/docs", "/redoc"):
            html = c.get(page).text
            assert "cdn." not in html and "https://" not in html.replace("https://fonts.googleapis.com", ""), page
            for asset in [part.split('"')[0] for part in html.split('src="')[1:]]:
                assert c.get(asset).status_code == 200, asset
