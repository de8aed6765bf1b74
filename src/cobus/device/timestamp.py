"""The device's TIME: the consumer of the time stamp object with the COB-ID 1012h.

A TIME received in pre-operational or operational is the event
:class:`~cobus.device.TimeReceived`. This device consumes TIME and never produces it: a write
of 1012h with bit 30 set is refused.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, Any

from cobus.device._core import Core, abort
from cobus.device._entries import Entry
from cobus.device._objects import RW, U32, var
from cobus.device.events import TimeReceived
from cobus.errors import CobusError
from cobus.od import ObjectDictionary
from cobus.proto import Event, Frame
from cobus.proto import nmt as _nmt
from cobus.proto import timestamp as _time
from cobus.proto.sdo import SdoAbortCode

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost, Subscription

__all__ = ["TimeService", "define_objects"]


def define_objects(od: ObjectDictionary) -> None:
    """1012h: TIME consumed on 100h."""
    od.add(var(0x1012, 0, "COB-ID time stamp", U32, RW, 0x80000100))


class TimeService:
    """TIME of one device: the consumer of 1012h."""

    def __init__(self, core: Core) -> None:
        self._core = core
        self._host: MachineHost | None = None
        self._sub: Subscription | None = None
        core.handle(0x1012, self._w_cob_id)

    def build(self) -> None:
        """(Re)build the consumer from 1012h (none when the dictionary lacks it)."""
        self.close()
        core = self._core
        if 0x1012 not in core.indices:
            return
        try:
            cob = _time.TimeCobId.from_u32(int(core.value(0x1012, 0)))
        except CobusError as exc:
            core.report("1012h", exc)
            return
        if not cob.consume:
            return
        consumer = _time.TimeConsumer(cob.can_id, extended=cob.extended)
        self._host = host = core.network.attach(consumer, (), self._on_event)
        self._sub = core.network.subscribe(
            cob.can_id, partial(self._on_frame, host), extended=cob.extended
        )

    def close(self) -> None:
        """Stop consuming."""
        if self._host is not None:
            self._host.close()
        if self._sub is not None:
            self._sub.cancel()
        self._host = self._sub = None

    def _on_frame(self, host: MachineHost, frame: Frame, now: float) -> None:
        if self._core.nmt.allowed(_nmt.Service.SYNC):  # as SYNC: pre-operational, operational
            host.feed(frame, now)

    def _on_event(self, event: Event) -> None:
        if isinstance(event, _time.TimeStampReceived):
            self._core.emit(TimeReceived(self._core.node_id, event.time))

    def _w_cob_id(self, entry: Entry, value: Any) -> None:
        try:
            new = _time.TimeCobId.from_u32(value)
        except CobusError as exc:
            raise abort(SdoAbortCode.INVALID_VALUE, str(exc)) from None
        if new.produce:
            raise abort(
                SdoAbortCode.INVALID_VALUE,
                "1012h bit 30: this device does not produce TIME (it consumes it, bit 31)",
            )
        self._core.store(entry, value)
        if self._core.started:
            self.build()
