"""The asyncio network: one bus, one loop, one clock, and the dispatch COB-ID -> handlers.

Everything that touches protocol state runs on the network's event loop, so nothing needs a
lock. Frames sent by anything attached to the network are also delivered to the network's own
handlers (local echo, as a CAN controller's loopback does), so a master and simulated devices
attached to one network see each other exactly as they would on a wire.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections import deque
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

from cobus._moved import Moved
from cobus.errors import CobusError
from cobus.proto import NOTHING, Event, Frame, Machine, Out
from cobus.proto.connection_set import sdo_cob_ids
from cobus.runtime import bus as _bus
from cobus.runtime.errors import NetworkClosedError, TxOverflowError
from cobus.runtime.events import (
    BusState,
    BusStateChanged,
    HandlerFailed,
    ReceiveFailed,
    TxQueueFull,
    TxResumed,
)
from cobus.runtime.local_nodes import LocalNodes
from cobus.runtime.loop import RealTimeLoop, SimulatedEventLoop
from cobus.runtime.lss import AsyncNetworkLss
from cobus.runtime.multicast import EchoFreeSender, echo_free_sender
from cobus.runtime.reading import ReadingRole
from cobus.runtime.remote import AsyncRemoteNode, NetworkSync, NmtMaster, load_od
from cobus.runtime.sdo_transport import SdoTransport

if TYPE_CHECKING:
    from cobus.od import ObjectDictionary

__all__ = [
    "AsyncNetwork",
    "FrameHandler",
    "MachineHost",
    "NetworkClosedError",
    "Subscription",
    "TxOverflowError",
]

log = logging.getLogger(__name__)

FrameHandler = Callable[[Frame, float], object]
EventListener = Callable[[Event], Any]

_EXT = 1 << 31  # dispatch key flag for 29-bit identifiers
_BATCH = 256  # frames taken from the interface per wake-up
_DIRECT_WAIT = 0.002  # s a reader thread waits for a busy loop before it hands frames over
_PART_WAIT = 0.0005  # s the loop first waits for the rest of a frame split over segments
_PART_WAIT_MAX = 0.05  # s at most, while no more comes (a ping that no frame follows)
_FD_BACKOFF = 0.05  # s the loop first waits after a failed read of a bus's descriptor
_RETRY = 0.001  # seconds between attempts to flush the transmit backlog
_DRAIN_LIMIT = 1024  # frames dispatched per loop callback before yielding


def _key(cob_id: int, extended: bool) -> int:
    return cob_id | _EXT if extended else cob_id


class Subscription:
    """A registered frame handler; :meth:`cancel` removes it."""

    __slots__ = ("_handler", "_key", "_network")

    def __init__(self, network: AsyncNetwork, key: int | None, handler: FrameHandler) -> None:
        self._network = network
        self._key = key
        self._handler = handler

    def cancel(self) -> None:
        """Stop calling the handler."""
        self._network._unsubscribe(self._key, self._handler)


class MachineHost:
    """Drives one sans-I/O machine: feeds it frames, sends its frames, arms its timer.

    Its events go to ``on_event``. :meth:`run` applies any other call of the machine
    (``host.run(lambda now: client.start_upload(0x1000, 0, now))``).
    """

    __slots__ = (
        "_armed",
        "_handle",
        "_network",
        "_subscriptions",
        "machine",
        "on_event",
    )

    def __init__(
        self,
        network: AsyncNetwork,
        machine: Machine,
        on_event: Callable[[Event], None] | None,
    ) -> None:
        self._network = network
        self.machine = machine
        self.on_event = on_event
        self._armed: float | None = None
        self._handle: asyncio.TimerHandle | None = None
        self._subscriptions: list[Subscription] = []

    def listen(self, cob_id: int, *, extended: bool = False) -> None:
        """Feed the machine the frames with identifier ``cob_id``."""
        self._subscriptions.append(self._network.subscribe(cob_id, self.feed, extended=extended))

    def feed(self, frame: Frame, now: float) -> None:
        """Give the machine one frame and apply what it answers."""
        self.apply(self.machine.on_frame(frame, now))

    def run(self, call: Callable[[float], Out]) -> None:
        """Call ``call(now)`` (a method of the machine) and apply what it returns."""
        loop = self._network._loop  # (network.time(), inline: every blocking transfer's way)
        self.apply(call(loop.time() if loop is not None else self._network.time()))

    def apply(self, out: Out) -> None:
        """Send the frames and deliver the events of ``out``, then re-arm the timer.

        A frame the network cannot take (backlog full, network closed) or a failing event
        callback is reported as :class:`HandlerFailed`; the machine's timer is re-armed
        whatever happens, so producers keep running once the bus recovers.
        """
        network = self._network
        try:
            if out.frames:
                send = network.send
                for frame in out.frames:
                    try:
                        send(frame)
                    except CobusError as exc:
                        network.report_failure(
                            f"{type(self.machine).__name__} sending {frame!r}", exc
                        )
            if out.events and self.on_event is not None:
                for event in out.events:
                    try:
                        self.on_event(event)
                    except Exception as exc:
                        network.report_failure(
                            f"event callback of {type(self.machine).__name__}", exc
                        )
        finally:
            # In real time, a deadline that only moved later (each segment of a transfer,
            # each heartbeat) or went away (a transfer done) keeps the armed timer, which
            # re-arms or does nothing when it fires: a sleeping loop is woken only for a timer
            # due before it would wake anyway, so a blocking SDO trip that armed a fresh
            # timeout each time cost a wake-up of the loop. On the simulated clock every move
            # re-arms, so that timers due at one instant keep their order.
            deadline = self.machine.deadline
            armed = self._armed
            if (
                deadline != armed
                and network._loop is not None  # connected
                and (
                    armed is None
                    or (deadline is not None and deadline < armed)
                    or not network._realtime
                )
            ):
                self._rearm(deadline)

    def _rearm(self, deadline: float | None) -> None:
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None
        self._armed = deadline
        if deadline is not None:
            self._handle = self._network.loop.call_at(deadline, self._fire, deadline)

    def _fire(self, deadline: float) -> None:
        self._handle = None
        self._armed = None
        if not self._network.connected:
            return
        now = max(self._network.time(), deadline)
        later = self.machine.deadline
        if self._network._realtime and (later is None or later > now):
            if later is not None:
                self._rearm(later)  # it moved later since armed (see apply)
            return  # (or went away)
        try:
            out = self.machine.on_timer(now)
        except Exception as exc:  # a machine bug must not stop the network
            self._network.report_failure(f"timer of {type(self.machine).__name__}", exc)
            later = self.machine.deadline
            if later is not None and later > deadline:  # never spin on a failing deadline
                self._rearm(later)
            return
        self.apply(out)

    def close(self) -> None:
        """Detach the machine from the network: no more frames in, no more timers."""
        for sub in self._subscriptions:
            sub.cancel()
        self._subscriptions.clear()
        self._rearm(None)
        self._network._hosts.discard(self)


class AsyncNetwork:
    """A CAN network on one python-can bus, driven by an asyncio loop.

    Give it an open python-can ``bus``, or the arguments to open one (``interface``,
    ``channel``, ``bitrate`` and any python-can option); left out, python-can's configuration and
    the ``CAN_*`` environment variables apply. On a :class:`SimulatedEventLoop` with no bus
    given, the network opens a private python-can ``virtual`` bus.

    ``read_on_loop``: where the bus gives a descriptor the loop can watch (SocketCAN,
    ``udp_multicast``, python-can-remote), the loop reads it itself: one wake-up per received
    batch, the fewest for code awaiting on the loop. False reads it with a thread, as every
    other bus is read (on a ``RealTimeLoop`` the thread dispatches under the loop's protocol
    lock; on another loop it hands the frames over). The blocking
    :class:`~cobus.runtime.Network` passes False: its callers wait in their own threads
    anyway, and a turn of the loop costs more than the thread's read (``docs/realtime.md``,
    "Who reads the bus").
    """

    #: Frames received from the bus so far.
    frames_received: int
    #: Frames sent so far (not those the interface sends by itself: SYNC ``by_interface``,
    #: counted in ``frames_received`` when the network hears them back).
    frames_sent: int
    #: The nodes added with :meth:`add_remote`, by node-ID.
    remotes: dict[int, AsyncRemoteNode]
    #: The local devices (:class:`cobus.device.Device`, simulated devices) by node-ID: the
    #: node-IDs this process answers to on this network. Devices claim and release their
    #: node-ID here; read it as a mapping.
    devices: LocalNodes

    #: Moved above the runtime (it knows no device): ``cobus.device.add_device``.
    add_device = Moved("cobus.device.add_device(network, node_id, od)")

    def __init__(
        self,
        bus: can.BusABC | None = None,
        *,
        interface: str | None = None,
        channel: Any = None,
        bitrate: int | None = None,
        tx_backlog: int = 4096,
        read_on_loop: bool = True,
        **bus_kwargs: Any,
    ) -> None:
        if "simulated" in bus_kwargs:
            raise TypeError(
                "AsyncNetwork takes no simulated=: run it on a cobus.runtime.SimulatedEventLoop "
                "(its clock is the loop's), or use the blocking Network(simulated=True)"
            )
        self._bus = bus
        self._owns_bus = bus is None
        self._bus_args: dict[str, Any] = dict(bus_kwargs)
        self._bus_args.update(interface=interface, channel=channel, bitrate=bitrate)
        self._loop: asyncio.AbstractEventLoop | None = None
        #: Connected to a RealTimeLoop (see MachineHost.apply: kept timers).
        self._realtime = False
        self._handlers: dict[int, list[FrameHandler]] = {}
        self._monitors: list[FrameHandler] = []
        # Changed in place only, never rebound: RemotePdo and a device's Core keep this very
        # list to ask "does anyone listen?" without a call.
        self._listeners: list[EventListener] = []
        self._inbound: deque[Frame] = deque()
        self._drain_pending = False
        self._backlog: deque[Frame] = deque()
        self._backlog_limit = tx_backlog
        self._retry_handle: asyncio.TimerHandle | asyncio.Handle | None = None
        self._tx_blocked = False
        self._state = BusState.ACTIVE
        self._reader: threading.Thread | None = None
        #: A blocking network's bus with a descriptor: read by its reader thread or by a
        #: blocking caller waiting for an answer (cobus.runtime.reading).
        self._reading: ReadingRole | None = None
        self._reader_stop = threading.Event()
        self._hosts: set[MachineHost] = set()  # until host.close()
        #: node-ID -> who guards it, and how it is told another takes over (claim_guarding)
        self._guarded: dict[int, tuple[str, Callable[[str], object] | None]] = {}
        self._on_disconnect: list[Callable[[], object]] = []
        self._on_connect: list[Callable[[], object]] = []
        self._listener_tasks: set[asyncio.Task[Any]] = set()
        self._rx_pending: deque[can.Message] = deque()
        self._rx_posted = False
        self._read_on_loop = read_on_loop
        self._fd: int | None = None
        self._fd_ready: Callable[[], tuple[_bus.Readiness, int]] | None = None
        self._fd_resume: asyncio.TimerHandle | None = None
        self._fd_backoff = _FD_BACKOFF
        self._part_wait = _PART_WAIT
        self._fd_more: asyncio.Handle | None = None
        self._poll_hook: Callable[[], bool] | None = None
        self._state_poll: asyncio.TimerHandle | None = None
        #: Whether received error frames report our own controller (see bus.py).
        self._errors_local = True
        #: How the bus hands our own messages back, to drop them (see bus.py: OwnEcho).
        self._own_marked = False
        self._echo_tag: str | None = None
        #: udp_multicast: sends from a socket the bus does not hear (see multicast.py)
        self._tx: EchoFreeSender | None = None
        self.frames_received = 0
        self.frames_sent = 0
        self._failures: dict[tuple[object, ...], int] = {}  # by where they were raised
        self.remotes: dict[int, AsyncRemoteNode] = {}
        self._sdo_transports: dict[tuple[int, int], SdoTransport] = {}
        self.devices = LocalNodes()
        self._nmt: NmtMaster | None = None
        self._sync: NetworkSync | None = None
        self._lss: AsyncNetworkLss | None = None

    # ------------------------------------------------------------------ life cycle
    async def connect(self) -> AsyncNetwork:
        """Open the bus (if needed) and start receiving. Returns the network.

        After :meth:`disconnect`, ``connect`` again resumes: machines re-arm their timers and
        frames still waiting in the transmit backlog go out.
        """
        if self._loop is not None:
            return self
        loop = asyncio.get_running_loop()
        opened = False
        if self._bus is None:
            args = {k: v for k, v in self._bus_args.items() if v is not None}
            if isinstance(loop, SimulatedEventLoop) and "interface" not in args:
                args.update(interface="virtual", channel=f"cobus-sim-{id(self):x}")
            self._bus = _bus.open_bus(**args)
            opened = True
        self._loop = loop
        self._realtime = isinstance(loop, RealTimeLoop)
        try:
            self._start_receiving(loop, self._bus)
        except BaseException:
            self._loop = None
            self._realtime = False
            if self._tx is not None:  # (the filter off a bus the user keeps)
                self._tx.close()
                self._tx = None
            if opened:
                self._bus.shutdown()
                self._bus = None
            raise
        for host in list(self._hosts):
            host.apply(NOTHING)
        if self._backlog:
            self._retry_handle = loop.call_soon(self._flush)
        for callback in list(self._on_connect):
            try:
                callback()
            except Exception as exc:
                self.report_failure(f"connect callback {callback!r}", exc)
        return self

    async def disconnect(self) -> None:
        """Stop receiving and stop every machine's timer; shut the bus down if this network
        opened it. Operations still waiting (an SDO transfer) fail with
        :class:`NetworkClosedError`."""
        loop = self._loop
        if loop is None:
            return
        self._stop_receiving(loop)
        for host in list(self._hosts):  # machines stop with their network
            host._rearm(None)
        for handle in (self._retry_handle, self._state_poll):
            if handle is not None:
                handle.cancel()
        self._retry_handle = self._state_poll = None
        self._loop = None
        self._realtime = False
        self._inbound.clear()
        self._drain_pending = False
        for callback in list(self._on_disconnect):
            try:
                callback()
            except Exception as exc:
                log.exception("disconnect callback %r failed", callback)
                del exc
        if self._owns_bus and self._bus is not None:
            bus, self._bus = self._bus, None
            try:
                bus.shutdown()
            except (can.CanError, OSError) as exc:  # a driver failing to close: closed anyway
                self.report_failure("shutting the bus down", exc)

    def on_disconnect(self, callback: Callable[[], object]) -> None:
        """Call ``callback()`` when the network disconnects (to fail pending operations)."""
        self._on_disconnect.append(callback)

    def on_connect(self, callback: Callable[[], object]) -> None:
        """Call ``callback()`` each time the network connects (after a disconnect: to resume
        what does not resume with the machines' timers)."""
        self._on_connect.append(callback)

    def _forget(self, callback: Callable[[], object]) -> None:
        """No longer call ``callback`` on connect or disconnect."""
        for callbacks in (self._on_connect, self._on_disconnect):
            with contextlib.suppress(ValueError):
                callbacks.remove(callback)

    async def __aenter__(self) -> AsyncNetwork:
        return await self.connect()

    async def __aexit__(self, *exc: object) -> None:
        await self.disconnect()

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        """The event loop the network runs on; :class:`NetworkClosedError` when not connected."""
        if self._loop is None:
            raise NetworkClosedError("the network is not connected: await network.connect()")
        return self._loop

    @property
    def bus(self) -> can.BusABC:
        """The python-can bus; :class:`NetworkClosedError` when not connected."""
        if self._bus is None:
            raise NetworkClosedError("the network is not connected: await network.connect()")
        return self._bus

    @property
    def connected(self) -> bool:
        """Whether the network is connected."""
        return self._loop is not None

    @property
    def simulated(self) -> bool:
        """Whether the network runs on a :class:`SimulatedEventLoop`."""
        return isinstance(self._loop, SimulatedEventLoop)

    def time(self) -> float:
        """The network's clock in seconds (virtual on a simulated loop)."""
        loop = self._loop  # (the loop property, inline: every machine's call asks)
        if loop is None:
            raise NetworkClosedError("the network is not connected: await network.connect()")
        return loop.time()

    async def sleep(self, seconds: float) -> None:
        """Let the network run for ``seconds`` (virtual seconds on a simulated loop)."""
        await asyncio.sleep(seconds)

    @property
    def bus_state(self) -> BusState:
        """The controller's last reported state: error-active, warning, error-passive, bus-off."""
        return self._state

    @property
    def tx_backlog(self) -> int:
        """How many frames wait for the interface to take them."""
        return len(self._backlog)

    # ------------------------------------------------------------------ frames
    def subscribe(
        self, cob_id: int, handler: FrameHandler, *, extended: bool = False
    ) -> Subscription:
        """Call ``handler(frame, now)`` for every frame with this identifier."""
        key = _key(cob_id, extended)
        self._handlers.setdefault(key, []).append(handler)
        return Subscription(self, key, handler)

    def subscribe_all(self, handler: FrameHandler) -> Subscription:
        """Call ``handler(frame, now)`` for every frame (a monitor or trace writer)."""
        self._monitors.append(handler)
        return Subscription(self, None, handler)

    def _unsubscribe(self, key: int | None, handler: FrameHandler) -> None:
        handlers = self._monitors if key is None else self._handlers.get(key)
        if handlers and handler in handlers:
            handlers.remove(handler)
            if key is not None and not handlers:
                del self._handlers[key]

    def send(self, frame: Frame) -> None:
        """Transmit ``frame``; must be called on the network's loop.

        If the interface refuses it (buffer full, bus-off) the frame waits in a backlog and goes
        out when the interface takes frames again; :class:`TxOverflowError` if that backlog is
        full. The handlers and monitors of this network that listen to its identifier when it
        is sent receive it once it is on the bus (a handler subscribed after the send does
        not: the frame is only echoed when someone here listens).
        """
        if self._bus is None or self._loop is None:
            raise NetworkClosedError("cannot send: the network is not connected")
        if self._backlog:
            self._enqueue(frame)
            return
        # _message and _deliver's test, inline: every frame sent passes here
        msg = _bus.frame_to_message(frame)
        tag = self._echo_tag
        if tag is not None:
            msg.channel = tag
        try:
            (self._tx or self._bus).send(msg, timeout=0)
        except (can.CanError, OSError) as exc:
            self._enqueue(frame)
            self._blocked(str(exc))
            return
        self.frames_sent += 1
        if (
            self._monitors
            or (frame.cob_id | _EXT if frame.extended else frame.cob_id) in self._handlers
        ):
            self._deliver(frame)

    def attach(
        self,
        machine: Machine,
        cob_ids: Iterable[int] = (),
        on_event: Callable[[Event], None] | None = None,
        *,
        extended: bool = False,
    ) -> MachineHost:
        """Drive ``machine`` on this network: frames on ``cob_ids`` in (29-bit identifiers
        with ``extended=True``), its output out. A deadline it already has is armed."""
        host = MachineHost(self, machine, on_event)
        self._hosts.add(host)
        for cob_id in cob_ids:
            host.listen(cob_id, extended=extended)
        if self._loop is not None:
            host.apply(NOTHING)
        return host

    def claim_guarding(
        self,
        node_id: int,
        owner: str,
        *,
        take: bool = False,
        on_taken: Callable[[str], object] | None = None,
    ) -> str | None:
        """Record that ``owner`` (a name people read: "the master") guards ``node_id``
        here. One guarding master per node: each remote request flips the toggle bit of
        the node's reply, so a second master's requests break the first one's toggle.

        None if ``owner`` now guards the node; else the owner already guarding it, and
        nothing changes - unless ``take``: then that owner's ``on_taken(new owner)`` is
        called (it stops guarding) and ``owner`` guards the node from now on."""
        current = self._guarded.get(node_id)
        if current is not None and current[0] != owner:
            if not take:
                return current[0]
            if current[1] is not None:
                current[1](owner)
        self._guarded[node_id] = (owner, on_taken)
        return None

    def guarding_owner(self, node_id: int) -> str | None:
        """Who guards ``node_id`` here (see :meth:`claim_guarding`); None: nobody."""
        current = self._guarded.get(node_id)
        return None if current is None else current[0]

    def release_guarding(self, node_id: int, owner: str) -> None:
        """``owner`` no longer guards ``node_id`` (see :meth:`claim_guarding`)."""
        current = self._guarded.get(node_id)
        if current is not None and current[0] == owner:
            del self._guarded[node_id]

    # ------------------------------------------------------------------ nodes and services
    def sdo_transport(
        self, node_id: int, *, rx_cob_id: int | None = None, tx_cob_id: int | None = None
    ) -> SdoTransport:
        """The one SDO client transport of this network to ``node_id``'s SDO server (default
        COB-IDs 600h+id / 580h+id, or the pair given), shared by everyone here who asks
        that server: transfers queue on it in request order instead of aborting each other.
        Each caller :meth:`~cobus.runtime.sdo_transport.SdoTransport.release` it once."""
        if rx_cob_id is None or tx_cob_id is None:
            rx, tx = sdo_cob_ids(node_id)
            rx_cob_id = rx if rx_cob_id is None else rx_cob_id
            tx_cob_id = tx if tx_cob_id is None else tx_cob_id
        key = (rx_cob_id, tx_cob_id)
        transport = self._sdo_transports.get(key)
        if transport is None:
            transport = self._sdo_transports[key] = SdoTransport(self, *key)
        return transport.take()

    def add_remote(
        self,
        node_id: int,
        od: ObjectDictionary | str | Path | None = None,
        *,
        sdo_timeout: float = 1.0,
    ) -> AsyncRemoteNode:
        """A node this network talks to as a client; ``od`` may be an EDS/DCF path."""
        if node_id in self.remotes:
            raise ValueError(
                f"node {node_id} is already on this network: use network.remotes[{node_id}], "
                f"or remove_remote({node_id}) first to add it again"
            )
        node = AsyncRemoteNode(self, node_id, load_od(od, node_id), sdo_timeout=sdo_timeout)
        self.remotes[node_id] = node
        return node

    def remove_remote(self, node_id: int) -> None:
        """Forget a node added with :meth:`add_remote`: its subscriptions end, transfers and
        waits still running fail; it can be added again."""
        node = self.remotes.pop(node_id, None)
        if node is None:
            raise KeyError(f"node {node_id} was not added to this network")
        node._close()

    @property
    def nmt(self) -> NmtMaster:
        """The NMT master service: ``net.nmt.send(command, node_id)``."""
        if self._nmt is None:
            self._nmt = NmtMaster(self)
        return self._nmt

    @property
    def lss(self) -> AsyncNetworkLss:
        """The LSS master (CiA 305): ``await net.lss.fastscan()``, ``configure_node_id``..."""
        if self._lss is None:
            self._lss = AsyncNetworkLss(self)
        return self._lss

    @property
    def sync(self) -> NetworkSync:
        """The SYNC producer: ``net.sync.start(period)``, ``net.sync.stop()``."""
        if self._sync is None:
            self._sync = NetworkSync(self)
        return self._sync

    # ------------------------------------------------------------------ events
    def add_listener(self, listener: EventListener) -> None:
        """Call ``listener(event)`` for every event of the network (bus state, nodes...).

        Listeners run on the loop and must return quickly; a coroutine function is run as a
        task.
        """
        self._listeners.append(listener)

    def remove_listener(self, listener: EventListener) -> None:
        """Stop calling ``listener`` (given to :meth:`add_listener`)."""
        if listener in self._listeners:
            self._listeners.remove(listener)

    @property
    def listened(self) -> bool:
        """Whether any listener is registered: code that emits an event on every request
        may skip building it when nobody would see it."""
        return bool(self._listeners)

    def emit(self, event: Event) -> None:
        """Give ``event`` to every listener of the network."""
        if not self._listeners:  # the common case: every SDO event comes through here
            return
        for listener in list(self._listeners):
            try:
                result = listener(event)
                if asyncio.iscoroutine(result):
                    task = self.loop.create_task(result)
                    self._listener_tasks.add(task)
                    task.add_done_callback(self._listener_done)
            except Exception as exc:
                log.exception("event listener %r failed", listener)
                if not isinstance(event, HandlerFailed):
                    self.emit(HandlerFailed(f"listener {listener!r}", repr(exc)))

    def _listener_done(self, task: asyncio.Task[Any]) -> None:
        self._listener_tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            self.report_failure(f"listener task {task.get_name()}", task.exception())  # type: ignore[arg-type]

    def report_failure(self, where: str, exc: BaseException) -> None:
        """Report a failing handler or callback: a :class:`HandlerFailed` event each time; in
        the log, its traceback the first time, then a line at the 10th, 100th, 1000th... time
        (a callback that fails on every frame must not flood the log)."""
        tb = exc.__traceback__
        while tb is not None and tb.tb_next is not None:
            tb = tb.tb_next
        site = (type(exc), tb.tb_frame.f_code.co_filename, tb.tb_lineno) if tb else (type(exc),)
        count = self._failures[site] = self._failures.get(site, 0) + 1
        if count == 1:
            log.error("%s failed: %r", where, exc, exc_info=exc)
        elif count in (10, 100, 1000) or count % 10_000 == 0:
            log.error("%s failed again: %r (%d times so far)", where, exc, count)
        self.emit(HandlerFailed(where, repr(exc)))

    # ------------------------------------------------------------------ transmit backlog
    def _enqueue(self, frame: Frame) -> None:
        if len(self._backlog) >= self._backlog_limit:
            raise TxOverflowError(
                f"transmit backlog full ({self._backlog_limit} frames): the interface has not "
                f"accepted frames for a while (bus state {self._state.value}); frame {frame!r} "
                "was not sent"
            )
        self._backlog.append(frame)

    def _blocked(self, reason: str) -> None:
        if not self._tx_blocked:
            self._tx_blocked = True
            self.emit(TxQueueFull(len(self._backlog), reason))
        if self._retry_handle is None and self._loop is not None:
            self._retry_handle = self._loop.call_later(_RETRY, self._flush)

    def _message(self, frame: Frame) -> can.Message:
        """The python-can message that sends ``frame``."""
        msg = _bus.frame_to_message(frame)
        if self._echo_tag is not None:
            msg.channel = self._echo_tag  # to know its copy when the bus hands it back
        return msg

    def _flush(self) -> None:
        self._retry_handle = None
        bus = self._bus
        if bus is None:
            return
        sender = self._tx or bus
        while self._backlog:
            frame = self._backlog[0]
            try:
                sender.send(self._message(frame), timeout=0)
            except (can.CanError, OSError) as exc:
                self._blocked(str(exc))
                return
            self._backlog.popleft()
            self.frames_sent += 1
            self._deliver(frame)
        if self._tx_blocked:
            self._tx_blocked = False
            self.emit(TxResumed())

    # ------------------------------------------------------------------ receive path
    def _deliver(self, frame: Frame) -> None:
        """The local echo of a frame this network sent: to its own handlers, in order with
        what it receives. A frame no handler or monitor of this network listens to is not
        echoed at all (no loop callback for nothing)."""
        if (
            not self._monitors
            and (frame.cob_id | _EXT if frame.extended else frame.cob_id) not in self._handlers
        ):
            return
        self._inbound.append(frame)
        if not self._drain_pending and self._loop is not None:
            # scheduled, then marked: an interrupt in between (Ctrl-C in the main thread, which
            # begins blocking SDO transfers) costs a second drain, never a lost one
            self._loop.call_soon(self._drain)
            self._drain_pending = True

    def _drain(self) -> None:
        self._drain_pending = False
        inbound = self._inbound
        if not inbound or self._loop is None:
            return
        now = self._loop.time()
        dispatch = self._dispatch
        # Bounded: machines answering each other locally must not starve timers and I/O.
        for _ in range(_DRAIN_LIMIT):
            if not inbound:
                return
            dispatch(inbound.popleft(), now)
        if inbound and not self._drain_pending:
            self._loop.call_soon(self._drain)
            self._drain_pending = True

    def _dispatch(self, frame: Frame, now: float) -> None:
        """Hand ``frame`` to the monitors and to the handlers of its identifier."""
        if self._monitors:
            self._call_all(self._monitors, frame, now)
        targets = self._handlers.get(frame.cob_id | _EXT if frame.extended else frame.cob_id)
        if not targets:
            return
        if len(targets) == 1:
            try:
                targets[0](frame, now)
            except Exception as exc:
                self.report_failure(f"handler of {frame!r}", exc)
        else:
            self._call_all(targets, frame, now)

    def _call_all(self, targets: list[FrameHandler], frame: Frame, now: float) -> None:
        for handler in list(targets):
            try:
                handler(frame, now)
            except Exception as exc:
                self.report_failure(f"handler of {frame!r}", exc)

    def _on_messages(self, messages: Iterable[can.Message]) -> None:
        if self._drain_pending or self._inbound or self._loop is None:
            self._queue_messages(messages)
            return
        # Hot path: nothing is queued before these frames, so dispatch them in place.
        now = self._loop.time()
        convert = _bus.message_to_frame
        handlers = self._handlers
        marked, tag = self._own_marked, self._echo_tag
        received = 0
        for msg in messages:
            if (marked and not msg.is_rx) or (tag is not None and msg.channel == tag):
                continue  # our own message handed back: delivered already (local echo)
            if msg.is_error_frame:
                self._on_error_frame(msg)
                continue
            frame = convert(msg)
            if frame is None:
                continue
            received += 1
            # _dispatch, inlined for the common case: no monitor, one handler
            targets = handlers.get(frame.cob_id | _EXT if frame.extended else frame.cob_id)
            if self._monitors or (targets is not None and len(targets) != 1):
                self._dispatch(frame, now)
            elif targets is not None:
                try:
                    targets[0](frame, now)
                except Exception as exc:
                    self.report_failure(f"handler of {frame!r}", exc)
        self.frames_received += received
        if self._inbound and not self._drain_pending:
            # A handler sent frames: their echo is delivered after this batch, in order.
            self._drain()

    def _queue_messages(self, messages: Iterable[can.Message]) -> None:
        marked, tag = self._own_marked, self._echo_tag
        for msg in messages:
            if (marked and not msg.is_rx) or (tag is not None and msg.channel == tag):
                continue  # our own message handed back (see _on_messages)
            if msg.is_error_frame:
                self._on_error_frame(msg)
                continue
            frame = _bus.message_to_frame(msg)
            if frame is None:
                continue
            self.frames_received += 1
            self._inbound.append(frame)
        if self._inbound and not self._drain_pending:
            self._drain()

    def _on_error_frame(self, msg: can.Message) -> None:
        events, state, tx, rx = _bus.decode_error_frame(msg)
        if not self._errors_local:  # another participant's frame on a software hub:
            events, state = events[:1], None  # seen (BusErrorFrame), not our state
        for event in events:
            self.emit(event)
        if state is not None:
            self._set_state(state, tx, rx)

    def _set_state(self, state: BusState, tx: int | None = None, rx: int | None = None) -> None:
        if state is self._state:
            return
        old, self._state = self._state, state
        self.emit(BusStateChanged(old, state, tx, rx))
        if state is not BusState.BUS_OFF and self._backlog and self._retry_handle is None:
            self._flush()

    # -- receivers: a file descriptor on the loop, a thread, or a poll hook (simulated clock)
    def _start_receiving(self, loop: asyncio.AbstractEventLoop, bus: can.BusABC) -> None:
        self._errors_local = _bus.error_frames_are_local(bus)
        self._own_marked, self._echo_tag = _bus.own_echo(bus)
        self._tx = echo_free_sender(bus)  # (the tag stays: what python-can's socket sends)
        if isinstance(loop, SimulatedEventLoop):
            self._poll_hook = self._poll
            loop.add_poll_hook(self._poll)
            return
        source = _bus.loop_source(bus) if self._read_on_loop else None
        if source is not None:
            try:
                loop.add_reader(source.fd, self._read_ready)
                self._fd, self._fd_ready = source
            except (NotImplementedError, RuntimeError):
                self._fd = None
        if self._fd is None and not self._start_reading_role(loop, bus, source):
            self._start_reader_thread(loop, bus)
        if _bus.interface_reports_state(bus):
            self._state_poll = loop.call_later(0.5, self._poll_state)

    def _stop_receiving(self, loop: asyncio.AbstractEventLoop) -> None:
        if self._tx is not None:
            self._tx.close()
            self._tx = None
        if self._poll_hook is not None and isinstance(loop, SimulatedEventLoop):
            loop.remove_poll_hook(self._poll_hook)
            self._poll_hook = None
        if self._fd_more is not None:
            self._fd_more.cancel()
            self._fd_more = None
        paused = self._fd_resume is not None
        if self._fd_resume is not None:
            self._fd_resume.cancel()
            self._fd_resume = None
        if self._fd is not None:
            if not paused:  # (while paused it is not watched, and may be another's by now)
                loop.remove_reader(self._fd)
            self._fd = self._fd_ready = None
        self._fd_backoff, self._part_wait = _FD_BACKOFF, _PART_WAIT
        if self._reader is not None:
            self._reader_stop.set()
            self._reader.join(timeout=2.0)
            self._reader = None
        if self._reading is not None:
            self._reading.stop()
            self._reading = None

    def _take(self, bus: can.BusABC) -> list[can.Message]:
        batch: list[can.Message] = []
        while len(batch) < _BATCH:
            msg = bus.recv(0)
            if msg is None:
                break
            batch.append(msg)
        return batch

    def _poll(self) -> bool:
        bus = self._bus
        if bus is None:
            return False
        try:
            batch = self._take(bus)
        except (can.CanError, OSError) as exc:
            self.emit(ReceiveFailed(str(exc)))
            return False
        if batch:
            self.loop.call_soon(self._on_messages, batch)
            return True
        return False

    def _start_reading_role(
        self, loop: asyncio.AbstractEventLoop, bus: can.BusABC, source: _bus.LoopSource | None
    ) -> bool:
        """Whether blocking callers may read ``bus`` themselves (a reading role started):
        on a RealTimeLoop, when the loop does not read it and a readable descriptor means
        a whole frame waits (see cobus.runtime.reading)."""
        if self._read_on_loop or not isinstance(loop, RealTimeLoop):
            return False
        if source is None:
            source = _bus.loop_source(bus)
        if source is None or source.ready is not None:
            return False  # (python-can-remote: measured, see docs/realtime.md)
        reading = ReadingRole(loop, bus, source.fd, self._take, self._accept, self._read_failed)
        try:
            reading.start()
        except BaseException:
            reading.stop()
            raise
        self._reading = reading
        return True

    def _accept(self, batch: list[can.Message]) -> bool:
        """Dispatch frames a thread has read (a reader thread, or a blocking caller reading
        the bus): on a RealTimeLoop in that thread, under the loop's protocol lock (never
        while the loop runs), saving a hand-over; else, or when the loop stays busy, handed
        to the loop. False once the network is disconnected or the loop closed."""
        loop = self._loop
        if loop is None:
            return False
        pending = self._rx_pending
        marked, tag = self._own_marked, self._echo_tag
        for msg in batch:
            if (marked and not msg.is_rx) or (tag is not None and msg.channel == tag):
                continue  # our own message handed back (see _on_messages): not worth the lock
            pending.append(msg)
        if not pending:
            return True
        if isinstance(loop, RealTimeLoop):
            lock = loop.protocol_lock
            if lock.acquire(True, _DIRECT_WAIT):
                try:
                    if loop.is_closed():
                        return False
                    self._dispatch_pending()
                finally:
                    lock.release()
                    loop.wake_if_pending()  # (the threads this dispatch has to wake)
                return True
        # Hand-over: one wake-up of the loop per batch; while a wake-up is pending, frames
        # that arrive only join the queue (deque appends are atomic). Also the way out when
        # the loop is busy, so a reader is never starved by it; the queue keeps the order,
        # as the direct path empties it first.
        if not self._rx_posted:
            self._rx_posted = True
            try:
                loop.call_soon_threadsafe(self._drain_rx)
            except RuntimeError:  # the loop is closed
                return False
        return True

    def _read_failed(self, exc: Exception) -> None:
        loop = self._loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # (the loop is closed)
                loop.call_soon_threadsafe(self.emit, ReceiveFailed(str(exc)))

    def _start_reader_thread(self, loop: asyncio.AbstractEventLoop, bus: can.BusABC) -> None:
        self._reader_stop.clear()
        self._reader = threading.Thread(
            target=self._reader_thread, args=(loop, bus), name="cobus-rx", daemon=True
        )
        self._reader.start()

    def _read_ready(self) -> None:
        """The bus's descriptor is readable: read what waits, on the loop."""
        self._fd_more = None
        bus, ready = self._bus, self._fd_ready
        if bus is None or self._fd is None or self._fd_resume is not None:
            return  # (disconnected, or paused, since this was scheduled)
        batch: list[can.Message] = []
        failure: Exception | None = None
        part = huge = False
        try:
            if ready is None:  # readable: a whole frame waits; read until none is left
                while len(batch) < _BATCH:
                    msg = bus.recv(0)
                    if msg is None:
                        break
                    batch.append(msg)
            else:  # read what one look found waiting; the descriptor tells if more came
                readiness, whole = ready()
                if readiness is _bus.Readiness.WHOLE:
                    for _ in range(min(whole, _BATCH)):
                        msg = bus.recv(0)
                        if msg is None:
                            break
                        batch.append(msg)
                else:
                    part = readiness is _bus.Readiness.PART
                    huge = readiness is _bus.Readiness.HUGE
        except Exception as exc:  # any driver failure: report, back off, read on
            failure = exc
        if batch:
            self._fd_backoff, self._part_wait = _FD_BACKOFF, _PART_WAIT
            self._on_messages(batch)
        if failure is not None:
            self.emit(ReceiveFailed(str(failure)))
            self._pause_reader(self._fd_backoff)
            self._fd_backoff = min(self._fd_backoff * 2, 1.0)
        elif huge:  # a frame too long to wait for in the kernel's buffer: a thread reads on
            self._hand_to_thread()
        elif part:
            # The rest of a frame (or the data frame after a ping) is still on its way: wait
            # for it off the descriptor, which stays readable and would spin the loop; longer
            # each time nothing comes (a ping that no frame follows).
            self._pause_reader(self._part_wait)
            self._part_wait = min(self._part_wait * 2, _PART_WAIT_MAX)
        elif len(batch) == _BATCH and self._fd is not None and self._loop is not None:
            self._fd_more = self._loop.call_soon(self._read_ready)  # more may wait: read on

    def _pause_reader(self, delay: float) -> None:
        """Stop watching the descriptor for ``delay`` seconds (a partial frame, a failing
        interface: a descriptor that stays readable would keep the loop spinning)."""
        loop, fd = self._loop, self._fd
        if loop is None or fd is None or self._fd_resume is not None:
            return
        loop.remove_reader(fd)
        self._fd_resume = loop.call_later(delay, self._resume_reader)

    def _resume_reader(self) -> None:
        self._fd_resume = None
        loop, bus, fd = self._loop, self._bus, self._fd
        if loop is None or bus is None or fd is None:
            return
        source = _bus.loop_source(bus)
        if source is not None and source.fd == fd:
            try:
                loop.add_reader(fd, self._read_ready)
                return
            except (OSError, ValueError):
                pass
        # The descriptor is gone (a python-can-remote connection closed its socket): a
        # thread reads on, reports what fails and backs off.
        self._fd = self._fd_ready = None
        self._start_reader_thread(loop, bus)

    def _hand_to_thread(self) -> None:
        """From now on a reader thread reads this bus, not the loop."""
        loop, bus, fd = self._loop, self._bus, self._fd
        if loop is None or bus is None or fd is None:
            return
        loop.remove_reader(fd)
        self._fd = self._fd_ready = None
        self._start_reader_thread(loop, bus)

    def _reader_thread(self, loop: asyncio.AbstractEventLoop, bus: can.BusABC) -> None:
        if isinstance(loop, RealTimeLoop):  # handlers run here: get_running_loop() is the loop
            asyncio.events._set_running_loop(loop)
        backoff = 0.05
        stop = self._reader_stop
        accept = self._accept
        while not stop.is_set():
            try:
                msg = bus.recv(0.05)
            except Exception as exc:  # any driver failure: report, back off, read on
                if stop.is_set():
                    return
                try:
                    loop.call_soon_threadsafe(self.emit, ReceiveFailed(str(exc)))
                except RuntimeError:
                    return
                stop.wait(backoff)
                backoff = min(backoff * 2, 1.0)
                continue
            if msg is None:
                continue
            backoff = 0.05
            if not accept([msg]):
                return

    def _dispatch_pending(self) -> None:
        """Dispatch what the reader thread queued, holding the protocol lock."""
        if self._bus is None or self._loop is None:
            return
        pending = self._rx_pending
        batch = [pending.popleft() for _ in range(len(pending))]
        try:
            self._on_messages(batch)
        except Exception as exc:  # a bug here must not end the reader thread
            self.report_failure("dispatch of received frames", exc)

    def _drain_rx(self) -> None:
        self._rx_posted = False
        pending = self._rx_pending
        batch = [pending.popleft() for _ in range(len(pending))]
        if batch:
            self._on_messages(batch)

    def _poll_state(self) -> None:
        self._state_poll = None
        bus = self._bus
        if bus is None or self._loop is None:
            return
        state = _bus.read_state(bus)
        if state is not None:
            self._set_state(state)
        self._state_poll = self._loop.call_later(0.5, self._poll_state)
