"""Live pipeline (issue 7 item 2): the in-process simulated source at 10 kHz and 50 kHz through acquisition,
compensation, the recorder and the WebSocket hub to 10 clients on loopback.

For each rate, ``tcms serve`` runs as a separate process (simulated bench in real time, ``--sim-speed 1``, the
paper's measuring-chain geometry simulated and compensated) with a long test running, so the recorder writes
every sample to the store. Ten asyncio WebSocket clients in this process read ``/ws/live``:

* phase 1 (healthy): ``duration_s`` with the 10 clients — frames lost (sequence gaps + the header's dropped
  count), frame rate per client, latency from a sample's time stamp to its receipt;
* phase 2 (stalled): one more client that never reads (small receive buffer) for ``duration_s / 2`` — the
  healthy clients' frame rate against phase 1, the stalled client's dropped frames / eviction from the server.

Then the threaded real-time path (issue 16 item 4), in two forms, with the same ten clients:

* ``threaded_10khz``: the simulated bench at 10 kHz on the real-time clock (``virtual://sim?clock=real-time``):
  ``tcms serve`` reads it with the threaded scheduler — reader threads polling every 2 ms, the coordinator
  stepping every 20 ms, the status poller — exactly as it reads real instruments, but with no protocol between:
  a reading returns the samples produced since the last one, stamped when they were produced. This is what
  "the threaded path at 10 kHz" can mean here: no instrument of the bench delivers 10 kHz over its protocol.
* ``protocols``: ``tcms sim serve`` in one process and ``tcms serve --config bench-loopback.toml`` over the
  protocols (ND 287 and AED polled over TCP, the CiA 402 drive over CANopen) in another; latency from the
  instrument reading's stamp (``time.monotonic`` in the service at the request) to the client's receipt. Its
  sample rate is what the polled links deliver (each reading is one request and reply, a few hundred per
  second on loopback), not 10 kHz.

Every configuration runs ``RUNS`` times (a fresh service each time); the report gives min/median/max over the
runs, and a target holds when the worst run meets it.

Latency: the service reports the ``time.monotonic()`` at which its sample clock read 0 (CLOCK_MONOTONIC is
system-wide), so a sample stamped ``t`` was due at ``mono0 + t``; the latency of a frame is its receipt time
minus the due time of its OLDEST sample (the worst sample of the frame). CPU: the service process's user+system
CPU time over the wall time of phase 1 (from /proc), in cores.
"""

from __future__ import annotations

import asyncio
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import tomli_w
from tcms_daq.sim.instruments.child import start_simulators, stop_process

from benchmarks._runs import RUNS, spread

REPO = Path(__file__).resolve().parents[1]
N_CLIENTS = 10
RATES_HZ = (10_000.0, 50_000.0)
TOKEN = "benchmark-token"
HEADER = struct.Struct("<4sHHQdII")
P99_LIMIT_S = 0.100
CPU_LIMIT_CORES_AT_10KHZ = 1.0
STALL_RATE_RATIO_LIMIT = 0.95  # healthy clients keep ≥ 95 % of their frame rate beside a stalled client


def _bench_config(directory: Path, rate_hz: float, real_time: bool = False) -> Path:
    """config/bench-sim.toml at ``rate_hz``, simulating and compensating the paper's measuring chain;
    ``real_time``: the simulated instruments on the real-time clock (read by the threaded scheduler)."""
    src = REPO / "config" / "bench-sim.toml"
    data = tomllib.loads(src.read_text(encoding="utf-8"))
    geometry = str(REPO / "config" / "geometry-paper.toml")
    data["bench"]["reducers"] = str(REPO / "config" / data["bench"].get("reducers", "reducers.toml"))
    data["bench"]["compensation"] = geometry
    data["sim"]["sample_rate_hz"] = rate_hz
    data["sim"]["geometry"] = geometry
    if real_time:
        for kind in ("angle", "torque", "loader"):
            data["instruments"][kind]["url"] = "virtual://sim?clock=real-time"
    path = directory / f"bench-{int(rate_hz)}{'-real-time' if real_time else ''}.toml"
    path.write_text(tomli_w.dumps(data), encoding="utf-8")
    return path


def _start_service(config: Path | str, data_dir: Path, sim_speed: float = 1.0, overrides: tuple[str, ...] = ()
                   ) -> tuple[subprocess.Popen, str]:
    env = {**os.environ, "TCMS_API_TOKEN": TOKEN, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "tcms_daq.cli", "serve", "--port", "0", "--config", str(config),
         "--data-dir", str(data_dir), "--sim-speed", str(sim_speed), *(a for o in overrides for a in ("--set", o))],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if "service on http://" in line:
            hostport = line.split("http://", 1)[1].split("/", 1)[0]
            break
        if not line and proc.poll() is not None:
            raise RuntimeError("tcms serve exited during start")
    else:
        proc.kill()
        raise RuntimeError("tcms serve did not start")
    client = httpx.Client(base_url=f"http://{hostport}", timeout=10)
    while time.monotonic() < deadline:
        try:
            if client.get("/api/health").status_code == 200:
                break
        except httpx.TransportError:
            time.sleep(0.1)
    client.close()
    return proc, hostport


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class ClientLog:
    def __init__(self) -> None:
        self.seqs: list[int] = []
        self.received_mono: list[float] = []
        self.oldest_sample_s: list[float] = []
        self.dropped = 0
        self.samples = 0

    def add(self, frame: bytes, now: float) -> None:
        _, _, _, seq, t0, n, dropped = HEADER.unpack_from(frame)
        self.seqs.append(seq)
        self.received_mono.append(now)
        self.oldest_sample_s.append(t0)
        self.dropped = dropped
        self.samples += n


async def _reader(url: str, log: ClientLog, stop: asyncio.Event) -> None:
    import websockets

    async with websockets.connect(url, max_size=None, compression=None) as ws:
        await ws.recv()  # schema
        while not stop.is_set():
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            if isinstance(frame, bytes):
                log.add(frame, time.monotonic())


def _stalled_socket(host: str, port: int) -> socket.socket:
    """A WebSocket client that completes the handshake and then never reads (4 KiB receive buffer)."""
    import base64

    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((host, port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        f"GET /ws/live HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
    )
    return sock


def _window(logs: list[ClientLog], t_from: float, t_to: float) -> list[dict]:
    out = []
    for log in logs:
        recv = np.asarray(log.received_mono)
        sel = (recv >= t_from) & (recv < t_to)
        seqs = np.asarray(log.seqs)[sel]
        out.append({
            "frames": int(sel.sum()),
            "rate": float(sel.sum() / (t_to - t_from)),
            "gaps": int(np.sum(np.diff(seqs) - 1)) if len(seqs) > 1 else 0,
        })
    return out


async def _measure(hostport: str, duration_s: float, mono0: float) -> dict:
    host, port = hostport.rsplit(":", 1)
    url = f"ws://{hostport}/ws/live"
    logs = [ClientLog() for _ in range(N_CLIENTS)]
    stop = asyncio.Event()
    tasks = [asyncio.ensure_future(_reader(url, log, stop)) for log in logs]
    await asyncio.sleep(1.0)  # connect and settle
    t1 = time.monotonic()
    await asyncio.sleep(duration_s)
    t2 = time.monotonic()
    stalled = _stalled_socket(host, int(port))
    await asyncio.sleep(duration_s / 2)
    t3 = time.monotonic()
    stop.set()
    await asyncio.gather(*tasks, return_exceptions=True)
    async with httpx.AsyncClient(base_url=f"http://{hostport}", timeout=10) as c:
        live = (await c.get("/api/live/clients")).json()
    stalled.close()

    healthy = _window(logs, t1, t2)
    shared = _window(logs, t2, t3)
    lat = []
    for log in logs:
        recv = np.asarray(log.received_mono)
        sel = (recv >= t1) & (recv < t3)
        lat.append(recv[sel] - (mono0 + np.asarray(log.oldest_sample_s)[sel]))
    latency = np.concatenate(lat) if lat else np.empty(0)
    lost = sum(h["gaps"] for h in healthy + shared) + sum(log.dropped for log in logs)
    rate_1 = float(np.mean([h["rate"] for h in healthy]))
    rate_2_min = float(min(s["rate"] for s in shared))
    return {
        "t1": t1, "t2": t2,
        "frames_lost_by_healthy_clients": lost,
        "frame_rate_per_client_hz": rate_1,
        "p50_latency_ms": float(np.percentile(latency, 50) * 1e3),
        "p99_latency_ms": float(np.percentile(latency, 99) * 1e3),
        "max_latency_ms": float(latency.max() * 1e3),
        "min_healthy_rate_with_stalled_client_ratio": rate_2_min / rate_1,
        # the healthy clients dropped nothing (counted above), so the hub's total is the stalled client's,
        # including what it lost before it was evicted
        "stalled_client_dropped_frames": int(live["dropped_total"]) - sum(log.dropped for log in logs),
        "stalled_client_evicted": int(live["evicted_total"]),
        "samples_per_client_per_s": float(np.mean([log.samples for log in logs]) / (t3 - t1 + 1.0)),
    }


def _one_rate(rate_hz: float, duration_s: float, workdir: Path, real_time: bool = False) -> dict:
    config = _bench_config(workdir, rate_hz, real_time)
    proc, hostport = _start_service(config, workdir / f"data-{config.stem}")
    return _measure_service(proc, hostport, duration_s)


def _one_protocol_run(duration_s: float, workdir: Path) -> dict:
    """The threaded real-instrument path: ``tcms sim serve`` in one process, ``tcms serve`` over the protocols
    (ND 287 and AED polled over TCP, the drive over CANopen) in another; latency from the instrument reading's
    stamp (the service's ``time.monotonic``) to the client's receipt."""
    sim, info = start_simulators("--config", "bench-loopback.toml", cwd=REPO)
    urls = info["urls"]
    try:
        proc, hostport = _start_service("bench-loopback.toml", workdir / "data-protocols", overrides=(
            f"instruments.angle.url={urls['angle']}", f"instruments.torque.url={urls['torque']}",
            f"instruments.loader.url={urls['loader_canopen']}"))
        return _measure_service(proc, hostport, duration_s)
    finally:
        stop_process(sim)


def _measure_service(proc: subprocess.Popen, hostport: str, duration_s: float) -> dict:
    try:
        with httpx.Client(base_url=f"http://{hostport}", headers={"Authorization": f"Bearer {TOKEN}"},
                          timeout=10) as c:
            bench = c.get("/api/bench").json()
            mono0 = bench["monotonic_at_clock_zero_s"]
            # a long test (≈ 3 min of profile) so acquisition, compensation and the recorder all run
            run_id = c.post("/api/tests", json={"reducer": "RV-110E", "max_torque_nm": 1000, "cycles": 3,
                                                "profile": "continuous", "rate_nm_per_s": 100}).json()["id"]
            cpu0, wall0 = _cpu_seconds(proc.pid), time.monotonic()
            result = asyncio.run(_measure(hostport, duration_s, mono0))
            cpu1, wall1 = _cpu_seconds(proc.pid), time.monotonic()
            status = c.get(f"/api/tests/{run_id}").json()
            c.post(f"/api/tests/{run_id}/abort")
            result["test_status_during_measurement"] = status["status"]
            result["recorded_samples"] = status["sample_count"]
            result["service_cpu_cores"] = (cpu1 - cpu0) / (wall1 - wall0)
            return result
    finally:
        stop_process(proc)


# what each configuration reports, per run; the stalled-client phase is judged for the in-process ones
_COMMON = ("frames_lost_by_healthy_clients", "frame_rate_per_client_hz", "p50_latency_ms", "p99_latency_ms",
           "max_latency_ms", "service_cpu_cores", "samples_per_client_per_s", "recorded_samples")
_STALL = ("min_healthy_rate_with_stalled_client_ratio", "stalled_client_dropped_frames", "stalled_client_evicted")


def _configurations(workdir: Path) -> dict[str, tuple[Callable[[float], dict], tuple[str, ...]]]:
    """name -> (one run for a duration, the keys it reports)."""
    return {
        **{f"{int(rate / 1000)}khz": (lambda d, rate=rate: _one_rate(rate, d, workdir), _COMMON + _STALL)
           for rate in RATES_HZ},
        "threaded_10khz": (lambda d: _one_rate(10_000.0, d, workdir, real_time=True), _COMMON + _STALL),
        "protocols": (lambda d: _one_protocol_run(d, workdir), _COMMON),
    }


def run(quick: bool = False) -> dict:
    duration_s = 6.0 if quick else 20.0
    runs = 1 if quick else RUNS
    metrics: dict[str, float] = {"runs": runs}
    targets: dict[str, dict] = {}
    notes = []
    with tempfile.TemporaryDirectory(prefix="tcms-bench-live-") as tmp:
        for name, (one_run, keys) in _configurations(Path(tmp)).items():
            results = [one_run(duration_s) for _ in range(runs)]
            for key in keys:
                metrics.update(spread(f"{name}_{key}", [r[key] for r in results]))
            targets[f"{name}_frames_lost_by_healthy_clients_max"] = {
                "limit": 0, "met": bool(metrics[f"{name}_frames_lost_by_healthy_clients_max"] == 0)}
            targets[f"{name}_p99_latency_ms_max"] = {
                "limit": P99_LIMIT_S * 1e3, "met": bool(metrics[f"{name}_p99_latency_ms_max"] < P99_LIMIT_S * 1e3)}
            if "min_healthy_rate_with_stalled_client_ratio" in keys:
                targets[f"{name}_min_healthy_rate_with_stalled_client_ratio_min"] = {
                    "limit": STALL_RATE_RATIO_LIMIT,
                    "met": bool(metrics[f"{name}_min_healthy_rate_with_stalled_client_ratio_min"] >= STALL_RATE_RATIO_LIMIT)}
            if name in ("10khz", "threaded_10khz"):
                targets[f"{name}_service_cpu_cores_max"] = {
                    "limit": CPU_LIMIT_CORES_AT_10KHZ,
                    "met": bool(metrics[f"{name}_service_cpu_cores_max"] < CPU_LIMIT_CORES_AT_10KHZ)}
            states = sorted({r["test_status_during_measurement"] for r in results})
            notes.append(f"{name}: test {'/'.join(states)} during the measurement")
    return {
        "name": "live_pipeline",
        "metrics": metrics,
        "targets": targets,
        "notes": (
            f"{runs} runs per configuration (a fresh service each), each: {N_CLIENTS} healthy WebSocket clients for "
            f"{duration_s:g} s, then + 1 stalled client for {duration_s / 2:g} s; min/median/max over the runs, a "
            "target judged on the worst run. 10khz, 50khz: tcms serve in its own process, the simulated bench on "
            "the paced simulated clock (stepped scheduler), paper geometry simulated and compensated, a test "
            "running (recorder active). threaded_10khz: the same bench at 10 kHz on the real-time clock, read by "
            "the threaded scheduler (reader threads, coordinator) with no protocol between. protocols: tcms sim "
            "serve + tcms serve over ND 287/AED/CANopen on loopback at the rate the polled links deliver. Latency = "
            "receipt − due time of the oldest sample in the frame. CPU = service process CPU time / wall time "
            "(cores); the clients run on the same 2-core machine. " + "; ".join(notes)
        ),
    }


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run(quick="--full" not in sys.argv), indent=2))
