"""CAN network variables between controllers: each controller writes the lists it sends and
reads the others', on the same :class:`~cobus.runtime.AsyncNetwork` as its master or device.

>>> lists = AsyncNetworkVariables(network, load_netvars("plant.yml"), me="plc1")
>>> lists.start()
>>> lists["line_status.speed"] = 12.5          # a list plc1 sends
>>> lists["alarms.code"]                       # a list another controller sends

A list is sent as the definition says (cyclic, on change with a minimum gap, on the rising
edge of its event variable, or by :meth:`AsyncNetworkVariables.send`), and when a reader asks
at boot-up. A reader takes a list's values only as a whole set of one transmission; a set
with a frame missing is reported (:class:`ListIncomplete`) and dropped, never mixed with the
next one. The wire format: ``docs/network-variables.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import logging
import socket
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from cobus.blocks.netvar_lists import NetVarDefinition, VarList
from cobus.blocks.netvar_udp import (
    DATA,
    DEFAULT_PORT,
    Telegram,
    TelegramError,
    UdpDefinition,
    UdpVarList,
)
from cobus.proto import Event, Frame
from cobus.runtime.errors import NetworkClosedError
from cobus.runtime.twin import BlockingTwin

__all__ = [
    "AsyncNetworkVariables",
    "AsyncUdpNetworkVariables",
    "ListIncomplete",
    "ListMalformed",
    "ListReceived",
    "ListRequested",
    "ListSendFailed",
    "ListStale",
    "NetVarEvent",
    "NetworkVariables",
]

log = logging.getLogger(__name__)

#: A cyclic list counts as stale after this many intervals without a complete set.
STALE_INTERVALS = 3
#: Seconds the frames of one transmission may take to come in (at most half a cyclic
#: list's interval); a partial set older than that is dropped, never completed by frames
#: of a later transmission with the same counter.
SET_WINDOW = 0.1
#: Seconds between a reader's requests at boot-up until the list comes (at most 10).
REQUEST_RETRY = 1.0


#: A list of either form: over CAN (YAML) or over UDP (.gvl).
AnyList = VarList | UdpVarList


def _modes(lst: AnyList) -> frozenset[str]:
    """How a list is sent: one way over CAN; CODESYS may combine them over UDP."""
    return lst.modes if isinstance(lst, UdpVarList) else frozenset({lst.transmit})


@dataclass(frozen=True, slots=True)
class NetVarEvent(Event):
    """Base of the events of the network variables; ``list`` names the list."""

    list: str
    time: float


@dataclass(frozen=True, slots=True)
class ListReceived(NetVarEvent):
    """A complete set of a list came in: its values (flattened names)."""

    values: Mapping[str, Any]
    counter: int | None

    def __str__(self) -> str:
        return f"list {self.list}: received"


@dataclass(frozen=True, slots=True)
class ListIncomplete(NetVarEvent):
    """A transmission of a list lost frames: ``missing`` frame numbers (0 = first) of the
    set with ``counter``; the set was dropped."""

    counter: int
    missing: tuple[int, ...]

    def __str__(self) -> str:
        frames = ", ".join(str(n) for n in self.missing)
        return f"list {self.list}: frame(s) {frames} of transmission {self.counter} missing"


@dataclass(frozen=True, slots=True)
class ListMalformed(NetVarEvent):
    """A frame on a list's COB-ID (over UDP: a telegram of the list, ``cob_id`` its
    identifier, ``telegram`` true) that does not fit the definition (the definitions on
    the controllers differ?)."""

    cob_id: int
    reason: str
    telegram: bool = False

    def __str__(self) -> str:
        if self.telegram:
            return f"list {self.list} (identifier {self.cob_id}): {self.reason}"
        return f"list {self.list}: frame {self.cob_id:03X}h: {self.reason}"


@dataclass(frozen=True, slots=True)
class ListStale(NetVarEvent):
    """A cyclic list sent no complete set for ``silence`` seconds (its writer is gone?)."""

    silence: float

    def __str__(self) -> str:
        return f"list {self.list}: nothing for {self.silence:.3g} s"


@dataclass(frozen=True, slots=True)
class ListSendFailed(NetVarEvent):
    """A transmission of a list this controller writes could not go out (backlog full,
    network closed); the next one is tried as usual."""

    reason: str

    def __str__(self) -> str:
        return f"list {self.list}: not sent: {self.reason}"


@dataclass(frozen=True, slots=True)
class ListRequested(NetVarEvent):
    """A reader asked for a list this controller sends (at its boot-up)."""

    def __str__(self) -> str:
        return f"list {self.list}: requested"


class _Writer:
    def __init__(self, owner: AsyncNetworkVariables, var_list: AnyList) -> None:
        self.owner = owner
        self.list = var_list
        self.counter = 0
        self.last_payload: bytes | None = None
        self.last_sent: float | None = None
        self.pending: asyncio.TimerHandle | None = None
        self.timer: asyncio.TimerHandle | None = None
        self.due = 0.0
        self.sent = 0
        self.failed = 0

    def start(self) -> None:
        modes = _modes(self.list)
        if "cyclic" in modes:
            self.due = self.owner._time()
            self._cycle()
        elif "on_change" in modes:
            self.send()  # the values it starts with: a reader that came first has them

    def _cycle(self) -> None:
        assert self.list.interval is not None
        try:
            self.send()
        finally:  # (a failed transmission does not end the cycle)
            self.due += self.list.interval
            now = self.owner._time()
            if self.due < now:  # late (a busy loop): skip, do not burst
                self.due = now
            self.timer = self.owner._loop().call_at(self.due, self._cycle)

    def changed(self, edges: set[str]) -> None:
        lst = self.list
        modes = _modes(lst)
        if "on_event" in modes and lst.event is not None and lst.event in edges:
            self.send()
        if "on_change" in modes:
            payload = self.owner._payload(lst)
            if payload == self.last_payload or self.pending is not None:
                return
            now = self.owner._time()
            wait = 0.0 if self.last_sent is None else self.last_sent + lst.min_gap - now
            if wait <= 0:
                self.send()
            else:
                self.pending = self.owner._loop().call_later(wait, self._deferred)

    def _deferred(self) -> None:
        self.pending = None
        if self.owner._payload(self.list) != self.last_payload:
            self.send()

    def send(self) -> None:
        lst = self.list
        owner = self.owner
        payload = owner._payload(lst)
        counter, self.counter = self.counter, (self.counter + 1) % owner._COUNTER_WRAP
        self.last_payload = payload
        self.last_sent = owner._time()
        try:
            owner._transmit(lst, payload, counter)
        except Exception as exc:  # backlog full, network closed: said, and tried again later
            self.failed += 1
            self.last_payload = None
            owner._emit(ListSendFailed(lst.name, owner._time(), str(exc) or repr(exc)))
            return
        self.sent += 1

    def stop(self) -> None:
        for handle in (self.pending, self.timer):
            if handle is not None:
                handle.cancel()
        self.pending = self.timer = None


class _Reader:
    def __init__(self, owner: AsyncNetworkVariables, var_list: AnyList) -> None:
        self.owner = owner
        self.list = var_list
        self.parts: dict[int, bytes] = {}
        self.counter: int | None = None
        self.began = 0.0
        self.done: tuple[int, float] | None = None  # the counter completed last, and when
        self.received_at: float | None = None
        self.watch: asyncio.TimerHandle | None = None
        self.asking: asyncio.TimerHandle | None = None
        self.stale = False
        self.received = 0
        self.incomplete = 0
        self.malformed = 0
        #: Telegrams with flags cobus cannot honour (acknowledgement, checksum): dropped.
        self.flagged = 0
        #: Telegrams of a transmission already taken, or older (UDP): dropped.
        self.late = 0
        interval = var_list.interval
        self.window = min(SET_WINDOW, interval / 2) if interval else SET_WINDOW

    def start(self) -> None:
        if self.list.request_at_boot:
            self._ask(10)
        self._arm()

    def _ask(self, tries: int) -> None:
        """Request the list (a remote frame on its first COB-ID), again until it comes."""
        self.asking = None
        if self.received or tries <= 0:
            return
        self.owner._request(self.list)
        self.asking = self.owner._loop().call_later(REQUEST_RETRY, self._ask, tries - 1)

    def _arm(self) -> None:
        interval = self.list.interval
        if self.list.transmit != "cyclic" or interval is None:
            return
        if self.watch is not None:
            self.watch.cancel()
        self.watch = self.owner._loop().call_later(interval * STALE_INTERVALS, self._silent)

    def _silent(self) -> None:
        self.watch = None
        if not self.stale:
            self.stale = True
            assert self.list.interval is not None
            silence = self.list.interval * STALE_INTERVALS
            self.owner._emit(ListStale(self.list.name, self.owner._time(), silence))

    def on_frame(self, frame: Frame, now: float) -> None:
        lst = self.list
        assert isinstance(lst, VarList)
        if frame.rtr:
            return  # another reader's request
        k = frame.cob_id - lst.cob_id
        data = bytes(frame.data)
        if not lst.headed:
            if len(data) != lst.size:
                self._malformed(frame, now, f"{len(data)} bytes, the list has {lst.size}")
                return
            self._complete(data, None, now)
            return
        if k >= lst.frames:
            self._malformed(frame, now, f"frame {k}: the list has {lst.frames} frame(s)")
            return
        chunk = min(7, lst.size - 7 * k)
        if len(data) != chunk + 1:
            self._malformed(frame, now, f"{len(data)} bytes, frame {k} has {chunk + 1}")
            return
        self.take(k, data[0], data[1:], now)

    def take(self, k: int, counter: int, part: bytes, now: float) -> None:
        """Part ``k`` of the transmission ``counter`` (checked against the definition):
        a list is taken only whole, from the parts of one transmission."""
        lst = self.list
        if self.done is not None and self.done[0] == counter and now - self.done[1] <= self.window:
            return  # a frame of the set just completed, again: nothing new
        if self.parts and (counter != self.counter or now - self.began > self.window):
            self._drop(now)  # another transmission (or one too old to finish): no mixing
        if k in self.parts:
            if self.parts[k] == part:
                return  # the same frame twice
            self._drop(now)
        if not self.parts:
            self.counter, self.began = counter, now
        self.parts[k] = part
        if len(self.parts) == lst.frames:
            payload = b"".join(self.parts[n] for n in range(lst.frames))
            self.parts = {}
            self.done = (counter, now)
            self._complete(payload, counter, now)

    def _drop(self, now: float) -> None:
        if self.parts and self.counter is not None:
            missing = tuple(n for n in range(self.list.frames) if n not in self.parts)
            self.incomplete += 1
            self.owner._emit(ListIncomplete(self.list.name, now, self.counter, missing))
        self.parts = {}

    def _malformed(self, frame: Frame, now: float, reason: str) -> None:
        self.malformed_at(frame.cob_id, now, reason)

    def malformed_at(self, cob_id: int, now: float, reason: str) -> None:
        """A frame (or telegram: ``cob_id`` the list identifier) that does not fit."""
        self.malformed += 1
        udp = isinstance(self.list, UdpVarList)
        self.owner._emit(ListMalformed(self.list.name, now, cob_id, reason, udp))

    def _complete(self, payload: bytes, counter: int | None, now: float) -> None:
        values = self.list.unpack(payload)
        self.owner._values[self.list.name].update(values)
        self.received_at = now
        self.received += 1
        self.stale = False
        self._arm()
        self.owner._emit(ListReceived(self.list.name, now, values, counter))

    def stop(self) -> None:
        for handle in (self.watch, self.asking):
            if handle is not None:
                handle.cancel()
        self.watch = self.asking = None
        self.parts = {}
        self.counter = None


class AsyncNetworkVariables:
    """The lists of ``definition`` on ``network`` as controller ``me``: the lists whose
    ``sender`` is ``me`` are written, all others read. Call :meth:`start` on the loop."""

    def __init__(
        self, network: Any, definition: NetVarDefinition | UdpDefinition, *, me: str
    ) -> None:
        if isinstance(definition, UdpDefinition) and not isinstance(self, AsyncUdpNetworkVariables):
            raise TypeError("lists over UDP (.gvl): use AsyncUdpNetworkVariables")
        if definition.controllers and me not in definition.controllers:
            raise ValueError(
                f"controller {me!r} is not in the definition ({', '.join(definition.controllers)})"
            )
        self.network = network
        self.definition = definition
        self.me = me
        self._values: dict[str, dict[str, Any]] = {
            name: {v.name: v.zero for v in lst.variables} for name, lst in definition.lists.items()
        }
        self._writers = {
            name: _Writer(self, lst) for name, lst in definition.lists.items() if lst.sender == me
        }
        self._readers = {
            name: _Reader(self, lst) for name, lst in definition.lists.items() if lst.sender != me
        }
        self._listeners: list[Callable[[NetVarEvent], object]] = []
        self._subs: list[Any] = []
        self._started = False
        self._closed = False

    # ------------------------------------------------------------------ life cycle

    def start(self) -> None:
        """Listen to the lists it reads, answer requests for those it writes, start the
        cyclic ones and ask for the ``request_at_boot`` ones (call on the network's loop)."""
        if self._started:
            return
        net = self.network
        if not net.connected:
            raise NetworkClosedError("the network is not connected: connect it first")
        self._started = True
        self._closed = False
        for reader in self._readers.values():
            assert isinstance(reader.list, VarList)
            for cob_id in reader.list.cob_ids:
                self._subs.append(net.subscribe(cob_id, reader.on_frame))
        for writer in self._writers.values():
            assert isinstance(writer.list, VarList)
            self._subs.append(net.subscribe(writer.list.cob_id, self._request_handler(writer)))
        for writer in self._writers.values():
            writer.start()
        for reader in self._readers.values():
            reader.start()

    def _request_handler(self, writer: _Writer) -> Callable[[Frame, float], None]:
        def on_frame(frame: Frame, now: float) -> None:
            if frame.rtr:
                self._emit(ListRequested(writer.list.name, now))
                writer.send()

        return on_frame

    def close(self) -> None:
        """Stop sending and listening."""
        for sub in self._subs:
            sub.cancel()
        self._subs.clear()
        for writer in self._writers.values():
            writer.stop()
        for reader in self._readers.values():
            reader.stop()
        self._started = False
        self._closed = True

    def _send(self, frame: Frame) -> None:
        try:
            self.network.send(frame)
        except Exception as exc:  # (a request that cannot go out is tried again)
            log.warning("network variables: %s not sent: %s", frame, exc)

    # ------------------------------------------------------------------ the transport
    # (what the CAN form and the UDP form do each their own way)

    #: A list's transmission counter wraps here.
    _COUNTER_WRAP = 0x100

    def _time(self) -> float:
        return float(self.network.time())

    def _loop(self) -> asyncio.AbstractEventLoop:
        loop: asyncio.AbstractEventLoop = self.network.loop
        return loop

    def _transmit(self, lst: AnyList, payload: bytes, counter: int) -> None:
        """Send one transmission of a list (an exception: it failed)."""
        assert isinstance(lst, VarList)
        for k, data in enumerate(lst.split(payload, counter)):
            self.network.send(Frame(lst.cob_id + k, data))

    def _request(self, lst: AnyList) -> None:
        """Ask for a list (a remote frame on its first COB-ID)."""
        assert isinstance(lst, VarList)
        self._send(Frame(lst.cob_id, rtr=True, dlc=lst.size if not lst.headed else 8))

    def _check_running(self) -> None:
        if self._closed:
            raise NetworkClosedError("the network variables were closed")

    # ------------------------------------------------------------------ values

    def _split(self, name: str) -> tuple[AnyList, str]:
        list_name, dot, var = name.partition(".")
        if not dot:
            raise KeyError(f"{name!r}: name a variable as LIST.VARIABLE")
        lst = self.definition[list_name]
        lst.variable(var)  # KeyError names the variables there are
        return lst, var

    def __getitem__(self, name: str) -> Any:
        lst, var = self._split(name)
        return self._values[lst.name][var]

    def __setitem__(self, name: str, value: Any) -> None:
        lst, var = self._split(name)
        self.set(lst.name, {var: value})

    def values(self, list_name: str) -> dict[str, Any]:
        """The values of a list (as last set, or as last received complete)."""
        return dict(self._values[self.definition[list_name].name])

    def set(self, list_name: str, values: Mapping[str, Any]) -> None:
        """Set variables of a list this controller writes, together (one transmission at
        most for them); each value is checked against its type first."""
        lst = self.definition[list_name]
        writer = self._writers.get(lst.name)
        if writer is None:
            raise PermissionError(
                f"list {lst.name!r} is written by {lst.sender!r}, not by {self.me!r}"
            )
        self._check_running()
        normal = {}
        for var_name, value in values.items():
            var = lst.variable(var_name)
            normal[var_name] = var.decode(var.encode(value))  # ValueError before any change
        stored = self._values[lst.name]
        edges = {name for name, value in normal.items() if value and not stored.get(name)}
        stored.update(normal)  # (as a reader will see them: 1 is True, REAL32 rounded)
        if self._started:
            writer.changed(edges)

    def send(self, list_name: str) -> None:
        """Send a list this controller writes now (an event; after :meth:`start`)."""
        lst = self.definition[list_name]
        self._check_running()
        if not self._started:
            raise NetworkClosedError("start() the network variables first")
        writer = self._writers.get(lst.name)
        if writer is None:
            raise PermissionError(
                f"list {lst.name!r} is written by {lst.sender!r}, not by {self.me!r}"
            )
        writer.send()

    def age(self, list_name: str) -> float | None:
        """Seconds since a list this controller reads came complete (None: never yet)."""
        reader = self._readers.get(self.definition[list_name].name)
        if reader is None or reader.received_at is None:
            return None
        return self._time() - reader.received_at

    def statistics(self) -> dict[str, dict[str, int]]:
        """Per list: transmissions sent, or complete sets received and incomplete ones."""
        out: dict[str, dict[str, int]] = {}
        for name, writer in self._writers.items():
            out[name] = {"sent": writer.sent, "failed": writer.failed}
        for name, reader in self._readers.items():
            out[name] = {
                "received": reader.received,
                "incomplete": reader.incomplete,
                "malformed": reader.malformed,
            }
            if isinstance(reader.list, UdpVarList):
                out[name]["flagged"] = reader.flagged
                out[name]["late"] = reader.late
        return out

    def stale(self, list_name: str) -> bool:
        """Whether a cyclic list this controller reads brought no complete set for
        3 intervals (until the next one comes)."""
        reader = self._readers.get(self.definition[list_name].name)
        return reader is not None and reader.stale

    def _payload(self, lst: AnyList) -> bytes:
        if isinstance(lst, VarList):
            return lst.pack(self._values[lst.name])
        return lst.pack_values(self._values[lst.name])

    # ------------------------------------------------------------------ events

    def add_listener(self, listener: Callable[[NetVarEvent], object]) -> None:
        """Call ``listener(event)`` for each :class:`ListReceived`, :class:`ListIncomplete`,
        :class:`ListMalformed`, :class:`ListStale`, :class:`ListRequested` and
        :class:`ListSendFailed` (on the network's loop; a blocking network's callback
        thread for :class:`NetworkVariables`)."""
        self._listeners.append(listener)

    def remove_listener(self, listener: Callable[[NetVarEvent], object]) -> None:
        """Stop calling ``listener``."""
        if listener in self._listeners:
            self._listeners.remove(listener)

    def _emit(self, event: NetVarEvent) -> None:
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception:  # an application's failure must not stop the lists
                log.exception("network variable listener %r failed", listener)


#: A telegram this many transmissions behind the last one taken (within LATE_WINDOW seconds
#: of it), or behind the one being gathered (within the list's set window), is late and
#: dropped: a datagram twice, or reordered. Further behind, or later, it is a sender that
#: started again (its counter anew), and taken.
LATE_TRANSMISSIONS = 16
LATE_WINDOW = 0.25
#: Seconds between two requests of a list it answers (more in between: one transmission).
REQUEST_GAP = 0.1


def _loopback(host: str) -> bool:
    host = host.removeprefix("::ffff:")
    return host == "localhost" or host.startswith("127.") or host == "::1"


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, owner: AsyncUdpNetworkVariables) -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        try:
            self.owner.datagram(data, addr)
        except Exception:  # (a telegram must never stop the lists)
            log.exception("network variables: datagram from %s", addr)

    def error_received(self, exc: Exception) -> None:
        log.warning("network variables: %s", exc)


class AsyncUdpNetworkVariables(AsyncNetworkVariables):
    """Network variables over UDP, as CODESYS controllers exchange them: the lists of
    ``definition`` (:class:`~cobus.blocks.netvar_udp.UdpDefinition`, e.g. from ``.gvl``
    files); the lists named in ``send`` are written, the others read. The same values,
    events, statistics and transmission modes as over CAN.

    >>> lists = AsyncUdpNetworkVariables(UdpDefinition.of([load_gvl("plant.gvl")]))
    >>> await lists.open()                       # 127.0.0.1:1202
    >>> lists["plant.speed"]

    It listens on ``bind``:``port`` (127.0.0.1 unless told: ``"0.0.0.0"`` for telegrams
    from other hosts) and sends each list to ``to`` (host, port), else to the address and
    port of its definition; a broadcast address needs ``broadcast=True``. Datagrams that
    are no telegram, of lists it does not know, or with the acknowledgement or checksum
    flags are counted (:meth:`dropped`) and dropped, never a crash. ``first_counter``: the
    counter of the first transmission (a one-shot sender starts elsewhere each time, so a
    receiver does not take it for a repeat). ``share_port``: listen on a port another
    program on this host listens on too, a CODESYS runtime (which must allow it as well):
    each gets the broadcasts (bind 0.0.0.0 for those of the network), but a datagram sent
    to this host's address goes to one of them only (on Linux the one bound last)."""

    _COUNTER_WRAP = 0x10000

    def __init__(
        self,
        definition: UdpDefinition,
        *,
        send: Any = (),
        bind: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        to: tuple[str, int] | None = None,
        broadcast: bool = False,
        first_counter: int = 0,
        share_port: bool = False,
    ) -> None:
        sent = set(send)
        for what, number in (("port", port), ("port of to", to[1] if to else 0)):
            if not 0 <= number <= 0xFFFF:
                raise ValueError(f"{what} {number}: a UDP port is 0..65535")
        unknown = sent - set(definition.lists)
        if unknown:
            raise KeyError(
                f"no variable list {', '.join(sorted(unknown))}; the lists: "
                f"{', '.join(definition.lists)}"
            )
        ids: dict[int, str] = {}
        for lst in definition.lists.values():
            if lst.list_id in ids:
                raise ValueError(
                    f"lists {ids[lst.list_id]} and {lst.name} have one identifier, "
                    f"{lst.list_id}: give each list its own"
                )
            ids[lst.list_id] = lst.name
        mine = {
            n: dataclasses.replace(lst, sender="cobus" if n in sent else "")
            for n, lst in definition.lists.items()
        }
        super().__init__(None, UdpDefinition(mine), me="cobus")
        self.bind = bind
        self.port = port
        self.to = to
        self.broadcast = broadcast
        self.share_port = share_port
        self._socket: socket.socket | None = None
        self._transport: asyncio.DatagramTransport | None = None
        self._event_loop: asyncio.AbstractEventLoop | None = None
        self._by_id = {lst.list_id: lst.name for lst in mine.values()}
        #: Datagrams taken, and those dropped by why.
        self._counts = {
            "datagrams": 0,
            "not_telegrams": 0,
            "foreign": 0,
            "of_own_lists": 0,
            "requests": 0,
        }
        self._answered: dict[str, float] = {}  # (a list's last request answered, when)
        #: Each destination (host, port): its address, or why there is none.
        self._resolved: dict[tuple[str, int], tuple[str, int] | Exception] = {}
        for writer in self._writers.values():
            writer.counter = first_counter % self._COUNTER_WRAP
        self._opening = False
        #: The last datagram that was no telegram: who sent it and why.
        self.last_junk: tuple[Any, str] | None = None

    @property
    def address(self) -> tuple[str, int]:
        """Where it listens (the port the system gave, with ``port=0``)."""
        if self._socket is None:
            return self.bind, self.port
        host, port = self._socket.getsockname()[:2]
        return str(host), int(port)

    async def open(self) -> None:
        """Open the socket and :meth:`start` the lists (on the running loop)."""
        if self._transport is not None or self._opening:
            return
        loop = asyncio.get_running_loop()
        family = socket.AF_INET6 if ":" in self.bind else socket.AF_INET
        self._opening = True
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            if self.broadcast:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            if family == socket.AF_INET6:  # (IPv4 peers too, where the system allows it)
                with contextlib.suppress(OSError, AttributeError):
                    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
            if self.share_port:  # (a CODESYS runtime on this host listens on 1202 too)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self.bind, self.port))
            sock.setblocking(False)
            transport, _ = await loop.create_datagram_endpoint(lambda: _Datagrams(self), sock=sock)
        except OSError as exc:
            sock.close()
            raise OSError(
                f"cannot listen on {self.bind}:{self.port}: {exc.strerror or exc}"
            ) from None
        except BaseException:
            sock.close()
            raise
        finally:
            self._opening = False
        self._socket, self._transport, self._event_loop = sock, transport, loop
        self._closed = False
        await self._look_up(loop, family)
        self.start()

    async def _look_up(self, loop: asyncio.AbstractEventLoop, family: int) -> None:
        """Each destination's address, looked up once here (never a name lookup on the
        loop when a list goes out); what cannot be found is said when it would be sent."""
        wanted = {self.to} if self.to else set()
        for lst in self.definition.lists.values():
            if not self.to and isinstance(lst, UdpVarList):
                wanted.add((lst.address, lst.port))
        for host, port in wanted:
            if ":" in host and family != socket.AF_INET6:
                self._resolved[(host, port)] = OSError(
                    f"cannot send to {host}: an IPv6 address needs an IPv6 bind (::1, or :: "
                    "for every interface)"
                )
                continue
            try:
                found = await loop.getaddrinfo(
                    host,
                    port,
                    family=family if family == socket.AF_INET else 0,
                    type=socket.SOCK_DGRAM,
                )
            except OSError as exc:
                why = exc.strerror or str(exc)
                self._resolved[(host, port)] = OSError(
                    f"cannot send to {host}: no such host ({why})"
                )
                continue
            found_family, *_, address = found[0]
            ip = str(address[0])
            if family == socket.AF_INET6 and found_family == socket.AF_INET:
                ip = "::ffff:" + ip  # (an IPv4 peer from a dual-stack socket)
            self._resolved[(host, port)] = (ip, port)

    def start(self) -> None:
        """Start the lists (after :meth:`open`, which calls it)."""
        if self._transport is None:
            raise NetworkClosedError("open() the UDP network variables first")
        if self._started:
            return
        self._started = True
        for writer in self._writers.values():
            writer.start()
        for reader in self._readers.values():
            reader.start()

    def close(self) -> None:
        """Stop sending and listening, and close the socket."""
        super().close()
        if self._transport is not None:
            if self._event_loop is not None and self._event_loop.is_closed():
                if self._socket is not None:  # (its loop is gone: the socket alone)
                    self._socket.close()
            else:
                self._transport.close()
        self._transport = self._socket = None

    def dropped(self) -> dict[str, int]:
        """Datagrams received, and those dropped: ``not_telegrams`` (short, foreign
        identity, a length that does not match...), ``foreign`` (a list it does not
        know), ``of_own_lists`` (telegrams of a list it sends); ``requests`` received
        (those within 100 ms of one answered get no answer of their own); per list:
        :meth:`statistics`."""
        return dict(self._counts)

    # ------------------------------------------------------------------ the transport

    def _time(self) -> float:
        return self._loop().time()

    def _loop(self) -> asyncio.AbstractEventLoop:
        if self._event_loop is None:
            raise NetworkClosedError("open() the UDP network variables first")
        return self._event_loop

    def _transmit(self, lst: AnyList, payload: bytes, counter: int) -> None:
        assert isinstance(lst, UdpVarList)
        if self._socket is None:
            raise NetworkClosedError("the UDP network variables are closed")
        where = self.to or (lst.address, lst.port)
        for telegram in lst.telegrams(payload, counter):
            self._sendto(telegram, where)

    def _sendto(self, telegram: Telegram, where: tuple[str, int]) -> None:
        assert self._socket is not None
        target = self._resolved.get(where, where)
        if isinstance(target, Exception):
            raise target
        host, port = target
        try:
            self._socket.sendto(telegram.to_bytes(), (host, port))
        except PermissionError:
            raise PermissionError(
                f"sending to {where[0]}:{port} was refused: a broadcast address needs "
                "broadcast=True (cobus netvars --broadcast)"
            ) from None
        except socket.gaierror as exc:
            raise OSError(f"cannot send to {where[0]}: no such host ({exc.strerror})") from None
        except OSError as exc:
            hint = ""
            unreachable = (errno.EINVAL, errno.ENETUNREACH, errno.EADDRNOTAVAIL)
            if exc.errno in unreachable and _loopback(self.bind) and not _loopback(host):
                hint = (
                    f" (it sends from {self.bind}, which reaches this host only: "
                    "bind='0.0.0.0', --bind 0.0.0.0, for other hosts)"
                )
            raise OSError(
                f"cannot send to {where[0]}:{port}: {exc.strerror or exc}{hint}"
            ) from None

    def _request(self, lst: AnyList) -> None:
        assert isinstance(lst, UdpVarList)
        try:
            self._sendto(lst.request(), self.to or (lst.address, lst.port))
        except OSError as exc:  # (asked again a second later)
            log.warning("network variables: request of %s not sent: %s", lst.name, exc)

    def datagram(self, data: bytes, addr: Any = None) -> None:
        """Take one datagram (what the socket received)."""
        counts = self._counts
        counts["datagrams"] += 1
        try:
            telegram = Telegram.parse(data)
        except TelegramError as exc:
            counts["not_telegrams"] += 1
            self.last_junk = (addr, str(exc))
            return
        name = self._by_id.get(telegram.list_id)
        if name is None:
            counts["foreign"] += 1
            return
        now = self._time()
        if telegram.kind != DATA:  # a request: answered when it is a list it sends
            writer = self._writers.get(name)
            if writer is not None and self._started:
                counts["requests"] += 1
                last = self._answered.get(name)
                if last is not None and now - last < REQUEST_GAP:
                    return  # (a storm of requests is one transmission, not one each)
                self._answered[name] = now
                self._emit(ListRequested(name, now))
                writer.send()
            return
        reader = self._readers.get(name)
        if reader is None:
            counts["of_own_lists"] += 1  # (its own broadcast heard back, or another sender)
            return
        if not self._started:
            return
        lst = reader.list
        assert isinstance(lst, UdpVarList)
        # a telegram of a transmission taken already, or of one older than that or than
        # the one being gathered (a datagram twice, or late): never taken again
        done = reader.done
        behind = []
        if done is not None and now - done[1] <= LATE_WINDOW:
            behind.append((done[0] - telegram.counter) % 0x10000)
        if reader.parts and reader.counter is not None and now - reader.began <= reader.window:
            behind.append((reader.counter - telegram.counter) % 0x10000 - 1)
        if any(0 <= b <= LATE_TRANSMISSIONS for b in behind):
            reader.late += 1
            return
        if telegram.flags & 0x03:
            reader.flagged += 1
            reader.malformed_at(
                lst.list_id,
                now,
                f"telegram with flags {telegram.flags:02X}h (acknowledgement or checksum, "
                "neither published): dropped",
            )
            return
        if telegram.sub_index >= lst.frames:
            reader.malformed_at(
                lst.list_id,
                now,
                f"telegram {telegram.sub_index}: the list has {lst.frames} telegram(s)",
            )
            return
        _, count, size = lst.parts[telegram.sub_index]
        if telegram.count != count or len(telegram.data) != size:
            reader.malformed_at(
                lst.list_id,
                now,
                f"telegram {telegram.sub_index}: {telegram.count} values in "
                f"{len(telegram.data)} bytes, the definition has {count} in {size} "
                "(are the definitions the same?)",
            )
            return
        reader.take(telegram.sub_index, telegram.counter, telegram.data, now)


class NetworkVariables(BlockingTwin, twin_of=AsyncNetworkVariables):
    """The network variables for blocking code: ``NetworkVariables(net, definition,
    me="plc1")`` on a blocking :class:`~cobus.runtime.Network`, with the methods of
    :class:`AsyncNetworkVariables`."""

    def __init__(self, network: Any, definition: Any, *, me: str) -> None:
        if isinstance(network, AsyncNetworkVariables):
            super().__init__(network, definition)
            return
        runner = getattr(network, "_runner", None)
        if runner is None:
            raise TypeError(
                "NetworkVariables takes a blocking Network; in async code use AsyncNetworkVariables"
            )
        aio = runner.call(lambda: AsyncNetworkVariables(network.aio, definition, me=me))
        super().__init__(aio, runner)
