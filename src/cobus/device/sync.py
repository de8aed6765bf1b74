"""The device's SYNC: the consumer of 1005h (with the communication cycle period 1006h, the
synchronous window 1007h and the counter overflow 1019h) and, when bit 30 of 1005h says so,
the producer.

Every SYNC received in pre-operational or operational goes to the PDOs (``on_sync(counter)``);
a SYNC missing for longer than the cycle period is the communication error
``("sync",)`` (EMCY 8100h) until the next one, a SYNC of the wrong length the one-shot EMCY
8240h.

Choices where CiA 301 leaves one: the SYNC identifier cannot change while this device
generates SYNC (clear bit 30 first); 1019h can change only while 1006h is 0; in stopped the
producer falls silent and on leaving stopped its counter starts again at 1.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any

from cobus.device._core import Core, abort
from cobus.device._entries import Entry
from cobus.device._objects import RW, U8, U32, var
from cobus.device.emcy import COMM_BIT, EmcyService
from cobus.device.events import SyncLost, SyncRestored
from cobus.errors import CobusError
from cobus.od import ObjectDictionary
from cobus.proto import NOTHING, Event, Frame
from cobus.proto import nmt as _nmt
from cobus.proto import sync as _sync
from cobus.proto.emcy import EmcyCode
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbortCode
from cobus.runtime.periodic import InterfaceTimer

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost, Subscription

__all__ = ["OnSync", "SyncService", "define_objects"]

_ABORT = SdoAbortCode

#: ``on_sync(counter)``: a SYNC received (``counter`` None without a counter byte).
OnSync = Callable[[int | None], None]


def define_objects(od: ObjectDictionary) -> None:
    """1005h, 1006h, 1007h and 1019h with their CiA 301 defaults (SYNC on 80h, consumed)."""
    add = od.add
    add(var(0x1005, 0, "COB-ID SYNC", U32, RW, 0x80))
    add(var(0x1006, 0, "Communication cycle period", U32, RW, 0))
    add(var(0x1007, 0, "Synchronous window length", U32, RW, 0))
    add(var(0x1019, 0, "Synchronous counter overflow value", U8, RW, 0))


class SyncService:
    """SYNC of one device: consumer and producer, 1005h, 1006h, 1007h, 1019h."""

    def __init__(
        self, core: Core, emcy: EmcyService, on_sync: OnSync, *, by_interface: bool = False
    ) -> None:
        self._core = core
        self._emcy = emcy
        self._on_sync = on_sync
        #: produce SYNC through the CAN interface's own timing (cobus.runtime.periodic)
        self._by_interface = by_interface
        self._timer: InterfaceTimer | None = None
        self._timer_start: asyncio.TimerHandle | None = None
        self._consumer: _sync.SyncConsumer | None = None
        self._consumer_host: MachineHost | None = None
        self._sub: Subscription | None = None
        self._producer: _sync.SyncProducer | None = None
        self._producer_host: MachineHost | None = None
        core.handle(0x1005, self._w_cob_id)
        core.handle(0x1006, self._w_period)
        core.handle(0x1007, self._w_window)
        core.handle(0x1019, self._w_overflow)

    def in_window(self, now: float) -> bool:
        """Whether ``now`` is within the synchronous window (1007h) of the last SYNC; always
        True without a window."""
        consumer = self._consumer
        return consumer is None or not consumer.window_us or consumer.in_window(now)

    def build(self) -> None:
        """(Re)build consumer and producer from 1005h, 1006h, 1007h and 1019h."""
        self.close()
        core = self._core
        now = core.now()
        try:
            cob = _sync.SyncCobId.from_u32(int(core.value(0x1005, 0, _sync.SYNC_COB_ID)))
            overflow = int(core.value(0x1019, 0))
            consumer = _sync.SyncConsumer(cob.can_id, extended=cob.extended, overflow=overflow)
            consumer.set_period(int(core.value(0x1006, 0)), now)
            consumer.set_window(int(core.value(0x1007, 0)))
        except CobusError as exc:
            core.report("SYNC parameters", exc)
            return
        network = core.network
        self._consumer = consumer
        self._consumer_host = host = network.attach(consumer, (), self._on_event)
        self._sub = network.subscribe(
            cob.can_id, partial(self._on_frame, host), extended=cob.extended
        )
        if cob.generate:
            producer = _sync.SyncProducer(cob.can_id, extended=cob.extended, overflow=overflow)
            producer.set_period(int(core.value(0x1006, 0)), now)
            self._producer = producer
            if self._by_interface:
                self._retime()
            else:
                self._producer_host = network.attach(producer, ())
                self._producer_host.apply(NOTHING)

    def _retime(self) -> None:
        """(SYNC by the interface) Stop the interface's SYNC, and start it again as the
        producer now says: its identifier, counter (from 1) and period, one period from now
        (the interface would send the first at once: a shorter interval, before the
        boot-up); none while the period is 0, generation is off, SYNC is not allowed in the
        device's state (initialising, stopped) or the network is not connected (it starts
        again on connect)."""
        self._stop_timer()
        producer = self._producer
        network = self._core.network
        if (
            producer is None
            or not producer.generate
            or not producer.period_us
            or not self._core.nmt.allowed(_nmt.Service.SYNC)
            or not network.connected
        ):
            return
        cid, ext = producer.can_id, producer.extended
        counts = range(1, producer.overflow + 1) if producer.overflow else (None,)
        frames = [
            Frame(cid, extended=ext) if c is None else Frame(cid, bytes((c,)), extended=ext)
            for c in counts
        ]
        period = producer.period_us / 1e6
        try:
            timer = InterfaceTimer(network, frames, period)
        except CobusError as exc:
            self._core.report("SYNC by the interface", exc)
            return
        self._timer = timer
        self._timer_start = network.loop.call_later(period, self._start_timer, timer)

    def _start_timer(self, timer: InterfaceTimer) -> None:
        self._timer_start = None
        if self._timer is not timer or not self._core.network.connected:
            return
        try:
            timer.start()
        except CobusError as exc:
            self._core.report("SYNC by the interface", exc)

    def _stop_timer(self) -> None:
        if self._timer_start is not None:
            self._timer_start.cancel()
            self._timer_start = None
        if self._timer is not None:
            self._timer.stop()
            self._timer = None

    def attach(self) -> None:
        """The device is on its network: (by the interface) its SYNC, which ends when the
        network disconnects, starts again when it connects."""
        if self._by_interface:
            self._core.network.on_connect(self._retime)

    def detach(self) -> None:
        """The device is closed: forget the network (:meth:`close` first)."""
        self._core.network._forget(self._retime)

    def close(self) -> None:
        """Stop consuming and producing."""
        self._stop_timer()
        for host in (self._consumer_host, self._producer_host):
            if host is not None:
                host.close()
        if self._sub is not None:
            self._sub.cancel()
        self._consumer = self._producer = None
        self._consumer_host = self._producer_host = self._sub = None

    def state_changed(self, old: NmtState, new: NmtState, now: float) -> None:
        """CiA 301: no SYNC produced in stopped; on leaving it the counter starts at 1."""
        producer, host = self._producer, self._producer_host
        if producer is not None and NmtState.STOPPED in (old, new):
            period = 0 if new is NmtState.STOPPED else int(self._core.value(0x1006, 0))
            producer.set_period(period, now)
            if host is not None:
                host.apply(NOTHING)
        if self._by_interface and producer is not None:
            # on (after the boot-up, on leaving stopped) or off, as SYNC becomes allowed
            allowed = self._core.nmt.allowed(_nmt.Service.SYNC)
            if allowed != (self._timer is not None):
                self._retime()

    def _on_frame(self, host: MachineHost, frame: Frame, now: float) -> None:
        if self._core.nmt.allowed(_nmt.Service.SYNC):  # pre-operational and operational
            host.feed(frame, now)

    def _on_event(self, event: Event) -> None:
        core = self._core
        if isinstance(event, _sync.SyncReceived):
            self._on_sync(event.counter)
        elif isinstance(event, _sync.SyncTimedOut):
            self._emcy.raise_error(("sync",), EmcyCode.COMMUNICATION, COMM_BIT)
            core.emit(SyncLost(core.node_id))
        elif isinstance(event, _sync.SyncResumed):
            self._emcy.clear([("sync",)])
            core.emit(SyncRestored(core.node_id))
        elif isinstance(event, _sync.UnexpectedSyncLength):
            self._emcy.one_shot(EmcyCode.UNEXPECTED_SYNC_LENGTH, COMM_BIT)

    # ------------------------------------------------------------------ objects

    def _w_cob_id(self, entry: Entry, value: Any) -> None:
        try:
            new = _sync.SyncCobId.from_u32(value)
        except CobusError as exc:
            raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
        producer = self._producer
        if (
            producer is not None
            and new.generate
            and (new.can_id, new.extended) != (producer.can_id, producer.extended)
        ):
            raise abort(
                _ABORT.INVALID_VALUE,
                "1005h: the SYNC identifier cannot change while this device generates SYNC; "
                "clear bit 30 first",
            )
        unchanged = value == self._core.value(0x1005, 0, _sync.SYNC_COB_ID)
        self._core.store(entry, value)
        if self._core.started and not unchanged:  # (a configuration download rewrites it)
            self.build()

    def _w_period(self, entry: Entry, value: Any) -> None:
        self._core.store(entry, value)
        now = self._core.now()
        if self._consumer is not None and self._consumer_host is not None:
            self._consumer.set_period(value, now)
            self._consumer_host.apply(NOTHING)
        producer = self._producer
        if producer is not None:
            before = producer.period_us
            if self._core.nmt.allowed(_nmt.Service.SYNC):  # (0 while stopped, CiA 301)
                producer.set_period(value, now)
            if self._producer_host is not None:
                self._producer_host.apply(NOTHING)
            elif self._by_interface and (producer.period_us != before or self._timer is None):
                self._retime()  # (the same period again keeps the phase)

    def _w_window(self, entry: Entry, value: Any) -> None:
        self._core.store(entry, value)
        if self._consumer is not None:
            self._consumer.set_window(value)

    def _w_overflow(self, entry: Entry, value: Any) -> None:
        if self._core.value(0x1006, 0):
            raise abort(
                _ABORT.DEVICE_STATE,
                "1019h can only change while the communication cycle period 1006h is 0",
            )
        try:
            _sync.check_overflow(value)
        except CobusError as exc:
            raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
        self._core.store(entry, value)
        if self._consumer is not None:
            self._consumer.set_overflow(value)
        if self._producer is not None:
            self._producer.set_overflow(value)
