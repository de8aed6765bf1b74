"""Remote nodes seen from this network: SDO client channels and the NMT master service.

``node.sdo.upload/download`` move raw bytes; ``node.sdo.read/write`` convert through the node's
object dictionary (type, access and limits checked before anything is sent).
"""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from cobus._moved import renamed_names
from cobus.od import NameLookupError, parse_address, resolve, resolve_object
from cobus.proto import NOTHING, Event, Frame, Out
from cobus.proto.nmt import NmtCommand, check_node_id, nmt_command_frame
from cobus.proto.sdo import SdoClient, check_timeout
from cobus.proto.sync import SyncConfigError, SyncProducer
from cobus.runtime._service import check_not_bool, parse_nmt_command, removed_error
from cobus.runtime.emcy import AsyncRemoteEmcy
from cobus.runtime.errors import NetworkClosedError, ObjectAccessError, ObjectNotFoundError
from cobus.runtime.nmt import AsyncRemoteNmt
from cobus.runtime.pdo import AsyncPdoSet
from cobus.runtime.periodic import InterfaceTimer
from cobus.runtime.sdo_transport import SdoTransport, downloaded, refused_block, uploaded

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from cobus.od import Array, ObjectDictionary, Record, Variable
    from cobus.runtime.network import AsyncNetwork, MachineHost

__all__ = [
    "AsyncRemoteNode",
    "AsyncSdoRecord",
    "AsyncSdoVariable",
    "NetworkSync",
    "NmtCommands",
    "NmtMaster",
    "ObjectAccessError",
    "ObjectNotFoundError",
    "SdoChannel",
]

Key = int | str


class _NoValue:
    def __repr__(self) -> str:
        return "<sub-index 0>"


NO_VALUE: Any = _NoValue()


def load_od(od: ObjectDictionary | str | Path | None, node_id: int) -> ObjectDictionary | None:
    """An object dictionary from an object, or from an EDS/DCF path (``$NODEID`` = node_id;
    left unresolved for a node-ID outside 1..127, an LSS slave's FFh)."""
    if od is None or not isinstance(od, str | Path):
        return od
    from cobus.od import load

    return load(od, node_id=node_id if 1 <= node_id <= 127 else None)


class SdoChannel:
    """One SDO client channel to a server (default: 600h+id / 580h+id).

    Transfers on one channel run one after the other, in the order they were asked for —
    and with those of everyone else on this network who asks the same server (the master's
    node, another remote node object): they share one
    :class:`~cobus.runtime.sdo_transport.SdoTransport`. ``read``/``write`` and
    ``sdo[name]`` go through the node's object dictionary; ``upload``/``download`` move raw
    bytes.
    """

    #: The node-ID of the server.
    node_id: Final[int]
    #: The node's object dictionary (None: raw transfers only).
    od: Final[ObjectDictionary | None]
    #: The transport this channel's transfers queue on (shared per COB-ID pair).
    transport: Final[SdoTransport]

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        od: ObjectDictionary | None,
        *,
        rx_cob_id: int | None = None,
        tx_cob_id: int | None = None,
        timeout: float = 1.0,
        emit: bool = True,
    ) -> None:
        self.node_id = node_id
        self.od = od
        self._network = network
        self._timeout = check_timeout(timeout)
        self._emit = emit
        self.transport = network.sdo_transport(node_id, rx_cob_id=rx_cob_id, tx_cob_id=tx_cob_id)
        self._removed = False

    @property
    def client(self) -> SdoClient:
        """The protocol machine of the shared transport."""
        return self.transport.client

    @property
    def timeout(self) -> float:
        """Seconds to wait for each answer of the server (``sdo.timeout = 3`` for a slow
        device); applies from the next frame sent."""
        return self._timeout

    @timeout.setter
    def timeout(self, seconds: float) -> None:
        self._timeout = check_timeout(seconds)
        self.transport.set_timeout(self, self._timeout)

    @property
    def progress(self) -> tuple[int, int | None]:
        """(bytes moved, bytes in all or None while unknown) of this channel's transfer under
        way, for a progress bar; (0, None) between its transfers."""
        if self.transport.owner is not self:
            return 0, None
        return self.transport.client.progress

    def __repr__(self) -> str:
        od = "no dictionary" if self.od is None else f"{len(self.od)} objects"
        client = self.transport.client
        return (
            f"<SdoChannel to node {self.node_id} (0x{client.rx_cob_id:X}/"
            f"0x{client.tx_cob_id:X}, {od})>"
        )

    def close(self) -> None:
        """Release the channel (its owner is done with the node): a transfer of it under
        way fails, later ones raise; other channels to the node go on."""
        self._close()

    def _close(self) -> None:
        if self._removed:
            return
        self._removed = True
        self.transport.interrupt(
            self,
            NetworkClosedError(f"node {self.node_id} was removed during an SDO transfer"),
            removed_error(self.node_id),
        )
        self.transport.release()

    def _timeout_now(self) -> float:
        return self._timeout

    def check_open(self) -> None:
        """Raise what keeps a transfer from starting: the node was removed from its network,
        or the network is closed."""
        if self._removed:
            raise removed_error(self.node_id)
        if not self._network.connected:
            raise NetworkClosedError(f"the network is closed: no SDO with node {self.node_id}")

    def begin(
        self, start: Callable[[float], Out], finish: Callable[[Event | BaseException], None]
    ) -> Callable[[], None] | None:
        """Start a transfer now if the channel is free, for blocking code that holds the
        loop's protocol lock (see :meth:`SdoTransport.begin
        <cobus.runtime.sdo_transport.SdoTransport.begin>`); None when it is busy."""
        if self._removed or self._network._loop is None:  # (the checks, inline: every call)
            self.check_open()
        return self.transport.begin(
            start, finish, timeout=self._timeout, emit=self._emit, owner=self
        )

    async def transfer(self, start: Callable[[float], Out]) -> Event:
        """Run a transfer in its turn and return its final event (see
        :meth:`SdoTransport.transfer <cobus.runtime.sdo_transport.SdoTransport.transfer>`)."""
        self.check_open()
        return await self.transport.transfer(
            start, timeout=self._timeout_now, emit=self._emit, owner=self, check=self.check_open
        )

    async def upload(self, index: int, subindex: int = 0, *, block: bool = False) -> bytes:
        """Read the raw bytes of ``index:subindex`` from the server.

        ``block=True`` uses block upload and falls back to segmented if the server refuses it.
        """
        self.check_open()  # (transfer(), inline: one coroutine less on every transfer)
        transport = self.transport
        event = await transport.transfer(
            partial(transport.client.start_upload, index, subindex, block=block),
            timeout=self._timeout,  # (re-read from this channel if the transfer had to wait)
            emit=self._emit,
            owner=self,
            check=self.check_open,
        )
        if block and refused_block(event):
            return await self.upload(index, subindex)
        return uploaded(event)

    async def download(
        self,
        index: int,
        subindex: int,
        data: bytes,
        *,
        block: bool = False,
        size_indicated: bool = True,
    ) -> None:
        """Write raw bytes to ``index:subindex`` on the server."""
        self.check_open()  # (transfer(), inline)
        transport = self.transport
        event = await transport.transfer(
            transport.download_call(index, subindex, data, block, size_indicated),
            timeout=self._timeout,
            emit=self._emit,
            owner=self,
            check=self.check_open,
        )
        if block and refused_block(event):
            await self.download(index, subindex, data, size_indicated=size_indicated)
            return
        downloaded(event)

    # -- typed access through the object dictionary
    def variable(self, index: Key | tuple[Key, Key], subindex: Key = 0) -> Variable:
        """The object dictionary entry named by index or name, and subindex or name.

        Every form :func:`cobus.od.resolve` takes: names match with case and separators
        ignored (``"producer heartbeat time"``), a name that matches nothing gets the close
        names in its error; ``"Record.Sub"`` (as PDOs name their values), ``(index,
        subindex)`` and ``"0x1018:01"`` name a sub-object too."""
        try:
            return resolve(self._od(), index, None if subindex == 0 else subindex)
        except NameLookupError as exc:
            raise self._not_found(exc) from None

    def _od(self) -> ObjectDictionary:
        if self.od is None:
            raise ObjectNotFoundError(
                f"node {self.node_id} has no object dictionary: give one to add_remote() "
                "or use sdo.upload()/sdo.download() for raw bytes"
            )
        return self.od

    def _not_found(self, exc: Exception) -> ObjectNotFoundError:
        return ObjectNotFoundError(f"node {self.node_id}: {exc}")

    def __contains__(self, key: object) -> bool:
        """Whether the node's dictionary has what ``sdo[key]`` names (an index, a name,
        ``(index, sub)``, ``"0x1018:01"``, ``"Record.Sub"``...)."""
        if self.od is None or not isinstance(key, int | str | tuple):
            return False
        try:
            self[key]
        except (ObjectNotFoundError, ValueError, TypeError):
            return False
        return True

    def __iter__(self) -> Iterator[AsyncSdoVariable | AsyncSdoRecord]:
        """Every object of the node's dictionary, in index order."""
        return iter([self[obj.index] for obj in (self.od or ())])

    def __len__(self) -> int:
        """How many objects the node's dictionary has (0 without one)."""
        return 0 if self.od is None else len(self.od)

    def __getitem__(self, key: Key | tuple[Key, Key]) -> AsyncSdoVariable | AsyncSdoRecord:
        """An object of the node by index or name: ``await sdo["Producer heartbeat
        time"].read()``; a record or array gives its sub-objects by ``[sub]``;
        ``sdo[0x1018, 1]``, ``sdo["0x1018:01"]`` and ``sdo["Identity object.Vendor-ID"]``
        give a sub-object."""
        from cobus.od import Variable

        if isinstance(key, tuple):
            return AsyncSdoVariable(self, self.variable(key))
        od = self._od()
        address = parse_address(key) if isinstance(key, str) else None
        try:
            if address is not None and address[1] is not None:
                return AsyncSdoVariable(self, resolve(od, key))
            obj = resolve_object(od, key, suggest=False)  # ("did you mean": resolve()'s)
        except NameLookupError as exc:
            if exc.candidates or not isinstance(key, str) or address is not None:
                raise self._not_found(exc) from None
            try:  # "Record.Sub", "Record[n]", a sub-object by its own name
                return AsyncSdoVariable(self, resolve(od, key))
            except NameLookupError as inner:
                raise self._not_found(inner) from None
        if isinstance(obj, Variable):
            return AsyncSdoVariable(self, obj)
        return AsyncSdoRecord(self, obj)

    async def read(self, index: Key | tuple[Key, Key], subindex: Key = 0) -> Any:
        """Read an entry and decode it with its data type (refused at once when the EDS
        says it cannot be read; ``upload()`` reads the raw bytes regardless)."""
        var = self.variable_to_read(index, subindex)
        return var.decode(await self.upload(var.index, var.subindex))

    async def write(
        self, index: Key | tuple[Key, Key], subindex: Any = NO_VALUE, value: Any = NO_VALUE
    ) -> None:
        """Encode ``value`` with the entry's data type (access and limits checked) and write
        it: ``write(index, subindex, value)``, or ``write(index, value)`` /
        ``write(index, value=v)`` for sub-index 0 (or a ``(index, sub)`` / ``"Record.Sub"``
        index)."""
        var, data = self.value_to_write(index, subindex, value)
        await self.download(var.index, var.subindex, data)

    def variable_to_read(self, index: Key | tuple[Key, Key], subindex: Key = 0) -> Variable:
        """The entry :meth:`read` names, refused at once when the EDS says it cannot be read
        (:class:`~cobus.runtime.errors.ObjectAccessError`)."""
        var = self.variable(index, subindex)
        check_access(var, self.node_id, write=False)
        return var

    def value_to_write(
        self, index: Key | tuple[Key, Key], subindex: Any, value: Any
    ) -> tuple[Variable, bytes]:
        """The entry :meth:`write` names and ``value`` encoded for it: access and limits
        checked, nothing sent."""
        if value is NO_VALUE:
            if subindex is NO_VALUE:
                raise TypeError("write() needs the value to write")
            subindex, value = 0, subindex
        elif subindex is NO_VALUE:
            subindex = 0
        var = self.variable(index, subindex)
        check_access(var, self.node_id, write=True)
        return var, encode_for(var, value, self.node_id)


def check_access(var: Variable, node_id: int, *, write: bool) -> None:
    """Refuse before anything is sent what the EDS says the object does not allow."""
    if not (var.writable if write else var.readable):
        raise ObjectAccessError(var, node_id, write=write)


def encode_for(var: Variable, value: Any, node_id: int) -> bytes:
    """``value`` encoded for ``var``; a range error names the node and the object."""
    from cobus.od import ValueRangeError

    try:
        check_not_bool(var, value)
        return var.encode(value)
    except ValueRangeError as exc:
        where = f"0x{var.index:04X}:{var.subindex:02X}"
        raise ValueRangeError(f"node {node_id}, {var.name!r} ({where}): {exc}") from None


class AsyncSdoVariable:
    """One object of a remote node reached over SDO (``node.sdo["Device type"]``)."""

    #: The dictionary entry (name, type, access, limits).
    od: Final[Variable]
    #: The node's SDO channel it is read and written through.
    channel: Final[SdoChannel]

    def __init__(self, channel: SdoChannel, var: Variable) -> None:
        self.channel = channel
        self.od = var

    def __repr__(self) -> str:
        var = self.od
        return (
            f"<SdoVariable {var.name!r} 0x{var.index:04X}:{var.subindex:02X} of node "
            f"{self.channel.node_id}>"
        )

    @property
    def name(self) -> str:
        """The object's name in the node's dictionary."""
        return self.od.name

    @property
    def index(self) -> int:
        """The object's index."""
        return self.od.index

    @property
    def subindex(self) -> int:
        """The object's sub-index."""
        return self.od.subindex

    async def read(self) -> Any:
        """Read the value from the node and decode it."""
        check_access(self.od, self.channel.node_id, write=False)
        return self.od.decode(await self.channel.upload(self.od.index, self.od.subindex))

    async def write(self, value: Any) -> None:
        """Check ``value`` against the type, access and limits and write it to the node."""
        check_access(self.od, self.channel.node_id, write=True)
        data = encode_for(self.od, value, self.channel.node_id)
        await self.channel.download(self.od.index, self.od.subindex, data)

    async def upload(self, *, block: bool = False) -> bytes:
        """The raw bytes of the object."""
        return await self.channel.upload(self.od.index, self.od.subindex, block=block)

    async def download(self, data: bytes, *, block: bool = False) -> None:
        """Write raw bytes to the object."""
        await self.channel.download(self.od.index, self.od.subindex, data, block=block)


class AsyncSdoRecord:
    """A record or array of a remote node reached over SDO: ``[sub]`` gives its sub-objects."""

    #: The dictionary object.
    od: Final[Record | Array]
    #: The node's SDO channel its sub-objects are read and written through.
    channel: Final[SdoChannel]

    def __init__(self, channel: SdoChannel, obj: Record | Array) -> None:
        self.channel = channel
        self.od = obj

    def __repr__(self) -> str:
        return f"<SdoRecord {self.od.name!r} 0x{self.od.index:04X} of node {self.channel.node_id}>"

    @property
    def name(self) -> str:
        """The record's or array's name in the node's dictionary."""
        return self.od.name

    def __getitem__(self, subindex: Key) -> AsyncSdoVariable:
        return AsyncSdoVariable(self.channel, self.channel.variable(self.od.index, subindex))

    def __iter__(self) -> Iterator[AsyncSdoVariable]:
        return iter([AsyncSdoVariable(self.channel, var) for var in self.od])

    def __len__(self) -> int:
        return len(self.od)

    def __contains__(self, subindex: object) -> bool:
        """Whether the record has the sub-object (number or name, as ``[sub]`` takes it)."""
        if not isinstance(subindex, int | str):
            return False
        try:
            self.channel.variable(self.od.index, subindex)
        except ObjectNotFoundError:
            return False
        return True


class NmtCommands:
    """The NMT commands by name, on top of :meth:`send` (shared by the async and blocking
    faces of the NMT master)."""

    def send(self, command: NmtCommand | int | str, node_id: int = 0) -> None:
        """Send NMT ``command`` (enum, number or name such as ``"start"``) to ``node_id`` (0: every
        node)."""
        raise NotImplementedError

    def start(self, node_id: int = 0) -> None:
        """Start ``node_id`` (0: every node): NMT state OPERATIONAL."""
        self.send(NmtCommand.START, node_id)

    def stop(self, node_id: int = 0) -> None:
        """Stop ``node_id`` (0: every node): NMT state STOPPED."""
        self.send(NmtCommand.STOP, node_id)

    def enter_preoperational(self, node_id: int = 0) -> None:
        """Put ``node_id`` (0: every node) into PRE-OPERATIONAL."""
        self.send(NmtCommand.ENTER_PREOPERATIONAL, node_id)

    def reset_node(self, node_id: int = 0) -> None:
        """Reset the application of ``node_id`` (0: every node)."""
        self.send(NmtCommand.RESET_NODE, node_id)

    def reset_communication(self, node_id: int = 0) -> None:
        """Reset the communication of ``node_id`` (0: every node)."""
        self.send(NmtCommand.RESET_COMMUNICATION, node_id)


class NmtMaster(NmtCommands):
    """Sends NMT commands (``net.nmt.send(NmtCommand.START, 0)`` starts every node)."""

    def __init__(self, network: AsyncNetwork) -> None:
        self._network = network
        self._observers: list[Callable[[int, int], object]] = []

    def send(self, command: NmtCommand | int | str, node_id: int = 0) -> None:
        """Send NMT ``command`` (enum, number or name such as ``"start"``) to ``node_id`` (0: every
        node)."""
        command = parse_nmt_command(command)
        check_node_id(node_id, broadcast=True)
        self._network.send(nmt_command_frame(command, node_id))
        for observer in list(self._observers):
            try:
                observer(int(command), node_id)
            except Exception as exc:
                self._network.report_failure("NMT command observer", exc)

    def add_observer(self, callback: Callable[[int, int], object]) -> None:
        """Call ``callback(command, node_id)`` for each NMT command this network sends (here
        or through a remote node's ``nmt``): a master learns the states its own application
        asks for, and tells them from someone else's commands on the bus."""
        self._observers.append(callback)

    def remove_observer(self, callback: Callable[[int, int], object]) -> None:
        """Stop calling ``callback`` (see :meth:`add_observer`)."""
        if callback in self._observers:
            self._observers.remove(callback)


class AsyncRemoteNode:
    """A node on the bus that this network talks to as a client (master side).

    ``sdo`` reads and writes its objects, ``nmt`` follows its state and commands it, ``emcy``
    keeps its emergencies, ``tpdo`` / ``rpdo`` receive and send its process data. Give it
    the node's EDS/DCF (``net.add_remote(2, "drive.eds")``) to use names and types.
    """

    #: The node-ID, 1..127.
    node_id: Final[int]
    #: The node's object dictionary (from its EDS/DCF), or None.
    od: Final[ObjectDictionary | None]
    #: The SDO client channel to the node's default SDO server.
    sdo: Final[SdoChannel]
    #: The node's NMT state, commands to it, heartbeat supervision.
    nmt: Final[AsyncRemoteNmt]
    #: The node's emergencies.
    emcy: Final[AsyncRemoteEmcy]
    #: The node's transmit PDOs (received here).
    tpdo: Final[AsyncPdoSet]
    #: The node's receive PDOs (sent from here).
    rpdo: Final[AsyncPdoSet]
    #: The network the node is on.
    network: Final[AsyncNetwork]

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        od: ObjectDictionary | None = None,
        *,
        sdo_timeout: float = 1.0,
    ) -> None:

        check_node_id(node_id)
        self.node_id = node_id
        self.od = od
        self.network = network
        self.sdo = SdoChannel(network, node_id, od, timeout=sdo_timeout)
        self.nmt = AsyncRemoteNmt(network, node_id)
        self.emcy = AsyncRemoteEmcy(network, node_id)
        self.tpdo = AsyncPdoSet(network, self.sdo, transmit_by_node=True)
        self.rpdo = AsyncPdoSet(network, self.sdo, transmit_by_node=False)

    def __repr__(self) -> str:
        return f"RemoteNode({self.node_id})"

    def _close(self) -> None:
        self.tpdo._close()
        self.rpdo._close()
        self.emcy._close()
        self.nmt._close()
        self.sdo._close()


class NetworkSync:
    """The SYNC producer of this network: ``net.sync.start(0.01)`` sends SYNC every 10 ms.

    The network's loop times it, or, with ``start(..., by_interface=True)``, the CAN interface
    itself (SocketCAN's kernel: no Python pause can delay it; see
    :mod:`cobus.runtime.periodic`).
    """

    def __init__(self, network: AsyncNetwork) -> None:
        self._network = network
        self._producer: SyncProducer | None = None
        self._host: MachineHost | None = None
        self._timer: InterfaceTimer | None = None
        self._wanted = False  # the interface's SYNC: started, not stopped (resumed on connect)
        network.on_connect(self._connected)  # (a timer stops itself on disconnect)

    @property
    def running(self) -> bool:
        """Whether SYNC is being sent periodically (or will be again once the network
        connects: it resumes, as it does after a disconnect)."""
        return self._host is not None or self.by_interface

    @property
    def by_interface(self) -> bool:
        """Whether the CAN interface times the SYNC (``start(..., by_interface=True)``;
        False once the interface's sending ended on its own: a bus shut down)."""
        timer = self._timer
        return timer is not None and (
            timer.running or (self._wanted and not self._network.connected)
        )

    @property
    def period(self) -> float | None:
        """The SYNC period in seconds, or None while stopped."""
        if self._timer is not None:
            return self._timer.period if self.by_interface else None
        if self._producer is None or self._host is None:
            return None
        return self._producer.period_us / 1e6

    @property
    def late_max(self) -> float:
        """The longest delay of a SYNC behind its time so far, in seconds (the host was busy).

        0 while the interface times the SYNC: what it sends late, cobus cannot see."""
        return 0.0 if self._producer is None else self._producer.late_max

    @property
    def skipped(self) -> int:
        """SYNC periods that passed without a SYNC because the host was busy for longer
        (0 while the interface times the SYNC, see :attr:`late_max`)."""
        return 0 if self._producer is None else self._producer.skipped

    @property
    def send_errors(self) -> int:
        """SYNCs the interface's sending thread could not send since the last
        ``start(..., by_interface=True)`` (python-can's udp_multicast: the 1st, 10th,
        100th... are reported as :class:`~cobus.runtime.HandlerFailed`); 0 otherwise."""
        return 0 if self._timer is None else self._timer.errors

    def start(
        self, period: float, *, overflow: int = 0, cob_id: int = 0x80, by_interface: bool = False
    ) -> None:
        """Send SYNC every ``period`` seconds (the first one period from now; by the
        interface, at once).

        ``overflow`` 2..240 adds the CiA 301 counter (1..overflow) to each SYNC; 0 = no counter.

        ``by_interface=True`` hands the SYNC, counter included, to the CAN interface: on
        SocketCAN the kernel sends it, so that no garbage collection, busy thread or burst of
        frames in this process delays it (the first goes out at once). The network still
        hears each SYNC, from the bus. A network that disconnects and connects again
        resumes it.
        :class:`~cobus.runtime.periodic.InterfaceTimingError` where the interface cannot do
        that (only SocketCAN and python-can's udp_multicast can, see
        :mod:`cobus.runtime.periodic`).
        """
        us = round(period * 1e6) if math.isfinite(period) else 0  # (NaN, inf: out of range)
        if not 1 <= us <= 0xFFFFFFFF:
            raise ValueError(
                f"SYNC period {period!r} s is out of range: 1006h holds 1 us to 4294.967295 s"
            )
        self._network.loop  # noqa: B018  # NetworkClosedError, before the SYNC running stops
        producer = SyncProducer(cob_id, overflow=overflow)
        if by_interface:
            counts = range(1, overflow + 1) if overflow else (None,)
            frames = [
                Frame(cob_id) if count is None else Frame(cob_id, bytes((count,)))
                for count in counts
            ]
            timer = InterfaceTimer(self._network, frames, us / 1e6)  # (raises before stop)
            self.stop()  # never two at once
            self._producer = producer
            self._timer = timer
            timer.start()
            self._wanted = True
            return
        self.stop()
        self._timer = None
        producer.set_period(us, self._network.time())
        self._producer = producer
        self._host = self._network.attach(producer)
        self._host.apply(NOTHING)

    def send(self) -> None:
        """Send one SYNC now, outside the period (e.g. once per application cycle).

        Not while the interface sends SYNC with a counter
        (:class:`~cobus.proto.sync.SyncConfigError`): it keeps the count, and a SYNC in
        between would break it."""
        if self.by_interface and self._producer is not None and self._producer.overflow:
            raise SyncConfigError(
                "the interface is sending SYNC with a counter: a SYNC in between would break "
                "its count; stop() it first, or start it without by_interface"
            )
        producer = self._producer or SyncProducer()
        self._producer = producer
        for frame in producer.send(self._network.time()).frames:
            self._network.send(frame)

    def stop(self) -> None:
        """Stop sending SYNC."""
        if self._host is not None:
            self._host.close()
            self._host = None
        self._wanted = False
        if self._timer is not None:
            self._timer.stop()  # (kept: its send_errors)

    def _connected(self) -> None:
        """Start the interface's SYNC again, as the loop's producer resumes."""
        old = self._timer
        if not self._wanted or old is None or old.running:
            return
        timer = InterfaceTimer(self._network, old.frames, old.period)
        self._timer = timer  # (its send_errors start again)
        timer.start()


#: The async classes are AsyncX, their blocking twins X (see :mod:`cobus`).
__getattr__ = renamed_names(
    __name__,
    {
        "RemoteNode": ("AsyncRemoteNode", AsyncRemoteNode),
        "SdoRecord": ("AsyncSdoRecord", AsyncSdoRecord),
        "SdoVariable": ("AsyncSdoVariable", AsyncSdoVariable),
        "SyncService": ("NetworkSync", NetworkSync),
    },
)
