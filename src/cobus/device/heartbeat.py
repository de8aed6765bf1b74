"""The device's heartbeat: the producer of 1017h and the consumer of 1016h.

The producer starts with the period of 1017h after the boot-up message; a period of 0 stops
it. :attr:`Simulation.heartbeat_muted <cobus.device.Simulation.heartbeat_muted>` silences it without
changing its period. The consumer watches every node 1016h names with a non-zero time; a node
whose heartbeat stops is the communication error ``("hb", node)`` (EMCY 8130h) until it is
heard again, reboots, or is no longer watched, and triggers the error behaviour 1029h.

Choices where CiA 301 leaves one: one 1016h entry per node (a second entry for a node already
watched is refused with 06040043); the consumer has at most 127 entries.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cobus.device._core import Core, abort
from cobus.device._entries import Entry
from cobus.device._gates import MutableHeartbeat
from cobus.device._objects import RW, U8, U16, U32, composite, var
from cobus.device.emcy import COMM_BIT, EmcyService
from cobus.device.events import HeartbeatLost, HeartbeatRestored
from cobus.errors import CobusError
from cobus.od import Array, ObjectDictionary
from cobus.proto import NOTHING, Event
from cobus.proto import heartbeat as _hb
from cobus.proto import nmt as _nmt
from cobus.proto.emcy import EmcyCode
from cobus.proto.sdo import SdoAbortCode

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost, Subscription

__all__ = ["HeartbeatService", "define_objects"]

_ABORT = SdoAbortCode


def define_objects(od: ObjectDictionary, *, consumers: int) -> None:
    """1016h with ``consumers`` entries (all unused) and 1017h (no heartbeat produced)."""
    composite(
        od,
        Array(0x1016, "Consumer heartbeat time"),
        [
            (0, "Highest sub-index supported", U8, consumers),
            *((n, f"Consumer heartbeat time {n}", U32, 0) for n in range(1, consumers + 1)),
        ],
    )
    od.add(var(0x1017, 0, "Producer heartbeat time", U16, RW, 0))


class HeartbeatService:
    """Heartbeat of one device: producer (1017h) and consumer (1016h)."""

    def __init__(self, core: Core, emcy: EmcyService, on_error: Callable[[], None]) -> None:
        self._core = core
        self._emcy = emcy
        self._on_error = on_error
        self._producer: _hb.HeartbeatProducer | None = None
        self._producer_host: MachineHost | None = None
        self._consumer: _hb.HeartbeatConsumer | None = None
        self._consumer_host: MachineHost | None = None
        self._watching: dict[int, Subscription] = {}
        core.handle(0x1016, self._w_consumer)
        core.handle(0x1017, self._w_producer)

    def build(self, now: float) -> None:
        """The producer (silent until :meth:`boot`) and the consumer of 1016h."""
        core = self._core
        network = core.network
        if core.deviations.error_control:
            self._producer = _hb.HeartbeatProducer(
                core.node_id, state_getter=lambda: core.nmt.state
            )
            self._producer_host = network.attach(
                MutableHeartbeat(self._producer, core.simulation), ()
            )
        size = core.value(0x1016, 0, 0)
        if size:
            consumer = _hb.HeartbeatConsumer(min(int(size), 127))
            self._consumer = consumer
            self._consumer_host = network.attach(consumer, (), self._on_event)
            for sub in range(1, consumer.size + 1):
                value = core.value(0x1016, sub, 0)
                if value:
                    try:
                        consumer.set_entry(sub, int(value), now)
                    except CobusError as exc:
                        core.report(f"1016h sub {sub}", exc)
            self._watch()

    def boot(self, now: float) -> None:
        """After the boot-up message: produce with the period of 1017h."""
        if self._producer is not None and self._producer_host is not None:
            self._producer.set_period(int(self._core.value(0x1017, 0)), now)
            self._producer_host.apply(NOTHING)

    def close(self) -> None:
        """Stop producing and watching."""
        for sub in self._watching.values():
            sub.cancel()
        self._watching.clear()
        for host in (self._producer_host, self._consumer_host):
            if host is not None:
                host.close()
        self._producer = self._consumer = None
        self._producer_host = self._consumer_host = None

    # ------------------------------------------------------------------ consumer

    def _on_event(self, event: Event) -> None:
        core = self._core
        if isinstance(event, _hb.HeartbeatTimeout):
            code = EmcyCode.LIFE_GUARD_OR_HEARTBEAT
            self._emcy.raise_error(("hb", event.node_id), code, COMM_BIT)
            core.emit(HeartbeatLost(core.node_id, event.node_id))
            self._on_error()
        elif isinstance(event, _hb.HeartbeatResumed):
            self._emcy.clear([("hb", event.node_id)])
            core.emit(HeartbeatRestored(core.node_id, event.node_id, event.state))
        elif isinstance(event, _hb.BootupReceived):
            self._emcy.clear([("hb", event.node_id)])

    def _watch(self) -> None:
        """Listen to exactly the nodes the consumer watches."""
        consumer = self._consumer
        host = self._consumer_host
        wanted: set[int] = set()
        if consumer is not None:
            for sub in range(1, consumer.size + 1):
                node, ms = _hb.decode_consumer_entry(consumer.entry(sub))
                if node and ms:
                    wanted.add(node)
        for node in list(self._watching):
            if node not in wanted:
                self._watching.pop(node).cancel()
        if host is not None:
            for node in wanted - set(self._watching):
                self._watching[node] = self._core.network.subscribe(
                    _nmt.ERROR_CONTROL_BASE + node, host.feed
                )

    def _watched(self, node: int) -> bool:
        consumer = self._consumer
        if consumer is None:
            return False
        return any(
            (consumer.entry(s) >> 16) & 0xFF == node and consumer.entry(s) & 0xFFFF
            for s in range(1, consumer.size + 1)
        )

    # ------------------------------------------------------------------ objects

    def _w_consumer(self, entry: Entry, value: Any) -> None:
        core = self._core
        sub = entry.subindex
        if sub == 0:
            raise abort(_ABORT.WRITE_READ_ONLY, "1016h sub 0 is read-only")
        try:
            node, ms = _hb.decode_consumer_entry(value)
        except CobusError as exc:
            raise abort(_ABORT.INVALID_VALUE, str(exc)) from None
        if node > 127:
            raise abort(_ABORT.INVALID_VALUE, f"1016h sub {sub}: node-ID {node} is not 1..127")
        if node and ms:
            for other in range(1, 128):
                if other == sub:
                    continue
                existing = core.entries.get(0x1016 << 8 | other)
                if existing is None:
                    continue
                o_node, o_ms = (existing.value >> 16) & 0xFF, existing.value & 0xFFFF
                if o_node == node and o_ms:
                    raise abort(
                        _ABORT.PARAMETER_INCOMPATIBLE,
                        f"1016h sub {sub} would watch node {node} a second time (sub {other} "
                        "does already); clear that entry first",
                    )
        core.store(entry, value)
        consumer, host = self._consumer, self._consumer_host
        if consumer is not None and host is not None and sub <= consumer.size:
            consumer.set_entry(sub, value, core.now())
            host.apply(NOTHING)
            self._watch()
            if not (node and ms):
                self._emcy.clear([k for k in self._emcy.keys("hb") if not self._watched(k[1])])

    def _w_producer(self, entry: Entry, value: Any) -> None:
        self._core.store(entry, value)
        if self._producer is not None and self._producer_host is not None:
            self._producer.set_period(value, self._core.now())
            self._producer_host.apply(NOTHING)
