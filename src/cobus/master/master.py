"""The NMT master: boots a network as CiA 302-2 describes it and keeps it running.

>>> master = Master(network, load_network("line.yml"))
>>> await master.boot(timeout=10)          # every mandatory node operational
>>> master.inputs["drive1.position"]
>>> master.outputs["drive1.controlword"] = 0x0F

Everything runs on the network's event loop: the boot-up of each node is a task of its own,
supervision is driven by the protocol machines of :mod:`cobus.proto` hosted on the network.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
from collections.abc import Awaitable, Callable, Mapping
from typing import Any, Final

from cobus.master.boot import LssStep
from cobus.master.config import NetworkConfig, load_network
from cobus.master.config.model import EXTENDED, INVALID
from cobus.master.diagnostics import BusLoadMeter, MasterDiagnostics
from cobus.master.errors import (
    BootTimeoutError,
    MasterError,
    NodeNotFoundError,
)
from cobus.master.events import MasterEvent, MasterStateChanged, NetworkStopped
from cobus.master.image import Inputs, Outputs, ProcessImage
from cobus.master.node import ManagedNode
from cobus.master.process import MasterRpdos
from cobus.master.producers import MasterProducers
from cobus.master.states import MasterState, MasterStatus, NodeState
from cobus.proto import Event, Frame
from cobus.proto.connection_set import emcy_cob_id
from cobus.proto.emcy import EmcyConsumer, EmcyReceived
from cobus.proto.heartbeat import (
    BootupReceived,
    HeartbeatMonitor,
    HeartbeatTimeout,
    RemoteStateChanged,
)
from cobus.proto.nmt import NmtState
from cobus.runtime import (
    AsyncNetwork,
    BusState,
    BusStateChanged,
    HandlerFailed,
    MachineHost,
    NetworkClosedError,
    RxOverflow,
    Subscription,
    TxOverflowError,
    TxQueueFull,
)

__all__ = ["BootStep", "Master", "MasterListener", "TpdoListener"]

log = logging.getLogger(__name__)

MasterListener = Callable[[MasterEvent], object]
#: ``listener(node_id, tpdo_number, now)``: see :meth:`Master.add_tpdo_listener`.
TpdoListener = Callable[[int, int, float], object]
#: ``await step(node)`` in a node's boot-up: see :meth:`Master.add_boot_step`.
BootStep = Callable[[ManagedNode], Awaitable[str | None]]


class Master:
    """The NMT master of ``network`` for the network described by ``config`` (a
    :class:`NetworkConfig` or the path of a network file).

    :meth:`start` boots the network in the background, :meth:`boot` waits until it runs,
    :meth:`stop` ends supervision. ``nodes`` maps node-IDs to :class:`ManagedNode`;
    ``inputs`` / ``outputs`` are the process image; ``diagnostics`` the global diagnostics.
    """

    #: The network the master runs.
    network: Final[AsyncNetwork]
    #: The network description it boots.
    config: Final[NetworkConfig]
    #: The global diagnostics (frames, bus load, errors).
    diagnostics: Final[MasterDiagnostics]
    #: The process image behind ``inputs`` and ``outputs``.
    image: Final[ProcessImage]
    #: The process image's inputs (TPDO signals) by ``"node.signal"``.
    inputs: Final[Inputs]
    #: The process image's outputs (RPDO signals) by ``"node.signal"``; setting one sends it.
    outputs: Final[Outputs]
    #: The managed nodes by node-ID.
    nodes: dict[int, ManagedNode]
    #: The RPDOs the master sends from the process image (SYNC, events, event timers).
    rpdos: MasterRpdos

    def __init__(
        self, network: AsyncNetwork, config: NetworkConfig | str | os.PathLike[str]
    ) -> None:
        if not isinstance(config, NetworkConfig):
            config = load_network(config)
        self.network = network
        self.config = config
        self.diagnostics = MasterDiagnostics()
        self.image = ProcessImage(config)
        self.inputs = Inputs(self.image)
        self.outputs = Outputs(self.image, self.set_output)
        self._listeners: list[MasterListener] = []
        self._tpdo_listeners: list[TpdoListener] = []
        self._state = MasterState.INITIALISING
        self._status = MasterStatus.OFFLINE
        self._started = False
        self._running = asyncio.Event()
        self._lss_task: asyncio.Task[None] | None = None
        self._lss: LssStep | None = None
        self._monitor = HeartbeatMonitor(track_all=True)
        self._monitor_host: MachineHost = network.attach(self._monitor, (), self._on_monitor)
        self._subs: list[Subscription] = []
        self._hosts: list[MachineHost] = []
        self._producers = MasterProducers(network)
        self._sync_seen = False
        self._meter = BusLoadMeter(config.master.bitrate, config.master.bus_load_window)
        self.nodes: dict[int, ManagedNode] = {}
        self._port = _NodePort(self)
        for node_id, node_config in config.nodes.items():
            self.nodes[node_id] = ManagedNode(self._port, node_config)
        self.rpdos = MasterRpdos(network, self.image, self.nodes)
        # The NMT commands this process sends (the application's, the master's own) set the
        # state a node is expected in; a change nobody here asked for is "unexpected".
        network.nmt.add_observer(self._on_nmt_sent)

    def _on_nmt_sent(self, command: int, node_id: int) -> None:
        for node in self.nodes.values() if node_id == 0 else [self.nodes.get(node_id)]:
            if node is not None:
                node.supervision.commanded(command)

    # ================================================================== state

    @property
    def state(self) -> MasterState:
        """The Lenze master state code (0-2 start, 3 configuring, 5 running)."""
        return self._state

    @property
    def status(self) -> MasterStatus:
        """The Beckhoff master state (RUN, RESET, OFFLINE, STOP)."""
        return self._status

    @property
    def started(self) -> bool:
        """Whether :meth:`start` (or :meth:`boot`) was called and :meth:`stop` not since."""
        return self._started

    @property
    def running(self) -> bool:
        """Whether the network runs (process data flows)."""
        return self._status is MasterStatus.RUN

    @property
    def bus_load(self) -> float:
        """Bus load in % over the configured window (``master.bus_load_window``)."""
        return self._meter.load(self.network.time())

    def node(self, key: int | str) -> ManagedNode:
        """A node by node-ID or by its name in the network file."""
        if isinstance(key, int) and key in self.nodes:
            return self.nodes[key]
        for node in self.nodes.values():
            if node.name == key:
                return node
        names = ", ".join(f"{n.name} ({n.node_id})" for n in self.nodes.values())
        raise NodeNotFoundError(f"no node {key!r} in this network; the nodes are: {names}")

    def add_boot_step(self, key: int | str | None, step: BootStep, name: str | None = None) -> None:
        """Run ``await step(node)`` in the boot-up of node ``key`` (None: of every node) each
        time it boots: after the start-up writes and the error control set-up, before the
        node counts as configured and is started; in the order the steps were added, also
        for nodes with ``do_not_initialise`` (the step decides what to send).

        The text the step returns is the detail of a :class:`BootStepDone` event and is kept
        in ``node.step_results[name]``. A step raising :class:`BootStepError` (or failing
        otherwise) holds the node back: it is not started, its diagnostic says SDO error, its
        ``problem`` names the step and the reason, and :class:`BootStepFailed` is emitted.
        ``name``: default the step's ``name`` attribute or its function name."""
        label = name or getattr(step, "name", None) or getattr(step, "__name__", None) or "step"
        nodes = self.nodes.values() if key is None else [self.node(key)]
        for node in nodes:
            node.boot_steps.append((str(label), step))

    def _set_state(self, new: MasterState) -> None:
        old = self._state
        if new is not old:
            self._state = new
            self._emit(MasterStateChanged(old, new))

    def _set_status(self, new: MasterStatus) -> None:
        self._status = new
        if new is MasterStatus.RUN:
            self._running.set()
        else:
            self._running.clear()

    # ================================================================== events

    def add_listener(self, listener: MasterListener) -> None:
        """Call ``listener(event)`` for every :class:`MasterEvent` (on the event loop)."""
        self._listeners.append(listener)

    def remove_listener(self, listener: MasterListener) -> None:
        """Stop calling ``listener`` (given to :meth:`add_listener`)."""
        if listener in self._listeners:
            self._listeners.remove(listener)

    def add_tpdo_listener(self, listener: TpdoListener) -> None:
        """Call ``listener(node_id, tpdo_number, now)`` each time a TPDO has been taken into
        the process image (``master.inputs`` hold its values; TPDOs of nodes that are not
        operational, and too short ones, are not taken).

        The place for application code that must answer within the cycle, e.g. a toggle
        handshake: the ZAPI ACE2 of seed 000 expects the opposite of its TPDO1 toggle bit
        in RPDO1 before the next SYNC; set the output here and an event-driven RPDO (type
        254/255) goes out at once (:meth:`send_rpdo` when the value did not change)."""
        self._tpdo_listeners.append(listener)

    def remove_tpdo_listener(self, listener: TpdoListener) -> None:
        """Stop calling ``listener`` (given to :meth:`add_tpdo_listener`)."""
        if listener in self._tpdo_listeners:
            self._tpdo_listeners.remove(listener)

    def _tpdo_taken(self, node_id: int, number: int, now: float) -> None:
        for listener in list(self._tpdo_listeners):
            try:
                listener(node_id, number, now)
            except Exception as exc:  # an application's failure must not stop the master
                log.exception("master TPDO listener %r failed", listener)
                self.network.emit(HandlerFailed(f"master TPDO listener {listener!r}", repr(exc)))

    def _emit(self, event: MasterEvent) -> None:
        for listener in list(self._listeners):
            try:
                listener(event)
            except Exception as exc:  # an application's failure must not stop the master
                log.exception("master listener %r failed", listener)
                self.network.emit(HandlerFailed(f"master listener {listener!r}", repr(exc)))
        if self.network.connected:
            self.network.emit(event)

    def _on_network_event(self, event: Event) -> None:
        diag = self.diagnostics
        if isinstance(event, BusStateChanged):
            diag.bus_state = event.new
            if event.tx_errors is not None:
                diag.tx_errors = event.tx_errors
            if event.rx_errors is not None:
                diag.rx_errors = event.rx_errors
            if event.new is BusState.BUS_OFF:
                diag.bus_off_count += 1
        elif isinstance(event, TxQueueFull):
            diag.tx_queue_overflows += 1
        elif isinstance(event, RxOverflow):
            diag.rx_overflows += 1

    # ================================================================== life cycle

    def start(self) -> None:
        """Start the boot-up of the network in the background (call on the event loop).

        Producers first (the master's heartbeat, SYNC, TIME), then the resets and one boot-up
        task per node. When the master produces SYNC, it starts the nodes only once its first
        SYNC is out (one period after this call): some devices refuse NMT start unless SYNC
        already runs (the ZAPI ACE2 of seed 000 raises alarm 248), and a node that needs no
        boot-up (``do_not_initialise``) is ready sooner."""
        if self._started:
            raise MasterError("the master is already started; stop() it first")
        net = self.network
        loop = net.loop
        cfg = self.config.master
        self._producers.start_sync(cfg)  # first: an interface that cannot time it stops all
        self._started = True
        self._sync_seen = False
        self._set_status(MasterStatus.RESET)
        self._state = MasterState.INITIALISING
        now = net.time()
        net.add_listener(self._on_network_event)
        self._subs.append(net.subscribe_all(self._on_frame))
        self._subs.append(net.subscribe(cfg.sync_cob_id, self._on_sync))
        emcy = EmcyConsumer()
        emcy_ids: list[int] = []
        for node in self.nodes.values():
            if not node.config.enabled:
                continue
            var = node.config.od.get_variable(0x1014, 0)
            cob = var.value if var is not None and isinstance(var.value, int) else None
            can_id = emcy_cob_id(node.node_id)
            if cob is not None and not cob & (INVALID | EXTENDED):
                can_id = cob & 0x7FF
                emcy.set_cob_id(node.node_id, can_id)
            emcy_ids.append(can_id)
            node.supervision.install()
        self._hosts.append(net.attach(emcy, emcy_ids, self._on_emcy))
        self._producers.start_heartbeat_and_time(cfg, now)
        self.rpdos.start()
        # the node-IDs LSS gives (CiA 302-2 with CiA 305), then the resets and the boots
        self._set_state(MasterState.RESETTING)
        enabled = [n for n in self.nodes.values() if n.config.enabled]
        by_lss = [n for n in enabled if n.config.lss]
        if by_lss:
            self._lss = LssStep(net, by_lss)
            self._lss_task = loop.create_task(
                self._lss_then_boot(self._lss, enabled), name="cobus-master-lss"
            )
        else:
            self._reset_and_boot(enabled)

    async def _lss_then_boot(self, step: LssStep, enabled: list[ManagedNode]) -> None:
        if await step.run():
            self._reset_and_boot(enabled)
        else:
            for node in enabled:
                node.problem = step.problem

    def _reset_and_boot(self, enabled: list[ManagedNode]) -> None:
        """Reset the nodes (one broadcast or each its own) and start their boot tasks."""
        broadcast = self.config.master.reset == "broadcast" and not any(
            n.config.do_not_initialise for n in enabled
        )
        if broadcast and enabled:
            for node in enabled:
                node.boot.expect_bootup()
            self.network.nmt.reset_node(0)
        self._set_state(MasterState.AWAITING_BOOTUP)
        for node in enabled:
            node.boot.spawn("await" if broadcast else "reset")
        if not enabled:
            self.network.loop.call_soon(self._check_boot_complete)

    async def boot(self, timeout: float | None = None) -> None:
        """Start the network (unless started) and wait until it runs: every mandatory node
        configured and started, every optional one started or found absent.

        :class:`BootTimeoutError` after ``timeout`` seconds names the nodes that hold the
        network back; the master keeps trying in the background."""
        if not self._started:
            self.start()
        if self.running:
            return
        try:
            await asyncio.wait_for(self._running.wait(), timeout)
        except TimeoutError:
            blockers = [n.describe() for n in self.nodes.values() if not n.settled]
            if self._lss is not None and self._lss_task is not None and not self._lss_task.done():
                blockers.insert(0, self._lss.progress())
            if not blockers and self._status is MasterStatus.STOP:
                blockers = ["the network reaction stopped every node"]
            raise BootTimeoutError(timeout or 0.0, blockers) from None

    async def stop(self, *, stop_nodes: bool = False) -> None:
        """End the boot-up tasks and the supervision; with ``stop_nodes`` send NMT stop to
        every node first. The master can be started again."""
        if not self._started:
            return
        net = self.network
        if stop_nodes and net.connected:
            net.nmt.stop(0)
        tasks = [n.boot_task for n in self.nodes.values() if n.boot_task is not None]
        if self._lss_task is not None:
            self._lss_task.cancel()
            tasks.append(self._lss_task)
            self._lss_task = None
        for node in self.nodes.values():
            node.boot.cancel()
        for task in tasks:
            if not task.done():
                with contextlib.suppress(asyncio.CancelledError, Exception):  # ended on purpose
                    await task
        for node in self.nodes.values():
            node.boot_task = None
            node.supervision.stop()
        for sub in self._subs:
            sub.cancel()
        self._subs.clear()
        for host in self._hosts:
            host.close()
        self._hosts.clear()
        self.rpdos.stop()
        self._producers.stop()
        net.remove_listener(self._on_network_event)
        self._started = False
        self._set_status(MasterStatus.OFFLINE)
        self._set_state(MasterState.INITIALISING)
        for node in self.nodes.values():
            node.set_state(NodeState.UNDEFINED)

    async def restart_node(self, key: int | str) -> None:
        """Boot a node again (a manual restart after a fault); see :meth:`ManagedNode.restart`."""
        await self.node(key).restart()

    # ================================================================== boot-up progress

    def _note_configuring(self) -> None:
        if self._state < MasterState.CONFIGURING:
            self._set_state(MasterState.CONFIGURING)

    def _node_configured(self, node: ManagedNode) -> None:
        if self._status is MasterStatus.RUN:
            self._start_nodes([node])
        elif self._status is MasterStatus.STOP:
            self._try_resume()

    def _node_finished(self, node: ManagedNode) -> None:
        if self._status is MasterStatus.RESET:
            self._check_boot_complete()
        elif self._status is MasterStatus.STOP:
            self._try_resume()

    def _check_boot_complete(self) -> None:
        if self._status is not MasterStatus.RESET or not self._started:
            return
        if all(n.settled for n in self.nodes.values()):
            if self._producers.own_sync and not self._sync_seen:
                return  # SYNC runs before the first start: _on_sync starts the network
            self._start_network()

    def _startable(self) -> list[ManagedNode]:
        return [
            n
            for n in self.nodes.values()
            if n.config.enabled and n.config.auto_start and n.state is NodeState.CONFIGURED
        ]

    def _start_network(self) -> None:
        startable = self._startable()
        left_out = [
            n
            for n in self.nodes.values()
            if n.config.enabled and n.state is not NodeState.ABSENT and n not in startable
        ]
        self._set_state(MasterState.RUNNING)
        self._set_status(MasterStatus.RUN)
        now = self.network.time()
        if self.config.master.start == "broadcast" and not left_out and startable:
            self.network.nmt.start(0)
            for node in startable:
                node.supervision.mark_started(now)
            self.rpdos.send_all(startable)
        else:
            self._start_nodes(startable)

    def _start_nodes(self, nodes: list[ManagedNode]) -> None:
        now = self.network.time()
        started = []
        for node in nodes:
            if not node.config.auto_start or node.state is not NodeState.CONFIGURED:
                continue
            self.network.nmt.start(node.node_id)
            node.supervision.mark_started(now)
            started.append(node)
        self.rpdos.send_all(started)

    def _stop_all(self, cause: ManagedNode, reason: str) -> None:
        """The network reaction: NMT stop to every node."""
        if self._status is MasterStatus.STOP:
            return
        self.network.nmt.stop(0)
        for node in self.nodes.values():
            if node.config.enabled:
                node.supervision.mark_stopped()
        self._set_status(MasterStatus.STOP)
        self._emit(NetworkStopped(cause.node_id, reason))

    def _try_resume(self) -> None:
        """After a network stop: start every node again once no node is faulty."""
        if self._status is not MasterStatus.STOP:
            return
        if any(n.state is NodeState.ERROR_CONTROL for n in self.nodes.values()):
            return
        self._set_status(MasterStatus.RUN)
        now = self.network.time()
        resumed = []
        for node in self.nodes.values():
            if not node.config.enabled or not node.config.auto_start:
                continue
            if node.state in (NodeState.OPERATIONAL, NodeState.CONFIGURED):
                self.network.nmt.start(node.node_id)
                node.supervision.mark_started(now)
                resumed.append(node)
        self.rpdos.send_all(resumed)

    # ================================================================== frames and events

    def _send(self, frame: Frame) -> bool:
        try:
            self.network.send(frame)
        except (TxOverflowError, NetworkClosedError):
            self.diagnostics.send_errors += 1
            return False
        return True

    def _on_frame(self, frame: Frame, now: float) -> None:
        self.diagnostics.frames += 1
        self._meter.add(frame, now)

    def _on_monitor(self, event: Event) -> None:
        node_id = getattr(event, "node_id", None)
        node = self.nodes.get(node_id) if isinstance(node_id, int) else None
        if node is None or not self._started:
            return
        if isinstance(event, BootupReceived):
            if self._lss_task is not None and not self._lss_task.done():
                return  # (a device LSS just named: the master's resets follow)
            node.supervision.on_bootup()
        elif isinstance(event, HeartbeatTimeout):
            if node.error_control == "heartbeat":
                node.supervision.error_control_lost("heartbeat")
        elif isinstance(event, RemoteStateChanged) and event.new is not NmtState.INITIALISING:
            node.supervision.on_heartbeat_state(event.new)

    def _on_emcy(self, event: Event) -> None:
        if isinstance(event, EmcyReceived):
            node = self.nodes.get(event.node_id)
            if node is not None:
                node.supervision.on_emcy(event, self.network.time())

    def _on_sync(self, frame: Frame, now: float) -> None:
        diag = self.diagnostics
        diag.sync_count += 1
        diag.sync_toggle = not diag.sync_toggle
        if not self._sync_seen:
            self._sync_seen = True
            if self._status is MasterStatus.RESET:
                self._check_boot_complete()
                return
        if self.running:
            self.rpdos.on_sync()

    # ================================================================== process image

    def set_output(self, name: str, value: Any) -> None:
        """Set an output signal (``master.outputs[name] = value`` does the same).

        Event-driven RPDOs (254/255) go out at once when the value changes, synchronous ones
        with the next SYNC; nothing goes to a node that is not operational."""
        self.set_outputs({name: value})

    def set_outputs(self, values: Mapping[str, Any], *, always: bool = False) -> None:
        """Set several output signals at once: each event-driven RPDO they are in goes out
        once (not once per signal) when one of its values changed, or with ``always=True``
        even when none did (a device such as the ZAPI ACE2 wants an answer every cycle);
        synchronous RPDOs go with the next SYNC."""
        self.rpdos.set_outputs(values, always=always)

    def send_rpdo(self, key: int | str, number: int) -> bool:
        """Send RPDO ``number`` of a node now with the current outputs, whether they changed
        or not (an event-driven RPDO otherwise goes out only on a change, a synchronous one
        with the SYNC): for devices that want an RPDO every cycle, such as the ZAPI ACE2
        whose handshake needs an answer to each TPDO1. Returns whether it was sent (not
        while the node is not operational or the network does not run)."""
        return self.rpdos.send(self.node(key), number)

    def summary(self) -> list[dict[str, Any]]:
        """One line of figures per node (state, diagnostic, EMCY count...)."""
        return [n.summary() for n in self.nodes.values()]


class _NodePort:
    """The master as its nodes see it (:class:`~cobus.master._context.NodeContext`)."""

    __slots__ = ("_master",)

    def __init__(self, master: Master) -> None:
        self._master = master

    @property
    def master(self) -> Master:
        return self._master

    @property
    def network(self) -> AsyncNetwork:
        return self._master.network

    @property
    def config(self) -> NetworkConfig:
        return self._master.config

    @property
    def image(self) -> ProcessImage:
        return self._master.image

    @property
    def diagnostics(self) -> MasterDiagnostics:
        return self._master.diagnostics

    @property
    def status(self) -> MasterStatus:
        return self._master.status

    @property
    def started(self) -> bool:
        return self._master.started

    @property
    def running(self) -> bool:
        return self._master.running

    def emit(self, event: MasterEvent) -> None:
        self._master._emit(event)

    def note_configuring(self) -> None:
        self._master._note_configuring()

    def node_configured(self, node: ManagedNode) -> None:
        self._master._node_configured(node)

    def node_finished(self, node: ManagedNode) -> None:
        self._master._node_finished(node)

    def stop_all(self, cause: ManagedNode, reason: str) -> None:
        self._master._stop_all(cause, reason)

    def send_all_rpdos(self, nodes: list[ManagedNode]) -> None:
        self._master.rpdos.send_all(nodes)

    def tpdo_taken(self, node_id: int, number: int, now: float) -> None:
        self._master._tpdo_taken(node_id, number, now)

    def send(self, frame: Frame) -> bool:
        return self._master._send(frame)

    def keep(self, subscription: Subscription) -> None:
        self._master._subs.append(subscription)

    def keep_host(self, host: MachineHost) -> None:
        self._master._hosts.append(host)

    def watch_heartbeat(self, node_id: int, consumer_time: float, now: float) -> None:
        monitor = self._master._monitor
        monitor.watch(node_id, consumer_time, now)
        if consumer_time:
            self._master._monitor_host.apply(monitor.on_timer(now))

    def heartbeat_frame(self, frame: Frame, now: float) -> None:
        self._master._monitor_host.feed(frame, now)
