"""What the services of one device share: its network, its entries and the way a value is
written, events go out and failures are told. Each service (``sdo_server``, ``pdo``, ``sync``,
``time``, ``emcy``, ``heartbeat``, ``guarding``, ``nmt``, ``storage``) gets this one object as
its port to the rest of the device, instead of reaching into the :class:`Device` or into a
sibling. A service registers here what the others must know of the objects it owns: their
write handlers (as CANopenNode's ``CO_SYNC.c`` registers ``OD_write_1005``), the COB-IDs of
the pre-defined connection set that follow the node-ID, the objects never stored, and a
download it decodes itself.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cobus.device._entries import Entry
from cobus.device.events import ConfigurationProblem, DeviceEvent
from cobus.od import ObjectDictionary
from cobus.proto.nmt import NmtSlave
from cobus.proto.sdo import SdoAbort, SdoAbortCode
from cobus.runtime.events import HandlerFailed

if TYPE_CHECKING:
    from cobus.device.simulation import Simulation
    from cobus.runtime.network import AsyncNetwork

__all__ = ["EXTENDED", "INVALID", "Core", "DownloadHandler", "Listener", "WriteHandler", "abort"]

#: The logger the device has always used for failing callbacks.
log = logging.getLogger("cobus.device.device")

Listener = Callable[[DeviceEvent], object]
#: ``handler(entry, value)``: takes a checked value written to an object the service owns
#: (by SDO or by the application); stores it and applies it, or raises :class:`SdoAbort`.
WriteHandler = Callable[[Entry, Any], None]
#: ``handler(entry, data)``: takes the raw bytes of an SDO download to an entry whose bytes
#: its service decodes itself (instead of by the entry's data type and access).
DownloadHandler = Callable[[Entry, bytes], None]

#: Bit 31 of a COB-ID parameter: not valid.
INVALID = 1 << 31
#: Bit 29 of a COB-ID parameter: a 29-bit identifier.
EXTENDED = 1 << 29


def abort(code: int, reason: str) -> SdoAbort:
    """The refusal of a write or read, with its CiA 301 abort code and the reason."""
    return SdoAbort(code, reason)


class Core:
    """The shared state of one device and the few operations every service needs."""

    __slots__ = (
        "deviations",
        "downloads",
        "entries",
        "handlers",
        "heard_by_network",
        "indices",
        "listeners",
        "network",
        "nmt",
        "node_bases",
        "node_id",
        "not_stored",
        "od",
        "simulation",
        "started",
    )

    def __init__(
        self,
        network: AsyncNetwork,
        od: ObjectDictionary,
        node_id: int,
        simulation: Simulation,
    ) -> None:
        self.network = network
        self.od = od
        self.node_id = node_id
        #: The device's simulation settings, which its SDO servers and heartbeat read.
        self.simulation = simulation
        #: How the device departs from CiA 301.
        self.deviations = simulation.deviations
        self.entries: dict[int, Entry] = {}
        for var in od.variables():
            if var.index < 0x1000:  # data type definitions and dummies
                continue
            entry = Entry(var)
            self.entries[entry.key] = entry
        self.indices: set[int] = {obj.index for obj in od if obj.index >= 0x1000}
        self.handlers: dict[int, WriteHandler] = {}
        #: Entry key -> the base its pre-defined COB-ID adds the node-ID to (CiA 301).
        self.node_bases: dict[int, int] = {}
        #: Objects the storage never stores (command objects, the error history).
        self.not_stored: set[int] = set()
        #: Entry key -> the service's decoder of an SDO download to that entry.
        self.downloads: dict[int, DownloadHandler] = {}
        self.listeners: list[Listener] = []
        #: The network's listeners, the list itself. An event built per request or frame
        #: (EntryWritten, RpdoReceived) is skipped unless ``listeners or heard_by_network``:
        #: asked of the lists directly, without a call.
        self.heard_by_network = network._listeners
        #: The NMT slave of the current communication (a new one after a node-ID change).
        self.nmt = NmtSlave(self.machine_node_id)
        self.started = False

    @property
    def machine_node_id(self) -> int:
        """The node-ID the device's protocol machines are built with: the device's own, or
        1 while it has none (FFh: unconfigured, the machines stay off the network then)."""
        node_id = self.node_id
        return node_id if node_id <= 127 else 1

    @property
    def unconfigured(self) -> bool:
        """Whether the device has no node-ID (FFh) and answers LSS only."""
        return self.node_id > 127

    def now(self) -> float:
        """The network's clock."""
        return self.network.time()

    def handle(self, index: int, handler: WriteHandler) -> None:
        """Writes to ``index`` go to ``handler`` (when the dictionary has that object)."""
        if index in self.indices:
            self.handlers[index] = handler

    def follows_node_id(self, index: int, subindex: int, base: int) -> None:
        """The entry is a COB-ID of the pre-defined connection set: ``base`` + node-ID."""
        self.node_bases[index << 8 | subindex] = base

    def node_offset(self, entry: Entry, value: Any) -> int | None:
        """``value - node_id`` when ``value`` follows ``$NODEID`` (an entry whose default is a
        ``$NODEID`` expression and holds it, or a pre-defined COB-ID that holds its CiA 301
        value), else None: such a value moves with a node-ID change and is stored relative."""
        if not isinstance(value, int) or isinstance(value, bool):
            return None
        node_id = self.node_id
        var = entry.var
        if var.relative:
            return value - node_id if value == var.value else None
        base = self.node_bases.get(entry.key)
        if base is None or value & EXTENDED or value & 0x1FFFFFFF != base + node_id:
            return None
        return value - node_id

    def entry(self, index: int, subindex: int) -> Entry:
        """The entry an SDO request names, or the abort for a missing object or sub-index."""
        entry = self.entries.get(index << 8 | subindex)
        if entry is None:
            if index in self.indices:
                raise abort(SdoAbortCode.NO_SUBINDEX, f"0x{index:04X} has no sub-index {subindex}")
            raise abort(SdoAbortCode.NO_OBJECT, f"no object 0x{index:04X}")
        return entry

    def value(self, index: int, subindex: int, default: int = 0) -> Any:
        """The stored value of an entry, ``default`` when the dictionary lacks it."""
        entry = self.entries.get(index << 8 | subindex)
        return default if entry is None else entry.value

    def store(self, entry: Entry, value: Any) -> None:
        """Keep ``value``; the TPDOs that map the entry see the change."""
        old = entry.value
        entry.value = value
        if entry.tpdos and value != old:
            now = self.network.time()
            for tpdo in entry.tpdos:
                host = tpdo.host
                if host is not None:
                    host.apply(tpdo.on_change(now))

    def write(self, entry: Entry, value: Any, *, remote: bool) -> None:
        """A checked value for ``entry``: to its service's handler, else (through the
        application's write callback when a master wrote it) stored."""
        handler = self.handlers.get(entry.index)
        if handler is not None:
            handler(entry, value)
            return
        if remote and entry.writer is not None:
            self.call_writer(entry, value)
        if entry.tpdos:
            self.store(entry, value)
        else:  # store's work when no TPDO maps the entry, a call less per write
            entry.value = value

    def call_writer(self, entry: Entry, value: Any) -> None:
        """The application's write callback of ``entry``; a failure refuses the write."""
        writer = entry.writer
        assert writer is not None
        try:
            writer(value)
        except SdoAbort:
            raise
        except Exception as exc:
            self.failure(f"write callback of 0x{entry.index:04X}:{entry.subindex:02X}", exc)
            raise abort(SdoAbortCode.CANNOT_STORE, f"the application refused: {exc!r}") from None

    def cob_id(self, kind: str, number: int, value: int) -> int:
        """The CiA 301 form of a stored COB-ID parameter (see
        :attr:`Deviations.cob_id_rule <cobus.device.Deviations.cob_id_rule>`)."""
        rule = self.deviations.cob_id_rule
        if rule is None:
            return value
        try:
            return int(rule(kind, number, value))
        except Exception as exc:
            self.failure(f"COB-ID rule for {kind} {number}", exc)
            raise abort(
                SdoAbortCode.INVALID_VALUE, f"the COB-ID rule refused 0x{value:08X}"
            ) from None

    def emit(self, event: DeviceEvent) -> None:
        """To the device's listeners, then to the network's."""
        for listener in list(self.listeners):
            try:
                listener(event)
            except Exception as exc:
                self.failure(f"device {self.node_id} listener {listener!r}", exc)
        self.network.emit(event)

    def report(self, what: str, exc: Exception) -> None:
        """A configuration value the device cannot use: reported, that part stays off."""
        self.emit(ConfigurationProblem(self.node_id, f"{what}: {exc}"))

    def failure(self, where: str, exc: BaseException) -> None:
        """An application callback raised: logged and reported, the device goes on."""
        log.error("device %d: %s failed: %r", self.node_id, where, exc, exc_info=exc)
        self.network.emit(HandlerFailed(f"device {self.node_id}: {where}", repr(exc)))
