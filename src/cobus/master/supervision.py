"""The supervision of one node under the master, once its boot has configured it.

CiA 302-2 leaves a configured node to the master's error control: its heartbeat (or the node
guarding the boot fell back to) is watched, a loss or a toggle fault runs the node's error
reaction (CiA 302-2 "error control event"; stop the node, stop all, or nothing), and a node
heard again comes back (cheaply when its own report says it never re-booted, by a new boot
otherwise). Beside that: its emergencies (8 kept, newest first), its TPDOs (counted, length
checked, watched by their event timers), the NMT state it reports against the one the master
expects (a node that leaves it is brought back a few times at most), and the state last
commanded by this process (the application's own stop is not undone).

:class:`NodeSupervision` is ``node.supervision``; it sees the node's public state and the
master only through the node's :class:`~cobus.master._context.NodeContext`.
"""

from __future__ import annotations

from collections import deque
from functools import partial
from typing import TYPE_CHECKING

from cobus.master.events import (
    ErrorControlLost,
    ErrorControlRestored,
    GuardingToggleFault,
    NodeBooted,
    NodeEmergency,
    StateRestored,
    TpdoLengthError,
    TpdoMissing,
    TpdoRestored,
    UnexpectedState,
)
from cobus.master.states import EmcyRecord, NodeState
from cobus.proto import Event, Frame
from cobus.proto import guarding as _guarding
from cobus.proto.connection_set import error_control_cob_id
from cobus.proto.emcy import EmcyReceived
from cobus.proto.nmt import NmtState
from cobus.proto.pdo import RpdoResumed, RpdoTimeout, RpdoWatchdog

if TYPE_CHECKING:
    import asyncio

    from cobus.master.config import PdoLayout
    from cobus.master.node import ManagedNode
    from cobus.runtime import MachineHost

__all__ = ["NodeSupervision"]

#: The EMCY code of an RPDO the node missed (CiA 301 "RPDO timeout").
_RPDO_TIMEOUT_EMCY = 0x8250
#: Who guards a node, for the network's record (AsyncNetwork.claim_guarding).
_GUARD_OWNER = "the master"
_VALID_STATES = {int(s) for s in NmtState if s is not NmtState.INITIALISING}


class NodeSupervision:
    """What the master watches of one configured node: ``node.supervision``.

    Its flags are read-only here (the node's diagnostic and LEDs read them); the master
    tells it what happened (:meth:`mark_started`, :meth:`commanded`, :meth:`on_emcy` ...),
    the node's boot resets, starts and stops it.
    """

    def __init__(self, node: ManagedNode) -> None:
        self.node = node
        self.context = node.context
        self.config = node.config
        self.node_id = node.node_id
        self.emcy_count = 0
        self.error_register = 0
        self._emcy: deque[EmcyRecord] = deque(maxlen=8)
        self._rebooted = False
        self._ec_lost = False
        self._toggle_fault = False
        self._heard_again = False
        self._rpdo_missing = False
        self._last_ec: float | None = None
        #: The NMT state the node's last heartbeat (or guarding reply) gave, and when.
        self._heard: tuple[float, NmtState] | None = None
        #: The last NMT state this process commanded the node into since its boot-up (the
        #: application's or the master's own stop is not undone by a wake).
        self._last_commanded: NmtState | None = None
        self._first_check: asyncio.TimerHandle | None = None
        #: A pending NMT command bringing the node back to the state the master expects.
        self._heal: asyncio.TimerHandle | None = None
        self._unexpected = False  # an UnexpectedState not yet followed by StateRestored
        self._heals: list[float] = []  # when the last heals were sent (a limit per window)
        self._guard: _guarding.GuardingMaster | None = None
        self._guard_host: MachineHost | None = None
        self._guard_bad = False
        self._watchdogs: dict[int, tuple[RpdoWatchdog, MachineHost, PdoLayout]] = {}
        self._tpdos_seen: set[int] = set()
        self._tpdos_missing: set[int] = set()
        self._tpdos_short: set[int] = set()

    # ================================================================== what it found

    @property
    def lost(self) -> bool:
        """The node's heartbeat or guarding is lost (not heard within its time)."""
        return self._ec_lost

    @property
    def toggle_fault(self) -> bool:
        """A guarding reply came with the wrong toggle bit."""
        return self._toggle_fault

    @property
    def rebooted(self) -> bool:
        """The node booted again by itself since the master last started it."""
        return self._rebooted

    @property
    def rpdo_missing(self) -> bool:
        """The node's last emergency said it misses an RPDO (8250h, not reset since)."""
        return self._rpdo_missing

    @property
    def tpdo_missing(self) -> bool:
        """A watched TPDO of the node stayed away longer than its event timer."""
        return bool(self._tpdos_missing)

    @property
    def tpdo_too_short(self) -> bool:
        """A TPDO of the node came shorter than its mapping."""
        return bool(self._tpdos_short)

    @property
    def tpdos_pending(self) -> bool:
        """A watched TPDO has not come since the node was started."""
        return any(n not in self._tpdos_seen for n in self._watchdogs)

    @property
    def heard(self) -> tuple[float, NmtState] | None:
        """When (network time) the node's last heartbeat or guarding reply came, and the
        state it gave (None: none since the master started)."""
        return self._heard

    @property
    def last_commanded(self) -> NmtState | None:
        """The NMT state this process last commanded the node into since its boot-up."""
        return self._last_commanded

    @property
    def emcy_history(self) -> tuple[EmcyRecord, ...]:
        """The last 8 emergencies, newest first."""
        return tuple(self._emcy)

    def reset(self) -> None:
        """A new boot: supervision stopped, its flags and its count of commands back
        cleared."""
        self.stop()
        self._ec_lost = self._toggle_fault = self._heard_again = False
        self._tpdos_missing.clear()
        self._tpdos_short.clear()
        self._tpdos_seen.clear()
        self._heal_done()
        self._heals.clear()  # (a new boot: a new count of commands back)

    # ================================================================== start / stop

    def mark_started(self, now: float) -> None:
        """The master sent the NMT start (to this node or to all)."""
        self._heal_done()
        self.node.expected_nmt = NmtState.OPERATIONAL
        self.node.nmt_state = NmtState.OPERATIONAL
        self._rebooted = False
        self._tpdos_seen.clear()
        self._tpdos_missing.clear()
        self._tpdos_short.clear()
        for watchdog, host, layout in self._watchdogs.values():
            assert layout.timeout is not None
            ms = max(1, min(0xFFFF, round(layout.timeout * 1000)))
            watchdog.set_event_timer(0, now)
            watchdog.set_event_timer(ms, now)
            host.apply(watchdog.on_timer(now))
        self.node.set_state(NodeState.OPERATIONAL)

    def mark_stopped(self) -> None:
        """The master sent an NMT stop to this node (or to all)."""
        self._heal_done()
        self.node.expected_nmt = NmtState.STOPPED
        self.node.nmt_state = NmtState.STOPPED
        self._disarm_watchdogs()
        self.context.image.zero_inputs(self.node_id)

    # ================================================================== supervision

    def install(self) -> None:
        """Subscribe what the node's supervision needs (called once by the master)."""
        context = self.context
        net = context.network
        context.keep(net.subscribe(error_control_cob_id(self.node_id), self._on_ec_frame))
        for layout in self.config.tpdos:
            context.keep(
                net.subscribe(
                    layout.cob_id, partial(self._on_tpdo, layout), extended=layout.extended
                )
            )
            if layout.timeout is not None:
                watchdog = RpdoWatchdog(layout.cob_id, 0, extended=layout.extended)
                host = net.attach(watchdog, (), partial(self._on_watchdog, layout.number))
                context.keep_host(host)
                self._watchdogs[layout.number] = (watchdog, host, layout)

    def start(self) -> None:
        """The node is configured: watch its heartbeat (the first one within its consumer
        time) or guard it, as its boot set error control up."""
        now = self.context.network.time()
        kind = self.node.error_control
        cfg = self.config
        if kind == "heartbeat":
            self.context.watch_heartbeat(self.node_id, cfg.heartbeat_consumer_time, now)
            self._first_check = self.context.network.loop.call_later(
                cfg.heartbeat_consumer_time, self._check_first_heartbeat, now
            )
        elif kind == "guarding":
            guard_ms, factor = (
                (cfg.guard_time, cfg.life_time_factor or 3)
                if cfg.guard_time
                else cfg.fallback_guarding
            )
            self.context.network.claim_guarding(self.node_id, _GUARD_OWNER, take=True)
            self._guard = _guarding.GuardingMaster(self.node_id, guard_ms, factor)
            self._guard_host = self.context.network.attach(self._guard, (), self._on_guard_event)
            guard = self._guard
            self._guard_host.run(lambda t: guard.start(t))

    def stop(self) -> None:
        """Stop watching the node (error control, first heartbeat, healing, TPDO watchdogs)."""
        if self._first_check is not None:
            self._first_check.cancel()
            self._first_check = None
        if self._heal is not None:
            self._heal.cancel()
            self._heal = None
        now = self.context.network.time() if self.context.network.connected else 0.0
        self.context.watch_heartbeat(self.node_id, 0.0, now)
        if self._guard_host is not None:
            self._guard_host.close()
            self.context.network.release_guarding(self.node_id, _GUARD_OWNER)
        self._guard = None
        self._guard_host = None
        self._disarm_watchdogs()

    def _disarm_watchdogs(self) -> None:
        if not self.context.network.connected:
            return
        now = self.context.network.time()
        for watchdog, host, _layout in self._watchdogs.values():
            watchdog.set_event_timer(0, now)
            host.apply(watchdog.on_timer(now))

    def _check_first_heartbeat(self, since: float) -> None:
        self._first_check = None
        if self._last_ec is None or self._last_ec < since:
            self.error_control_lost("heartbeat")

    def _on_ec_frame(self, frame: Frame, now: float) -> None:
        if frame.rtr:
            return
        self._last_ec = now
        data = frame.data
        if len(data) == 1:
            code = data[0] & 0x7F
            if code in _VALID_STATES:
                self._heard = (now, NmtState(code))
            elif code == 0:  # a boot-up: pre-operational from now on
                self._heard = (now, NmtState.PRE_OPERATIONAL)
        if self.node.error_control != "guarding" or data == b"\x00":
            # A guarding reply is no heartbeat (its toggle bit would read as a malformed
            # one); the monitor only needs a guarded node's boot-up, to see it re-boot.
            self.context.heartbeat_frame(frame, now)
        if self.node.error_control == "guarding" and self._guard_host is not None:
            self._guard_bad = False
            self._guard_host.feed(frame, now)
            if len(data) == 1 and data[0] & 0x7F in _VALID_STATES and not self._guard_bad:
                self._alive("guarding", NmtState(data[0] & 0x7F))
        elif (
            self.node.error_control == "heartbeat"
            and len(data) == 1
            and data[0] in _VALID_STATES
            and (self._ec_lost or self.node.state is NodeState.ERROR_CONTROL)
        ):
            self._alive("heartbeat", NmtState(data[0]))

    def _on_guard_event(self, event: Event) -> None:
        if isinstance(event, _guarding.GuardingToggleError):
            self._guard_bad = True
            self._toggle_fault = True
            self.node.problem = f"guarding toggle {event.received}, expected {event.expected}"
            self.context.emit(GuardingToggleFault(self.node_id, event.expected, event.received))
            self._fault()
        elif isinstance(event, _guarding.MalformedGuardingReply):
            self._guard_bad = True
        elif isinstance(event, _guarding.GuardingNodeLost):
            self.error_control_lost("guarding")
        elif (
            isinstance(event, _guarding.GuardingStateChanged)
            and event.new is not NmtState.INITIALISING
        ):
            self._reported(event.new)

    def error_control_lost(self, kind: str) -> None:
        """The node's error control (``kind``: heartbeat or guarding) was lost: its error
        reaction."""
        if self._ec_lost:
            return
        self._ec_lost = True
        self.node.problem = f"no {kind} within its time"
        self.context.emit(ErrorControlLost(self.node_id, kind))
        self._fault()

    def _fault(self) -> None:
        """An error control fault: state 99, inputs 0, the configured reaction."""
        was_running = self.node.state is NodeState.OPERATIONAL
        self.node.set_state(NodeState.ERROR_CONTROL)
        self._disarm_watchdogs()
        if self.config.zero_inputs:
            self.context.image.zero_inputs(self.node_id)
        reaction = self.config.error_reaction
        if reaction == "stop_node":
            self.context.network.nmt.stop(self.node_id)
            self.node.expected_nmt = NmtState.STOPPED
        elif reaction == "stop_all" and (was_running or self.context.running):
            self.context.stop_all(self.node, self.node.problem or "error control fault")

    def _alive(self, kind: str, state: NmtState) -> None:
        """A valid heartbeat or guarding reply: ends a loss or a toggle fault. With a manual
        restart the fault stays shown until the application restarts the node."""
        if not (self._ec_lost or self._toggle_fault):
            return
        manual = self.config.restart == "manual"
        if self.node.state is NodeState.ERROR_CONTROL and manual:
            if not self._heard_again:
                self._heard_again = True
                self.node.problem = "heard again; waiting for a manual restart"
                self.context.emit(ErrorControlRestored(self.node_id, kind, state))
            return
        self._ec_lost = False
        self._toggle_fault = False
        self.context.emit(ErrorControlRestored(self.node_id, kind, state))
        if self.node.state is not NodeState.ERROR_CONTROL:
            return
        if (
            state is NmtState.OPERATIONAL
            and self.node.expected_nmt is NmtState.OPERATIONAL
            and not self._rebooted
        ):
            # The cheap check: its own report says it never re-booted (a re-booted node
            # comes back pre-operational, with a boot-up) - its configuration is intact,
            # so it goes on as it is. Only a real re-boot costs a full reconfiguration:
            # on a lossy bus a node then degrades for a moment instead of collapsing.
            self.node.problem = None
            self.mark_started(self.context.network.time())
            if self.context.running:  # outputs set while it was away reach it now
                self.context.send_all_rpdos([self.node])
            return
        self.node.boot.spawn("reset")

    def _reported(self, state: NmtState) -> None:
        """The node reports ``state`` by heartbeat or guarding."""
        old = self.node.nmt_state
        self.node.nmt_state = state
        expected = self.node.expected_nmt
        if (
            expected is not None
            and state is not expected
            and state is not old
            and self.node.state is NodeState.OPERATIONAL
        ):
            self.context.emit(UnexpectedState(self.node_id, expected, state))
            self._unexpected = True
            self._disarm_watchdogs()
            if self.config.zero_inputs:
                self.context.image.zero_inputs(self.node_id)
            self._bring_back(expected, state)
        elif (
            state is NmtState.OPERATIONAL
            and expected is NmtState.OPERATIONAL
            and old is not state
            and self.node.state is NodeState.OPERATIONAL
        ):
            # back in operational: supervise the TPDOs again
            self.mark_started(self.context.network.time())
        if expected is not None and state is expected and old is not None and old is not state:
            self._heal_done()
            if self._unexpected:
                self._unexpected = False
                self.context.emit(StateRestored(self.node_id, state))

    #: At most this many NMT commands bring a node back within HEAL_WINDOW seconds; a node
    #: that keeps leaving the expected state after that is left as it is (and says so).
    HEAL_LIMIT = 3
    HEAL_WINDOW = 10.0
    #: Seconds between noticing the unexpected state and the command (someone else's
    #: command sequence, or the node's own reset, may still be under way).
    HEAL_DELAY = 0.2

    def _bring_back(self, expected: NmtState, state: NmtState) -> None:
        """A node left the state the master expects (someone else's NMT command, a local
        fault): with ``restart: auto`` it gets the command back, a few times at most; with
        ``restart: manual`` it waits for the application (``master.restart``)."""
        if self.config.restart == "manual":
            self._say(f"reports {state.name}; waiting for a manual restart")
            return
        network = self.context.network
        now = network.time()
        self._heals = [t for t in self._heals if now - t < self.HEAL_WINDOW]
        if len(self._heals) >= self.HEAL_LIMIT:
            self._say(
                f"reports {state.name} again after {self.HEAL_LIMIT} commands back to "
                f"{expected.name} within {self.HEAL_WINDOW:g} s: left as it is"
            )
            return
        if self._heal is not None:
            self._heal.cancel()
        self._say(f"reports {state.name}; bringing it back to {expected.name}")
        self._heal = network.loop.call_later(self.HEAL_DELAY, self._send_back)

    def _say(self, text: str) -> None:
        """Show ``text`` as the node's problem unless another problem is shown already."""
        if self.node.problem is None or self.node.problem.startswith("reports "):
            self.node.problem = text

    def _heal_done(self) -> None:
        """The node is where the master wants it (or the master took over): no command
        back is pending and the 'reports ...' text goes."""
        if self._heal is not None:
            self._heal.cancel()
            self._heal = None
        if self.node.problem is not None and self.node.problem.startswith("reports "):
            self.node.problem = None

    def _send_back(self) -> None:
        self._heal = None
        expected = self.node.expected_nmt
        if (
            expected is None
            or self.node.state is not NodeState.OPERATIONAL
            or not self.context.network.connected
        ):
            return
        if self.node.nmt_state is expected:
            self._heal_done()
            return
        command = {
            NmtState.OPERATIONAL: "start",
            NmtState.PRE_OPERATIONAL: "enter_preoperational",
            NmtState.STOPPED: "stop",
        }.get(expected)
        if command is None:
            return
        network = self.context.network
        self._heals.append(network.time())
        try:
            getattr(network.nmt, command)(self.node_id)
        except Exception as exc:  # (a full transmit backlog, a closed network)
            network.report_failure(f"master: node {self.node_id} NMT {command}", exc)
        # Did it take? If the node still reports the old state, count it and try again.
        check = max(self.HEAL_DELAY, 2 * (self.config.heartbeat_consumer_time or 0.5))
        self._heal = network.loop.call_later(check, self._check_back)

    def _check_back(self) -> None:
        self._heal = None
        expected, state = self.node.expected_nmt, self.node.nmt_state
        if expected is None or state is None or self.node.state is not NodeState.OPERATIONAL:
            return
        if state is expected:
            self._heal_done()
        else:
            self._bring_back(expected, state)

    def commanded(self, command: int) -> None:
        """This process sent NMT ``command`` to the node (the application or the master): the
        state it asks for is the one expected from now on."""
        wanted = {
            0x01: NmtState.OPERATIONAL,
            0x02: NmtState.STOPPED,
            0x80: NmtState.PRE_OPERATIONAL,
        }.get(command)
        if wanted is not None:
            self._last_commanded = wanted
        if wanted is None or self.node.state is not NodeState.OPERATIONAL:
            return  # (a reset: the boot-up that follows is handled; a node not running yet)
        self._heal_done()
        if wanted is self.node.expected_nmt:
            return
        self.node.expected_nmt = wanted
        if wanted is not NmtState.OPERATIONAL:
            self._disarm_watchdogs()
            if self.config.zero_inputs:
                self.context.image.zero_inputs(self.node_id)

    def on_bootup(self) -> None:
        """The node sent its boot-up message: its boot takes it, or (sent by itself) the
        node boots again."""
        node = self.node
        node.nmt_state = NmtState.PRE_OPERATIONAL
        self._last_commanded = None
        if node.boot.take_bootup():
            self.context.emit(NodeBooted(self.node_id, True))
            return
        self.context.emit(NodeBooted(self.node_id, False))
        if not self.context.started or not self.config.enabled:
            return
        running = node.boot_task is not None and not node.boot_task.done()
        if running and node.state is NodeState.UNDEFINED:
            return  # a boot-up from before the master's reset, which is on its way
        if node.state is NodeState.ERROR_CONTROL and self.config.restart == "manual":
            node.problem = "booted again; waiting for a manual restart"
            return
        if node.state is NodeState.OPERATIONAL and self.config.zero_inputs:
            self.context.image.zero_inputs(self.node_id)
        self._rebooted = True
        node.boot.spawn("booted")

    def on_heartbeat_state(self, state: NmtState) -> None:
        """The master's heartbeat consumer heard the node in ``state``."""
        if self.node.error_control == "heartbeat" or self.node.error_control is None:
            self._reported(state)

    def on_emcy(self, event: EmcyReceived, now: float) -> None:
        """An emergency of the node (from the master's EMCY consumer) at ``now``."""
        self.emcy_count += 1
        self.error_register = int(event.register)
        record = EmcyRecord(
            self.node_id, now, event.code, event.register, event.manufacturer_data, event.text
        )
        self._emcy.appendleft(record)
        if event.code == _RPDO_TIMEOUT_EMCY:
            self._rpdo_missing = True
        elif event.is_reset:
            self._rpdo_missing = False
        self.context.emit(
            NodeEmergency(
                self.node_id, event.code, int(event.register), event.manufacturer_data, event.text
            )
        )

    # ================================================================== process data

    def _on_tpdo(self, layout: PdoLayout, frame: Frame, now: float) -> None:
        if frame.rtr or not self.node.operational:
            return  # process data is blocked unless the node is operational
        number = layout.number
        self.node.tpdo_received[number] = self.node.tpdo_received.get(number, 0) + 1
        counters = self.context.diagnostics.pdo_counters
        key = (self.node_id, "tpdo", number)
        counters[key] = counters.get(key, 0) + 1
        watch = self._watchdogs.get(number)
        if watch is not None:
            watch[1].feed(frame, now)
        data = frame.data
        if len(data) < layout.length:
            if number not in self._tpdos_short:
                self._tpdos_short.add(number)
                self.context.emit(TpdoLengthError(self.node_id, number, layout.length, len(data)))
            return
        self._tpdos_short.discard(number)
        self._tpdos_seen.add(number)
        self.context.image.update_tpdo(self.node_id, number, layout.codec.unpack(data))
        self.context.tpdo_taken(self.node_id, number, now)

    def _on_watchdog(self, number: int, event: Event) -> None:
        watch = self._watchdogs.get(number)
        if watch is None:
            return
        layout = watch[2]
        if isinstance(event, RpdoTimeout):
            self._tpdos_missing.add(number)
            if self.config.zero_inputs:
                self.context.image.zero_inputs(self.node_id, number)
            self.context.emit(TpdoMissing(self.node_id, number, layout.cob_id))
        elif isinstance(event, RpdoResumed):
            self._tpdos_missing.discard(number)
            self.context.emit(TpdoRestored(self.node_id, number, layout.cob_id))
