"""Events a device reports to its application.

Every event names the device by ``node_id`` (several devices may share a network) and goes to
the device's listeners (:meth:`Device.add_listener`) and to the network's
(:meth:`AsyncNetwork.add_listener`).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from cobus._moved import Renamed, renamed_names
from cobus.proto import Event
from cobus.proto.nmt import NmtCommand, NmtState

__all__ = [
    "BitRateSwitched",
    "Booted",
    "ConfigurationProblem",
    "DeviceEvent",
    "EmergencySent",
    "EntryWritten",
    "HeartbeatLost",
    "HeartbeatRestored",
    "LifeGuardingLost",
    "LifeGuardingRestored",
    "LssBitTimingConfigured",
    "LssConfigurationStored",
    "LssNodeIdConfigured",
    "LssStoreFailed",
    "NmtCommandReceived",
    "NodeIdChanged",
    "ParametersRestored",
    "ParametersStored",
    "RpdoLost",
    "RpdoReceived",
    "RpdoRestored",
    "StateChanged",
    "StorageProblem",
    "SyncLost",
    "SyncRestored",
    "TimeReceived",
    "WrongLengthRpdoReceived",
]


@dataclass(frozen=True, slots=True)
class DeviceEvent(Event):
    """Base class of every device event; ``node_id`` is the device's node-ID."""

    node_id: int


@dataclass(frozen=True, slots=True)
class Booted(DeviceEvent):
    """The device sent its boot-up message and is pre-operational."""


@dataclass(frozen=True, slots=True)
class StateChanged(DeviceEvent):
    """The NMT state of the device changed from ``old`` to ``new``."""

    old: NmtState
    new: NmtState


@dataclass(frozen=True, slots=True)
class NmtCommandReceived(DeviceEvent):
    """An NMT command addressed to the device arrived (the indication of CiA 301): start,
    stop, enter pre-operational, reset node, reset communication.

    It is reported before the command takes effect, so a listener of RESET_NODE still sees
    the application values that are about to return to their power-on values."""

    command: NmtCommand


@dataclass(frozen=True, slots=True)
class EntryWritten(DeviceEvent):
    """A master wrote ``value`` into ``index:subindex`` by SDO (already stored)."""

    index: int
    subindex: int
    value: Any


@dataclass(frozen=True, slots=True)
class RpdoReceived(DeviceEvent):
    """RPDO ``number`` was applied: ``entries`` ``(index, subindex)`` got ``values``."""

    number: int
    entries: tuple[tuple[int, int], ...]
    values: tuple[Any, ...]


@dataclass(frozen=True, slots=True)
class RpdoLost(DeviceEvent):
    """RPDO ``number`` did not arrive within its event timer (EMCY 8250h was sent)."""

    number: int
    cob_id: int


@dataclass(frozen=True, slots=True)
class RpdoRestored(DeviceEvent):
    """RPDO ``number`` arrives again after :class:`RpdoLost`."""

    number: int
    cob_id: int


@dataclass(frozen=True, slots=True)
class WrongLengthRpdoReceived(DeviceEvent):
    """RPDO ``number`` came with ``received`` bytes where its mapping takes ``expected``
    (an event, named as one: it was ``PdoLengthError``, the name of proto's exception).

    Shorter: not processed, EMCY 8210h; longer: processed, EMCY 8220h."""

    number: int
    expected: int
    received: int


@dataclass(frozen=True, slots=True)
class HeartbeatLost(DeviceEvent):
    """The heartbeat of ``producer`` (watched through 1016h) timed out; EMCY 8130h was sent."""

    producer: int


@dataclass(frozen=True, slots=True)
class HeartbeatRestored(DeviceEvent):
    """The heartbeat of ``producer`` arrives again, reporting ``state``."""

    producer: int
    state: NmtState


@dataclass(frozen=True, slots=True)
class LifeGuardingLost(DeviceEvent):
    """The master stopped guarding within 100Ch x 100Dh; EMCY 8130h was sent."""


@dataclass(frozen=True, slots=True)
class LifeGuardingRestored(DeviceEvent):
    """Guarding requests arrive again after :class:`LifeGuardingLost`."""


@dataclass(frozen=True, slots=True)
class SyncLost(DeviceEvent):
    """No SYNC within 1.5 x the communication cycle period 1006h; EMCY 8100h was sent."""


@dataclass(frozen=True, slots=True)
class SyncRestored(DeviceEvent):
    """SYNC arrives again after :class:`SyncLost`."""


@dataclass(frozen=True, slots=True)
class TimeReceived(DeviceEvent):
    """A TIME stamp arrived (1012h bit 31 set): ``when`` in UTC."""

    when: datetime


@dataclass(frozen=True, slots=True)
class EmergencySent(DeviceEvent):
    """The device reported an emergency (sent now, after the inhibit time, or only recorded
    in 1003h when the NMT state forbids EMCY)."""

    code: int
    register: int
    manufacturer_data: bytes
    #: Deprecated name of :attr:`manufacturer_data` (as :class:`~cobus.proto.emcy.Emergency`
    #: has it); goes in the next release.
    manufacturer = Renamed("manufacturer_data")


@dataclass(frozen=True, slots=True)
class ParametersStored(DeviceEvent):
    """1010h sub ``subindex`` (1 all, 2 communication, 3 application) was saved."""

    subindex: int


@dataclass(frozen=True, slots=True)
class ParametersRestored(DeviceEvent):
    """1011h sub ``subindex``: the stored parameters were dropped; the defaults apply from the
    next reset (node, or communication for the communication parameters)."""

    subindex: int


@dataclass(frozen=True, slots=True)
class StorageProblem(DeviceEvent):
    """A stored parameter could not be applied (``reason`` says which and why); the device
    uses the power-on value of that entry instead."""

    reason: str


@dataclass(frozen=True, slots=True)
class ConfigurationProblem(DeviceEvent):
    """A communication parameter of the dictionary cannot be used (e.g. a default PDO
    mapping of an object that is not mappable): ``reason`` says which; that service (the
    PDO, the SYNC consumer...) stays off until the parameter is corrected by SDO."""

    reason: str


@dataclass(frozen=True, slots=True)
class NodeIdChanged(DeviceEvent):
    """The device changed its node-ID from ``old`` to ``node_id`` (FFh: it has none now and
    answers LSS only, until a master gives it one)."""

    old: int


@dataclass(frozen=True, slots=True)
class LssNodeIdConfigured(DeviceEvent):
    """An LSS master configured node-ID ``pending`` (FFh: none): the device takes it at the
    next reset of its communication, or at once when it had none and the master switches it
    back to waiting."""

    pending: int


@dataclass(frozen=True, slots=True)
class LssBitTimingConfigured(DeviceEvent):
    """An LSS master configured bit timing ``index`` of CiA 305's table (``kbits``; None:
    automatic detection): the device switches when the master activates it."""

    index: int
    kbits: int | None


@dataclass(frozen=True, slots=True)
class BitRateSwitched(DeviceEvent):
    """The device switched to bit timing ``index`` (``kbits``) when an LSS master activated
    it, one switch delay after the command."""

    index: int
    kbits: int | None


@dataclass(frozen=True, slots=True)
class LssConfigurationStored(DeviceEvent):
    """The device stored the node-ID ``pending`` and bit timing ``bit_timing`` (None: the one
    stored before) an LSS master configured: it starts with them from now on."""

    pending: int
    bit_timing: int | None


@dataclass(frozen=True, slots=True)
class LssStoreFailed(DeviceEvent):
    """An LSS master's store request failed: ``error`` 1 not supported, 2 storage media
    access error (the answer says so), ``reason`` why."""

    error: int
    reason: str


__getattr__ = renamed_names(
    __name__, {"PdoLengthError": ("WrongLengthRpdoReceived", WrongLengthRpdoReceived)}
)
