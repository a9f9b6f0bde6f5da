"""The closed loop over the service: ``tcms_daq.sim.trials.closed_loop`` with a ``ServiceRig``.

Each case gets its own service (``create_app`` under uvicorn on a free loopback port, its own data directory) on
a copy of the default simulated bench with the case's effects switched on in ``[sim.effects]``. A run is
``POST /api/tests`` (the trial design as a request: ±amplitude, its loops at each rate), then
``POST /api/discrepancy`` on the stored run against the bench model in use; the apply step is
``POST /api/discrepancy/{id}/apply`` (the analysis's model file, with its standard uncertainties, becomes the
bench model's next version) and run 2's analysis is against that version. Run 2 is new data: the same bench
goes on (its noise and its clock continue), with run 2's programme.

    python -m tcms_daq.service.closed_loop --closed-loop 0.5 --closed-loop 1 [--sim-speed 40] [--case NAME …]

takes the options of ``python -m tcms_daq.sim.trials --closed-loop`` and prints the same table. (It lives with the
service, a composition root, because it composes the app; the simulator's package does not import the service.)
"""

from __future__ import annotations

import secrets
import socket
import tempfile
import threading
import time
import tomllib
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

import httpx
import tomli_w
from tcms_daq.sim.trials import LoopAnalysis, LoopRig, RigFactory, TrialDesign
from tcms_daq.sim.trials import main as trials_main

from tcms_daq.discrepancy.model_file import parse_model

# The service's simulated clock runs this many simulated seconds per real second (a run of the trial design,
# about 70 s of programme, takes a few seconds of wall time).
DEFAULT_SIM_SPEED = 40.0


def bench_config_with_effects(directory: Path, table: dict[str, dict[str, float]], seed: int,
                              sample_rate_hz: float | None = None) -> Path:
    """A copy of the default simulated bench config (its paths made absolute) with ``[sim.effects]`` = ``table``,
    ``[sim] seed`` = ``seed`` and, when given, its ``sample_rate_hz``, written into ``directory``."""
    from tcms_daq.config.loader import default_bench_config_path

    source = default_bench_config_path()
    data = tomllib.loads(source.read_text(encoding="utf-8"))
    for key in ("compensation", "reducers"):
        data["bench"][key] = str(source.parent / data["bench"][key])
    data["sim"]["geometry"] = str(source.parent / data["sim"]["geometry"])
    data["sim"]["effects"] = table
    data["sim"]["seed"] = seed
    if sample_rate_hz is not None:
        data["sim"]["sample_rate_hz"] = sample_rate_hz
    path = directory / "bench.toml"
    path.write_text(tomli_w.dumps(data), encoding="utf-8")
    return path


def request_of(design: TrialDesign) -> dict[str, Any]:
    """The trial design as a ``POST /api/tests`` body: ±amplitude, ``loops_per_rate`` loops at each rate."""
    return {"reducer": design.reducer, "max_torque_nm": design.amplitude_nm, "cycles": design.loops_per_rate,
            "profile": "continuous", "rates": list(design.rates_nm_per_s)}


def programme_s(design: TrialDesign) -> float:
    """Simulated seconds of the design's torque programme (ramps only; the service adds its preload and moves)."""
    a = design.amplitude_nm
    return sum((a + 2 * a * 2 * design.loops_per_rate + a) / rate for rate in design.rates_nm_per_s)


class ServiceRig:
    """A closed-loop rig talking HTTP to a running service (``client``: authorised for tests, discrepancy and
    apply). ``sim_speed`` sizes the wait for a run's end (a ceiling, not a pace)."""

    def __init__(self, client: httpx.Client, sim_speed: float, data_dir: Path | None = None):
        self.client = client
        self.sim_speed = sim_speed
        self.data_dir = data_dir  # the service's data directory (its store and analyses), when known

    @staticmethod
    def _checked(response: httpx.Response, what: str) -> httpx.Response:
        """``response`` when it succeeded; RuntimeError naming ``what`` and the answer otherwise."""
        if response.status_code >= 300:
            raise RuntimeError(f"{what}: HTTP {response.status_code} {response.text[:300]}")
        return response

    def _ok(self, response: httpx.Response, what: str) -> Any:
        return self._checked(response, what).json()

    def analyse(self, design: TrialDesign, seed: int) -> LoopAnalysis:
        doc = self.analyse_request(request_of(design), programme_s(design))
        toml = self.client.get(f"/api/discrepancy/{doc['id']}/model")
        model = parse_model(self._checked(toml, "GET model").text, f"analysis {doc['id']} model.toml")
        return LoopAnalysis(doc["verdict"], [e["name"] for e in doc["effects"]], model,
                            float(doc["cv_rms_after_arcsec"]), float(doc["noise_floor_arcsec"]), ref=doc["id"])

    def analyse_request(self, body: dict[str, Any], programme_s: float = 300.0) -> dict[str, Any]:
        """POST /api/tests with ``body``, wait for its end, POST /api/discrepancy on it: the analysis document.
        ``programme_s``: simulated seconds the test takes at most (sizes the wait's ceiling)."""
        run_id = self._ok(self.client.post("/api/tests", json=body), "POST /api/tests")["id"]
        # generous ceiling: 10× the programme at the nominal speed (a loaded machine paces the clock slower),
        # plus a minute for the service's own steps
        deadline = time.monotonic() + 60.0 + 10.0 * programme_s / self.sim_speed
        while True:
            status = self._ok(self.client.get(f"/api/tests/{run_id}"), "GET /api/tests/{id}")["status"]
            if status not in ("queued", "running"):
                break
            if time.monotonic() > deadline:
                raise RuntimeError(f"test {run_id} still {status} after its ceiling")
            time.sleep(0.1)
        if status != "completed":
            raise RuntimeError(f"test {run_id} ended {status}")
        return self._ok(self.client.post("/api/discrepancy", json={"run_id": run_id}), "POST /api/discrepancy")

    def apply(self, analysis: LoopAnalysis) -> str | None:
        r = self.client.post(f"/api/discrepancy/{analysis.ref}/apply")
        if r.status_code in (409, 422):
            return f"HTTP {r.status_code}: {r.json().get('detail')}"
        self._ok(r, "POST /api/discrepancy/{id}/apply")
        return None


@contextmanager
def serving(table: dict[str, dict[str, float]], seed: int, sim_speed: float = DEFAULT_SIM_SPEED,
            sample_rate_hz: float | None = TrialDesign().sample_rate_hz) -> Iterator[ServiceRig]:
    """A service on a loopback port over a simulated bench with ``table`` hidden, sampling at ``sample_rate_hz``
    (the in-process trials' rate by default; None: the bench config's); yields its ``ServiceRig``."""
    import uvicorn

    from tcms_daq.service.app import ServiceSettings, create_app

    token = secrets.token_urlsafe(16)
    with tempfile.TemporaryDirectory(prefix="tcms-closed-loop-") as tmp:
        root = Path(tmp)
        settings = ServiceSettings(data_dir=root / "data",
                                   config_path=bench_config_with_effects(root, table, seed, sample_rate_hz),
                                   api_token=token, sim_speed=sim_speed)
        sock = socket.socket()
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        server = uvicorn.Server(uvicorn.Config(create_app(settings), log_level="warning"))
        thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
        thread.start()
        try:
            deadline = time.monotonic() + 120.0  # a ceiling: the wait ends when uvicorn has started
            while not server.started:
                if time.monotonic() > deadline or not thread.is_alive():
                    raise RuntimeError("the service did not start")
                time.sleep(0.02)
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120.0,
                              headers={"Authorization": f"Bearer {token}"}) as client:
                yield ServiceRig(client, sim_speed, settings.data_dir)
        finally:
            server.should_exit = True
            thread.join(30)
            sock.close()


def service_rig(sim_speed: float = DEFAULT_SIM_SPEED,
                sample_rate_hz: float | None = TrialDesign().sample_rate_hz) -> RigFactory:
    """A ``trials.RigFactory`` that runs each closed loop on its own service."""

    def factory(table: dict[str, dict[str, float]], seed: int) -> AbstractContextManager[LoopRig]:
        return serving(table, seed, sim_speed, sample_rate_hz)

    return factory


def main(argv: list[str] | None = None) -> int:
    """``python -m tcms_daq.service.closed_loop``: the trials' closed loop, each loop on its own service."""
    import argparse

    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--sim-speed", type=float, default=DEFAULT_SIM_SPEED,
                        help="simulated seconds per real second (default 40)")
    known, rest = parser.parse_known_args(argv)
    return trials_main(rest, prog="python -m tcms_daq.service.closed_loop", rig=service_rig(known.sim_speed))


if __name__ == "__main__":
    raise SystemExit(main())
