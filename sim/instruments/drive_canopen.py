"""CANopen front end of the simulated CiA 402 drive: a canopen ``LocalNode`` (object dictionary
``tcms_daq/protocols/drive402.eds``) on a python-can bus (``virtual`` in-process or ``socketcand`` via the loopback hub).

- NMT slave with boot-up and a heartbeat producer (0x1017, default 100 ms).
- SDO server: reads of the live objects come from the drive model, writes go into it; a value the drive
  refuses aborts with 0x06090030 (range) or 0x08000022 (state), writes to read-only objects 0x06010002.
- PDOs (canopen's LocalNode does not tie PDOs to the OD, protocols.md §5.3, so this module copies values):
  RPDO1 (0x200+n: controlword, target torque) is applied in OPERATIONAL only; TPDO1 (0x180+n: statusword,
  torque actual, position actual) and TPDO2 (0x280+n: mode display, error code) are sent every event-timer
  period (10 ms) and right after every RPDO, in OPERATIONAL only.
- EMCY producer: every drive fault (and the error reset) is sent as an EMCY frame.
- Heartbeat consumer 0x1016: once the master's heartbeat has been seen, its absence for the configured time
  while the drive is enabled makes the drive react as 0x6007 says (fault 0x8130 by default). Time this process
  could not run (its check came late: a loaded machine starves the simulator, which a real drive's firmware never
  is) does not count as the master's silence: the master's frames may be waiting unread in the socket.
Fault injection (``inject``): ``heartbeat_loss`` (stop the heartbeat producer), ``mute`` (the node sends
nothing at all: no SDO answers, PDOs, heartbeat or EMCY), ``garbage`` (TPDO1 sent with 3 junk bytes).
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from pathlib import Path

import canopen
from canopen.sdo.exceptions import SdoAbortedError
from tcms_daq.sim.instruments.drive402 import Drive402Model, DriveCommandError
from tcms_daq.sim.instruments.loop import PeriodicThread

from tcms_daq.protocols.cia402 import drive_eds_path

log = logging.getLogger(__name__)

FAULTS = ("heartbeat_loss", "mute", "garbage")
STALL_GRACE_PERIODS = 5  # a check later than this many cycle periods means the simulator itself was held up
ABORT_RANGE, ABORT_STATE, ABORT_READ_ONLY = 0x06090030, 0x08000022, 0x06010002


class DriveCanopenNode:
    name = "drive CANopen sim"

    def __init__(
        self,
        drive: Drive402Model,
        *,
        node_id: int = 1,
        heartbeat_ms: int = 100,
        tpdo_period_s: float = 0.01,
        eds: Path | str | None = None,
        **bus_options,
    ):
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id must be 1…127, got {node_id}")
        self.drive = drive
        self.node_id = node_id
        self.heartbeat_ms = int(heartbeat_ms)
        self.tpdo_period_s = float(tpdo_period_s)
        self.eds = Path(eds) if eds is not None else drive_eds_path()
        self.bus_options = bus_options
        self.fault: str | None = None
        self.network: canopen.Network | None = None
        self.node: canopen.LocalNode | None = None
        self._timer = PeriodicThread(self._cycle, self.tpdo_period_s, f"drive-canopen-{node_id}")
        self._send_lock = threading.Lock()
        # one TPDO snapshot at a time, sent before the next is taken: the event timer and the RPDO handler both
        # send, and a snapshot taken first but sent second would show the master a state the drive has left
        self._tpdo_lock = threading.Lock()
        self._consumer: tuple[int, float] | None = None  # (master node id, timeout s)
        self._master_seen: float | None = None
        self._last_cycle: float | None = None
        # what the heartbeat consumer did and when (time.monotonic(), system-wide): tests and the control channel
        self.consumer_reactions: list[dict[str, float | str]] = []
        self.rpdos_received = 0
        self._sdo_subscribed = True

    # -- lifecycle -------------------------------------------------------------------------------------

    @property
    def _net(self) -> canopen.Network:
        """The CAN network of a started node (RuntimeError before ``start``)."""
        if self.network is None:
            raise RuntimeError("the simulated CANopen node is not started")
        return self.network

    def start(self) -> None:
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1  # receive-thread poll period: bounds how long stop() waits for it
        network.connect(**self.bus_options)
        node = canopen.LocalNode(self.node_id, canopen.import_od(str(self.eds), self.node_id))
        network.add_node(node)
        node.data_store.setdefault(0x1017, {})[0] = struct.pack("<H", self.heartbeat_ms)
        node.add_read_callback(self._on_sdo_read)
        node.add_write_callback(self._on_sdo_write)
        node.tpdo.read(from_od=True)
        node.rpdo.read(from_od=True)
        node.rpdo[1].add_callback(self._on_rpdo)
        self.network, self.node = network, node
        self._sdo_subscribed = True
        self.drive.add_emcy_listener(self._on_emcy)
        network.send_message(0x700 + self.node_id, bytes([0x00]))  # boot-up
        node.nmt.state = "PRE-OPERATIONAL"  # INITIALISING -> PRE-OP: the heartbeat producer starts
        self._timer.start()

    def stop(self) -> None:
        self._timer.stop()
        self.drive.remove_emcy_listener(self._on_emcy)
        if self.node is not None:
            self.node.nmt.stop_heartbeat()
        if self.network is not None:
            try:
                self.network.disconnect()
            except Exception as exc:  # noqa: BLE001 - best effort at shutdown
                log.debug("disconnect: %s", exc)
        self.network = self.node = None
        self._consumer = None
        self._master_seen = None

    def restart(self) -> None:
        """Power-cycle the drive: the model and the node (NMT state, heartbeat, consumer) start from scratch."""
        self.stop()
        self.drive.power_cycle()
        self.start()

    def inject(self, fault: str | None) -> None:
        if fault is not None and fault not in FAULTS:
            raise ValueError(f"{self.name}: unknown fault {fault!r} (known: {', '.join(FAULTS)})")
        self.fault = fault
        node = self.node
        if node is None:
            return
        if fault in ("heartbeat_loss", "mute"):
            node.nmt.stop_heartbeat()
        elif fault is None:
            node.nmt.start_heartbeat(self.heartbeat_ms)
        # a mute node does not answer SDO requests at all (the client times out)
        sdo_subscribed = self._sdo_subscribed
        if fault == "mute" and sdo_subscribed:
            self._net.unsubscribe(node.sdo.rx_cobid, node.sdo.on_request)
            self._sdo_subscribed = False
        elif fault != "mute" and not sdo_subscribed:
            self._net.subscribe(node.sdo.rx_cobid, node.sdo.on_request)
            self._sdo_subscribed = True

    # -- SDO -------------------------------------------------------------------------------------------

    def _on_sdo_read(self, index: int, subindex: int, od):
        d = self.drive
        with d.lock:
            getter = d.od_getters().get(index)
            return getter() if getter is not None else None

    def _on_sdo_write(self, index: int, subindex: int, od, data: bytes) -> None:
        setters = self.drive.od_setters()
        if index == 0x1016 and subindex == 1:
            value = od.decode_raw(data)
            master, time_ms = (value >> 16) & 0x7F, value & 0xFFFF
            self._consumer = (master, time_ms / 1000.0) if master and time_ms else None
            self._master_seen = None
            if self._consumer:
                self._net.subscribe(0x700 + master, self._on_master_heartbeat)
            return
        setter = setters.get(index)
        if setter is None:
            return  # plain OD entries (0x1017 is handled by the NMT slave)
        try:
            setter(od.decode_raw(data))
        except DriveCommandError as exc:
            raise SdoAbortedError(ABORT_STATE if exc.kind == "state" else ABORT_RANGE) from None

    # -- PDO, heartbeat, EMCY --------------------------------------------------------------------------

    def _on_rpdo(self, pdo_map) -> None:
        node = self.node
        if node is None or node.nmt.state != "OPERATIONAL" or self.fault == "mute":
            return
        self.rpdos_received += 1
        controlword, target = (var.raw for var in pdo_map.map[:2])
        self.drive.write_rpdo(controlword, target)
        self._send_tpdos()

    def _on_master_heartbeat(self, can_id, data, timestamp) -> None:
        self._master_seen = time.monotonic()

    def _on_emcy(self, code: int, register: int) -> None:
        node = self.node
        if node is None or self.fault == "mute":
            return
        with self._send_lock:
            node.emcy.send(code, register)

    def _send_tpdos(self) -> None:
        node = self.node
        if node is None or node.nmt.state != "OPERATIONAL" or self.fault == "mute":
            return
        d = self.drive
        with self._tpdo_lock:
            values = d.process_values()
            with self._send_lock:
                tpdo1, tpdo2 = node.tpdo[1], node.tpdo[2]
                if self.fault == "garbage":
                    self._net.send_message(tpdo1.cob_id, b"\xde\xad\x01")
                    return
                for tpdo in (tpdo1, tpdo2):
                    for var in tpdo.map:
                        var.raw = values[var.index]
                tpdo1.transmit()
                tpdo2.transmit()

    def _cycle(self) -> None:
        """Every event-timer period: the TPDOs, and the heartbeat consumer's check of the master."""
        try:
            self._send_tpdos()
            now = time.monotonic()
            last, self._last_cycle = self._last_cycle, now
            stalled_s = 0.0 if last is None else now - last - STALL_GRACE_PERIODS * self.tpdo_period_s
            consumer, seen = self._consumer, self._master_seen
            if seen is not None and stalled_s > 0:
                seen = self._master_seen = seen + stalled_s  # the simulator was not running: not the master's silence
            if consumer and seen is not None and now - seen > consumer[1]:
                self._master_seen = None  # one reaction per loss
                reaction = self.drive.communication_lost()
                if reaction is not None:
                    self.consumer_reactions.append({"reaction": reaction, "at_monotonic_s": now,
                                                    "silent_s": now - seen})
        except Exception as exc:  # noqa: BLE001 - keep the node alive; the bus may be reconnecting
            log.debug("drive CANopen sim cycle: %s", exc)
