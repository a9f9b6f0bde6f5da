"""The small protocols every instrument driver implements, and the driver error types.

Three instrument kinds (DESIGN §1, §4): an angle source, a torque source and a loader. Drivers are synchronous
and blocking with timeouts everywhere; the acquisition layer runs them in worker threads. Every reading is
stamped at the driver with the driver's clock (``time.monotonic`` for real instruments, the simulated clock
for in-process simulated ones); the driver's own waiting (deadlines, frame ages, retry delays) runs on a
:class:`drivers.timebase.Timebase`, real time unless a test injects a manual one.

Sign conventions: positive torque twists the output in the positive angle direction. Angles in arcsec,
torque in N·m, times in s.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from tcms_daq.errors import TcmsError
from tcms_daq.samples import INPUT_ANGLE_COLUMN as _INPUT_ANGLE_COLUMN

if TYPE_CHECKING:  # the mixin below runs on a SerialInstrument's link (transport imports this module)
    from tcms_daq.drivers.transport import SerialLink

Clock = Callable[[], float]

log = logging.getLogger(__name__)


class InstrumentError(TcmsError):
    """Base of all driver failures; the message always names the instrument."""

    def __init__(self, instrument: str, message: str):
        super().__init__(f"{instrument}: {message}")
        self.instrument = instrument


class InstrumentTimeout(InstrumentError):
    """No (complete) reply within the timeout."""


class MalformedReply(InstrumentError):
    """A reply arrived but does not match the protocol's framing."""


class DeviceFault(InstrumentError):
    """The instrument reports a fault (encoder '?' unit, drive FAULT state, EMCY …)."""

    def __init__(self, instrument: str, message: str, code: int | None = None):
        super().__init__(instrument, message)
        self.code = code


class Disconnected(InstrumentError):
    """The link is down and the bounded reconnect did not bring it back."""


class CommandRejected(InstrumentError):
    """A command failed validation (limits, units) before any byte left, or the device refused it."""


@dataclass(frozen=True)
class Batch:
    """Readings of one channel: ``time_s`` stamped at the driver, ``value`` in the channel's unit, and ``extra``
    per-reading columns the acquisition carries into the samples (e.g. the ND 287's ``angle_datum``)."""

    time_s: np.ndarray
    value: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @staticmethod
    def empty() -> Batch:
        return Batch(np.empty(0), np.empty(0))

    def __len__(self) -> int:
        return len(self.time_s)


def concat_common_columns(parts: Sequence[Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The extra columns of consecutive batches joined: the columns every part has, each concatenated in order
    (a column missing from one part cannot be lined up with the readings and is left out)."""
    if not parts:
        return {}
    keys = set(parts[0]).intersection(*parts[1:])
    return {k: np.concatenate([p[k] for p in parts]) for k in sorted(keys)}


class ReinitialisedOnReconnect:
    """Mixin of a polled instrument that comes back from a power cycle with its power-on settings (the AED's
    format, scaling and tare; the ND 287's datum): the subclass's ``reinitialise()`` runs when the link was opened
    or re-opened, before the next reply counts. A re-open is the link's ``reconnects`` moving; a query that crossed
    one is re-initialised and repeated (``query_stamped``). ``power_cycles`` counts the re-initialisations after
    a re-open of a configured link: power cycles of the instrument, as far as the driver can tell (a link that
    drops and comes back is taken for one: the driver cannot tell a pulled cable from a power cycle)."""

    name: str
    clock: Clock
    link: SerialLink
    _configured_epoch: int | None = None
    power_cycles: int = 0

    def reinitialise(self) -> None:
        """Send the instrument's settings (the subclass's); raises InstrumentError when it refuses them."""
        raise NotImplementedError

    def connect(self) -> None:
        """Open the link (the next class in the MRO: the transport) and configure the instrument."""
        super().connect()  # type: ignore[misc]  # a mixin: the transport class follows it in the MRO
        self.configure()

    def close(self) -> None:
        super().close()  # type: ignore[misc]
        self.forget_configuration()

    def configure(self) -> None:
        """Re-initialise now (again if the link was re-opened half-way through) and note the link's epoch."""
        if self._configured_epoch is not None and self._configured_epoch != self.link.reconnects:
            self.power_cycles += 1
            log.warning("%s: link re-opened (power cycle %d as far as the driver can tell): re-initialising",
                        self.name, self.power_cycles)
        for _ in range(2):
            epoch = self.link.reconnects
            self.reinitialise()
            if epoch == self.link.reconnects:
                break
        self._configured_epoch = self.link.reconnects

    def forget_configuration(self) -> None:
        """The link was closed on purpose: the next connect configures afresh (not counted as a power cycle)."""
        self._configured_epoch = None

    def ensure_configured(self) -> None:
        """Configure (again) when the link was opened or re-opened since the last configuration."""
        if self._configured_epoch != self.link.reconnects:
            self.configure()

    def query_stamped(self, command: bytes, reader: Callable[[Any], bytes]) -> tuple[float, bytes]:
        """(clock time at the request, raw reply) on a configured link; a query that crossed a re-open is
        re-initialised and repeated, and stamped at the repeated request."""
        self.ensure_configured()
        epoch = self.link.reconnects
        time_s = self.clock()
        reply = self.link.exchange(command, reader)
        if epoch != self.link.reconnects:
            self.configure()
            time_s = self.clock()
            reply = self.link.exchange(command, reader)
        return time_s, reply


@dataclass(frozen=True)
class LoaderStatus:
    """A snapshot of the loader (CiA 402 drive) state.

    state: CiA 402 state name ("SWITCH ON DISABLED", "OPERATION ENABLED", "FAULT", …);
    torque_actual_nm: measured motor torque; error_code: 0x603F (0 = none); position_deg: the loader shaft's
    (the reducer output's) position from the drive's position actual 0x6064 (None: the driver cannot tell);
    moving: a profile-position move is under way (target not reached).
    """

    state: str
    torque_actual_nm: float
    fault: bool
    error_code: int = 0
    position_counts: int = 0
    time_s: float = 0.0
    position_deg: float | None = None
    moving: bool = False


@dataclass(frozen=True)
class InputDriveStatus:
    """A snapshot of the second axis's input drive (CiA 402 profile velocity).

    state: CiA 402 state name; velocity_deg_per_s: velocity actual 0x606C at the input shaft (deg/s, positive
    turning the output positive through the reducer); position_deg: position actual 0x6064 of the input shaft;
    error_code: 0x603F (0 = none); time_s: the driver clock when it was read.
    """

    state: str
    velocity_deg_per_s: float
    fault: bool
    error_code: int = 0
    position_deg: float = 0.0
    time_s: float = 0.0


@runtime_checkable
class AngleSource(Protocol):
    name: str

    def connect(self) -> None: ...

    def close(self) -> None: ...

    def read(self) -> Batch:
        """Readings (angle in arcsec) taken since the previous call; at least one for polled instruments."""
        ...


@runtime_checkable
class TorqueSource(Protocol):
    name: str

    def connect(self) -> None: ...

    def close(self) -> None: ...

    def read(self) -> Batch:
        """Readings (torque in N·m) taken since the previous call; at least one for polled instruments."""
        ...

    def tare(self) -> None:
        """Zero the torque channel at the present load."""
        ...


@runtime_checkable
class Loader(Protocol):
    name: str
    rated_torque_nm: float

    def connect(self) -> None: ...

    def close(self) -> None: ...

    def enable(self) -> None:
        """Walk the drive state machine to OPERATION ENABLED in profile torque mode (4)."""
        ...

    def disable(self) -> None:
        """Target torque 0, then leave OPERATION ENABLED (disable voltage)."""
        ...

    def set_torque(self, target_nm: float, slope_nm_per_s: float | None = None) -> None:
        """Command a target torque (validated against the limits before any byte leaves)."""
        ...

    def status(self) -> LoaderStatus: ...

    def fault_reset(self) -> None: ...


@runtime_checkable
class Positioner(Protocol):
    """A loader that can also turn the output to a position (CiA 402 profile position mode, mode 1), for tests at
    several output positions. Moves are made at zero torque only; ``enable()`` returns to profile torque."""

    def move_to(self, position_deg: float, velocity_deg_per_s: float) -> None:
        """Start a move of the output to ``position_deg`` at ``velocity_deg_per_s`` and return at once
        (``status().moving`` until it arrives). CommandRejected, nothing moved, while torque is applied."""
        ...


@runtime_checkable
class InputDrive(Protocol):
    """The second axis's input drive: turns the reducer's input at a commanded velocity (CiA 402 profile velocity,
    mode 3). Velocities in deg/s at the input shaft; every stop ramps (the drive's deceleration) before it disables."""

    name: str

    def connect(self) -> None: ...

    def close(self) -> None: ...

    def enable(self) -> None:
        """Walk the drive state machine to OPERATION ENABLED in profile velocity (3) at target velocity 0."""
        ...

    def set_velocity(self, velocity_deg_per_s: float) -> None:
        """Command a target velocity (validated against the limit before any byte leaves)."""
        ...

    def disable(self) -> None:
        """Target velocity 0, wait (bounded) for the shaft to stop, then leave OPERATION ENABLED (disable voltage)."""
        ...

    def status(self) -> InputDriveStatus: ...

    def fault_reset(self) -> None: ...


#: the extra column of an angle pair source (the counter card): the input angle (arcsec of the input shaft), beside
#: the output angle in ``Batch.value`` (one definition: ``tcms_daq.samples``)
INPUT_ANGLE_COLUMN = _INPUT_ANGLE_COLUMN
