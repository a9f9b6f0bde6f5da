"""The second axis (issue 28): the input drive in profile velocity over CANopen (node 2 on the loader's bus) and
Modbus (unit 2 on the loader's server), the input torque AED, the ND 287 in coupled mode and the two-axis counter,
against the simulators on loopback; and the input drive's safety: it stops by itself when the software behind its
link is killed (SIGKILL) or the link goes mute, and a safe start finds one left turning without a watchdog and
brings it to rest."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from tcms_daq.drivers.aed import AED
from tcms_daq.drivers.base import INPUT_ANGLE_COLUMN, CommandRejected, InputDrive
from tcms_daq.drivers.cia402_velocity import CiA402VelocityCanopen, CiA402VelocityModbus
from tcms_daq.drivers.counter import Counter2Axis
from tcms_daq.drivers.nd287 import ND287, ND287Coupled
from tcms_daq.drivers.testing import driver_for, wait_until

from tcms_daq.acquisition.bench import Bench, SafeStart
from tcms_daq.acquisition.clock import MonotonicClock

RATIO = 100.0
FRICTION_NM = 0.5
SECOND_AXIS = ("modbus", "canopen", "input_drive", "input_aed", "nd287_coupled", "counter", "nd287")
STOP_BOUND_S = 2.0  # as the loader's (issue 22): stopped by its own watchdog within 2 s of the kill or mute
POWERED = ("OPERATION ENABLED", "SWITCHED ON", "QUICK STOP ACTIVE")


@pytest.fixture
def axis_sims(make_sims):
    def make(**options):
        sims = make_sims(instruments=SECOND_AXIS, can_interface="socketcand", input_ratio=RATIO,
                         input_friction_nm=FRICTION_NM, **options)
        sims.physics.start(speed=1.0)
        return sims
    return make


def _url(sims, link: str) -> str:
    if link == "canopen":
        return f"socketcand://127.0.0.1:{sims.ports['socketcand']}/{sims.options.can_channel}"
    return f"tcp://127.0.0.1:{sims.ports['modbus']}"


def _settings(link: str, watchdog: bool = True) -> dict:
    if link == "canopen":
        return {"connect_timeout_s": 5.0, **({} if watchdog else {"drive_consumer_timeout_ms": 0})}
    return {"timeout_s": 0.5, **({} if watchdog else {"comm_timeout_ms": 0})}


def _drive(sims, link: str, watchdog: bool = True) -> CiA402VelocityCanopen | CiA402VelocityModbus:
    cls = CiA402VelocityCanopen if link == "canopen" else CiA402VelocityModbus
    return driver_for(cls, _url(sims, link), **_settings(link, watchdog))


@pytest.mark.parametrize("link", ["canopen", "modbus"])
def test_input_drive_turns_the_input_and_the_instruments_see_it(axis_sims, link):
    sims = axis_sims()
    drive = _drive(sims, link)
    counter = driver_for(Counter2Axis, f"socket://127.0.0.1:{sims.ports['counter']}")
    coupled = driver_for(ND287Coupled, f"socket://127.0.0.1:{sims.ports['nd287_coupled']}", ratio=RATIO)
    plain = driver_for(ND287, f"socket://127.0.0.1:{sims.ports['nd287_coupled']}")
    aed = driver_for(AED, f"socket://127.0.0.1:{sims.ports['input_aed']}", nominal_torque_nm=50.0)
    with drive, counter, coupled, aed:
        assert isinstance(drive, InputDrive)
        with pytest.raises(CommandRejected):
            drive.set_velocity(drive.max_velocity_deg_per_s * 1.5)  # nothing sent
        with pytest.raises(CommandRejected):
            drive.set_torque(1.0)
        drive.enable()
        drive.set_velocity(360.0)
        assert wait_until(lambda: abs(drive.status().velocity_deg_per_s - 360.0) < 1.0, timeout_s=5)
        counter.read()  # drain what was latched at rest and on the ramp
        assert sims.input_drive is not None and sims.input_drive.state.label == "OPERATION ENABLED"
        time.sleep(0.3)
        batch = counter.read()
        # latched pairs at the card's 1 kHz: the input turns at 360 deg/s, the output at 1/i of it (rigid ratio)
        assert len(batch) >= 200
        rate_hz = (len(batch) - 1) / (batch.time_s[-1] - batch.time_s[0])
        assert 900 < rate_hz < 1100, rate_hz
        inp, out = batch.extra[INPUT_ANGLE_COLUMN], batch.value
        slope = (inp[-1] - inp[0]) / (batch.time_s[-1] - batch.time_s[0])
        assert abs(slope / 3600.0 - 360.0) < 20.0, slope
        twist = out - inp / RATIO  # the output minus the input through the ratio: the bench's (twist) reading
        assert twist.max() - twist.min() < 2.0, (twist.min(), twist.max())
        # the coupled display shows X1 − X2/i: the rotation cancels, what is left is small
        _, te = coupled.read_one()
        assert abs(te) < 60.0, te
        # the input torque: the Coulomb friction the input drive overcomes (no loader torque)
        torque = aed.read().value.mean()
        assert abs(torque - FRICTION_NM) < 0.2, torque
        drive.disable()
        assert wait_until(lambda: (st := drive.status()).state == "SWITCH ON DISABLED"
                          and abs(st.velocity_deg_per_s) < 1.0, timeout_s=2)
    # a display not in its coupled mode is refused by the coupled driver (series ' ')
    single = driver_for(ND287Coupled, f"socket://127.0.0.1:{sims.ports['nd287']}", ratio=RATIO)
    with single, pytest.raises(CommandRejected, match="coupled"):
        single.read_one()
    del plain


CHILD = r"""
import json, sys, time
from tcms_daq.drivers.testing import driver_for
from tcms_daq.drivers.cia402_velocity import CiA402VelocityCanopen, CiA402VelocityModbus
link, url, settings = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
cls = CiA402VelocityCanopen if link == "canopen" else CiA402VelocityModbus
drive = driver_for(cls, url, **settings)
drive.connect()
drive.enable()
drive.set_velocity(720.0)
print("moving", flush=True)
time.sleep(600)
"""


def _start_child(sims, link: str, watchdog: bool = True) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-c", CHILD, link, _url(sims, link),
                             json.dumps(_settings(link, watchdog))], stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "moving"
    drive = sims.input_drive
    assert wait_until(lambda: drive.velocity_deg_per_s() > 700.0, timeout_s=10)
    return proc


def _wait_for(fn, timeout_s: float):
    """The first truthy value of ``fn()`` within ``timeout_s`` (AssertionError after)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = fn()
        if value:
            return value
        time.sleep(0.01)
    raise AssertionError(f"not within {timeout_s} s")


def _stopped_by_itself(sims, since: float) -> float:
    """Seconds from ``since`` to the input drive's watchdog reaction (the simulator's own record)."""
    link = "input_canopen"
    reaction = _wait_for(lambda: [r for r in sims.watchdog_reactions()
                                   if r["at_monotonic_s"] >= since and (r["link"] == link or r.get("device_id") == 2)],
                          timeout_s=10)[0]
    drive = sims.input_drive
    assert wait_until(lambda: drive.state.label not in POWERED and drive.velocity_deg_per_s() == 0.0, timeout_s=10)
    assert drive.state.label == "FAULT" and drive.error_code == 0x8130
    return reaction["at_monotonic_s"] - since


@pytest.mark.parametrize("link", ["canopen", "modbus"])
@pytest.mark.parametrize("event", ["kill", "mute"])
def test_input_drive_stops_by_itself(axis_sims, link, event):
    sims = axis_sims()
    if event == "kill":
        proc = _start_child(sims, link)
        since = time.monotonic()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    else:
        drive = _drive(sims, link)
        drive.connect()
        drive.enable()
        drive.set_velocity(720.0)
        assert wait_until(lambda: sims.input_drive.velocity_deg_per_s() > 700.0, timeout_s=10)
        since = time.monotonic()
        sims.inject("socketcand" if link == "canopen" else "modbus", "mute")
    stop_s = _stopped_by_itself(sims, since)
    print(f"{link} {event}: input drive stopped by its watchdog {stop_s:.3f} s after")
    assert stop_s <= STOP_BOUND_S, stop_s
    if event == "mute":
        sims.inject("socketcand" if link == "canopen" else "modbus", None)
        drive.close()


@pytest.mark.parametrize("link", ["canopen", "modbus"])
def test_safe_start_stops_an_input_drive_left_turning(axis_sims, link):
    """Without its watchdog (configured off on both sides) the input drive keeps turning when the software dies; the
    next bench's safe start finds it enabled and turning and brings it to rest before anything else."""
    sims = axis_sims(modbus_comm_timeout_s=0.0)
    proc = _start_child(sims, link, watchdog=False)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    time.sleep(0.5)
    assert sims.input_drive.state.label == "OPERATION ENABLED" and sims.input_drive.velocity_deg_per_s() > 700.0
    drive = _drive(sims, link, watchdog=False)
    bench = Bench(angle=None, torque=None, loader=None, clock=MonotonicClock(), input_drive=drive)  # type: ignore[arg-type]
    drive.connect()
    try:
        report: SafeStart = bench.make_input_drive_safe()
    finally:
        drive.close()
    assert report.found_state == "OPERATION ENABLED" and report.safe, report
    assert report.final_state == "SWITCH ON DISABLED", report
    assert "720.0 deg/s" in report.message, report.message
    assert sims.input_drive.velocity_deg_per_s() == 0.0
