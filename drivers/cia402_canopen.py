"""CiA 402 servo loader over CANopen (canopen 2.4.1 on python-can 4.6.1): Loader.

URL: ``socketcand://host:port/channel`` (a socketcand daemon, e.g. the simulator's loopback hub) or
``virtual://channel`` (python-can's in-process virtual bus, tests). Other python-can interfaces:
``<interface>://<channel>`` (e.g. ``pcan://PCAN_USBBUS1``, ``socketcan://can0``) with ``bitrate`` given.

Sequence (CiA 301/402): wait for the drive's heartbeat → NMT pre-operational → SDO: check 0x1000 is a CiA 402
device, read the rated torque 0x6076, set the producer heartbeat 0x1017 and the drive's heartbeat consumer
0x1016 (it faults with 0x8130 when this master goes silent), upload the PDO mapping and check it (RPDO1 =
controlword + target torque, TPDO1 = statusword + torque actual + position actual, TPDO2 = mode display +
error code) → start this master's heartbeat → NMT operational. ``enable()`` writes 0x6072/0x6087/0x6060 = 4 by
SDO, reads 0x6061 back and fails loudly if the mode did not take (canopen's BaseNode402.op_mode only logs),
then walks 0x06 → 0x07 → 0x0F over RPDO1, confirming each state from TPDO1. EMCY frames are recorded; the
drive's FAULT state raises DeviceFault with the EMCY / 0x603F code.

Failures: SDO without answer → InstrumentTimeout; SDO abort → CommandRejected; TPDO of the wrong length →
MalformedReply; no heartbeat for ``heartbeat_timeout_s`` (or a broken socketcand link) → a bounded reconnect
(``reconnect_attempts`` re-opens, each waiting at most ``reconnect_timeout_s`` for the drive's heartbeat), then
Disconnected. Once that bound is spent the link counts as lost: every later call re-probes once, waiting only
``heartbeat_timeout_s`` for a heartbeat, so a dead drive costs each call a short wait, not the whole bound again,
and a drive that comes back is configured again on the next call. Every method on a lost link (or before
``connect()``/after ``close()``) raises Disconnected naming the instrument; ``disable()`` and ``quick_stop()``
with the heartbeat gone but the bus still open send their frames anyway (the drive may still hear them) and
then raise Disconnected, since nothing confirms them. A boot-up message (the drive restarted) makes the
driver configure the drive again. The Loader logic itself (state walk, scaling, ramp-down) is
``drivers.cia402.CiA402Loader``; this module supplies the CANopen primitives.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import can
import canopen
from can.broadcastmanager import ThreadBasedCyclicSendTask
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from tcms_daq.drivers.base import Clock, CommandRejected, Disconnected, InstrumentTimeout, MalformedReply
from tcms_daq.drivers.cia402 import CiA402Loader
from tcms_daq.drivers.timebase import REAL_TIME, Timebase

from tcms_daq.errors import ConfigError
from tcms_daq.protocols.cia402 import (
    CW_DISABLE_VOLTAGE,
    MIN_HEARTBEAT_CONSUMER_PERIODS,
    drive_eds_path,
    heartbeat_consumer_timeout_ms,
    to_int16,
)

log = logging.getLogger(__name__)


class _QuietStreamSplits(logging.Filter):
    """python-can's socketcand client warns whenever a TCP read ends inside a frame text; that is normal
    stream behaviour (it waits for the rest), not a fault worth a warning on every run."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "incomplete message" not in record.getMessage()


logging.getLogger("can.interfaces.socketcand.socketcand").addFilter(_QuietStreamSplits())

DEVICE_TYPE_402 = 0x0192  # low word of 0x1000
LINK_ERROR_BACKOFF_S = 0.1  # the receive thread's pause after a failed bus read
SOCKETCAND_HANDSHAKE_ATTEMPTS = 3  # connects tried when python-can's socketcand handshake meets bus traffic
TPDO1_MAP = [(0x6041, 16), (0x6077, 16), (0x6064, 32)]
TPDO2_MAP = [(0x6061, 8), (0x603F, 16)]
RPDO1_MAP = [(0x6040, 16), (0x6071, 16)]
SETTING_OBJECTS = {"max_torque": 0x6072, "torque_slope": 0x6087, "mode": 0x6060,  # CiA402Loader settings
                   "target_position": 0x607A, "profile_velocity": 0x6081}


class _LinkErrorListener(can.Listener):
    """Hands the receive thread's read errors to the driver (python-can calls ``on_error`` of its listeners and
    keeps the thread alive when one handled it)."""

    def __init__(self, on_error: Callable[[Exception], None]):
        self._handle = on_error

    def on_message_received(self, msg: can.Message) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        self._handle(exc)


#: python-can interfaces of real CAN adapters a loader URL may name (``pcan://PCAN_USBBUS1``); network-based
#: software buses other than socketcand are refused: they are not confined to the bench's loopback or bus.
HARDWARE_CAN_INTERFACES = frozenset({
    "socketcan", "pcan", "kvaser", "ixxat", "vector", "slcan", "gs_usb", "nican", "nixnet", "canalystii",
    "seeedstudio", "systec", "usb2can", "neovi", "etas", "cantact", "robotell", "serial",
})


def parse_can_url(url: str, bitrate: int | None = None) -> dict[str, Any]:
    """python-can bus options for a loader URL (see module doc)."""
    parsed = urlparse(url)
    if parsed.scheme == "socketcand":
        channel = parsed.path.strip("/")
        if not (parsed.hostname and parsed.port and channel):
            raise ConfigError(f"CAN URL {url!r}: expected socketcand://host:port/channel")
        return {"interface": "socketcand", "host": parsed.hostname, "port": parsed.port, "channel": channel}
    if parsed.scheme == "virtual":
        channel = (parsed.netloc + parsed.path).strip("/")
        if not channel:
            raise ConfigError(f"CAN URL {url!r}: expected virtual://channel")
        return {"interface": "virtual", "channel": channel}
    if parsed.scheme and parsed.scheme not in HARDWARE_CAN_INTERFACES:
        raise ConfigError(f"CAN URL {url!r}: unsupported CAN interface {parsed.scheme!r} (use socketcand://, "
                          f"virtual:// or a CAN adapter: {', '.join(sorted(HARDWARE_CAN_INTERFACES))})")
    if parsed.scheme and (parsed.netloc or parsed.path):
        options: dict[str, Any] = {"interface": parsed.scheme, "channel": (parsed.netloc + parsed.path).strip("/")}
        if bitrate:
            options["bitrate"] = bitrate
        return options
    raise ConfigError(f"CAN URL {url!r}: expected socketcand://host:port/channel or virtual://channel")


class CiA402Canopen(CiA402Loader):
    """Loader: a CiA 402 drive in profile torque mode over CANopen (SDO configuration, PDO process data)."""

    def __init__(
        self,
        url: str,
        *,
        name: str = "CiA 402 drive (CANopen)",
        node_id: int = 1,
        master_node_id: int = 0x7F,
        eds: str | Path | None = None,
        bitrate: int | None = None,
        max_torque_nm: float | None = None,
        torque_slope_nm_per_s: float = 200.0,
        sdo_timeout_s: float = 1.0,
        heartbeat_ms: int = 100,
        heartbeat_timeout_s: float | None = None,
        master_heartbeat_ms: int = 100,
        drive_consumer_timeout_ms: int | None = None,
        state_timeout_s: float = 2.0,
        connect_timeout_s: float = 2.0,
        reconnect_attempts: int = 2,
        reconnect_timeout_s: float | None = None,
        clock: Clock = time.monotonic,
        timebase: Timebase = REAL_TIME,
        counts_per_rev: int = 1 << 20,
        move_torque_window_nm: float | None = None,
    ):
        if not 1 <= node_id <= 127 or not 1 <= master_node_id <= 127 or node_id == master_node_id:
            raise ValueError(f"{name}: node ids must be 1…127 and differ (drive {node_id}, master {master_node_id})")
        super().__init__(name=name, max_torque_nm=max_torque_nm, torque_slope_nm_per_s=torque_slope_nm_per_s,
                         state_timeout_s=state_timeout_s, clock=clock, timebase=timebase)
        if not (isinstance(counts_per_rev, int) and counts_per_rev > 0):
            raise ValueError(f"{name}: counts_per_rev must be a positive integer, got {counts_per_rev!r}")
        self.counts_per_rev = counts_per_rev
        self.move_torque_window_nm = move_torque_window_nm
        self.url = url
        self.bus_options = parse_can_url(url, bitrate)
        self.node_id = node_id
        self.master_node_id = master_node_id
        self.eds = str(eds or drive_eds_path())
        self.sdo_timeout_s = float(sdo_timeout_s)
        self.heartbeat_ms = int(heartbeat_ms)
        self.heartbeat_timeout_s = float(heartbeat_timeout_s or max(3.5 * heartbeat_ms / 1000.0, 0.2))
        self.master_heartbeat_ms = int(master_heartbeat_ms)
        # the drive's heartbeat consumer: derived from this master's producer period with margin (a loaded host may
        # hold the producer thread up for a few periods; that must not fault the drive), 0 = off
        self.drive_consumer_timeout_ms = (heartbeat_consumer_timeout_ms(self.master_heartbeat_ms)
                                          if drive_consumer_timeout_ms is None else int(drive_consumer_timeout_ms))
        if self.drive_consumer_timeout_ms and (
                self.master_heartbeat_ms <= 0
                or self.drive_consumer_timeout_ms < MIN_HEARTBEAT_CONSUMER_PERIODS * self.master_heartbeat_ms):
            raise ValueError(f"{name}: drive_consumer_timeout_ms {self.drive_consumer_timeout_ms} must be at least "
                             f"{MIN_HEARTBEAT_CONSUMER_PERIODS} master heartbeat periods ({self.master_heartbeat_ms} ms)"
                             " with the master's heartbeat on")
        self.connect_timeout_s = float(connect_timeout_s)
        self.reconnect_attempts = int(reconnect_attempts)
        # one reconnect attempt waits this long for the drive's heartbeat (default: as long as connect() does)
        self.reconnect_timeout_s = float(reconnect_timeout_s or self.connect_timeout_s)
        if not (self.reconnect_attempts >= 1 and self.reconnect_timeout_s > 0 and self.connect_timeout_s > 0):
            raise ValueError(f"{name}: reconnect_attempts must be >= 1 and the timeouts > 0")

        self.network: canopen.Network | None = None
        self.node: canopen.RemoteNode | None = None
        self._master_heartbeat: Any = None  # python-can's periodic send task, while running
        self._cond = threading.Condition()
        self._tpdo1: tuple[int, int, int, float] | None = None  # statusword, torque ‰, position, time
        self._tpdo2: tuple[int, int] | None = None  # mode display, error code
        self._malformed: str | None = None
        self._last_heartbeat: float | None = None
        self._booted = False
        self._controlword = CW_DISABLE_VOLTAGE
        self._target_permille = 0
        self.last_emcy: tuple[int, int] | None = None  # (code, register)
        self.reconnects = 0
        self._wanted = False  # connect() was called and close() was not: reconnect on a lost link
        self._lost = False  # the bounded reconnect was spent without success: later calls only re-probe
        self._bus_error = False  # the bus reported a read/send error since it was opened
        self.late_heartbeats = 0  # the drive's heartbeat came back after a short wait, link kept (diagnostics)

    # -- link management -------------------------------------------------------------------------------

    def connect(self) -> None:
        self._open()
        try:
            self._setup(self.connect_timeout_s)
        except BaseException:
            self._teardown()
            raise
        self._wanted = True
        self._lost = False

    def close(self) -> None:
        """Leave cleanly: switch off the drive's watch on this master's heartbeat (0x1016) before going quiet,
        so a drive that is later commanded another way (e.g. Modbus) does not fault with 0x8130."""
        self._wanted = False
        self._lost = False
        if self.node is not None and self.drive_consumer_timeout_ms > 0 and self._heartbeat_alive():
            try:
                self._sdo_write(0x1016, 0, subindex=1)
            except (InstrumentTimeout, CommandRejected, Disconnected) as exc:
                log.debug("%s: clearing the heartbeat consumer: %s", self.name, exc)
        self._teardown()

    def _open(self) -> None:
        options = dict(self.bus_options)
        if options["interface"] == "socketcand":
            # python-can retries a refused connection for 10 s in a busy loop: probe first, fail fast
            try:
                socket.create_connection((options["host"], options["port"]), timeout=self.connect_timeout_s).close()
            except OSError as exc:
                raise Disconnected(self.name, f"socketcand at {options['host']}:{options['port']}: {exc}") from None
            options.setdefault("tcp_tune", True)
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1  # receive-thread poll period: bounds how long close() waits for it
        # without a listener's on_error, python-can's receive thread dies with the CanError of a lost link
        network.listeners.append(_LinkErrorListener(self._on_link_error))  # type: ignore[arg-type]  # any can.Listener
        for attempt in range(SOCKETCAND_HANDSHAKE_ATTEMPTS if options["interface"] == "socketcand" else 1):
            try:
                network.connect(**options)
                break
            except can.CanError as exc:
                # python-can's socketcand client reads the handshake's "< ok >" with one recv(): on a busy bus the
                # first frames can arrive in the same read and fail the handshake; a second connect succeeds
                if "Expected '< ok >'" in str(exc) and attempt + 1 < SOCKETCAND_HANDSHAKE_ATTEMPTS:
                    log.debug("%s: socketcand handshake met bus traffic, connecting again: %s", self.name, exc)
                    network.disconnect()
                    continue
                raise Disconnected(self.name, f"cannot open CAN bus {self.url}: {exc}") from None
            except (OSError, TimeoutError, ValueError) as exc:
                raise Disconnected(self.name, f"cannot open CAN bus {self.url}: {exc}") from None
        node = canopen.RemoteNode(self.node_id, self.eds)
        node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout_s  # canopen's 0.3 s default is flaky on a loaded CI
        node.sdo.MAX_RETRIES = 1
        network.add_node(node)
        node.nmt.add_heartbeat_callback(self._on_heartbeat)
        node.emcy.add_callback(self._on_emcy)
        self.network, self.node = network, node
        self._bus_error = False

    def _start_master_heartbeat(self) -> None:
        """This master's heartbeat producer on its own thread (python-can's cyclic task, catching up after a stall),
        started once the drive's heartbeat was seen and its consumer armed, running until the link is torn down.
        A link declared lost stays torn down until the drive is heard again: this master then falls silent on
        purpose, and the drive's consumer stops the drive by itself."""
        network = self.network
        if self.master_heartbeat_ms <= 0 or network is None or network.bus is None:
            return
        task = self._master_heartbeat
        if task is not None and not getattr(task, "stopped", False):
            return
        message = can.Message(arbitration_id=0x700 + self.master_node_id, data=[0x05], is_extended_id=False)
        self._master_heartbeat = ThreadBasedCyclicSendTask(
            network.bus, network.send_lock, message, self.master_heartbeat_ms / 1000.0,
            on_error=self._on_producer_error,
        )

    def _on_producer_error(self, exc: Exception) -> bool:
        """A failed heartbeat send stops the producer (python-can logs it); the next command restarts it on a bus
        that is still open, or reconnects."""
        self._bus_error = True
        return False

    def _teardown(self) -> None:
        task, self._master_heartbeat = self._master_heartbeat, None
        if task is not None:
            try:
                task.stop()
            except Exception:  # noqa: BLE001
                pass
        network, self.network, self.node = self.network, None, None
        if network is not None:
            try:
                network.disconnect()
            except Exception as exc:  # noqa: BLE001 - the bus may already be gone
                log.debug("%s: disconnect: %s", self.name, exc)
        with self._cond:
            self._tpdo1 = self._tpdo2 = None
            self._last_heartbeat = None

    def _setup(self, heartbeat_wait_s: float) -> None:
        node = self._link()
        if not self._wait_heartbeat(heartbeat_wait_s):
            raise Disconnected(self.name, f"no heartbeat from node {self.node_id} within {heartbeat_wait_s:g} s")
        self._booted = False
        self._send_nmt(lambda: setattr(node.nmt, "state", "PRE-OPERATIONAL"))
        device_type = self._sdo_read(0x1000)
        if device_type & 0xFFFF != DEVICE_TYPE_402:
            raise ConfigError(f"{self.name}: node {self.node_id} device type 0x{device_type:08X} is not CiA 402")
        self._configure_scaling(self._sdo_read(0x6076))
        self._sdo_write(0x1017, self.heartbeat_ms)
        if self.drive_consumer_timeout_ms > 0:
            self._sdo_write(0x1016, (self.master_node_id << 16) | self.drive_consumer_timeout_ms, subindex=1)
        self._read_pdo_mapping()
        self._target_permille = 0
        network = self.network
        if network is None or network.bus is None:
            raise Disconnected(self.name, "CAN bus closed during configuration")
        self._start_master_heartbeat()
        with self._cond:
            self._tpdo1 = self._tpdo2 = None  # only values sent after this (re)start count
            self._malformed = None
        self._send_nmt(lambda: setattr(node.nmt, "state", "OPERATIONAL"))
        if self._wait_tpdo(lambda sw: True, self.connect_timeout_s) is None:
            raise InstrumentTimeout(self.name, "no TPDO1 from the drive after NMT start")

    def _read_pdo_mapping(self) -> None:
        node = self._link()
        try:
            node.tpdo.read()
            node.rpdo.read()
        except SdoCommunicationError as exc:
            raise InstrumentTimeout(self.name, f"PDO configuration upload: {exc}") from None
        except SdoAbortedError as exc:
            raise CommandRejected(self.name, f"PDO configuration upload aborted: {exc}") from None
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"PDO configuration upload: {exc}") from None

        def layout(pdo_map) -> list[tuple[int, int]]:
            return [(var.index, var.length) for var in pdo_map.map]

        for label, pdo_map, expected in (("TPDO1", node.tpdo[1], TPDO1_MAP), ("TPDO2", node.tpdo[2], TPDO2_MAP),
                                         ("RPDO1", node.rpdo[1], RPDO1_MAP)):
            if layout(pdo_map) != expected:
                raise ConfigError(f"{self.name}: {label} maps {layout(pdo_map)}, expected {expected}")
        node.tpdo[1].add_callback(self._on_tpdo1)
        node.tpdo[2].add_callback(self._on_tpdo2)

    def _ensure_link(self) -> None:
        """Re-open the link (bounded) if the heartbeat is gone; re-configure a drive that booted again.

        The first loss gets ``reconnect_attempts`` attempts of up to ``reconnect_timeout_s`` each; a link already
        declared lost gets one attempt of up to ``heartbeat_timeout_s`` (enough to hear a drive that is back),
        never longer than ``reconnect_timeout_s``."""
        if not self._wanted:
            raise Disconnected(self.name, "not connected; call connect() first")
        alive = self.network is not None and self._heartbeat_alive()
        if not alive and not self._lost and self.network is not None and not self._bus_error:
            # the bus is open and healthy: a heartbeat late on a loaded machine is not a lost link. Wait one more
            # heartbeat timeout before tearing the link down (which silences this master and faults the drive)
            alive = self._wait_heartbeat(self.heartbeat_timeout_s)
            if alive:
                self.late_heartbeats += 1
                log.info("%s: the drive's heartbeat was late (> %g s); link kept", self.name, self.heartbeat_timeout_s)
        if alive and not self._booted:
            self._start_master_heartbeat()  # restarted if a send error stopped it
            return
        if alive:
            reason = "drive restarted (boot-up)"
        elif self._lost:
            reason = "link lost earlier"
        else:
            reason = f"heartbeat lost (none for {self.heartbeat_timeout_s:g} s)"
        if self._lost:
            attempts, wait_s = 1, min(self.heartbeat_timeout_s, self.reconnect_timeout_s)
        else:
            attempts, wait_s = self.reconnect_attempts, self.reconnect_timeout_s
        last: Exception | None = None
        for _attempt in range(attempts):
            try:
                if not alive:
                    self._teardown()
                    self._open()
                self._setup(wait_s)
                self.reconnects += 1
                self._lost = False
                return
            except (Disconnected, InstrumentTimeout) as exc:
                last = exc
                alive = False
        self._teardown()
        self._lost = True
        raise Disconnected(self.name, f"{reason}; {attempts} reconnect attempt{'s' if attempts > 1 else ''} "
                                      f"failed: {last}")

    def _link(self) -> canopen.RemoteNode:
        """The node of an open link, else Disconnected (never an AttributeError on a torn-down link)."""
        node = self.node
        if node is None:
            raise Disconnected(self.name, "no link to the drive (lost, reconnect failed, or not connected)")
        return node

    # -- callbacks (python-can notifier thread) --------------------------------------------------------

    def _on_link_error(self, exc: Exception) -> None:
        """The receive thread's bus read failed: the link is lost now (the next command reconnects, bounded);
        logged once per link, and the thread is slowed down instead of spinning on a dead bus."""
        self._bus_error = True
        with self._cond:
            first = self._last_heartbeat is not None
            self._last_heartbeat = None
            self._cond.notify_all()
        if first:
            log.warning("%s: CAN link lost (%s: %s); reconnecting on the next command", self.name,
                        type(exc).__name__, exc)
        time.sleep(LINK_ERROR_BACKOFF_S)  # throttles a real thread: real time

    def _on_heartbeat(self, state: int) -> None:
        with self._cond:
            self._last_heartbeat = self.timebase.now()
            if state == 0:
                self._booted = True  # boot-up: the drive lost its configuration
            self._cond.notify_all()

    def _on_emcy(self, error) -> None:
        with self._cond:
            self.last_emcy = (error.code, error.register)
            self._cond.notify_all()

    def _on_tpdo1(self, pdo_map) -> None:
        data = pdo_map.data
        with self._cond:
            if len(data) != 8:
                self._malformed = f"TPDO1 of {len(data)} bytes, expected 8: {bytes(data).hex(' ')}"
            else:
                self._tpdo1 = (pdo_map[0x6041].raw, pdo_map[0x6077].raw, pdo_map[0x6064].raw, self.timebase.now())
            self._cond.notify_all()

    def _on_tpdo2(self, pdo_map) -> None:
        data = pdo_map.data
        with self._cond:
            if len(data) != 3:
                self._malformed = f"TPDO2 of {len(data)} bytes, expected 3: {bytes(data).hex(' ')}"
            else:
                self._tpdo2 = (pdo_map[0x6061].raw, pdo_map[0x603F].raw)

    # -- primitives --------------------------------------------------------------------------------------

    def _heartbeat_alive(self) -> bool:
        with self._cond:
            last = self._last_heartbeat
        return last is not None and self.timebase.now() - last <= self.heartbeat_timeout_s

    def _time_left(self, timeout_s: float) -> Callable[[], float]:
        """s left of a wait for a frame: it ends ``timeout_s`` after now on the timebase or in real time,
        whichever comes first (a manual timebase that nobody advances cannot make it wait forever)."""
        on_timebase, in_real_time = self.timebase.now() + timeout_s, time.monotonic() + timeout_s
        return lambda: min(on_timebase - self.timebase.now(), in_real_time - time.monotonic())

    def _wait_heartbeat(self, timeout_s: float) -> bool:
        left = self._time_left(timeout_s)
        with self._cond:
            while True:
                if self._last_heartbeat is not None and self.timebase.now() - self._last_heartbeat <= self.heartbeat_timeout_s:
                    return True
                if left() <= 0:
                    return False
                self._cond.wait(min(left(), 0.05))

    def _wait_tpdo(self, predicate, timeout_s: float, after: float | None = None):
        """The first TPDO1 (newer than ``after``) whose statusword satisfies ``predicate``, or None."""
        left = self._time_left(timeout_s)
        with self._cond:
            while True:
                if self._malformed:
                    text, self._malformed = self._malformed, None
                    raise MalformedReply(self.name, text)
                tpdo = self._tpdo1
                if tpdo is not None and (after is None or tpdo[3] > after) and predicate(tpdo[0]):
                    return tpdo
                if left() <= 0:
                    return None
                self._cond.wait(min(left(), 0.05))

    def _send_nmt(self, action) -> None:
        try:
            action()
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"NMT: {exc}") from None

    def _sdo_read(self, index: int, subindex: int | None = None) -> int:
        node = self._link()
        try:
            var = node.sdo[index] if subindex is None else node.sdo[index][subindex]
            return var.raw
        except SdoCommunicationError as exc:
            raise InstrumentTimeout(self.name, f"SDO read 0x{index:04X}: {exc}") from None
        except SdoAbortedError as exc:
            raise CommandRejected(self.name, f"SDO read 0x{index:04X} aborted: {exc}") from None
        except (can.CanError, OSError, RuntimeError) as exc:  # RuntimeError: canopen's "Not connected"
            raise Disconnected(self.name, f"SDO read 0x{index:04X}: {exc}") from None

    def _sdo_write(self, index: int, value: int, subindex: int | None = None) -> None:
        node = self._link()
        try:
            var = node.sdo[index] if subindex is None else node.sdo[index][subindex]
            var.raw = value
        except SdoCommunicationError as exc:
            raise InstrumentTimeout(self.name, f"SDO write 0x{index:04X} = {value}: {exc}") from None
        except SdoAbortedError as exc:
            raise CommandRejected(self.name, f"SDO write 0x{index:04X} = {value} aborted: {exc}") from None
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"SDO write 0x{index:04X}: {exc}") from None

    def _send_rpdo(self, controlword: int, target_permille: int) -> float:
        rpdo = self._link().rpdo[1]
        rpdo[0x6040].raw = controlword
        rpdo[0x6071].raw = target_permille
        sent_at = self.timebase.now()
        try:
            rpdo.transmit()
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"RPDO1: {exc}") from None
        self._controlword, self._target_permille = controlword, target_permille
        return sent_at

    def _error_code(self) -> int:
        with self._cond:
            tpdo2, emcy = self._tpdo2, self.last_emcy
        if tpdo2 is not None and tpdo2[1]:
            return tpdo2[1]
        return emcy[0] if emcy else 0

    def _latest_tpdo(self) -> tuple[int, int, int, float]:
        """The latest TPDO1 (statusword, torque ‰, position, time), InstrumentTimeout if none or stale."""
        tpdo = self._wait_tpdo(lambda sw: True, self.state_timeout_s)
        if tpdo is None:
            raise InstrumentTimeout(self.name, "no TPDO1 from the drive")
        if self.timebase.now() - tpdo[3] > self.heartbeat_timeout_s:
            raise InstrumentTimeout(self.name, f"TPDO1 stale for {self.timebase.now() - tpdo[3]:.2f} s")
        return tpdo

    # -- CiA402Loader primitives: SDO settings, RPDO1 commands, TPDO process data ------------------------

    def _ensure_ready(self) -> None:
        self._ensure_link()

    def _stop_link_degraded(self) -> str | None:
        if self.node is None:
            self._ensure_link()
        return None if self._heartbeat_alive() else f"no heartbeat for {self.heartbeat_timeout_s:g} s"

    def _read_statusword(self) -> int:
        return self._latest_tpdo()[0]

    def _read_error_code(self) -> int:
        """The last TPDO2 / EMCY code; 0x603F by SDO when neither told it yet (e.g. just after connecting to a
        drive already in FAULT)."""
        code = self._error_code()
        if code == 0:
            try:
                code = self._sdo_read(0x603F)
            except (InstrumentTimeout, CommandRejected, Disconnected):
                pass
        return code

    def _read_torque_permille(self) -> int:
        return self._latest_tpdo()[1]

    def _read_process(self) -> tuple[int, int, int]:
        statusword, torque_permille, position, _ = self._latest_tpdo()
        return statusword, torque_permille, position

    def _read_mode_display(self) -> int:
        return to_int16(self._sdo_read(0x6061))

    def _write_setting(self, name: str, value: int) -> None:
        self._sdo_write(SETTING_OBJECTS[name], value)

    def _write_target(self, permille: int) -> None:
        self._send_rpdo(self._controlword, permille)

    def _reset_target(self) -> None:
        self._target_permille = 0  # RPDO1 carries it with the next controlword

    def _write_controlword(self, controlword: int) -> float:
        return self._send_rpdo(controlword, self._target_permille)

    def _await_statusword(self, predicate: Callable[[int], bool], since: float | None,
                          timeout_s: float) -> tuple[int | None, int]:
        tpdo = self._wait_tpdo(predicate, timeout_s, after=since)
        if tpdo is not None:
            return tpdo[0], tpdo[0]
        with self._cond:
            last = self._tpdo1[0] if self._tpdo1 else 0
        return None, last

    def fault_reset(self) -> None:
        super().fault_reset()
        with self._cond:
            self.last_emcy = None
