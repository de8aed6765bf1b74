"""The device's node guarding and life guarding: the responder to the master's remote frames
on 700h + node-ID, with the guard time 100Ch and the life time factor 100Dh.

Each guarding request is answered with the NMT state and the toggle bit. When the master's
requests stop for longer than guard time x life time factor, life guarding has expired: the
communication error ``("guard",)`` (EMCY 8130h) until the next request, and the error
behaviour 1029h. A device whose deviations turn error control off does not answer at all.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cobus.device._core import Core
from cobus.device._entries import Entry
from cobus.device._objects import RW, U8, U16, var
from cobus.device.emcy import COMM_BIT, EmcyService
from cobus.device.events import LifeGuardingLost, LifeGuardingRestored
from cobus.od import ObjectDictionary
from cobus.proto import NOTHING, Event
from cobus.proto import guarding as _guarding
from cobus.proto import nmt as _nmt
from cobus.proto.emcy import EmcyCode

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost, Subscription

__all__ = ["GuardingService", "define_objects"]


def define_objects(od: ObjectDictionary) -> None:
    """100Ch guard time and 100Dh life time factor (0: no life guarding)."""
    od.add(var(0x100C, 0, "Guard time", U16, RW, 0))
    od.add(var(0x100D, 0, "Life time factor", U8, RW, 0))


class GuardingService:
    """Node and life guarding of one device: 100Ch and 100Dh."""

    def __init__(self, core: Core, emcy: EmcyService, on_error: Callable[[], None]) -> None:
        self._core = core
        self._emcy = emcy
        self._on_error = on_error
        self._responder: _guarding.GuardingResponder | None = None
        self._host: MachineHost | None = None
        self._sub: Subscription | None = None
        core.handle(0x100C, self._w_guarding)
        core.handle(0x100D, self._w_guarding)

    def build(self, now: float) -> None:
        """Answer guarding requests, with the guard time and life time factor stored."""
        core = self._core
        if not core.deviations.error_control:
            return
        responder = _guarding.GuardingResponder(core.node_id, lambda: core.nmt.state)
        responder.set_guard_time(int(core.value(0x100C, 0)), now)
        responder.set_life_time_factor(int(core.value(0x100D, 0)), now)
        self._responder = responder
        self._host = host = core.network.attach(responder, (), self._on_event)
        self._sub = core.network.subscribe(_nmt.ERROR_CONTROL_BASE + core.node_id, host.feed)

    def close(self) -> None:
        """Stop answering."""
        if self._sub is not None:
            self._sub.cancel()
        if self._host is not None:
            self._host.close()
        self._responder = None
        self._host = self._sub = None

    def _on_event(self, event: Event) -> None:
        core = self._core
        if isinstance(event, _guarding.LifeGuardingExpired):
            self._emcy.raise_error(("guard",), EmcyCode.LIFE_GUARD_OR_HEARTBEAT, COMM_BIT)
            core.emit(LifeGuardingLost(core.node_id))
            self._on_error()
        elif isinstance(event, _guarding.LifeGuardingResumed):
            self._emcy.clear([("guard",)])
            core.emit(LifeGuardingRestored(core.node_id))

    def _w_guarding(self, entry: Entry, value: Any) -> None:
        self._core.store(entry, value)
        responder, host = self._responder, self._host
        if responder is not None and host is not None:
            if entry.index == 0x100C:
                responder.set_guard_time(value, self._core.now())
            else:
                responder.set_life_time_factor(value, self._core.now())
            host.apply(NOTHING)
