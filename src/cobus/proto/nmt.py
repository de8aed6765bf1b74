"""NMT: network management commands and the slave state machine (CiA 301).

The NMT master sends ``000h [2] cs node`` (node 0 = every node). A slave boots into
pre-operational with the boot-up message ``700h+id [1] 00`` and then follows the commands
addressed to it. Which services a node may use depends on its NMT state; :meth:`NmtSlave.allowed`
answers that question for the layers above.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from cobus._enum import NamedIntEnum
from cobus._moved import renamed_names
from cobus.errors import CobusError
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.connection_set import ERROR_CONTROL_BASE, NMT_COB_ID
from cobus.proto.frame import Frame

__all__ = [
    "ERROR_CONTROL_BASE",
    "NMT_COB_ID",
    "MalformedNmt",
    "MalformedNmtError",
    "NmtCommand",
    "NmtError",
    "NmtRequest",
    "NmtSlave",
    "NmtState",
    "NmtStateChanged",
    "ResetCommunication",
    "ResetNode",
    "Service",
    "bootup_frame",
    "check_node_id",
    "nmt_command_frame",
    "parse_nmt",
]


class NmtError(CobusError, ValueError):
    """An NMT request that cannot be built or applied (bad node-ID, command or state)."""


class MalformedNmtError(NmtError):
    """A received frame on 000h that is not a valid NMT command."""


class NmtCommand(NamedIntEnum):
    """NMT command specifiers (byte 0 of the 000h frame)."""

    START = 0x01
    STOP = 0x02
    ENTER_PREOPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


class NmtState(NamedIntEnum):
    """NMT states with the codes heartbeat and node guarding report (bits 0-6)."""

    INITIALISING = 0x00
    BOOTUP = 0x00
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


class Service(Enum):
    """Communication services whose use depends on the NMT state (CiA 301 table of states)."""

    SDO = "SDO"
    PDO = "PDO"
    SYNC = "SYNC"
    TIME = "TIME"
    EMCY = "EMCY"
    ERROR_CONTROL = "error control"
    HEARTBEAT = "error control"
    NMT = "NMT"
    BOOTUP = "boot-up"


_SERVICES: dict[NmtState, frozenset[Service]] = {
    NmtState.INITIALISING: frozenset({Service.BOOTUP}),
    NmtState.PRE_OPERATIONAL: frozenset(
        {
            Service.SDO,
            Service.SYNC,
            Service.TIME,
            Service.EMCY,
            Service.ERROR_CONTROL,
            Service.NMT,
        }
    ),
    NmtState.OPERATIONAL: frozenset(
        {
            Service.SDO,
            Service.PDO,
            Service.SYNC,
            Service.TIME,
            Service.EMCY,
            Service.ERROR_CONTROL,
            Service.NMT,
        }
    ),
    NmtState.STOPPED: frozenset({Service.ERROR_CONTROL, Service.NMT}),
}

_COMMANDS: dict[int, NmtCommand] = {int(c): c for c in NmtCommand}


def check_node_id(node_id: int, *, broadcast: bool = False) -> int:
    """Return ``node_id`` if it is a valid node-ID (1..127, or 0 when ``broadcast``)."""
    low = 0 if broadcast else 1
    if not isinstance(node_id, int) or isinstance(node_id, bool) or not low <= node_id <= 127:
        allowed = "0 (all nodes) or 1..127" if broadcast else "1..127"
        raise NmtError(f"node-ID {node_id!r} is out of range: use {allowed}")
    return node_id


@dataclass(frozen=True, slots=True)
class NmtStateChanged(Event):
    """The local NMT state changed from ``old`` to ``new``."""

    old: NmtState
    new: NmtState


@dataclass(frozen=True, slots=True)
class ResetNode(Event):
    """Reset node received: reset the application and communication objects to their
    power-on values, then call :meth:`NmtSlave.boot` to send the boot-up message."""


@dataclass(frozen=True, slots=True)
class ResetCommunication(Event):
    """Reset communication received: reset 1000h-1FFFh to their power-on values, then call
    :meth:`NmtSlave.boot` to send the boot-up message."""


@dataclass(frozen=True, slots=True)
class MalformedNmt(Event):
    """A frame on 000h that is not an NMT command; ``reason`` says what is wrong with it."""

    data: bytes
    reason: str


class NmtRequest(NamedTuple):
    """A decoded NMT command: what to do and to whom (0 = every node)."""

    command: NmtCommand
    node_id: int


def nmt_command_frame(command: NmtCommand | int, node_id: int) -> Frame:
    """The ``000h [2] cs node`` frame of ``command`` for ``node_id`` (0 = all nodes)."""
    cs = _COMMANDS.get(int(command))
    if cs is None:
        known = ", ".join(f"{c.name}={c.value:02X}h" for c in NmtCommand)
        raise NmtError(f"unknown NMT command 0x{int(command):02X}: use one of {known}")
    check_node_id(node_id, broadcast=True)
    return Frame(NMT_COB_ID, bytes((cs, node_id)))


def bootup_frame(node_id: int) -> Frame:
    """The boot-up message ``700h+id [1] 00`` of ``node_id``."""
    check_node_id(node_id)
    return Frame(ERROR_CONTROL_BASE + node_id, b"\x00")


def _malformed_reason(frame: Frame) -> str | None:
    if frame.rtr:
        return "remote frame on the NMT identifier (NMT commands are data frames)"
    if len(frame.data) != 2:
        return f"NMT command with {len(frame.data)} data bytes; it must carry exactly 2"
    cs, node_id = frame.data
    if cs not in _COMMANDS:
        return f"unknown NMT command specifier 0x{cs:02X}"
    if node_id > 127:
        return f"NMT command addressed to node-ID {node_id}, outside 0..127"
    return None


def parse_nmt(frame: Frame) -> NmtRequest:
    """Decode an NMT command frame; raise :class:`MalformedNmtError` saying what is wrong."""
    if frame.cob_id != NMT_COB_ID or frame.extended:
        raise MalformedNmtError(
            f"frame {frame!r} is not on the NMT identifier 000h (11-bit); route only 000h here"
        )
    reason = _malformed_reason(frame)
    if reason is not None:
        raise MalformedNmtError(f"{frame!r}: {reason}")
    return NmtRequest(_COMMANDS[frame.data[0]], frame.data[1])


class NmtSlave:
    """The NMT state machine of one node (sans-I/O).

    Start with :meth:`boot`. Commands received with :meth:`on_frame` (or applied locally with
    :meth:`apply`) move the state and report :class:`NmtStateChanged`. A reset command reports
    :class:`ResetNode` or :class:`ResetCommunication` and leaves the node in initialisation:
    the owner resets what the command asks, then calls :meth:`boot` again, which sends the
    boot-up message — so the owner decides when the boot-up goes out.
    """

    __slots__ = ("_emcy", "_pdo", "_sdo", "_services", "_state", "node_id")

    def __init__(self, node_id: int) -> None:
        self.node_id = check_node_id(node_id)
        self._state = NmtState.INITIALISING
        self._set_services(NmtState.INITIALISING)

    def _set_services(self, state: NmtState) -> None:
        # the flags asked per frame are kept as plain bools: an Enum's hash is Python code
        services = self._services = _SERVICES[state]
        self._sdo = Service.SDO in services
        self._pdo = Service.PDO in services
        self._emcy = Service.EMCY in services

    @property
    def state(self) -> NmtState:
        """The NMT state."""
        return self._state

    @property
    def deadline(self) -> float | None:
        return None

    @property
    def services(self) -> frozenset[Service]:
        """The services usable in the current state."""
        return self._services

    def allowed(self, service: Service) -> bool:
        """Whether ``service`` may send or be received in the current state."""
        return service in self._services

    @property
    def pdo_allowed(self) -> bool:
        """Whether PDOs may be sent and received (OPERATIONAL only)."""
        return self._pdo

    @property
    def sdo_allowed(self) -> bool:
        """Whether SDO is served (PRE-OPERATIONAL and OPERATIONAL)."""
        return self._sdo

    @property
    def emcy_allowed(self) -> bool:
        """Whether emergencies may be sent (PRE-OPERATIONAL and OPERATIONAL)."""
        return self._emcy

    def boot(self, now: float) -> Out:
        """Leave initialisation: send the boot-up message and enter pre-operational."""
        if self._state is not NmtState.INITIALISING:
            raise NmtError(
                f"node {self.node_id} is {self._state.name}, not initialising: it boots only "
                "after power-on or a reset command (apply RESET_NODE or RESET_COMMUNICATION)"
            )
        frame = Frame(ERROR_CONTROL_BASE + self.node_id, b"\x00")
        return Out((frame,), self._move(NmtState.PRE_OPERATIONAL))

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.cob_id != NMT_COB_ID or frame.extended:
            return NOTHING
        data = frame.data
        if frame.rtr or len(data) != 2 or data[0] not in _COMMANDS or data[1] > 127:
            reason = _malformed_reason(frame)
            assert reason is not None
            return Out((), (MalformedNmt(data, reason),))
        target = data[1]
        if target != 0 and target != self.node_id:
            return NOTHING
        return self.apply(_COMMANDS[data[0]], now)

    def on_timer(self, now: float) -> Out:
        return NOTHING

    def apply(self, command: NmtCommand | int, now: float) -> Out:
        """Apply ``command`` as if received (also for local decisions, e.g. life guarding
        expiry -> ENTER_PREOPERATIONAL). Ignored while initialising: the node is not up yet."""
        cs = _COMMANDS.get(command)
        if cs is None:
            raise NmtError(f"unknown NMT command {command!r}: use an NmtCommand member")
        if self._state is NmtState.INITIALISING:
            return NOTHING
        command = cs
        if command is NmtCommand.START:
            return self._to(NmtState.OPERATIONAL)
        if command is NmtCommand.STOP:
            return self._to(NmtState.STOPPED)
        if command is NmtCommand.ENTER_PREOPERATIONAL:
            return self._to(NmtState.PRE_OPERATIONAL)
        if command is NmtCommand.RESET_NODE:
            return Out((), (*self._move(NmtState.INITIALISING), ResetNode()))
        # what is left is RESET_COMMUNICATION
        return Out((), (*self._move(NmtState.INITIALISING), ResetCommunication()))

    def _to(self, new: NmtState) -> Out:
        if new is self._state:
            return NOTHING
        return Out((), self._move(new))

    def _move(self, new: NmtState) -> tuple[Event, ...]:
        old = self._state
        self._state = new
        self._set_services(new)
        return (NmtStateChanged(old, new),)


#: One name per idea: StateChanged is the device's event (see :mod:`cobus.device.events`).
__getattr__ = renamed_names(__name__, {"StateChanged": ("NmtStateChanged", NmtStateChanged)})
