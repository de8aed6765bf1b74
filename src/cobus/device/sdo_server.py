"""The device's SDO servers: one channel per SDO server parameter object (1200h, the default
channel on 600h/580h + node-ID, and 1201h-127Fh where the dictionary has them), each a
:class:`~cobus.proto.sdo.SdoServer` serving the device's entries with every check.

What the servers serve is :class:`SdoBackend`: an upload reads the entry (through the
application's read callback when one is bound), a download decodes and checks the value and
hands it to the service that owns the object (or stores it, through the application's write
callback), then emits :class:`~cobus.device.EntryWritten`.

Choices where CiA 301 leaves one: SDO identifiers are 11-bit; the identifier of a valid
channel cannot change (write it with bit 31 set first); in stopped the channels are rebuilt,
so transfers in progress end silently.
"""

from __future__ import annotations

from typing import Any

from cobus.device._core import EXTENDED, INVALID, Core, abort
from cobus.device._entries import Entry, decode_download
from cobus.device._gates import LateSdoServer
from cobus.device._objects import RO, U8, U32, composite, var
from cobus.device.events import EntryWritten
from cobus.errors import CobusError
from cobus.od import Access, NodeRelative, ObjectDictionary, Record
from cobus.proto import Frame
from cobus.proto.connection_set import SDO_RX_BASE, SDO_TX_BASE
from cobus.proto.sdo import SdoAbort, SdoAbortCode, SdoServer

__all__ = ["SdoBackend", "SdoServerService", "define_objects"]

_ABORT = SdoAbortCode
# What Access.readable and .writable test, as module globals: asked on every request, and a
# property is a call (an Enum class attribute, in Python 3.11, slower still).
_RO, _WO, _CONST = Access.RO, Access.WO, Access.CONST


class SdoBackend:
    """What the SDO servers of a device serve: its entries, with every check (an
    :class:`~cobus.proto.sdo.SdoServerBackend`)."""

    __slots__ = ("_core",)

    def __init__(self, core: Core) -> None:
        self._core = core

    def upload(self, index: int, subindex: int) -> bytes:
        """The encoded value of an entry, or the abort that refuses it."""
        core = self._core
        entry = core.entries.get(index << 8 | subindex)
        if entry is None:
            entry = core.entry(index, subindex)  # raises the abort that names what is missing
        var = entry.var
        if var.access is _WO:  # asked each time: the application may change it
            raise abort(_ABORT.READ_WRITE_ONLY, f"{var.name!r} is write-only")
        reader = entry.reader
        if reader is None:
            value = entry.value
        else:
            try:
                value = reader()
            except SdoAbort:
                raise
            except Exception as exc:
                core.failure(f"read callback of 0x{index:04X}:{subindex:02X}", exc)
                raise abort(_ABORT.CANNOT_STORE, f"the application failed: {exc!r}") from None
        try:
            return entry.encoder(value)
        except CobusError as exc:
            raise abort(
                _ABORT.GENERAL_ERROR,
                f"the application's value {value!r} does not fit {var.data_type.name}: {exc}",
            ) from None

    def download(self, index: int, subindex: int, data: bytes) -> None:
        """Write an entry from its encoded value, or raise the abort that refuses it."""
        core = self._core
        entry = core.entries.get(index << 8 | subindex)
        if entry is None:
            entry = core.entry(index, subindex)  # raises the abort that names what is missing
        var = entry.var
        if core.downloads:
            own = core.downloads.get(entry.key)
            if own is not None:  # a service decodes these bytes itself
                own(entry, data)
                return
        access = var.access
        if access is _RO or access is _CONST:  # not writable (Access.writable, without a call)
            raise abort(_ABORT.WRITE_READ_ONLY, f"{var.name!r} is {access}")
        size = entry.size
        unpack = entry.unpack
        if unpack is not None and len(data) == size:
            value = unpack(data)[0]  # what decode_download returns, where nothing can refuse
        else:
            if (
                core.deviations.padded_writes
                and size is not None
                and size < len(data) <= 4
                and not any(data[size:])
            ):
                data = data[:size]
            value = decode_download(entry, data)
        core.write(entry, value, remote=True)
        if core.listeners or core.heard_by_network:  # anyone to hear it (see Core)
            core.emit(EntryWritten(core.node_id, index, subindex, value))

    def download_limit(self, index: int, subindex: int) -> int | None:
        """The most bytes a download of no fixed size may bring into the entry (None: the
        server's own limit)."""
        return self._core.entry(index, subindex).download_limit

    def size_hint(self, index: int, subindex: int) -> int | None:
        """The size a download to the entry must have (None: any), or the abort."""
        entry = self._core.entry(index, subindex)
        if not entry.var.access.writable:
            raise abort(_ABORT.WRITE_READ_ONLY, f"{entry.var.name!r} is {entry.var.access}")
        return entry.size


class _Channel:
    """One server channel: its machine, the host that drives it, and the subscription to its
    requests, taken only while NMT allows SDO.

    The machine goes behind the gate of a late answer (:class:`LateSdoServer`) once the
    simulation sets a response delay, and stays there until the channel is rebuilt; with no
    delay the host drives the server itself, a gate's two calls per request less.
    """

    __slots__ = ("core", "host", "number", "server", "subscription")

    def __init__(self, core: Core, number: int, server: SdoServer, rx: int) -> None:
        self.core = core
        self.number = number
        self.server = server
        late = core.simulation.sdo_response_delay > 0
        self.host = core.network.attach(LateSdoServer(server, core.simulation) if late else server)
        self.subscription = core.network.subscribe(rx, self.on_frame)

    def gate(self) -> None:
        """Put the gate of a late answer in front of the server, if it is not there yet, in
        the same host: a transfer in progress goes on with its timer as armed (the gate's
        deadline is the server's while nothing waits), and a request being served when the
        delay is set (from the application's read or write callback) ends in the same host."""
        host = self.host
        if host.machine is self.server:
            host.machine = LateSdoServer(self.server, self.core.simulation)

    def on_frame(self, frame: Frame, now: float) -> None:
        """A request: to the machine (what ``host.feed`` does, one call less per request)."""
        # sdo_allowed's slot, read directly: the device owns its NMT slave, and the property
        # would be a call on every request
        if self.core.nmt._sdo:
            host = self.host
            host.apply(host.machine.on_frame(frame, now))

    def close(self) -> None:
        self.subscription.cancel()
        self.host.close()


def define_objects(od: ObjectDictionary, *, servers: int) -> None:
    """1200h (the default channel on 600h/580h + node-ID) and ``servers - 1`` more server
    channels 1201h..., not valid until a master configures them."""
    for n in range(servers):
        index = 0x1200 + n
        if n == 0:
            server = Record(index, "SDO server parameter")
            server.add(var(index, 0, "Highest sub-index supported", U8, RO, 2))
            for sub, name, base in (
                (1, "client to server", SDO_RX_BASE),
                (2, "server to client", SDO_TX_BASE),
            ):
                server.add(var(index, sub, f"COB-ID {name}", U32, RO, NodeRelative(base)))
            od.add(server)
            continue
        composite(
            od,
            Record(index, f"SDO server parameter {n + 1}"),
            [
                (0, "Highest sub-index supported", U8, 3),
                (1, "COB-ID client to server", U32, INVALID),
                (2, "COB-ID server to client", U32, INVALID),
                (3, "Node-ID of the SDO client", U8, 0),
            ],
        )


class SdoServerService:
    """The SDO server channels of one device and their parameters 1200h-127Fh."""

    def __init__(self, core: Core, *, timeout: float, max_download: int = 1 << 20) -> None:
        self._core = core
        self._timeout = timeout
        self._max_download = max_download
        self.backend = SdoBackend(core)
        self._channels: dict[int, _Channel] = {}
        for index in range(0x1200, 0x1280):
            core.handle(index, self._w_server)
        core.follows_node_id(0x1200, 1, SDO_RX_BASE)  # the default channel of the connection set
        core.follows_node_id(0x1200, 2, SDO_TX_BASE)

    def build(self) -> None:
        """(Re)build every valid channel; transfers in progress end silently."""
        self.close()
        core = self._core
        if not core.deviations.serve_sdo:
            return
        for n in range(128):
            index = 0x1200 + n
            if n and index not in core.indices:
                continue
            if n == 0:
                rx = int(core.value(index, 1, SDO_RX_BASE + core.node_id)) & 0x7FF
                tx = int(core.value(index, 2, SDO_TX_BASE + core.node_id)) & 0x7FF
            else:
                try:
                    rx_value = core.cob_id("sdo_rx", n + 1, int(core.value(index, 1, INVALID)))
                    tx_value = core.cob_id("sdo_tx", n + 1, int(core.value(index, 2, INVALID)))
                except SdoAbort as exc:
                    core.report(f"SDO server channel {n + 1}", exc)
                    continue
                if rx_value & INVALID or tx_value & INVALID:
                    continue
                rx, tx = rx_value & 0x7FF, tx_value & 0x7FF
            server = SdoServer(
                rx,
                tx,
                self.backend,
                timeout=self._timeout,
                max_download=self._max_download,
                reports=False,
            )
            self._channels[n] = _Channel(core, n, server, rx)

    def delay_changed(self) -> None:
        """The simulation's SDO response delay changed: a delay puts every channel behind
        its gate (a delay set back to 0 leaves them there: requests still waiting keep their
        order, and the gate lets the next ones straight through)."""
        if self._core.simulation.sdo_response_delay > 0:
            for channel in self._channels.values():
                channel.gate()

    def close(self) -> None:
        """Close every channel."""
        for channel in self._channels.values():
            channel.close()
        self._channels.clear()

    def _w_server(self, entry: Entry, value: Any) -> None:
        core = self._core
        sub = entry.subindex
        if sub in (1, 2):
            kind, number = ("sdo_rx" if sub == 1 else "sdo_tx"), entry.index - 0x1200 + 1
            new = core.cob_id(kind, number, value)
            if new & EXTENDED:
                raise abort(_ABORT.INVALID_VALUE, "29-bit SDO identifiers are not supported")
            can_id = new & 0x1FFFFFFF
            if can_id > 0x7FF:
                raise abort(_ABORT.INVALID_VALUE, f"SDO identifier 0x{can_id:X} is not 11-bit")
            old = core.cob_id(kind, number, int(entry.value))
            if not old & INVALID and not new & INVALID and old & 0x7FF != can_id:
                raise abort(
                    _ABORT.INVALID_VALUE,
                    f"0x{entry.index:04X} sub {sub}: the identifier cannot change while the "
                    "channel is valid; write it with bit 31 set first",
                )
        core.store(entry, value)
        if core.started and sub in (1, 2):
            self.build()
