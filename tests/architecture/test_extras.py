"""Lean runtime dependencies: the service runs a test without the optional extras, and each optional part used
without its extra says in one line which extra to install (tcms_daq/extras.py; pyproject.toml's extras)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tcms_daq.extras import EXTRAS

ROOT = Path(__file__).resolve().parents[2]

# Run in a child interpreter where the extras' modules cannot be imported (a None in sys.modules makes `import`
# raise ImportError and find_spec answer None), as after `pip install tcms-daq` without extras.
_WITHOUT_EXTRAS = r"""
import json, sys, time
from pathlib import Path
BLOCKED = json.loads(sys.argv[1])
for name in BLOCKED:
    sys.modules[name] = None
from fastapi.testclient import TestClient
from tcms_daq.extras import MissingExtra
from tcms_daq.service.app import ServiceSettings, create_app
from tcms_daq.store import open_store

out = {}
app = create_app(ServiceSettings(data_dir=Path(sys.argv[2]), api_token="t", sim_speed=100))
auth = {"Authorization": "Bearer t"}
with TestClient(app, base_url="http://127.0.0.1") as client:  # the loopback Host the service accepts
    out["health"] = client.get("/api/health").status_code
    run = client.post("/api/tests", headers=auth, json={"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1,
                                                         "rate_nm_per_s": 400}).json()
    deadline = time.monotonic() + 120
    while (status := client.get(f"/api/tests/{run['id']}").json()["status"]) in ("queued", "running"):
        assert time.monotonic() < deadline, "the test did not end within 120 s"
        time.sleep(0.1)
    out["status"] = status
    out["csv"] = client.get(f"/api/tests/{run['id']}/samples?format=csv").status_code
    mdf4 = client.get(f"/api/tests/{run['id']}/samples?format=mdf4")
    out["mdf4"] = [mdf4.status_code, mdf4.json()["detail"]]
try:
    open_store("postgresql://nobody@127.0.0.1:9/none", Path(sys.argv[2]))
except MissingExtra as exc:
    out["postgres"] = str(exc)
print(json.dumps(out))
"""


def _module(requirement: str) -> str:
    """The top-level module a requirement installs (``psycopg[binary]==3.3.9`` -> ``psycopg``)."""
    name = re.split(r"[\[<>=!~ ;]", requirement, maxsplit=1)[0]
    return name.replace("-", "_").lower()


def test_the_extras_table_is_pyprojects():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    optional = project["optional-dependencies"]
    for extra, modules in EXTRAS.items():
        assert sorted(_module(r) for r in optional[extra]) == sorted(modules), extra
    runtime = {_module(r) for r in project["dependencies"]}
    assert not runtime & {m for modules in EXTRAS.values() for m in modules}, "an extra is also a runtime dependency"
    assert f"tcms-daq[{','.join(EXTRAS)}]" in optional["test"], "the test tools install every extra"


@pytest.mark.slow
def test_the_service_runs_a_test_without_the_extras_and_names_them_when_used(tmp_path):
    blocked = sorted({m for modules in EXTRAS.values() for m in modules})
    proc = subprocess.run([sys.executable, "-c", _WITHOUT_EXTRAS, json.dumps(blocked), str(tmp_path / "data")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["health"] == 200 and out["status"] == "completed" and out["csv"] == 200
    assert out["mdf4"] == [501, "the MDF4 export needs the optional [exports] dependencies: "
                                "pip install 'tcms-daq[exports]'"]
    assert out["postgres"] == ("the PostgreSQL run store needs the optional [plant] dependencies: "
                               "pip install 'tcms-daq[plant]'")
