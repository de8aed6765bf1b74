"""The device's NMT: the slave state machine fed with the commands on COB-ID 000h, the
boot-up message, and the error behaviour 1029h.

The service routes what the machine decides to the device: a state change (the device tells
its services in turn), a reset node or a reset communication. A communication error found by
the heartbeat consumer or life guarding applies 1029h sub 1: 0 enter pre-operational (from
operational), 1 no change, 2 stopped.

Choices where CiA 301 leaves one: :class:`~cobus.device.NmtCommandReceived` is emitted for
every well-formed command addressed to this node or to all nodes, before it takes effect;
1029h values 3-7Fh are refused as reserved, 80h-FFh are accepted and act as "no change".
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cobus.device._core import Core, abort
from cobus.device._entries import Entry
from cobus.device._objects import U8, composite
from cobus.device.events import NmtCommandReceived
from cobus.od import Array, ObjectDictionary
from cobus.proto import Event, Frame, Out
from cobus.proto import nmt as _nmt
from cobus.proto.nmt import NmtCommand, NmtSlave, NmtState
from cobus.proto.sdo import SdoAbortCode

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost, Subscription

__all__ = ["NmtService", "OnReset", "OnStateChanged", "define_objects"]

_ABORT = SdoAbortCode
_COMMANDS = {int(c): c for c in NmtCommand}

#: ``on_state_changed(old, new)``
OnStateChanged = Callable[[NmtState, NmtState], None]
#: ``on_reset(application)``: True for reset node, False for reset communication.
OnReset = Callable[[bool], None]


def define_objects(od: ObjectDictionary) -> None:
    """1029h: on a communication error, enter pre-operational (the CiA 301 default)."""
    composite(
        od,
        Array(0x1029, "Error behavior object"),
        [(0, "Highest sub-index supported", U8, 1), (1, "Communication error", U8, 0)],
    )


class NmtService:
    """NMT slave of one device: commands, boot-up, state changes, 1029h."""

    def __init__(self, core: Core, *, on_state_changed: OnStateChanged, on_reset: OnReset) -> None:
        self._core = core
        self._on_state_changed = on_state_changed
        self._on_reset = on_reset
        self._host: MachineHost | None = None
        self._sub: Subscription | None = None
        core.handle(0x1029, self._w_error_behaviour)

    def open(self) -> None:
        """Follow the NMT commands on 000h."""
        network = self._core.network
        self._host = network.attach(self._core.nmt, (), self._on_event)
        self._sub = network.subscribe(_nmt.NMT_COB_ID, self._on_frame)

    def close(self) -> None:
        """Stop following NMT commands."""
        if self._sub is not None:
            self._sub.cancel()
            self._sub = None
        if self._host is not None:
            self._host.close()
            self._host = None

    def renew(self, node_id: int) -> None:
        """A new slave machine for ``node_id`` (closed: :meth:`open` follows)."""
        self._core.nmt = NmtSlave(node_id if node_id <= 127 else 1)  # (FFh: not opened)

    def boot(self) -> None:
        """Enter pre-operational, with the boot-up message (unless the deviations drop it)."""
        self._run(self._boot_out)

    def apply(self, command: NmtCommand) -> None:
        """Apply ``command`` as if the master had sent it."""
        self._run(lambda now: self._core.nmt.apply(command, now))

    def communication_error(self) -> None:
        """CiA 301 1029h sub 1: 0 pre-operational (if operational), 1 no change, 2 stopped."""
        mode = self._core.value(0x1029, 1, 0)
        state = self._core.nmt.state
        if mode == 0 and state is NmtState.OPERATIONAL:
            self.apply(NmtCommand.ENTER_PREOPERATIONAL)
        elif mode == 2 and state is not NmtState.STOPPED:
            self.apply(NmtCommand.STOP)

    def _run(self, call: Callable[[float], Out]) -> None:
        if self._host is not None:
            self._host.run(call)

    def _boot_out(self, now: float) -> Out:
        out = self._core.nmt.boot(now)
        return out if self._core.deviations.send_bootup else Out((), out.events)

    def _on_frame(self, frame: Frame, now: float) -> None:
        core = self._core
        data = frame.data
        if (
            not frame.rtr
            and not frame.extended
            and len(data) == 2
            and data[1] in (0, core.node_id)
            and core.nmt.state is not NmtState.INITIALISING
        ):
            command = _COMMANDS.get(data[0])
            if command is not None:
                core.emit(NmtCommandReceived(core.node_id, command))
        if self._host is not None:
            self._host.feed(frame, now)

    def _on_event(self, event: Event) -> None:
        if isinstance(event, _nmt.NmtStateChanged):
            self._on_state_changed(event.old, event.new)
        elif isinstance(event, _nmt.ResetNode):
            self._on_reset(True)
        elif isinstance(event, _nmt.ResetCommunication):
            self._on_reset(False)

    def _w_error_behaviour(self, entry: Entry, value: Any) -> None:
        if entry.subindex == 0:
            raise abort(_ABORT.WRITE_READ_ONLY, "1029h sub 0 is read-only")
        if 2 < value < 0x80:
            raise abort(
                _ABORT.INVALID_VALUE,
                f"1029h sub {entry.subindex}: {value} is reserved (0 pre-operational, "
                "1 no change, 2 stopped, 80h-FFh manufacturer-specific)",
            )
        self._core.store(entry, value)
