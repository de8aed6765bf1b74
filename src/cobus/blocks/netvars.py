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
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from cobus.blocks.netvar_lists import NetVarDefinition, VarList
from cobus.proto import Event, Frame
from cobus.runtime.errors import NetworkClosedError
from cobus.runtime.twin import BlockingTwin

__all__ = [
    "AsyncNetworkVariables",
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
    """A frame on a list's COB-ID that does not fit the definition (the definitions on the
    controllers differ?)."""

    cob_id: int
    reason: str

    def __str__(self) -> str:
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
    def __init__(self, owner: AsyncNetworkVariables, var_list: VarList) -> None:
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
        if self.list.transmit == "cyclic":
            self.due = self.owner.network.time()
            self._cycle()
        elif self.list.transmit == "on_change":
            self.send()  # the values it starts with: a reader that came first has them

    def _cycle(self) -> None:
        assert self.list.interval is not None
        try:
            self.send()
        finally:  # (a failed transmission does not end the cycle)
            self.due += self.list.interval
            now = self.owner.network.time()
            if self.due < now:  # late (a busy loop): skip, do not burst
                self.due = now
            self.timer = self.owner.network.loop.call_at(self.due, self._cycle)

    def changed(self, edges: set[str]) -> None:
        lst = self.list
        if lst.transmit == "on_event":
            if lst.event is not None and lst.event in edges:
                self.send()
        elif lst.transmit == "on_change":
            payload = self.owner._payload(lst)
            if payload == self.last_payload or self.pending is not None:
                return
            now = self.owner.network.time()
            wait = 0.0 if self.last_sent is None else self.last_sent + lst.min_gap - now
            if wait <= 0:
                self.send()
            else:
                self.pending = self.owner.network.loop.call_later(wait, self._deferred)

    def _deferred(self) -> None:
        self.pending = None
        if self.owner._payload(self.list) != self.last_payload:
            self.send()

    def send(self) -> None:
        lst = self.list
        net = self.owner.network
        payload = self.owner._payload(lst)
        counter, self.counter = self.counter, (self.counter + 1) & 0xFF
        self.last_payload = payload
        self.last_sent = net.time()
        try:
            for k, data in enumerate(lst.split(payload, counter)):
                net.send(Frame(lst.cob_id + k, data))
        except Exception as exc:  # backlog full, network closed: said, and tried again later
            self.failed += 1
            self.last_payload = None
            self.owner._emit(ListSendFailed(lst.name, net.time(), str(exc) or repr(exc)))
            return
        self.sent += 1

    def stop(self) -> None:
        for handle in (self.pending, self.timer):
            if handle is not None:
                handle.cancel()
        self.pending = self.timer = None


class _Reader:
    def __init__(self, owner: AsyncNetworkVariables, var_list: VarList) -> None:
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
        dlc = self.list.size if not self.list.headed else 8
        self.owner._send(Frame(self.list.cob_id, rtr=True, dlc=dlc))
        loop = self.owner.network.loop
        self.asking = loop.call_later(REQUEST_RETRY, self._ask, tries - 1)

    def _arm(self) -> None:
        interval = self.list.interval
        if self.list.transmit != "cyclic" or interval is None:
            return
        if self.watch is not None:
            self.watch.cancel()
        self.watch = self.owner.network.loop.call_later(interval * STALE_INTERVALS, self._silent)

    def _silent(self) -> None:
        self.watch = None
        if not self.stale:
            self.stale = True
            assert self.list.interval is not None
            silence = self.list.interval * STALE_INTERVALS
            self.owner._emit(ListStale(self.list.name, self.owner.network.time(), silence))

    def on_frame(self, frame: Frame, now: float) -> None:
        lst = self.list
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
        counter = data[0]
        if self.done is not None and self.done[0] == counter and now - self.done[1] <= self.window:
            return  # a frame of the set just completed, again: nothing new
        if self.parts and (counter != self.counter or now - self.began > self.window):
            self._drop(now)  # another transmission (or one too old to finish): no mixing
        if k in self.parts:
            if self.parts[k] == data[1:]:
                return  # the same frame twice
            self._drop(now)
        if not self.parts:
            self.counter, self.began = counter, now
        self.parts[k] = data[1:]
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
        self.malformed += 1
        self.owner._emit(ListMalformed(self.list.name, now, frame.cob_id, reason))

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

    def __init__(self, network: Any, definition: NetVarDefinition, *, me: str) -> None:
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
            for cob_id in reader.list.cob_ids:
                self._subs.append(net.subscribe(cob_id, reader.on_frame))
        for writer in self._writers.values():
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

    def _check_running(self) -> None:
        if self._closed:
            raise NetworkClosedError("the network variables were closed")

    # ------------------------------------------------------------------ values

    def _split(self, name: str) -> tuple[VarList, str]:
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
        return float(self.network.time() - reader.received_at)

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
        return out

    def stale(self, list_name: str) -> bool:
        """Whether a cyclic list this controller reads brought no complete set for
        3 intervals (until the next one comes)."""
        reader = self._readers.get(self.definition[list_name].name)
        return reader is not None and reader.stale

    def _payload(self, lst: VarList) -> bytes:
        return lst.pack(self._values[lst.name])

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
