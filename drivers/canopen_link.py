"""The CANopen link to one CiA 402 drive (canopen 2.4.1 on python-can 4.6.1), below the loader
(``drivers.cia402_canopen.CiA402Canopen``): what the drive sends by itself (:class:`DriveProcessData`: its
heartbeat, boot-up, TPDOs and EMCY, as python-can's notifier thread receives them) and the link that opens the bus,
configures the drive, keeps this master's heartbeat, speaks SDO/NMT/RPDO and re-opens a lost link within a bound
(:class:`CanopenLink`). The sequence and the failure semantics are the loader module's docstring.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
import canopen
from can.broadcastmanager import ThreadBasedCyclicSendTask
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError
from tcms_daq.drivers.base import CommandRejected, Disconnected, InstrumentTimeout, MalformedReply
from tcms_daq.drivers.options import CanopenLinkOptions
from tcms_daq.drivers.timebase import Timebase

from tcms_daq.errors import ConfigError
from tcms_daq.protocols.cia402 import CW_DISABLE_VOLTAGE

log = logging.getLogger("tcms_daq.drivers.cia402_canopen")

DEVICE_TYPE_402 = 0x0192  # low word of 0x1000
LINK_ERROR_BACKOFF_S = 0.1  # the receive thread's pause after a failed bus read
SOCKETCAND_HANDSHAKE_ATTEMPTS = 3  # connects tried when python-can's socketcand handshake meets bus traffic


@dataclass(frozen=True)
class PdoLayout:
    """What the drive's PDOs carry, as (object index, bits) in order: RPDO1 = controlword + the target (torque ‰ or
    velocity counts/s); TPDO1 = statusword + the actual of that target [+ position actual]; TPDO2 = mode display +
    error code [+ position actual, when TPDO1 has no room for it]."""

    rpdo1: tuple[tuple[int, int], ...]
    tpdo1: tuple[tuple[int, int], ...]
    tpdo2: tuple[tuple[int, int], ...]

    @property
    def target_index(self) -> int:
        return self.rpdo1[1][0]

    def length(self, pdo: str) -> int:
        """The bytes a PDO of this layout carries."""
        return sum(bits for _, bits in getattr(self, pdo)) // 8


#: the loader (profile torque): target torque 0x6071, torque actual 0x6077, position in TPDO1
TORQUE_LAYOUT = PdoLayout(rpdo1=((0x6040, 16), (0x6071, 16)), tpdo1=((0x6041, 16), (0x6077, 16), (0x6064, 32)),
                          tpdo2=((0x6061, 8), (0x603F, 16)))
#: the input drive (profile velocity): target velocity 0x60FF, velocity actual 0x606C, position in TPDO2
VELOCITY_LAYOUT = PdoLayout(rpdo1=((0x6040, 16), (0x60FF, 32)), tpdo1=((0x6041, 16), (0x606C, 32)),
                            tpdo2=((0x6061, 8), (0x603F, 16), (0x6064, 32)))
TPDO1_MAP = list(TORQUE_LAYOUT.tpdo1)
TPDO2_MAP = list(TORQUE_LAYOUT.tpdo2)
RPDO1_MAP = list(TORQUE_LAYOUT.rpdo1)

#: TPDO1 as received: statusword, the actual (torque ‰ or velocity counts/s), position actual counts, time
#: (timebase s)
Tpdo1 = tuple[int, int, int, float]


class _LinkErrorListener(can.Listener):
    """Hands the receive thread's read errors to the link (python-can calls ``on_error`` of its listeners and
    keeps the thread alive when one handled it)."""

    def __init__(self, on_error: Callable[[Exception], None]):
        self._handle = on_error

    def on_message_received(self, msg: can.Message) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        self._handle(exc)


class DriveProcessData:
    """What the drive sends by itself — heartbeat (and boot-up), TPDO1, TPDO2, EMCY — under one condition, written
    by python-can's notifier thread and waited for by the caller's. Times on ``timebase``; a wait also ends after
    as long in real time (a manual timebase nobody advances cannot make it wait forever)."""

    def __init__(self, name: str, timebase: Timebase, heartbeat_timeout_s: float,
                 layout: PdoLayout = TORQUE_LAYOUT):
        self.name = name
        self.layout = layout
        self.position = 0  # position actual from TPDO2, for a layout whose TPDO1 has no room for it
        self.timebase = timebase
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.cond = threading.Condition()
        self.tpdo1: Tpdo1 | None = None
        self.tpdo2: tuple[int, int] | None = None  # mode display, error code
        self.malformed: str | None = None
        self.last_heartbeat: float | None = None
        self.booted = False  # a boot-up message came: the drive lost its configuration
        self.last_emcy: tuple[int, int] | None = None  # (code, register)

    # -- python-can notifier thread ----------------------------------------------------------------------

    def on_heartbeat(self, state: int) -> None:
        with self.cond:
            self.last_heartbeat = self.timebase.now()
            if state == 0:
                self.booted = True
            self.cond.notify_all()

    def on_emcy(self, error: Any) -> None:
        with self.cond:
            self.last_emcy = (error.code, error.register)
            self.cond.notify_all()

    def on_tpdo1(self, pdo_map: Any) -> None:
        data, layout = pdo_map.data, self.layout
        with self.cond:
            if len(data) != layout.length("tpdo1"):
                self.malformed = (f"TPDO1 of {len(data)} bytes, expected {layout.length('tpdo1')}: "
                                  f"{bytes(data).hex(' ')}")
            else:
                values = [pdo_map[index].raw for index, _ in layout.tpdo1]
                position = values[2] if len(values) > 2 else self.position
                self.tpdo1 = (values[0], values[1], position, self.timebase.now())
            self.cond.notify_all()

    def on_tpdo2(self, pdo_map: Any) -> None:
        data, layout = pdo_map.data, self.layout
        with self.cond:
            if len(data) != layout.length("tpdo2"):
                self.malformed = (f"TPDO2 of {len(data)} bytes, expected {layout.length('tpdo2')}: "
                                  f"{bytes(data).hex(' ')}")
            else:
                values = [pdo_map[index].raw for index, _ in layout.tpdo2]
                self.tpdo2 = (values[0], values[1])
                if len(values) > 2:
                    self.position = values[2]

    def lose_heartbeat(self) -> bool:
        """The link failed: no heartbeat counts any more (waiters wake up). True when one counted until now."""
        with self.cond:
            had = self.last_heartbeat is not None
            self.last_heartbeat = None
            self.cond.notify_all()
        return had

    def forget_link(self) -> None:
        """The link was torn down: nothing seen on it counts any more."""
        with self.cond:
            self.tpdo1 = self.tpdo2 = None
            self.last_heartbeat = None

    def restart(self) -> None:
        """The drive was (re)started: only process data sent after this counts."""
        with self.cond:
            self.tpdo1 = self.tpdo2 = None
            self.malformed = None

    # -- the caller's side -------------------------------------------------------------------------------

    def heartbeat_alive(self) -> bool:
        with self.cond:
            last = self.last_heartbeat
        return last is not None and self.timebase.now() - last <= self.heartbeat_timeout_s

    def _time_left(self, timeout_s: float) -> Callable[[], float]:
        on_timebase, in_real_time = self.timebase.now() + timeout_s, time.monotonic() + timeout_s
        return lambda: min(on_timebase - self.timebase.now(), in_real_time - time.monotonic())

    def wait_heartbeat(self, timeout_s: float) -> bool:
        left = self._time_left(timeout_s)
        with self.cond:
            while True:
                last = self.last_heartbeat
                if last is not None and self.timebase.now() - last <= self.heartbeat_timeout_s:
                    return True
                if left() <= 0:
                    return False
                self.cond.wait(min(left(), 0.05))

    def wait_tpdo(self, predicate: Callable[[int], bool], timeout_s: float, after: float | None = None
                  ) -> Tpdo1 | None:
        """The first TPDO1 (newer than ``after``) whose statusword satisfies ``predicate``, or None;
        MalformedReply for a TPDO of the wrong length."""
        left = self._time_left(timeout_s)
        with self.cond:
            while True:
                if self.malformed:
                    text, self.malformed = self.malformed, None
                    raise MalformedReply(self.name, text)
                tpdo = self.tpdo1
                if tpdo is not None and (after is None or tpdo[3] > after) and predicate(tpdo[0]):
                    return tpdo
                if left() <= 0:
                    return None
                self.cond.wait(min(left(), 0.05))

    def error_code(self) -> int:
        """The last TPDO2 error code, else the last EMCY's, else 0."""
        with self.cond:
            tpdo2, emcy = self.tpdo2, self.last_emcy
        if tpdo2 is not None and tpdo2[1]:
            return tpdo2[1]
        return emcy[0] if emcy else 0


class CanopenLink:
    """The bus and the drive's node: open, configure (CiA 301/402 sequence), this master's heartbeat producer,
    SDO/NMT/RPDO with the driver's error types, and the bounded reconnect of a lost link. ``configure_scaling``
    gets the drive's rated torque 0x6076 (mN·m) at each configuration."""

    def __init__(self, options: CanopenLinkOptions, bus_options: dict[str, Any], eds: str, timebase: Timebase,
                 configure_scaling: Callable[[int], None], layout: PdoLayout = TORQUE_LAYOUT):
        self.name = options.name
        self.url = options.url
        self.bus_options = bus_options
        self.node_id = options.node_id
        self.master_node_id = options.master_node_id
        self.eds = eds
        self.sdo_timeout_s = options.sdo_timeout_s
        self.heartbeat_ms = options.heartbeat_ms
        self.heartbeat_timeout_s = options.link_timeout_s
        self.master_heartbeat_ms = options.master_heartbeat_ms
        self.drive_consumer_timeout_ms = options.consumer_timeout_ms
        self.connect_timeout_s = options.connect_timeout_s
        self.reconnect_attempts = options.reconnect_attempts
        # one reconnect attempt waits this long for the drive's heartbeat (default: as long as connect() does)
        self.reconnect_timeout_s = options.reconnect_timeout_s or options.connect_timeout_s
        self.timebase = timebase
        self._configure_scaling = configure_scaling
        self.layout = layout
        self.process = DriveProcessData(self.name, timebase, self.heartbeat_timeout_s, layout)
        self.network: canopen.Network | None = None
        self.node: canopen.RemoteNode | None = None
        self._master_heartbeat: Any = None  # python-can's periodic send task, while running
        self.controlword = CW_DISABLE_VOLTAGE  # RPDO1 as last sent (a target goes out with the controlword)
        self.target_permille = 0
        self.reconnects = 0
        self.wanted = False  # connect() was called and close() was not: reconnect on a lost link
        self._lost = False  # the bounded reconnect was spent without success: later calls only re-probe
        self._bus_error = False  # the bus reported a read/send error since it was opened
        self.late_heartbeats = 0  # the drive's heartbeat came back after a short wait, link kept (diagnostics)

    def connect(self) -> None:
        self._open()
        try:
            self._setup(self.connect_timeout_s)
        except BaseException:
            self.teardown()
            raise
        self.wanted = True
        self._lost = False

    def close(self) -> None:
        """Leave cleanly: switch off the drive's watch on this master's heartbeat (0x1016) before going quiet,
        so a drive that is later commanded another way (e.g. Modbus) does not fault with 0x8130."""
        self.wanted = False
        self._lost = False
        if self.node is not None and self.drive_consumer_timeout_ms > 0 and self.process.heartbeat_alive():
            try:
                self.sdo_write(0x1016, 0, subindex=1)
            except (InstrumentTimeout, CommandRejected, Disconnected) as exc:
                log.debug("%s: clearing the heartbeat consumer: %s", self.name, exc)
        self.teardown()

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
        node.nmt.add_heartbeat_callback(self.process.on_heartbeat)
        node.emcy.add_callback(self.process.on_emcy)
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

    def _on_link_error(self, exc: Exception) -> None:
        """The receive thread's bus read failed: the link is lost now (the next command reconnects, bounded);
        logged once per link, and the thread is slowed down instead of spinning on a dead bus."""
        self._bus_error = True
        if self.process.lose_heartbeat():
            log.warning("%s: CAN link lost (%s: %s); reconnecting on the next command", self.name,
                        type(exc).__name__, exc)
        time.sleep(LINK_ERROR_BACKOFF_S)  # throttles a real thread: real time

    def teardown(self) -> None:
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
        self.process.forget_link()

    def _setup(self, heartbeat_wait_s: float) -> None:
        node = self.link()
        if not self.process.wait_heartbeat(heartbeat_wait_s):
            raise Disconnected(self.name, f"no heartbeat from node {self.node_id} within {heartbeat_wait_s:g} s")
        self.process.booted = False
        self._send_nmt(lambda: setattr(node.nmt, "state", "PRE-OPERATIONAL"))
        device_type = self.sdo_read(0x1000)
        if device_type & 0xFFFF != DEVICE_TYPE_402:
            raise ConfigError(f"{self.name}: node {self.node_id} device type 0x{device_type:08X} is not CiA 402")
        self._configure_scaling(self.sdo_read(0x6076))
        self.sdo_write(0x1017, self.heartbeat_ms)
        # the consumer of this master's heartbeat: armed, or (0) cleared: a consumer an earlier master left armed
        # would stop the drive when this one, which asked for none, goes silent
        self.sdo_write(0x1016, (self.master_node_id << 16) | self.drive_consumer_timeout_ms
                       if self.drive_consumer_timeout_ms > 0 else 0, subindex=1)
        self._read_pdo_mapping()
        self.target_permille = 0
        network = self.network
        if network is None or network.bus is None:
            raise Disconnected(self.name, "CAN bus closed during configuration")
        self._start_master_heartbeat()
        self.process.restart()
        self._send_nmt(lambda: setattr(node.nmt, "state", "OPERATIONAL"))
        if self.process.wait_tpdo(lambda sw: True, self.connect_timeout_s) is None:
            raise InstrumentTimeout(self.name, "no TPDO1 from the drive after NMT start")

    def _read_pdo_mapping(self) -> None:
        node = self.link()
        try:
            node.tpdo.read()
            node.rpdo.read()
        except SdoCommunicationError as exc:
            raise InstrumentTimeout(self.name, f"PDO configuration upload: {exc}") from None
        except SdoAbortedError as exc:
            raise CommandRejected(self.name, f"PDO configuration upload aborted: {exc}") from None
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"PDO configuration upload: {exc}") from None

        def layout(pdo_map: Any) -> list[tuple[int, int]]:
            return [(var.index, var.length) for var in pdo_map.map]

        for label, pdo_map, expected in (("TPDO1", node.tpdo[1], list(self.layout.tpdo1)),
                                         ("TPDO2", node.tpdo[2], list(self.layout.tpdo2)),
                                         ("RPDO1", node.rpdo[1], list(self.layout.rpdo1))):
            if layout(pdo_map) != expected:
                raise ConfigError(f"{self.name}: {label} maps {layout(pdo_map)}, expected {expected}")
        node.tpdo[1].add_callback(self.process.on_tpdo1)
        node.tpdo[2].add_callback(self.process.on_tpdo2)

    def ensure(self) -> None:
        """Re-open the link (bounded) if the heartbeat is gone; re-configure a drive that booted again.

        The first loss gets ``reconnect_attempts`` attempts of up to ``reconnect_timeout_s`` each; a link already
        declared lost gets one attempt of up to ``heartbeat_timeout_s`` (enough to hear a drive that is back),
        never longer than ``reconnect_timeout_s``."""
        if not self.wanted:
            raise Disconnected(self.name, "not connected; call connect() first")
        alive = self.network is not None and self.process.heartbeat_alive()
        if not alive and not self._lost and self.network is not None and not self._bus_error:
            # the bus is open and healthy: a heartbeat late on a loaded machine is not a lost link. Wait one more
            # heartbeat timeout before tearing the link down (which silences this master and faults the drive)
            alive = self.process.wait_heartbeat(self.heartbeat_timeout_s)
            if alive:
                self.late_heartbeats += 1
                log.info("%s: the drive's heartbeat was late (> %g s); link kept", self.name, self.heartbeat_timeout_s)
        if alive and not self.process.booted:
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
                    self.teardown()
                    self._open()
                self._setup(wait_s)
                self.reconnects += 1
                self._lost = False
                return
            except (Disconnected, InstrumentTimeout) as exc:
                last = exc
                alive = False
        self.teardown()
        self._lost = True
        raise Disconnected(self.name, f"{reason}; {attempts} reconnect attempt{'s' if attempts > 1 else ''} "
                                      f"failed: {last}")

    def link(self) -> canopen.RemoteNode:
        """The node of an open link, else Disconnected (never an AttributeError on a torn-down link)."""
        node = self.node
        if node is None:
            raise Disconnected(self.name, "no link to the drive (lost, reconnect failed, or not connected)")
        return node

    # -- primitives ----------------------------------------------------------------------------------------

    def _send_nmt(self, action: Callable[[], None]) -> None:
        try:
            action()
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"NMT: {exc}") from None

    def sdo_read(self, index: int, subindex: int | None = None) -> int:
        node = self.link()
        try:
            var = node.sdo[index] if subindex is None else node.sdo[index][subindex]
            return var.raw
        except SdoCommunicationError as exc:
            raise InstrumentTimeout(self.name, f"SDO read 0x{index:04X}: {exc}") from None
        except SdoAbortedError as exc:
            raise CommandRejected(self.name, f"SDO read 0x{index:04X} aborted: {exc}") from None
        except (can.CanError, OSError, RuntimeError) as exc:  # RuntimeError: canopen's "Not connected"
            raise Disconnected(self.name, f"SDO read 0x{index:04X}: {exc}") from None

    def sdo_write(self, index: int, value: int, subindex: int | None = None) -> None:
        node = self.link()
        try:
            var = node.sdo[index] if subindex is None else node.sdo[index][subindex]
            var.raw = value
        except SdoCommunicationError as exc:
            raise InstrumentTimeout(self.name, f"SDO write 0x{index:04X} = {value}: {exc}") from None
        except SdoAbortedError as exc:
            raise CommandRejected(self.name, f"SDO write 0x{index:04X} = {value} aborted: {exc}") from None
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"SDO write 0x{index:04X}: {exc}") from None

    def send_rpdo(self, controlword: int, target_permille: int) -> float:
        """RPDO1 (controlword, target: torque ‰ or velocity counts/s as the layout says); the time it was sent on the
        timebase."""
        rpdo = self.link().rpdo[1]
        rpdo[0x6040].raw = controlword
        rpdo[self.layout.target_index].raw = target_permille
        sent_at = self.timebase.now()
        try:
            rpdo.transmit()
        except (can.CanError, OSError, RuntimeError) as exc:
            raise Disconnected(self.name, f"RPDO1: {exc}") from None
        self.controlword, self.target_permille = controlword, target_permille
        return sent_at
