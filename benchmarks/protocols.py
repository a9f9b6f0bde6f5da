"""Protocol throughput on loopback against the simulated instruments, beside the limit of the real link.

Measured (one process, simulators on their own event-loop/notifier threads, physics not ticking):
- ND 287 readings/s through the ``nd287`` driver (STX → 17-byte frame over ``socket://`` loopback);
- Modbus transactions/s through the ``cia402-modbus`` driver (read of the statusword, TCP and RTU-over-TCP
  framing), through its serial-line client (``drivers.modbus_rtu.RtuSerialClient``, the path for real serial
  ports: replies read by their known length, t3.5 kept before each request) on the same RTU server, and,
  as the baseline, with pymodbus' stock serial client (waits for line silence in >= 1 ms polling steps);
- CANopen PDO round trips/s: RPDO1 (controlword + target torque, 4 data bytes) out, the drive's TPDO1
  (8 bytes) back, on python-can's in-process ``virtual`` bus and across the loopback socketcand hub.

Link limits computed from frame sizes (what the real wire allows, ignoring device reaction times):
- ND 287, 7E2 = 11 bits per character: 1 request + 17 reply characters = 198 bits per reading
  (9600 Bd → 48.5/s; 115 200 Bd → 582/s). Real displays add t2 ≈ 30 ms output delay (protocols.md §1.3).
- Modbus RTU at 115 200 Bd, 11 bits per character: read one register = 8 request + 7 reply bytes, plus the
  1.75 ms minimum inter-frame silence before each frame (t3.5 above 19 200 Bd).
- CAN at 1 Mbit/s, base frame of n data bytes = 47 + 8n bits without stuff bits (8 bytes → 111 bits). One
  round trip puts RPDO1 (4 bytes, 79 bits), TPDO1 (8 bytes, 111 bits) and TPDO2 (3 bytes, 71 bits) on the bus.
A target is met when the loopback rate is at least the real link's limit, i.e. the software is not the
bottleneck of the real bench.
"""

from __future__ import annotations

import time
import uuid

import can
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient

from benchmarks._runs import RUNS, spread

CHAR_BITS_7E2 = 11
CHAR_BITS_RTU = 11
RTU_SILENCE_S = 1.75e-3


def can_frame_bits(data_bytes: int) -> int:
    """Bits of a CAN base frame (11-bit id) with ``data_bytes`` data bytes, incl. 3-bit intermission, no stuffing."""
    return 47 + 8 * data_bytes


def link_limits() -> dict[str, float]:
    nd_bits = (1 + 17) * CHAR_BITS_7E2
    rtu_s = (8 + 7) * CHAR_BITS_RTU / 115200 + 2 * RTU_SILENCE_S
    can_bits = can_frame_bits(4) + can_frame_bits(8) + can_frame_bits(3)
    return {
        "nd287_limit_9600_per_s": 9600 / nd_bits,
        "nd287_limit_115200_per_s": 115200 / nd_bits,
        "modbus_rtu_limit_115200_per_s": 1.0 / rtu_s,
        "can_pdo_round_trip_limit_1mbit_per_s": 1e6 / can_bits,
        "can_pdo_round_trip_bits": float(can_bits),
    }


def _rate(fn, duration_s: float) -> float:
    fn()  # warm-up
    n = 0
    start = time.perf_counter()
    deadline = start + duration_s
    while True:
        fn()
        n += 1
        now = time.perf_counter()
        if now >= deadline:
            return n / (now - start)


def _pdo_round_trips(url_options: dict, duration_s: float, node_id: int = 1) -> float:
    bus = can.Bus(**url_options)
    try:
        bus.send(can.Message(arbitration_id=0x000, data=[0x01, node_id], is_extended_id=False))  # NMT start
        rpdo = can.Message(arbitration_id=0x200 + node_id, data=[0, 0, 0, 0], is_extended_id=False)
        tpdo_id = 0x180 + node_id
        time.sleep(0.05)
        while bus.recv(0) is not None:  # drop what came before
            pass

        def round_trip() -> None:
            bus.send(rpdo)
            deadline = time.perf_counter() + 1.0
            while time.perf_counter() < deadline:
                msg = bus.recv(1.0)
                if msg is not None and msg.arbitration_id == tpdo_id:
                    return
            raise TimeoutError("no TPDO1 answered the RPDO within 1 s")

        return _rate(round_trip, duration_s)
    finally:
        bus.shutdown()


def run(quick: bool = False) -> dict:
    """Every rate measured in ``RUNS`` runs (min/median/max); a target is met when the slowest run reaches the
    link limit."""
    runs = [_measure(quick) for _ in range(1 if quick else RUNS)]
    metrics: dict[str, float] = {"runs": len(runs)}
    for key in runs[0]:
        metrics.update(spread(key, [r[key] for r in runs]))
    limits = link_limits()
    metrics.update(limits)
    metrics["modbus_rtu_serial_line_speedup_vs_stock_client"] = (
        metrics["modbus_rtu_serial_line_transactions_per_s_median"]
        / metrics["modbus_rtu_serial_client_transactions_per_s_median"])
    # each measured rate must reach the link limit of its bus (metric -> limit key of link_limits())
    minimums = {
        "nd287_readings_per_s": "nd287_limit_115200_per_s",
        "modbus_rtu_serial_line_transactions_per_s": "modbus_rtu_limit_115200_per_s",
        "modbus_rtu_transactions_per_s": "modbus_rtu_limit_115200_per_s",
        "canopen_pdo_round_trips_virtual_per_s": "can_pdo_round_trip_limit_1mbit_per_s",
        "canopen_pdo_round_trips_socketcand_per_s": "can_pdo_round_trip_limit_1mbit_per_s",
    }
    targets = {f"{metric}_min": {"limit": limits[limit], "met": bool(metrics[f"{metric}_min"] >= limits[limit])}
               for metric, limit in minimums.items()}
    return {
        "name": "protocols",
        "metrics": metrics,
        "targets": targets,
        "notes": (f"min/median/max of {len(runs)} runs; loopback rates against the simulators (driver + simulator "
                  "in one process, 2 shared cores) "
                  "beside the real link limits from frame sizes: ND 287 7E2 at 115 200 Bd (9600 Bd limit "
                  "also listed), Modbus RTU at 115 200 Bd with the 1.75 ms inter-frame silence, CAN at 1 Mbit/s "
                  "for RPDO1 + TPDO1 + TPDO2 without stuff bits. The driver's serial-line client reads each RTU reply by "
                  "its length (5 + byte count for functions 1-4, 8 for 5/6/15/16, 5 for an exception) and waits "
                  "t3.5 (1.75 ms) after the last reply byte before the next request, so on loopback it is bound "
                  "by that silence, not by polling; pymodbus' stock serial client (baseline, no longer used by "
                  "the driver) polls the line for silence in >= 1 ms steps and stays below the 115 200 Bd limit. "
                  "The socketcand path pays two TCP hops and python-can's text framing per frame."),
    }


def _measure(quick: bool) -> dict[str, float]:
    from tcms_daq.drivers.cia402_modbus import CiA402Modbus
    from tcms_daq.drivers.nd287 import ND287
    from tcms_daq.drivers.testing import driver_for
    from tcms_daq.sim.bench import SimulatedBench
    from tcms_daq.sim.instruments.drive_canopen import DriveCanopenNode
    from tcms_daq.sim.instruments.physics import SharedPhysics
    from tcms_daq.sim.instruments.serve import InstrumentSimulators, SimulatorOptions

    duration_s = 0.3 if quick else 1.5
    physics = SharedPhysics(SimulatedBench())
    opts = SimulatorOptions.from_mapping(
        {"ports": {"nd287": 0, "modbus": 0, "modbus_rtu": 0, "socketcand": 0}},
        instruments=("nd287", "modbus", "modbus_rtu", "canopen"), can_interface="socketcand",
        can_channel=f"bench-{uuid.uuid4().hex[:8]}",
    )
    sims = InstrumentSimulators(physics, opts)
    ports = sims.start()
    metrics: dict[str, float] = {}
    try:
        with driver_for(ND287, f"socket://127.0.0.1:{ports['nd287']}", timeout_s=1.0) as nd:
            metrics["nd287_readings_per_s"] = _rate(nd.read_one, duration_s)
        with driver_for(CiA402Modbus, f"tcp://127.0.0.1:{ports['modbus']}", timeout_s=1.0) as drive:
            metrics["modbus_tcp_transactions_per_s"] = _rate(lambda: drive.link.read_register("statusword"), duration_s)
        with driver_for(CiA402Modbus, f"socket://127.0.0.1:{ports['modbus_rtu']}", timeout_s=1.0) as drive:
            metrics["modbus_rtu_transactions_per_s"] = _rate(lambda: drive.link.read_register("statusword"), duration_s)
        # what a real serial line gets: the driver's serial-line client (pyserial, replies read by length)
        with driver_for(CiA402Modbus, f"socket://127.0.0.1:{ports['modbus_rtu']}", timeout_s=1.0, serial_line=True) as drive:
            metrics["modbus_rtu_serial_line_transactions_per_s"] = _rate(
                lambda: drive.link.read_register("statusword"), duration_s)
        # baseline: pymodbus' stock serial client waits for the line to fall silent by polling it in ≥ 1 ms steps
        serial_client = ModbusSerialClient(f"socket://127.0.0.1:{ports['modbus_rtu']}", framer=FramerType.RTU,
                                           baudrate=115200, timeout=1.0, retries=0)
        serial_client.connect()
        try:
            metrics["modbus_rtu_serial_client_transactions_per_s"] = _rate(
                lambda: serial_client.read_holding_registers(0x3200, count=1, device_id=1), duration_s)
        finally:
            serial_client.close()
        # periodic TPDOs off (event timer 10 s), so every TPDO1 is the answer to an RPDO
        sims.canopen.stop()
        hub_node = DriveCanopenNode(sims.drive, tpdo_period_s=10.0, interface="socketcand",
                                    channel=opts.can_channel, host="127.0.0.1", port=ports["socketcand"],
                                    tcp_tune=True)
        hub_node.start()
        try:
            metrics["canopen_pdo_round_trips_socketcand_per_s"] = _pdo_round_trips(
                {"interface": "socketcand", "channel": opts.can_channel, "host": "127.0.0.1",
                 "port": ports["socketcand"], "tcp_tune": True}, duration_s)
        finally:
            hub_node.stop()
        channel = f"bench-{uuid.uuid4().hex[:8]}"
        virtual_node = DriveCanopenNode(sims.drive, tpdo_period_s=10.0, interface="virtual", channel=channel)
        virtual_node.start()
        try:
            metrics["canopen_pdo_round_trips_virtual_per_s"] = _pdo_round_trips(
                {"interface": "virtual", "channel": channel}, duration_s)
        finally:
            virtual_node.stop()
    finally:
        sims.stop()
    return metrics


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run(), indent=2))
