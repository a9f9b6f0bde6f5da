"""Build a wheel, install it (without extras: the runtime dependencies only) into a fresh virtual environment
outside the source tree, check that it added exactly one top-level package (``tcms_daq``) plus the console script
``tcms``, and run the product from another directory: ``tcms run`` (the in-process simulated bench), ``tcms serve``
with one test through the REST API, ``tcms sim serve --free-ports --urls-file`` + ``tcms run --sim-urls`` and
``tcms serve --sim-urls`` over the real protocols, and the README's quick tour as written (scripts/quick_tour.py,
the venv's ``bin`` first on PATH, in an empty directory).

    .venv/bin/python scripts/wheel_smoke.py [--keep DIR] [--no-tour]

Exits non-zero with the failing step's output. Used by .ci/run; needs the package index pip is configured for.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
import zipfile
from pathlib import Path

from tcms_daq.sim.instruments.child import start_simulators, stop_process

REPO = Path(__file__).resolve().parents[1]

TOKEN = "wheel-smoke-token"


def step(title: str, cmd: list[str], cwd: Path, timeout_s: float = 600.0, env: dict | None = None) -> str:
    print(f"wheel-smoke: {title}", flush=True)
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout_s, env=env)
    if proc.returncode != 0:
        sys.exit(f"wheel-smoke: FAILED: {title}\n$ {' '.join(cmd)}\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}")
    return proc.stdout


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def http(method: str, url: str, body: dict | None = None) -> dict:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method, headers={
        "Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=10) as resp:
        return json.loads(resp.read())


def wait_for(condition, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    last_error: Exception | None = None
    while time.monotonic() < deadline:
        try:
            value = condition()
            if value:
                return value
        except Exception as exc:  # not up yet
            last_error = exc
        time.sleep(0.2)
    sys.exit(f"wheel-smoke: FAILED: {what} within {timeout_s:.0f} s (last error: {last_error})")


def serve_one_test(tcms: Path, cwd: Path, env: dict, *extra: str, certificate: bool = True) -> None:
    """`tcms serve` from another directory; one short test through the API completes with an evaluation."""
    port = free_port()
    proc = subprocess.Popen([str(tcms), "serve", "--port", str(port), "--data-dir", str(cwd / "data"),
                             "--sim-speed", "50", *extra], cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_for(lambda: http("GET", f"{base}/api/health"), 60, "tcms serve answering /api/health")
        run = http("POST", f"{base}/api/tests", {"reducer": "RV-110E", "max_torque_nm": 200, "cycles": 1,
                                                 "rate_nm_per_s": 200})
        done = wait_for(lambda: (r := http("GET", f"{base}/api/tests/{run['id']}"))["status"]
                        in ("completed", "failed", "aborted") and r, 120, "the test to end")
        if done["status"] != "completed":
            sys.exit(f"wheel-smoke: FAILED: the served test ended {done['status']}: {json.dumps(done)[:2000]}")
        print(f"wheel-smoke: tcms serve{''.join(' ' + a for a in extra)}: test {run['id']} completed", flush=True)
        if not certificate:
            return
        # the certificate's Typst template is package data: the installed wheel typesets it
        with urllib.request.urlopen(f"{base}/api/tests/{run['id']}/certificate.pdf", timeout=120) as answer:
            pdf = answer.read()
        if not pdf.startswith(b"%PDF-"):
            sys.exit(f"wheel-smoke: FAILED: the certificate is not a PDF: {pdf[:200]!r}")
        print(f"wheel-smoke: tcms serve: certificate of {run['id']} ({len(pdf)} bytes)", flush=True)
    finally:
        proc.terminate()
        try:
            out, _ = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        if proc.returncode not in (0, -15):
            print(out[-4000:])


def loopback_run(tcms: Path, cwd: Path, env: dict) -> None:
    """`tcms sim serve --free-ports --urls-file` and, reading that file, `tcms run` (with port overrides too: no
    edited TOML copy) and `tcms serve` over the real protocols."""
    urls_file = cwd / "sim.json"
    try:
        sim, info = start_simulators("--free-ports", "--urls-file", str(urls_file), command=[str(tcms)], cwd=cwd,
                                     env=env)
    except RuntimeError as exc:
        sys.exit(f"wheel-smoke: FAILED: {exc}")
    try:
        urls = info["urls"]
        out = step("tcms run --config bench-loopback.toml --set … (real protocols)", [
            str(tcms), "run", "--config", "bench-loopback.toml", "--max-torque", "200", "--cycles", "1",
            "--conditioning", "1", "--rate", "400", "--json",
            "--set", f"instruments.angle.url={urls['angle']}", "--set", f"instruments.torque.url={urls['torque']}",
            "--set", f"instruments.loader.url={urls['loader_canopen']}"], cwd, timeout_s=300, env=env)
        result = json.loads(out)
        print(f"wheel-smoke: loopback run rigidity {result['rigidity_nm_per_arcmin']:.1f} N·m/arcmin")
        out = step("tcms run --config bench-loopback-modbus.toml --sim-urls sim.json (real protocols)", [
            str(tcms), "run", "--config", "bench-loopback-modbus.toml", "--sim-urls", urls_file.name,
            "--max-torque", "200", "--cycles", "1", "--conditioning", "1", "--rate", "400", "--json"], cwd,
            timeout_s=300, env=env)
        print(f"wheel-smoke: --sim-urls run rigidity {json.loads(out)['rigidity_nm_per_arcmin']:.1f} N·m/arcmin")
        # the service's clock is the simulators' (started at speed 1), not the in-process bench's --sim-speed 50
        serve_one_test(tcms, cwd, env, "--config", "bench-loopback.toml", "--sim-urls", urls_file.name,
                       "--sim-speed", "1", certificate=False)
    finally:
        stop_process(sim)


def start_tour(bin_dir: Path, tour_dir: Path, env: dict) -> tuple[subprocess.Popen[str], Path]:
    """The README's quick tour (scripts/quick_tour.py) in a process of its own, beside the steps that follow: both
    spend most of their time waiting on the real-time simulators. Its output goes to a file."""
    tour_dir.mkdir(parents=True, exist_ok=True)
    log = tour_dir.parent / "tour.log"
    print("wheel-smoke: the README's quick tour, as written, in an empty directory (beside the next steps)", flush=True)
    with log.open("w", encoding="utf-8") as out:
        proc = subprocess.Popen([sys.executable, str(REPO / "scripts" / "quick_tour.py"), str(bin_dir), "--workdir",
                                 str(tour_dir)], stdout=out, stderr=subprocess.STDOUT, text=True, env=env)
    return proc, log


def finish_tour(proc: subprocess.Popen[str], log: Path, timeout_s: float = 1200.0) -> None:
    """Wait for the tour, print what it printed, and fail on a failing line."""
    try:
        code = proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        code = proc.wait()
    print(log.read_text(encoding="utf-8"), end="", flush=True)
    if code != 0:
        sys.exit(f"wheel-smoke: FAILED: the quick tour (exit {code}; its output above)")
    print("wheel-smoke: the quick tour ran as written", flush=True)


def check_installed_files(vpy: Path, cwd: Path, env: dict) -> None:
    """The installed distribution's files (its RECORD) are the package ``tcms_daq``, its dist-info and the console
    script ``tcms``: nothing else lands in site-packages or bin."""
    listing = step("list the installed distribution's files", [str(vpy), "-c", (
        "import json, importlib.metadata as m; d = m.distribution('tcms-daq'); "
        "print(json.dumps([(str(f), str(f.locate())) for f in d.files]))")], cwd, env=env)
    bin_dir = vpy.parent.resolve()
    tops: set[str] = set()
    for relative, located in json.loads(listing):
        path = Path(located).resolve()
        if path.parent == bin_dir:
            tops.add(f"bin/{path.name}")
        elif relative.startswith(".."):
            tops.add(relative)  # outside site-packages and not a script: reported below
        else:
            tops.add(relative.split("/")[0])
    dist_info = {t for t in tops if t.endswith(".dist-info")}
    if len(dist_info) != 1 or tops - dist_info != {"tcms_daq", "bin/tcms"}:
        sys.exit(f"wheel-smoke: FAILED: the wheel installed {sorted(tops)}, not tcms_daq + its dist-info + bin/tcms")
    print("wheel-smoke: the installation added one top-level package, tcms_daq, and the console script tcms",
          flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", metavar="DIR", help="work in DIR and keep it (default: a temporary directory)")
    parser.add_argument("--no-tour", action="store_true", help="skip the README's quick tour (the longest step)")
    args = parser.parse_args()
    work = Path(args.keep or tempfile.mkdtemp(prefix="tcms-wheel-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        step("build the wheel", [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(work / "dist"),
                                 str(REPO)], work)
        wheel = next((work / "dist").glob("tcms_daq-*.whl"))
        with zipfile.ZipFile(wheel) as archive:
            top_level = {name.split("/")[0] for name in archive.namelist() if ".dist-info/" not in name}
        if top_level != {"tcms_daq"}:
            sys.exit(f"wheel-smoke: FAILED: the wheel installs {sorted(top_level)}, not one package tcms_daq")
        print("wheel-smoke: the wheel installs one top-level package, tcms_daq", flush=True)
        step("create a fresh venv", [sys.executable, "-m", "venv", str(work / "venv")], work)
        vpy = work / "venv" / "bin" / "python"
        step("install the wheel (with its runtime dependencies, no extras)",
             [str(vpy), "-m", "pip", "install", "-q", str(wheel)], work)
        elsewhere = work / "elsewhere"
        elsewhere.mkdir(exist_ok=True)
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
        env["TCMS_API_TOKEN"] = TOKEN
        check_installed_files(vpy, elsewhere, env)
        where = step("the installed package is used", [str(vpy), "-c", "import tcms_daq; print(tcms_daq.__file__)"],
                     elsewhere, env=env)
        if str(REPO) in where:
            sys.exit(f"wheel-smoke: FAILED: imported from the source tree: {where}")
        tcms = work / "venv" / "bin" / "tcms"
        out = step("tcms run (in-process simulated bench)", [str(tcms), "run", "--max-torque", "300", "--cycles",
                                                              "1", "--conditioning", "1", "--json"], elsewhere, env=env)
        print(f"wheel-smoke: tcms run rigidity {json.loads(out)['rigidity_nm_per_arcmin']:.1f} N·m/arcmin")
        out = step("python -m tcms_daq.discrepancy.trials (one hidden effect, one out of the catalogue)",
                   [str(work / "venv" / "bin" / "python"), "-m", "tcms_daq.discrepancy.trials", "--seeds", "1",
                    "--case", "thermal_drift", "--case", "encoder_slip", "--json"], elsewhere, env=env)
        trials = json.loads(out)["summary"]
        if trials["naming_accuracy"] != 1.0 or trials["out_of_catalogue"]["honesty_rate"] != 1.0:
            sys.exit(f"wheel-smoke: FAILED: discrepancy trials from the wheel: {trials}")
        print("wheel-smoke: discrepancy trials named the hidden drift and did not explain the slip")
        out = step("tcms run --config bench-station.toml --method transmission-error (the packaged station)",
                   [str(tcms), "run", "--config", "bench-station.toml", "--method", "transmission-error", "--json"],
                   elsewhere, env=env)
        te = json.loads(out)
        if not te["te_orders"] or not all(te["within_u"].values()):
            sys.exit(f"wheel-smoke: FAILED: transmission error from the wheel: {te['within_u']}")
        print(f"wheel-smoke: transmission error {te['transmission_error_arcsec']:.1f}″, orders "
              + ", ".join(f"{line['order']:g} ({line.get('component') or 'no component'})" for line in te["te_orders"]))
        tour = None if args.no_tour else start_tour(vpy.parent, work / "tour", env)
        serve_one_test(tcms, elsewhere, env)
        loopback_run(tcms, elsewhere, env)
        if tour is not None:
            finish_tour(*tour)
        print("wheel-smoke: ok", flush=True)
        return 0
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
