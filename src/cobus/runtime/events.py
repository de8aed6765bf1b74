"""Events the runtime itself reports: the state of the bus and of the transmit path."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from cobus.proto import Event

__all__ = [
    "BusErrorFrame",
    "BusState",
    "BusStateChanged",
    "HandlerFailed",
    "ReceiveFailed",
    "RxOverflow",
    "TxBufferOverflow",
    "TxQueueFull",
    "TxResumed",
]


class BusState(enum.Enum):
    """The CAN controller's fault confinement state (ISO 11898-1)."""

    ACTIVE = "error-active"
    WARNING = "warning"
    PASSIVE = "error-passive"
    BUS_OFF = "bus-off"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True, slots=True)
class BusStateChanged(Event):
    """The controller moved to another fault confinement state."""

    old: BusState
    new: BusState
    tx_errors: int | None = None
    rx_errors: int | None = None


@dataclass(frozen=True, slots=True)
class BusErrorFrame(Event):
    """An error frame reported by the interface, decoded (SocketCAN error classes)."""

    classes: tuple[str, ...]
    data: bytes


@dataclass(frozen=True, slots=True)
class RxOverflow(Event):
    """The controller or driver lost received frames because its buffer overflowed."""


@dataclass(frozen=True, slots=True)
class TxBufferOverflow(Event):
    """The controller or driver dropped frames to transmit because its buffer overflowed."""


@dataclass(frozen=True, slots=True)
class TxQueueFull(Event):
    """The interface refused a frame (transmit buffer full, bus-off...).

    The frame is kept in the runtime's backlog and sent when the interface accepts frames again;
    ``backlog`` is how many frames are waiting.
    """

    backlog: int
    reason: str


@dataclass(frozen=True, slots=True)
class TxResumed(Event):
    """The interface accepts frames again; the backlog has been sent."""


@dataclass(frozen=True, slots=True)
class ReceiveFailed(Event):
    """Reading from the interface failed; the runtime keeps trying."""

    reason: str


@dataclass(frozen=True, slots=True)
class HandlerFailed(Event):
    """A frame handler or event listener raised. The runtime logged it and went on."""

    where: str
    error: str
