"""NMT of one remote node as its client sees it: ``node.nmt``.

The node's state is what it last reported: its heartbeat (or a boot-up message, which reports
INITIALISING). Commands go to this node only. ``watch_heartbeat(timeout)`` makes this side a
heartbeat consumer of the node (:class:`~cobus.proto.heartbeat.HeartbeatTimeout` once the
node falls silent for ``timeout`` seconds, :class:`~cobus.proto.heartbeat.HeartbeatResumed`
when it is heard again). The events go to the callbacks of ``node.nmt`` and to the network's
listeners.

Choice: sending a command does not change :attr:`AsyncRemoteNmt.state`: the state is only what the
node says (python-canopen assumes the commanded state at once; a node that missed the command,
or refused it, would then be shown wrongly). :attr:`AsyncRemoteNmt.commanded` keeps the command.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Final

from cobus._moved import renamed_names
from cobus.proto import NOTHING, Event, Frame
from cobus.proto.connection_set import ERROR_CONTROL_BASE as _HEARTBEAT
from cobus.proto.heartbeat import (
    BootupReceived,
    HeartbeatMonitor,
    HeartbeatResumed,
    RemoteStateChanged,
)
from cobus.proto.nmt import NmtCommand, NmtState
from cobus.runtime._service import Callbacks, Waiters, parse_nmt_command, removed_error
from cobus.runtime.errors import NmtTimeoutError

if TYPE_CHECKING:
    from cobus.runtime.network import AsyncNetwork, MachineHost, Subscription

__all__ = ["AsyncRemoteNmt", "NmtTimeoutError"]

_STATES = frozenset(int(s) for s in NmtState)
_BOOTUP = int(NmtState.INITIALISING)  # a global: asked for every heartbeat
_RESETS = (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION)
_COMMAND_FOR = {
    NmtState.OPERATIONAL: NmtCommand.START,
    NmtState.STOPPED: NmtCommand.STOP,
    NmtState.PRE_OPERATIONAL: NmtCommand.ENTER_PREOPERATIONAL,
}


def _parse_state(state: NmtState | int | str) -> NmtState:
    if isinstance(state, str):
        key = state.upper().replace("-", "_").replace(" ", "_")
        aliases = {"PREOPERATIONAL": "PRE_OPERATIONAL", "BOOTUP": "INITIALISING"}
        try:
            return NmtState[aliases.get(key, key)]
        except KeyError:
            names = ", ".join(s.name.lower() for s in NmtState)
            raise ValueError(f"unknown NMT state {state!r}; use one of {names}") from None
    return NmtState(state)


class AsyncRemoteNmt:
    """The NMT state of one remote node, the commands to it, its heartbeat supervision."""

    #: The node-ID.
    node_id: Final[int]
    #: When the node was last heard (heartbeat or boot-up), on the network's clock.
    last_heard: float | None
    #: How many boot-up messages the node sent while watched.
    bootups: int
    #: The last command sent to the node through this object (or None).
    commanded: NmtCommand | None

    def __init__(self, network: AsyncNetwork, node_id: int) -> None:
        self._network = network
        self._removed = False
        self.node_id = node_id
        self.last_heard = None
        self.bootups = 0
        self.commanded = None
        self._reset_answered = False  # a boot-up answered our last reset, unclaimed
        self._monitor = HeartbeatMonitor(track_all=False)
        self._monitor.watch(node_id, 0.0, 0.0)
        self._host: MachineHost = network.attach(self._monitor, on_event=self._on_event)
        self._subscription: Subscription | None = network.subscribe(
            _HEARTBEAT + node_id, self._on_frame
        )
        self._callbacks: Callbacks[Event] = Callbacks(network, f"NMT of node {node_id}")
        self._waiters: Waiters[Event] = Waiters(network)

    def __repr__(self) -> str:
        state = "unknown" if self.state is None else self.state.name
        lost = " (heartbeat lost)" if self.lost else ""
        return f"<NMT of node {self.node_id}: {state}{lost}>"

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> NmtState | None:
        """The state the node last reported (None: not heard yet). Setting it sends the
        command that leads there (``nmt.state = "OPERATIONAL"`` sends start), as with
        python-canopen; the state itself changes when the node reports it."""
        return self._monitor.state(self.node_id)

    @state.setter
    def state(self, state: NmtState | int | str) -> None:
        if isinstance(state, str):
            key = state.upper().replace("-", " ").replace("_", " ")
            reset = {"RESET": NmtCommand.RESET_NODE, "RESET NODE": NmtCommand.RESET_NODE}
            reset["RESET COMMUNICATION"] = NmtCommand.RESET_COMMUNICATION
            if key in reset:
                self.send(reset[key])
                return
        wanted = _parse_state(state)
        command = _COMMAND_FOR.get(wanted)
        if command is None:
            raise ValueError(
                f"no NMT command leads to {wanted.name}; use reset_node() for a boot-up"
            )
        self.send(command)

    @property
    def heartbeat_timeout(self) -> float:
        """The heartbeat consumer time in seconds (0: the heartbeat is not supervised)."""
        return self._monitor.timeout(self.node_id)

    @property
    def lost(self) -> bool:
        """Whether the supervised heartbeat timed out and the node has not been heard since."""
        return self._monitor.is_lost(self.node_id)

    def watch_heartbeat(self, timeout: float) -> None:
        """Expect a heartbeat at least every ``timeout`` seconds (0 stops supervising).

        Set it somewhat above the node's producer time (1017h), e.g. 1.5 times."""
        self._monitor.watch(self.node_id, timeout, self._network.time())
        self._host.apply(NOTHING)

    # ------------------------------------------------------------------ commands
    def send(self, command: NmtCommand | int | str) -> None:
        """Send an NMT command to this node (``"start"``, ``NmtCommand.STOP``, 0x81...)."""
        parsed = parse_nmt_command(command)
        self._network.nmt.send(parsed, self.node_id)  # (observers of the network's NMT see it)
        self.commanded = NmtCommand(parsed)
        self._reset_answered = False

    def start(self) -> None:
        """Start the node (NMT state OPERATIONAL)."""
        self.send(NmtCommand.START)

    def stop(self) -> None:
        """Stop the node (NMT state STOPPED)."""
        self.send(NmtCommand.STOP)

    def enter_preoperational(self) -> None:
        """Put the node into PRE-OPERATIONAL."""
        self.send(NmtCommand.ENTER_PREOPERATIONAL)

    def reset_node(self) -> None:
        """Reset the node's application (it boots up again)."""
        self.send(NmtCommand.RESET_NODE)

    def reset_communication(self) -> None:
        """Reset the node's communication (it boots up again)."""
        self.send(NmtCommand.RESET_COMMUNICATION)

    # ------------------------------------------------------------------ waiting
    async def wait_for_state(self, state: NmtState | int | str, timeout: float = 1.0) -> NmtState:
        """Return once the node reports ``state`` (at once if it last reported it);
        :class:`NmtTimeoutError` after ``timeout`` seconds."""
        wanted = _parse_state(state)
        if self.state is wanted and not self.lost:
            return wanted
        await self._wait(
            lambda e: (
                (isinstance(e, RemoteStateChanged) and e.new is wanted)
                or (isinstance(e, HeartbeatResumed) and e.state is wanted)
            ),
            timeout,
            f"report state {wanted.name}",
        )
        return wanted

    async def wait_for_bootup(self, timeout: float = 5.0) -> None:
        """Return at the node's next boot-up message; :class:`NmtTimeoutError` after
        ``timeout`` seconds. After :meth:`reset_node` or :meth:`reset_communication`, the
        boot-up that answered it counts even if it came before this call (a fast node)."""
        if self._reset_answered:
            self._reset_answered = False
            return
        await self._wait(lambda e: isinstance(e, BootupReceived), timeout, "boot up")
        self._reset_answered = False

    async def wait_for_heartbeat(self, timeout: float = 1.0) -> NmtState:
        """The state in the node's next heartbeat; :class:`NmtTimeoutError` after
        ``timeout`` seconds."""
        await self._wait(lambda e: isinstance(e, _Heard), timeout, "send a heartbeat")
        state = self.state
        assert state is not None
        return state

    async def _wait(self, match: Callable[[Event], bool], timeout: float, what: str) -> None:
        if self._removed:
            raise removed_error(self.node_id)

        def timed_out() -> NmtTimeoutError:
            heard = (
                "it has not been heard: its heartbeat producer time 1017h may be 0, or its "
                "boot-up came before this side listened"
                if self.last_heard is None
                else f"last heard {self._network.time() - self.last_heard:.3g} s ago in state "
                f"{'unknown' if self.state is None else self.state.name}"
            )
            return NmtTimeoutError(
                f"node {self.node_id} did not {what} within {timeout:g} s ({heard})"
            )

        await self._waiters.wait(timeout, timed_out, match)

    # ------------------------------------------------------------------ events
    def add_callback(self, callback: Callable[[Event], object]) -> None:
        """Call ``callback(event)`` with each NMT event of the node: state changes, boot-up,
        heartbeat timeout and resumption, malformed heartbeats."""
        self._callbacks.add(callback)

    def remove_callback(self, callback: Callable[[Event], object]) -> None:
        """Stop calling ``callback`` (given to :meth:`add_callback`)."""
        self._callbacks.remove(callback)

    def _on_frame(self, frame: Frame, now: float) -> None:
        data = frame.data
        if len(data) == 1 and data[0] & 0x80 and not frame.rtr:
            # a node guarding reply: bit 7 is the toggle, bits 0-6 the state
            data = bytes((data[0] & 0x7F,))
            frame = Frame(frame.cob_id, data)
        self._host.feed(frame, now)  # the monitor's events first: the state is then current
        if frame.rtr or len(data) != 1 or data[0] not in _STATES:
            return
        self.last_heard = now
        if data[0] == _BOOTUP:
            self.bootups += 1
            self._reset_answered = self.commanded in _RESETS
        self._resolve(_HEARD)

    def _on_event(self, event: Event) -> None:
        self._resolve(event)
        self._callbacks(event)
        self._network.emit(event)

    def _resolve(self, event: Event) -> None:
        self._waiters.resolve(event)

    def _close(self) -> None:
        self._removed = True
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        self._host.close()
        self._waiters.fail(removed_error(self.node_id))


class _Heard(Event):
    """Internal: a frame arrived on the node's heartbeat identifier."""


_HEARD = _Heard()

#: The async classes are AsyncX, their blocking twins X (see :mod:`cobus`).
__getattr__ = renamed_names(__name__, {"RemoteNmt": ("AsyncRemoteNmt", AsyncRemoteNmt)})
